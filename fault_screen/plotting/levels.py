"""The traffic light: screening level against time, on an axis of its own whose x is time (so
that it never hides data), with legend entries and labels of the level changes that never
overprint each other.

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


def draw_level_band(ax, time, level, *, height: float = 1.0, alpha: float = 1.0):
    """Colour the bottom ``height`` (axis fraction) of ``ax`` by screening level; ``time`` in the
    axis' own time unit. Meant for an axis of its own (:func:`level_axis`)."""
    import matplotlib.transforms as mtransforms
    from matplotlib.patches import Rectangle

    t = np.asarray(time, dtype=float)
    tr = mtransforms.blended_transform_factory(ax.transData, ax.transAxes)
    for a, b, lev in _segments(level):
        t1 = t[b] if b < t.size else t[-1]
        ax.add_patch(Rectangle((t[a], 0.0), t1 - t[a], height, transform=tr, facecolor=LEVEL_COLOURS[lev],
                               edgecolor="none", alpha=alpha, zorder=6, clip_on=True))


def level_handles(level) -> list:
    """Legend entries (patches) for the levels that occur in ``level``."""
    from matplotlib.patches import Patch

    from ..screening import LEVEL_NAMES

    present = sorted({int(v) for v in np.asarray(level).ravel()})
    return [Patch(facecolor=LEVEL_COLOURS[v], edgecolor="none", label=f"screening level {LEVEL_NAMES[v]}")
            for v in present]


def level_axis(ax, time, level) -> None:
    """Make ``ax`` (a thin axis sharing x with the others) the level band."""
    draw_level_band(ax, time, level)
    ax.set_yticks([])
    ax.set_ylabel("level", rotation=0, ha="right", va="center")


def label_transitions(fig, ax, transitions, f: float) -> tuple[list, int]:
    """Label each level change (time s, from, to, rule) on the band ``ax`` (x: time times
    ``f``) on one of two rows, leaving out a label that would overprint another or run off the
    axis (their number is added to the x label); returns (the texts placed, the number left out).
    ``fig`` is drawn once first so that the text extents are the final ones."""
    from ..screening import LEVEL_NAMES

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    right = ax.get_window_extent(renderer).x1
    rows: list[list] = [[], []]
    placed, left_out = [], 0
    for when, came_from, to, rule in transitions:
        ax.axvline(when * f, color="k", lw=0.8)
        # a rise names the rule that fired; a fall only where the level went back to
        words = f" {LEVEL_NAMES[to]}: {rule}" if to > came_from else f" back to {LEVEL_NAMES[to]}"
        for row, y in zip(rows, (0.72, 0.28)):
            text = ax.text(when * f, y, words, transform=ax.get_xaxis_transform(),
                           fontsize="x-small", va="center", ha="left", clip_on=False, zorder=7,
                           bbox={"facecolor": "w", "alpha": 0.7, "edgecolor": "none", "pad": 1.0})
            text.set_in_layout(False)
            box = text.get_window_extent(renderer)
            if box.x1 <= right and not any(box.overlaps(other) for other in row):
                row.append(box)
                placed.append(text)
                break
            text.remove()
        else:
            left_out += 1
    if left_out:  # said under the axis, where it overprints nothing
        ax.set_xlabel(f"{ax.get_xlabel()}; {left_out} level changes not labelled ('fault-screen "
                      f"screen' lists them all)")
    return placed, left_out


def result_levels(result):
    """The screening level at each output time of a screened result, or None."""
    sc = (getattr(result, "extra", None) or {}).get("screening")
    return np.asarray(sc["level"]) if sc and "level" in sc else None
