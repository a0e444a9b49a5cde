"""What every figure shares: the Agg canvas (pyplot and the global backend are not touched),
atomic saving, the time axis' unit, the title, the flow-rate unit and the clock-time axis."""
from __future__ import annotations

import os
import re
from pathlib import Path

from ..outputs import display

MPA, _ = display("injection", "overpressure")   # figures show stresses in MPa, slips in mm
MM, _ = display("injection", "slip")
L_PER_MIN = 60e3


def time_scale(t_end: float) -> tuple[float, str]:
    """(factor from s, unit) for a time axis spanning ``t_end`` seconds."""
    if t_end <= 3600.0:
        return 1.0, "s"
    if t_end <= 10 * 3600.0:
        return 1 / 60.0, "min"
    if t_end <= 5 * 86400.0:
        return 1 / 3600.0, "h"
    return 1 / 86400.0, "d"


def _figure(**kw):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kw)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path) -> Path:
    """Write a PNG atomically (temporary name, then rename)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    try:
        fig.savefig(tmp, format="png", dpi=150)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _title(result) -> str:
    """The scene's title; for a replay, the log replayed replaces the scene's own schedule
    (a bundled scene's "stand-in step-rate schedule" is not what was run)."""
    try:
        title = str(result.scene.title)
    except AttributeError:  # pragma: no cover - a result without a scene
        return ""
    meta = getattr(result, "meta", None) or {}
    log = meta.get("log_file")
    if log:
        title = re.sub(r",?\s*[^,]*\bschedule\b[^,]*$", "", title).strip()
        title = f"{title}, replay of {Path(str(log)).name}" if title else f"replay of {Path(str(log)).name}"
    return title if len(title) <= 90 else title[:87] + "..."  # keep the suptitle on the canvas


def flow_unit(result) -> tuple[float, str]:
    """(factor from m3/s, unit) for flow-rate axes: the replayed log's own unit, else L/min."""
    from ..units import factor

    unit = (getattr(result, "meta", None) or {}).get("log_flow_unit") or "L/min"
    try:
        return 1.0 / factor(unit, "flow_rate"), unit
    except ValueError:
        return L_PER_MIN, "L/min"


def start_time(result):
    """Aware datetime of model time 0 (``meta['start']``: --t0 or the log's first stamp), or None."""
    from datetime import datetime

    text = (getattr(result, "meta", None) or {}).get("start")
    if not text:
        return None
    try:
        dt = datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        return None
    return dt if dt.utcoffset() is not None else None


def _clock_axis(ax, start, f):
    """A second x axis on top in clock time (the date added when the run spans days)."""
    from datetime import timedelta

    from matplotlib.ticker import FuncFormatter

    if start is None:
        return None
    sec = ax.secondary_xaxis("top", functions=(lambda v: v, lambda v: v))
    span = abs(ax.get_xlim()[1] - ax.get_xlim()[0]) / f
    fmt = "%d %b %H:%M" if span > 86400 else ("%H:%M:%S" if span < 600 else "%H:%M")

    def label(v, _pos):
        try:
            return (start + timedelta(seconds=float(v) / f)).strftime(fmt)
        except (OverflowError, ValueError):
            return ""
    sec.xaxis.set_major_formatter(FuncFormatter(label))
    sec.set_xlabel(f"clock time ({start.tzname() or start.strftime('%z')}, {start:%Y-%m-%d})")
    return sec

