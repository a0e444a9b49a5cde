"""Space-time maps along the fault (the layout of Fig. 10 of Schwartzkopff et al.)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..outputs import display
from ._canvas import _figure, _save, _title, start_time, time_scale
from .events import _event_label, _events_in, _rug_time_y

#: Smallest change coloured on the space-time maps (SI): 1 kPa of overpressure (a downhole
#: gauge's resolution) and 1 um of slip or opening (a borehole displacement sensor's); below,
#: the model's numbers are round-off and penalty give, not something a sensor could see
COLOUR_FLOORS = {"overpressure": 1e3, "slip": 1e-6, "opening": 1e-6}
BELOW_FLOOR_GREY = "0.9"


def active_half_width(result, *, fraction: float = 0.01, slip_floor: float = 1e-9,
                      pad: float = 1.5) -> float | None:
    """Half width (m) around the injection point holding the fault's activity: where the
    overpressure, opening change or slip ever exceeds ``fraction`` of its peak (slip and opening
    only above ``slip_floor`` m, so numerical noise does not count), times ``pad``.  None when the
    activity covers most of the fault (then the whole fault is shown)."""
    x = np.asarray(result.fault_x, dtype=float)
    if x.size < 2:
        return None
    reach = 0.0
    for key, floor in (("overpressure", 0.0), ("opening", slip_floor), ("slip", slip_floor)):
        if key not in result.fault:
            continue
        a = np.asarray(result.fault[key], dtype=float)
        if key == "opening":
            a = a - a[:1]
        amax = np.nanmax(np.abs(a), axis=0) if a.size else np.zeros_like(x)
        peak = float(np.nanmax(amax)) if amax.size else 0.0
        if peak <= floor:
            continue
        hot = amax > max(fraction * peak, floor)
        if np.any(hot):
            reach = max(reach, float(np.max(np.abs(x[hot]))))
    full = float(max(-x.min(), x.max()))
    lim = max(pad * reach, 0.05 * full)
    return None if lim >= 0.8 * full or reach == 0.0 else lim


def plot_space_time(result, path, events=None, *, xlim=None) -> Path:
    """Space-time maps of fault pressure, slip and opening (Fig. 10 layout) to the PNG ``path``.

    The distance axis is zoomed on the active part of the fault (:func:`active_half_width`)
    unless ``xlim`` (m, m) is given."""
    t = np.asarray(result.time, dtype=float)
    f, tu = time_scale(float(t[-1]) if t.size else 0.0)
    x = np.asarray(result.fault_x, dtype=float)
    order = np.argsort(x, kind="stable")
    x = x[order]
    fields = [
        # overpressure: the in-situ pore pressure varies with depth and would hide the plume
        ("overpressure", *display("fault", "overpressure"), "fault overpressure", "viridis"),
        ("slip", *display("fault", "slip"), "slip", None),
        ("opening", *display("fault", "opening"), "opening", "magma"),
    ]
    from matplotlib import colormaps
    ev = _events_in(events, float(t[0]), float(t[-1])) if t.size else None
    fig = _figure(figsize=(15, 5.5), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True, sharex=True)
    for ax, (key, scale, shown_unit, name, cmap) in zip(axes, fields):
        label = f"{name} ({shown_unit})"
        z = np.asarray(result.fault[key], dtype=float)[:, order] * scale
        floor = COLOUR_FLOORS[key] * scale
        # below the floor: numerical noise, not a measurable change; left uncoloured (grey)
        z = np.ma.masked_where(~(np.abs(z) >= floor), z)
        kw = {}
        lo = float(z.min()) if z.count() else 0.0
        hi = float(z.max()) if z.count() else 0.0
        if cmap is None:  # slip: diverging if it changes sign
            if lo < 0 < hi:
                lim = max(-lo, hi)
                cmap, kw = "RdBu_r", {"vmin": -lim, "vmax": lim}
            else:
                cmap = "viridis"
        cmap = colormaps[cmap].with_extremes(bad=BELOW_FLOOR_GREY)
        if not z.count():
            kw = {"vmin": 0.0, "vmax": floor}
        label = f"{label}; grey: |{key}| < {floor:g} {shown_unit}"
        # the profiles have their own times when [output] thins them
        tp = np.asarray(getattr(result, "profile_time", t), dtype=float)
        mesh = ax.pcolormesh(x, tp * f, z, shading="nearest", cmap=cmap, rasterized=True, **kw)
        cb = fig.colorbar(mesh, ax=ax, pad=0.01)
        cb.set_label(label)
        ax.set_title(label.split(" (")[0], loc="left")
        if not z.count():
            ax.text(0.5, 0.5, f"no {key} (all |{key}| < {floor:g} {shown_unit})", transform=ax.transAxes,
                    ha="center", va="center", fontsize="small",
                    bbox={"facecolor": "w", "alpha": 0.8, "edgecolor": "0.5"})
        ax.set_xlabel("distance along fault from injection point (m)")
        ax.axvline(0.0, color="w", lw=0.6, ls=":", alpha=0.8)
        if ev is not None:
            te, me, n_out, _ = ev
            h = _rug_time_y(ax, te * f, me, label=_event_label(te.size, n_out))
    axes[0].set_ylabel(f"time ({tu} after model time 0)")
    axes[0].set_ylim(t[0] * f, t[-1] * f)
    start = start_time(result)
    if start is not None:
        axes[0].set_title(f"overpressure; t = 0 at {start.isoformat(sep=' ')}", loc="left")
    lim = active_half_width(result) if xlim is None else None
    if xlim is not None:
        axes[0].set_xlim(*xlim)
    elif lim is not None:
        axes[0].set_xlim(max(-lim, x[0]), min(lim, x[-1]))
    if ev is not None:
        fig.legend([h], [h.get_label()], loc="outside lower center", fontsize="small",
                   frameon=False)
    fig.suptitle(f"{_title(result)}: fault, space-time", x=0.01, ha="left")
    return _save(fig, path)

