"""The screening figure: metrics against time with the thresholds of the ``[monitor]`` rules
(peak slip rate, utilisation, Coulomb margin and delta CFF, injection overpressure and induced
slip, event magnitudes when events are given) and the level band."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..outputs import display
from ._canvas import _figure, _save, _title, time_scale
from .levels import LEVEL_COLOURS, label_transitions, level_axis, level_handles

MPA, _ = display("screening", "min_coulomb_margin")   # stresses in MPa, slips in mm (the schema's)
MM, _ = display("screening", "induced_slip")
#: m/s: below, a fault at rest (the creep of the regularised friction law, ~1e-12 m/s in the
#: bundled scenes): drawn as "below", not as a value
RATE_FLOOR = 1e-12


def screening_figures(result, out_dir, events=None, prefix: str = "") -> list[Path]:
    """``[<prefix>screening.png]`` in ``out_dir`` for a screened result (one holding
    ``/screening/``), else ``[]`` (what :func:`fault_screen.plotting.plot_result` adds)."""
    if "screening" not in (getattr(result, "extra", None) or {}):
        return []
    return [plot_screening(result, Path(out_dir) / f"{prefix}screening.png", events)]


def screening_arrays(result) -> dict:
    """The ``/screening/`` arrays of ``result`` (evaluated now if the result has none)."""
    stored = (getattr(result, "extra", None) or {}).get("screening")
    if stored and "level" in stored:
        return stored
    from ..screening import screen_result

    return screen_result(result, store=False).arrays()


def rule_thresholds(spec) -> list[tuple[str, float, int, str]]:
    """(metric, value, level, label) for every comparison of a metric with a threshold name or a
    number in the rules of ``spec`` (a MonitorSpec): what the screening figure draws."""
    from ..rules import METRICS, parse_condition
    from ..screening import LEVEL_NAMES, thresholds_of

    named = thresholds_of(spec)
    known = set(METRICS) | set(named)
    out = []
    for i, rule in enumerate(spec.rules):
        cond = parse_condition(rule.when, known)
        for left, op, right in cond.comparisons():
            for metric, other in ((left, right), (right, left)):
                if isinstance(metric, str) and metric in METRICS:
                    value = named.get(other) if isinstance(other, str) else other
                    if value is not None and not (isinstance(other, str) and other in METRICS):
                        name = rule.name or f"rules[{i}]"
                        out.append((metric, float(value), LEVEL_NAMES.index(rule.level),
                                    f"{name}: {left} {op} {right}"))
                    break
    return out


def _magnitude_sizes(m):
    """Marker areas growing with magnitude; magnitudes may be negative (micro-seismicity)."""
    m = np.asarray(m, dtype=float)
    if m.size == 0 or not np.any(np.isfinite(m)):
        return np.full(m.size, 30.0)
    return np.clip(20.0 + 40.0 * np.nan_to_num(m - np.nanmin(m), nan=0.0), 20.0, 300.0)


def plot_screening(result, path, events=None, spec=None) -> Path:
    """The screening figure of ``result`` to the PNG ``path``; ``spec``: the [monitor] whose
    thresholds are drawn (default: the result's scene's)."""
    from ..screening import LEVEL_NAMES, read_transitions

    sc = screening_arrays(result)
    spec = spec if spec is not None else result.scene.monitor
    t = np.asarray(result.time, dtype=float)
    f, tu = time_scale(float(t[-1]) if t.size else 0.0)
    ts = t * f
    if events is None and "events" in (getattr(result, "extra", None) or {}):
        events = result.extra["events"]
    ev_t = ev_m = None
    if events is not None:
        get = events.get if isinstance(events, dict) else lambda k: getattr(events, k)
        ev_t = np.asarray(get("time"), dtype=float)
        ev_m = np.asarray(get("magnitude"), dtype=float)
        keep = (ev_t >= t[0]) & (ev_t <= t[-1]) if t.size else ev_t < 0
        ev_t, ev_m = ev_t[keep], ev_m[keep]
    has_events = ev_t is not None and ev_t.size > 0

    panels = ["peak_slip_rate", "max_utilisation", "stress", "injection"] + (["event_magnitude"] if has_events else [])
    fig = _figure(figsize=(10, 2.3 * len(panels) + 1.0), layout="constrained")
    axes = fig.subplots(len(panels) + 1, 1, sharex=True,
                        gridspec_kw={"height_ratios": [3] * len(panels) + [0.45]})
    ax_of = dict(zip(panels, axes))
    ax_of.update(min_coulomb_margin=ax_of["stress"], delta_cff=ax_of["stress"],
                 injection_overpressure=ax_of["injection"])
    scale = {"min_coulomb_margin": MPA, "delta_cff": MPA, "injection_overpressure": MPA,
             "induced_slip": MM}

    ax = ax_of["peak_slip_rate"]
    rate = np.asarray(sc["peak_slip_rate"], dtype=float)
    above = rate >= RATE_FLOOR
    ax.semilogy(ts, np.where(above, rate, np.nan), color="k", lw=1.5, label="peak slip rate")
    if np.any(~above & np.isfinite(rate)):
        # not a value: a fault at rest, whose model creep is not slip
        ax.axhspan(RATE_FLOOR / 10, RATE_FLOOR, color="0.88", zorder=0,
                   label=f"below {RATE_FLOOR:g} m/s: at rest")
        ax.plot(ts[~above], np.full(int(np.count_nonzero(~above)), RATE_FLOOR / 3), ls="none",
                marker="v", ms=3, color="0.45", markevery=max(1, int(np.count_nonzero(~above)) // 60),
                label="peak slip rate below the floor")
    ax.set_ylabel("peak slip rate (m/s)")
    ax = ax_of["max_utilisation"]
    ax.plot(ts, sc["max_utilisation"], color="k", lw=1.5, label="max utilisation")
    ax.axhline(1.0, color="0.4", ls=":", lw=1, label="failure (1)")
    ax.set_ylabel("max |tau| / (mu0 sigma'n) (-)")
    ax = ax_of["stress"]
    ax.plot(ts, np.asarray(sc["min_coulomb_margin"]) * MPA, color="tab:blue", lw=1.5,
            label="min Coulomb margin")
    ax.plot(ts, np.asarray(sc["delta_cff"]) * MPA, color="tab:purple", lw=1.5,
            label="delta CFF at injection point")
    ax.axhline(0.0, color="0.4", ls=":", lw=1)
    ax.set_ylabel("stress (MPa)")
    ax = ax_of["injection"]
    ax.plot(ts, np.asarray(sc["injection_overpressure"]) * MPA, color="tab:blue", lw=1.5,
            label="injection overpressure")
    ax.set_ylabel("overpressure (MPa)")
    tw = ax.twinx()
    tw.plot(ts, np.asarray(sc["induced_slip"]) * MM, color="tab:red", lw=1.5, label="induced slip")
    tw.set_ylabel("induced slip (mm)", color="tab:red")
    ax_of["induced_slip"] = tw
    if has_events:
        ax = ax_of["event_magnitude"]
        ok = np.isfinite(ev_m)
        ax.scatter(ev_t[ok] * f, ev_m[ok], s=_magnitude_sizes(ev_m[ok]), color="crimson",
                   edgecolor="k", linewidth=0.5, zorder=3, label=f"events ({int(ok.sum())})")
        if ok.any():
            ax.vlines(ev_t[ok] * f, np.nanmin(ev_m[ok]) - 0.5, ev_m[ok], color="crimson", lw=0.6)
        ax.set_ylabel("magnitude")

    shown: dict[str, list] = {}
    for metric, value, lev, label in rule_thresholds(spec):
        target = ax_of.get(metric)
        if target is None:
            continue
        target.axhline(value * scale.get(metric, 1.0), color=LEVEL_COLOURS[lev], ls="--", lw=1.2,
                       label=label)
        shown.setdefault(metric, []).append(value * scale.get(metric, 1.0))
    span_values(ax_of["peak_slip_rate"], [rate[above], shown.get("peak_slip_rate", [])],
                log=True, floor=RATE_FLOOR / 10)
    span_values(ax_of["max_utilisation"], [sc["max_utilisation"], [1.0],
                                           shown.get("max_utilisation", [])])
    span_values(ax_of["stress"], [np.asarray(sc["min_coulomb_margin"]) * MPA,
                                  np.asarray(sc["delta_cff"]) * MPA, [0.0],
                                  shown.get("min_coulomb_margin", []), shown.get("delta_cff", [])])
    span_values(ax_of["injection"], [np.asarray(sc["injection_overpressure"]) * MPA, [0.0],
                                     shown.get("injection_overpressure", [])])
    span_values(ax_of["induced_slip"], [np.asarray(sc["induced_slip"]) * MM, [0.0],
                                        shown.get("induced_slip", [])])
    if has_events:
        span_values(ax_of["event_magnitude"], [ev_m[np.isfinite(ev_m)],
                                               shown.get("event_magnitude", [])])
    for key in panels:
        ax = ax_of[key]
        ax.grid(alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        if key == "injection":
            h2, l2 = ax_of["induced_slip"].get_legend_handles_labels()
            handles, labels = handles + h2, labels + l2
        if handles:
            ax.legend(handles, labels, fontsize="x-small", loc="best", framealpha=0.8)

    band = axes[-1]
    level_axis(band, ts, sc["level"])
    fig.legend(handles=level_handles(sc["level"]), loc="outside lower right", ncols=3,
               fontsize="x-small", frameon=False)
    band.set_xlabel(f"time ({tu})")
    if t.size:
        band.set_xlim(ts[0], ts[-1] if ts[-1] > ts[0] else ts[0] + 1.0)
    worst = int(np.max(sc["level"])) if np.size(sc["level"]) else 0
    axes[0].set_title(f"{_title(result)}: screening, highest level {LEVEL_NAMES[worst]}", loc="left",
                      fontsize="medium")
    label_transitions(fig, band, read_transitions(sc), f)
    return _save(fig, path)


def span_values(ax, groups, *, log: bool = False, floor: float | None = None) -> None:
    """Set the y limits of ``ax`` to hold every finite value of ``groups`` (data and the
    thresholds drawn), with a margin; on a log axis, values at or below 0 are left out and
    ``floor`` is the lowest limit."""
    values = np.concatenate([np.ravel(np.asarray(g, dtype=float)) for g in groups] or [np.empty(0)])
    values = values[np.isfinite(values)]
    if log:
        values = values[values > 0]
        if floor is not None:
            values = np.append(values, floor)
        if values.size:
            lo, hi = float(values.min()), float(values.max())
            ax.set_ylim(lo / 2 if floor is None else floor, hi * 10)
        return
    if values.size:
        lo, hi = float(values.min()), float(values.max())
        pad = 0.06 * (hi - lo) if hi > lo else max(abs(hi), 1.0) * 0.1
        ax.set_ylim(lo - pad, hi + pad)

