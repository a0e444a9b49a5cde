"""The step's fused passes (``solver``'s kernels that replaced several numpy passes): the same
floats as the numpy they replaced, bit for bit (the solver's bit-for-bit results rest on it)."""
import numpy as np
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

finite_or_not = st.floats(width=64, allow_subnormal=True)


@settings(deadline=None)   # (the first call loads the kernel)
@given(st.integers(1, 300), st.integers(0, 12), st.floats(0.0, 0.5), st.integers(0, 2**32 - 1),
       st.lists(finite_or_not, max_size=4))
def test_update_through_columns_gives_the_floats_of_a_csc_product_added(n, m, density, seed, odd):
    """base + M dN for a few CSC columns M (the reference products brought up to date through
    the condensed unknowns): bit for bit ``base + M @ dN`` as scipy makes it, on random
    patterns with duplicate-free columns, empty columns and rows, and infinities or NaN in dN."""
    from fault_screen.solver import _columns_on, _updated_through_columns

    rng = np.random.default_rng(seed)
    M = sp.random(n, m, density=density, format="csc", random_state=rng) * 1e3
    dN = rng.normal(size=m)
    dN[:len(odd)] = odd[:m]
    base = rng.normal(size=n) * 10.0 ** rng.integers(-5, 5, size=n)
    with np.errstate(all="ignore"):
        expected = base + M @ dN
        got = _updated_through_columns(base, *_columns_on(M), dN)
    assert np.array_equal(got, expected, equal_nan=True)
    assert got is not base and np.array_equal(base, base)   # (base not changed in place)


def _reference_norms_by_vectors(scale, AHx, Cd, dt, flow_known, mech_at, flow_at):
    """The passes the fused kernel replaced: the entries' vectors, then ``_norm_at`` of each."""
    from fault_screen.solver import _norm_at

    n = len(scale)
    mech = np.zeros(n)
    flow = np.zeros(n)
    mech[mech_at] = scale[mech_at] * AHx[mech_at]
    flow[flow_at] = scale[flow_at] * (np.abs(Cd[flow_at]) / dt + np.abs(AHx[n + flow_at])
                                      + flow_known[flow_at])
    return _norm_at(mech, mech_at)[0], _norm_at(flow, flow_at)[0]


@settings(deadline=None)
@given(st.integers(1, 200), st.integers(0, 2**32 - 1), st.sampled_from([1e-200, 1.0, 1e200]),
       st.lists(st.tuples(st.integers(0, 10**6), finite_or_not), max_size=3))
def test_reference_norms_fused_give_the_floats_of_the_vectors_norms(n, seed, size, odd):
    """The convergence test's reference magnitudes made where each entry's square is summed:
    equal to the bit to the vectors of entries and their ``_norm_at`` (the overflow and
    underflow guard included: magnitudes 1e-200 and 1e200), inf where an entry is not finite."""
    from fault_screen.solver import _reference_norms

    rng = np.random.default_rng(seed)
    scale = rng.uniform(0.1, 10.0, size=n)
    AHx = rng.normal(size=2 * n) * size
    Cd = rng.normal(size=n) * size
    flow_known = np.abs(rng.normal(size=n)) * size
    for k, v in odd:
        AHx[k % (2 * n)] = v
    order = rng.permutation(n)
    mech_at, flow_at = np.sort(order[: n // 2]), np.sort(order[n // 2:])
    with np.errstate(all="ignore"):
        expected = _reference_norms_by_vectors(scale, AHx, Cd, 5.0, flow_known, mech_at, flow_at)
        got = _reference_norms(scale, AHx, Cd, 5.0, flow_known, mech_at, flow_at)
    assert np.array_equal(np.array(got), np.array(expected), equal_nan=True)
    vectors = (scale[mech_at] * AHx[mech_at],
               scale[flow_at] * (np.abs(Cd[flow_at]) / 5.0 + np.abs(AHx[n + flow_at])
                                 + flow_known[flow_at]))
    for value, v in zip(got, vectors):
        if not np.all(np.isfinite(v)):
            assert value == np.inf
        elif len(v) and np.max(np.abs(v)) > 0:
            # the norm to round-off at any magnitude (squares that over- or underflow rescaled)
            largest = np.max(np.abs(v))
            assert abs(value - largest * np.linalg.norm(v / largest)) <= 1e-13 * value
