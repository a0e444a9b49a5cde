"""The traffic-light band: screening level against time on any axis whose x is time.

The level at an output time holds until the next one, so the band colours [t_i, t_i+1) with
level_i.
"""
from __future__ import annotations

import numpy as np

LEVEL_COLOURS = ("#2ca02c", "#f2c200", "#d62728")


def _segments(level):
    """(start index, end index exclusive, level) runs of equal level."""
    level = np.asarray(level)
    if level.size == 0:
        return []
    cut = np.flatnonzero(np.diff(level)) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [level.size]])
    return [(int(a), int(b), int(level[a])) for a, b in zip(starts, ends)]



def draw_level_band(ax, time, level, *, height: float = 0.04, alpha: float = 0.6):
    """Colour the bottom ``height`` (axis fraction) of ``ax`` by screening level; ``time`` in the
    axis' own time unit."""
    import matplotlib.transforms as mtransforms
    from matplotlib.patches import Rectangle

    t = np.asarray(time, dtype=float)
    tr = mtransforms.blended_transform_factory(ax.transData, ax.transAxes)
    for a, b, lev in _segments(level):
        t1 = t[b] if b < t.size else t[-1]
        ax.add_patch(Rectangle((t[a], 0.0), t1 - t[a], height, transform=tr, facecolor=LEVEL_COLOURS[lev],
                               edgecolor="none", alpha=alpha, zorder=6, clip_on=True))



def draw_result_level_band(result, axes, time_factor: float) -> None:
    """The level band of a screened result on each of ``axes`` (x: time times ``time_factor``);
    nothing for a result without ``/screening/``."""
    sc = (getattr(result, "extra", None) or {}).get("screening")
    if not sc or "level" not in sc:
        return
    for ax in axes:
        draw_level_band(ax, np.asarray(result.time, dtype=float) * time_factor, sc["level"])

