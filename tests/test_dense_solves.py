"""Dense Newton solves (hfdi.linsolve.dense): Cholesky for tangents symmetric
to rounding (from CHOLESKY_FROM rows on), LU otherwise.

The solve is one function run at both speeds: as plain Python it calls
scipy's LAPACK wrappers, compiled it calls the same routines of the same
library. Both take the same route (the same routine on the same triangle)
and give the same solution bit for bit, whatever the matrix: symmetric
positive definite, symmetric to rounding, symmetric but indefinite (Cholesky
fails, LU follows), not symmetric, singular, not finite.
"""
from __future__ import annotations

import numpy as np
import pytest

from hfdi.linsolve import dense
from hfdi.linsolve.dense import CHOLESKY_FROM, SYMMETRY_TOLERANCE, work_ints


def solve(a, b, solver=dense.solve):
    """``a⁻¹ b`` by ``solver`` (the solve or its compiled twin), or ``None``
    where it reports a singular or non-finite matrix."""
    n = a.shape[0]
    x = np.array(b, dtype=float)
    ok = solver(np.ascontiguousarray(a, dtype=float), x, np.zeros((n, n)),
                np.zeros(n, np.int32), work_ints())
    return x if ok else None


def is_symmetric(a, test=dense.symmetric):
    return bool(test(np.ascontiguousarray(a, dtype=float), np.empty(a.shape[0])))


def compiled(function):
    pytest.importorskip("numba")
    from hfdi.core.jit import twin
    return twin(function)


def _spd(n, rng, scale=1.0):
    x = rng.standard_normal((n, n))
    return scale * (x @ x.T + n * np.eye(n))


def _indefinite(n, rng):
    a = _spd(n, rng)
    a[n // 2, n // 2] = -10.0 * n * n          # a negative pivot: not positive definite
    return a


def _overflowing(n):
    """Finite, its difference from its transpose not (inf: not symmetric)."""
    a = np.eye(n)
    a[0, 1], a[1, 0] = 1.5e308, -1.5e308
    return a


def _at_tolerance(rng, n, past):
    """Symmetric positive definite but for one pair, which differs by the
    limit of :func:`hfdi.linsolve.dense.symmetric` (the largest float difference
    within it), or ``past`` it by the least step of a float."""
    a = _spd(n, rng)
    limit = SYMMETRY_TOLERANCE * (np.sqrt(abs(a[4, 4])) * np.sqrt(abs(a[2, 2])))
    a[4, 2] = a[2, 4] + limit
    while abs(a[4, 2] - a[2, 4]) > limit:
        a[4, 2] = np.nextafter(a[4, 2], -np.inf)
    if past:
        while abs(a[4, 2] - a[2, 4]) <= limit:
            a[4, 2] = np.nextafter(a[4, 2], np.inf)
    return a


def _cases():
    rng = np.random.default_rng(7)
    spd = _spd(21, rng)
    rounded = spd.copy()
    rounded[3, 5] *= 1.0 + 1e-14                # symmetric to rounding
    skewed = spd.copy()
    skewed[3, 5] *= 1.0 + 1e-9                  # not symmetric
    return {
        "spd": (spd, "potrf"),
        "spd_tiny": (_spd(10, rng, 1e-200), "potrf"),
        "spd_huge": (_spd(10, rng, 1e200), "potrf"),
        "spd_below_the_cholesky_size": (_spd(CHOLESKY_FROM - 1, rng), "gesv"),
        "one": (np.array([[4.0]]), "gesv"),
        "symmetric_to_rounding": (rounded, "potrf"),
        "indefinite": (_indefinite(12, rng), "potrf+gesv"),
        "not_symmetric": (skewed, "gesv"),
        "general": (rng.standard_normal((9, 9)), "gesv"),
        "overflowing_difference": (_overflowing(12), "gesv"),
        "at_the_tolerance": (_at_tolerance(rng, 12, False), "potrf"),
        "just_past_the_tolerance": (_at_tolerance(rng, 12, True), "gesv"),
    }


CASES = _cases()


def _routes(monkeypatch):
    """Record which LAPACK routines the Python solve calls."""
    called = []
    for name in ("_potrf", "_gesv"):
        routine = getattr(dense, name)

        def spy(*args, _routine=routine, _name=name, **kwargs):
            called.append(_name[1:])
            return _routine(*args, **kwargs)
        monkeypatch.setattr(dense, name, spy)
    return called


@pytest.mark.parametrize("name", list(CASES))
def test_the_route_follows_symmetry_and_definiteness(name, monkeypatch):
    a, route = CASES[name]
    b = np.arange(1.0, a.shape[0] + 1.0)
    called = _routes(monkeypatch)
    x = solve(a, b)
    assert "+".join(called) == route
    want = np.linalg.solve(a, b)
    # backward error at the level of rounding, whichever route; Cholesky
    # solves with the lower triangle, which differs from a by its asymmetry
    with np.errstate(over="ignore", invalid="ignore"):
        asymmetry = np.abs(a - a.T).max() / np.abs(a).max() if route == "potrf" else 0.0
    residual = np.abs(a @ x - b).max() / np.abs(a).max() / np.abs(x).max()
    assert residual < 1e-14 + 2.0 * asymmetry
    np.testing.assert_allclose(x, want, rtol=1e-9 * np.linalg.cond(a), atol=0)


def test_is_symmetric_holds_each_pair_to_its_own_rows():
    a = np.array([[1.0, 2.0], [2.0, 9.0]])
    assert is_symmetric(a)
    for delta, expected in ((2.9e-12, True), (3.1e-12, False)):
        b = a.copy()
        b[0, 1] += delta                       # √1 · √9 = 3: limit 3e-12
        assert is_symmetric(b) is expected
    # a stiff entry does not widen the limit of a soft coupling
    stiff = np.eye(10)
    stiff[0, 0] = 1e10
    stiff[1, 2] = 1e-9
    assert not is_symmetric(stiff)
    stiff[1, 2] = stiff[2, 1] = 0.5
    stiff[2, 1] += 1e-13
    assert is_symmetric(stiff)
    assert is_symmetric(np.zeros((3, 3)))
    for bad in (np.nan, np.inf):
        b = a.copy()
        b[0, 1] = b[1, 0] = bad
        assert not is_symmetric(b)


def test_a_soft_asymmetry_beside_a_stiff_entry_is_solved_exactly():
    a = np.eye(10)
    a[0, 0] = 1e10
    a[1, 2] = 0.009                            # a true asymmetry, not rounding
    b = np.arange(1.0, 11.0)
    np.testing.assert_allclose(solve(a, b), np.linalg.solve(a, b), rtol=1e-14)


@pytest.mark.slow
def test_singular_and_non_finite_matrices_fail_at_both_speeds():
    for a in (np.zeros((3, 3)), np.ones((12, 12)),     # the second symmetric, rank one
              np.array([[1.0, np.nan], [np.nan, 1.0]]), np.array([[np.inf, 0.0], [0.0, 1.0]])):
        assert solve(a, np.ones(a.shape[0])) is None
        assert solve(a, np.ones(a.shape[0]), compiled(dense.solve)) is None


# -- the compiled path --------------------------------------------------------------------

@pytest.mark.slow                               # compiles the solve
@pytest.mark.parametrize("name", list(CASES))
def test_the_compiled_solve_is_the_python_solve_bit_for_bit(name):
    a, _ = CASES[name]
    b = np.linspace(-1.0, 2.0, a.shape[0])
    np.testing.assert_array_equal(solve(a, b, compiled(dense.solve)), solve(a, b))


def test_the_compiled_symmetry_test_decides_as_the_python_one():
    symmetric = compiled(dense.symmetric)
    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 21):
        for _ in range(300):
            a = rng.standard_normal((n, n)) * 10.0 ** rng.integers(-300, 300)
            a = a + a.T
            a[np.diag_indices(n)] *= 10.0 ** rng.integers(-8, 9, n)   # rows of other scales
            i, j = rng.integers(0, n, 2)
            a[i, j] *= 1.0 + rng.choice([0.0, 1e-13, 9.9e-13, 1.01e-12, 1e-11, 1e-3, -2.0])
            assert is_symmetric(a, symmetric) == is_symmetric(a)
    for a in (_overflowing(12), _at_tolerance(rng, 12, False), _at_tolerance(rng, 12, True)):
        assert is_symmetric(a, symmetric) == is_symmetric(a)


def test_the_finiteness_tests_agree_with_numpy_at_both_speeds():
    """The compiled tests read the floats' exponent bits (vectors and C-ordered
    matrices, as the stepping code holds them)."""
    from hfdi.core.arrays import all_finite, all_finite_matrix
    tests = (all_finite, all_finite_matrix, compiled(all_finite), compiled(all_finite_matrix))
    rng = np.random.default_rng(5)
    base = rng.standard_normal((9, 14))
    for bad in (None, np.nan, np.inf, -np.inf):
        for where in range(0, base.size, 11):
            a = base.copy()
            if bad is not None:
                a.flat[where] = bad
            want = bad is None
            for test in tests[1::2]:
                assert test(a) == want, (bad, where)
            for row in a:
                for test in tests[::2]:
                    assert test(row) == bool(np.all(np.isfinite(row))), (bad, where)
    for test in tests[::2]:
        assert test(np.array([1.7976931348623157e308, -5e-324, -0.0]))
        assert test(np.empty(0))
    for test in tests[1::2]:
        assert test(np.empty((0, 4)))


def test_a_difference_that_overflows_is_not_symmetric_and_warns_nothing():
    import warnings
    a = np.array([[1.0, 1.5e308], [-1.5e308, 1.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not is_symmetric(a)
        assert not is_symmetric(np.array([[1.0, np.inf], [np.inf, 1.0]]))
