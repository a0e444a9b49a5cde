"""Helpers for trying the monitor against local stand-ins of the services it reads."""
