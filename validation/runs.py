"""The one run driver: the paper's experiments run, measured and kept.

:func:`run_experiment` integrates one benchmark of :mod:`validation.experiments`
with one scheme and setting; :func:`table_run` adds its ``ε`` (Eq. 42)
against the IDA reference; :func:`run_tables` maps it over a sweep (serially
or on a :class:`validation.parallel.Runner`); :class:`ProblemRuns` keeps the
runs of one problem for its figures. References come from the disk cache of
:mod:`validation.reference` through one in-memory memo, :func:`problem_reference`.
"""
from __future__ import annotations

import json
import math
import sys
import threading
import time
from collections import OrderedDict
from dataclasses import asdict, dataclass, field

import numpy as np

import hfdi

from .errors import error_norms, estimated_error_norm
from .experiments import ENERGY_LIMIT, PAPER_SCHEMES, experiment
from .reference import cached_reference, default_atol, default_cache_dir

__all__ = ["RunRecord", "run_experiment", "integrate", "make_record", "problem_reference", "table_run",
           "run_tables", "Progress", "ProblemRuns", "scheme_title", "run_label"]


@dataclass
class RunRecord:
    """One run of a table: a problem, a scheme and a target iteration count
    (the paper's mode), a relative tolerance (error control), or both."""

    problem: str
    scheme: str
    target: float | None
    steps: int
    mean_iterations: float
    mean_step: float
    cpu_time: float
    status: str
    message: str
    t_reached: float
    eps: dict = field(default_factory=dict)
    rtol: float | None = None
    #: ε_u as the run's global error estimate tells it (:func:`estimated_error_norm`)
    eps_u_estimated: float = math.nan

    @property
    def label(self) -> str:
        """``N̄`` (``2·N̄`` for Bathe), ``rtol`` or both, as the table heads its column."""
        parts = []
        if self.target is not None:
            parts.append(("2·" if self.scheme == "bathe" else "") + format(self.target, ".1f"))
        if self.rtol is not None:
            parts.append(format(self.rtol, ".0e"))
        return "/".join(parts)

    @property
    def diverged(self) -> bool:
        return self.status != "SUCCESS"

    def as_dict(self) -> dict:
        return asdict(self)


def run_experiment(problem: str, scheme: str, target: float | None,
                   t_end: float | None = None, params: dict | None = None, rtol=None,
                   progress=None, compiled=False):
    """Integrate ``problem`` to its ``T_o`` (or ``t_end``) at the target
    iteration count ``target`` (the paper's mode), under error control at
    ``rtol``, or both; returns (model, result). ``progress`` is passed to
    :func:`hfdi.integrate`; ``compiled`` true takes the steps in compiled
    code where the model allows (``compiled=None`` of :func:`hfdi.integrate`),
    its loop loaded (or compiled) by a short run first, so that the run's CPU
    time is its steps'."""
    model = hfdi.models.get(problem, **(params or {}))
    t_end = experiment(problem).observation_time if t_end is None else t_end
    if compiled:
        integrate(model, scheme, 1e-6 * t_end, target, rtol, compiled=None)
    return model, integrate(model, scheme, t_end, target, rtol, progress=progress,
                            compiled=None if compiled else False)


def integrate(model, scheme: str, t_end: float, target=None, rtol=None, atol=None,
              progress=None, compiled=False):
    """:func:`hfdi.integrate` as every run of validation and of the benchmarks
    makes it: at the target iteration count ``target`` (the paper's mode),
    under error control at ``rtol`` (and ``atol``), or both, with the energy
    guard :data:`validation.experiments.ENERGY_LIMIT`; ``compiled`` as in
    :class:`hfdi.Integrator`."""
    return hfdi.integrate(model, scheme, t_end, target_iterations=target, rtol=rtol, atol=atol,
                          energy_limit=ENERGY_LIMIT, progress=progress, compiled=compiled)


def make_record(problem, scheme, target, model, result, reference=None, rtol=None) -> RunRecord:
    """The table record of one run, with ``ε`` against ``reference`` when given."""
    st = result.stats
    eps = error_norms(model, result, reference) if reference is not None else {}
    return RunRecord(problem, scheme, None if target is None else float(target), st.steps,
                     st.mean_iterations, st.mean_step, st.cpu_time, result.status.name,
                     result.message, float(result.t[-1]), eps,
                     None if rtol is None else float(rtol), estimated_error_norm(result))


#: References kept by :func:`problem_reference` in one process, most recently used
#: last. A sweep asks for one problem's references run after run (the runs
#: are in problem order), so a few are enough.
KEPT_REFERENCES = 4
_kept: OrderedDict = OrderedDict()
_kept_lock = threading.Lock()


def problem_reference(problem: str, t_end=None, params=None, rtol=1e-12, atol_factors=(1.0, 1.0),
              say=None):
    """The dense IDA reference of ``problem`` over ``[0, t_end]`` (``T_o`` by default).

    Read from the disk cache (or computed and stored there) the first time
    in a process, then kept in memory (:data:`KEPT_REFERENCES`, least
    recently used dropped). A worker whose cache lacks it (a Dask worker on
    another machine) computes it: IDA is deterministic, so it is the same
    reference. Thread-safe (a Dask worker may run tasks in threads).

    Parameters
    ----------
    atol_factors : (float, float)
        Scale the default absolute tolerances of ``rtol``
        (:func:`validation.reference.default_atol`) of the displacements and
        of the velocities.
    say : callable, optional
        ``say(text)`` before and after a reference is loaded or computed
        (not when it is found in memory).
    """
    fu, fv = (float(f) for f in atol_factors)
    key = (problem, json.dumps(params or {}, sort_keys=True, default=repr),
           None if t_end is None else float(t_end), float(rtol), fu, fv,
           str(default_cache_dir()))
    with _kept_lock:
        if key in _kept:
            _kept.move_to_end(key)
            return _kept[key]
        start = time.perf_counter()
        t_end = experiment(problem).observation_time if t_end is None else float(t_end)
        what = f"rtol {rtol:g}" + (f", atol ×{fu:g} (u) ×{fv:g} (v)"
                                   if (fu, fv) != (1.0, 1.0) else "")
        if say is not None:
            say(f"reference {problem} over [0, {t_end:g}], {what}: "
                "loading or computing (IDA; cached once computed)")
        atol = None
        if (fu, fv) != (1.0, 1.0):
            model = hfdi.models.get(problem, **(params or {}))
            atol = default_atol(model, rtol, t_end)
            atol[:model.n_dof] *= fu
            atol[model.n_dof:] *= fv
        ref = cached_reference(problem, params, t_end=t_end, rtol=rtol, atol=atol)
        if say is not None:
            origin = "from cache" if ref.from_cache else "computed"
            say(f"reference {problem} {what}: {ref.t.size} nodes, {origin} "
                f"({time.perf_counter() - start:.1f} s)")
        _kept[key] = ref
        while len(_kept) > KEPT_REFERENCES:
            _kept.popitem(last=False)
        return ref


def table_run(problem: str, scheme: str, target: float | None, t_end=None, params=None,
              eps_rtol=1e-12, rtol=None, progress=None, compiled=False) -> RunRecord:
    """One run of a table and its record, with ``ε`` against the rtol
    ``eps_rtol`` reference (:func:`problem_reference`; none when ``None``);
    ``compiled`` as in :func:`run_experiment`.

    The unit of work of :func:`run_tables`: a module-level function of plain
    arguments, so that it runs the same in a worker process.
    """
    model, result = run_experiment(problem, scheme, target, t_end, params, rtol, progress,
                                   compiled)
    reference = None if eps_rtol is None else problem_reference(problem, t_end, params, eps_rtol)
    return make_record(problem, scheme, target, model, result, reference, rtol)


def run_tables(problems, schemes=PAPER_SCHEMES, targets=None, t_end=None, params=None,
               eps=True, runner=None, progress=None, say=None, rtols=None,
               run_progress=None, compiled=False) -> dict:
    """Every run of the paper's tables of several problems (their targets unless
    ``targets``), each record with ``ε`` (Eq. 42) of every quantity of interest
    of its model when ``eps``.

    Parameters
    ----------
    problems : sequence of str
    schemes, targets, t_end, params
        Schemes (default the paper's three), target iteration counts (every
        scheme; default :meth:`Experiment.table_targets`: the paper's, and
        :data:`~validation.experiments.OTHER_SCHEME_TARGETS` for a scheme it
        did not run), end time (default ``T_o``) and model parameters (every
        problem).
    rtols : sequence of float, optional
        Relative tolerances: the runs are error-controlled, one per rtol
        (combined with each of ``targets`` when both are given).
    eps : bool
        Compute ``ε`` against the rtol 1e-12 reference.
    runner : validation.parallel.Runner, optional
        Where the runs go (default: one after the other in this process).
        Each run is a task; the references are computed or loaded here first,
        one after the other, so that the workers find them in the disk cache.
    progress : callable, optional
        ``progress(record)`` for each run, in the order of the runs.
    say : callable, optional
        ``say(text)`` for the references.
    run_progress : callable, optional
        ``run_progress(label)`` returns the ``progress(t, statistics)``
        callback of :func:`hfdi.integrate` for the run ``label``; used when the
        runs are made in this process (a worker's output is not shown).
    compiled : bool
        Take the steps in compiled code where the model allows
        (:func:`run_experiment`); the steps and N̄ are the same.

    Returns
    -------
    dict
        Problem name → list of :class:`RunRecord` (scheme by scheme, target
        by target); identical whatever the runner, apart from the
        measured ``cpu_time``.
    """
    from .parallel import Runner, single_threaded_blas
    runner = runner or Runner()
    problems = list(problems)
    if eps:
        for problem in problems:
            if say is not None:
                say(f"IDA reference of {problem} (rtol 1e-12; computed once, then cached)")
            # BLAS on one thread, as where a worker without the cache computes it
            with single_threaded_blas():
                if runner.parallel:
                    # fills the disk cache for the workers; not kept here
                    cached_reference(problem, params, rtol=1e-12, t_end=(
                        experiment(problem).observation_time if t_end is None else t_end))
                else:
                    problem_reference(problem, t_end, params)
    tasks = []
    for problem in problems:
        exp = experiment(problem)
        for scheme in schemes:
            for target in (targets or ([None] if rtols else exp.table_targets(scheme))):
                for rtol in (rtols or [None]):
                    progress_of_run = None
                    if run_progress is not None and not runner.parallel:
                        label = "/".join(f"{k}={v:g}" for k, v in (("N̄", target),
                                                                    ("rtol", rtol))
                                         if v is not None)
                        progress_of_run = run_progress(f"{problem} {scheme} {label}")
                    tasks.append((problem, scheme, None if target is None else float(target),
                                  t_end, params, 1e-12 if eps else None, rtol,
                                  progress_of_run, bool(compiled)))
    records = runner.map(table_run, tasks,
                         on_result=None if progress is None else lambda i, r: progress(r))
    tables = {problem: [] for problem in problems}
    for record in records:
        tables[record.problem].append(record)
    return tables


# -- progress and labels ------------------------------------------------------------

class Progress:
    """Progress lines on stderr, each prefixed with the time since the start.

    Parameters
    ----------
    stream : file, optional
        Where to write; ``sys.stderr`` at the time of each line by default
        (so that a test's capture sees it).
    enabled : bool
        ``False`` silences every line.
    checkpoint : callable, optional
        Called before each line, that is between two outputs; the command
        lines pass one that raises ``KeyboardInterrupt`` again after a Ctrl-C
        that a library swallowed.
    """

    def __init__(self, stream=None, enabled=True, checkpoint=None):
        self.start = time.perf_counter()
        self.stream = stream
        self.enabled = enabled
        self.checkpoint = checkpoint

    @property
    def elapsed(self) -> float:
        """Seconds since the display started."""
        return time.perf_counter() - self.start

    def say(self, text: str) -> None:
        """Write one line."""
        if self.checkpoint is not None:
            self.checkpoint()
        if self.enabled:
            print(f"[{self.elapsed:7.1f} s] {text}", file=self.stream or sys.stderr, flush=True)


def scheme_title(scheme: str) -> str:
    """The scheme's name as the paper writes it (its class name in :data:`hfdi.SCHEMES`)."""
    return hfdi.SCHEMES[scheme].__name__ if scheme in hfdi.SCHEMES else scheme


def run_label(scheme: str, target: float, mean_step: float | None = None,
              plain=False) -> str:
    """Legend text of a run, in the paper's notation (Bathe's target as ``2·N̄``).

    Mathtext for matplotlib unless ``plain``.
    """
    head = "2·" if scheme == "bathe" else ""
    n_bar, dt = ("N̄", "Δt_mv") if plain else (r"$\bar N$", r"$\Delta t_{mv}$")
    text = f"{scheme_title(scheme)} {n_bar} = {head}{target:.1f}"
    if mean_step is not None and math.isfinite(mean_step):
        text += f" ({dt} = {mean_step:.2g})"
    return text


class ProblemRuns:
    """The runs and references of one problem, each computed once when first needed.

    Parameters
    ----------
    problem : str
        A name of :func:`hfdi.models.get`.
    schemes : sequence of str
        Schemes of the table runs (default the paper's three).
    targets : sequence of float, optional
        Target iteration counts of the table runs (every scheme); when
        omitted, :meth:`Experiment.table_targets` per scheme (the paper's).
    t_end : float, optional
        End of the table runs and of the reference; the model's ``T_o`` when
        omitted.
    long_t_end : float, optional
        End of the long energy runs (Figs. 7, 18). Default: ``t_end`` when it
        is given, else the experiment's ``long_time``.
    params : dict, optional
        Model parameters.
    progress : Progress, optional
    compiled : bool
        Take the runs' steps in compiled code where the model allows
        (:func:`run_experiment`): the same steps, ``t_T`` then of compiled code.
    """

    def __init__(self, problem, schemes=PAPER_SCHEMES, targets=None, t_end=None,
                 long_t_end=None, params=None, progress=None, compiled=False):
        self.problem = problem
        self.compiled = bool(compiled)
        self.params = dict(params or {})
        self.model = hfdi.models.get(problem, **self.params)
        self.schemes = tuple(schemes)
        self.targets = None if targets is None else tuple(float(t) for t in targets)
        self.experiment = experiment(problem)
        self.t_end = float(self.experiment.observation_time if t_end is None else t_end)
        if long_t_end is not None:
            self.long_t_end = float(long_t_end)
        elif t_end is not None:
            self.long_t_end = self.t_end
        else:
            self.long_t_end = self.experiment.long_time
        self.progress = progress or Progress(enabled=False)
        self._runs: dict = {}
        self._records = None

    def table_targets(self, scheme: str) -> tuple:
        """Targets of the table runs of ``scheme``."""
        return self.targets or self.experiment.table_targets(scheme)

    def long_targets(self) -> tuple:
        """HFDI targets of the long energy runs."""
        return self.table_targets("hfdi")

    def run(self, scheme: str, target: float, t_end: float | None = None):
        """The :class:`hfdi.Result` of one run, integrated on first request."""
        t_end = self.t_end if t_end is None else float(t_end)
        key = (scheme, float(target), t_end)
        if key not in self._runs:
            start = time.perf_counter()
            _, result = run_experiment(self.problem, scheme, float(target), t_end, self.params,
                                       compiled=self.compiled)
            st = result.stats
            self.progress.say(
                f"run {self.problem} {run_label(scheme, target, plain=True)} "
                f"to t = {t_end:g}: {st.steps} steps, N_mv {st.mean_iterations:.3f}, "
                f"{result.status.name} ({time.perf_counter() - start:.1f} s)")
            self._runs[key] = result
        return self._runs[key]

    def reference(self, rtol: float = 1e-12, atol_factors=(1.0, 1.0)):
        """The dense IDA reference over ``[0, t_end]`` (:func:`problem_reference`)."""
        return problem_reference(self.problem, self.t_end, self.params, rtol, atol_factors,
                                 say=self.progress.say)

    def record(self, scheme: str, target: float, reference=None) -> RunRecord:
        """The table record of one run, as :func:`validation.tables.table_run` makes it."""
        return make_record(self.problem, scheme, target, self.model, self.run(scheme, target),
                           reference)

    def records(self) -> list:
        """Every table run with its ``ε`` against the rtol 1e-12 reference."""
        if self._records is None:
            reference = self.reference()
            self._records = [self.record(s, t, reference)
                             for s in self.schemes for t in self.table_targets(s)]
        return self._records

    def set_records(self, records: list) -> None:
        """Use table records read back from disk instead of recomputing them."""
        self._records = list(records)

    def plot_times(self) -> np.ndarray:
        """Uniform times over ``[0, t_end]`` fine enough to draw the reference.

        As many as the reference has IDA steps (which resolve its fastest
        oscillation), between 2001 and 100001.
        """
        n = int(np.clip(self.reference().t.size, 2001, 100_001))
        return np.linspace(0.0, self.t_end, n)

    def reference_quantity(self, name: str):
        """Plot times and the reference's quantity ``name`` (n, m) there."""
        t = self.plot_times()
        u, v = self.reference().at(t)
        return t, self.model.quantities(t, u, v)[name]


