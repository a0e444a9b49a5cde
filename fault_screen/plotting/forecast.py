"""``<stem>-forecast.png``: the screening metrics ahead under each plan.

Peak slip rate, largest utilisation and injection overpressure against the time after "now"
(one line per plan; the advised rate dashed), with the thresholds of the ``[monitor]`` rules,
the "now" line, each plan's time to yellow (and red) marked, and the advice written out.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

# the figure machinery, in one place (the plotting modules are moving into a package)
from ._canvas import _figure, _save, time_scale
from .levels import LEVEL_COLOURS
from .screening import rule_thresholds

__all__ = ["plot_forecast"]

#: peak slip rates below this (m/s) are drawn at it: the round-off of a fault at rest (1e-21 m/s
#: on Rustrel) would stretch the axis over twenty decades
SLIP_RATE_FLOOR = 1e-12

PANELS = (("peak_slip_rate", "peak slip rate (m/s)", 1.0),
          ("max_utilisation", "largest utilisation (-)", 1.0),
          ("injection_overpressure", "injection overpressure (MPa)", 1e-6))


def plot_forecast(forecasts, path, *, spec=None, advice=None, title: str = "", ensemble=None) -> Path:
    """Draw ``forecasts`` (made at one time) to the PNG ``path``; ``spec``: the ``[monitor]`` whose
    thresholds are drawn; ``advice``: the :class:`~fault_screen.forecast.Advice` made there;
    ``ensemble``: one :class:`~fault_screen.forecast.ensemble.EnsembleForecast` per forecast, in
    the same order, whose members' 10-90 % band is shaded around each plan's line."""
    from ..screening import LEVEL_NAMES, RED, YELLOW

    forecasts = list(forecasts)
    if not forecasts:
        raise ValueError("no forecast to draw")
    made_at = forecasts[0].made_at
    lines = [(f, "-") for f in forecasts]
    if advice is not None and not advice.even_zero_reaches:
        lines.append((advice.below, "--"))
    span = max(float(f.time[-1] - made_at) for f, _ in lines)
    factor, unit = time_scale(span)
    fig = _figure(figsize=(9, 8), layout="constrained")
    axes = fig.subplots(len(PANELS), 1, sharex=True)
    colours = [c for c in (f"C{i}" for i in range(10)) if c not in ("C3", "C8")]
    for k, (f, style) in enumerate(lines):
        t = (f.time - made_at) * factor
        label = _advised_label(advice) if style == "--" else f.plan
        for ax, (name, _, scale) in zip(axes, PANELS):
            y = f.metrics.get(name)
            if y is None:
                continue
            y = np.asarray(y, dtype=float) * scale
            if name == "peak_slip_rate":   # below SLIP_RATE_FLOOR: round-off of a fault at rest
                y = np.maximum(y, SLIP_RATE_FLOOR)
            colour = "k" if style == "--" else colours[k % len(colours)]   # (red and yellow mean levels)
            ax.plot(t, y, style, color=colour, label=label, lw=1.6)
            if ensemble is not None and style == "-":
                _band(ax, f, ensemble[k].forecasts, name, scale, t, colour)
            for level, marker in ((YELLOW, "o"), (RED, "s")):
                when = f.time_to_yellow if level == YELLOW else f.time_to_red
                if when is None:
                    continue
                i = int(np.argmin(np.abs(f.time - made_at - when)))
                if np.isfinite(y[i]) and not (name == "peak_slip_rate" and y[i] <= SLIP_RATE_FLOOR):
                    ax.plot(t[i], y[i], marker, color=LEVEL_COLOURS[level], mec="k", ms=7, zorder=5)
    for ax, (name, label, scale) in zip(axes, PANELS):
        ax.set_ylabel(label)
        ax.axvline(0.0, color="k", lw=1.0)
        if name == "peak_slip_rate":
            ax.set_yscale("log")
        for metric, value, level, text in (rule_thresholds(spec) if spec is not None else []):
            if metric == name:
                ax.axhline(value * scale, color=LEVEL_COLOURS[level], ls=":", lw=1.2,
                           label=f"{LEVEL_NAMES[level]}: {text.split(':', 1)[0]}")
        ax.grid(alpha=0.3)
    axes[0].text(0.0, 1.02, " now", transform=axes[0].get_xaxis_transform(), ha="left", va="bottom")
    axes[0].legend(loc="upper left", fontsize=8, ncols=2)
    if axes[1].get_legend_handles_labels()[0]:
        axes[1].legend(loc="lower left", fontsize=8, ncols=2)
    axes[-1].set_xlabel(f"time after now ({unit}); now = t {made_at:g} s of the run")
    heading = f"Forecast from t = {made_at:g} s over {span * factor:g} {unit}"
    if title:
        heading += f"\n{title}"
    if advice is not None:
        heading += f"\n{advice.describe()}"
    fig.suptitle(heading, fontsize=10)
    return _save(fig, Path(path))


def _band(ax, f, members, name, scale, t, colour):
    """The 10-90 % band of the members' ``name`` at the times of ``f`` (shaded)."""
    series = [np.interp(f.time, m.time, np.asarray(m.metrics[name], dtype=float))
              for m in members if name in m.metrics and m.time is not None and m.time.size]
    if len(series) < 2:
        return
    lo, hi = np.nanpercentile(np.array(series) * scale, [10, 90], axis=0)
    if name == "peak_slip_rate":
        lo, hi = np.maximum(lo, SLIP_RATE_FLOOR), np.maximum(hi, SLIP_RATE_FLOOR)
    ax.fill_between(t, lo, hi, color=colour, alpha=0.2, lw=0, label=f"{f.plan}: members 10-90 %")


def _advised_label(advice) -> str:
    if advice.control == "rate":
        return f"advised: {advice.rate * 60e3:.4g} L/min"
    return f"advised: {advice.rate / 1e6:.4g} MPa"
