"""Replace a module's functions or a class's methods while a benchmark times or counts them, and
put them back: the one lookup-and-restore that the benchmarks' timers and counters share
(``sweeps.py``, ``performance.py``, ``woodbury.py``, ``per_step.py``).

    with Patches() as patches:
        patches.replace("fault_screen.solver", "NewtonSolver._prepare", lambda f: timed(f))
        ...                                   # run; the originals are back on leaving the block
"""
from __future__ import annotations

import importlib


class Patches:
    """Replacements made by ``replace``, undone last first by ``restore`` (or on leaving a
    ``with`` block)."""

    def __init__(self):
        self._undo = []

    def replace(self, owner, name, make):
        """Replace ``owner``'s ``name`` by ``make(function)`` and return the function.

        ``owner`` is a module, a module's dotted name or a class; ``name`` may go through
        classes (``"NewtonSolver._prepare"``). A classmethod or staticmethod stays one, so that
        ``make`` always wraps the plain function."""
        if isinstance(owner, str):
            owner = importlib.import_module(owner)
        *path, leaf = name.split(".")
        for part in path:
            owner = getattr(owner, part)
        raw = owner.__dict__[leaf]
        kind = type(raw) if isinstance(raw, (classmethod, staticmethod)) else None
        function = raw.__func__ if kind else raw
        new = make(function)
        setattr(owner, leaf, kind(new) if kind else new)
        self._undo.append((owner, leaf, raw))
        return function

    def restore(self):
        while self._undo:
            owner, leaf, raw = self._undo.pop()
            setattr(owner, leaf, raw)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.restore()
