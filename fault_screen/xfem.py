"""Geometry of the embedded fault: level set, cut elements, enriched nodes and quadrature.

The fault is a straight line through ``point`` at ``angle`` (counter-clockwise from x). Its unit
tangent is ``t = (cos a, sin a)`` and normal ``n = (-sin a, cos a)``; the level set (paper Eq. 5)
is the signed distance ``phi(x) = n . (x - point)``, so the "+" side is the one ``n`` points to.

Cut elements (level set of both signs at their nodes) are integrated by splitting the reference
square along the fault into two convex polygons, fanning them into triangles and using a 7-point
degree-5 rule on each; the fault itself by 4-point Gauss–Legendre on its segment in each cut
element. Everything here is set up once per scene (plain numpy); kernels get the arrays.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .kernels import basis
from .mesh import StructuredMesh

# Radon's 7-point, degree-5 rule on the reference triangle, barycentric coordinates and weights
# summing to 1 (multiply by the triangle's area).
_S15 = np.sqrt(15.0)
_A1, _A2 = (6.0 - _S15) / 21.0, (6.0 + _S15) / 21.0
_W1, _W2 = (155.0 - _S15) / 1200.0, (155.0 + _S15) / 1200.0
TRI_BARY = np.array(
    [[1 / 3, 1 / 3, 1 / 3],
     [_A1, _A1, 1 - 2 * _A1], [_A1, 1 - 2 * _A1, _A1], [1 - 2 * _A1, _A1, _A1],
     [_A2, _A2, 1 - 2 * _A2], [_A2, 1 - 2 * _A2, _A2], [1 - 2 * _A2, _A2, _A2]]
)
TRI_W = np.array([9 / 40, _W1, _W1, _W1, _W2, _W2, _W2])
GL4_X, GL4_W = np.polynomial.legendre.leggauss(4)
GAUSS2 = np.array([-1.0, 1.0]) / np.sqrt(3.0)
REF_CORNERS = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])

#: Heaviside enrichment of a node is dropped only when its enriched function vanishes
#: identically (no support on the far side of the fault), which would make the system singular.
#: Thin slivers are kept: they are needed for exactness (patch test) and the Jacobi scaling of
#: the solver keeps them well conditioned (see tests/verification/test_verification_patch.py).
SLIVER_FRACTION = 0.0

#: A fault through mesh nodes (through a node, or along a mesh line) is moved off them along its
#: normal by this fraction of the smallest element size. A node exactly on the fault belongs to
#: neither side: its shifted Heaviside function would not vanish in the uncut elements on its
#: far side, which the assembly never integrates (the in-situ state then shows an
#: out-of-balance force), and a fault along a mesh line cuts no element at all. 1e-6 of an
#: element is far below any physical length of the model, and the patch tests are exact at that
#: offset (tests/verification/test_verification_patch.py).
NODE_CLEARANCE = 1e-6


def _clip(poly: np.ndarray, f: np.ndarray, sign: float) -> np.ndarray:
    """Part of convex polygon ``poly`` where ``sign * f >= 0`` (``f`` linear, given at vertices)."""
    out = []
    n = len(poly)
    for k in range(n):
        a, b = poly[k], poly[(k + 1) % n]
        fa, fb = sign * f[k], sign * f[(k + 1) % n]
        if fa >= 0:
            out.append(a)
        if (fa > 0 > fb) or (fa < 0 < fb):
            out.append(a + (b - a) * fa / (fa - fb))
    return np.array(out)


def _polygon_quadrature(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points and reference-area weights of a fan triangulation of a convex polygon."""
    pts, wts = [], []
    for k in range(1, len(poly) - 1):
        tri = np.array([poly[0], poly[k], poly[k + 1]])
        area = 0.5 * abs((tri[1, 0] - tri[0, 0]) * (tri[2, 1] - tri[0, 1])
                         - (tri[2, 0] - tri[0, 0]) * (tri[1, 1] - tri[0, 1]))
        if area <= 1e-14:
            continue
        pts.append(TRI_BARY @ tri)
        wts.append(TRI_W * area)
    if not pts:
        return np.zeros((0, 2)), np.zeros(0)
    return np.vstack(pts), np.concatenate(wts)


@dataclass(frozen=True)
class FaultGeometry:
    """Where the fault is with respect to the mesh (all arrays plain numpy)."""

    point: np.ndarray              # (2,) m, origin of the along-fault coordinate s
    tangent: np.ndarray            # (2,)
    normal: np.ndarray             # (2,)
    node_phi: np.ndarray           # (n_nodes,) signed distance, m
    cut_elements: np.ndarray       # (n_cut,) element ids
    # sub-cell quadrature of cut elements, padded with zero weights
    cut_qp: np.ndarray             # (n_cut, nq, 2) reference coordinates
    cut_w: np.ndarray              # (n_cut, nq) weights in m^2 (area)
    cut_side: np.ndarray           # (n_cut, nq) Heaviside value 0/1 at the point
    # fault Gauss points, ordered by s
    gp_element: np.ndarray         # (n_gp,) index into cut_elements
    gp_ref: np.ndarray             # (n_gp, 2) reference coordinates
    gp_w: np.ndarray               # (n_gp,) length weights, m
    gp_s: np.ndarray               # (n_gp,) along-fault coordinate, m
    gp_segment: np.ndarray         # (n_gp,) segment index
    gp_xi1d: np.ndarray            # (n_gp,) position on its segment in [0, 1]
    # fault segments (one per cut element) and the 1-D fault node line
    segment_s: np.ndarray          # (n_seg, 2) s at the segment ends, increasing
    segment_ref: np.ndarray        # (n_cut, 2, 2) reference coordinates of the segment ends
    fault_node_s: np.ndarray       # (n_fault_nodes,) s of segment ends
    segment_nodes: np.ndarray      # (n_seg, 2) fault-node ids of each segment
    segment_element: np.ndarray    # (n_seg,) index into cut_elements of each segment's element
    heaviside_enriched: np.ndarray  # (n_nodes,) bool: node carries Heaviside DOFs
    pressure_enriched: np.ndarray  # (n_nodes,) bool: node carries modified-level-set DOFs
    shift: float = 0.0             # m along the normal the fault was moved off mesh nodes
    #: a finite fault's tips after snapping to element edges (s, m); None: across the whole model
    tips: tuple[float, float] | None = None

    @property
    def length(self) -> float:
        return float(self.fault_node_s[-1] - self.fault_node_s[0])


def locate_fault(mesh: StructuredMesh, point, angle_deg: float, length: float | None = None) -> FaultGeometry:
    """Cut a straight fault into ``mesh``: through the whole model, or with ``length`` (m) a
    finite one centred on ``point`` (see ``_finite``). Raises ``ValueError`` if it misses."""
    a = np.deg2rad(angle_deg)
    t = np.array([np.cos(a), np.sin(a)])
    n = np.array([-np.sin(a), np.cos(a)])
    point = np.asarray(point, dtype=float)
    coords = mesh.coordinates
    elems = mesh.elements
    phi = (coords - point) @ n
    point, phi, shift = _clear_nodes(mesh, point, n, phi)
    ephi = phi[elems]
    cut = np.flatnonzero((ephi.min(axis=1) < 0.0) & (ephi.max(axis=1) > 0.0))
    if cut.size == 0:
        raise ValueError("the fault does not cross any element: it misses the domain")
    sizes = mesh.element_sizes

    qps, ws, sides, seg_s, seg_pts = [], [], [], [], []
    for e in cut:
        fref = ephi[e]
        # phi is linear in reference coordinates on a rectangle: phi = c0 + c1 xi + c2 eta
        c1 = 0.25 * (-fref[0] + fref[1] + fref[2] - fref[3])
        c2 = 0.25 * (-fref[0] - fref[1] + fref[2] + fref[3])
        c0 = 0.25 * fref.sum()
        det = 0.25 * sizes[e, 0] * sizes[e, 1]
        q, w, sd = [], [], []
        for side, sign in ((1, 1.0), (0, -1.0)):
            poly = _clip(REF_CORNERS, fref, sign)
            if len(poly) >= 3:
                p, pw = _polygon_quadrature(poly)
                q.append(p)
                w.append(pw * det)
                sd.append(np.full(len(pw), side))
        qps.append(np.vstack(q))
        ws.append(np.concatenate(w))
        sides.append(np.concatenate(sd))
        # segment: where c0 + c1 xi + c2 eta = 0 crosses the reference square's edges
        ends = []
        for k in range(4):
            pa, pb = REF_CORNERS[k], REF_CORNERS[(k + 1) % 4]
            fa = c0 + c1 * pa[0] + c2 * pa[1]
            fb = c0 + c1 * pb[0] + c2 * pb[1]
            if fa == 0.0:
                ends.append(pa)
            elif fa * fb < 0.0:
                ends.append(pa + (pb - pa) * fa / (fa - fb))
        ends = _unique_points(np.round(np.array(ends), 14))
        if len(ends) != 2:
            raise ValueError(f"fault meets element {e} in {len(ends)} points; expected 2")
        xe = coords[elems[e]]
        phys = np.array([_ref_to_phys(xe, r) for r in ends])
        s_ends = (phys - point) @ t
        order = np.argsort(s_ends)
        seg_s.append(s_ends[order])
        seg_pts.append(ends[order])

    nq = max(len(w) for w in ws)
    n_cut = len(cut)
    cut_qp = np.zeros((n_cut, nq, 2))
    cut_w = np.zeros((n_cut, nq))
    cut_side = np.zeros((n_cut, nq), dtype=np.int64)
    for k in range(n_cut):
        m = len(ws[k])
        cut_qp[k, :m], cut_w[k, :m], cut_side[k, :m] = qps[k], ws[k], sides[k]

    segment_s = np.array(seg_s)
    order = np.argsort(segment_s[:, 0])
    # renumber cut elements along the fault so that everything is ordered by s
    cut = cut[order]
    cut_qp, cut_w, cut_side = cut_qp[order], cut_w[order], cut_side[order]
    segment_s = segment_s[order]
    seg_pts = [seg_pts[k] for k in order]
    beyond_tips = np.zeros(0, dtype=np.int64)
    tips = None
    if length is not None:
        keep, tips = _finite(segment_s, length, float(sizes[cut].min()))
        beyond_tips = cut[~keep]
        cut, cut_qp, cut_w, cut_side = cut[keep], cut_qp[keep], cut_w[keep], cut_side[keep]
        segment_s = segment_s[keep]
        seg_pts = [p for p, k in zip(seg_pts, keep) if k]
        n_cut = len(cut)

    # 1-D fault nodes: segment ends, merged where consecutive segments meet
    h_min = float(sizes[cut].min())
    ends_all = np.sort(segment_s.ravel())
    nodes = [ends_all[0]]
    for v in ends_all[1:]:
        if v - nodes[-1] > 1e-9 * h_min:
            nodes.append(v)
    fault_node_s = np.array(nodes)
    segment_nodes = np.column_stack([
        np.abs(fault_node_s[None, :] - segment_s[:, :1]).argmin(axis=1),
        np.abs(fault_node_s[None, :] - segment_s[:, 1:]).argmin(axis=1),
    ]).astype(np.int64)
    zero_length = segment_nodes[:, 0] == segment_nodes[:, 1]
    if zero_length.any():
        raise ValueError("the fault only touches the corner of an element; move it slightly")

    gp = _fault_gauss_points(segment_s, np.array(seg_pts), np.arange(n_cut))

    # enriched nodes and the sliver criterion for the Heaviside enrichment
    cut_nodes = elems[cut]
    enriched = np.zeros(mesh.n_nodes, dtype=bool)
    enriched[cut_nodes.ravel()] = True
    support = np.zeros(mesh.n_nodes)
    far_side = np.zeros(mesh.n_nodes)
    # the standard shape functions at the points (nq, 4 each), tabulated at once
    shapes = np.ascontiguousarray(np.moveaxis(basis.shape(cut_qp[:, :, 0], cut_qp[:, :, 1]),
                                              0, -1))
    for k in range(n_cut):
        xe_nodes = cut_nodes[k]
        shape = shapes[k]
        for a in range(4):
            node = xe_nodes[a]
            node_side = 1 if phi[node] > 0 else 0
            wN = cut_w[k] * shape[:, a]
            support[node] += wN.sum()
            far_side[node] += wN[cut_side[k] != node_side].sum()
    heav = enriched & (far_side > SLIVER_FRACTION * np.maximum(support, 1e-300))
    # past a tip the line crosses elements the fault does not cut: a node of one of them (the
    # tip's edge) gets no jump, so the fault closes at its tip
    heav[elems[beyond_tips].ravel()] = False
    if length is not None and not heav.any():
        raise ValueError(f"fault.length = {length:g} m is too short to slip on this mesh: the "
                         f"{n_cut} element(s) it cuts have every node on an edge through a tip, where "
                         f"the jump is 0; make it longer (two elements at least) or refine there")

    return FaultGeometry(
        point=point, tangent=t, normal=n, node_phi=phi, cut_elements=cut,
        cut_qp=cut_qp, cut_w=cut_w, cut_side=cut_side,
        **gp, segment_s=segment_s, segment_ref=np.array(seg_pts), fault_node_s=fault_node_s,
        segment_nodes=segment_nodes, segment_element=np.arange(n_cut),
        heaviside_enriched=heav, pressure_enriched=enriched, shift=shift,
        tips=tips,
    )


def _finite(segment_s, length, h_min):
    """(keep, tips) of a finite fault: the segments (one per cut element, ordered by s) that lie
    between the tips s = -length/2 and +length/2, each tip snapped to the nearest element edge
    along the fault (the nearest segment end; the ends of the line where the model ends first).

    Standard X-FEM without tip enrichment: the Heaviside enrichment covers only elements the
    fault cuts completely, and the nodes of the element edge through a tip are not enriched, so
    the jump closes linearly over the last element. The stress singularity of a real tip is not
    represented; the slip of a uniformly loaded crack converges to the elliptical profile as the
    elements shrink (tests/hard_cases/test_finite_fault.py)."""
    if not length > 0:
        raise ValueError(f"fault.length = {length} m must be > 0")
    ends = np.unique(segment_s.ravel())
    s_lo = float(ends[np.argmin(np.abs(ends + 0.5 * length))])
    s_hi = float(ends[np.argmin(np.abs(ends - 0.5 * length))])
    if not s_hi - s_lo > 1e-9 * h_min:
        raise ValueError(f"fault.length = {length:g} m is shorter than the element edges it can end on "
                         f"(the elements it crosses are {h_min:g} m or larger): make it longer or refine there")
    tol = 1e-9 * h_min
    keep = (segment_s[:, 0] >= s_lo - tol) & (segment_s[:, 1] <= s_hi + tol)
    return keep, (s_lo, s_hi)


def _fault_gauss_points(segment_s, segment_ref, segment_element) -> dict:
    """4-point Gauss-Legendre points of every fault segment (the gp_* fields)."""
    gp_el, gp_ref, gp_w, gp_s, gp_seg, gp_xi = [], [], [], [], [], []
    for k in range(len(segment_s)):
        r0, r1 = segment_ref[k]
        s0, s1 = segment_s[k]
        for xg, wg in zip(GL4_X, GL4_W):
            lam = 0.5 * (xg + 1.0)
            gp_el.append(segment_element[k])
            gp_ref.append(r0 + lam * (r1 - r0))
            gp_w.append(0.5 * wg * (s1 - s0))
            gp_s.append(s0 + lam * (s1 - s0))
            gp_seg.append(k)
            gp_xi.append(lam)
    return dict(gp_element=np.array(gp_el, dtype=np.int64), gp_ref=np.array(gp_ref), gp_w=np.array(gp_w),
                gp_s=np.array(gp_s), gp_segment=np.array(gp_seg, dtype=np.int64), gp_xi1d=np.array(gp_xi))


def with_node_at(geom: FaultGeometry, s: float) -> FaultGeometry:
    """The geometry with a node of the 1-D fault line at along-fault coordinate ``s``: the segment
    holding ``s`` is split in two (both in the same cut element), unless ``s`` is already within
    1e-9 of a segment of a node.

    For the fault's own pressure line: the pressure of a point source (or held at a point) has a
    kink there, which linear elements represent only at a node. Inside a segment the source is
    shared by the segment's two nodes and the pressure is flattened over the whole segment (the
    slip of the 30-degree verification scene grew by 90 % with the point moved half an element)."""
    k, lam = locate_point_on_fault(geom, s)
    s0, s1 = geom.segment_s[k]
    if min(lam, 1.0 - lam) <= 1e-9:
        return geom
    r0, r1 = geom.segment_ref[k]
    rm = r0 + lam * (r1 - r0)
    segment_s = np.insert(geom.segment_s, k + 1, [s, s1], axis=0)
    segment_s[k, 1] = s
    segment_ref = np.insert(geom.segment_ref, k + 1, [rm, r1], axis=0)
    segment_ref[k, 1] = rm
    segment_element = np.insert(geom.segment_element, k + 1, geom.segment_element[k])
    fault_node_s = np.insert(geom.fault_node_s, int(np.searchsorted(geom.fault_node_s, s)), s)
    segment_nodes = np.column_stack([
        np.abs(fault_node_s[None, :] - segment_s[:, :1]).argmin(axis=1),
        np.abs(fault_node_s[None, :] - segment_s[:, 1:]).argmin(axis=1),
    ]).astype(np.int64)
    return replace(geom, **_fault_gauss_points(segment_s, segment_ref, segment_element),
                   segment_s=segment_s, segment_ref=segment_ref, segment_element=segment_element,
                   fault_node_s=fault_node_s, segment_nodes=segment_nodes)


def _clear_nodes(mesh: StructuredMesh, point, n, phi):
    """(point, phi, shift): the fault moved along ``n`` by NODE_CLEARANCE of the smallest
    element when it passes (within round-off) through mesh nodes; unchanged otherwise."""
    h_min = float(mesh.element_sizes.min())
    touch = 1e-3 * NODE_CLEARANCE * h_min
    if not np.any(np.abs(phi) <= touch):
        return point, phi, 0.0
    shift = NODE_CLEARANCE * h_min
    while np.any(np.abs(phi - shift) <= touch):  # never lands on another node (rare: try further)
        shift *= 2.0
    return point + shift * n, phi - shift, shift


def no_fault(mesh: StructuredMesh) -> FaultGeometry:
    """The geometry of a scene without a fault: nothing cut, nothing enriched."""
    z2 = np.zeros((0, 2))
    zi = np.zeros(0, dtype=np.int64)
    return FaultGeometry(
        point=np.zeros(2), tangent=np.array([1.0, 0.0]), normal=np.array([0.0, 1.0]),
        node_phi=np.ones(mesh.n_nodes), cut_elements=zi, cut_qp=np.zeros((0, 1, 2)),
        cut_w=np.zeros((0, 1)), cut_side=np.zeros((0, 1), dtype=np.int64), gp_element=zi,
        gp_ref=z2, gp_w=np.zeros(0), gp_s=np.zeros(0), gp_segment=zi, gp_xi1d=np.zeros(0),
        segment_s=z2, segment_ref=np.zeros((0, 2, 2)), fault_node_s=np.zeros(0),
        segment_nodes=np.zeros((0, 2), dtype=np.int64), segment_element=zi,
        heaviside_enriched=np.zeros(mesh.n_nodes, dtype=bool),
        pressure_enriched=np.zeros(mesh.n_nodes, dtype=bool))


def _unique_points(points: np.ndarray) -> np.ndarray:
    """``np.unique(points, axis=0)`` for the few points where a line crosses an element's edges:
    the distinct rows, sorted lexicographically (numpy's general routine costs more than the
    rest of an element's cut)."""
    return np.array(sorted(set(map(tuple, points.tolist()))), dtype=float).reshape(-1, 2)


def tabulate_cut(cut_elements, elements, node_phi, sizes, cut_qp, cut_side):
    """The cut elements' functions at their quadrature points (the padding points of an element
    with fewer too, at their reference position, as the weights there are zero): the 4 standard
    and 4 shifted-Heaviside displacement functions and their gradients (Nu, gu), the 4 standard
    and 4 modified-level-set pressure functions and theirs (Np, gp), for all points at once in
    numpy (the arithmetic, sums included, in the order of ``kernels.basis``, so the values are
    the same to the bit as a point at a time)."""
    nc, nqc = cut_qp.shape[:2]
    xi, eta = cut_qp[:, :, 0], cut_qp[:, :, 1]
    hx, hy = sizes[cut_elements, 0][:, None], sizes[cut_elements, 1][:, None]
    # (basis's formulas are elementwise: on arrays of points they give every point at once;
    # contiguous, as the products downstream sum in an order that follows the memory layout)
    N = np.ascontiguousarray(np.moveaxis(basis.shape(xi, eta), 0, -1))      # (nc, nqc, 4)
    dN = np.ascontiguousarray(np.transpose(basis.shape_gradient(xi, eta, hx, hy),
                                           (2, 3, 0, 1)))                    # (nc, nqc, 4, 2)
    phi = node_phi[elements[cut_elements]][:, None, :]                # (nc, 1, 4)
    node_side = (phi > 0).astype(np.float64)
    shift = cut_side[:, :, None] - node_side                          # (nc, nqc, 4)
    Nl, gl = basis.level_set_basis(N, dN, phi)
    Nu = np.concatenate([N, N * shift], axis=2)
    gu = np.concatenate([dN, dN * shift[..., None]], axis=2)
    Np = np.concatenate([N, Nl], axis=2)
    gp = np.concatenate([dN, gl], axis=2)
    return Nu, gu, Np, gp


def _ref_to_phys(xe: np.ndarray, r: np.ndarray) -> np.ndarray:
    return basis.shape(r[0], r[1]) @ xe


def locate_point_on_fault(geom: FaultGeometry, s: float) -> tuple[int, float]:
    """Segment index containing along-fault coordinate ``s`` and the position in it (0..1)."""
    if s < geom.segment_s[0, 0] - 1e-12 or s > geom.segment_s[-1, 1] + 1e-12:
        raise ValueError(f"point s = {s} m is off the fault (fault spans {geom.segment_s[0, 0]:.6g} "
                         f"to {geom.segment_s[-1, 1]:.6g} m)")
    k = int(np.searchsorted(geom.segment_s[:, 1], s))
    k = min(k, len(geom.segment_s) - 1)
    s0, s1 = geom.segment_s[k]
    return k, float(np.clip((s - s0) / (s1 - s0), 0.0, 1.0))
