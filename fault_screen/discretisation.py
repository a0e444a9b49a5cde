"""The discretisation of a scene: mesh, fault geometry, materials, unknowns, tabulated bases,
fault points, the injection point and the boundary conditions. Built once, then read-only.

Which unknown blocks exist is decided by the physics terms (``physics.terms_for``), never by
reading the scene's effects here. Unknown vector layout (absent blocks are empty)::

    [ u (2 per node) | a (2 per Heaviside-enriched node) | p (rock, per node)
      | c (per level-set-enriched node) | pf (per fault node) | q (pressure control) ]

Pressures are overpressures (Pa) from the initial pore pressure; displacements (m) from the
in-situ state, which is in equilibrium on its own.
"""
from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass

import numpy as np

from . import xfem
from .kernels import basis, contact, rock
from .mesh import StructuredMesh, build_mesh
from .physics import Physics, effects_on, terms_for
from .physics.base import BLOCK_ORDER
from .physics.materials import effective_rock
from .scene import EDGES, Scene, SceneError


class FaultShiftWarning(UserWarning):
    """The fault was moved off mesh nodes by a tiny documented amount (xfem.NODE_CLEARANCE)."""


class FaultTipWarning(UserWarning):
    """A finite fault's tips were snapped to element edges: the modelled length differs."""


@dataclass(frozen=True)
class Blocks:
    """Start and size of each unknown block."""
    u: slice
    a: slice
    p: slice
    c: slice
    pf: slice
    q: slice
    n: int


@dataclass(frozen=True)
class ElementGroup:
    """Elements sharing a quadrature layout, with bases tabulated at their points."""
    elements: np.ndarray     # (ne,) element ids
    Nu: np.ndarray           # (ne, nq, nbu) displacement basis
    grad_u: np.ndarray       # (ne, nq, nbu, 2)
    Np: np.ndarray           # (ne, nq, nbp) pressure basis (first 4: standard shape functions)
    grad_p: np.ndarray       # (ne, nq, nbp, 2)
    w: np.ndarray            # (ne, nq) quadrature weights, m^2
    umap: np.ndarray | None  # (ne, 2 nbu) displacement DOFs or -1 (None: no displacement)
    pmap: np.ndarray | None  # (ne, nbp) pressure DOFs or -1 (None: no rock pressure)


@dataclass(frozen=True)
class FaultPoints:
    """Fault Gauss-point data (plain arrays, ordered by s)."""
    N: np.ndarray            # (n_gp, 4) standard shape functions of the cut element (jump basis)
    jump_dofs: np.ndarray    # (n_gp, 8) Heaviside DOFs (x, y per node) or -1
    Np: np.ndarray           # (n_gp, nbp) fault-pressure basis
    dNp_ds: np.ndarray       # (n_gp, nbp)
    p_dofs: np.ndarray       # (n_gp, nbp) fault-pressure DOFs or -1
    weight: np.ndarray       # (n_gp,) m
    s: np.ndarray            # (n_gp,) m along the fault
    xy: np.ndarray           # (n_gp, 2) m
    sigma_n0: np.ndarray     # (n_gp,) in-situ effective normal stress on the fault, Pa (compr. +)
    tau0: np.ndarray         # (n_gp,) in-situ shear stress on the fault, Pa
    p0: np.ndarray           # (n_gp,) initial pore pressure, Pa


@dataclass(frozen=True)
class InjectionPoint:
    """Where fluid enters the fault: its bases and DOFs (one point of the fault)."""
    s: float                 # m along the fault
    xy: np.ndarray           # (2,) m
    N: np.ndarray            # (4,) jump basis
    jump_dofs: np.ndarray    # (8,)
    Np: np.ndarray           # fault-pressure basis
    p_dofs: np.ndarray       # fault-pressure DOFs or -1
    p0: float                # initial pore pressure, Pa
    nearest_point: int       # index of the nearest fault Gauss point (contact quantities)


class Discretisation:
    """Everything about a scene that is fixed for the whole run (read-only once built)."""

    def __init__(self, scene: Scene, physics: Physics):
        self.scene = scene
        self.physics = physics
        self.mesh = model_mesh(scene, physics)
        self.coords = self.mesh.coordinates
        self.elements = self.mesh.elements
        self.has_fault = physics.has_fault
        try:
            self.fault = (xfem.locate_fault(self.mesh, scene.fault_point, scene.fault.angle, scene.fault.length)
                          if self.has_fault else xfem.no_fault(self.mesh))
        except ValueError as exc:
            raise SceneError(f"fault.point = {scene.fault_point}, fault.angle = {scene.fault.angle}: {exc}") from None
        if self.fault.shift:
            warnings.warn(f"fault.point = {scene.fault_point}, fault.angle = {scene.fault.angle}: the fault "
                          f"passes through mesh nodes; it is moved {self.fault.shift:.3g} m along its normal "
                          f"(xfem.NODE_CLEARANCE of an element) so that every node lies on one side",
                          FaultShiftWarning, stacklevel=3)
        tips, length = self.fault.tips, scene.fault.length
        if tips is not None and max(abs(tips[0] + 0.5 * length), abs(tips[1] - 0.5 * length)) > 1e-9 * length:
            lo, hi = tips
            warnings.warn(f"fault.length = {scene.fault.length:g} m: the tips are snapped to the nearest element "
                          f"edges along the fault, s = {lo:.6g} and {hi:.6g} m from fault.point; the modelled "
                          f"length is {hi - lo:.6g} m", FaultTipWarning, stacklevel=3)
        if self.has_fault and "pf" in physics.blocks:  # the fault's own pressure line: a node at the source
            try:
                self.fault = xfem.with_node_at(self.fault, scene.injection.position)
            except ValueError as exc:
                raise SceneError(f"injection.position = {scene.injection.position!r}: {exc}") from None
        origin = self.fault.point if self.has_fault else np.asarray(scene.fault_point, dtype=float)
        self.injection_xy = origin + scene.injection.position * self.fault.tangent
        self.in_situ = physics.in_situ
        self._materials()
        self._number_unknowns(physics.blocks)
        self.cut_elements = self.fault.cut_elements
        self._tabulate_fault()
        self._boundary_conditions()
        self._injection_point()
        self._frozen = True

    def __setattr__(self, name, value):
        if getattr(self, "_frozen", False):
            raise AttributeError(f"the discretisation is read-only (tried to set {name!r})")
        object.__setattr__(self, name, value)

    def has(self, block: str) -> bool:
        """Does the unknown block exist (``u``, ``a``, ``p``, ``c``, ``pf``, ``q``)?"""
        return block in self._declared

    # ------------------------------------------------------------------ materials
    def _materials(self):
        s = self.scene
        centroids = self.coords[self.elements].mean(axis=1)
        zone_of = np.zeros(self.mesh.n_elements, dtype=np.int64)
        specs = [s.rock]
        zones = list(self.physics.zones(s)) + list(s.zones)
        for k, z in enumerate(zones, start=1):
            if z.band is not None:
                inside = np.abs((centroids - self.fault.point) @ self.fault.normal) <= z.band
            else:
                x0, x1, y0, y1 = z.box
                inside = ((centroids[:, 0] >= x0) & (centroids[:, 0] <= x1)
                          & (centroids[:, 1] >= y0) & (centroids[:, 1] <= y1))
            zone_of[inside] = k
            specs.append(s.rock.with_overrides(z.rock))
        self.zone_of = zone_of
        props = [effective_rock(spec, s.fluid.bulk_modulus, s.fluid.viscosity) for spec in specs]
        self.zone_props = props
        # per zone, then indexed by element (one elasticity matrix per zone, not per element)
        self.el_D = np.array([rock.plane_strain_elasticity(p["E"], p["nu"]) for p in props])[zone_of]
        self.el_alpha = np.array([p["alpha"] for p in props])[zone_of]
        self.el_mobility = np.array([p["mobility"] for p in props])[zone_of]
        self.el_inv_M = np.array([p["inv_M"] for p in props])[zone_of]

    # ------------------------------------------------------------------ unknowns
    def _number_unknowns(self, declared):
        nn = self.mesh.n_nodes
        f = self.fault
        self._declared = frozenset(declared)
        self.heav_index = np.full(nn, -1, dtype=np.int64)
        self.lset_index = np.full(nn, -1, dtype=np.int64)
        sizes = dict.fromkeys(BLOCK_ORDER, 0)
        if "u" in declared:
            sizes["u"] = 2 * nn
        if "a" in declared:
            ids = np.flatnonzero(f.heaviside_enriched)
            self.heav_index[ids] = np.arange(len(ids))
            sizes["a"] = 2 * len(ids)
        if "p" in declared:
            sizes["p"] = nn
        if "c" in declared:
            ids = np.flatnonzero(f.pressure_enriched)
            self.lset_index[ids] = np.arange(len(ids))
            sizes["c"] = len(ids)
        if "pf" in declared:
            sizes["pf"] = len(f.fault_node_s)
        if "q" in declared:
            sizes["q"] = 1
        start = 0
        sl = {}
        for key in BLOCK_ORDER:
            sl[key] = slice(start, start + sizes[key])
            start += sizes[key]
        self.blocks = Blocks(n=start, **sl)
        self.n_dofs = start

    def dof_coordinates(self) -> np.ndarray:
        """(n_dofs, 2) where each unknown sits (m): its node, the fault point of a fault-line
        pressure, the injection point for the pressure-control multiplier (sparse orderings)."""
        b, c = self.blocks, self.coords
        xy = np.zeros((self.n_dofs, 2))
        xy[b.u] = np.repeat(c, 2, axis=0)[: b.u.stop - b.u.start]
        xy[b.a] = np.repeat(c[self.heav_index >= 0], 2, axis=0)[: b.a.stop - b.a.start]
        xy[b.p] = c[: b.p.stop - b.p.start]
        xy[b.c] = c[self.lset_index >= 0][: b.c.stop - b.c.start]
        if b.pf.stop > b.pf.start:
            xy[b.pf] = self.fault.point + self.fault.fault_node_s[:, None] * self.fault.tangent
        xy[b.q] = self.injection_xy
        return xy

    def dof_counts(self) -> dict:
        b = self.blocks
        return {k: getattr(b, k).stop - getattr(b, k).start for k in BLOCK_ORDER}

    def _u_map(self, nodes):
        """(n, 8) standard displacement DOFs of element nodes."""
        d = np.empty((len(nodes), 8), dtype=np.int64)
        d[:, 0::2] = self.blocks.u.start + 2 * nodes
        d[:, 1::2] = self.blocks.u.start + 2 * nodes + 1
        return d

    def _a_map(self, nodes):
        h = self.heav_index[nodes]
        d = np.empty((len(nodes), 8), dtype=np.int64)
        d[:, 0::2] = np.where(h >= 0, self.blocks.a.start + 2 * h, -1)
        d[:, 1::2] = np.where(h >= 0, self.blocks.a.start + 2 * h + 1, -1)
        return d

    def _p_map(self, nodes):
        return (self.blocks.p.start + nodes).astype(np.int64)

    def _c_map(self, nodes):
        c = self.lset_index[nodes]
        return np.where(c >= 0, self.blocks.c.start + c, -1).astype(np.int64)

    # ------------------------------------------------------------------ bulk tabulation
    @functools.cached_property
    def element_groups(self) -> tuple:
        """The rock's elements in groups with their shape functions, gradients and weights at
        the quadrature points and their DOF maps (``ElementGroup``): the standard elements, the
        cut ones. Tabulated at the first use; ``release_element_groups`` drops them (a run needs
        them to assemble its constant matrices only: 24 MB on the fine 30 deg scene), and the
        next use tabulates them again, the same arrays."""
        return self._tabulate_bulk()

    def release_element_groups(self) -> None:
        self.__dict__.pop("element_groups", None)

    def _tabulate_bulk(self) -> tuple:
        f = self.fault
        ne = self.mesh.n_elements
        is_cut = np.zeros(ne, dtype=bool)
        is_cut[f.cut_elements] = True
        std_elements = np.flatnonzero(~is_cut)
        sizes = self.mesh.element_sizes
        g = xfem.GAUSS2
        ref = np.array([[x, y] for y in g for x in g])
        nq = len(ref)
        hs = sizes[std_elements]
        N = np.array([basis.shape(xi, eta) for xi, eta in ref])                 # (nq, 4)
        unit = np.array([basis.shape_gradient(xi, eta, 1.0, 1.0) for xi, eta in ref])  # (nq, 4, 2)
        grads = unit[None, :, :, :] / hs[:, None, None, :]
        std_N = np.broadcast_to(N, (len(hs), nq, 4)).copy()
        std_w = np.broadcast_to(0.25 * hs[:, :1] * hs[:, 1:], (len(hs), nq)).copy()

        # cut elements: 8 displacement functions (4 standard, 4 Heaviside), 8 pressure functions
        cut_Nu, cut_gu, cut_Np, cut_gp = xfem.tabulate_cut(
            np.asarray(f.cut_elements, dtype=np.int64), self.elements, f.node_phi, sizes,
            np.ascontiguousarray(f.cut_qp, dtype=np.float64),
            np.ascontiguousarray(f.cut_side, dtype=np.float64))

        # local -> global maps
        std_nodes = self.elements[std_elements]
        cut_nodes = self.elements[self.cut_elements]
        std_umap = cut_umap = std_pmap = cut_pmap = None
        if self.has("u"):
            std_umap = self._u_map(std_nodes)
            cut_umap = np.hstack([self._u_map(cut_nodes), self._a_map(cut_nodes)])
        if self.has("p"):
            none4 = -np.ones((len(cut_nodes), 4), dtype=np.int64)
            std_pmap = self._p_map(std_nodes)
            cut_pmap = np.hstack([self._p_map(cut_nodes),
                                  self._c_map(cut_nodes) if self.has("c") else none4])
        groups = []
        if len(std_elements):
            groups.append(ElementGroup(std_elements, std_N, grads, std_N, grads, std_w, std_umap, std_pmap))
        if len(self.cut_elements):
            groups.append(ElementGroup(self.cut_elements, cut_Nu, cut_gu, cut_Np, cut_gp, f.cut_w,
                                       cut_umap, cut_pmap))
        return tuple(groups)

    # ------------------------------------------------------------------ fault tabulation
    def _tabulate_fault(self):
        """The fault's Gauss points: their standard shape functions, position, and the pressure
        functions along the fault (the rock's, standard and level-set enriched, traced along the
        tangent; or the fault line's own linear ones), all points at once."""
        f = self.fault
        ng = len(f.gp_s)
        sizes = self.mesh.element_sizes
        nodes = self.elements[self.cut_elements[f.gp_element]]                  # (ng, 4)
        xi, eta = f.gp_ref[:, 0], f.gp_ref[:, 1]
        N = np.ascontiguousarray(basis.shape(xi, eta).T)                        # (ng, 4)
        # (each point's row times its element's coordinates: the same product as one at a time)
        xy = np.matmul(N[:, None, :], self.coords[nodes])[:, 0, :]
        # the fault pressure is the trace of the rock pressure unless the fault has its own line
        trace = self.has("c") or (not self.has("pf") and self.has("p"))
        nbp = 8 if trace else 2
        pmap = -np.ones((ng, nbp), dtype=np.int64)
        if trace:
            e = self.cut_elements[f.gp_element]
            dN = np.ascontiguousarray(np.transpose(
                basis.shape_gradient(xi, eta, sizes[e, 0], sizes[e, 1]), (2, 0, 1)))   # (ng, 4, 2)
            Nl, dNl = basis.level_set_basis(N, dN, f.node_phi[nodes])
            Np = np.concatenate([N, Nl], axis=1)
            dNp = np.concatenate([dN @ f.tangent, dNl @ f.tangent], axis=1)
            if self.has("p"):
                pmap[:, :4] = self._p_map(nodes)
            if self.has("c"):
                pmap[:, 4:] = self._c_map(nodes)
        else:
            lam = f.gp_xi1d
            s0, s1 = f.segment_s[f.gp_segment, 0], f.segment_s[f.gp_segment, 1]
            Np = np.column_stack([1.0 - lam, lam])
            dNp = np.column_stack([-1.0 / (s1 - s0), 1.0 / (s1 - s0)])
            if self.has("pf"):
                pmap = self.blocks.pf.start + f.segment_nodes[f.gp_segment]
        self.fault_pressure_is_trace = trace
        jump = self._a_map(nodes) if self.has("a") else -np.ones((ng, 8), dtype=np.int64)
        alpha_gp = self.el_alpha[self.cut_elements[f.gp_element]]
        sigma_n0, tau0, p0 = self.in_situ.fault_tractions(self, xy, alpha_gp)
        self.fault_points = FaultPoints(N=N, jump_dofs=jump, Np=Np, dNp_ds=dNp, p_dofs=pmap,
                                        weight=f.gp_w, s=f.gp_s, xy=xy, sigma_n0=sigma_n0,
                                        tau0=tau0, p0=p0)

    # ------------------------------------------------------------------ boundary conditions
    def _boundary_conditions(self):
        s = self.scene
        fixed = np.zeros(self.n_dofs, dtype=bool)
        self.load = np.zeros(self.n_dofs)  # applied traction changes (N per m thickness)
        f = self.fault
        for edge in EDGES:
            spec = getattr(s.boundary, edge)
            nodes = self.mesh.edge_nodes(edge)
            if self.has("u"):
                comps = {"pinned": (0, 1), "roller": ((0,) if edge in ("left", "right") else (1,)),
                         "free": ()}[spec.mechanical]
                for c in comps:
                    fixed[self.blocks.u.start + 2 * nodes + c] = True
                    h = self.heav_index[nodes]
                    fixed[self.blocks.a.start + 2 * h[h >= 0] + c] = True
                if any(spec.traction):
                    self._edge_traction(nodes, np.asarray(spec.traction))
            if spec.hydraulic == "drained":
                if self.has("p"):
                    fixed[self.blocks.p.start + nodes] = True
                if self.has("c"):
                    c = self.lset_index[nodes]
                    fixed[self.blocks.c.start + c[c >= 0]] = True
                if self.has("pf"):
                    # a fault end that lies on a drained edge is drained
                    ends = [(0, f.segment_s[0, 0]), (len(f.fault_node_s) - 1, f.segment_s[-1, 1])]
                    xmin, xmax, ymin, ymax = self.mesh.bounds
                    tol = 1e-9 * max(xmax - xmin, ymax - ymin)
                    for node, s_end in ends:
                        x, y = f.point + s_end * f.tangent
                        on = {"left": abs(x - xmin), "right": abs(x - xmax),
                              "bottom": abs(y - ymin), "top": abs(y - ymax)}[edge] < tol
                        if on:
                            fixed[self.blocks.pf.start + node] = True
        self.fixed = fixed
        self.free = np.flatnonzero(~fixed)

    def _edge_traction(self, nodes, traction):
        """Consistent forces of a uniform traction change on a boundary edge, split at the fault
        so that the Heaviside DOFs of cut edge segments get their share."""
        f = self.fault
        xy = self.coords[nodes]
        gx, gw = np.polynomial.legendre.leggauss(2)
        for i in range(len(nodes) - 1):
            a, b = nodes[i], nodes[i + 1]
            pa, pb = xy[i], xy[i + 1]
            L = np.linalg.norm(pb - pa)
            fa, fb = f.node_phi[a], f.node_phi[b]
            cuts = [0.0, 1.0]
            if fa * fb < 0:
                cuts = [0.0, fa / (fa - fb), 1.0]
            for lo, hi in zip(cuts[:-1], cuts[1:]):
                for x, w in zip(gx, gw):
                    lam = lo + 0.5 * (x + 1) * (hi - lo)
                    ww = 0.5 * w * (hi - lo) * L
                    Na, Nb = 1 - lam, lam
                    side = 1.0 if (1 - lam) * fa + lam * fb > 0 else 0.0
                    for node, Nv in ((a, Na), (b, Nb)):
                        self.load[self.blocks.u.start + 2 * node: self.blocks.u.start + 2 * node + 2] += ww * Nv * traction
                        h = self.heav_index[node]
                        if h >= 0:
                            shift = side - (1.0 if f.node_phi[node] > 0 else 0.0)
                            j = self.blocks.a.start + 2 * h
                            self.load[j:j + 2] += ww * Nv * shift * traction

    # ------------------------------------------------------------------ injection point
    def _injection_point(self):
        f = self.fault
        if not self.has_fault:
            self.injection = InjectionPoint(s=0.0, xy=self.injection_xy, N=np.zeros(4),
                                            jump_dofs=-np.ones(8, dtype=np.int64), Np=np.zeros(0),
                                            p_dofs=np.zeros(0, dtype=np.int64),
                                            p0=self.scene.initial.pore_pressure, nearest_point=0)
            return
        s_inj = self.scene.injection.position
        try:
            k, lam = xfem.locate_point_on_fault(f, s_inj)
        except ValueError as exc:
            raise SceneError(f"injection.position = {s_inj!r}: {exc}") from None
        r0, r1 = f.segment_ref[k]
        xi, eta = r0 + lam * (r1 - r0)
        e = self.cut_elements[f.segment_element[k]]
        nodes = self.elements[e]
        Ng = basis.shape(xi, eta)
        jump_dofs = self._a_map(nodes[None, :])[0] if self.has("a") else -np.ones(8, dtype=np.int64)
        if self.fault_pressure_is_trace:
            hx, hy = self.mesh.element_sizes[e]
            Nl, _ = basis.level_set_basis(Ng, basis.shape_gradient(xi, eta, hx, hy), f.node_phi[nodes])
            Np = np.concatenate([Ng, Nl])
            pm = -np.ones(8, dtype=np.int64)
            if self.has("p"):
                pm[:4] = self._p_map(nodes)
            if self.has("c"):
                pm[4:] = self._c_map(nodes)
        elif self.has("pf"):
            Np = np.array([1.0 - lam, lam])
            pm = self.blocks.pf.start + f.segment_nodes[k]
        else:  # dry fault: no fluid to inject into
            Np = np.zeros(2)
            pm = -np.ones(2, dtype=np.int64)
        # contact quantities live at the fault's Gauss points: at the injection point, the nearest
        nearest = int(np.argmin(np.abs(self.fault_points.s - s_inj))) if len(self.fault_points.s) else 0
        self.injection = InjectionPoint(s=s_inj, xy=self.injection_xy, N=Ng, jump_dofs=jump_dofs,
                                        Np=Np, p_dofs=pm, nearest_point=nearest,
                                        p0=float(self.in_situ.state(self, self.injection_xy[None, :])[1][0]))

    # ------------------------------------------------------------------ evaluation helpers
    def fault_jump(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(slip, opening) at the fault Gauss points (m)."""
        fp = self.fault_points
        return contact.fault_jumps(x, fp.N, fp.jump_dofs, self.fault.tangent, self.fault.normal)

    def fault_overpressure(self, x: np.ndarray) -> np.ndarray:
        fp = self.fault_points
        xv = np.where(fp.p_dofs >= 0, x[np.maximum(fp.p_dofs, 0)], 0.0)
        return np.sum(fp.Np * xv, axis=1)

    def injection_overpressure(self, x) -> float:
        inj = self.injection
        xv = np.where(inj.p_dofs >= 0, x[np.maximum(inj.p_dofs, 0)], 0.0)
        return float(inj.Np @ xv)

    def injection_jump(self, x) -> tuple[float, float]:
        """(slip, opening) at the injection point (m)."""
        inj = self.injection
        slip, opening = contact.fault_jumps(x, inj.N[None, :], inj.jump_dofs[None, :],
                                            self.fault.tangent, self.fault.normal)
        return float(slip[0]), float(opening[0])


def discretise(scene: Scene) -> Discretisation:
    """The terms a scene calls for and their discretisation (the in-situ state checked)."""
    physics = terms_for(scene)
    disc = Discretisation(scene, physics)
    for term in physics.terms:
        term.check(disc)
    return disc


# ---- the model's size before it is built ------------------------------------------------------
#: Memory of a run ~ BASE_MEMORY + BYTES_PER_UNKNOWN_LOG * N log2 N bytes (N unknowns; the
#: sparse factor's fill grows like N log N).  Fitted (least squares) to the peak resident memory
#: of `fault-screen run` of the calibrated Rustrel scene (1400 s) on nx x (nx + 1) meshes with
#: numpy 2.4, scipy 1.17, numba 0.68: 216 MB at 20 x 21 (N = 2.6k), 243 MB at 50 x 51, 331 MB at
#: 100 x 101 (N = 33k), 615 MB at 200 x 201 (N = 123k) (`python benchmarks/long_operation.py
#: --sizes 20,50,100,200`); within 5 % at all four.  Most of a small run's memory is the
#: imported libraries and the cached kernels, not the model.
BYTES_PER_UNKNOWN_LOG = 190.0
BASE_MEMORY = 220e6
#: node lines per axis up to which the estimate builds the mesh's lines (1-D arrays, 8 bytes a
#: line) rather than bounding their number
LINES_BUILT = 200_000


def model_mesh(scene: Scene, physics: Physics) -> StructuredMesh:
    """The mesh a scene is discretised on: ``[mesh]`` (uniform or graded), then refined as the
    physics terms need it (the leak-off grading across the fault)."""
    m = scene.mesh
    return physics.refine_mesh(scene, build_mesh(m.nx, m.ny, m.lx, m.ly, m.origin, m.refinement))


def _line_bound(length: float, n_uniform: int, refinement) -> int:
    """Elements along one axis, or an upper bound for a graded mesh: ``mesh.graded_line`` keeps
    every element but the two end ones at least half the fine size."""
    if refinement is None:
        return n_uniform
    return int(min(2.0 * length / refinement.size + 2.0, 1e18))


def mesh_shape(scene: Scene) -> tuple[int, int]:
    """(nx, ny): the elements along x and y of the mesh the run builds (``model_mesh``), the one
    mesh size that ``run`` and ``scene check`` print."""
    mesh = model_mesh(scene, terms_for(scene))
    return mesh.nx, mesh.ny


def estimate_size(scene: Scene) -> tuple[int, int, float]:
    """(elements, unknowns, bytes): a run's size before anything heavy is built. The node lines
    are built (``model_mesh``: the graded mesh and the leak-off grading, so ``elements`` is the
    built mesh's) unless an axis would have more than ``LINES_BUILT`` of them; then the counts
    are upper bounds (refusing an absurd mesh must not itself exhaust the memory). Unknowns:
    the nodes' and those of the nodes the fault enriches (tests/studies/test_accuracy.py states how
    close they come to the built model)."""
    m, switched_on = scene.mesh, effects_on(scene)
    on = {name: name in switched_on for name in ("mechanics", "poroelastic", "fault", "leak_off", "fault_flow")}
    nx, ny, lines = _size_lines(scene)
    nodes = (nx + 1) * (ny + 1)
    unknowns = 2 * on["mechanics"] * nodes + on["poroelastic"] * nodes
    if on["fault"]:
        unknowns += _fault_unknowns(scene, on, _cut_elements(scene, nx, ny, lines))
    return nx * ny, unknowns, BASE_MEMORY + BYTES_PER_UNKNOWN_LOG * unknowns * math.log2(max(unknowns, 2))


def estimate_cut_elements(scene: Scene) -> int:
    """Elements the fault cuts, as :func:`estimate_size` counts them (0 without a fault)."""
    if "fault" not in effects_on(scene):
        return 0
    return _cut_elements(scene, *_size_lines(scene))


def _size_lines(scene: Scene) -> tuple:
    """(nx, ny, node lines or None) of the mesh as built, or bounds on nx, ny beyond
    ``LINES_BUILT`` lines."""
    m = scene.mesh
    bound = (_line_bound(m.lx, m.nx, m.refinement), _line_bound(m.ly, m.ny, m.refinement))
    if max(bound) <= LINES_BUILT:
        mesh = model_mesh(scene, terms_for(scene))
        return mesh.nx, mesh.ny, (mesh.x_lines, mesh.y_lines)
    return bound[0], bound[1], None


def _fault_unknowns(scene: Scene, on: dict, cut: int) -> int:
    """Unknowns of the nodes the fault enriches (``cut`` elements: a staircase with two more
    nodes each), its own pressure line and the pressure-control multiplier."""
    enriched = 2 * (cut + 1)
    finite = scene.fault.length is not None
    # a finite fault's jump closes at its tips: the nodes of the edge through each tip carry none
    unknowns = (enriched - 4 * finite) * 2 * on["mechanics"] + enriched * on["leak_off"]
    if on["fault_flow"] and not on["leak_off"]:
        unknowns += cut + 1  # the fault's own pressure line
    return unknowns + (scene.injection.control == "pressure")


def _cut_elements(scene: Scene, nx: int, ny: int, lines) -> int:
    """Elements the fault cuts: the stretch of fault line in the model (along s from the fault
    point, within the box and, for a finite fault, within its length) crosses one more element
    at each node line it passes."""
    m = scene.mesh
    angle = scene.fault.angle % 180.0
    along = 0 if min(angle, 180.0 - angle) < 1e-9 else (1 if abs(angle - 90.0) < 1e-9 else None)
    a = math.radians(angle)
    ca, sa = math.cos(a), math.sin(a)
    px, py = scene.fault_point
    x0, y0 = m.origin
    s0, s1 = -math.inf, math.inf
    for c, p, lo, hi in ((ca, px, x0, x0 + m.lx), (sa, py, y0, y0 + m.ly)):
        if abs(c) > 1e-12:
            s0, s1 = max(s0, min((lo - p) / c, (hi - p) / c)), min(s1, max((lo - p) / c, (hi - p) / c))
    finite = scene.fault.length is not None
    if finite:
        s0, s1 = max(s0, -0.5 * scene.fault.length), min(s1, 0.5 * scene.fault.length)
    if along is not None and not finite:
        cut = (nx, ny)[along]
    elif lines is None:
        cut = nx + ny
    else:
        def crossed(axis_lines, a_, b_):
            lo, hi = sorted((a_, b_))
            tol = 1e-9 * (axis_lines[-1] - axis_lines[0])
            inner = axis_lines[1:-1]  # the domain's edges are not crossed
            return int(np.count_nonzero((inner >= lo - tol) & (inner <= hi + tol)))

        cut = 1 + crossed(lines[0], px + s0 * ca, px + s1 * ca) + crossed(lines[1], py + s0 * sa, py + s1 * sa)
    return cut
