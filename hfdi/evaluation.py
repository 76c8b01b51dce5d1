"""The one checked gateway to a model.

:class:`Evaluator` wraps a :class:`~hfdi.system.SecondOrderSystem`: it checks
its mass and damping once, and every value of the model it hands out for its
shape (a wrong one is a mistake in the model: :class:`ModelError`) and for
being finite (else :class:`NonFiniteError`, a failed attempt). For the
stepping code, :meth:`Evaluator.functions` records a fault in
:attr:`Evaluator.fault` and returns a value of a wrong shape or not finite
instead of raising, as compiled kernels signal it.
"""
from __future__ import annotations

import hashlib
import math
import numbers
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from . import checks
from .core.arrays import DENSE, DIAGONAL, NONE, SPARSE
from .linsolve.sparse import DENSE_BELOW, Factorization
from .system import SecondOrderSystem

__all__ = ["State", "Evaluator", "ModelError", "NonFiniteError", "ModelFault", "DENSE_BELOW",
           "brief", "normalise_matrix"]


class ModelError(ValueError):
    """A mistake in the model: a function returned the wrong shape, or at the
    initial state a value that is not finite, or raised there."""


class NonFiniteError(ArithmeticError):
    """A model function returned NaN or infinity at some state.

    Unlike a :class:`ModelError` this is not a mistake in the model as such:
    a trial state of the corrector may lie where the model is undefined, and a
    shorter step may avoid it. The corrector treats it as a failed attempt.
    """


class ModelFault(Exception):
    """The model failed where no shorter step helps (its potential energy at an
    accepted state): the run stops with ``MODEL_ERROR``, this message."""


def brief(x) -> str:
    """A short text of a vector for messages (long vectors are elided)."""
    x = np.asarray(x, dtype=float).ravel()
    parts = [f"{v:.6g}" for v in (x if x.size <= 8 else np.concatenate([x[:3], x[-3:]]))]
    if x.size > 8:
        parts[3:3] = [f"... ({x.size} entries) ..."]
    return "[" + ", ".join(parts) + "]"


_ndarray = np.ndarray
_float64 = np.dtype(np.float64)
_isfinite = np.isfinite


def all_finite(x) -> bool:
    """Whether every entry of the float array ``x`` is finite (no NaN, no infinity)."""
    return _isfinite(x).all()


def _at_u(u) -> str:
    return f"u = {brief(u)}"


def _at_u_w(u, w) -> str:
    return f"u = {brief(u)}, w = {brief(w)}"


def _at_t(t) -> str:
    return f"t = {t:.10g}"


def _refuse_none(value, what, shape):
    # np.array(None, dtype=float) is a NaN of shape (): name the usual cause
    if value is None:
        raise ModelError(f"{what} returned None, expected an array of shape {shape} "
                         f"(a missing return statement?)")


def _refuse_complex(value, what):
    if checks.complex_values(value):
        raise ModelError(f"{what} returned complex values; a model must return real ones "
                         f"(their imaginary parts would be dropped)")


def _first_bad(values) -> str:
    """The first non-finite entry of ``values`` (an array or sparse matrix) and its index."""
    if sp.issparse(values):
        coo = values.tocoo()
        k = int(np.flatnonzero(~np.isfinite(coo.data))[0])
        value, index = coo.data[k], [int(coo.row[k]), int(coo.col[k])]
    else:
        arr = np.asarray(values)
        position = np.argwhere(~np.isfinite(arr))[0]
        value, index = arr[tuple(position)], [int(i) for i in position]
    return f"{float(value)!r} at {index}"


def normalise_matrix(a, n: int, name: str):
    """Return ``a`` as a 1-D diagonal, a 2-D ndarray or CSR sparse, checked to be ``n``×``n``.

    ``None`` stays ``None``. The checks (real, finite, the shape) and their
    messages naming ``name`` are :func:`hfdi.checks.square_matrix`'s. A sparse
    or dense matrix that is exactly diagonal is stored as its diagonal.
    """
    if a is None:
        return None
    a = checks.square_matrix(name, a, n)
    if sp.issparse(a):
        a = sp.csr_matrix(a, dtype=float, copy=True)
        if a.nnz == 0 or (a - sp.diags(a.diagonal())).count_nonzero() == 0:
            return np.asarray(a.diagonal(), dtype=float)
        return a
    if a.ndim == 1:
        return a.copy()
    if np.count_nonzero(a - np.diag(np.diag(a))) == 0:
        return np.diag(a).copy()
    # a copy: a model's matrix changed in place later must not change the run's
    return np.array(a, dtype=float, order="C")


def _same_matrix(a, b) -> bool:
    """Two normalised matrices with the same entries (``None`` is zero; a
    sparse, a dense and a diagonal form of one matrix are the same)."""
    if a is None or b is None:
        other = b if a is None else a
        return other is None or not (other.count_nonzero() if sp.issparse(other)
                                     else np.count_nonzero(other))
    if not (sp.issparse(a) or sp.issparse(b)) and a.ndim == b.ndim:
        return a.shape == b.shape and np.array_equal(a, b)
    def as_sparse(m):
        return sp.diags(m).tocsr() if not sp.issparse(m) and m.ndim == 1 else sp.csr_matrix(m)
    a, b = as_sparse(a), as_sparse(b)
    return a.shape == b.shape and (a != b).count_nonzero() == 0


def matrices_digest(*matrices) -> str:
    """A digest of normalised matrices' entries, the same for a sparse, a dense
    and a diagonal form of one matrix (``None`` is zero): what a state records
    of the ``M`` and ``C`` it was computed with."""
    digest = hashlib.sha256()
    for m in matrices:
        if m is None:
            digest.update(b"zero;")
            continue
        csr = sp.csr_matrix(sp.diags(m) if not sp.issparse(m) and m.ndim == 1 else m,
                            dtype=float, copy=True)
        csr.eliminate_zeros()
        if csr.nnz == 0:
            digest.update(b"zero;")
            continue
        csr.sort_indices()
        for part in (np.asarray(csr.shape, np.int64), csr.indptr.astype(np.int64),
                     csr.indices.astype(np.int64), csr.data + 0.0):
            digest.update(part.tobytes())
        digest.update(b";")
    return digest.hexdigest()[:32]


def matrix_kind(a) -> int:
    """The kind (:mod:`hfdi.core.arrays`) of a normalised matrix."""
    if a is None:
        return NONE
    if sp.issparse(a):
        return SPARSE
    return DIAGONAL if a.ndim == 1 else DENSE


@dataclass(frozen=True, init=False)
class State:
    """The solution at one time.

    Attributes
    ----------
    t : float
    u, v, a : ndarray (N,)
        Displacement, velocity, acceleration.
    f : ndarray (N,)
        Internal force ``f(u)``, kept so that the next step need not recompute it.
    p : ndarray (N,)
        External load ``p(t)``.
    """

    t: float
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    f: np.ndarray
    p: np.ndarray

    def __init__(self, t, u, v, a, f, p):
        # the fields written once, past the frozen class's __setattr__, which
        # costs three times as much (a co-simulation step makes one or two States)
        fields = self.__dict__
        fields["t"], fields["u"], fields["v"], fields["a"], fields["f"], fields["p"] = \
            t, u, v, a, f, p

    def copy(self) -> "State":
        """A copy owning copies of its arrays (``copy.deepcopy``, at a tenth of its cost)."""
        return State(self.t, self.u.copy(), self.v.copy(), self.a.copy(),
                     None if self.f is None else self.f.copy(),
                     None if self.p is None else self.p.copy())


class Evaluator:
    """Checking wrapper around a :class:`~hfdi.system.SecondOrderSystem`.

    Parameters
    ----------
    system : SecondOrderSystem
    extra_load : callable ``t -> (N,)``, optional
        Added to the model's load (used for inputs of a co-simulation).

    The methods :meth:`force`, :meth:`stiffness`, :meth:`stiffness_derivative`,
    :meth:`load`, :meth:`load_rate` and :meth:`potential_energy` raise on a
    fault (and count the evaluations in ``nfev``, ``njev``, ``ntev``,
    ``npev``); :meth:`functions` are the stepping code's, which signal it.
    """

    def __init__(self, system: SecondOrderSystem, extra_load=None):
        if not isinstance(system, SecondOrderSystem):
            raise TypeError(f"system must be a hfdi.SecondOrderSystem, got {type(system).__name__}")
        n = checks.integer("system.n_dof", system.n_dof, 1)
        self.system = system
        self.n = n
        self.mass = normalise_matrix(system.mass, n, "system.mass")
        if self.mass is None:
            raise ValueError("system.mass must be given")
        self.damping = normalise_matrix(system.damping, n, "system.damping")
        # a mass not positive definite, a damping not semi-definite: mistakes
        # in the model, reported here rather than as a diverging run
        for name, matrix, semi in (("system.mass", self.mass, False),
                                   ("system.damping", self.damping, True)):
            if matrix is None:
                continue
            checks.symmetric_definite(
                name, matrix, semi=semi,
                what=" (negative damping is not allowed)" if semi else "")
        self.mass, self.damping = (self._stored(a) for a in (self.mass, self.damping))
        self.extra_load = extra_load
        self.nfev = self.njev = self.ntev = self.npev = 0
        self._mass_factor = None
        self._mass_floor = None
        self._matrices = None
        self._vector_shape = (n,)
        self._matrix_shape = (n, n)
        #: Compiled f, K and T called instead of the model's methods
        #: (:class:`hfdi.compiled.SparseKernels`, see :meth:`use_kernels`).
        self.kernels = None
        #: :mod:`hfdi.compiled.band` with them: the sparse tangents go into
        #: band storage in compiled code.
        self.bands = None
        #: The last fault a function of :meth:`functions` met: ``(message,
        #: mistake)``, ``mistake`` true for a :class:`ModelError`.
        self.fault = None

    def _stored(self, matrix):
        """A normalised matrix as the run keeps it: dense below the sparse size."""
        return matrix.toarray() if self.n < DENSE_BELOW and sp.issparse(matrix) else matrix

    @property
    def matrices(self) -> str:
        """:func:`matrices_digest` of the ``M`` and ``C`` read at construction."""
        if self._matrices is None:
            self._matrices = matrices_digest(self.mass, self.damping)
        return self._matrices

    def matrix_changed(self) -> str:
        """The name of the model's matrix (``"mass"``, ``"damping"``) that is no
        longer the one read at construction, or ``""``: the run reads them once."""
        for name, mine in (("mass", self.mass), ("damping", self.damping)):
            now = normalise_matrix(getattr(self.system, name), self.n, f"system.{name}")
            if not _same_matrix(mine, None if now is None else self._stored(now)):
                return name
        return ""

    @property
    def mass_kind(self) -> int:
        return matrix_kind(self.mass)

    @property
    def mass_diagonal(self) -> np.ndarray:
        """The diagonal of ``M`` (of a diagonal, dense or sparse one), (N,)."""
        m = self.mass
        return m if m.ndim == 1 else np.asarray(m.diagonal()).ravel()

    @property
    def damping_kind(self) -> int:
        return matrix_kind(self.damping)

    def mass_floor(self) -> float:
        """A lower bound of the smallest eigenvalue of ``M`` (> 0; 0 where only a
        bound that is not positive is known), computed once: the smallest entry
        of a diagonal ``M``, the smallest eigenvalue of a dense one, Gershgorin's
        bound of a sparse one."""
        if self._mass_floor is None:
            m = self.mass
            if m.ndim == 1:
                floor = float(m.min())
            elif isinstance(m, np.ndarray):
                floor = float(np.linalg.eigvalsh(m)[0])
            else:
                diagonal = np.asarray(m.diagonal()).ravel()
                off = np.asarray(abs(m).sum(axis=1)).ravel() - np.abs(diagonal)
                floor = float((diagonal - off).min())
            self._mass_floor = max(floor, 0.0)
        return self._mass_floor

    def damping_rate(self) -> float:
        """``‖C‖_∞ / λ_min(M)`` (a bound of the fastest damping rate; 0 without C,
        inf without a positive bound of ``λ_min(M)``)."""
        C = self.damping
        if C is None:
            return 0.0
        rows = np.abs(C) if C.ndim == 1 else np.asarray(abs(C).sum(axis=1))
        floor = self.mass_floor()
        return float(rows.max()) / floor if floor > 0 else math.inf

    def use_kernels(self, kernels) -> None:
        """Call ``kernels.force``, ``.stiffness`` and ``.stiffness_derivative``
        (:class:`hfdi.compiled.SparseKernels`, checked against the model by
        the caller) instead of the model's methods, and build the sparse
        tangents' bands compiled (:mod:`hfdi.compiled.band`); ``None`` goes
        back to the Python model and builders."""
        self.kernels = kernels
        if kernels is None:
            self.bands = None
        else:
            from .compiled import band
            self.bands = band

    # -- counted model calls --------------------------------------------------
    # The common case, a finite float ndarray of the right shape, is recognised
    # with a few attribute tests and one ufunc. ``where(*args)`` places a
    # failure. A copy is returned: a model may hand back the same buffer.
    def _vector(self, value, what, where, *args):
        if (type(value) is _ndarray and value.shape == self._vector_shape
                and value.dtype == _float64 and all_finite(value)):
            return value.copy()
        _refuse_complex(value, what)
        _refuse_none(value, what, f"({self.n},)")
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise ModelError(f"{what} returned {value!r:.80}, expected an array of "
                             f"shape ({self.n},)") from None
        if arr.shape != (self.n,):
            raise ModelError(f"{what} returned shape {arr.shape}, expected ({self.n},)")
        if not np.isfinite(arr).all():
            raise NonFiniteError(f"{what} is not finite ({_first_bad(arr)}) at {where(*args)}")
        return arr

    def _matrix(self, value, what, where, *args):
        if (type(value) is _ndarray and value.shape == self._matrix_shape
                and value.dtype == _float64 and all_finite(value)):
            return value.copy()
        n = self.n
        _refuse_complex(value, what)
        _refuse_none(value, what, f"({n}, {n})")
        if sp.issparse(value):
            if value.shape != (n, n):
                raise ModelError(f"{what} returned shape {value.shape}, expected ({n}, {n})")
            if not all_finite(value.data):
                raise NonFiniteError(f"{what} is not finite ({_first_bad(value)}) at "
                                     f"{where(*args)}")
            return value.toarray() if n < DENSE_BELOW else value.copy()
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise ModelError(f"{what} returned {type(value).__name__} {value!r:.80}, expected "
                             f"an array or sparse matrix of shape ({n}, {n})") from None
        if arr.shape != (n, n):
            raise ModelError(f"{what} returned shape {arr.shape}, expected ({n}, {n})")
        if not np.isfinite(arr).all():
            raise NonFiniteError(f"{what} is not finite ({_first_bad(arr)}) at {where(*args)}")
        return arr

    def force(self, u):
        self.nfev += 1
        return self._force(u)

    def _force(self, u):
        k = self.kernels
        f = self.system.internal_force(u) if k is None else k.force(u)
        return self._vector(f, "internal_force", _at_u, u)

    def stiffness(self, u):
        self.njev += 1
        return self._stiffness(u)

    def _stiffness(self, u):
        k = self.kernels
        K = self.system.stiffness(u) if k is None else k.stiffness(u)
        return self._matrix(K, "stiffness", _at_u, u)

    def stiffness_derivative(self, u, w):
        self.ntev += 1
        return self._stiffness_derivative(u, w)

    def _stiffness_derivative(self, u, w):
        k = self.kernels
        T = self.system.stiffness_derivative(u, w) if k is None else \
            k.stiffness_derivative(u, w)
        return self._matrix(T, "stiffness_derivative", _at_u_w, u, w)

    def load(self, t):
        p = self._vector(self.system.load(t), "load", _at_t, t)
        if self.extra_load is not None:
            p = p + self._vector(self.extra_load(t), "extra_load", _at_t, t)
        return p

    @property
    def has_load_rate(self):
        return self.system.load_rate is not None and self.extra_load is None

    def load_rate(self, t):
        return self._vector(self.system.load_rate(t), "load_rate", _at_t, t)

    def potential_energy(self, u):
        """``V(u)`` as a float; NaN (the model's "unknown") passes unchecked.
        A real number or an array of one is expected: ``None``, a bool or a
        string is refused (numpy would read ``None`` as NaN and ``"1.0"`` as
        1)."""
        self.npev += 1
        return self._potential_energy(u)

    def _potential_energy(self, u):
        value = self.system.potential_energy(u)
        _refuse_complex(value, "potential_energy")
        if isinstance(value, float):                  # float and numpy's float64
            return float(value)
        arr = None
        if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
            arr = np.asarray(float(value))
        elif isinstance(value, np.ndarray) and value.dtype.kind in "iuf":
            arr = value.astype(float)
        if arr is None or arr.size != 1:
            shape = "" if arr is None else f" of shape {arr.shape}"
            raise ModelError(f"potential_energy returned {type(value).__name__}{shape}, "
                             f"expected a float")
        return float(arr.reshape(()))

    # -- mass and damping -----------------------------------------------------
    def mass_times(self, x):
        return self.mass * x if self.mass.ndim == 1 else self.mass @ x

    def damping_times(self, x):
        if self.damping is None:
            return np.zeros_like(x)
        return self.damping * x if self.damping.ndim == 1 else self.damping @ x

    def mass_solve(self, b):
        if self._mass_factor is None:
            self._mass_factor = Factorization(self.mass)
        return self._mass_factor.solve(b)

    def acceleration(self, t, u, v, f=None, p=None):
        """``a = M⁻¹(p − f − C v)`` (Eq. 14)."""
        f = self.force(u) if f is None else f
        p = self.load(t) if p is None else p
        return self.mass_solve(p - f - self.damping_times(v))

    def kinetic_energy(self, v):
        return 0.5 * float(v @ self.mass_times(v))

    # -- the stepping code's functions --------------------------------------------
    def functions(self, stage, exact_rate=False):
        """The model as the stepping code calls it, with the scheme's ``stage``
        function: :data:`hfdi.core.state.FUNCTIONS` of Python callables. A
        fault is recorded in :attr:`fault` and signalled by a value of a wrong
        shape (a :class:`ModelError`) or not finite (anything else);
        ``potential_energy`` raises :class:`ModelFault`."""
        from .core.state import FUNCTIONS
        n = self.n
        nan_vector = np.full(n, np.nan)
        no_vector, no_matrix = np.empty(0), np.empty((0, 0))
        nan_matrix = (np.full((n, n), np.nan) if n < DENSE_BELOW else
                      sp.csr_matrix(([np.nan], ([0], [0])), shape=(n, n)))

        def guarded(evaluate, missing, failed):
            def call(*args):
                try:
                    return evaluate(*args)
                except ModelError as exc:
                    self.fault = (str(exc), True)
                    return missing
                except NonFiniteError as exc:
                    self.fault = (str(exc), False)
                except Exception as exc:   # the model failed at some state: an attempt fails
                    self.fault = (f"model raised {type(exc).__name__}: {exc}", False)
                return failed.copy() if isinstance(failed, np.ndarray) else failed
            return call

        def potential_energy(u, params):
            try:
                return self._potential_energy(u)
            except Exception as exc:
                raise ModelFault(f"{type(exc).__name__}: {exc}") from None

        return FUNCTIONS.new(
            force=guarded(lambda u, params: self._force(u), no_vector, nan_vector),
            stiffness=guarded(lambda u, params: self._stiffness(u), no_matrix, nan_matrix),
            stiffness_derivative=guarded(lambda u, w, params: self._stiffness_derivative(u, w),
                                         no_matrix, nan_matrix),
            potential_energy=potential_energy,
            load=guarded(lambda t, params: self.load(t), no_vector, nan_vector),
            load_rate=guarded(lambda t, params: self.load_rate(t) if exact_rate else
                              nan_vector, no_vector, nan_vector),
            stage=stage)
