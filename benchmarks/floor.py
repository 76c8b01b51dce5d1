"""The floor: what one Newton correction cannot avoid, timed on the library's own code.

A correction of a stage evaluates the model's internal force ``f(u)`` and its
tangent ``K(u)`` and solves one dense linear system; HFDI's stage (Eq. 21)
also evaluates ``T(u)[v_D]`` and forms the product ``S B⁻¹ S``. The floor of
a scheme on a model is the sum of those unit costs, each timed in a compiled
loop that calls

* the model's own compiled kernels (``compiled_kernels()``, as
  :func:`hfdi.compiled.kernels_of` gives them), and
* the dense solve of the stepping code, :func:`hfdi.linsolve.dense.solve`
  (Cholesky for a tangent symmetric to rounding from
  :data:`~hfdi.linsolve.dense.CHOLESKY_FROM` rows on, else LU), in its
  compiled form, on work arrays allocated once, as the stepping code does;

with nothing of the step restated here. What the library's compiled path
costs per Newton iteration above the floor is its predictor, residual and
tangent assembly, checks, error estimate, controller and energy balance
(docs/compiled.md). The floor is a cost per correction; a step costs it
times the run's corrections per step.

:func:`unit_costs` gives the unit costs (µs per call), :func:`floor_us` their
sum for a scheme. ``python -m benchmarks profile --paths`` prints the floor
beside the compiled path's µs per iteration.
"""
from __future__ import annotations

import math
import time

import numpy as np

__all__ = ["unit_costs", "floor_us", "correction_costs", "UNIT_COSTS"]

#: The unit costs :func:`unit_costs` measures (µs per call).
UNIT_COSTS = ("force", "stiffness", "stiffness_derivative", "potential_energy", "solve",
              "product")

_LOOPS = {}


def _loops():
    """The timing loops, compiled on first use (numba imported here)."""
    if _LOOPS:
        return _LOOPS
    from numba import njit

    from hfdi.core.jit import twin
    from hfdi.linsolve.dense import solve as library_solve
    # the stepping code's dense solve as compiled code calls it
    solve = twin(library_solve)

    @njit
    def vector_calls(kernel, u, params, n):
        total = 0.0
        for _ in range(n):
            total += kernel(u, params)[0]
        return total

    @njit
    def matrix_calls(kernel, u, params, n):
        total = 0.0
        for _ in range(n):
            total += kernel(u, params)[0, 0]
        return total

    @njit
    def derivative_calls(kernel, u, w, params, n):
        total = 0.0
        for _ in range(n):
            total += kernel(u, w, params)[0, 0]
        return total

    @njit
    def scalar_calls(kernel, u, params, n):
        total = 0.0
        for _ in range(n):
            total += kernel(u, params)
        return total

    @njit
    def solves(A, b, x, lu, pivots, ints, n):
        total = 0.0
        for _ in range(n):
            x[:] = b
            if not solve(A, x, lu, pivots, ints):
                return math.nan
            total += x[0]
        return total

    @njit
    def products(A, B, out, n):
        total = 0.0
        for _ in range(n):
            np.dot(A, B, out)
            total += out[0, 0]
        return total

    _LOOPS.update(vector_calls=vector_calls, matrix_calls=matrix_calls,
                  derivative_calls=derivative_calls, scalar_calls=scalar_calls, solves=solves,
                  products=products)
    return _LOOPS


def _kernels(model):
    from hfdi.compiled import kernels_of
    kernels, why = kernels_of(model)
    if kernels is None:
        raise ValueError(f"model {getattr(model, 'name', type(model).__name__)!r} has no "
                         f"compiled kernels: {why}")
    return kernels


def unit_costs(model, u, repeats: int = 3, calls: int = 2000) -> dict:
    """µs per call, in compiled loops, of the model's kernels at ``u`` and of
    the dense linear algebra of one Newton correction; best of ``repeats``.

    Parameters
    ----------
    model : SecondOrderSystem
        A model with compiled kernels (``ValueError`` naming the model otherwise).
    u : array_like (N,)
        Where the kernels are evaluated (say the end state of a run).
    repeats, calls : int
        Timed loops (the fastest kept) and calls per loop, each ``>= 1``.

    Returns
    -------
    dict
        The keys of :data:`UNIT_COSTS`: ``force`` ``f(u)``, ``stiffness``
        ``K(u)``, ``stiffness_derivative`` ``T(u)[w]``, ``potential_energy``
        ``V(u)``; ``solve``: :func:`hfdi.linsolve.dense.solve` with an (N, N)
        matrix of ``K(u)``'s pattern and symmetry (``K`` plus a diagonal that
        makes it definite, as a tangent ``c M + K`` is) and one right-hand side;
        ``product``: an (N, N) product into a given array, HFDI's ``S B⁻¹ S``.
    """
    for name, value in (("repeats", repeats), ("calls", calls)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    from hfdi.linsolve.dense import work_ints

    kernels = _kernels(model)
    u = np.ascontiguousarray(u, dtype=float)
    if u.ndim != 1 or u.size != int(model.n_dof) or not np.isfinite(u).all():
        raise ValueError(f"u must be a finite vector of the model's {int(model.n_dof)} "
                         f"entries, got shape {u.shape}")
    loops = _loops()
    n = u.size
    w = np.sin(np.arange(1, n + 1.0))
    p = kernels.params
    K = np.asarray(kernels.stiffness(u, p), dtype=float)
    A = np.ascontiguousarray(K + np.diag(np.abs(K).sum(axis=1) + 1.0))
    x, lu = np.empty(n), np.empty((n, n))
    pivots, ints = np.empty(n, np.int32), work_ints()
    out = np.empty((n, n))
    runs = {"force": lambda m: loops["vector_calls"](kernels.force, u, p, m),
            "stiffness": lambda m: loops["matrix_calls"](kernels.stiffness, u, p, m),
            "stiffness_derivative": lambda m: loops["derivative_calls"](
                kernels.stiffness_derivative, u, w, p, m),
            "potential_energy": lambda m: loops["scalar_calls"](kernels.potential_energy, u,
                                                                p, m),
            "solve": lambda m: loops["solves"](A, w, x, lu, pivots, ints, m),
            "product": lambda m: loops["products"](A, A, out, m)}
    costs = {}
    for name in UNIT_COSTS:
        run = runs[name]
        if not math.isfinite(run(1)):                 # compiles; the solve must succeed
            raise ValueError(f"the {name} of model {model.name!r} at u is not finite")
        best = math.inf
        for _ in range(int(repeats)):
            start = time.perf_counter()
            run(int(calls))
            best = min(best, time.perf_counter() - start)
        costs[name] = 1e6 * best / int(calls)
    return costs


def correction_costs(scheme) -> tuple:
    """The unit costs (keys of :func:`unit_costs`) one Newton correction of
    ``scheme``'s stages pays: ``f``, ``K`` and a solve; for HFDI's stage
    also ``T(u)[v_D]`` and the product ``S B⁻¹ S``."""
    import hfdi
    hfdi_stage = isinstance(hfdi.get_scheme(scheme), hfdi.HFDI)
    return ("force", "stiffness", "solve") + \
        (("stiffness_derivative", "product") if hfdi_stage else ())


def floor_us(model, scheme, costs: dict | None = None, u=None, repeats: int = 3) -> float:
    """µs per Newton correction of ``scheme`` on ``model`` that no
    implementation avoids: the sum of the unit costs of
    :func:`correction_costs` (``costs`` from :func:`unit_costs`, measured at
    ``u`` — default the model's initial displacement — when not given)."""
    if costs is None:
        u = model.initial_displacement if u is None else u
        u = np.zeros(int(model.n_dof)) if u is None else u
        costs = unit_costs(model, u, repeats)
    missing = [name for name in correction_costs(scheme) if name not in costs]
    if missing:
        raise ValueError(f"costs lacks {', '.join(missing)} (see benchmarks.floor.unit_costs)")
    return float(sum(costs[name] for name in correction_costs(scheme)))
