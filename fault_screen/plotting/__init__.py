"""Figures of a run (PNG, matplotlib's Agg canvas; pyplot and the global backend are not touched).

* :func:`plot_injection_point` -- overpressure (MPa), slip and opening (mm) at the injection point
  against time, flow rate on a twin axis (the layout of Fig. 9 of Schwartzkopff et al.);
* :func:`plot_space_time` -- space-time maps (distance along the fault x time) of fault overpressure
  (MPa), slip and opening (mm) (Fig. 10);
* :func:`plot_screening` -- the screening metrics with the rules' thresholds and the level band;
* :func:`plot_result` -- all of them, into a directory.

Seismic events (anything with ``.time`` in s of model time and ``.magnitude``, e.g.
:class:`fault_screen.io.events.EventCatalog`) are drawn as markers on every time axis.
"""
from __future__ import annotations

from pathlib import Path

from ._canvas import flow_unit, start_time, time_scale
from .events import magnitude_groups
from .injection_point import plot_injection_point
from .levels import LEVEL_COLOURS, draw_level_band, level_handles, result_levels
from .screening import plot_screening, rule_thresholds, screening_arrays, screening_figures
from .space_time import active_half_width, plot_space_time

__all__ = ["plot_result", "plot_injection_point", "plot_space_time", "plot_screening",
           "screening_figures", "rule_thresholds", "screening_arrays", "draw_level_band",
           "level_handles", "result_levels", "LEVEL_COLOURS", "time_scale", "flow_unit",
           "magnitude_groups", "start_time", "active_half_width"]


def plot_result(result, out_dir, *, events=None, prefix: str = "") -> list[Path]:
    """Both figures into ``out_dir`` (created): ``<prefix>injection-point.png`` and
    ``<prefix>space-time.png``; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return [plot_injection_point(result, out / f"{prefix}injection-point.png", events),
            plot_space_time(result, out / f"{prefix}space-time.png", events)] + screening_figures(result, out, events, prefix)

