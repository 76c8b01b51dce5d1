"""What a run gives back: :class:`Statistics`, :class:`Result` and the rows of
accepted steps."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from .dense import Solution
from .evaluation import State
from .messages import Status
from .system import SecondOrderSystem

__all__ = ["Statistics", "Result", "Rows", "STATISTICS_FIELDS", "global_error_ratio"]


def global_error_ratio(global_error, rtol, atol, u_scale, v_scale) -> float:
    """The estimated global error over the tolerance, at its worst:
    ``max |g_i| / (atol_i + rtol_i·S)`` over the rows of ``global_error``
    ((k, 2N) or (2N,)) and the components, ``S`` being ``u_scale`` for
    ``u``'s and ``v_scale`` for ``v``'s; NaN where the estimate was lost."""
    g = np.abs(np.atleast_2d(global_error))
    if np.isnan(g).any():
        return math.nan
    n = g.shape[1] // 2
    scale = np.concatenate([np.full(n, float(u_scale)), np.full(n, float(v_scale))])
    return float((g / (atol + rtol * scale)).max()) if g.size else 0.0


@dataclass
class Statistics:
    """Counters of a run, as the paper counts them (Section 5, Eq. 43).

    Attributes
    ----------
    steps : int
        Predictor–corrector steps, diverged attempts included.
    accepted, rejected : int
        Accepted steps and rejected attempts, diverged or failing the error
        test (``steps = accepted + rejected``).
    newton_iterations : int
        ``N_tot``: Newton corrections of all steps, diverged ones included
        (both sub-steps for Bathe).
    first_step_trials : int
        Attempts made to choose the first step size (the accepted one included).
    first_step_trial_iterations : int
        Newton corrections of the discarded first-step trials; they are not in
        ``steps`` or ``newton_iterations``.
    error_test_failures : int
        Attempts whose corrector converged but whose local error estimate
        failed the tolerance (part of ``rejected``).
    nfev, njev, ntev, npev, nlu : int
        Evaluations of f, K, T and V, and linear factorisations.
    cpu_time : float
        Process time of the run, seconds.
    """

    steps: int = 0
    accepted: int = 0
    rejected: int = 0
    newton_iterations: int = 0
    error_test_failures: int = 0
    first_step_trials: int = 0
    first_step_trial_iterations: int = 0
    nfev: int = 0
    njev: int = 0
    ntev: int = 0
    npev: int = 0
    nlu: int = 0
    cpu_time: float = 0.0
    t_start: float = 0.0
    t_reached: float = 0.0

    @property
    def mean_iterations(self) -> float:
        """``N_mv = N_tot / steps`` (Eq. 43)."""
        return self.newton_iterations / self.steps if self.steps else float("nan")

    @property
    def mean_step(self) -> float:
        """``Δt_mv``: time covered divided by ``steps``."""
        return (self.t_reached - self.t_start) / self.steps if self.steps else float("nan")


@dataclass
class Result:
    """Solution of :func:`integrate`.

    Attributes
    ----------
    t : ndarray (n,)
        Times of the initial state and of every accepted step (with
        ``save_steps=False``: of the initial and the last state only). At a
        declared load breakpoint where the acceleration jumps, the time is
        there twice: the state the step reached (the load's left limit),
        then the one the next step starts from (a step of size 0).
    u, v, a : ndarray (n, N)
        Displacement, velocity and acceleration at ``t``.
    step_size : ndarray (n,)
        Size of the step that ended at ``t`` (NaN at the start).
    iterations : ndarray (n,)
        Newton corrections of the accepted step that ended at ``t``.
    energy_increment : ndarray (n,)
        ``ΔE`` of the step ending at ``t`` (Eq. 40; 0 at the start).
    total_energy : ndarray (n,)
        ``W = V + T`` at ``t``.
    external_work : ndarray (n,)
        Work of the load from the start (Eq. 41, summed).
    global_error : ndarray (n, 2N)
        The estimated global error of ``(u, v)`` at ``t`` (``u``'s N columns,
        then ``v``'s): the local error estimates carried through the
        linearised motion (docs/algorithm.md, "Global error estimate",
        with its limits). Zero at the start; NaN from where it was lost,
        and throughout with ``global_error=False``.
    status : Status
    message : str
    success : bool
    stats : Statistics
    scheme : str
    t_eval : ndarray (m,) or None
        The requested output times.
    u_eval, v_eval : ndarray (m, N) or None
        ``u`` and ``v`` there, by the dense output (NaN past the end of a
        failed run).
    system : SecondOrderSystem
        The model integrated.
    rtol, atol : ndarray (2N,) or None
        The tolerances of ``u`` and ``v`` the run was asked for (with
        ``error="global"``: the global ones, also where a rerun took
        tighter ones); ``None`` in the modes without error control.
    runs : int
        The runs made (``error="global"`` may repeat one).
    t_events : list of ndarray (k,) or None
        Per event function (``events=``), the times of its zeros, in order;
        ``None`` without events.
    u_events, v_events : list of ndarray (k, N) or None
        ``u`` and ``v`` at those zeros (by the dense output).
    """

    t: np.ndarray
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    step_size: np.ndarray
    iterations: np.ndarray
    energy_increment: np.ndarray
    total_energy: np.ndarray
    external_work: np.ndarray
    global_error: np.ndarray
    status: Status
    message: str
    stats: Statistics
    scheme: str
    t_eval: np.ndarray | None = None
    u_eval: np.ndarray | None = None
    v_eval: np.ndarray | None = None
    system: SecondOrderSystem | None = field(default=None, repr=False)
    steps_saved: bool = True
    rtol: np.ndarray | None = None
    atol: np.ndarray | None = None
    runs: int = 1
    t_events: list | None = None
    u_events: list | None = None
    v_events: list | None = None
    #: The largest |u|, |v| and |g| (2N) over every accepted step, kept or not
    #: (:attr:`global_error_ratio`); None: from the kept rows.
    peaks: tuple | None = field(default=None, repr=False)

    @property
    def success(self) -> bool:
        """Whether the run reached ``t_end``, or a terminal event, as asked."""
        return self.status in (Status.SUCCESS, Status.TERMINATED)

    @property
    def global_error_ratio(self) -> float | None:
        """The estimated global error over the tolerance, at its worst:
        ``max |g_i(t)| / (atol_i + rtol_i·S)`` over the kept steps and the
        components, ``S`` the largest ``|u|`` of the run for ``u``'s
        components and the largest ``|v|`` for ``v``'s (the solution's
        scale: a component that passes through zero is not held to its own
        size there); over every accepted step, also those not kept
        (``save_steps=False``). NaN where the estimate was lost; ``None``
        without ``rtol``."""
        if self.rtol is None:
            return None
        if self.peaks is not None:
            u_peak, v_peak, g_peak = self.peaks
            return global_error_ratio(g_peak, self.rtol, self.atol, u_peak, v_peak)
        return global_error_ratio(self.global_error, self.rtol, self.atol,
                                  np.abs(self.u).max(), np.abs(self.v).max())

    @property
    def sol(self) -> Solution:
        """Dense output over the run: ``sol(t)`` gives ``(u, v)`` at any ``t``
        in ``[t[0], t[-1]]`` by Hermite interpolants on the step ends
        (:class:`~hfdi.dense.Solution`: quintic in ``u``, cubic in ``v``), and
        ``sol.global_error(t)`` the estimated global error there."""
        if not self.steps_saved:
            raise ValueError("sol needs the steps: this run was made with save_steps=False")
        return Solution(self.t, self.u, self.v, self.a, self.global_error)

    def quantities(self, system: SecondOrderSystem | None = None) -> dict:
        """The quantities of interest of ``system`` (default: the model
        integrated) at ``t``, a dict of (n, m) arrays."""
        return (system or self.system).quantities(self.t, self.u, self.v)

    def __repr__(self):
        st = self.stats
        return (f"Result(scheme={self.scheme!r}, status={self.status.name}, steps={st.steps}, "
                f"mean_iterations={st.mean_iterations:.3f}, mean_step={st.mean_step:.4g}, "
                f"t_final={self.t[-1]:.6g})")


class Rows:
    """Per-step records in blocks of arrays: a step taken in Python is copied
    into the open block (grown by doubling), a call of the compiled loop hands
    over its own rows as a block (:meth:`extend`), and :meth:`arrays` joins
    the blocks once."""

    def __init__(self, n: int):
        self.n = n
        self.size = 0                 # rows in all blocks
        self._blocks = []             # sealed blocks: dicts of arrays of equal length
        self._open = 0                # rows in the open block
        self._alloc(64)

    def _alloc(self, capacity):
        old = getattr(self, "data", None)
        self.data = {"t": np.empty(capacity), "u": np.empty((capacity, self.n)),
                     "v": np.empty((capacity, self.n)), "a": np.empty((capacity, self.n)),
                     "step_size": np.empty(capacity), "iterations": np.empty(capacity, int),
                     "energy_increment": np.empty(capacity), "total_energy": np.empty(capacity),
                     "external_work": np.empty(capacity),
                     "global_error": np.empty((capacity, 2 * self.n))}
        if old is not None:
            for key, arr in old.items():
                self.data[key][:self._open] = arr[:self._open]

    def append(self, state: State, h, iterations, increment, energy, work, global_error):
        if self._open == self.data["t"].shape[0]:
            self._alloc(2 * self._open)
        i = self._open
        d = self.data
        d["t"][i] = state.t
        d["u"][i] = state.u
        d["v"][i] = state.v
        d["a"][i] = state.a
        d["step_size"][i] = h
        d["iterations"][i] = iterations
        d["energy_increment"][i] = increment
        d["total_energy"][i] = energy
        d["external_work"][i] = work
        d["global_error"][i] = global_error
        self._open += 1
        self.size += 1

    def _seal(self):
        if self._open:
            # a copy of the rows, not a view that would keep the whole open
            # block; the open block is then written again from its start
            self._blocks.append({key: arr[:self._open].copy() for key, arr in self.data.items()})
            self._open = 0

    def extend(self, arrays: dict):
        """Append the rows of ``arrays`` (the keys of :meth:`arrays`), kept as
        they are: the caller gives up the arrays."""
        self._seal()
        self._blocks.append(arrays)
        self.size += arrays["t"].shape[0]

    def arrays(self) -> dict:
        blocks = self._blocks + ([{key: arr[:self._open] for key, arr in self.data.items()}]
                                 if self._open or not self._blocks else [])
        if len(blocks) == 1:
            return {key: np.array(arr) for key, arr in blocks[0].items()}
        return {key: np.concatenate([block[key] for block in blocks]) for key in self.data}


STATISTICS_FIELDS = tuple(f.name for f in fields(Statistics))
