"""Figures of a run (PNG, matplotlib's Agg canvas; pyplot and the global backend are not touched).

* :func:`plot_injection_point` -- overpressure (MPa), slip and opening (mm) at the injection point
  against time, flow rate (L/min) on a twin axis (the layout of Fig. 9 of Schwartzkopff et al.);
* :func:`plot_space_time` -- space-time maps (distance along the fault x time) of fault overpressure
  (MPa), slip and opening (mm) (Fig. 10);
* :func:`plot_result` -- both, into a directory.

Seismic events (``events``: anything with ``.time`` in s of model time and ``.magnitude``, e.g.
:class:`fault_screen.io.events.EventCatalog`) are drawn as markers on every time axis.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from .outputs import display

MPA, _ = display("injection", "overpressure")   # figures show stresses in MPa, slips in mm
MM, _ = display("injection", "slip")
L_PER_MIN = 60e3

__all__ = ["plot_result", "plot_injection_point", "plot_space_time", "time_scale", "flow_unit",
           "magnitude_groups", "start_time"]


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


def _events_in(events, t0, t1):
    """(times, magnitudes, number outside [t0, t1], mask of those inside) of the events, or
    None."""
    if events is None or len(np.asarray(events.time)) == 0:
        return None
    t = np.asarray(events.time, dtype=float)
    m = np.asarray(events.magnitude, dtype=float)
    keep = (t >= t0) & (t <= t1)
    return t[keep], m[keep], int(np.count_nonzero(~keep)), keep


def _distances(events):
    d = getattr(events, "distance_to_injection", None)
    if d is None:
        return None
    d = np.asarray(d, dtype=float)
    return d if np.any(np.isfinite(d)) else None


def _marker_sizes(m):
    """Marker areas (pt^2) growing with magnitude above the catalogue's smallest, so negative
    magnitudes (micro-seismicity) size like any others; events without magnitude get 25."""
    m = np.asarray(m, dtype=float)
    if m.size == 0 or not np.any(np.isfinite(m)):
        return np.full(m.size, 36.0)
    lo = np.nanmin(m)
    s = 25.0 + 30.0 * np.nan_to_num(m - lo, nan=0.0)
    return np.clip(s, 25.0, 250.0)


def _event_label(n_in, n_out):
    lab = f"seismic events ({n_in})"
    if n_out:
        lab += f"; {n_out} outside the run not shown"
    return lab


def _rug_time_x(ax, times, mags, label=None):
    """Events as triangles along the top of an axis whose x is time."""
    import matplotlib.transforms as mtransforms

    tr = mtransforms.blended_transform_factory(ax.transData, ax.transAxes)
    return ax.scatter(times, np.full(times.size, 0.97), s=_marker_sizes(mags), marker="v",
                      facecolor="crimson", edgecolor="k", linewidth=0.5, transform=tr,
                      clip_on=False, zorder=5, label=label)


def _rug_time_y(ax, times, mags, label=None):
    """Events as triangles along the left edge of an axis whose y is time."""
    import matplotlib.transforms as mtransforms

    tr = mtransforms.blended_transform_factory(ax.transAxes, ax.transData)
    return ax.scatter(np.full(times.size, 0.0), times, s=_marker_sizes(mags), marker=">",
                      facecolor="crimson", edgecolor="k", linewidth=0.5, transform=tr,
                      clip_on=False, zorder=5, label=label)


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
    from .units import factor

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


def magnitude_groups(events, keep=None) -> list[tuple[str, np.ndarray]]:
    """[(magnitude type, indices)]: ML and mb are different scales, so each type is drawn and
    labelled on its own ("?" for events without a type)."""
    n = len(np.asarray(events.time))
    types = list(getattr(events, "magnitude_type", ()) or ())
    types = [t.decode() if isinstance(t, bytes) else str(t) for t in types] + [""] * (n - len(types))
    idx = np.arange(n) if keep is None else np.flatnonzero(keep)
    groups: dict[str, list[int]] = {}
    for i in idx:
        groups.setdefault(types[i] or "?", []).append(int(i))
    return [(k, np.array(v, dtype=int)) for k, v in sorted(groups.items())]


def plot_injection_point(result, path, events=None) -> Path:
    """Injection point history (Fig. 9 layout) to the PNG ``path``.

    Flow rates are drawn in the replayed log's unit (L/min otherwise); when the log has a
    pressure column, a panel sets the measured pressure against the modelled injection
    pressure; with a known start (``meta['start']``) a clock-time axis is added on top.
    Events: magnitudes per magnitude type, coloured by distance to the injection point when
    the catalogue has distances."""
    t = np.asarray(result.time, dtype=float)
    f, tu = time_scale(float(t[-1]) if t.size else 0.0)
    inj = result.injection
    qf, qu = flow_unit(result)
    q = np.asarray(inj["flow_rate"], dtype=float) * qf
    ev = _events_in(events, float(t[0]), float(t[-1])) if t.size else None
    has_mag = ev is not None and np.any(np.isfinite(ev[1]))
    log = result.extra.get("log") if getattr(result, "extra", None) else None
    has_log_p = log is not None and "pressure" in log and np.size(log["pressure"]) > 0 \
        and "pressure" in inj

    panels = (["mag"] if has_mag else []) + ["p"] + (["meas"] if has_log_p else []) + ["d"]
    ratios = {"mag": 1.2, "p": 3, "meas": 2.2, "d": 3}
    fig = _figure(figsize=(9, 4 + 1.1 * sum(ratios[k] for k in panels)), layout="constrained")
    axes = dict(zip(panels, np.atleast_1d(fig.subplots(len(panels), 1, sharex=True, gridspec_kw={
        "height_ratios": [ratios[k] for k in panels]}))))
    ax_p, ax_d = axes["p"], axes["d"]

    def flow_twin(ax):
        tw = ax.twinx()
        hs = []
        if log is not None and "time" in log and "flow_rate" in log:
            tl = np.asarray(log["time"], dtype=float)
            ql = np.asarray(log["flow_rate"], dtype=float) * qf
            hs += tw.plot(tl * f, ql, color="tab:orange", lw=2.5, alpha=0.45,
                          label=f"flow rate, log samples ({qu})")
        # the model's rate is the average over each step, recorded at the step's end
        hs += tw.plot(t * f, q, color="0.35", lw=1.2, drawstyle="steps-pre",
                      label=f"flow rate, model step average ({qu})")
        tw.set_ylabel(f"flow rate ({qu})")
        top = max(float(np.nanmax(q)) if q.size else 0.0, 1e-12)
        if log is not None and "flow_rate" in log and np.size(log["flow_rate"]):
            top = max(top, float(np.nanmax(log["flow_rate"])) * qf)
        tw.set_ylim(0, 1.15 * top)
        return tw, hs

    pf, pu = display("injection", "overpressure")
    hp = ax_p.plot(t * f, np.asarray(inj["overpressure"], dtype=float) * pf, color="tab:blue",
                   lw=1.8, label=f"overpressure ({pu})")
    ax_p.set_ylabel(f"overpressure at injection point ({pu})")
    _, hq = flow_twin(ax_p)
    ax_p.set_zorder(2)
    ax_p.patch.set_visible(False)

    hm = []
    if has_log_p:
        ax_m = axes["meas"]
        hm += ax_m.plot(t * f, np.asarray(inj["pressure"], dtype=float) * MPA, color="tab:blue",
                        lw=1.8, label="pressure, model at the injection point (MPa)")
        hm += ax_m.plot(np.asarray(log["time"], dtype=float) * f,
                        np.asarray(log["pressure"], dtype=float) * MPA, color="k", lw=1.0,
                        ls="--", label="pressure, measured (log) (MPa)")
        ax_m.set_ylabel("injection pressure (MPa)")
        ax_m.grid(alpha=0.3)

    sf, su = display("injection", "slip")
    hs = ax_d.plot(t * f, np.asarray(inj["slip"], dtype=float) * sf, color="tab:red", lw=1.8,
                   label=f"slip ({su})")
    ho = ax_d.plot(t * f, np.asarray(inj["opening"], dtype=float) * sf, color="tab:green",
                   lw=1.8, label=f"opening ({su})")
    ax_d.set_ylabel(f"slip, opening at injection point ({su})")
    _, hq2 = flow_twin(ax_d)
    ax_d.set_zorder(2)
    ax_d.patch.set_visible(False)
    ax_d.set_xlabel(f"time ({tu} after model time 0)")

    he = []
    top_ax = axes[panels[0]]
    if ev is not None:
        te, me, n_out, keep = ev
        lab = _event_label(te.size, n_out)
        for ax in (ax_p, ax_d):
            h = _rug_time_x(ax, te * f, me, label=lab)
        he = [h]
        if has_mag:
            _magnitude_panel(fig, axes["mag"], events, keep, f)
    top_ax.set_title(f"{_title(result)}: injection point", loc="left")

    handles = hp + hm + hs + ho + hq + he
    fig.legend(handles, [h.get_label() for h in handles], loc="outside lower center", ncols=3,
               fontsize="small", frameon=False)
    for ax in axes.values():
        ax.grid(alpha=0.3)
    ax_p.set_xlim(t[0] * f, t[-1] * f)
    _clock_axis(top_ax, start_time(result), f)
    from .plotting_screening import draw_result_level_band
    draw_result_level_band(result, (ax_p, ax_d), f)  # the screening traffic light, if screened
    return _save(fig, path)


def _magnitude_panel(fig, ax, events, keep, f):
    """Magnitude against time: one marker shape per magnitude type; colour = distance to the
    injection point (m) when known.  The axis follows the data, negative magnitudes included."""
    t = np.asarray(events.time, dtype=float)
    m = np.asarray(events.magnitude, dtype=float)
    d = _distances(events)
    ok = keep & np.isfinite(m)
    lo, hi = float(np.nanmin(m[ok])), float(np.nanmax(m[ok]))
    base = lo - 0.3 - 0.1 * (hi - lo)
    ax.vlines(t[ok] * f, base, m[ok], color="0.6", lw=0.6, zorder=1)
    markers = "osD^vP*X"
    norm = None
    if d is not None and np.any(np.isfinite(d[ok])):
        from matplotlib.colors import Normalize

        norm = Normalize(0.0, float(np.nanmax(d[ok])))
    sc = None
    for k, (mtype, idx) in enumerate(magnitude_groups(events, ok)):
        kw = ({"c": d[idx], "cmap": "plasma_r", "norm": norm} if norm is not None
              else {"color": "crimson"})
        sc = ax.scatter(t[idx] * f, m[idx], s=_marker_sizes(m[idx]), marker=markers[k % len(markers)],
                        edgecolor="k", linewidth=0.5, zorder=3, label=mtype, **kw)
    if norm is not None and sc is not None:
        fig.colorbar(sc, ax=ax, pad=0.01).set_label("distance to injection (m)")
    ax.set_ylim(base, hi + 0.3 + 0.1 * (hi - lo))
    ax.set_ylabel("magnitude")
    ax.legend(title="type", fontsize="x-small", title_fontsize="x-small", loc="upper left",
              ncols=4)


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
    ev = _events_in(events, float(t[0]), float(t[-1])) if t.size else None
    fig = _figure(figsize=(15, 5.5), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    for ax, (key, scale, shown_unit, name, cmap) in zip(axes, fields):
        label = f"{name} ({shown_unit})"
        z = np.asarray(result.fault[key], dtype=float)[:, order] * scale
        kw = {}
        if cmap is None:  # slip: diverging if it changes sign
            lo, hi = float(np.nanmin(z)), float(np.nanmax(z))
            if lo < 0 < hi:
                lim = max(-lo, hi)
                cmap, kw = "RdBu_r", {"vmin": -lim, "vmax": lim}
            else:
                cmap = "viridis"
        # the profiles have their own times when [output] thins them
        tp = np.asarray(getattr(result, "profile_time", t), dtype=float)
        mesh = ax.pcolormesh(x, tp * f, z, shading="nearest", cmap=cmap, rasterized=True, **kw)
        cb = fig.colorbar(mesh, ax=ax, pad=0.01)
        cb.set_label(label)
        ax.set_title(label.split(" (")[0], loc="left")
        if key in ("slip", "opening") and float(np.nanmax(np.abs(z), initial=0.0)) < 1e-6:
            ax.text(0.5, 0.5, f"no {key} (all |{key}| < 1e-6 mm)", transform=ax.transAxes,
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


def plot_result(result, out_dir, *, events=None, prefix: str = "") -> list[Path]:
    """Both figures into ``out_dir`` (created): ``<prefix>injection-point.png`` and
    ``<prefix>space-time.png``; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    from .plotting_screening import screening_figures
    return [plot_injection_point(result, out / f"{prefix}injection-point.png", events),
            plot_space_time(result, out / f"{prefix}space-time.png", events)] + screening_figures(result, out, events, prefix)
