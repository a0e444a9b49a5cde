"""Meshes for OpenGeoSys's HYDRO_MECHANICS_WITH_LIE process, written as plain VTU with numpy.

OGS's lower-interface elements put the fault on element edges: the domain mesh holds
serendipity quadrilaterals (VTK_QUADRATIC_QUAD, Taylor-Hood with linear pressure) and, along the
node line of the fault, quadratic line elements with their own material id. The node lines are
the ones fault_screen builds (``fault_screen.mesh``): uniform, or graded towards a point on the
fault, with the fault's line kept as a node line. Dirichlet conditions are set on boundary
meshes that name their nodes in the domain mesh (``bulk_node_ids``).

    python benchmarks/peers/ogs_mesh.py OUTDIR            # the uniform mesh of the scene
    python benchmarks/peers/ogs_mesh.py OUTDIR --graded   # the mesh graded towards the fault
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

VTK_VERTEX, VTK_QUADRATIC_EDGE, VTK_QUADRATIC_QUAD = 1, 21, 23
MATRIX_ID, FAULT_ID = 0, 1
#: the scene's domain (m), the fault's line and the injection point on it (rustrel-pressure.toml)
LX = LY = 250.0
FAULT_Y = INJECTION_X = 125.0
UNIFORM_ELEMENTS = 50
#: the graded mesh: elements of SIZE m within HALF_WIDTH of the injection point, growing by
#: GROWTH outside (fault_screen's [mesh.refinement])
SIZE, HALF_WIDTH, GROWTH = 1.0, (40.0, 2.0), 1.15


def ogs_node_lines(graded: bool):
    """OGS's node lines (x, y), the fault's y and the injection point's x (m)."""
    if not graded:
        lines = np.linspace(0.0, LX, UNIFORM_ELEMENTS + 1)
        return lines, np.linspace(0.0, LY, UNIFORM_ELEMENTS + 1), FAULT_Y, INJECTION_X
    from fault_screen.mesh import graded_line

    return (graded_line(0.0, LX, INJECTION_X, HALF_WIDTH[0], SIZE, GROWTH),
            graded_line(0.0, LY, FAULT_Y, HALF_WIDTH[1], SIZE, GROWTH), FAULT_Y, INJECTION_X)


@dataclass(frozen=True)
class QuadraticGrid:
    """Node numbering of a structured 8-node mesh on the node lines ``x_lines`` by ``y_lines``:
    corners first, then the mid-points of the edges along x, then those along y."""

    x_lines: np.ndarray
    y_lines: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.x_lines) - 1, len(self.y_lines) - 1

    def corner(self, i, j):
        nx, _ = self.shape
        return np.asarray(j) * (nx + 1) + np.asarray(i)

    def mid_x(self, i, j):
        """Mid-point of the edge from corner (i, j) to (i + 1, j)."""
        nx, ny = self.shape
        return (nx + 1) * (ny + 1) + np.asarray(j) * nx + np.asarray(i)

    def mid_y(self, i, j):
        """Mid-point of the edge from corner (i, j) to (i, j + 1)."""
        nx, ny = self.shape
        return (nx + 1) * (ny + 1) + nx * (ny + 1) + np.asarray(j) * (nx + 1) + np.asarray(i)

    def points(self) -> np.ndarray:
        x, y = self.x_lines, self.y_lines
        xm, ym = 0.5 * (x[1:] + x[:-1]), 0.5 * (y[1:] + y[:-1])
        blocks = [np.meshgrid(x, y), np.meshgrid(xm, y), np.meshgrid(x, ym)]
        xy = np.concatenate([np.column_stack([gx.ravel(), gy.ravel()]) for gx, gy in blocks])
        return np.column_stack([xy, np.zeros(len(xy))])

    def quads(self) -> np.ndarray:
        nx, ny = self.shape
        i, j = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny)))
        return np.column_stack([self.corner(i, j), self.corner(i + 1, j), self.corner(i + 1, j + 1),
                                self.corner(i, j + 1), self.mid_x(i, j), self.mid_y(i + 1, j),
                                self.mid_x(i, j + 1), self.mid_y(i, j)])

    def row_edges(self, j: int) -> np.ndarray:
        """Quadratic line elements along the node line y = y_lines[j], left to right."""
        i = np.arange(self.shape[0])
        return np.column_stack([self.corner(i, j), self.corner(i + 1, j), self.mid_x(i, j)])

    def column_edges(self, i: int) -> np.ndarray:
        """Quadratic line elements along the node line x = x_lines[i], bottom to top."""
        j = np.arange(self.shape[1])
        return np.column_stack([self.corner(i, j), self.corner(i, j + 1), self.mid_y(i, j)])


def _array(name: str, dtype: str, values, components: int = 1) -> str:
    text = " ".join(repr(float(v)) if dtype.startswith("Float") else str(int(v))
                    for v in np.ravel(values))
    return (f'<DataArray type="{dtype}" Name="{name}" NumberOfComponents="{components}" '
            f'format="ascii">{text}</DataArray>')


def write_vtu(path: Path, points: np.ndarray, cells: list[tuple[int, np.ndarray]], *,
              point_data: dict | None = None, cell_data: dict | None = None) -> None:
    """An ASCII unstructured grid: ``cells`` a list of (VTK cell type, connectivity rows);
    data dictionaries map a name to (VTK type, values)."""
    conn = np.concatenate([c.ravel() for _, c in cells])
    sizes = np.concatenate([np.full(len(c), c.shape[1]) for _, c in cells])
    types = np.concatenate([np.full(len(c), t) for t, c in cells])
    pieces = ['<?xml version="1.0"?>',
              '<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian" '
              'header_type="UInt64">', "<UnstructuredGrid>",
              f'<Piece NumberOfPoints="{len(points)}" NumberOfCells="{len(types)}">',
              "<Points>", _array("Points", "Float64", points, 3), "</Points>", "<Cells>",
              _array("connectivity", "Int64", conn), _array("offsets", "Int64", np.cumsum(sizes)),
              _array("types", "UInt8", types), "</Cells>"]
    for tag, data in (("PointData", point_data), ("CellData", cell_data)):
        if data:
            pieces += [f"<{tag}>", *(_array(k, t, v) for k, (t, v) in data.items()), f"</{tag}>"]
    pieces += ["</Piece>", "</UnstructuredGrid>", "</VTKFile>", ""]
    path.write_text("\n".join(pieces), encoding="ascii")


def _write_subset(path: Path, all_points: np.ndarray, cell_type: int, cells: np.ndarray) -> None:
    """A boundary mesh made of ``cells`` (domain node ids), renumbered, with ``bulk_node_ids``."""
    bulk = np.unique(cells)
    local = np.searchsorted(bulk, cells)
    write_vtu(path, all_points[bulk], [(cell_type, local)],
              point_data={"bulk_node_ids": ("UInt64", bulk)})


def write_ogs_meshes(outdir: Path, x_lines: np.ndarray, y_lines: np.ndarray, fault_y: float,
                     injection_x: float) -> dict:
    """The domain mesh with the fault along y = ``fault_y`` (must be a node line) and the
    boundary meshes (sides, the fault's two ends, the injection node). Returns the node count
    and the number of matrix and fault elements."""
    outdir.mkdir(parents=True, exist_ok=True)
    grid = QuadraticGrid(np.asarray(x_lines, float), np.asarray(y_lines, float))
    j_fault = int(np.argmin(np.abs(grid.y_lines - fault_y)))
    i_inj = int(np.argmin(np.abs(grid.x_lines - injection_x)))
    if abs(grid.y_lines[j_fault] - fault_y) > 1e-9 or abs(grid.x_lines[i_inj] - injection_x) > 1e-9:
        raise ValueError("the fault and the injection point must lie on node lines")
    points = grid.points()
    quads, fault = grid.quads(), grid.row_edges(j_fault)
    write_vtu(outdir / "domain.vtu", points, [(VTK_QUADRATIC_QUAD, quads), (VTK_QUADRATIC_EDGE, fault)],
              cell_data={"MaterialIDs": ("Int32", np.r_[np.full(len(quads), MATRIX_ID),
                                                        np.full(len(fault), FAULT_ID)])})
    nx, ny = grid.shape
    for name, edges in (("left", grid.column_edges(0)), ("right", grid.column_edges(nx)),
                        ("bottom", grid.row_edges(0)), ("top", grid.row_edges(ny))):
        _write_subset(outdir / f"{name}.vtu", points, VTK_QUADRATIC_EDGE, edges)
    ends = grid.corner(np.array([0, nx]), np.array([j_fault, j_fault]))
    _write_subset(outdir / "fault_ends.vtu", points, VTK_VERTEX, ends[:, None])
    _write_subset(outdir / "injection.vtu", points, VTK_VERTEX,
                  np.array([[int(grid.corner(i_inj, j_fault))]]))
    return {"nodes": len(points), "matrix_elements": len(quads), "fault_elements": len(fault),
            "injection_node": int(grid.corner(i_inj, j_fault))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("outdir", type=Path)
    ap.add_argument("--graded", action="store_true")
    args = ap.parse_args()
    x_lines, y_lines, fault_y, injection_x = ogs_node_lines(graded=args.graded)
    print(write_ogs_meshes(args.outdir, x_lines, y_lines, fault_y, injection_x))


if __name__ == "__main__":
    main()
