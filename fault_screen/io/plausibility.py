"""Is a log what an injection can be?  Checks that catch unit mistakes before they turn into a
green light: a time column in days read as seconds gives thousands of samples a millisecond
apart; a rate column in m3/min read as m3/s gives a rate no pump delivers.

:func:`check_plausible` returns the findings: ``stop`` ones (the command stops with exit code 2
unless the user accepts them) and ``warn`` ones (said loudly, the run goes on).  Each is one line
with the numbers and the option that fixes it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional

import numpy as np

__all__ = ["Finding", "check_plausible", "FASTEST_SAMPLING", "LONGEST_LOG", "LARGEST_RATE",
           "LARGEST_VOLUME"]

#: Shortest median interval (s) between samples of an injection logger: 100 samples a second is
#: beyond field and laboratory pump loggers alike.
FASTEST_SAMPLING = 0.01
#: Intervals (s) at most this short are the ramps the readers insert (steps, held gaps), not rows.
ROW_SPACING = 2e-6
#: Longest log (s): a century of injection (the scene's plausible time.end).
LONGEST_LOG = 3.2e9
#: Largest plausible rate (m3/s): the scene's plausible injection rate (larger spreads exist,
#: but a single fault interval taking more is a unit mistake far more often).
LARGEST_RATE = 1.0
#: Largest plausible volume (m3) of one log: ten times the largest disposal wells' decades.
LARGEST_VOLUME = 1e8


@dataclass(frozen=True)
class Finding:
    """``level`` "stop" or "warn", and the one-line ``message``."""

    level: str
    message: str


def _spacing(seconds: float) -> str:
    if seconds < 1:
        return f"{seconds * 1e3:.3g} ms"
    if seconds < 120:
        return f"{seconds:.3g} s"
    if seconds < 7200:
        return f"{seconds / 60:.3g} min"
    return f"{seconds / 3600:.3g} h"


def check_plausible(time, flow_rate, *, scene_rate: Optional[float] = None,
                    option: str = "--accept-implausible",
                    time_unit_option: str = "--time-unit",
                    flow_unit_option: str = "--flow-unit") -> List[Finding]:
    """Findings about samples ``time`` (s) and ``flow_rate`` (m3/s) of a log.

    ``scene_rate`` (m3/s): the largest rate of the scene's own schedule, if any; a log whose
    peak differs from it by more than a factor 1000 is said loudly (the scene was built for
    another scale).
    """
    t = np.asarray(time, dtype=np.float64)
    q = np.asarray(flow_rate, dtype=np.float64)
    out: List[Finding] = []
    if t.size < 2:
        return out
    duration = float(t[-1] - t[0])
    volume = float(np.sum(0.5 * (q[1:] + q[:-1]) * np.diff(t)))
    peak = float(np.max(np.abs(q)))
    d = np.diff(t)
    rows = d[d > ROW_SPACING]          # not the ramps of rate steps and held gaps (<= 1 us)
    median = float(np.median(rows if rows.size else d))
    said = f"{t.size} samples over {_spacing(duration)}, {volume:.6g} m3"
    accept = f"or add {option} to go on"
    if median < FASTEST_SAMPLING:
        out.append(Finding("stop", (
            f"{said}: a sample every {_spacing(median)} (median) is faster than any injection "
            f"logger (at most one per {FASTEST_SAMPLING * 1e3:g} ms); if the time column is not in "
            f"seconds give its unit with {time_unit_option} (e.g. {time_unit_option} min or d), "
            f"{accept}")))
    if duration > LONGEST_LOG:
        out.append(Finding("stop", (
            f"{said}: longer than a century ({LONGEST_LOG:g} s); check the time column's unit "
            f"({time_unit_option}), {accept}")))
    if peak > LARGEST_RATE:
        out.append(Finding("stop", (
            f"{said}: a peak rate of {peak:.6g} m3/s is beyond what one fault interval takes "
            f"(plausible up to {LARGEST_RATE:g} m3/s); check the rate's unit ({flow_unit_option}), "
            f"{accept}")))
    if volume > LARGEST_VOLUME:
        out.append(Finding("stop", (
            f"{said}: more than {LARGEST_VOLUME:g} m3 injected; check the units, {accept}")))
    if scene_rate is not None and scene_rate > 0 and peak > 0 and \
            not 1e-3 <= peak / scene_rate <= 1e3:
        out.append(Finding("warn", (
            f"{said}: the log's peak rate {peak:.6g} m3/s is {peak / scene_rate:.3g} times the "
            f"scene's scheduled peak {scene_rate:.6g} m3/s; the scene may be built for another "
            f"scale, or a unit is wrong")))
    return out
