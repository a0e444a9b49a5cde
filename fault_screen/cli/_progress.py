"""Progress display for long runs.

On a terminal: one line redrawn in place with ``\\r`` (bar, percentage, steps done, simulated
time, wall time, estimated time left).  Otherwise (a pipe, a log file, CI): a plain line each
time another 10 % of the simulated time is done.
"""
from __future__ import annotations

import sys
import time as _time


def format_duration(seconds: float) -> str:
    """``42.0 s``, ``3 min 05 s``, ``2 h 03 min``."""
    if seconds != seconds or seconds < 0:  # nan
        return "?"
    if seconds < 60:
        return f"{seconds:.1f} s"
    if seconds < 3600:
        m, s = divmod(int(round(seconds)), 60)
        return f"{m} min {s:02d} s"
    h, rest = divmod(int(round(seconds)), 3600)
    return f"{h} h {rest // 60:02d} min"


class Progress:
    """``progress(step, t, end, wall)`` callback for :func:`fault_screen.simulate`."""

    def __init__(self, stream=None, *, tty: bool | None = None, width: int = 24,
                 interval: float = 0.1, every: float = 0.1):
        self.stream = stream if stream is not None else sys.stdout
        if tty is None:
            isatty = getattr(self.stream, "isatty", None)
            tty = bool(isatty and isatty())
        self.tty = tty
        self.width = width
        self.interval = interval      # s between redraws on a terminal
        self.every = every            # fraction of the run between plain lines
        self._next_fraction = every
        self._last_draw = -float("inf")
        self._last_len = 0
        self._open = False
        self._first = None            # (t, wall) at the first step: excludes the model build

    def _eta(self, t: float, end: float, wall: float) -> float:
        """Time left from the pace since the first step (the first one includes the set-up)."""
        if self._first is None:
            self._first = (t, wall)
        t1, w1 = self._first
        if t > t1:
            return (wall - w1) / (t - t1) * (end - t)
        return 0.0 if t >= end else float("nan")    # unknown until a second step is done

    def __call__(self, step: int, t: float, end: float, wall: float) -> None:
        frac = min(max(t / end, 0.0), 1.0) if end > 0 else 1.0
        done = frac >= 1.0 - 1e-12
        eta = self._eta(t, end, wall)
        if self.tty:
            now = _time.monotonic()
            if not done and now - self._last_draw < self.interval:
                return
            self._last_draw = now
            n = int(round(frac * self.width))
            bar = "#" * n + "-" * (self.width - n)
            line = (f"[{bar}] {100 * frac:5.1f}%  step {step}  t {t:.6g}/{end:.6g} s  "
                    f"wall {format_duration(wall)}  left ~{format_duration(eta)}")
            pad = " " * max(0, self._last_len - len(line))
            self.stream.write("\r" + line + pad)
            self.stream.flush()
            self._last_len = len(line)
            self._open = True
            if done:
                self.close()
        else:
            if frac + 1e-12 < self._next_fraction and not done:
                return
            while self._next_fraction <= frac + 1e-12:
                self._next_fraction += self.every
            self.stream.write(f"{100 * frac:3.0f}%  step {step}  t = {t:.6g} s of {end:.6g} s  "
                              f"wall {format_duration(wall)}  left ~{format_duration(eta)}\n")
            self.stream.flush()

    def close(self) -> None:
        """End the in-place line (call before printing anything else, also after an error)."""
        if self._open:
            self.stream.write("\n")
            self.stream.flush()
            self._open = False
