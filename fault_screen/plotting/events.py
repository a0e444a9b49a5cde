"""Seismic events on the figures: markers sized by magnitude, rugs along time axes, the
magnitude panel. ``events``: anything with ``.time`` (s of model time) and ``.magnitude``, e.g.
:class:`fault_screen.io.events.EventCatalog`."""
from __future__ import annotations

import numpy as np


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

