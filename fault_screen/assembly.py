"""Generic sparse assembly: local arrays plus local-to-global maps -> global COO triplets.

A map entry of -1 means "no unknown here" (a DOF that the scene does not create, or a fixed
one); such rows and columns are skipped, so switched-off effects cost nothing downstream.
"""
import numpy as np
import scipy.sparse as sp

from ._jit import kernel


@kernel
def scatter_matrices(local, row_map, col_map):
    """``local`` (n, nr, nc) with maps (n, nr), (n, nc) -> (rows, cols, vals) of kept entries."""
    n, nr, nc = local.shape
    rows = np.empty(n * nr * nc, dtype=np.int64)
    cols = np.empty(n * nr * nc, dtype=np.int64)
    vals = np.empty(n * nr * nc)
    k = 0
    for e in range(n):
        for a in range(nr):
            r = row_map[e, a]
            if r < 0:
                continue
            for b in range(nc):
                c = col_map[e, b]
                if c < 0:
                    continue
                v = local[e, a, b]
                if v == 0.0:
                    continue
                rows[k] = r
                cols[k] = c
                vals[k] = v
                k += 1
    return rows[:k], cols[:k], vals[:k]


class TripletBuilder:
    """Collects COO blocks and turns them into one CSR matrix (duplicates summed)."""

    def __init__(self, n: int):
        self.n = n
        self._rows, self._cols, self._vals = [], [], []

    def add(self, local, row_map, col_map, scale: float = 1.0):
        if local.shape[0] == 0:
            return
        r, c, v = scatter_matrices(np.ascontiguousarray(local, dtype=np.float64),
                                   np.ascontiguousarray(row_map, dtype=np.int64),
                                   np.ascontiguousarray(col_map, dtype=np.int64))
        self._rows.append(r)
        self._cols.append(c)
        self._vals.append(v * scale)

    def tocsr(self) -> sp.csr_matrix:
        if not self._rows:
            return sp.csr_matrix((self.n, self.n))
        rows = np.concatenate(self._rows)
        cols = np.concatenate(self._cols)
        vals = np.concatenate(self._vals)
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.n, self.n))
