"""Structured meshes of bilinear quadrilaterals over a rectangle (plane strain, 1 m thick).

Node ``(i, j)`` (column ``i`` along x, row ``j`` along y) has index ``j * (nx + 1) + i``; element
``(i, j)`` has index ``j * nx + i`` and nodes ordered counter-clockwise from the lower-left one.
Node lines may be graded (finer around a point of interest) but stay axis-aligned, so every
element is a rectangle and its isoparametric map is affine: a straight fault stays straight in
reference coordinates, which keeps the sub-division of cut elements exact.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def graded_line(start: float, length: float, focus: float, half_width: float, size: float,
                growth: float) -> np.ndarray:
    """Node coordinates on ``[start, start + length]``: spacing ``size`` within ``half_width`` of
    ``focus``, then growing geometrically by ``growth`` towards both ends (m)."""
    end = start + length
    # whole elements of exactly ``size`` on each side of the focus, so the focus is a node line
    n_lo = int(np.floor(min(half_width, focus - start) / size + 1e-9))
    n_hi = int(np.floor(min(half_width, end - focus) / size + 1e-9))
    lo, hi = focus - n_lo * size, focus + n_hi * size
    core = focus + size * np.arange(-n_lo, n_hi + 1)

    def outward(extent: float) -> np.ndarray:
        if extent <= 1e-12 * length:
            return np.zeros(0)
        sizes = []
        h = size
        running = 0.0  # sum(sizes) to round-off: the exact sum is taken only near the end
        while running < extent * (1.0 - 1e-6) or sum(sizes) < extent:
            h *= growth
            sizes.append(h)
            running += h
        if len(sizes) > 1 and sum(sizes) - extent > 0.5 * sizes[-1]:
            sizes.pop()  # fold a short last element into the others rather than keep a sliver
        sizes = np.asarray(sizes) * (extent / np.sum(sizes))
        return np.cumsum(sizes)

    left = lo - outward(lo - start)[::-1]
    right = hi + outward(end - hi)
    nodes = np.concatenate([left, core, right])
    nodes[0], nodes[-1] = start, end
    return nodes


@dataclass(frozen=True)
class StructuredMesh:
    """Axis-aligned structured mesh. Coordinates in m."""

    x_lines: np.ndarray
    y_lines: np.ndarray

    @property
    def nx(self) -> int:
        return len(self.x_lines) - 1

    @property
    def ny(self) -> int:
        return len(self.y_lines) - 1

    @property
    def n_nodes(self) -> int:
        return (self.nx + 1) * (self.ny + 1)

    @property
    def n_elements(self) -> int:
        return self.nx * self.ny

    @property
    def coordinates(self) -> np.ndarray:
        xx, yy = np.meshgrid(self.x_lines, self.y_lines)
        return np.column_stack([xx.ravel(), yy.ravel()])

    @property
    def elements(self) -> np.ndarray:
        nx, ny = self.nx, self.ny
        i, j = np.meshgrid(np.arange(nx), np.arange(ny))
        n0 = (j * (nx + 1) + i).ravel()
        return np.column_stack([n0, n0 + 1, n0 + nx + 2, n0 + nx + 1]).astype(np.int64)

    @property
    def element_sizes(self) -> np.ndarray:
        """(n_elements, 2) widths along x and y (m)."""
        hx, hy = np.meshgrid(np.diff(self.x_lines), np.diff(self.y_lines))
        return np.column_stack([hx.ravel(), hy.ravel()])

    def edge_nodes(self, edge: str) -> np.ndarray:
        nx, ny = self.nx, self.ny
        ids = np.arange(self.n_nodes).reshape(ny + 1, nx + 1)
        return {"bottom": ids[0, :], "top": ids[-1, :], "left": ids[:, 0], "right": ids[:, -1]}[edge].copy()

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return (self.x_lines[0], self.x_lines[-1], self.y_lines[0], self.y_lines[-1])


def build_mesh(nx: int, ny: int, lx: float, ly: float, origin=(0.0, 0.0), refinement=None) -> StructuredMesh:
    """Uniform ``nx`` by ``ny`` mesh, or a graded one when ``refinement`` (with ``center``,
    ``half_width``, ``size``, ``growth``) is given; then nx and ny follow from the grading."""
    x0, y0 = origin
    if refinement is None:
        return StructuredMesh(np.linspace(x0, x0 + lx, nx + 1), np.linspace(y0, y0 + ly, ny + 1))
    cx, cy = refinement.center
    wx, wy = refinement.half_width
    return StructuredMesh(
        graded_line(x0, lx, cx, wx, refinement.size, refinement.growth),
        graded_line(y0, ly, cy, wy, refinement.size, refinement.growth),
    )


def grade_across(lines: np.ndarray, at: float, size: float, growth: float) -> np.ndarray:
    """Node lines (one axis) refined around ``at``: an element of height ``size`` centred on
    ``at``, then elements growing by ``growth`` on each side until they reach the spacing of the
    original lines there, which are kept beyond (m). Lines already finer than ``size`` at ``at``
    are returned unchanged. Used to resolve a thin boundary layer along an axis-aligned line."""
    lines = np.asarray(lines, dtype=float)
    lo_end, hi_end = lines[0], lines[-1]

    def spacing(y: float) -> float:
        k = int(np.clip(np.searchsorted(lines, y, side="right") - 1, 0, len(lines) - 2))
        return float(lines[k + 1] - lines[k])

    if spacing(at) <= size:
        return lines
    new = []
    for sign in (1.0, -1.0):
        z, h = 0.5 * size, size
        while True:
            y = at + sign * z
            if not lo_end < y < hi_end:
                break
            new.append(y)
            if h * growth >= spacing(y):
                break
            h *= growth
            z += h
        # original lines closer than half the next size to the graded ones would leave slivers
        reach = z + 0.5 * h * growth
        lines = lines[(sign * (lines - at) > reach) | (sign * (lines - at) <= 0)
                      | (lines == lo_end) | (lines == hi_end)]
    out = np.unique(np.concatenate([lines, new]))
    # a graded line within a sliver of a domain edge: drop it, keep the edge
    h_min = 0.5 * size
    keep = np.ones(len(out), dtype=bool)
    keep[1:-1] = (out[1:-1] - lo_end > 1e-3 * h_min) & (hi_end - out[1:-1] > 1e-3 * h_min)
    return out[keep]
