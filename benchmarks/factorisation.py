"""Factorisations of the free system, side by side on the same matrices (issue 28 items 1-2).

    python benchmarks/factorisation.py                    # every scene (minutes on 2 cores)
    python benchmarks/factorisation.py --scenes rustrel rustrel-paper

For each scene and step size the scaled free Jacobian M = D (A + C/dt + theta Hf) D is taken in
the solver's own order (the bulk B in its nested-dissection order, the condensed unknowns N
last: the bordered design) and factorised by

- ``superlu``: SuperLU as the solver calls it today (given order, SymmetricMode, SuperLU's
  default diagonal pivot threshold on a poroelastic block, 0.1 on an elastic one);
- ``superlu-sym``: SuperLU on the symmetric form S = E M (E: -dt on the flow rows, which makes
  the poroelastic block symmetric and quasi-definite), threshold 0.1;
- ``qdldl``: the quasi-definite LDL^T of the ``qdldl`` package on S (no pivoting; the package
  applies its own AMD order to the given one), first made at the first step size and then only
  refactorised numerically (``update``: the ordering and symbolic analysis reused) at the others;
- ``ldl``: the solver's own multifrontal LDL^T of S's bulk with N as its border
  (``fault_screen/ldl.py``, what the solver runs for a poroelastic bulk), its symbolic analysis
  made at the first step size (its time in the note) and reused at the others, which pay the
  numeric factorisation only; factor time includes the dense LU of the Schur complement on N,
  solve time the forward sweep, that LU's solve and the backward sweep. Its note also gives the
  CPU time of making the matrix of that step size as the solver hands it to the factorisation:
  "summed", by sparse sums and products (A + C/dt + theta Hf scaled, permuted, its rows times
  E), its symmetry checked, its lower triangle and condensed block taken, as the solver did
  before the fixed pattern; "fixed", written into the pattern fixed at the first step size
  (``fault_screen/fixed_pattern.py``: one pass over the values), as the solver does now.

S is the symmetric form where the solver uses it (a poroelastic bulk, whose factors change with
the step size); an elastic bulk (the fine 30-degree scene) is factorised as it is, M. There the
bulk's rows and columns are symmetric (``ldl`` factorises them) but the fault block N x N is
not (asym 2: the fault's flow rows against its opening), so S is not symmetric as a whole:
qdldl, which reads the whole matrix from its upper triangle, fails there (its error is in the
note), and the bordered ``ldl`` leaves that block to the dense Schur complement.

Columns: factor time, solve time (one right-hand side), the factors' memory (values and indices),
and the relative residual |M x - b| / |b| of the solve on the unsymmetric M, b random. The
``asym`` column is max |S - S^T| / max |S| (0 up to round-off where the symmetric form holds).
The table is printed and written to docs/performance/factorisation.md (generated: do not edit).

``--fronts`` prints instead, per scene at the largest step size, where the numeric LDL^T's work
goes: multiply-adds of the pivot blocks, of the rows below them (L21) and of the updates of the
later rows, with the part that the condensed rows N cause (their rows of L21, their updates of
S and of the bulk rows), by front size, with the entries each pass over the fronts touches
(zeroed, the matrix's own added, the children's updates added, L packed, the update copied
out) and the multiply-adds per entry moved; the entries moved by the extend-add; the CPU time
of the numeric factorisation with the large fronts through BLAS (``ldl.BLAS_MIN_WIDTH`` and
``BLAS_MIN_ROWS``) and with every front by loops, the same matrix alternately in one run; and the
CPU time of numpy's matrix product (BLAS dgemm, one thread) on the very shapes of the products
the BLAS fronts make, which bounds what those fronts can take; and the parts that a
refactorisation runs in two threads (``ldl.LDLSymbolic.parts``, the top's last front shared by
the threads: ``ldl._front_by_halves``, by BLAS panels also in the loops-only timing): each part's
thread CPU time in one thread and the wall time in one and in two threads; and where the wall in
two threads goes (medians of timers around the kernels and of the shared front's own clock
stamps, ``ldl._front_by_halves``): the set-up before the parts, each part's wall and the later
one's lead, the join, the top, the shared front's wall against its halves' path (per stretch
between their meetings the longer half's), the end, and the process's minor page faults per
factorisation.
Every timing is the least CPU time of ``--repeat`` runs in this one process, with one BLAS
thread (on a shared machine wall time measures the other processes too); compare rows of one
run. Each method factorises the whole free matrix in one call: the solver splits a
large bulk into parts factorised one after the other (``bordered_lu.SplitBorderedLU``), which
takes less time and memory than the rows here, alike for every method.
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
STEP_SIZES = (5.0, 60.0, 600.0)


def _scene(key):
    from fault_screen import Scene

    configs = ROOT / "configs"
    if key == "rustrel":
        return Scene.from_toml(configs / "rustrel-2015-calibrated.toml")
    if key == "rustrel-paper":
        return Scene.from_toml(configs / "rustrel-2015-calibrated-paper-units.toml")
    if key == "rustrel-200x201":
        s = Scene.from_toml(configs / "rustrel-2015-calibrated.toml")
        return s.replace(mesh=replace(s.mesh, nx=200, ny=201))
    if key == "fine-T0.7-dip30":
        from verification_cost import scaled_scene

        return scaled_scene("fluid-driven-slip-T0.7-dip30", 0.5)
    raise SystemExit(f"unknown scene {key}")


SCENES = ("rustrel", "rustrel-paper", "rustrel-200x201", "fine-T0.7-dip30")


def free_matrices(scene, step_sizes):
    """(M, E, nB) for each step size: the scaled free Jacobian in the solver's order, the row
    signs and step sizes that make it symmetric (E), and the number of bulk unknowns."""
    from fault_screen import Simulation

    sim = Simulation(scene)
    solver, disc = sim.solver, sim.disc
    x0 = np.zeros(disc.n_dofs)
    contact = disc.physics.contact
    history = contact.initial_history(disc) if contact is not None else None
    solver._prepare(step_sizes[0], x0, history)
    system = solver.system
    order = system.order
    D = sp.diags(system.scale)
    mech = np.zeros(disc.n_dofs, dtype=bool)
    mech[disc.blocks.u] = True
    mech[disc.blocks.a] = True
    out = []
    for dt in step_sizes:
        M = (D @ system._linear_jacobian(dt) @ D).tocsr()[order][:, order].tocsc()
        E = np.ones(len(order)) if system.factors_any_dt else np.where(mech[order], 1.0, -dt)
        out.append((M, E, len(system.B)))
    return out, disc.n_dofs, _builds(system, mech[order])


def _builds(system, mechanical):
    """dt -> (CPU time of the matrix summed, in the fixed pattern) (``_best`` of 3 each)."""
    from fault_screen import ldl
    from fault_screen.bordered_lu import _linear_rows_symmetric
    from fault_screen.fixed_pattern import FixedBulk

    order, nB = system.order, len(system.B)
    D = sp.diags(system.scale)
    flow = None if system.factors_any_dt else ~mechanical
    bulk = FixedBulk((system.A, system.C, system.Hf), system.time_weight, order, system.scale,
                     flow, nB)

    def summed(dt):
        M = (D @ system._linear_jacobian(dt) @ D).tocsr()[order][:, order].tocsc()
        if flow is not None:
            M.data *= np.where(flow, -dt, 1.0)[M.indices]
        _linear_rows_symmetric(M, nB)
        return ldl._lower(M, nB), M[nB:, nB:].toarray()

    def fixed(dt):
        values = bulk.values(dt)
        return bulk.lower(values), bulk.condensed(values)

    return lambda dt: (_best(lambda: summed(dt), 3)[0], _best(lambda: fixed(dt), 3)[0])


def _best(fn, repeat):
    """The least CPU time of ``repeat`` calls (the process's, one BLAS thread: on a shared
    machine wall time measures the other processes too), and the last call's value."""
    best, value = np.inf, None
    for _ in range(repeat):
        t0 = time.process_time()
        value = fn()
        best = min(best, time.process_time() - t0)
    return best, value


def _residual(M, x, b):
    return float(np.linalg.norm(M @ x - b) / np.linalg.norm(b))


def measure(key, repeat):
    import qdldl

    from fault_screen.bordered_lu import SYMMETRIC_PIVOT_THRESHOLD, _linear_rows_symmetric

    mats, n_dofs, builds = free_matrices(_scene(key), STEP_SIZES)
    rows = []
    ldl = None
    analyses = []
    rng = np.random.default_rng(0)
    for dt, (M, E, nB) in zip(STEP_SIZES, mats):
        b = rng.standard_normal(M.shape[0])
        S = sp.diags(E) @ M
        S = S.tocsc()
        largest = abs(S).max()
        asym = abs(S - S.T).max() / largest if largest else 0.0
        elastic = _linear_rows_symmetric(M, nB)
        base = dict(scene=key, dt=dt, n=M.shape[0], nB=nB, asym=asym)

        def superlu(A, threshold):
            return spla.splu(A, permc_spec="NATURAL", diag_pivot_thresh=threshold,
                             options=dict(SymmetricMode=True))

        for name, A, threshold, rhs_scale in (
                ("superlu", M, SYMMETRIC_PIVOT_THRESHOLD if elastic else None, None),
                ("superlu-sym", S, SYMMETRIC_PIVOT_THRESHOLD, E)):
            t_fact, lu = _best(lambda: superlu(A, threshold), repeat)
            rhs = b if rhs_scale is None else rhs_scale * b
            t_solve, x = _best(lambda: lu.solve(rhs), repeat)
            memory = (lu.L.nnz + lu.U.nnz) * 12 / 1e6
            rows.append(dict(base, method=name, factor=t_fact, solve=t_solve, memory=memory,
                             residual=_residual(M, x, b), note=""))
            lu = None
        row = _ldl_row(base, S, E, M, b, nB, analyses, repeat)
        t_summed, t_fixed = builds(dt)
        row["note"] += (f"; matrix of this dt summed {1e3 * t_summed:.1f} ms, "
                        f"fixed {1e3 * t_fixed:.1f} ms")
        rows.append(row)
        upper = sp.triu(S, format="csc")
        try:
            if ldl is None:
                t_fact, ldl = _best(lambda: qdldl.Solver(upper, upper=True), repeat)
                note = "ordering + symbolic + numeric"
            else:
                t_fact, _ = _best(lambda: ldl.update(upper, upper=True), repeat)
                note = "numeric only (update)"
        except RuntimeError as error:   # (qdldl's own error, e.g. its index type overflowing)
            rows.append(dict(base, method="qdldl", factor=np.nan, solve=np.nan, memory=np.nan,
                             residual=np.nan, note=f"failed: {error}"))
            continue
        t_solve, y = _best(lambda: ldl.solve(E * b), repeat)
        L_factor = ldl.factors()[0]
        memory = (L_factor.nnz * 12 + 2 * M.shape[0] * 8) / 1e6
        rows.append(dict(base, method="qdldl", factor=t_fact, solve=t_solve, memory=memory,
                         residual=_residual(M, y, b), note=note))
    return rows


def _ldl_row(base, S, E, M, b, nB, analyses, repeat):
    """The ``ldl`` row: ``analyses`` (a list holding the symbolic analyses, empty at the first
    step size) is filled at the first call and reused."""
    import scipy.linalg

    from fault_screen import ldl
    from fault_screen.bordered_lu import BorderedLU, lu_solve

    note = "numeric only (analysis kept)"
    if not analyses:
        t0 = time.perf_counter()
        analyses.append(ldl.SymbolicAnalyses())
        analyses[0].of(ldl._lower(S, nB), nB)
        note = f"symbolic analysis {time.perf_counter() - t0:.3f} s, then numeric"

    def factor():
        lu = BorderedLU(S, nB, analyses[0])
        return lu, scipy.linalg.lu_factor(lu.schur, check_finite=False)

    try:
        t_fact, (lu, schur_lu) = _best(factor, repeat)
    except ldl.NotQuasiDefinite as error:
        return dict(base, method="ldl", factor=np.nan, solve=np.nan, memory=np.nan,
                    residual=np.nan, note=f"failed: {error}")
    if not lu.quasi_definite:
        return dict(base, method="ldl", factor=np.nan, solve=np.nan, memory=np.nan,
                    residual=np.nan, note="not symmetric: SuperLU's")
    rhs = E * b

    def solve():
        swept, condensed = lu.forward(rhs[:nB], rhs[nB:])
        x_N = lu_solve(schur_lu, condensed)
        return np.concatenate([lu.backward(swept, x_N), x_N])

    t_solve, x = _best(solve, repeat)
    first, width, row_at, value_at, rows, values = lu._L.arrays
    memory = (values.nbytes + rows.nbytes + lu._D.nbytes + schur_lu[0].nbytes) / 1e6
    return dict(base, method="ldl", factor=t_fact, solve=t_solve, memory=memory,
                residual=_residual(M, x, b), note=note)


def table(rows):
    head = ("| scene | dt (s) | unknowns | method | factor CPU (s) | solve CPU (ms) | memory (MB) "
            "| residual | asym | note |")
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['dt']:g} | {r['n']} | {r['method']} | {r['factor']:.3f} "
                     f"| {1e3 * r['solve']:.2f} | {r['memory']:.1f} | {r['residual']:.1e} "
                     f"| {r['asym']:.0e} | {r['note']} |")
    return "\n".join(lines)


def fronts(key, repeat):
    """The ``--fronts`` report of one scene (see the module docstring), printed."""
    from fault_screen import ldl

    (M, E, nB), = free_matrices(_scene(key), STEP_SIZES[-1:])[0]
    S = (sp.diags(E) @ M).tocsc()
    lower, condensed = ldl._lower(S, nB), S[nB:, nB:].toarray()
    symbolic = ldl.SymbolicAnalyses().of(lower, nB)
    first, width, row_at, srows, tparent, children, relative = symbolic.tree
    m = np.diff(row_at)
    w = width
    u = m - w
    m_N = np.add.reduceat((srows >= nB).astype(np.int64), row_at[:-1]) if len(m) else m
    u_B = u - m_N
    pivot, below, update = ldl.front_multiply_adds(w, u)
    by_N = m_N * w * w / 2.0 + w * (m_N * u_B + m_N * (m_N + 1) / 2.0)
    total = pivot + below + update
    blas = (w >= ldl.BLAS_MIN_WIDTH) & (u >= ldl.BLAS_MIN_ROWS)
    print(f"\n{key}: bulk {nB} unknowns, N {S.shape[0] - nB}, {len(m)} supernodes "
          f"({int(blas.sum())} through BLAS), L {int(np.sum(m * w))} entries packed")
    print(f"multiply-adds (M): pivot blocks {pivot.sum() / 1e6:.1f}, "
          f"rows below {below.sum() / 1e6:.1f}, updates {update.sum() / 1e6:.1f}; "
          f"total {total.sum() / 1e6:.1f}, of which caused by N "
          f"{by_N.sum() / 1e6:.1f} ({100 * by_N.sum() / total.sum():.0f} %); extend-add entries "
          f"{np.sum((u * (u + 1) / 2.0)[tparent >= 0]) / 1e6:.1f} M")
    moved = _entries_moved(lower, symbolic)
    print("| front rows | fronts | multiply-adds (M) | N's share | median width | entries moved "
          "(M): zeroed, own, extend-add in, packed, update out | multiply-adds per entry moved |\n"
          "|---|---|---|---|---|---|---|")
    for lo, hi in ((0, 64), (64, 128), (128, 256), (256, 512), (512, 1 << 40)):
        at = (m >= lo) & (m < hi)
        if at.any():
            each = moved[:, at].sum(axis=1)
            print(f"| {lo}-{hi if hi < 1 << 40 else ''} | {int(at.sum())} "
                  f"| {total[at].sum() / 1e6:.1f} "
                  f"| {100 * by_N[at].sum() / total[at].sum():.0f} % | {np.median(w[at]):.0f} "
                  f"| {', '.join(f'{x / 1e6:.2f}' for x in each)} "
                  f"| {total[at].sum() / each.sum():.1f} |")
    times = {"BLAS fronts": np.inf, "loops only": np.inf}
    for _ in range(repeat):
        for name, limits in (("BLAS fronts", (ldl.BLAS_MIN_WIDTH, ldl.BLAS_MIN_ROWS)),
                             ("loops only", (1 << 40, 1 << 40))):
            t = _best(lambda: ldl._numeric(lower, condensed.copy(), symbolic, 1, *limits,
                                                   share_front=True), 1)[0]
            times[name] = min(times[name], t)
    parts = _parts(lower, condensed, symbolic, repeat)
    shapes = []   # (rows, inner, columns) of each product the BLAS fronts make
    for t in np.flatnonzero(blas):
        c0 = 0
        while c0 < w[t]:
            b = min(ldl.PANEL, w[t] - c0)
            n_below = m[t] - c0 - b
            shapes += [(min(ldl.SOLVE_BLOCK, b - s0), s0, n_below)
                       for s0 in range(ldl.SOLVE_BLOCK, b, ldl.SOLVE_BLOCK)]
            shapes += [(min(i0 + ldl.UPDATE_BLOCK, n_below) - i0, b,
                        min(i0 + ldl.UPDATE_BLOCK, n_below))
                       for i0 in range(0, n_below, ldl.UPDATE_BLOCK)]
            c0 += b
    rng = np.random.default_rng(0)
    operands = [(rng.random((a, k)), rng.random((c, k)).T) for a, k, c in shapes]
    t_dot = _best(lambda: [np.dot(x, y) for x, y in operands], repeat)[0]
    products = sum(a * k * c for a, k, c in shapes)
    print(f"numeric CPU: {1e3 * times['BLAS fronts']:.1f} ms with the BLAS fronts "
          f"({total.sum() / times['BLAS fronts'] / 1e9:.1f} G multiply-adds/s), "
          f"{1e3 * times['loops only']:.1f} ms by loops alone; numpy dot alone on the BLAS "
          f"fronts' {len(shapes)} product shapes ({products / 1e6:.1f} M multiply-adds): "
          f"{1e3 * t_dot:.1f} ms ({products / t_dot / 1e9:.1f} G/s)")
    first_cpu, second_cpu, top_cpu, front_cpu, walls, line = parts
    print(f"the parts of a refactorisation (ldl.LDLSymbolic.parts), thread CPU in one thread: "
          f"{1e3 * first_cpu:.1f} and {1e3 * second_cpu:.1f} ms beside each other, then the top "
          f"{1e3 * top_cpu:.1f} ms and its last front shared by the two threads "
          f"({1e3 * front_cpu:.1f} ms in one); wall in one thread {1e3 * walls[1]:.1f} ms, in "
          f"two {1e3 * walls[2]:.1f} ms (at this load)")
    if line:
        ms = {k: 1e3 * v for k, v in line.items()}
        path = max(first_cpu, second_cpu) + top_cpu + line["front_path"]
        print(f"two threads, where the wall goes (median ms): set-up {ms['setup']:.2f}, the "
              f"parts {ms['first']:.2f} and {ms['second']:.2f} (the later ends "
              f"{ms['imbalance']:.2f} after), to the top {ms['to_top']:.2f}, the top "
              f"{ms['top']:.2f}, to the shared front {ms['to_front']:.2f}, the front "
              f"{ms['front']:.2f} (its halves' path {ms['front_path']:.2f}, lost to "
              f"{line['meetings']:.0f} meetings {ms['front'] - ms['front_path']:.2f}), the end "
              f"{ms['end']:.2f}: wall {ms['wall']:.2f} against "
              f"the threads' path {1e3 * path:.2f} (the parts and the top's thread CPU in one "
              f"thread, the front's halves in two); {line['faults']:.0f} minor page faults a "
              f"factorisation")

def _entries_moved(lower, symbolic):
    """Entries each front's passes over memory touch in a numeric factorisation
    (``ldl._eliminate``), rows: its lower triangle zeroed, the matrix's own entries of its
    columns added, its children's updates added (extend-add), its packed L written, its update
    copied out (to the stack, or added into the condensed block); columns: the supernodes."""
    first, width, row_at = symbolic.tree[:3]
    m = np.diff(row_at)
    u = m - width
    own = lower.indptr[first + width] - lower.indptr[first]
    child_in = np.zeros(len(m))
    for t in range(len(m)):
        kids = symbolic.child_list[symbolic.child_ptr[t]:symbolic.child_ptr[t + 1]]
        child_in[t] = np.sum(u[kids] * (u[kids] + 1) / 2.0)
    return np.array([m * (m + 1) / 2.0, own, child_in, width * (width + 1) / 2.0 + u * width,
                     u * (u + 1) / 2.0])


def _front_halves(stamps):
    """From the shared front's clock stamps of a two-thread factorisation
    (``ldl._front_by_halves``: each half's start, each meeting's arrival and departure, its
    end): (its wall from the first half's start, its path: per stretch between meetings the
    longer half's, meetings). The wall less the path is what the halves lost to meeting (a
    half noticing the other's arrival late). The second half starts earlier, after its part of
    the tree, and waits at the first meeting."""
    t = stamps[:, 0::2] + 1e-9 * stamps[:, 1::2]   # (s)
    meetings = (t.shape[1] - 2) // 2
    begin = np.concatenate([t[:, :1], t[:, 2:-1:2]], axis=1)   # (each stretch's start, end)
    end = np.concatenate([t[:, 1:-1:2], t[:, -1:]], axis=1)
    path = float(np.sum(np.max(end - begin, axis=0)))
    return float(t[:, -1].max() - t[0, 0]), path, meetings


def _parts(lower, condensed, symbolic, repeat):
    """The numeric factorisation's parts, the least of ``repeat`` runs each: in one thread each
    part's thread CPU time (the first part, the second, the top less a shared front, that
    front); the wall time in one and in two threads; and of the two-thread runs the median
    timeline (ms): the set-up before the parts (allocations, buffers, the second thread's
    start), each part's wall and the later one's lead (imbalance), from the later end to the
    top, the top, from it to the shared front, the front's wall and its path
    (``_front_halves``), the end (after the front), and the minor page faults of the process
    per factorisation."""
    from fault_screen import ldl

    names = ("_eliminate", "_front_by_halves", "_await_part", "_front_buffers")
    saved, log = {name: getattr(ldl, name) for name in names}, []

    def timed(name):
        def call(*args):
            w0, t0 = time.perf_counter(), time.thread_time()
            try:
                return saved[name](*args)
            finally:
                log.append((name, threading.get_ident() == caller, w0, time.perf_counter(),
                            time.thread_time() - t0))
        return call

    caller = threading.get_ident()
    best = [np.inf] * 4
    timeline = []
    for name in names:
        setattr(ldl, name, timed(name))
    try:
        for _ in range(repeat):
            log.clear()
            ldl._numeric(lower, condensed.copy(), symbolic, 1, share_front=True)
            parts = [e[4] for e in log if e[0] == "_eliminate"]
            front = sum(e[4] for e in log if e[0] == "_front_by_halves")
            best = [min(b, t) for b, t in zip(best, parts[:2] + [sum(parts[2:]), front])]
        for _ in range(max(repeat, 5)):
            log.clear()
            schur = condensed.copy()   # (not in the timeline: the caller's array)
            faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            w0 = time.perf_counter()
            ldl._numeric(lower, schur, symbolic, 2, share_front=True)
            w1 = time.perf_counter()
            faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
            runs = [e for e in log if e[0] == "_eliminate"]
            own, other = ([e for e in runs if e[1] == mine] for mine in (True, False))
            if len(own) < 2 or not other:
                continue
            halves = [e for e in log if e[0] == "_front_by_halves" and e[1]]
            top_end = own[-1][3]
            front = _front_halves(symbolic.front_stamps) if halves else (0.0, 0.0, 0)
            timeline.append(dict(
                setup=min(own[0][2], other[0][2]) - w0,
                first=own[0][3] - own[0][2], second=other[0][3] - other[0][2],
                imbalance=abs(own[0][3] - other[0][3]),
                to_top=own[1][2] - max(own[0][3], other[0][3]), top=own[1][3] - own[1][2],
                to_front=(halves[0][2] - top_end) if halves else 0.0,
                front=front[0], front_path=front[1],
                end=w1 - (halves[0][3] if halves else top_end), wall=w1 - w0, faults=faults,
                meetings=front[2]))
    finally:
        for name, fn in saved.items():
            setattr(ldl, name, fn)
    walls = {}
    for threads in (1, 2):
        walls[threads] = np.inf
        for _ in range(repeat):
            schur = condensed.copy()
            t0 = time.perf_counter()
            ldl._numeric(lower, schur, symbolic, threads, share_front=True)
            walls[threads] = min(walls[threads], time.perf_counter() - t0)
    median = ({k: float(np.median([r[k] for r in timeline])) for k in timeline[0]}
              if timeline else {})
    return (*best, walls, median)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), choices=SCENES)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--fronts", action="store_true",
                        help="where the numeric LDL^T's work goes (see the docstring), "
                             "printed only")
    args = parser.parse_args(argv)
    from threadpoolctl import threadpool_limits

    if args.fronts:
        load0 = os.getloadavg()[0]
        for key in args.scenes:
            with threadpool_limits(limits=1, user_api="blas"):
                fronts(key, args.repeat)
        print(f"\nload average {load0:.1f} before, {os.getloadavg()[0]:.1f} after")
        return

    load0 = os.getloadavg()[0]
    rows = []
    for key in args.scenes:
        with threadpool_limits(limits=1, user_api="blas"):
            rows += measure(key, args.repeat)
        print(table([r for r in rows if r["scene"] == key]), flush=True)
    text = table(rows)
    print(f"\nload average {load0:.1f} before, {os.getloadavg()[0]:.1f} after")
    if not args.no_write:
        from doc_tables import write

        path = write("factorisation", "Factorisations of the free system",
                     "Every row factorises the same scaled matrix of the scene at that step size; "
                     "see the script's docstring for the methods and columns. Times are the "
                     "process's CPU times with one BLAS thread (least of the repeats), which a "
                     "busy machine inflates less than wall times.", text.splitlines(), load0)
        print(f"written {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
