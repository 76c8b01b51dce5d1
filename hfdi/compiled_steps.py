"""How an :class:`~hfdi.Integrator` runs its steps compiled: the choice of the
path, the compiled loop's call (and the Python steps where a kernel raised),
and the C function a native host steps it through.

:class:`CompiledSteps` is a part of :class:`~hfdi.Integrator` (a base class of
it), kept apart from the rest of the integrator's bookkeeping.
"""
from __future__ import annotations

import math

import numpy as np

from . import compiled as compiled_path
from .compiled import shadowed
from .core import codes
from .core.jit import compiling
from .core.state import CONFIG, DATA, FUNCTIONS, RUN, VECTORS
from .evaluation import DENSE_BELOW
from .messages import Status
from .models.loads import hat_load_params
from .stepping.loop import advance_affine, advance_hfdi
from .system import HeldLoad

__all__ = ["CompiledSteps", "FLEXIBLE_PATH"]

#: What a run says once per process and reason when its model keeps it off the
#: compiled path (docs/compiled.md, "Models", for a model that runs compiled).
FLEXIBLE_PATH = ("the steps run in Python, 30 to 80 times slower per Newton iteration than "
                 "compiled, because {reason}; docs/compiled.md (\"Models\") tells how a "
                 "model runs compiled")


class CompiledSteps:
    """The compiled path of an :class:`~hfdi.Integrator`."""

    # -- which path ---------------------------------------------------------------
    def _choose_path(self, compiled, current, K0, T0, potential):
        """Compiled when the model's kernels compute it (or ``compiled=True``
        demands it), else the model through the Evaluator, with compiled
        kernels inside where they can serve (a sparse model's)."""
        ev = self.ev
        initial = compiled_path.InitialValues(
            current.t, current.u, current.v, current.f, K0, T0, potential,
            math.inf if self.t_bound is None else self.t_bound)
        if compiled is False:
            self._not_compiled = "compiled=False"
            return
        if ev.n >= DENSE_BELOW:
            compiled_path.use_sparse_kernels(ev, compiled, initial)
            self._not_compiled = f"the system has {ev.n} degrees of freedom (N ≥ {DENSE_BELOW})"
            return
        reason, kernels = compiled_path.compiled_reason(self, initial)
        if reason:
            self._not_compiled = str(reason)
            if not compiled_path.refused(compiled, reason, "the compiled path cannot run"):
                compiled_path.say_once(reason, FLEXIBLE_PATH)
            return
        self._use_compiled(kernels)

    def _use_compiled(self, kernels):
        """Run the loop compiled with ``kernels`` (:class:`hfdi.compiled.CompiledKernels`)."""
        ev, scheme = self.ev, self.scheme
        load = kernels.load if kernels.load is not None else compiled_path.zero_load
        rate = kernels.load_rate if self._cfg.exact_rate else load
        functions = FUNCTIONS.new(force=kernels.force, stiffness=kernels.stiffness,
                                  stiffness_derivative=kernels.stiffness_derivative,
                                  potential_energy=kernels.potential_energy, load=load,
                                  load_rate=rate, stage=scheme.stage)
        from .core.numba_types import function_struct_of
        with compiling(f"the kernels of model {type(self.system).__name__}"):
            fn = function_struct_of(functions)   # each loaded from the disk cache, or compiled
        # the compiled loop adds a held load's value (DATA.held) to its compiled
        # load; the Python steps call the Evaluator's load, which adds it itself
        held = isinstance(ev.extra_load, HeldLoad)
        cfg = CONFIG.pack(self._cfg)
        cfg["has_held"] = held
        self._data = self._data._replace(
            params=np.ascontiguousarray(kernels.params, dtype=float),
            load_params=np.ascontiguousarray(
                kernels.load_params if kernels.load_params is not None else
                hat_load_params(ev.n), dtype=float),     # the zero load
            held=np.zeros(ev.n) if held else np.zeros(0))
        self._compiled_call = [fn, cfg, None, None]
        self._kernels = kernels         # what the run computes with (follow_model)
        self._advance_compiled = advance_hfdi if self._hfdi else advance_affine
        self._refresh_compiled()

    def _leave_compiled(self, reason: str):
        """The rest of the run takes its steps in Python, for ``reason``."""
        self._compiled_call = None
        self._not_compiled = reason

    def _refresh_compiled(self, data: bool = True):
        """The compiled structs of the vectors and, unless ``data`` is false (only
        the vectors were replaced), of the data are out of date: made again
        when next needed (:meth:`_compiled_structs`; a run through
        ``integrate`` replaces its vectors before its first step)."""
        call = self._compiled_call
        if call is not None:
            if data:
                call[2] = None
            call[3] = None

    def _compiled_structs(self):
        """``(fn, cfg, data, vec)`` of the compiled loop, its structs made where
        they are out of date."""
        call = self._compiled_call
        if call[2] is None:
            call[2] = DATA.compiled(self._data)
        if call[3] is None:
            call[3] = VECTORS.compiled(self._vec)
        return call

    # -- a C function of the compiled loop ---------------------------------------------
    def native_advance(self):
        """This integrator's compiled loop behind a C function
        (:class:`hfdi.compiled.NativeAdvance`), for a host that steps it without
        Python (an FMU's native layer).

        Raises
        ------
        ValueError
            When the steps do not run compiled (:attr:`compiled`).
        """
        if self._compiled_call is None:
            raise ValueError("integrator must run compiled (Integrator.compiled), it does not")
        from .compiled.native import NativeAdvance
        fn, cfg, data, vec = self._compiled_structs()
        return NativeAdvance(self, fn, cfg, data, vec, self._data.held, self._run,
                             self._state_block, self._hfdi)

    def _native_ready(self) -> str:
        """Why a native host may not take the next steps now (``""``: it may)."""
        if self._compiled_call is None:
            return "the steps do not run compiled"
        if self._events is not None:
            return "event functions are watched, by the Python side"
        if self.failed:
            return "the run has failed"
        if self._model_version is not None and \
                self.system.parameter_version != self._model_version:
            return "the model changed since the last step"
        if shadowed(self.system):
            return "a method of the model is replaced on the instance"
        if not self._held_ready():
            return "the held load is not a finite vector of N values"
        return ""

    def _native_synced(self, cpu_time: float) -> None:
        """After a native host took steps (:meth:`NativeAdvance.sync`)."""
        self._run_cpu += cpu_time
        if self.finished and self._run.status >= 0:
            self._run.status = int(Status.SUCCESS)
            self._message = f"reached t_bound = {self.t_bound!r}"

    def _shadowed(self) -> bool:
        """Whether a method of the model was replaced on the instance since the
        run began compiled: the rest of the run is the Python steps', said once."""
        name = shadowed(self.system)
        if name:
            reason = f"{type(self.system).__name__}.{name} is replaced on the instance"
            compiled_path.say_once(reason, "{reason}; the rest of the run takes its steps "
                                   "in Python, which call it")
            self._leave_compiled(reason)
        return bool(name)

    def _held_ready(self) -> bool:
        """A held load's value into ``DATA.held``; false when it is not a finite
        (N,) vector (the Python steps then meet it and say so)."""
        if not self._data.held.size:
            return True
        try:
            value = np.asarray(self.ev.extra_load.source(), dtype=float)
        except Exception:
            return False
        if value.shape != (self.ev.n,) or not np.isfinite(value).all():
            return False
        self._data.held[:] = value
        return True

    def _compiled_steps(self, t_stop, max_accepted):
        fn, cfg, data, vec = self._compiled_structs()
        run = RUN.pack(self._run)
        vectors = self._vec
        saved = [getattr(vectors, name).copy() for name in _SNAPSHOT]
        while True:
            try:
                with compiling("the integrator's loop for "
                               + ("HFDI's stages" if self._hfdi else "affine stages")):
                    reason = self._advance_compiled(fn, cfg, data, run, vec, t_stop,
                                                    max_accepted)
            except Exception as exc:
                # a kernel raised: its steps of this call are lost with it. The
                # rest of the run is the Python steps', where a raising model
                # fails an attempt
                for name, value in zip(_SNAPSHOT, saved):
                    getattr(vectors, name)[:] = value
                raised = f"{type(exc).__name__}: {exc}"
                self._leave_compiled(f"a compiled kernel raised {raised}")
                compiled_path.say_once(raised, "a compiled kernel raised {reason}; the rest "
                                       "of the run takes its steps in Python")
                self._python_steps(t_stop, max_accepted)
                return
            RUN.unpack(run, self._run)
            self._hand_on_rows()
            if reason != codes.ROWS_FULL:
                return
            saved = [getattr(vectors, name).copy() for name in _SNAPSHOT]


#: The vectors a call of the compiled loop may leave half written when a kernel raises.
_SNAPSHOT = ("u", "v", "a", "f", "p", "u_previous", "v_previous", "a_previous", "f_previous",
             "p_previous", "global_error")
