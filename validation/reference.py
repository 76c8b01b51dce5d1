"""Reference solutions by SUNDIALS' IDA (through scikit-sundae), and their cache.

The error norm of the paper (Eq. 42) compares an analysis with a reference
solution ``z*``. The paper takes a fine-step Newmark run, linearly
interpolated; this project (``docs/algorithm.md``, "Error norm") takes the
first-order form ``y = (u, v)``,

    u' = v,        M v' + C v = p(t) − f(u),

integrated by IDA (variable-order, variable-step BDF, orders 1–5) at a tight
tolerance, written as the implicit residual

    F(t, y, y') = [u' − v ;  M v' + C v + f(u) − p(t)] = 0

with the analytic iteration matrix
``∂F/∂y + c_j ∂F/∂y' = [[c_j I, −I], [K(u), C + c_j M]]``.

Evaluating the reference at an analysis's step times
----------------------------------------------------
Eq. 42 needs ``z*`` exactly at the step times of each analysis, and these
differ from run to run. Two ways are offered:

* :func:`ida_reference` with ``t_eval`` = the analysis's step times: IDA
  returns its solution at exactly those times (interpolated by IDA's own BDF
  polynomial). One IDA run per analysis; for the paper's dumbbell at
  ``rtol = 1e-12`` that is about 10 s (105 154 internal steps, 134 058
  residual evaluations) whatever the number of output times.
* :func:`ida_dense_reference` (the default of :func:`cached_reference`):
  one IDA run that keeps every internal step ``(t_k, u_k, v_k, a_k)``;
  :meth:`Reference.at` then evaluates on each step ``[t_k, t_k+1]`` the
  quintic Hermite interpolant ``P`` of ``u`` that matches ``u``, ``u' = v``
  and ``u'' = a`` at both ends, and takes ``v = P'``. IDA chooses its steps
  so that a polynomial of degree ≤ 5 reproduces the solution to the
  tolerance over a step, so ``P`` is as accurate as IDA's own output
  interpolation: on the dumbbell (rtol 1e-12) ``P`` agrees with IDA's output
  at an HFDI run's step times to 5e-15 in ``u`` and 1e-9 in ``v`` (|v| ≈ 10),
  while the reference itself moves by 4e-10 in ``u`` and 1e-6 in ``v`` when
  the tolerance is tightened to 1e-13. One IDA run then serves every analysis
  of a table, and the cache keeps it across sessions (about 11 MB for the
  dumbbell). The exception is the few steps around a kink of the load,
  where IDA's own steps shrink to 1e-8 s and the acceleration at their ends
  comes from either side of the kink: there ``P'`` is off by up to 3e-6 in
  ``v`` on the articulated system (against 9e-10 at IDA's step times,
  measured against an independent DOP853 solution split at the kinks);
  the error norms, integrals over the run, change by 2e-10.

Large models
------------
Both keep ``2 × 2N`` numbers per node time; :func:`ida_march` keeps only the
last state and hands each one to a callback (``benchmarks.scale`` uses it on
the toss rule at 6000 elements). The band solver's analytic Jacobian goes
through a full ``(2N, 2N)`` array of scikit-sundae; above ``BAND_LIMIT``
unknowns the band solver takes SUNDIALS' own banded difference-quotient
Jacobian instead (``band_jacobian``), which needs no such array.

Failures
--------
IDA reports a failure through the status of its result, not by raising; it is
turned here into :class:`IDAError` with the message SUNDIALS printed. A NaN
in the residual would make IDA cut its step until it gives up much later (or
spin), so the residual raises :class:`NonFiniteResidualError` at once.
"""
from __future__ import annotations

import contextlib
import hashlib
import inspect
import io
import json
import math
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import hfdi
from hfdi.dense import hermite_quintic
from hfdi.evaluation import normalise_matrix

from hfdi.files import atomic_file, cache_dir

__all__ = [
    "Reference",
    "IDAError",
    "NonFiniteResidualError",
    "ida_reference",
    "ida_solve",
    "ida_dense_reference",
    "ida_march",
    "cached_reference",
    "default_atol",
    "default_cache_dir",
]

#: Version of the cache layout and of the reference computation; part of the
#: cache key so that a change of either invalidates old entries.
CACHE_FORMAT = 1

#: Default ``max_num_steps`` of IDA, per output interval. IDA's own default
#: (500) is far too small for stiff models at tight tolerance: the dumbbell
#: takes ~10⁵ steps over its observation time.
MAX_NUM_STEPS = 1_000_000

#: Systems up to this many first-order unknowns use the dense linear solver
#: with ``linsolver="auto"``; LU of a matrix this small costs less than the
#: bookkeeping of a band or sparse one.
DENSE_LIMIT = 100
#: The band solver's Jacobian template is a full (2N, 2N) array in
#: scikit-sundae, so ``"auto"`` picks the band solver only up to this size, and
#: an explicit ``"band"`` takes the analytic Jacobian only up to it; above it
#: the band solver gets SUNDIALS' own banded difference-quotient Jacobian,
#: which needs no such template (see :class:`_FirstOrderForm`).
BAND_LIMIT = 2000

#: Ways of forming the iteration matrix of the band solver.
BAND_JACOBIANS = ("auto", "analytic", "internal")


class IDAError(RuntimeError):
    """IDA stopped with a failure status.

    Attributes
    ----------
    status : int
        IDA's return flag (negative).
    message : str
        scikit-sundae's description of the flag.
    sundials_message : str
        What SUNDIALS' error handler printed (e.g. ``"[IDASolve, Error: -1]
        At t = ..., mxstep steps taken before reaching tout."``), or ``""``.
    t : float
        The last time IDA reached.
    """

    def __init__(self, status, message, sundials_message, t):
        self.status = int(status)
        self.message = str(message)
        self.sundials_message = str(sundials_message).strip()
        self.t = float(t)
        text = f"IDA failed with status {self.status} at t = {self.t:.10g}: {self.message}"
        if self.sundials_message:
            text += f" SUNDIALS: {self.sundials_message}"
        super().__init__(text)

    def __reduce__(self):
        # rebuilt from its own fields when it comes back from a worker process
        return type(self), (self.status, self.message, self.sundials_message, self.t)


class NonFiniteResidualError(FloatingPointError):
    """The model gave a non-finite force or load during the reference run."""


# -- matrices of the model ----------------------------------------------------

def _times(a, x):
    if a is None:
        return 0.0
    if isinstance(a, np.ndarray) and a.ndim == 1:
        return a * x
    return a @ x


def _solve(a, b):
    if isinstance(a, np.ndarray) and a.ndim == 1:
        return b / a
    if sp.issparse(a):
        return spla.spsolve(sp.csc_matrix(a), b)
    return np.linalg.solve(a, b)


def _triplets(a, n):
    """Rows, columns and values of the structural entries of ``a``."""
    if a is None:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0)
    if isinstance(a, np.ndarray) and a.ndim == 1:
        idx = np.arange(n)
        return idx, idx, a.astype(float)
    if sp.issparse(a):
        c = sp.coo_matrix(a)
        return c.row.astype(int), c.col.astype(int), c.data.astype(float)
    a = np.asarray(a, dtype=float)
    r, c = np.nonzero(a)
    return r, c, a[r, c]


def _stiffness_pattern(model, u0, n):
    """Structural pattern of ``K(u)``: the union over ``u0`` and two perturbed states.

    One state is not enough: an entry may vanish there by symmetry (the
    dumbbell's ``K_xy`` is zero while the bond lies along x).
    """
    rng = np.random.default_rng(12345)
    scale = float(getattr(model, "u_scale", 1.0) or 1.0)
    pattern = np.zeros((0, 2), dtype=np.int64)
    for k in range(3):
        u = u0 if k == 0 else u0 + 1e-3 * scale * rng.standard_normal(n)
        r, c, _ = _triplets(model.stiffness(u), n)
        pattern = np.vstack([pattern, np.column_stack([r, c])])
    return np.unique(pattern, axis=0)


# -- the first-order form -------------------------------------------------------

class _FirstOrderForm:
    """Residual and iteration matrix of ``y = (u, v)`` for IDA.

    Dense solver: block ordering ``y = [u; v]``. Band and sparse solvers:
    node-interleaved ordering ``y = (u_1, v_1, u_2, v_2, ...)``, so that a
    tangent of half-bandwidth ``b`` gives an iteration matrix of bandwidths
    about ``2b + 1`` rather than ``N``.

    The band solver's Jacobian (``band_jacobian``): scikit-sundae (1.2)
    hands a user ``jacfn`` of the band solver a full ``(2N, 2N)`` array and
    copies only its band into SUNDIALS' band matrix, so the analytic
    Jacobian costs ``32 N²`` bytes (10 GB at 18 000 DOF). ``"internal"``
    gives IDA no ``jacfn``: SUNDIALS then fills its band matrix by its own
    banded difference quotients (``lband + uband + 1`` residual evaluations
    per Jacobian) and scikit-sundae allocates no template at all. The
    Jacobian only steers IDA's Newton iteration, so either gives the solution
    to the tolerance. ``"auto"``: analytic up to ``BAND_LIMIT`` unknowns,
    internal above.
    """

    def __init__(self, model, linsolver="auto", band_jacobian="auto"):
        n = int(model.n_dof)
        if n < 1:
            raise ValueError(f"model.n_dof must be >= 1, got {model.n_dof}")
        self.model = model
        self.n = n
        self.n_eq = 2 * n
        self.M = normalise_matrix(model.mass, n, "model mass")
        if self.M is None:
            raise ValueError("the model has no mass matrix")
        self.C = normalise_matrix(model.damping, n, "model damping")
        #: ``on_residual(t)``, called before each residual evaluation (see :func:`ida_solve`)
        self.on_residual = None
        self.dropped_entries = 0
        u0 = model.initial_displacement
        u0 = np.zeros(n) if u0 is None else np.asarray(u0, dtype=float)

        linsolver = str(linsolver).lower()
        if linsolver not in ("auto", "dense", "band", "sparse"):
            raise ValueError(f"linsolver must be 'auto', 'dense', 'band' or 'sparse', "
                             f"got {linsolver!r}")
        pattern = None
        if linsolver == "auto":
            if self.n_eq <= DENSE_LIMIT:
                linsolver = "dense"
            else:
                pattern = self._pattern(_stiffness_pattern(model, u0, n))
                lband, uband = self._bands(pattern)
                k_sparse = sp.issparse(model.stiffness(u0))
                if lband + uband + 1 <= self.n_eq // 4 and self.n_eq <= BAND_LIMIT:
                    linsolver = "band"
                elif not k_sparse and self.n_eq <= 2 * BAND_LIMIT:
                    linsolver = "dense"
                else:
                    linsolver = "sparse"
        self.linsolver = linsolver
        band_jacobian = str(band_jacobian).lower()
        if band_jacobian not in BAND_JACOBIANS:
            raise ValueError(f"band_jacobian must be 'auto', 'analytic' or 'internal', "
                             f"got {band_jacobian!r}")
        if linsolver != "band":
            # the dense and sparse solvers always get the analytic Jacobian
            self.jacobian_kind = "analytic"
        elif band_jacobian == "auto":
            self.jacobian_kind = "analytic" if self.n_eq <= BAND_LIMIT else "internal"
        else:
            self.jacobian_kind = band_jacobian

        if linsolver == "dense":
            self.su, self.sv = slice(0, n), slice(n, 2 * n)
        else:
            self.su, self.sv = slice(0, 2 * n, 2), slice(1, 2 * n, 2)
        self.iu = np.arange(self.n_eq)[self.su]
        self.iv = np.arange(self.n_eq)[self.sv]

        # constant part J0 + c_j J1 of the iteration matrix: J0 = [[0, -I], [0, C]],
        # J1 = [[I, 0], [0, M]]; K(u) is added at every Jacobian evaluation
        rc, cc, vc = _triplets(self.C, n)
        rows0 = np.concatenate([self.iu, self.iv[rc]])
        cols0 = np.concatenate([self.iv, self.iv[cc]])
        vals0 = np.concatenate([-np.ones(n), vc])
        rm, cm, vm = _triplets(self.M, n)
        rows1 = np.concatenate([self.iu, self.iv[rm]])
        cols1 = np.concatenate([self.iu, self.iv[cm]])
        vals1 = np.concatenate([np.ones(n), vm])

        self.options = {"linsolver": linsolver}
        if self.jacobian_kind == "internal":
            # No (n_eq, n_eq) array anywhere: only the bandwidths, from the
            # sparse pattern; IDA differences the residual within the band.
            if pattern is None:
                pattern = self._pattern(_stiffness_pattern(model, u0, n))
            lband, uband = self._bands(pattern)
            self.options.update(lband=int(lband), uband=int(uband))
            self.jacobian = None
        elif linsolver in ("dense", "band"):
            J0 = np.zeros((self.n_eq, self.n_eq))
            J1 = np.zeros((self.n_eq, self.n_eq))
            np.add.at(J0, (rows0, cols0), vals0)
            np.add.at(J1, (rows1, cols1), vals1)
            self._J0, self._J1 = J0, J1
            self.jacobian = self._jac_dense
            if linsolver == "band":
                if pattern is None:
                    pattern = self._pattern(_stiffness_pattern(model, u0, n))
                lband, uband = self._bands(pattern)
                self.options.update(lband=int(lband), uband=int(uband))
        else:
            if pattern is None:
                pattern = self._pattern(_stiffness_pattern(model, u0, n))
            self._sparsity = pattern
            nnz = pattern.nnz
            cols = np.repeat(np.arange(self.n_eq), np.diff(pattern.indptr))
            self._keys = cols.astype(np.int64) * self.n_eq + pattern.indices
            self._base0 = np.bincount(self._position(rows0, cols0), vals0, minlength=nnz)
            self._base1 = np.bincount(self._position(rows1, cols1), vals1, minlength=nnz)
            self.jacobian = self._jac_sparse
            self.options.update(sparsity=pattern)

    # structure
    def _pattern(self, k_pattern):
        """Sparsity of the iteration matrix in the interleaved order, CSC with sorted
        indices (only the band and sparse solvers need it, and both interleave)."""
        n = self.n
        iu, iv = 2 * np.arange(n), 2 * np.arange(n) + 1
        rows = [iu, iu, iv[k_pattern[:, 0]], iv]
        cols = [iu, iv, iu[k_pattern[:, 1]], iv]
        for a in (self.M, self.C):
            r, c, _ = _triplets(a, n)
            rows.append(iv[r])
            cols.append(iv[c])
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        pattern = sp.csc_matrix((np.ones(rows.size), (rows, cols)), shape=(self.n_eq, self.n_eq))
        pattern.sum_duplicates()
        pattern.sort_indices()
        pattern.data[:] = 1.0
        return pattern

    @staticmethod
    def _bands(pattern):
        coo = pattern.tocoo()
        diff = coo.row.astype(np.int64) - coo.col
        return int(max(diff.max(), 0)), int(max((-diff).max(), 0))

    def _position(self, rows, cols):
        keys = np.asarray(cols, np.int64) * self.n_eq + np.asarray(rows, np.int64)
        pos = np.searchsorted(self._keys, keys)
        pos = np.minimum(pos, self._keys.size - 1)
        if not np.array_equal(self._keys[pos], keys):
            raise AssertionError("constant Jacobian entry outside the sparsity pattern")
        return pos

    # IDA callbacks
    def residual(self, t, y, yp, res):
        if self.on_residual is not None:
            self.on_residual(t)
        model = self.model
        u = np.array(y[self.su])
        v = y[self.sv]
        rv = _times(self.M, yp[self.sv]) + model.internal_force(u) - model.load(t)
        if self.C is not None:
            rv = rv + _times(self.C, v)
        res[self.su] = yp[self.su] - v
        res[self.sv] = rv
        if not np.isfinite(res).all():
            bad = [name for name, part in (("u", y[self.su]), ("v", v),
                                           ("f(u)", model.internal_force(u)),
                                           ("p(t)", model.load(t)))
                   if not np.isfinite(part).all()]
            raise NonFiniteResidualError(
                f"the residual of the first-order form is not finite at t = {t:.10g} "
                f"(non-finite: {', '.join(bad) or 'M v′ + C v'}); the model gave NaN or inf")

    def _jac_dense(self, t, y, yp, res, cj, JJ):
        np.multiply(self._J1, cj, out=JJ)
        JJ += self._J0
        K = self.model.stiffness(np.array(y[self.su]))
        JJ[self.sv, self.su] = K.toarray() if sp.issparse(K) else K

    def _jac_sparse(self, t, y, yp, res, cj, JJ):
        r, c, val = _triplets(self.model.stiffness(np.array(y[self.su])), self.n)
        keys = self.iu[c].astype(np.int64) * self.n_eq + self.iv[r]
        pos = np.minimum(np.searchsorted(self._keys, keys), self._keys.size - 1)
        inside = self._keys[pos] == keys
        if not inside.all():
            # Entries outside the pattern are dropped: the Newton matrix is then
            # inexact, which slows IDA's Newton iteration but not its accuracy.
            self.dropped_entries += int(np.count_nonzero(val[~inside]))
        JJ[:] = self._base0 + cj * self._base1 + np.bincount(pos[inside], val[inside],
                                                             minlength=self._keys.size)

    # states
    def initial_state(self, t0):
        model, n = self.model, self.n
        u0 = model.initial_displacement
        v0 = model.initial_velocity
        u0 = np.zeros(n) if u0 is None else np.asarray(u0, dtype=float).copy()
        v0 = np.zeros(n) if v0 is None else np.asarray(v0, dtype=float).copy()
        if u0.shape != (n,) or v0.shape != (n,):
            raise ValueError(f"initial displacement and velocity must have shape ({n},), "
                             f"got {u0.shape} and {v0.shape}")
        a0 = _solve(self.M, model.load(t0) - model.internal_force(u0) - _times(self.C, v0))
        if not (np.isfinite(u0).all() and np.isfinite(v0).all() and np.isfinite(a0).all()):
            raise NonFiniteResidualError(f"the initial state is not finite at t0 = {t0}: "
                                         f"u0 = {u0}, v0 = {v0}, a0 = {a0}")
        y0 = np.empty(self.n_eq)
        yp0 = np.empty(self.n_eq)
        y0[self.su], y0[self.sv] = u0, v0
        yp0[self.su], yp0[self.sv] = v0, a0
        return u0, v0, y0, yp0

    def to_ida_order(self, x_uv):
        """A vector in ``(u, v)`` block order, in IDA's order."""
        out = np.empty(self.n_eq)
        out[self.su], out[self.sv] = x_uv[:self.n], x_uv[self.n:]
        return out

    def from_ida_order(self, x):
        return np.concatenate([x[self.su], x[self.sv]])


def default_atol(model, rtol, span):
    """Per-component absolute tolerances ``(atol_u, atol_v)`` of the reference.

    ``atol_u,i = rtol · max(|u0_i|, u_scale)`` and
    ``atol_v,i = rtol · max(|v0_i|, V)`` with the velocity scale
    ``V = max(‖v0‖∞, u_scale / span)``: a position is resolved to the relative
    tolerance of the model's length scale, so that a coordinate starting at 0
    still has a positive floor, and a velocity to that of the initial speed
    or, for a model starting at rest, of one length per observation time.
    Models whose motion is much smaller than ``u_scale`` should pass ``atol``.

    Parameters
    ----------
    model : hfdi.SecondOrderSystem
    rtol : float
    span : float
        Length of the integration interval.

    Returns
    -------
    ndarray (2N,)
        In ``(u, v)`` block order.
    """
    n = int(model.n_dof)
    scale = float(getattr(model, "u_scale", 1.0) or 1.0)
    u0 = model.initial_displacement
    v0 = model.initial_velocity
    u0 = np.zeros(n) if u0 is None else np.abs(np.asarray(u0, dtype=float))
    v0 = np.zeros(n) if v0 is None else np.abs(np.asarray(v0, dtype=float))
    vel = max(float(v0.max(initial=0.0)), scale / span if span > 0 else scale)
    return rtol * np.concatenate([np.maximum(u0, scale), np.maximum(v0, vel)])


# -- the reference ---------------------------------------------------------------

@dataclass
class Reference:
    """An IDA reference solution on a set of nodes.

    Attributes
    ----------
    t : ndarray (n,)
        Node times: the requested output times (:func:`ida_reference`) or
        every internal step of IDA (:func:`ida_dense_reference`).
    u, v, a : ndarray (n, N)
        Displacement, velocity and acceleration at ``t``.
    rtol : float
    atol : ndarray (2N,)
        Absolute tolerances, ``(u, v)`` block order.
    dense : bool
        ``True`` when the nodes are IDA's internal steps, so that
        :meth:`at` may interpolate between them.
    stats : dict
        ``nfev``, ``njev``, ``steps`` (internal steps, ``None`` when IDA
        does not report them), ``wall_time`` [s], ``linsolver``, ``lband``,
        ``uband``, ``status``.
    message : str
        IDA's final message.
    sundials_messages : str
        Anything SUNDIALS' error handler printed during a successful run.
    cache_path : str or None
        The cache file this reference was read from or written to.
    from_cache : bool
    """

    t: np.ndarray
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    rtol: float
    atol: np.ndarray
    dense: bool = False
    stats: dict = field(default_factory=dict)
    message: str = ""
    sundials_messages: str = ""
    cache_path: str | None = None
    from_cache: bool = False

    @property
    def t_span(self):
        return float(self.t[0]), float(self.t[-1])

    def quantities(self, model) -> dict:
        """The model's quantities of interest at the nodes: name → (n, m)."""
        return model.quantities(self.t, self.u, self.v)

    def at(self, t):
        """Displacement and velocity at the times ``t``.

        Node times are returned exactly. Between nodes a dense reference
        interpolates with :func:`hfdi.dense.hermite_quintic` (``u = P``, ``v = P'``); a
        reference of requested output times only cannot be interpolated to
        IDA's accuracy, and raises.

        Parameters
        ----------
        t : array_like (n,)
            Inside the reference's time span (up to a rounding of
            ``1e-12`` of its length).

        Returns
        -------
        u, v : ndarray (n, N)
        """
        u, v, _ = self._values(t)
        return u, v

    def evaluate(self, t) -> "Reference":
        """The reference at the times ``t``, as a new (not dense) :class:`Reference`.

        Between nodes the acceleration is the interpolant's ``P''``, one order
        less accurate than ``v``; the error norms do not use it.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        u, v, a = self._values(t)
        return replace(self, t=t, u=u, v=v, a=a, dense=False, cache_path=None,
                       from_cache=False)

    def _values(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.ndim != 1:
            raise ValueError(f"t must be 1-D, got shape {t.shape}")
        t0, t1 = self.t_span
        slack = 1e-12 * max(abs(t1 - t0), abs(t1), 1e-300)
        if t.size and (not np.isfinite(t).all() or np.min(t) < t0 - slack
                       or np.max(t) > t1 + slack):
            raise ValueError(f"times outside the reference's span [{t0}, {t1}]: "
                             f"[{np.min(t)}, {np.max(t)}]")
        t = np.clip(t, t0, t1)
        idx = np.clip(np.searchsorted(self.t, t), 0, self.t.size - 1)
        on_node = self.t[idx] == t
        shape = (t.size, self.u.shape[1])
        u, v, a = np.empty(shape), np.empty(shape), np.empty(shape)
        u[on_node], v[on_node], a[on_node] = (self.u[idx[on_node]], self.v[idx[on_node]],
                                              self.a[idx[on_node]])
        off = ~on_node
        if off.any():
            if not self.dense:
                raise ValueError(
                    "this reference holds IDA's solution at requested output times only; "
                    f"{int(off.sum())} time(s) are not among them (first {t[off][0]!r}). "
                    "Compute it at those times (ida_reference) or use a dense reference "
                    "(ida_dense_reference, cached_reference).")
            u[off], v[off], a[off] = hermite_quintic(self.t, self.u, self.v, self.a, t[off])
        return u, v, a

    # storage
    def _arrays(self):
        meta = {"rtol": self.rtol, "dense": self.dense, "stats": self.stats,
                "message": self.message, "sundials_messages": self.sundials_messages}
        return {"t": self.t, "u": self.u, "v": self.v, "a": self.a, "atol": self.atol,
                "meta": np.array(json.dumps(meta, default=_json_default))}

    @classmethod
    def _from_arrays(cls, data):
        meta = json.loads(str(data["meta"]))
        return cls(t=np.array(data["t"]), u=np.array(data["u"]), v=np.array(data["v"]),
                   a=np.array(data["a"]), rtol=float(meta["rtol"]),
                   atol=np.array(data["atol"]), dense=bool(meta["dense"]),
                   stats=meta["stats"], message=meta["message"],
                   sundials_messages=meta["sundials_messages"])


# -- running IDA -------------------------------------------------------------------

def _check_tolerances(model, rtol, atol, span, form):
    rtol = float(rtol)
    if not (math.isfinite(rtol) and 0 < rtol < 1):
        raise ValueError(f"rtol must be in (0, 1), got {rtol!r}")
    if atol is None:
        atol_uv = default_atol(model, rtol, span)
    else:
        atol_uv = np.broadcast_to(np.asarray(atol, dtype=float), (form.n_eq,)).copy()
        if not (np.isfinite(atol_uv).all() and (atol_uv > 0).all()):
            raise ValueError(f"atol must be positive and finite, got {atol!r}")
    return rtol, atol_uv


def _solver(form, rtol, atol_uv, max_num_steps):
    from sksundae.ida import IDA
    with warnings.catch_warnings():
        # scikit-sundae warns that its own finite-difference Jacobian on the
        # sparsity pattern yields to 'jacfn': the analytic one is meant.
        warnings.filterwarnings("ignore", message="Custom sparse Jacobian approximation")
        return IDA(form.residual, jacfn=form.jacobian, rtol=rtol,
                   atol=form.to_ida_order(atol_uv), max_num_steps=int(max_num_steps),
                   **form.options)


def _run(solver, tspan, y0, yp0):
    """``solver.solve`` with SUNDIALS' printed messages captured; raises on failure."""
    buffer = io.StringIO()
    start = time.perf_counter()
    with contextlib.redirect_stdout(buffer):
        sol = solver.solve(tspan, y0, yp0)
    wall = time.perf_counter() - start
    printed = buffer.getvalue().strip()
    if not sol.success:
        t_reached = sol.t[-1] if np.size(sol.t) else tspan[0]
        raise IDAError(sol.status, sol.message, printed, t_reached)
    return sol, wall, printed


def _stats(sol, wall, form, steps):
    return {"nfev": int(sol.nfev), "njev": int(sol.njev), "steps": steps,
            "wall_time": float(wall), "linsolver": form.linsolver,
            "jacobian": form.jacobian_kind,
            "lband": form.options.get("lband"), "uband": form.options.get("uband"),
            "status": int(sol.status), "dropped_jacobian_entries": form.dropped_entries}


def ida_solve(model, t_end, *, rtol, atol=None, on_residual=None,
              max_num_steps=10 ** 9, linsolver="auto") -> dict:
    """One IDA run of ``model`` from its initial state over ``[0, t_end]``,
    every internal step kept; a failure is reported, not raised.

    The run of a work–precision comparison: the same first-order form,
    iteration matrix and initial derivative as :func:`ida_reference`.

    Parameters
    ----------
    model : hfdi.SecondOrderSystem
    t_end : float
    rtol : float
    atol : array_like (2N,), optional
        In ``(u, v)`` order; :func:`default_atol` by default.
    on_residual : callable, optional
        ``on_residual(t)`` before each residual evaluation: counts them, and
        an exception it raises stops the run and reaches the caller (a work
        budget).
    max_num_steps : int
    linsolver : str

    Returns
    -------
    dict
        ``t`` (n,) distinct times, ``u``, ``v`` (n, N), ``success``,
        ``status`` (IDA's flag), ``message`` (with what SUNDIALS printed),
        ``nfev``, ``njev``, ``linsolver`` and ``atol`` (2N,).
    """
    form = _FirstOrderForm(model, linsolver)
    form.on_residual = on_residual
    atol_uv = default_atol(model, rtol, t_end) if atol is None else \
        np.asarray(atol, dtype=float)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        solver = _solver(form, rtol, atol_uv, max_num_steps)
        _, _, y0, yp0 = form.initial_state(0.0)
        # two times: scikit-sundae returns every internal step
        sol = solver.solve(np.array([0.0, t_end]), y0, yp0)
    t = np.asarray(sol.t, dtype=float)
    keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, bool)
    y = np.asarray(sol.y)[keep]
    message = str(sol.message)
    if printed.getvalue().strip():
        message += " SUNDIALS: " + printed.getvalue().strip()
    return {"t": t[keep], "u": y[:, form.su], "v": y[:, form.sv],
            "success": bool(sol.success), "status": int(sol.status), "message": message,
            "nfev": int(sol.nfev), "njev": int(sol.njev), "linsolver": form.linsolver,
            "atol": atol_uv}


def ida_reference(model, t_eval, *, rtol=1e-12, atol=None, t0=0.0,
                  max_num_steps=MAX_NUM_STEPS, linsolver="auto",
                  band_jacobian="auto") -> Reference:
    """IDA's solution of ``M u'' + C u' + f(u) = p(t)`` exactly at ``t_eval``.

    Integrates the first-order form ``y = (u, v)`` (module docstring) from the
    model's initial state at ``t0`` with the analytic iteration matrix and a
    consistent initial derivative ``y'(t0) = (v0, M⁻¹(p − f − C v0))``.

    Parameters
    ----------
    model : hfdi.SecondOrderSystem
    t_eval : array_like (n,)
        Strictly increasing output times ``>= t0``, e.g. an analysis's step
        times; one or two times are fine.
    rtol : float
        IDA's relative tolerance.
    atol : float or array_like (2N,), optional
        Absolute tolerances in ``(u, v)`` order; :func:`default_atol` when
        omitted.
    t0 : float
        Initial time of the model's initial state.
    max_num_steps : int
        IDA's limit of internal steps per output interval.
    linsolver : {"auto", "dense", "band", "sparse"}
        ``"auto"``: dense up to ``DENSE_LIMIT`` unknowns, band when the
        interleaved iteration matrix is narrow, sparse (SuperLU_MT) otherwise.
    band_jacobian : {"auto", "analytic", "internal"}
        Iteration matrix of the band solver: the analytic one through
        scikit-sundae's full ``(2N, 2N)`` template, or SUNDIALS' own banded
        difference quotients, which need no such array; ``"auto"``: analytic
        up to ``BAND_LIMIT`` unknowns. Ignored by the other solvers.

    Returns
    -------
    Reference
        ``dense=False``; ``stats["steps"]`` is ``None`` (IDA's normal mode
        does not report it).

    Raises
    ------
    IDAError
        IDA failed; the message includes SUNDIALS' own.
    NonFiniteResidualError
        The model produced NaN or inf.
    """
    t_eval = np.atleast_1d(np.asarray(t_eval, dtype=float))
    t0 = float(t0)
    if t_eval.ndim != 1 or t_eval.size == 0 or not np.isfinite(t_eval).all():
        raise ValueError("t_eval must be a non-empty 1-D array of finite times")
    if np.any(np.diff(t_eval) <= 0):
        raise ValueError("t_eval must be strictly increasing")
    if t_eval[0] < t0:
        raise ValueError(f"t_eval must start at or after t0 = {t0}, got {t_eval[0]}")
    form = _FirstOrderForm(model, linsolver, band_jacobian)
    span = float(t_eval[-1] - t0)
    rtol, atol_uv = _check_tolerances(model, rtol, atol, span, form)
    u0, v0, y0, yp0 = form.initial_state(t0)
    n = form.n
    if span == 0.0:
        return Reference(t=t_eval.copy(), u=u0[None].copy(), v=v0[None].copy(),
                         a=form.from_ida_order(yp0)[None, n:], rtol=rtol, atol=atol_uv,
                         stats={"steps": 0, "wall_time": 0.0, "linsolver": form.linsolver},
                         message="t_eval is the initial time")
    tspan = t_eval if t_eval[0] == t0 else np.concatenate([[t0], t_eval])
    # scikit-sundae switches to one-step output for two times: add midpoints
    while tspan.size < 3:
        tspan = np.sort(np.concatenate([tspan, 0.5 * (tspan[:-1] + tspan[1:])]))
    sol, wall, printed = _run(_solver(form, rtol, atol_uv, max_num_steps), tspan, y0, yp0)
    rows = np.searchsorted(tspan, t_eval)
    if sol.t.size != tspan.size or not np.array_equal(sol.t[rows], t_eval):
        raise IDAError(sol.status, "IDA did not return every requested time", printed,
                       sol.t[-1])
    y, yp = sol.y[rows], sol.yp[rows]
    return Reference(t=t_eval.copy(), u=y[:, form.su].copy(), v=y[:, form.sv].copy(),
                     a=yp[:, form.sv].copy(), rtol=rtol, atol=atol_uv, dense=False,
                     stats=_stats(sol, wall, form, None), message=str(sol.message),
                     sundials_messages=printed)


def ida_dense_reference(model, t_end, *, rtol=1e-12, atol=None, t0=0.0,
                        linsolver="auto", band_jacobian="auto") -> Reference:
    """IDA's solution at every internal step over ``[t0, t_end]``, for interpolation.

    Same problem and options as :func:`ida_reference`; the result keeps IDA's
    internal steps (the last one lands exactly on ``t_end``) and evaluates
    anywhere in ``[t0, t_end]`` by :meth:`Reference.at` (quintic Hermite,
    module docstring). IDA's ``max_num_steps`` does not apply: it counts steps
    per output, and here every step is an output.

    Returns
    -------
    Reference
        ``dense=True``; ``stats["steps"]`` is the number of internal steps.
    """
    t0, t_end = float(t0), float(t_end)
    if not (math.isfinite(t_end) and t_end > t0):
        raise ValueError(f"t_end must be finite and > t0 = {t0}, got {t_end!r}")
    form = _FirstOrderForm(model, linsolver, band_jacobian)
    rtol, atol_uv = _check_tolerances(model, rtol, atol, t_end - t0, form)
    _, _, y0, yp0 = form.initial_state(t0)
    sol, wall, printed = _run(_solver(form, rtol, atol_uv, MAX_NUM_STEPS),
                              np.array([t0, t_end]), y0, yp0)
    t, y, yp = sol.t, sol.y, sol.yp
    if t[-1] != t_end:
        raise IDAError(sol.status, f"IDA stopped at t = {t[-1]!r} before t_end = {t_end!r}",
                       printed, t[-1])
    keep = np.concatenate([[True], np.diff(t) > 0])     # no zero-length intervals
    t, y, yp = t[keep], y[keep], yp[keep]
    return Reference(t=t.copy(), u=y[:, form.su].copy(), v=y[:, form.sv].copy(),
                     a=yp[:, form.sv].copy(), rtol=rtol, atol=atol_uv, dense=True,
                     stats=_stats(sol, wall, form, int(t.size - 1)),
                     message=str(sol.message), sundials_messages=printed)


def ida_march(model, t_end, *, t_eval=None, callback=None, rtol=1e-12, atol=None, t0=0.0,
              max_num_steps=MAX_NUM_STEPS, linsolver="auto", band_jacobian="auto",
              wall_limit=None) -> Reference:
    """IDA from ``t0`` to ``t_end`` one internal step at a time, keeping only the last state.

    :func:`ida_dense_reference` keeps every internal step and
    :func:`ida_reference` every output, ``2 × 2N`` numbers each; for a large
    model over many steps that is gigabytes. Here each state is handed to
    ``callback`` and dropped, so memory stays ``O(N)`` however long the run,
    and the internal steps are counted (IDA's normal mode does not report
    them).

    Parameters
    ----------
    model : hfdi.SecondOrderSystem
    t_end : float
        End of the run, ``> t0``.
    t_eval : array_like, optional
        Increasing times in ``[t0, t_end]``: IDA's steps are made to land on
        them (as ``tstop``, so the values there are IDA's own, not
        interpolated) and ``callback`` is called there only. Landing shortens
        at most one step per time, so it changes IDA's work little when IDA
        takes many more steps than there are times. Without ``t_eval`` the
        callback gets every internal step.
    callback : callable ``callback(t, u, v)``, optional
        Gets copies it may keep.
    rtol, atol, t0, max_num_steps, linsolver, band_jacobian
        As :func:`ida_reference`.
    wall_limit : float, optional
        Stop after this many seconds of wall-clock time and return the state
        reached: ``stats["stopped"]`` is then ``"wall_limit"`` and the
        returned ``t`` is before ``t_end``.

    Returns
    -------
    Reference
        The last state only (``t = [t_reached]``, ``dense=False``); ``stats``
        as :func:`ida_reference` with ``steps`` (internal steps),
        ``t_reached`` and ``stopped`` (``None`` or ``"wall_limit"``).

    Raises
    ------
    IDAError, NonFiniteResidualError
        As :func:`ida_reference`.
    """
    t0, t_end = float(t0), float(t_end)
    if not (math.isfinite(t_end) and t_end > t0):
        raise ValueError(f"t_end must be finite and > t0 = {t0}, got {t_end!r}")
    if t_eval is not None:
        t_eval = np.atleast_1d(np.asarray(t_eval, dtype=float))
        if t_eval.ndim != 1 or not np.isfinite(t_eval).all() or np.any(np.diff(t_eval) <= 0):
            raise ValueError("t_eval must be a strictly increasing 1-D array of finite times")
        if t_eval.size and (t_eval[0] < t0 or t_eval[-1] > t_end):
            raise ValueError(f"t_eval must lie in [t0, t_end] = [{t0}, {t_end}]")
    if wall_limit is not None and not float(wall_limit) > 0:
        raise ValueError(f"wall_limit must be > 0 seconds, got {wall_limit!r}")
    form = _FirstOrderForm(model, linsolver, band_jacobian)
    rtol, atol_uv = _check_tolerances(model, rtol, atol, t_end - t0, form)
    _, _, y0, yp0 = form.initial_state(t0)
    solver = _solver(form, rtol, atol_uv, max_num_steps)
    stops = np.array([t_end]) if t_eval is None else \
        np.unique(np.concatenate([t_eval[t_eval > t0], [t_end]]))
    wanted = None if t_eval is None else set(t_eval.tolist())
    buffer = io.StringIO()
    steps, t, stopped = 0, t0, None
    y, yp = y0, yp0
    start = time.perf_counter()
    with contextlib.redirect_stdout(buffer):
        sol = solver.init_step(t0, y0, yp0)
        if not sol.success:
            raise IDAError(sol.status, sol.message, buffer.getvalue(), t0)
        if callback is not None and (wanted is None or t0 in wanted):
            callback(t0, y0[form.su].copy(), y0[form.sv].copy())
        for stop in stops:
            while t < stop:
                if wall_limit is not None and time.perf_counter() - start > wall_limit:
                    stopped = "wall_limit"
                    break
                sol = solver.step(float(stop), method="onestep", tstop=float(stop))
                if not sol.success:
                    raise IDAError(sol.status, sol.message, buffer.getvalue(), t)
                t = float(np.atleast_1d(sol.t)[-1])
                y, yp = np.atleast_2d(sol.y)[-1], np.atleast_2d(sol.yp)[-1]
                steps += 1
                if callback is not None and (wanted is None or (t == stop and t in wanted)):
                    callback(t, y[form.su].copy(), y[form.sv].copy())
            if stopped:
                break
    wall = time.perf_counter() - start
    stats = _stats(sol, wall, form, steps)
    stats.update(t_reached=t, stopped=stopped)
    return Reference(t=np.array([t]), u=y[form.su].copy()[None], v=y[form.sv].copy()[None],
                     a=yp[form.sv].copy()[None], rtol=rtol, atol=atol_uv, dense=False,
                     stats=stats, message=str(sol.message),
                     sundials_messages=buffer.getvalue().strip())


# -- cache ---------------------------------------------------------------------------

def default_cache_dir() -> Path:
    """The reference cache: :func:`hfdi.files.cache_dir` (``$HFDI_CACHE_DIR``
    or ``~/.cache/hfdi``)."""
    return cache_dir()


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj, key=repr)
    if isinstance(obj, Path):
        return str(obj)
    return repr(obj)


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


#: The modules of hfdi every reference reads a model through: the model
#: protocol, the checks of its values and the normalisation of its matrices.
_PROTOCOL_MODULES = ("system.py", "checks.py", "evaluation.py")


def model_sources(model) -> list:
    """The source files a model's forces come from: its module, every module
    of the package it lives in (for hfdi.models: the pair potential and the
    loads its models share), every module of hfdi its module takes a name
    from, and hfdi's model protocol, checks and the normalisation of its
    matrices (:data:`_PROTOCOL_MODULES`). The reference cache's key hashes
    them all, so that an edited model, or an edited helper of it, misses the
    cache. Every file listed exists (a file that is gone would make the key
    drop the sources altogether)."""
    source = inspect.getmodule(type(model))
    module = Path(inspect.getsourcefile(source))
    files = {module}
    if (module.parent / "__init__.py").is_file():
        files.update(module.parent.glob("*.py"))
    core = Path(hfdi.__file__).parent
    files.update(core / name for name in _PROTOCOL_MODULES)
    for value in vars(source).values():
        used = value if inspect.ismodule(value) else inspect.getmodule(value)
        name = getattr(used, "__name__", "")
        if name == "hfdi" or name.startswith("hfdi."):
            try:
                files.add(Path(inspect.getsourcefile(used)))
            except TypeError:                           # a built-in module: no source
                pass
    return sorted(path.resolve() for path in files if path.is_file())


def _model_source_digest(model):
    try:
        h = hashlib.sha256()
        for path in model_sources(model):
            h.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
        return h.hexdigest()
    except (OSError, TypeError):
        return None


def _cache_key(model_name, params, model, t0, t_end, t_eval, rtol, atol, linsolver,
               band_jacobian="auto"):
    try:
        from importlib.metadata import version
        sksundae_version = version("scikit-sundae")
    except Exception:                                   # pragma: no cover - metadata missing
        sksundae_version = None
    u0 = np.asarray(model.initial_displacement if model.initial_displacement is not None
                    else np.zeros(model.n_dof), dtype=float)
    v0 = np.asarray(model.initial_velocity if model.initial_velocity is not None
                    else np.zeros(model.n_dof), dtype=float)
    key = {
        "format": CACHE_FORMAT,
        "model": model_name,
        "params": params,
        "model_parameters": model.parameters(),
        "u0": _digest(u0.tobytes()), "v0": _digest(v0.tobytes()),
        "t0": t0, "t_end": t_end,
        "t_eval": None if t_eval is None else _digest(np.asarray(t_eval, float).tobytes()),
        "rtol": rtol,
        "atol": None if atol is None else np.asarray(atol, float).tolist(),
        "linsolver": linsolver,
        "hfdi": getattr(hfdi, "__version__", None),
        "sksundae": sksundae_version,
        "model_source": _model_source_digest(model),
    }
    if str(band_jacobian).lower() != "auto":
        key["band_jacobian"] = str(band_jacobian).lower()
    return json.dumps(key, sort_keys=True, default=_json_default)


def _load(path, key):
    """The cached reference at ``path`` if it is readable and its key matches, else None."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return None
            ref = Reference._from_arrays(data)
    except Exception:
        # Unreadable (truncated, corrupt, foreign): the caller recomputes it.
        return None
    n = ref.t.size
    # a matching key with damaged data (NaN, reversed times) is recomputed, not
    # used: it would print NaN error norms with exit status 0
    if not (n >= 1 and ref.u.shape[0] == n and ref.v.shape == ref.u.shape
            and ref.a.shape == ref.u.shape and np.isfinite(ref.t).all()
            and np.isfinite(ref.u).all() and np.isfinite(ref.v).all()
            and np.isfinite(ref.a).all() and np.all(np.diff(ref.t) > 0)):
        return None
    return ref


def _save(path: Path, key: str, ref: Reference):
    """Write atomically: a killed run leaves the old file or none, never half of one."""
    with atomic_file(path) as fh:
        np.savez(fh, key=np.array(key), **ref._arrays())


def cached_reference(model_name, params=None, t_eval=None, *, t_end=None, rtol=1e-12,
                     atol=None, t0=0.0, cache_dir=None, linsolver="auto",
                     refresh=False, band_jacobian="auto") -> Reference:
    """The IDA reference of a registered model, computed once and kept on disk.

    Without ``t_eval`` the reference is dense (:func:`ida_dense_reference`)
    over ``[t0, t_end]``, ``t_end`` defaulting to the benchmark's observation
    time ``T_o`` (:mod:`validation.experiments`): one IDA run then serves the error norms of every analysis of the
    model over that interval (or a part of it) through :meth:`Reference.at`.
    With ``t_eval`` it holds IDA's output at exactly those times
    (:func:`ida_reference`).

    The cache file is keyed by the model name, the parameters given and
    those the model reports, its initial state, the time interval (and a
    hash of ``t_eval``), the tolerances, the linear solver, the versions of
    hfdi and scikit-sundae, a hash of the model module's source and the cache
    format. It is written atomically (a temporary file in the same directory,
    then ``os.replace``); an unreadable or mismatched entry is recomputed.
    If the cache directory cannot be written, the reference is returned
    uncached with a warning.

    Parameters
    ----------
    model_name : str
        A name of :func:`hfdi.models.get`.
    params : dict, optional
        Keyword arguments of the model.
    t_eval : array_like, optional
    t_end : float, optional
    rtol : float
    atol : float or array_like (2N,), optional
    t0 : float
    cache_dir : str or Path, optional
        Default :func:`default_cache_dir`.
    linsolver : str
    refresh : bool
        Recompute and overwrite even if a valid entry exists.
    band_jacobian : str
        As :func:`ida_reference`; part of the key only when not ``"auto"``,
        so that the keys of existing entries stay as they were.

    Returns
    -------
    Reference
        With ``cache_path`` and ``from_cache`` set.
    """
    params = dict(params or {})
    model = hfdi.models.get(model_name, **params)
    t0 = float(t0)
    if t_eval is not None:
        t_eval = np.atleast_1d(np.asarray(t_eval, dtype=float))
        t_end = float(t_eval[-1])
    elif t_end is None:
        from .experiments import EXPERIMENTS
        if model_name not in EXPERIMENTS:
            raise ValueError(f"model {model_name!r} is no benchmark of the paper; give t_end")
        t_end = float(EXPERIMENTS[model_name].observation_time)
    else:
        t_end = float(t_end)
    key = _cache_key(model_name, params, model, t0, t_end, t_eval, float(rtol), atol, linsolver,
                     band_jacobian)
    directory = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in str(model_name))
    path = directory / f"reference-{safe}-{_digest(key.encode())[:24]}.npz"

    if not refresh and path.exists():
        ref = _load(path, key)
        if ref is not None:
            ref.cache_path, ref.from_cache = str(path), True
            return ref

    if t_eval is None:
        ref = ida_dense_reference(model, t_end, rtol=rtol, atol=atol, t0=t0, linsolver=linsolver,
                                  band_jacobian=band_jacobian)
    else:
        ref = ida_reference(model, t_eval, rtol=rtol, atol=atol, t0=t0, linsolver=linsolver,
                            band_jacobian=band_jacobian)
    try:
        _save(path, key, ref)
        ref.cache_path = str(path)
    except OSError as exc:
        warnings.warn(f"could not write the reference cache {path}: {exc}", RuntimeWarning,
                      stacklevel=2)
    ref.from_cache = False
    return ref
