"""Discretisation of a scene: mesh, fault, unknowns, and the matrices that do not change in time.

Only what the scene's effects call for is created: no displacement unknowns for rigid rock, no
rock pressure for impermeable rock, no enriched pressure without leak-off, no fault-pressure line
when the rock pressure carries the fault, no Lagrange multiplier under rate control. Assembly
touches only the terms that exist.

Unknown vector layout (blocks that the scene does not need are empty)::

    [ u (2 per node) | a (2 per Heaviside-enriched node) | p (rock, per node)
      | c (per level-set-enriched node) | pf (per fault node) | q_inj (pressure control) ]

Pressures are overpressures (Pa) from the initial pore pressure; displacements (m) from the
in-situ state, which is in equilibrium on its own.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import xfem
from .assembly import TripletBuilder
from .kernels import basis, contact, fault_flow, rock
from .mesh import build_mesh
from .scene import EDGES, RockSpec, Scene, SceneError, Zone


@dataclass
class Blocks:
    """Start and size of each unknown block."""
    u: slice
    a: slice
    p: slice
    c: slice
    pf: slice
    q: slice
    n: int


@dataclass
class ElementGroup:
    """Elements sharing a quadrature layout, with bases tabulated at their points."""
    elements: np.ndarray     # (ne,) element ids
    Nu: np.ndarray           # (ne, nq, nbu) displacement basis
    grad_u: np.ndarray       # (ne, nq, nbu, 2)
    Np: np.ndarray           # (ne, nq, nbp) pressure basis (first 4: standard shape functions)
    grad_p: np.ndarray       # (ne, nq, nbp, 2)
    w: np.ndarray            # (ne, nq) quadrature weights, m^2
    umap: np.ndarray | None  # (ne, 2 nbu) displacement DOFs or -1
    pmap: np.ndarray | None  # (ne, nbp) pressure DOFs or -1


@dataclass
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


def effective_rock(spec: RockSpec, fluid_bulk_modulus: float) -> dict:
    """Derived rock constants in SI: drained bulk modulus, Ks, 1/M (Biot modulus)."""
    E, nu, alpha, n = spec.youngs_modulus, spec.poissons_ratio, spec.biot_coefficient, spec.porosity
    K = E / (3.0 * (1.0 - 2.0 * nu))
    Ks = spec.solid_bulk_modulus
    if Ks is None:
        Ks = K / (1.0 - alpha) if alpha < 1.0 else np.inf
    inv_M = (alpha - n) / Ks + n / fluid_bulk_modulus
    return {"E": E, "nu": nu, "alpha": alpha, "mobility": None, "inv_M": inv_M, "Ks": Ks}


class Model:
    """Everything about a scene that is fixed for the whole run."""

    def __init__(self, scene: Scene):
        self.scene = scene
        ef = scene.effects
        m = scene.mesh
        self.mesh = build_mesh(m.nx, m.ny, m.lx, m.ly, m.origin, m.refinement)
        self.coords = self.mesh.coordinates
        self.elements = self.mesh.elements
        self.has_fault = ef.fault
        try:
            self.fault = (xfem.locate_fault(self.mesh, scene.fault_point, scene.fault.angle)
                          if ef.fault else xfem.no_fault(self.mesh))
        except ValueError as exc:
            raise SceneError(f"fault.point = {scene.fault_point}, fault.angle = {scene.fault.angle}: {exc}") from None
        self.has_u = ef.mechanics
        self.has_p = ef.poroelastic
        self.has_c = ef.fault and ef.poroelastic and ef.leak_off
        self.has_pf = ef.fault and ef.fault_flow and not ef.leak_off
        self.has_q = ef.fault and scene.injection.control == "pressure"
        self.injection_xy = (np.asarray(scene.fault_point, dtype=float)
                             + scene.injection.position * self.fault.tangent)
        self._materials()
        self._number_unknowns()
        self._tabulate_bulk()
        self._tabulate_fault()
        self._boundary_conditions()
        self._injection_point()
        self._assemble_static()
        if self.has_u:
            self.check_initial_equilibrium()

    # ------------------------------------------------------------------ materials
    def _materials(self):
        s = self.scene
        centroids = self.coords[self.elements].mean(axis=1)
        zone_of = np.zeros(self.mesh.n_elements, dtype=np.int64)
        specs = [s.rock]
        zones = list(s.zones)
        if s.effects.damage_zone:
            dz = s.damage_zone
            over = {k: v for k, v in (("youngs_modulus", dz.youngs_modulus),
                                      ("poissons_ratio", dz.poissons_ratio),
                                      ("permeability", dz.permeability)) if v is not None}
            zones.insert(0, Zone(name="damage zone", band=dz.width, rock=over))
        for k, z in enumerate(zones, start=1):
            if z.band is not None:
                inside = np.abs((centroids - self.fault.point) @ self.fault.normal) <= z.band
            else:
                x0, x1, y0, y1 = z.box
                inside = ((centroids[:, 0] >= x0) & (centroids[:, 0] <= x1)
                          & (centroids[:, 1] >= y0) & (centroids[:, 1] <= y1))
            zone_of[inside] = k
            specs.append(replace(s.rock, **z.rock))
        self.zone_of = zone_of
        mu = s.fluid.viscosity
        props = []
        for spec in specs:
            d = effective_rock(spec, s.fluid.bulk_modulus)
            d["mobility"] = spec.permeability / mu
            props.append(d)
        self.zone_props = props
        self.el_D = np.array([rock.plane_strain_elasticity(props[z]["E"], props[z]["nu"]) for z in zone_of])
        self.el_alpha = np.array([props[z]["alpha"] for z in zone_of])
        self.el_mobility = np.array([props[z]["mobility"] for z in zone_of])
        self.el_inv_M = np.array([props[z]["inv_M"] for z in zone_of])

    # ------------------------------------------------------------------ in-situ state
    def initial_state(self, xy: np.ndarray):
        """In-situ effective stress (n, 3: sxx', syy', sxy', Pa) and pore pressure (n,) at points.

        Uniform without gravity. With gravity, both vary with depth d = g_hat . (x - x_ref):
        p0 grows by the hydrostatic gradient; the effective stress along gravity by
        -(rho - alpha rho_f) g per metre (rho = n rho_f + (1 - n) rho_s, intact rock) and across
        it by lateral_stress_ratio times that, so that div(sigma' - alpha p0 I) + rho g = 0."""
        s = self.scene
        ini = s.initial
        sig = np.broadcast_to(np.array(ini.effective_stress, dtype=float), (len(xy), 3)).copy()
        p0 = np.full(len(xy), ini.pore_pressure)
        if not s.effects.gravity:
            return sig, p0
        e = np.array(ini.gravity_direction, dtype=float)
        e /= np.linalg.norm(e)
        ref = np.array(ini.reference_point if ini.reference_point is not None else self.injection_xy)
        depth = (xy - ref) @ e
        rk, fl = s.rock, s.fluid
        g = ini.gravity
        dp = ini.pore_pressure_gradient if ini.pore_pressure_gradient is not None else fl.density * g
        rho = rk.porosity * fl.density + (1 - rk.porosity) * rk.density
        k_lat = (ini.lateral_stress_ratio if ini.lateral_stress_ratio is not None
                 else rk.poissons_ratio / (1 - rk.poissons_ratio))
        vertical = -(rho * g - rk.biot_coefficient * dp)  # effective stress per metre of depth
        ep = np.array([-e[1], e[0]])
        grad = vertical * (np.outer(e, e) + k_lat * np.outer(ep, ep))
        sig[:, 0] += depth * grad[0, 0]
        sig[:, 1] += depth * grad[1, 1]
        sig[:, 2] += depth * grad[0, 1]
        p0 += dp * depth
        self.body_force_density = rho * g * e  # N/m^3
        return sig, p0

    # ------------------------------------------------------------------ unknowns
    def _number_unknowns(self):
        nn = self.mesh.n_nodes
        f = self.fault
        self.heav_index = np.full(nn, -1, dtype=np.int64)
        self.lset_index = np.full(nn, -1, dtype=np.int64)
        sizes = {}
        sizes["u"] = 2 * nn if self.has_u else 0
        if self.has_u:
            ids = np.flatnonzero(f.heaviside_enriched)
            self.heav_index[ids] = np.arange(len(ids))
            sizes["a"] = 2 * len(ids)
        else:
            sizes["a"] = 0
        sizes["p"] = nn if self.has_p else 0
        if self.has_c:
            ids = np.flatnonzero(f.pressure_enriched)
            self.lset_index[ids] = np.arange(len(ids))
            sizes["c"] = len(ids)
        else:
            sizes["c"] = 0
        sizes["pf"] = len(f.fault_node_s) if self.has_pf else 0
        sizes["q"] = 1 if self.has_q else 0
        start = 0
        sl = {}
        for key in ("u", "a", "p", "c", "pf", "q"):
            sl[key] = slice(start, start + sizes[key])
            start += sizes[key]
        self.blocks = Blocks(n=start, **sl)
        self.n_dofs = start

    def dof_counts(self) -> dict:
        b = self.blocks
        return {k: getattr(b, k).stop - getattr(b, k).start for k in ("u", "a", "p", "c", "pf", "q")}

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
    def _tabulate_bulk(self):
        f = self.fault
        ne = self.mesh.n_elements
        is_cut = np.zeros(ne, dtype=bool)
        is_cut[f.cut_elements] = True
        self.std_elements = np.flatnonzero(~is_cut)
        self.cut_elements = f.cut_elements
        sizes = self.mesh.element_sizes
        g = xfem.GAUSS2
        ref = np.array([[x, y] for y in g for x in g])
        N = xfem._bilinear(ref)  # (4 qp, 4)
        hs = sizes[self.std_elements]
        nq = len(ref)
        grads = np.zeros((len(hs), nq, 4, 2))
        for q in range(nq):
            xi, eta = ref[q]
            dxi = 0.25 * np.array([-(1 - eta), (1 - eta), (1 + eta), -(1 + eta)])
            deta = 0.25 * np.array([-(1 - xi), -(1 + xi), (1 + xi), (1 - xi)])
            grads[:, q, :, 0] = dxi[None, :] * 2.0 / hs[:, :1]
            grads[:, q, :, 1] = deta[None, :] * 2.0 / hs[:, 1:]
        self.std_N = np.broadcast_to(N, (len(hs), nq, 4)).copy()
        self.std_grad = grads
        self.std_w = np.broadcast_to(0.25 * hs[:, :1] * hs[:, 1:], (len(hs), nq)).copy()

        # cut elements: 8 displacement functions (4 standard, 4 Heaviside), 8 pressure functions
        nc, nqc = f.cut_qp.shape[:2]
        self.cut_Nu = np.zeros((nc, nqc, 8))
        self.cut_gu = np.zeros((nc, nqc, 8, 2))
        self.cut_Np = np.zeros((nc, nqc, 8))
        self.cut_gp = np.zeros((nc, nqc, 8, 2))
        for k, e in enumerate(f.cut_elements):
            nodes = self.elements[e]
            phi_e = f.node_phi[nodes]
            node_side = (phi_e > 0).astype(np.float64)
            hx, hy = sizes[e]
            for q in range(nqc):
                xi, eta = f.cut_qp[k, q]
                Nq = basis.shape(xi, eta)
                dN = basis.shape_gradient(xi, eta, hx, hy)
                Nh, dNh = basis.heaviside_basis(Nq, dN, float(f.cut_side[k, q]), node_side)
                Nl, dNl = basis.level_set_basis(Nq, dN, phi_e)
                self.cut_Nu[k, q, :4], self.cut_Nu[k, q, 4:] = Nq, Nh
                self.cut_gu[k, q, :4], self.cut_gu[k, q, 4:] = dN, dNh
                self.cut_Np[k, q, :4], self.cut_Np[k, q, 4:] = Nq, Nl
                self.cut_gp[k, q, :4], self.cut_gp[k, q, 4:] = dN, dNl
        self.cut_w = f.cut_w

        # local -> global maps
        std_nodes = self.elements[self.std_elements]
        cut_nodes = self.elements[self.cut_elements]
        none8 = -np.ones((len(cut_nodes), 4), dtype=np.int64)
        if self.has_u:
            self.std_umap = self._u_map(std_nodes)
            self.cut_umap = np.hstack([self._u_map(cut_nodes), self._a_map(cut_nodes)])
        if self.has_p:
            self.std_pmap = self._p_map(std_nodes)
            self.cut_pmap = np.hstack([self._p_map(cut_nodes),
                                       self._c_map(cut_nodes) if self.has_c else none8])

    def element_groups(self) -> list["ElementGroup"]:
        """The standard (2x2 Gauss) and cut (sub-cell) element groups with their tabulated bases
        and local-to-global maps (None where the scene has no such unknowns)."""
        out = []
        if len(self.std_elements):
            out.append(ElementGroup(self.std_elements, self.std_N, self.std_grad, self.std_N,
                                    self.std_grad, self.std_w, getattr(self, "std_umap", None),
                                    getattr(self, "std_pmap", None)))
        if len(self.cut_elements):
            out.append(ElementGroup(self.cut_elements, self.cut_Nu, self.cut_gu, self.cut_Np,
                                    self.cut_gp, self.cut_w, getattr(self, "cut_umap", None),
                                    getattr(self, "cut_pmap", None)))
        return out

    # ------------------------------------------------------------------ fault tabulation
    def _tabulate_fault(self):
        f = self.fault
        ng = len(f.gp_s)
        cut_nodes = self.elements[self.cut_elements]
        sizes = self.mesh.element_sizes
        N = np.zeros((ng, 4))
        xy = np.zeros((ng, 2))
        trace = self.has_c or (not self.has_pf and self.has_p)
        nbp = 8 if trace else 2
        Np = np.zeros((ng, nbp))
        dNp = np.zeros((ng, nbp))
        pmap = -np.ones((ng, nbp), dtype=np.int64)
        for g in range(ng):
            k = f.gp_element[g]
            e = self.cut_elements[k]
            xi, eta = f.gp_ref[g]
            Ng = basis.shape(xi, eta)
            N[g] = Ng
            xy[g] = Ng @ self.coords[cut_nodes[k]]
            if trace:
                dN = basis.shape_gradient(xi, eta, sizes[e, 0], sizes[e, 1])
                Nl, dNl = basis.level_set_basis(Ng, dN, f.node_phi[cut_nodes[k]])
                Np[g, :4], Np[g, 4:] = Ng, Nl
                dNp[g, :4], dNp[g, 4:] = dN @ f.tangent, dNl @ f.tangent
                if self.has_p:
                    pmap[g, :4] = self._p_map(cut_nodes[k])
                if self.has_c:
                    pmap[g, 4:] = self._c_map(cut_nodes[k])
            else:
                lam = f.gp_xi1d[g]
                s0, s1 = f.segment_s[f.gp_segment[g]]
                Np[g] = (1.0 - lam, lam)
                dNp[g] = (-1.0 / (s1 - s0), 1.0 / (s1 - s0))
                if self.has_pf:
                    pmap[g] = self.blocks.pf.start + f.segment_nodes[f.gp_segment[g]]
        self.fault_pressure_is_trace = trace
        jump = self._a_map(cut_nodes[f.gp_element]) if self.has_u else -np.ones((ng, 8), dtype=np.int64)
        sig, p0 = self.initial_state(xy)
        t, n = f.tangent, f.normal
        # bulk total stress sigma' - alpha p0 I balances the fault's sigma_n + p0 (Biot 1 on the fault)
        alpha_gp = self.el_alpha[self.cut_elements[f.gp_element]]
        snn = sig[:, 0] * n[0] ** 2 + sig[:, 1] * n[1] ** 2 + 2 * sig[:, 2] * n[0] * n[1]
        stn = (sig[:, 0] * t[0] * n[0] + sig[:, 1] * t[1] * n[1]
               + sig[:, 2] * (t[0] * n[1] + t[1] * n[0]))
        sigma_n0 = -snn - (1.0 - alpha_gp) * p0
        tau0 = stn
        self.fp = FaultPoints(N=N, jump_dofs=jump, Np=Np, dNp_ds=dNp, p_dofs=pmap, weight=f.gp_w,
                              s=f.gp_s, xy=xy, sigma_n0=sigma_n0, tau0=tau0, p0=p0)

    # ------------------------------------------------------------------ boundary conditions
    def _boundary_conditions(self):
        s = self.scene
        fixed = np.zeros(self.n_dofs, dtype=bool)
        self.load = np.zeros(self.n_dofs)  # applied traction changes (N per m thickness)
        f = self.fault
        for edge in EDGES:
            spec = getattr(s.boundary, edge)
            nodes = self.mesh.edge_nodes(edge)
            if self.has_u:
                comps = {"pinned": (0, 1), "roller": ((0,) if edge in ("left", "right") else (1,)),
                         "free": ()}[spec.mechanical]
                for c in comps:
                    fixed[self.blocks.u.start + 2 * nodes + c] = True
                    h = self.heav_index[nodes]
                    fixed[self.blocks.a.start + 2 * h[h >= 0] + c] = True
                if any(spec.traction):
                    self._edge_traction(nodes, np.asarray(spec.traction))
            if spec.hydraulic == "drained":
                if self.has_p:
                    fixed[self.blocks.p.start + nodes] = True
                if self.has_c:
                    c = self.lset_index[nodes]
                    fixed[self.blocks.c.start + c[c >= 0]] = True
                if self.has_pf:
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
            self.inj_N, self.inj_Np = np.zeros(4), np.zeros(0)
            self.inj_jump_dofs = -np.ones(8, dtype=np.int64)
            self.inj_p_dofs = np.zeros(0, dtype=np.int64)
            self.inj_s, self.inj_p0 = 0.0, self.scene.initial.pore_pressure
            self.fault_pressure_is_trace = False
            return
        s_inj = self.scene.injection.position
        try:
            k, lam = xfem.locate_point_on_fault(f, s_inj)
        except ValueError as exc:
            raise SceneError(f"injection.position = {s_inj!r}: {exc}") from None
        r0, r1 = f.segment_ref[k]
        xi, eta = r0 + lam * (r1 - r0)
        nodes = self.elements[self.cut_elements[k]]
        Ng = basis.shape(xi, eta)
        self.inj_N = Ng
        self.inj_jump_dofs = self._a_map(nodes[None, :])[0] if self.has_u else -np.ones(8, dtype=np.int64)
        if self.fault_pressure_is_trace:
            e = self.cut_elements[k]
            hx, hy = self.mesh.element_sizes[e]
            Nl, _ = basis.level_set_basis(Ng, basis.shape_gradient(xi, eta, hx, hy), f.node_phi[nodes])
            self.inj_Np = np.concatenate([Ng, Nl])
            pm = -np.ones(8, dtype=np.int64)
            if self.has_p:
                pm[:4] = self._p_map(nodes)
            if self.has_c:
                pm[4:] = self._c_map(nodes)
            self.inj_p_dofs = pm
        elif self.has_pf:
            self.inj_Np = np.array([1.0 - lam, lam])
            self.inj_p_dofs = self.blocks.pf.start + f.segment_nodes[k]
        else:  # dry fault: no fluid to inject into
            self.inj_Np = np.zeros(2)
            self.inj_p_dofs = -np.ones(2, dtype=np.int64)
        self.inj_s = s_inj
        self.inj_p0 = float(self.initial_state(self.injection_xy[None, :])[1][0])

    # ------------------------------------------------------------------ static matrices
    def _assemble_static(self):
        """K, Q, H, S of the rock; fault storage, conduction (constant aperture) and opening
        coupling. Split into: ``A`` (mechanics rows, acts on x at n+1), ``C`` (rate terms,
        acts on (x - x_n)/dt) and ``Hf`` (flow terms, theta-weighted)."""
        n = self.n_dofs
        A, C, Hf = TripletBuilder(n), TripletBuilder(n), TripletBuilder(n)
        for g in self.element_groups():
            els, gu, Np, gp, w, umap, pmap = g.elements, g.grad_u, g.Np, g.grad_p, g.w, g.umap, g.pmap
            if self.has_u:
                K = _per_element(rock.elastic_stiffness, gu, w, self.el_D[els])
                A.add(K, umap, umap)
            if self.has_u and self.has_p:
                Q = _per_element(rock.biot_coupling, gu, Np, w, self.el_alpha[els])
                A.add(Q, umap, pmap, scale=-1.0)
                C.add(np.transpose(Q, (0, 2, 1)), pmap, umap)
            if self.has_p:
                C.add(_per_element(rock.pore_storage, Np, w, self.el_inv_M[els]), pmap, pmap)
                Hf.add(_per_element(rock.darcy_conductance, gp, w, self.el_mobility[els]), pmap, pmap)
        # fault: storage and conduction on the fault-pressure carrier; walls pushed by pressure
        s = self.scene
        fp = self.fp
        self.fault_storativity = self.fault_transmissivity = 0.0
        if s.effects.fault_flow and self.has_fault:
            w2h = s.fault.hydraulic_aperture
            storativity = s.fault.storativity if s.fault.storativity is not None else w2h / s.fluid.bulk_modulus
            T = fault_flow.cubic_law_transmissivity(w2h, s.fluid.viscosity, s.fault.kappa)
            Sf = np.array([fault_flow.fault_storage(fp.Np[g], storativity, fp.weight[g]) for g in range(len(fp.s))])
            Hc = np.array([fault_flow.fault_conduction(fp.dNp_ds[g], T, fp.weight[g]) for g in range(len(fp.s))])
            C.add(Sf, fp.p_dofs, fp.p_dofs)
            if not s.effects.aperture_evolution:  # else assembled per iteration (solver)
                Hf.add(Hc, fp.p_dofs, fp.p_dofs)
            self.fault_storativity = storativity
            self.fault_transmissivity = T
        if self.has_u and self.has_fault:
            G = np.array([fault_flow.opening_coupling(fp.Np[g], fp.N[g], self.fault.normal, fp.weight[g])
                          for g in range(len(fp.s))])
            # the opening rate stores fluid in the fault (mass balance rows) ...
            if s.effects.fault_flow or self.has_c:
                C.add(G, fp.p_dofs, fp.jump_dofs)
            # ... and fault pressure pushes the walls apart (momentum rows)
            A.add(np.transpose(G, (0, 2, 1)), fp.jump_dofs, fp.p_dofs, scale=-1.0)
        if self.has_q:
            # pressure control: the injection rate is the multiplier of p(x_inj) = prescribed
            q = self.blocks.q.start
            rows = self.inj_p_dofs[None, :]
            Hf.add(-self.inj_Np[None, :, None], rows, np.array([[q]]))
            A.add(self.inj_Np[None, None, :], np.array([[q]]), rows)
        self.A = A.tocsr()
        self.C = C.tocsr()
        self.Hf = Hf.tocsr()
        self.source_vector = np.zeros(self.n_dofs)
        if not self.has_q:
            ok = self.inj_p_dofs >= 0
            self.source_vector[self.inj_p_dofs[ok]] = self.inj_Np[ok]

    # ------------------------------------------------------------------ in-situ equilibrium
    def initial_equilibrium_residual(self) -> tuple[float, float]:
        """Norm of the out-of-balance force of the in-situ state at the free displacement DOFs
        (N/m), and the norm of the forces it is made of (body force, stress divergence).

        The solution is written in changes from the in-situ state, which must therefore be in
        equilibrium by itself: total stress sigma' - alpha p0 I with body force, and the fault
        carrying the projected in-situ tractions."""
        r = np.zeros(self.n_dofs)
        scale = np.zeros(self.n_dofs)
        b = getattr(self, "body_force_density", np.zeros(2))
        for grp in self.element_groups():
            els, Nu, gu, w, umap = grp.elements, grp.Nu, grp.grad_u, grp.w, grp.umap
            Nstd = grp.Np[:, :, :4]  # standard shape functions locate the quadrature points
            xe = self.coords[self.elements[els]]               # (ne, 4, 2)
            xq = np.einsum("eqa,eac->eqc", Nstd, xe)          # quadrature points
            sig, p0 = self.initial_state(xq.reshape(-1, 2))
            alpha = np.repeat(self.el_alpha[els], xq.shape[1])
            sxx = (sig[:, 0] - alpha * p0).reshape(xq.shape[:2])
            syy = (sig[:, 1] - alpha * p0).reshape(xq.shape[:2])
            sxy = sig[:, 2].reshape(xq.shape[:2])
            fx = np.einsum("eq,eqb->eb", w * sxx, gu[..., 0]) + np.einsum("eq,eqb->eb", w * sxy, gu[..., 1])
            fy = np.einsum("eq,eqb->eb", w * sxy, gu[..., 0]) + np.einsum("eq,eqb->eb", w * syy, gu[..., 1])
            bx = np.einsum("eq,eqb->eb", w, Nu) * b[0]
            by = np.einsum("eq,eqb->eb", w, Nu) * b[1]
            local = np.empty((len(els), 2 * gu.shape[2]))
            local[:, 0::2], local[:, 1::2] = fx - bx, fy - by
            ok = umap >= 0
            np.add.at(r, umap[ok], local[ok])
            np.add.at(scale, umap[ok], np.abs(np.column_stack([bx, by]).reshape(local.shape)[ok])
                      + np.abs(local[ok]))
        fp = self.fp
        if len(fp.s):
            t, n = self.fault.tangent, self.fault.normal
            traction = fp.tau0[:, None] * t[None, :] - (fp.sigma_n0 + fp.p0)[:, None] * n[None, :]
            # int N_i T_c over the fault, laid out like jump_dofs (x, y per node)
            local = (fp.weight[:, None, None] * fp.N[:, :, None] * traction[:, None, :]).reshape(len(fp.s), 8)
            ok = fp.jump_dofs >= 0
            np.add.at(r, fp.jump_dofs[ok], local[ok])
        # the outer edges carry the in-situ tractions by assumption (the surroundings hold them),
        # so the check is on the interior nodes and their enriched DOFs
        inner = np.ones(self.mesh.n_nodes, dtype=bool)
        for edge in EDGES:
            inner[self.mesh.edge_nodes(edge)] = False
        keep = np.zeros(self.n_dofs, dtype=bool)
        nodes = np.flatnonzero(inner)
        keep[self.blocks.u.start + 2 * nodes] = keep[self.blocks.u.start + 2 * nodes + 1] = True
        h = self.heav_index[nodes]
        h = h[h >= 0]
        keep[self.blocks.a.start + 2 * h] = keep[self.blocks.a.start + 2 * h + 1] = True
        keep &= ~self.fixed
        return float(np.linalg.norm(r[keep])), float(np.linalg.norm(scale[keep]))

    def check_initial_equilibrium(self, rtol: float = 1e-8):
        out, ref = self.initial_equilibrium_residual()
        if out > rtol * max(ref, 1e-300):
            raise SceneError(
                f"the in-situ state is not in equilibrium (out-of-balance {out:.3e} N/m against "
                f"forces of {ref:.3e} N/m): the stress gradient with depth assumes one Biot "
                f"coefficient, porosity and density; zones that change them break it")

    # ------------------------------------------------------------------ evaluation helpers
    def fault_jump(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(slip, opening) at the fault Gauss points (m)."""
        if not self.has_u:
            z = np.zeros(len(self.fp.s))
            return z, z.copy()
        return contact.fault_jumps(x, self.fp.N, self.fp.jump_dofs, self.fault.tangent, self.fault.normal)

    def fault_overpressure(self, x: np.ndarray) -> np.ndarray:
        xv = np.where(self.fp.p_dofs >= 0, x[np.maximum(self.fp.p_dofs, 0)], 0.0)
        return np.sum(self.fp.Np * xv, axis=1)

    def injection_overpressure(self, x):
        xv = np.where(self.inj_p_dofs >= 0, x[np.maximum(self.inj_p_dofs, 0)], 0.0)
        return float(self.inj_Np @ xv)

    def injection_jump(self, x):
        if not self.has_u:
            return 0.0, 0.0
        d = self.inj_jump_dofs
        av = np.where(d >= 0, x[np.maximum(d, 0)], 0.0).reshape(4, 2)
        g = self.inj_N @ av
        return float(g @ self.fault.tangent), float(g @ self.fault.normal)


def _per_element(fn, *args):
    """Call a kernel element by element; the last argument may be per element or shared."""
    n = args[0].shape[0]
    if n == 0:
        return np.zeros((0, 1, 1))
    first = fn(*[a[0] for a in args])
    out = np.empty((n,) + first.shape)
    out[0] = first
    for e in range(1, n):
        out[e] = fn(*[a[e] for a in args])
    return out
