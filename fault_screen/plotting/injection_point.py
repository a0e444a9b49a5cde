"""The injection point against time (the layout of Fig. 9 of Schwartzkopff et al.)."""
from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from ..outputs import display
from ._canvas import MPA, _clock_axis, _figure, _save, _title, flow_unit, start_time, time_scale
from .events import _event_label, _events_in, _magnitude_panel, _rug_time_x
from .levels import level_axis, level_handles, result_levels


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

    levels = result_levels(result)
    panels = ((["mag"] if has_mag else []) + ["p"] + (["meas"] if has_log_p else []) + ["d"]
              + (["level"] if levels is not None else []))
    ratios = {"mag": 1.2, "p": 3, "meas": 2.2, "d": 3, "level": 0.3}
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
        ax.set_zorder(2)  # the data above the flow rate's twin axis
        ax.patch.set_visible(False)
        return tw, hs

    pf, pu = display("injection", "overpressure")
    hp = ax_p.plot(t * f, np.asarray(inj["overpressure"], dtype=float) * pf, color="tab:blue",
                   lw=1.8, label=f"overpressure ({pu})")
    ax_p.set_ylabel(f"overpressure at injection point ({pu})")
    _, hq = flow_twin(ax_p)

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
    hl = []
    if levels is not None:  # the traffic light on an axis of its own: it hides no data
        level_axis(axes["level"], t * f, levels)
        hl = level_handles(levels)
    axes[panels[-1]].set_xlabel(f"time ({tu} after model time 0)")

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
    top_ax.set_title(textwrap.fill(f"{_title(result)}: injection point", 80), loc="left")

    handles = hp + hm + hs + ho + hq + he + hl
    fig.legend(handles, [h.get_label() for h in handles], loc="outside lower center", ncols=3,
               fontsize="small", frameon=False)
    for key, ax in axes.items():
        if key != "level":
            ax.grid(alpha=0.3)
    ax_p.set_xlim(t[0] * f, t[-1] * f)
    _clock_axis(top_ax, start_time(result), f)
    return _save(fig, path)

