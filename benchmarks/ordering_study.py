"""Fill-reducing orders of the bulk against the fault's border (``fault_screen/ordering.py``).

    python benchmarks/ordering_study.py                          # counts, every scene (~1 min)
    python benchmarks/ordering_study.py --scenes rustrel-paper --time 7

The condensed (fault) unknowns N are never eliminated: every front whose subtree holds a bulk
unknown coupled to N carries N's rows up to the root. For each scene the symbolic L D L^T of its
scaled free matrix (the bulk B in the order of each row, N last) is counted (``ldl.LDLSymbolic``,
pattern only, nothing numeric):

- ``nested dissection``: ``ordering.nested_dissection`` as the solver calls it on main;
- ``fault into the first separator``: the same with ``fault_coupling`` (the number of N unknowns
  each bulk unknown couples to): where the fault runs along the first cut, its cut elements'
  unknowns beside the first separator join it;
- ``every coupled unknown beside it``: as the last, with every bulk unknown coupled to N taken
  as the fault's (also those that couple only to the fault's pressure by leak-off): a wider top
  front for fewer N rows below;
- ``..., largest child last``: the nested dissection's order (the first or the second row's)
  re-walked along its elimination tree with each node's children by subtree size, the largest
  last (next to its parent: the amalgamation (``ldl._amalgamate``) can merge along that chain;
  it loses the split of the first cut, which a bulk factorised in parts needs).

Columns: multiply-adds of the numeric factorisation (``ldl.front_multiply_adds``) and the part
that N's rows cause (as ``benchmarks/factorisation.py --fronts`` counts it), L's entries, the
supernodes (of them one column wide), the fronts with N rows, and the two-thread plan
(``ldl.LDLSymbolic.parts``): the multiply-adds of its two parts and of the top, and its path
(the larger part plus the top).

``--time R``: also the numeric factorisation of the matrix at dt = 600 s on each order,
interleaved R times in this one process (least of each): its CPU time in one thread
(``ldl.THREADS_ABOVE`` raised), and the wall and CPU time in two threads as the solver runs it
(a refactorisation: the symbolic analysis made before), and the entries of its factors
(``ldl.factorise``'s L entries; a split bulk's ``SplitBorderedLU.nnz``). A bulk that the solver factorises in
parts (``bordered_lu.SplitBorderedLU``, 200 x 201) is timed so (its parts one after the other),
and on the first two orders also as one L D L^T of the whole bulk (``(whole ..., not split)``),
as a smaller bulk is. On a shared machine compare rows of one run.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # (small dense work: one BLAS thread)

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
SCENES = ("rustrel-paper", "rustrel", "fine-T0.7-dip30", "rustrel-200x201")
STEP_SIZE = 600.0


def scene_matrix(key):
    """(S, nB, coordinates of B, N's coupling of B): the scaled symmetric free matrix at
    STEP_SIZE with B in its natural order, then N."""
    from factorisation import _scene
    from fault_screen import Simulation

    sim = Simulation(_scene(key))
    solver, disc = sim.solver, sim.disc
    contact = disc.physics.contact
    history = contact.initial_history(disc) if contact is not None else None
    solver._prepare(STEP_SIZE, np.zeros(disc.n_dofs), history)
    system = solver.system
    free = np.concatenate([system.B, system.N])
    nB = len(system.B)
    mech = np.zeros(disc.n_dofs, dtype=bool)
    mech[disc.blocks.u] = True
    mech[disc.blocks.a] = True
    D = sp.diags(system.scale)
    M = (D @ system._linear_jacobian(STEP_SIZE) @ D).tocsr()[free][:, free]
    E = np.ones(len(free)) if system.factors_any_dt else np.where(mech[free], 1.0, -STEP_SIZE)
    S = (sp.diags(E) @ M).tocsc()
    coupling = np.diff(S[:nB, nB:].tocsr().indptr)
    return S, nB, disc.dof_coordinates()[system.B], coupling


def orders(S, nB, xy, coupling):
    """name -> (B's order, its split as ``bordered_lu`` takes it) for each order studied."""
    from fault_screen.bordered_lu import split_layout
    from fault_screen.ordering import nested_dissection

    pattern = S[:nB, :nB]

    def nd(**extra):
        inner, split, quarters = nested_dissection(pattern, xy, return_split=True,
                                                   return_quarters=True, **extra)
        layout, split = split_layout(nB, split, quarters)
        return (inner if layout is None else inner[layout]), split

    out = {"nested dissection": nd(),
           "fault into the first separator": nd(fault_coupling=coupling),
           "every coupled unknown beside it": nd(fault_coupling=np.where(coupling > 0, 1, 0))}
    for name in ("nested dissection", "fault into the first separator"):
        out[f"{name}, largest child last"] = (_largest_child_last(S, nB, out[name][0]), None)
    return out


def _permuted(S, nB, inner):
    perm = np.concatenate([inner, np.arange(nB, S.shape[0])])
    return S[perm][:, perm].tocsc()


def _largest_child_last(S, nB, inner):
    """``inner`` re-walked depth first along its elimination tree, each node's children by the
    size of their subtrees, the largest last."""
    from fault_screen import ldl

    upper = ldl._lower(_permuted(S, nB, inner), nB).T.tocsc()
    upper.sort_indices()
    parent = ldl._etree(upper.indptr, upper.indices.astype(np.int64), nB)
    size = np.ones(nB, dtype=np.int64)
    for j in range(nB):   # (a parent comes after its children)
        if parent[j] != -1:
            size[parent[j]] += size[j]
    kids = [[] for _ in range(nB)]
    for j in range(nB):
        if parent[j] != -1:
            kids[parent[j]].append(j)
    walk = []
    stack = [(j, False) for j in sorted(np.flatnonzero(parent == -1), key=lambda j: -size[j])]
    while stack:
        j, children_done = stack.pop()
        if children_done:
            walk.append(j)
            continue
        stack.append((j, True))
        stack += [(c, False) for c in sorted(kids[j], key=lambda c: (-size[c], c))]
    return inner[np.asarray(walk, dtype=np.int64)]


def counts(S, nB, inner):
    """The symbolic L D L^T's counts in the order ``inner`` (see the module docstring)."""
    from fault_screen import ldl

    symbolic = ldl.LDLSymbolic(ldl._lower(_permuted(S, nB, inner), nB), nB)
    first, width, row_at, srows, tparent = symbolic.tree[:5]
    u = np.diff(row_at) - width
    m_N = np.add.reduceat((srows >= nB).astype(np.int64), row_at[:-1])
    total = np.sum(ldl.front_multiply_adds(width, u), axis=0)
    by_N = m_N * width * width / 2.0 + width * (m_N * (u - m_N) + m_N * (m_N + 1) / 2.0)
    parts = [float(total[p].sum()) for p in symbolic.parts]
    return dict(total=total.sum(), by_N=by_N.sum(), nnz=symbolic.nnz, supernodes=len(width),
                one_column=int(np.sum(width == 1)), with_N=int(np.sum(m_N > 0)), parts=parts,
                path=max(parts[:2]) + parts[2])


def count_table(key, S, nB, made):
    print(f"\n{key}: bulk {nB} unknowns, N {S.shape[0] - nB}, "
          f"{int(np.count_nonzero(S[:nB, nB:].getnnz(axis=1)))} bulk unknowns coupled to N")
    print("| order | multiply-adds (M) | N's share | L entries | supernodes (1 column) "
          "| fronts with N rows | two-thread parts + top (M) | path (M) | split |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, (inner, split) in made.items():
        c = counts(S, nB, inner)
        parts = " + ".join(f"{p / 1e6:.1f}" for p in c["parts"])
        print(f"| {name} | {c['total'] / 1e6:.1f} | {100 * c['by_N'] / c['total']:.0f} % "
              f"| {c['nnz']:,} | {c['supernodes']} ({c['one_column']}) | {c['with_N']} "
              f"| {parts} | {c['path'] / 1e6:.1f} | {split} |")


def time_table(S, nB, made, repeat):
    """The numeric factorisation's times on each order, interleaved (see --time)."""
    from fault_screen import ldl
    from fault_screen.bordered_lu import SPLIT_ABOVE, bordered_lu

    runs, entries = {}, {}
    for k, (name, (inner, split)) in enumerate(made.items()):
        M = _permuted(S, nB, inner)
        lower, condensed = ldl._lower(M, nB), M[nB:, nB:].toarray()
        whole = (lambda lower=lower, condensed=condensed, analyses=ldl.SymbolicAnalyses():
                 ldl.factorise_lower(lower, condensed.copy(), nB, analyses)[3])
        if split is not None and nB > SPLIT_ABOVE:
            runs[name] = (lambda M=M, split=split, analyses=ldl.SymbolicAnalyses():
                          bordered_lu(M, nB, split, analyses).nnz)
            if k < 2:
                runs[f"{name} (whole L D L^T, not split)"] = whole
        else:
            runs[name] = whole
    names = list(runs)
    for name, run in runs.items():
        run()   # (the symbolic analysis, then a refactorisation: the shared front's kernel)
        entries[name] = run()
    best = {(name, how): np.inf for name in names for how in ("1 CPU", "2 wall", "2 CPU")}
    threads_above = ldl.THREADS_ABOVE
    for _ in range(repeat):
        for name in names:
            try:
                ldl.THREADS_ABOVE = np.inf
                t0 = time.process_time()
                runs[name]()
                best[name, "1 CPU"] = min(best[name, "1 CPU"], time.process_time() - t0)
            finally:
                ldl.THREADS_ABOVE = threads_above
            t0, c0 = time.perf_counter(), time.process_time()
            runs[name]()
            best[name, "2 wall"] = min(best[name, "2 wall"], time.perf_counter() - t0)
            best[name, "2 CPU"] = min(best[name, "2 CPU"], time.process_time() - c0)
    print(f"\nnumeric factorisation at dt = {STEP_SIZE:g} s, least of {repeat} interleaved (ms):")
    print("| order | one thread CPU | two threads wall | two threads CPU | factors' entries |")
    print("|---|---|---|---|---|")
    for name in names:
        print(f"| {name} | {1e3 * best[name, '1 CPU']:.1f} | {1e3 * best[name, '2 wall']:.1f} "
              f"| {1e3 * best[name, '2 CPU']:.1f} | {entries[name]:,} |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    parser.add_argument("--time", type=int, default=0, metavar="R",
                        help="also time the numeric factorisation, R interleaved runs")
    args = parser.parse_args(argv)
    for key in args.scenes:
        S, nB, xy, coupling = scene_matrix(key)
        made = orders(S, nB, xy, coupling)
        count_table(key, S, nB, made)
        if args.time:
            time_table(S, nB, made, args.time)


if __name__ == "__main__":
    main()
