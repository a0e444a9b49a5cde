"""Readers and writers for operator data files (injection logs, ...)."""
