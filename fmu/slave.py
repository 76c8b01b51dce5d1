"""An FMI 2.0 co-simulation slave around :class:`hfdi.Integrator` (on pythonfmu 0.7's Python classes).

The slave only translates FMI calls into hfdi's public API. One FMU wraps one
model of hfdi's registry (``hfdi.models``); :mod:`fmu.build` copies this file
into the FMU's resources under a build-specific module name and generates a
small subclass of :class:`HfdiSlave` that names the model, the bundled copy of
``hfdi`` and the model's units (see :mod:`fmu.metadata`).

This module must import without ``hfdi`` being installed: it runs on the copy
of ``hfdi`` bundled in the FMU's resources under a private, build-specific
module name, so the FMU runs the code it was built with whatever ``hfdi`` the
importing process has (see :func:`load_bundle`). In an FMU, the entry module
(:mod:`fmu.entry`) imports the bundle, this module and pythonfmu's copy in the
resources under private names, without touching the host's ``sys.path``.

Variables (DOF numbers are 1-based, the convention of the Modelica-based tools
that read FMI's structured names; DOF ``i`` is hfdi's index ``i - 1``):

* parameters (fixed): ``scheme`` (newmark | bathe | hfdi), ``target_iterations``
  (0: not used), ``rtol`` (error control; 0: the master's tolerance of
  ``fmi2SetupExperiment`` when defined, else for a model with event
  functions hfdi's default rtol), ``tolerance`` (Newton tolerance η;
  0: automatic), ``initial_step`` (0: automatic),
  ``max_step`` (0: no limit), ``max_internal_steps``, ``error_mode`` (local |
  global: a doStep whose end misses the tolerance is discarded), ``compiled`` (the
  compiled driver of :mod:`hfdi.compiled`; false by default) and every scalar constructor parameter of the
  model (``model.NAME`` when the bare name is taken);
* inputs: ``F[i]``, an external force added to the model's load through
  ``extra_load`` (a :class:`hfdi.HeldLoad`) and held constant over each
  communication step;
* outputs: ``u[i]``, ``v[i]``, ``a[i]``, the model's quantities of interest
  (``NAME`` or ``NAME[k]``; ``z.NAME`` when the bare name is taken; a
  quantity equal to the displacement is not repeated), ``W`` (total energy),
  ``dE`` (Σ ΔE, paper Eq. 40), ``global_error_u`` and ``global_error_v`` (the
  largest entries of the estimated global error of ``u`` and ``v``), and the
  Integer outputs ``internal_steps`` and ``newton_iterations``.

How the FMU's native layer (``fmu/native/hfdi_fmi2.c``, ``hfdi_fmi3.c``, through
:mod:`fmu.entry`) maps this slave's behaviour onto FMI 2.0 statuses:

* ``do_step`` returning ``False`` gives ``fmi2Discard``;
* an exception (:class:`FmuError` from :meth:`HfdiSlave._reject`, or any
  other) gives ``fmi2Error``, with its text as the log message; the instance
  is left as it was, so the master may go on with it;
* a String value that is not UTF-8 is refused by the native layer itself
  (``fmi2Error``) before it reaches the slave.

Hence: ``do_step`` never raises (a failure is logged and answered with
``fmi2Discard``, the FMU back at the step's start, the time the native layer
reports as ``fmi2LastSuccessfulTime``); invalid parameters are rejected by
``fmi2ExitInitializationMode`` with ``fmi2Error`` and a log message naming the
parameter; a corrupt or foreign FMU state is rejected by ``fmi2SetFMUstate``
the same way; so is a call with an invalid value reference. One ``doStep``
takes at most ``max_internal_steps`` internal steps and each of them at most
``2 * target_iterations`` (at most 200) Newton corrections per attempt, so
that no call runs unbounded.
"""
from __future__ import annotations

import importlib
import importlib.util
import math
import numbers
import os
import re
import sys
from xml.etree.ElementTree import Element, SubElement

import numpy as np

# pythonfmu: in an FMU, the copy in its resources, which the entry module
# (fmu/entry.py) imports as "<this module's name>_pythonfmu" before this
# module, so that a pythonfmu of the host is neither used nor replaced; where
# this module is imported by name (building an FMU), the installed one.
_pythonfmu = sys.modules.get(__name__ + "_pythonfmu") or importlib.import_module("pythonfmu")
Boolean, DefaultExperiment, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, \
    Real, String = (getattr(_pythonfmu, name) for name in (
        "Boolean", "DefaultExperiment", "Fmi2Causality", "Fmi2Initial", "Fmi2Slave",
        "Fmi2Variability", "Integer", "Real", "String"))
Fmi2Status = importlib.import_module(_pythonfmu.__name__ + ".enums").Fmi2Status

__all__ = ["HfdiSlave", "FmuError", "load_bundle"]

#: Serialized FMU states start with this line; a version bump makes old ones unreadable.
_MAGIC = b"hfdi-fmu-state/4\n"
#: The FMU's own fields of a serialized state (beside its arrays and the integrator's key).
_STATE_HEADER = ("model", "bundle", "phase", "params", "mparams", "start_time", "stop_time",
                 "scales", "events")

_SOLVER_DEFAULTS = {"scheme": "hfdi", "target_iterations": 3.0, "rtol": 0.0, "tolerance": 0.0,
                    "initial_step": 0.0, "max_step": 0.0, "max_internal_steps": 100_000,
                    "compiled": False, "master_rtol": 0.0, "error_mode": "local"}
#: Values of the parameter error_mode.
_ERROR_MODES = ("local", "global")
#: Largest target_iterations: Newton may run 2 N-bar corrections per attempt
#: and 31 attempts per step, each unbounded in time when it cannot converge.
_MAX_TARGET_ITERATIONS = 100.0
#: hfdi's per-run step limit, lifted: the FMU bounds each doStep instead.
_UNLIMITED_STEPS = 2 ** 62
_RESERVED = frozenset(_SOLVER_DEFAULTS) | {"u", "v", "a", "F", "W", "dE", "internal_steps",
                                           "newton_iterations", "time", "global_error_u",
                                           "global_error_v"}
_INT32_MAX = 2 ** 31 - 1
#: The slave's life cycle, as its log messages name it.
_PHASES = {"instantiated": "instantiated", "initialization": "in initialization mode",
           "stepping": "initialized", "terminated": "terminated"}

#: SI exponents of the units the metadata tables use (FMI 2.0 BaseUnit).
_BASE_UNITS = {
    "1": {}, "m": {"m": 1}, "m/s": {"m": 1, "s": -1}, "m/s2": {"m": 1, "s": -2},
    "rad": {"rad": 1}, "rad/s": {"rad": 1, "s": -1}, "rad/s2": {"rad": 1, "s": -2},
    "1/s": {"s": -1}, "1/s2": {"s": -2}, "s": {"s": 1}, "kg": {"kg": 1},
    "N": {"kg": 1, "m": 1, "s": -2}, "N.m": {"kg": 1, "m": 2, "s": -2},
    "J": {"kg": 1, "m": 2, "s": -2}, "N/m": {"kg": 1, "s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1}, "Pa": {"kg": 1, "m": -1, "s": -2},
    "kg/m3": {"kg": 1, "m": -3},
}
#: Velocity, acceleration and force units belonging to a DOF unit.
_DERIVED = {"m": ("m/s", "m/s2", "N"), "rad": ("rad/s", "rad/s2", "N.m"),
            "1": ("1/s", "1/s2", "1")}


class FmuError(Exception):
    """A request the FMU refuses (reported to the master as ``fmi2Error``)."""


def _like(what, saved, mine):
    """``saved`` (a restored state's parameters) if it has the keys of
    ``mine`` with values of the same types (an int for a float too)."""
    if not isinstance(saved, dict) or set(saved) != set(mine):
        raise FmuError(f"the state's {what} are not this FMU's")
    for key, value in saved.items():
        kind = type(mine[key])
        ok = isinstance(value, kind) and (kind is bool or not isinstance(value, bool)) or (
            kind is float and isinstance(value, int) and not isinstance(value, bool))
        if not ok:
            raise FmuError(f"the state's {what}: {key} must be of type {kind.__name__}")
    return {key: type(mine[key])(value) for key, value in saved.items()}


def load_bundle(alias: str, resources):
    """The ``hfdi`` package bundled in ``resources``, imported as module ``alias``.

    In an FMU the entry module (:mod:`fmu.entry`) has imported it already,
    checked, from its lasting copy where one can be kept; this returns that
    module. Elsewhere, when pythonfmu's builder makes a slave to write the
    model description, the package is imported from ``resources`` (the
    build's staging folder) as it is.

    The bundled package uses relative imports only, so it can live under any
    name; a build-specific name keeps it apart from an ``hfdi`` the host
    process may have imported and from the copies inside other FMUs.

    Parameters
    ----------
    alias : str
        Module name, e.g. ``_hfdi_fmu_1a2b3c4d5e6f``.
    resources : str
        The FMU's ``resources`` directory, holding ``hfdi/``.

    Returns
    -------
    module
    """
    module = sys.modules.get(alias)
    if module is not None:
        return module
    package_dir = os.path.join(str(resources), "hfdi")
    init = os.path.join(package_dir, "__init__.py")
    if not os.path.isfile(init):
        raise ImportError(f"the FMU's resources hold no hfdi package ({package_dir})")
    spec = importlib.util.spec_from_file_location(alias, init,
                                                  submodule_search_locations=[package_dir])
    module = importlib.util.module_from_spec(spec)
    sys.modules[alias] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        for name in [n for n in sys.modules if n == alias or n.startswith(alias + ".")]:
            del sys.modules[name]
        raise
    return module


class _Real(Real):
    """A Real variable with a unit, whose start value is written to round-trip exactly."""

    def __init__(self, name, unit=None, **kwargs):
        super().__init__(name, **kwargs)
        self.unit = unit

    def to_xml(self):
        node = super().to_xml()
        real = node.find("Real")
        if self.unit:
            real.set("unit", self.unit)
        if self.start is not None:
            # pythonfmu writes 16 significant digits, which need not round-trip
            real.set("start", repr(float(self.start)))
        return node


class _Time(_Real):
    """The independent variable (pythonfmu 0.7 has no such causality: written here)."""

    def to_xml(self):
        node = super().to_xml()
        node.set("causality", "independent")
        node.attrib.pop("initial", None)
        return node


def _event_label(k, g) -> str:
    """How the FMU's descriptions name the event function ``g``: its name and the
    first line of its docstring."""
    name = getattr(g, "__name__", "") or f"events[{k}]"
    doc = (getattr(g, "__doc__", "") or "").strip().splitlines()
    direction = {-1: "falling zeros", 1: "rising zeros"}.get(
        int(getattr(g, "direction", 0) or 0), "zeros")
    return f"{name} ({direction}{': ' + doc[0].rstrip('.') if doc else ''})"


def _finite_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) \
        and math.isfinite(float(value))


class HfdiSlave(Fmi2Slave):
    """FMI 2.0 co-simulation slave integrating one model of ``hfdi.models``.

    Subclasses (generated by :mod:`fmu.build`) set the class attributes below;
    the native layer (:mod:`fmu.entry`) instantiates them with the keyword
    arguments ``instance_name``, ``resources`` and ``visible``.

    Attributes
    ----------
    model_name : str
        Registry name of the model.
    bundle : str
        Module name under which the bundled ``hfdi`` is imported.
    metadata : dict
        Units and labels (see :mod:`fmu.metadata`).
    """

    model_name: str = ""
    bundle: str = ""
    metadata: dict = {}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        hfdi = self._hfdi = load_bundle(self.bundle, self.resources)
        name = self.model_name
        meta = self.metadata or {}
        self._defaults = hfdi.models.describe(name)
        model = hfdi.models.get(name)
        n = self._n = int(model.n_dof)

        self.modelName = "hfdi_" + re.sub(r"\W", "_", name)
        self.description = (
            f"hfdi model {name!r} ({n} DOFs): M u'' + C u' + f(u) = p(t) + F integrated by "
            "the adaptive Newmark / Bathe / HFDI predictor-corrector, its step size from "
            "the paper's iteration-count rule and, with a tolerance (rtol or the "
            "master's), from the local error")
        self.version = str(getattr(hfdi, "__version__", ""))
        self.license = "MIT"
        stop = float(meta.get("stop_time") or 1.0)
        self.default_experiment = DefaultExperiment(start_time=0.0, stop_time=stop,
                                                    step_size=stop / 100.0)

        self._params = dict(_SOLVER_DEFAULTS)
        self._mparams = {}                   # constructor keyword -> value
        self._start_time = 0.0
        self._stop_time = None
        self._phase = "instantiated"
        self._itg = None                     # the hfdi.Integrator, from exitInitializationMode on
        self._itg_key = None                 # (params, model params, t0, stop) it was made with
        self._F_input = np.zeros(n)          # inputs as last set by the master
        self._F_applied = np.zeros(n)        # inputs the integrator's current state was computed with
        self._cache = None                   # outputs at the current state, computed on demand
        self._scales = (0.0, 0.0)            # largest |u|, |v| at the communication points
        self._state_outputs = {}             # value reference of u[i], v[i], a[i] -> (key, i)
        self._inputs = {}                    # value reference of F[i + 1] -> i
        self._read_plans = {}                # references -> how get_real reads them (_read_plan)
        self._gate = None                    # the native layer's gate (attach_native_gate)
        self._native = None                  # hfdi.compiled.NativeAdvance of self._itg

        dof_pattern = meta.get("dofs") or [["m", "degree of freedom {k}"]]
        self._dof_units = [dof_pattern[i % len(dof_pattern)][0] for i in range(n)]
        self._dof_labels = [dof_pattern[i % len(dof_pattern)][1].format(
            k=i // len(dof_pattern) + 1, k0=i // len(dof_pattern)) for i in range(n)]
        self._layout_quantities(model, meta.get("quantities") or {})
        # the event functions the model declares (docs/user-models.md, "Events"):
        # per function, the count of its zeros and the time of the last one
        declared = list(getattr(model, "events", None) or ())
        terminal = [k for k, g in enumerate(declared) if getattr(g, "terminal", False)]
        if terminal:
            raise FmuError(f"model {name!r} declares terminal event functions ({terminal}): "
                           "an FMU of it would have to stop the co-simulation, which this "
                           "FMU does not do")
        self._event_names = [_event_label(k, g) for k, g in enumerate(declared)]
        self._event_count = [0] * len(self._event_names)
        self._event_time = [0.0] * len(self._event_names)
        self._register_parameters(meta.get("parameters") or {})
        self._register_inputs()
        self._register_outputs()
        self._register_events()
        # the independent variable, last: the references above stay those of
        # FMUs built before it
        self.register_variable(_Time("time", unit="s", description="simulation time",
                                     causality=Fmi2Causality.local,
                                     variability=Fmi2Variability.continuous,
                                     getter=self.time, setter=self._time_setter))

    # -- variables --------------------------------------------------------------
    def _layout_quantities(self, model, qmeta):
        """Which quantities of interest become outputs, and their sizes."""
        u0 = np.zeros(self._n) if model.initial_displacement is None \
            else np.asarray(model.initial_displacement, dtype=float)
        v0 = np.zeros(self._n) if model.initial_velocity is None \
            else np.asarray(model.initial_velocity, dtype=float)
        values = model.quantities(np.array([0.0]), u0[None, :], v0[None, :])
        state = {"u": u0, "v": v0}
        self._zlayout = []                    # (quantity name, offset, width)
        self._zvars = []                      # (FMU name, unit, description)
        offset = 0
        for qname, value in values.items():
            arr = np.asarray(value, dtype=float)
            width = int(arr.size)             # one time: (1, m) or (1,)
            if qname in state and width == self._n \
                    and np.array_equal(arr.reshape(-1), state[qname]):
                continue                      # the same as the u[i] outputs
            unit, text, labels = (list(qmeta.get(qname, [])) + [None, None, None])[:3]
            unit = unit or "1"
            text = text or f"quantity of interest {qname!r}"
            base = re.sub(r"\W", "_", str(qname))
            if base in _RESERVED or base in self._defaults or not base[:1].isalpha():
                base = "z." + base
            for k in range(width):
                if width == 1:
                    self._zvars.append((base, unit, text))
                else:
                    label = labels[k] if labels and k < len(labels) else f"component {k + 1}"
                    self._zvars.append((f"{base}[{k + 1}]", unit,
                                        f"{text}: {label} ({k + 1} of {width})"))
            self._zlayout.append((qname, offset, width))
            offset += width
        self._nz = offset

    def _register_parameters(self, pmeta):
        fixed = dict(causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed)
        self.register_variable(String(
            "scheme", description="integration scheme: newmark, bathe, hfdi or "
            "generalized_alpha",
            getter=lambda: self._params["scheme"],
            setter=self._param_setter("scheme", str), **fixed))
        solver = [
            ("target_iterations", "1", "target Newton iterations per (sub-)step N-bar "
                                       "(paper Eq. 39), in [1, 100]; 0: not used (error "
                                       "control alone). With an rtol in force both rules "
                                       "apply (combined mode)"),
            ("rtol", "1", "relative tolerance of the local error of u and v (error "
                          "control), in [1e-13, 0.1); 0: the master's tolerance of "
                          "fmi2SetupExperiment when it defines one, else "
                          + (f"{self._hfdi.DEFAULT_RTOL:g} (the model has event "
                             "functions, whose zeros the iteration count alone misses)"
                             if self._event_names else "none")),
            ("tolerance", "1", "Newton tolerance eta of the corrector (Eq. 38), in "
                               f"[{self._hfdi.controller.TOL_RANGE[0]:g}, 1); "
                               "0: automatic (1e-8, below rtol/1000 under error control)"),
            ("initial_step", "s", "first trial step size; 0: automatic (1/omega_max)"),
            ("max_step", "s", "largest internal step size; 0: no limit"),
        ]
        for key, unit, text in solver:
            self.register_variable(_Real(key, unit=unit, description=text,
                                         getter=(lambda k=key: self._params[k]),
                                         setter=self._param_setter(key, float), **fixed))
        self.register_variable(Boolean(
            "compiled", description="take the internal steps in compiled code (numba: "
            "hfdi.Integrator(compiled=True)); the first instantiation after the FMU is "
            "extracted compiles (said in the log). false: the Python path",
            getter=lambda: self._params["compiled"],
            setter=self._param_setter("compiled", bool), **fixed))
        self.register_variable(String(
            "error_mode", description="what rtol bounds. local: each internal step's local "
            "error, at its share of the tolerance over the experiment (start to stop time), "
            "so that the error of the outputs follows rtol; global: that, and a doStep whose "
            "end would have an estimated global error (global_error_u, global_error_v) above "
            "atol + rtol * (largest |u|, |v| at the communication points) is discarded, the "
            "log naming the rtol that would meet it (a co-simulation cannot be rerun from "
            "inside; needs rtol)",
            getter=lambda: self._params["error_mode"],
            setter=self._param_setter("error_mode", str), **fixed))
        self.register_variable(Integer(
            "max_internal_steps", description="internal steps (diverged attempts included) "
            "one doStep may take, >= 1; a communication step needing more is discarded",
            getter=lambda: self._params["max_internal_steps"],
            setter=self._param_setter("max_internal_steps", int), **fixed))
        for key, default in self._defaults.items():
            fmu_name = f"model.{key}" if key in _RESERVED else key
            unit, text = (list(pmeta.get(key, [])) + [None, None])[:2]
            text = (text or "model parameter") + f" (hfdi.models.get({self.model_name!r}, "\
                f"{key}=...))"
            common = dict(description=text, getter=(lambda k=key: self._mparams[k]), **fixed)
            if isinstance(default, bool):
                var = Boolean(fmu_name, setter=self._param_setter(key, bool, True), **common)
            elif isinstance(default, numbers.Integral):
                var = Integer(fmu_name, setter=self._param_setter(key, int, True), **common)
            elif isinstance(default, numbers.Real):
                var = _Real(fmu_name, unit=unit or "1",
                            setter=self._param_setter(key, float, True), **common)
            elif isinstance(default, str):
                var = String(fmu_name, setter=self._param_setter(key, str, True), **common)
            else:
                continue                      # tuples, None: not scalar, the model's default is used
            self._mparams[key] = default.item() if isinstance(default, np.generic) else default
            self.register_variable(var)

    def _param_setter(self, key, convert, model=False):
        def setter(value):
            # _set refuses a parameter after initialization, before any value is set
            # looked up now: fmi2SetFMUstate replaces the dictionaries
            store = self._mparams if model else self._params
            store[key] = convert(value)
            self._cache = None
        return setter

    def _register_inputs(self):
        for i in range(self._n):
            unit = _DERIVED.get(self._dof_units[i], (None, None, "1"))[2]
            variable = _Real(
                f"F[{i + 1}]", unit=unit, causality=Fmi2Causality.input,
                variability=Fmi2Variability.continuous,
                description=f"external force on DOF {i + 1} ({self._dof_labels[i]}), added "
                            "to the model's load and held over each communication step",
                getter=(lambda i=i: self._F_input[i]), setter=self._input_setter(i))
            self.register_variable(variable)
            self._inputs[variable.value_reference] = i

    def _input_setter(self, i):
        def setter(value):
            self._F_input[i] = float(value)
            if self._itg is None:
                # before initialization the outputs show the initial state, whose
                # acceleration depends on the inputs; later they change in doStep only
                self._cache = None
        return setter

    def _register_outputs(self):
        out = dict(causality=Fmi2Causality.output, initial=Fmi2Initial.calculated)
        continuous = dict(variability=Fmi2Variability.continuous, **out)
        n = self._n
        for key, what, index in (("u", "displacement", 0), ("v", "velocity", 1),
                                 ("a", "acceleration", 2)):
            for i in range(n):
                unit = self._dof_units[i] if index == 0 else \
                    _DERIVED.get(self._dof_units[i], (self._dof_units[i] + "/s",
                                                      self._dof_units[i] + "/s2", "1"))[index - 1]
                variable = _Real(
                    f"{key}[{i + 1}]", unit=unit,
                    description=f"{what} {key} of DOF {i + 1} of {n} ({self._dof_labels[i]}; "
                                f"hfdi index {i})",
                    getter=(lambda k=key, i=i: self._outputs()[k][i]), **continuous)
                self.register_variable(variable)
                self._state_outputs[variable.value_reference] = (key, i)
        for j, (name, unit, text) in enumerate(self._zvars):
            self.register_variable(_Real(name, unit=unit, description=text,
                                         getter=(lambda j=j: self._quantities()[j]),
                                         **continuous))
        self.register_variable(_Real(
            "W", unit="J", description="total energy W = V + T at the communication point",
            getter=lambda: self._outputs()["W"], **continuous))
        self.register_variable(_Real(
            "dE", unit="J", description="cumulative energy error: sum of Delta E of the "
                                        "accepted steps (paper Eq. 40)",
            getter=lambda: self._outputs()["dE"], **continuous))
        for part, index in (("u", 0), ("v", 1)):
            unit = self._dof_units[0] if index == 0 else _DERIVED.get(
                self._dof_units[0], (self._dof_units[0] + "/s",))[0]
            if len(set(self._dof_units)) > 1:
                unit = "1"
            self.register_variable(_Real(
                f"global_error_{part}", unit=unit,
                description=f"estimated global error of {part}: its largest component "
                            f"(the local error estimates carried through the linearised "
                            f"motion; NaN where it was lost)",
                getter=(lambda k=f"g_{part}": self._outputs()[k]), **continuous))
        discrete = dict(variability=Fmi2Variability.discrete, **out)
        self.register_variable(Integer(
            "internal_steps", description="predictor-corrector steps since the start, "
                                          "diverged attempts included",
            getter=lambda: self._outputs()["steps"], **discrete))
        self.register_variable(Integer(
            "newton_iterations", description="Newton corrections since the start, diverged "
                                             "attempts included",
            getter=lambda: self._outputs()["iterations"], **discrete))

    def _register_events(self):
        discrete = dict(causality=Fmi2Causality.output, initial=Fmi2Initial.calculated,
                        variability=Fmi2Variability.discrete)
        for k, label in enumerate(self._event_names):
            self.register_variable(Integer(
                f"event_count[{k + 1}]", description=f"zeros of the model's event function "
                f"{k + 1}, {label}, since the start (counted where they happen, inside the "
                f"communication steps)", getter=(lambda k=k: self._event_count[k]),
                **discrete))
            self.register_variable(_Real(
                f"event_time[{k + 1}]", unit="s", description=f"time of the last zero of "
                f"the model's event function {k + 1}, {label}; the start time while "
                f"event_count[{k + 1}] is 0", getter=(lambda k=k: self._event_time[k]),
                **discrete))

    def _time_setter(self, value):
        self._reject(f"time is the independent variable: it changes in doStep only (value "
                     f"{value!r} refused)")

    # -- model description --------------------------------------------------------
    def to_xml(self, model_options=dict()):
        """pythonfmu's model description plus unit definitions, no direct
        feedthrough, and the initial unknowns of the calculated outputs."""
        root = super().to_xml(model_options)
        units = sorted({v.unit for v in self.vars.values() if isinstance(v, _Real) and v.unit})
        definitions = Element("UnitDefinitions")
        for unit in units:
            node = SubElement(definitions, "Unit", {"name": unit})
            base = _BASE_UNITS.get(unit)
            if base:
                SubElement(node, "BaseUnit", {k: str(e) for k, e in base.items()})
        children = list(root)
        root.insert(children.index(root.find("CoSimulation")) + 1, definitions)
        structure = root.find("ModelStructure")
        outputs = structure.find("Outputs")
        if outputs is not None:
            # an output changes only in doStep: it does not depend on the inputs directly
            for unknown in outputs:
                unknown.set("dependencies", "")
        initial = SubElement(structure, "InitialUnknowns")
        for index, var in enumerate(self.vars.values(), start=1):
            if var.causality == Fmi2Causality.output:
                SubElement(initial, "Unknown", {"index": str(index)})
        return root

    # -- life cycle -----------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        if self._phase != "instantiated":
            self._reject(f"fmi2SetupExperiment: the FMU is {_PHASES[self._phase]}; the "
                         "experiment is set up after fmi2Instantiate or fmi2Reset, before "
                         "fmi2EnterInitializationMode")
        start = float(start_time)
        if not math.isfinite(start):
            self._reject(f"fmi2SetupExperiment: start time {start_time!r} is not finite")
        stop = None if stop_time is None else float(stop_time)
        if stop is not None and not (math.isfinite(stop) and stop > start):
            self._reject(f"fmi2SetupExperiment: stop time {stop_time!r} must be finite and "
                         f"after the start time {start!r}")
        rtol = 0.0
        if tolerance is not None:
            low, high = self._hfdi.controller.RTOL_RANGE
            rtol = float(tolerance)
            if not (math.isfinite(rtol) and rtol > 0):
                self._reject(f"fmi2SetupExperiment: tolerance {tolerance!r} is not a "
                             "positive number")
            if not low <= rtol < high:
                clipped = min(max(rtol, low), 0.5 * high)
                self.log(f"fmi2SetupExperiment: tolerance {rtol!r} outside "
                         f"[{low:g}, {high:g}); {clipped:g} is used", Fmi2Status.warning)
                rtol = clipped
        self._start_time, self._stop_time = start, stop
        self._params["master_rtol"] = rtol
        self._event_time = [start] * len(self._event_names)

    def enter_initialization_mode(self):
        if self._phase != "instantiated":
            self._reject(f"fmi2EnterInitializationMode: the FMU is {_PHASES[self._phase]}; "
                         "it enters initialization mode once, after fmi2Instantiate or "
                         "fmi2Reset")
        self._phase = "initialization"

    def exit_initialization_mode(self):
        if self._phase != "initialization":
            # after initialization, starting again from t0 would silently discard
            # the simulation so far; before it, the master skipped a call (FMI 2.0)
            self._reject(f"fmi2ExitInitializationMode: the FMU is {_PHASES[self._phase]}; "
                         f"it exits initialization mode after fmi2EnterInitializationMode")
        try:
            bad = [f"F[{i + 1}] = {float(x)!r}" for i, x in enumerate(self._F_input)
                   if not math.isfinite(x)]
            if bad:
                raise FmuError(f"input {', '.join(bad)} is not finite")
            self._F_applied = self._F_input.copy()
            model, itg = self._make_integrator(self._params, self._mparams, self._start_time,
                                               self._stop_time)
            self._check_outputs_finite(itg)
        except FmuError as exc:
            self._reject(f"initialization rejected: {exc}")
        except Exception as exc:
            self._reject(f"initialization failed: {exc!r}")
        self._itg = itg
        self._itg_key = (dict(self._params), dict(self._mparams), self._start_time,
                         self._stop_time)
        self._event_count = [0] * len(self._event_names)
        self._event_time = [float(self._start_time)] * len(self._event_names)
        self._scales = self._scales_with(itg, (0.0, 0.0))
        self._phase = "stepping"
        self._cache = None
        self._prepare_native()
        self.log(f"{self.model_name}: scheme {self._params['scheme']}, controller "
                 f"{itg.controller!r}, t0 = {self._start_time}, first trial "
                 f"step {itg.proposed_step:.6g}", Fmi2Status.ok)

    def _check_outputs_finite(self, itg):
        """Refuse parameters whose initial outputs are not finite (a length
        scale of 5e-324 puts an infinite stretch among them): a master would
        read them as the state it starts from."""
        state = itg.state
        values = {"W": float(itg.total_energy)}
        try:
            quantities = itg.system.quantities(np.array([state.t]), state.u[None, :],
                                               state.v[None, :])
        except Exception:
            quantities = {}
        for qname, _, _ in self._zlayout:
            if qname in quantities:
                values[qname] = float(np.max(np.abs(np.asarray(quantities[qname], float))))
        bad = [f"{name} = {value!r}" for name, value in values.items() if not math.isfinite(value)]
        if bad:
            changed = [f"{key} = {value!r}" for key, value in self._mparams.items()
                       if value != self._defaults.get(key)]
            raise FmuError(f"the model parameters ({', '.join(changed) or 'defaults'}) give "
                           f"outputs that are not finite at t0: {', '.join(bad)}")

    def terminate(self):
        self._phase = "terminated"

    def _make_integrator(self, params, mparams, start_time, stop_time=None):
        """Check the parameters and make the model and its integrator.

        Raises
        ------
        FmuError
            Naming every parameter that is wrong.
        """
        hfdi = self._hfdi
        errors = []
        scheme = params["scheme"]
        key = str(scheme).strip().lower()
        if key not in hfdi.SCHEMES:
            errors.append(f"parameter scheme = {scheme!r} must be one of "
                          f"{', '.join(sorted(hfdi.SCHEMES))}")
        target = params["target_iterations"]
        if not (_finite_number(target) and (target == 0.0
                                            or 1.0 <= target <= _MAX_TARGET_ITERATIONS)):
            errors.append(f"parameter target_iterations = {target!r} must be 0 (not used) "
                          f"or a finite number in [1, {_MAX_TARGET_ITERATIONS:g}]")
        rtol = params["rtol"]
        low, high = hfdi.controller.RTOL_RANGE
        if not (_finite_number(rtol) and (rtol == 0.0 or low <= rtol < high)):
            errors.append(f"parameter rtol = {rtol!r} must be 0 (the master's tolerance or "
                          f"none) or a finite number in [{low:g}, {high:g})")
        tol = params["tolerance"]
        low, high = hfdi.controller.TOL_RANGE
        if not (_finite_number(tol) and (tol == 0.0 or low <= tol < high)):
            errors.append(f"parameter tolerance = {tol!r} must be 0 (automatic) or lie in "
                          f"[{low:g}, {high:g})")
        for name, zero in (("initial_step", "automatic"), ("max_step", "no limit")):
            value = params[name]
            if not (_finite_number(value) and value >= 0.0):
                errors.append(f"parameter {name} = {value!r} must be a finite number >= 0 "
                              f"(0: {zero})")
        mode = params.get("error_mode", "local")
        if mode not in _ERROR_MODES:
            errors.append(f"parameter error_mode = {mode!r} must be one of "
                          f"{', '.join(_ERROR_MODES)}")
        elif mode == "global" and not (rtol or params.get("master_rtol", 0.0)):
            errors.append("parameter error_mode = 'global' needs a tolerance: set rtol, or "
                          "the master's tolerance in fmi2SetupExperiment")
        budget = params["max_internal_steps"]
        if isinstance(budget, bool) or not isinstance(budget, numbers.Integral) or budget < 1:
            errors.append(f"parameter max_internal_steps = {budget!r} must be an integer >= 1")
        changed = {k: v for k, v in mparams.items() if v != self._defaults.get(k)}
        model = None
        try:
            model = hfdi.models.get(self.model_name, **mparams)
        except Exception as exc:
            listed = ", ".join(f"{k} = {v!r}" for k, v in changed.items()) or "the defaults"
            errors.append(f"model parameter(s) {listed} rejected by {self.model_name}: {exc}")
        if model is not None:
            problem = self._structure_problem(model)
            if problem:
                listed = ", ".join(f"{k} = {v!r}" for k, v in changed.items())
                errors.append(f"model parameter(s) {listed}: {problem}; this FMU was built "
                              f"for the model's default structure, rebuild it for others")
        if errors:
            raise FmuError("; ".join(errors))
        # the mode: the paper's rule, error control, or both (docs: fmu/README.md);
        # a model with events is error-controlled whatever is given: the
        # iteration count alone let the steps grow past whole bounces (the
        # impact oscillator to t = 3: 1 impact of 4)
        rtol = float(rtol) or float(params.get("master_rtol", 0.0)) or \
            (hfdi.DEFAULT_RTOL if self._event_names else None)
        target = float(target) or None
        compiled = bool(params["compiled"])
        try:
            itg = hfdi.Integrator(model, key, target_iterations=target, rtol=rtol,
                                  tol=float(tol) or None,
                                  t0=float(start_time),
                                  first_step=float(params["initial_step"]) or None,
                                  max_step=float(params["max_step"]) or None,
                                  max_steps=_UNLIMITED_STEPS, compiled=compiled,
                                  error_span=None if stop_time is None
                                  else float(stop_time) - float(start_time),
                                  extra_load=hfdi.HeldLoad(self._held_input))
        except hfdi.compiled.CompiledUnavailable as exc:
            raise FmuError(f"parameter compiled = true: {exc}") from None
        except Exception as exc:
            model_part = "".join(f", {k} = {v!r}" for k, v in changed.items())
            raise FmuError(f"the integrator rejected the parameters (scheme = {scheme!r}, "
                           f"target_iterations = {target!r}, rtol = {rtol!r}, "
                           f"tolerance = {tol!r}, "
                           f"initial_step = {params['initial_step']!r}, "
                           f"max_step = {params['max_step']!r}{model_part}): {exc}") from None
        return model, itg

    def _structure_problem(self, model):
        """Why ``model`` does not fit this FMU's variables, or ``""``."""
        if int(model.n_dof) != self._n:
            return f"the model has {model.n_dof} DOFs instead of {self._n}"
        u0 = np.zeros(self._n) if model.initial_displacement is None \
            else np.asarray(model.initial_displacement, dtype=float)
        v0 = np.zeros(self._n) if model.initial_velocity is None \
            else np.asarray(model.initial_velocity, dtype=float)
        values = model.quantities(np.array([0.0]), u0[None, :], v0[None, :])
        for qname, _, width in self._zlayout:
            if qname not in values or np.asarray(values[qname]).size != width:
                return f"quantity {qname!r} no longer has {width} component(s)"
        return ""

    def _held_input(self):
        # the input held over the current communication step (a hfdi.HeldLoad)
        return self._F_applied

    # -- stepping -------------------------------------------------------------------
    def do_step(self, current_time, step_size, early_return=False):
        """Advance to ``current_time + step_size`` exactly.

        Returns ``False`` (``fmi2Discard``) when the step cannot be taken; the
        FMU is then back at ``current_time`` (the time the native layer reports
        as ``fmi2LastSuccessfulTime``), with its outputs there, and the log says
        why. Raises :class:`FmuError` (``fmi2Error``, nothing changed) only for a
        step past the experiment's stop time.

        ``early_return`` (FMI 3.0's ``earlyReturnAllowed``): stop at the first
        zero of a model's event function after the step's start, after its
        reset; :meth:`time` is then the zero's time, before the step's end.
        """
        snapshot = None
        try:
            itg = self._itg
            t, h = float(current_time), float(step_size)
            if itg is None:
                return self._discard(f"doStep({t}, {h}) before a successful "
                                     "exitInitializationMode")
            if self._phase == "terminated":
                return self._discard(f"doStep({t}, {h}) after fmi2Terminate")
            if not math.isfinite(t):
                return self._discard(f"doStep({t}, {h}): the current communication point "
                                     "must be finite")
            if not (math.isfinite(h) and h > 0.0):
                return self._discard(f"doStep({t}, {h}): the step size must be positive "
                                     "and finite")
            here = itg.t
            if abs(t - here) > max(64.0 * math.ulp(max(abs(t), abs(here))), 1e-10 * h):
                return self._discard(f"doStep({t}, {h}) but the FMU is at t = {here!r}; "
                                     "restore an FMU state to go back")
            # inputs already applied were checked then (lists: np.array_equal costs 4x)
            inputs_changed = self._F_input.tolist() != self._F_applied.tolist()
            if inputs_changed:
                bad = [f"F[{i + 1}] = {float(x)!r}" for i, x in enumerate(self._F_input)
                       if not math.isfinite(x)]
                if bad:
                    return self._discard(f"doStep({t}, {h}): input {', '.join(bad)} is not "
                                         "finite")
            t_end = t + h
            if not t_end > here:
                return self._discard(f"doStep({t}, {h}): the step is below the time "
                                     "resolution at t")
            if not math.isfinite(t_end):
                return self._discard(f"doStep({t}, {h}): the end time overflows")
            if t_end > self._stop_limit() + 1e-10 * h:
                # FMI 2.0 (fmi2SetupExperiment), 3.0 (fmi3EnterInitializationMode):
                # past a defined stop time the FMU returns an error; here the
                # error control's share of the tolerance was set for that span
                raise FmuError(f"doStep({t}, {h}) ends at {t_end!r}, past the stop time "
                               f"{self._stop_time!r} that the experiment defined; set up "
                               f"the experiment with a later stop time (or none)")
            budget = int(self._itg_key[0]["max_internal_steps"])
            # the rollback of a failed step: never leaves this object, never written
            snapshot = (itg.get_state(copy_arrays=False), self._F_applied.copy(),
                        list(self._event_count), list(self._event_time))
            if inputs_changed:
                self._apply_inputs()
            # the budget of this doStep as the integrator's step limit: it holds
            # in the compiled driver as in the Python one
            itg.max_steps = itg.statistics.steps + budget
            counted = itg.event_count
            try:
                ok = itg.advance(t_end, until_event=bool(early_return and counted is not None))
            finally:
                itg.max_steps = _UNLIMITED_STEPS
            if counted is not None:
                self._count_events(itg, counted)
            reason = ""
            if not ok:
                reason = f"{itg.status.name}: {itg.message}"
                if itg.status == self._hfdi.Status.MAX_STEPS:
                    reason = (f"max_internal_steps = {budget} internal steps reached at "
                              f"t = {itg.t!r}")
            self._cache = None
            if ok:
                scales = self._scales_with(itg, self._scales)
                missed = self._global_tolerance_missed(itg, scales)
                if not missed:
                    self._scales = scales
                    self._open_gate()
                    return True
                self._rollback(snapshot)
                # an accumulated error: no shorter step undoes it
                return self._discard(f"step [{t!r}, {t_end!r}] rejected ({missed}); back "
                                     f"at t = {t!r}")
            self._rollback(snapshot)
            return self._discard(f"step [{t!r}, {t_end!r}] rejected ({reason}); back at "
                                 f"t = {t!r}: retry with a shorter communication step or "
                                 "other inputs, or restore an earlier FMU state")
        except FmuError:
            raise                 # refused before anything changed: fmi2Error
        except Exception as exc:  # a failed step is a discard, never a refusal
            try:
                if snapshot is not None:
                    self._rollback(snapshot)
            except Exception as again:
                self._itg = None
                self.log(f"rollback failed ({again!r}); restore an FMU state",
                         Fmi2Status.error)
            return self._discard(f"doStep({current_time}, {step_size}) failed: {exc!r}")

    def _stop_limit(self) -> float:
        """The last time a doStep may end at (plus ``1e-10·h``, the slack of
        its time): the stop time and a master's rounding of the sum of its
        steps, 1e-9 of the larger of the stop time and the span (fmpy takes
        the stop time as reached within that relative tolerance), or +inf
        without a stop time. The native layer's ``native_step`` takes it from
        the gate."""
        stop = self._stop_time
        if stop is None:
            return math.inf
        return stop + max(64.0 * math.ulp(abs(stop)),
                          1e-9 * max(abs(stop), stop - self._start_time))

    # -- the native path (fmu/native/hfdi_fmu_core.h: the gate and its protocol) ------
    def attach_native_gate(self, gate, fields):
        """Take the native layer's gate (a ctypes int64 array whose entries are
        named by ``fields``): from now on a doStep of this slave opens it
        (:meth:`_open_gate`)."""
        self._gate = np.frombuffer(gate, dtype=np.int64)
        self._gate_at = {name: i for i, name in enumerate(fields)}
        self._gate_table = None
        self._read_copy = np.empty((3, self._n))      # u, v, a, read on the Python path
        # addresses taken once: ndarray.ctypes costs 1.5 µs a call, and the
        # arrays stay where they are while this slave holds them
        self._read_copy_address = self._read_copy.ctypes.data
        self._gate_table_address = 0
        self._gate_stop = np.full(1, math.inf)         # _stop_limit(), as armed
        self._gate_stop_address = self._gate_stop.ctypes.data

    def _prepare_native(self):
        """The native path's C function for the new integrator, loaded (or
        compiled, once per machine) now rather than at the first doStep."""
        if self._gate is None or not self._itg.compiled:
            return
        try:
            self._native = self._itg.native_advance()
        except Exception as exc:
            self._gate = None
            self.log(f"the native path is off for this instance: {exc!r}", Fmi2Status.warning)
            return
        # said here, once per run: a message at the first native doStep would
        # not come again when the steps are repeated after a restored state
        self.log("doSteps after the first run in the native layer (the compiled driver "
                 "without Python) whenever they need nothing else", Fmi2Status.ok)

    def _open_gate(self):
        """Open the gate after a doStep of this slave. When the integrator runs
        in the compiled driver and the inputs are those applied, arm it: the
        native layer takes the next doSteps, reads the states and writes the
        inputs itself. Otherwise make it readable only: the states, copied
        here, are read there. Never raises: a gate that cannot be opened leaves
        every call to this slave."""
        gate = self._gate
        if gate is None:
            return
        try:
            itg = self._itg
            if itg is None or self._phase != "stepping":
                return
            at = self._gate_at
            table = self._gate_table
            if table is None:
                # value reference of u[i], v[i], a[i] -> its entry in the state
                # arrays (rows u, v, a of N); of F[i] -> -2 - i; of anything else -> -1
                rows = {"u": 0, "v": 1, "a": 2}
                inputs = self._inputs
                size = max([*self._state_outputs, *inputs], default=-1) + 1
                table = np.full(size, -1, dtype=np.int64)
                for vr, (key, i) in self._state_outputs.items():
                    table[vr] = rows[key] * self._n + i
                for vr, i in inputs.items():
                    table[vr] = -2 - i
                self._gate_table = table
                self._gate_table_address = table.ctypes.data
            gate[at["table"]] = self._gate_table_address
            gate[at["table_length"]] = table.size
            native = self._armed_native(itg)
            if native is not None:
                gate[at["function"]] = native.function_address
                gate[at["context"]] = native.context_address
                gate[at["time"]] = native.time_address
                gate[at["state"]] = native.state_address
                gate[at["inputs"]] = self._F_input.ctypes.data
                self._gate_stop[0] = self._stop_limit()
                gate[at["stop"]] = self._gate_stop_address
                gate[at["armed"]] = 1
            else:
                state, copy = itg.state, self._read_copy
                copy[0], copy[1], copy[2] = state.u, state.v, state.a
                gate[at["state"]] = self._read_copy_address
            gate[at["readable"]] = 1
        except Exception as exc:
            self._gate = None
            self.log(f"the native path is off for this instance: {exc!r}", Fmi2Status.warning)

    def _armed_native(self, itg):
        """The integrator's NativeAdvance armed from its state, or ``None`` when
        the next doStep must be this slave's."""
        if not itg.compiled or self._F_input.tolist() != self._F_applied.tolist() \
                or self._itg_key[0].get("error_mode") == "global":
            return None                # global: this slave checks every doStep's end
        native = self._native
        if native is None or native.integrator is not itg:
            native = self._native = itg.native_advance()
        if native.arm(max_steps_per_call=int(self._itg_key[0]["max_internal_steps"]),
                      inputs=self._F_input):
            return None
        return native

    def sync_native(self):
        """Take over the doSteps the native layer took since the gate was armed."""
        gate = self._gate
        if gate is None:
            return
        at = self._gate_at
        cpu_time = float(gate[at["cpu_ns"]]) * 1e-9
        gate[at["cpu_ns"]] = 0
        native = self._native
        if native is not None and native.sync(cpu_time):
            # the inputs the native steps applied (held from their start)
            self._F_applied = native.held
        gate[at["dirty"]] = 0
        self._cache = None

    def _apply_inputs(self):
        """Make the current state consistent with the inputs changed at this
        communication point.

        The state at the start of the step keeps the load and acceleration
        computed with the previous inputs; the schemes read both (Newmark and
        Bathe through ``a_n``, HFDI through ``p_n`` in the load rate, the energy
        balance through the work). They are recomputed with the new inputs, the
        acceleration's right limit at the jump of the load.
        """
        self._F_applied = self._F_input.copy()
        self._itg.load_changed()

    @staticmethod
    def _scales_with(itg, scales):
        """The largest ``|u|`` and ``|v|`` of ``scales`` and the current state."""
        state = itg.state
        return (max(scales[0], float(np.abs(state.u).max())),
                max(scales[1], float(np.abs(state.v).max())))

    def _global_tolerance_missed(self, itg, scales):
        """Under ``error_mode = global``, why the estimated global error misses
        the tolerance now (``hfdi.global_error_ratio`` with the scales of the
        communication points), else ``""``."""
        if self._itg_key[0].get("error_mode") != "global" or itg.tolerances is None:
            return ""
        rtol, atol = itg.tolerances
        ratio = self._hfdi.global_error_ratio(itg.global_error, rtol, atol, *scales)
        if ratio <= 1.0:
            return ""
        if not math.isfinite(ratio):
            return "error_mode = global: the global error estimate was lost"
        return (f"error_mode = global: the estimated global error would be {ratio:.3g} "
                f"times the tolerance at t = {itg.t!r}; rerun the experiment with rtol <= "
                f"{0.5 * float(rtol.min()) / ratio:.3g}")

    def _count_events(self, itg, before):
        """The zeros found since the counts were ``before`` into the event outputs."""
        after = itg.event_count
        last = itg.last_event_times
        for k in np.flatnonzero(after > before):
            self._event_count[k] = min(self._event_count[k] + int(after[k] - before[k]),
                                       _INT32_MAX)
            self._event_time[k] = float(last[k])

    def _rollback(self, snapshot):
        saved, applied, count, times = snapshot
        self._itg.set_state(saved)
        self._F_applied = applied
        self._event_count, self._event_time = count, times
        self._cache = None

    def _discard(self, message):
        self.log(message, Fmi2Status.discard)
        return False

    def _reject(self, message):
        """Refuse the call: :class:`FmuError`, ``fmi2Error`` with ``message``."""
        raise FmuError(message)

    # -- outputs ----------------------------------------------------------------------
    def _outputs(self):
        cache = self._cache
        if cache is None:
            cache = self._cache = self._compute_outputs()
        return cache

    def _compute_outputs(self):
        itg = self._itg
        if itg is None:
            # initialization mode: the initial state the current parameters give
            try:
                self._F_applied = self._F_input.copy()
                _, itg = self._make_integrator(self._params, self._mparams, self._start_time,
                                               self._stop_time)
            except Exception:
                nan = np.full(self._n, np.nan)
                return {"u": nan, "v": nan, "a": nan, "z": np.full(self._nz, np.nan),
                        "W": math.nan, "dE": math.nan, "steps": 0, "iterations": 0, "itg": None,
                        "g_u": math.nan, "g_v": math.nan}
        state, stats = itg.state, itg.statistics
        g = np.abs(itg.global_error)
        n = self._n
        return {"u": state.u, "v": state.v, "a": state.a, "z": None,
                "g_u": float(g[:n].max()), "g_v": float(g[n:].max()),
                "W": float(itg.total_energy), "dE": float(itg.energy_error),
                "steps": min(int(stats.steps), _INT32_MAX),
                "iterations": min(int(stats.newton_iterations), _INT32_MAX), "itg": itg}

    def _quantities(self):
        cache = self._outputs()
        if cache["z"] is None:
            itg = cache["itg"]
            state = itg.state
            z = np.full(self._nz, np.nan)
            try:
                values = itg.system.quantities(np.array([state.t]), state.u[None, :],
                                               state.v[None, :])
                for qname, offset, width in self._zlayout:
                    z[offset:offset + width] = np.asarray(values[qname], dtype=float).reshape(-1)
            except Exception as exc:
                self.log(f"quantities of interest unavailable at t = {state.t!r}: {exc!r}",
                         Fmi2Status.warning)
            cache["z"] = z
        return cache["z"]

    # -- getters and setters: no unguarded exception into the C++ layer --------------
    def _names(self, vrs) -> str:
        """The variables ``vrs`` refer to, for messages (unknown references as numbers)."""
        try:
            return ", ".join(self.vars[vr].name if vr in self.vars else f"#{vr}" for vr in vrs)
        except Exception:  # a message must not raise past _reject
            return repr(vrs)

    def _read_plan(self, vrs):
        """``(keys, picks)`` reading the state outputs ``vrs`` (``u[i]``, ``v[i]``,
        ``a[i]``): the arrays to read and, per reference, ``(array, index)``;
        ``None`` when another variable is among them. Kept for the next call
        with the same references (a master reads the same ones after every
        doStep), up to a few dozen lists."""
        where = self._state_outputs
        if not all(vr in where for vr in vrs):
            return None
        keys = sorted({where[vr][0] for vr in vrs})
        plan = keys, [(keys.index(where[vr][0]), where[vr][1]) for vr in vrs]
        if len(self._read_plans) < 64:
            self._read_plans[tuple(vrs)] = plan
        return plan

    def get_real(self, vrs):
        try:
            # a master reads the states after every doStep: those straight from
            # the outputs, without a getter call per variable
            try:
                keys, picks = self._read_plans[tuple(vrs)]
            except KeyError:
                plan = self._read_plan(vrs)
                if plan is None:
                    return super().get_real(vrs)
                keys, picks = plan
            except TypeError:
                return super().get_real(vrs)
            if self._itg is not None:       # the current state itself, no other output
                state = self._itg.state
                rows = [getattr(state, key).tolist() for key in keys]
            else:
                outputs = self._outputs()
                rows = [np.asarray(outputs[key], dtype=float).tolist() for key in keys]
            return [rows[k][i] for k, i in picks]
        except Exception as exc:
            self._reject(f"fmi2GetReal({self._names(vrs)}): {exc!r}")

    def get_integer(self, vrs):
        try:
            return super().get_integer(vrs)
        except Exception as exc:
            self._reject(f"fmi2GetInteger({self._names(vrs)}): {exc!r}")

    def get_boolean(self, vrs):
        try:
            return super().get_boolean(vrs)
        except Exception as exc:
            self._reject(f"fmi2GetBoolean({self._names(vrs)}): {exc!r}")

    def get_string(self, vrs):
        try:
            return super().get_string(vrs)
        except Exception as exc:
            self._reject(f"fmi2GetString({self._names(vrs)}): {exc!r}")

    def _set(self, setter, function, kind, vrs, values):
        # every reference and its type are checked before any value is set: a
        # call that fails must leave the FMU as it was (FMI: fmi2Error changes
        # nothing)
        try:
            vrs, values = list(vrs), list(values)
            if len(vrs) != len(values):
                raise ValueError(f"{len(vrs)} value references, {len(values)} values")
            unknown = [vr for vr in vrs if vr not in self.vars]
            if unknown:
                raise KeyError(unknown[0])
            other = [self.vars[vr] for vr in vrs if not isinstance(self.vars[vr], kind)]
            if other:
                raise TypeError(f"{other[0].name} is not of type {kind.__name__} (it is a "
                                f"{type(other[0]).__name__.strip('_')} variable)")
            convert = {Real: float, Integer: int, Boolean: bool, String: str}[kind]
            values = [convert(value) for value in values]
        except Exception as exc:
            self._reject(f"{function}({self._names(vrs)}): {exc!r}; no value was set")
        late = self._phase not in ("instantiated", "initialization")
        for vr in vrs:
            var = self.vars[vr]
            # FMI: after initialization only inputs (and tunable parameters,
            # which this FMU has none of) are set; outputs never
            if var.causality == Fmi2Causality.output:
                self._reject(f"{function}({self._names(vrs)}): {var.name} is an output; "
                             f"outputs cannot be set; no value was set")
            if late and var.causality == Fmi2Causality.parameter:
                self._reject(f"{function}({self._names(vrs)}): parameter {var.name} is fixed "
                             f"after initialization; no value was set")
        try:
            setter(vrs, values)
        except Exception as exc:
            self._reject(f"{function}({self._names(vrs)}): {exc!r}")

    def set_real(self, vrs, values):
        self._set(super().set_real, "fmi2SetReal", Real, vrs, values)

    def set_integer(self, vrs, values):
        self._set(super().set_integer, "fmi2SetInteger", Integer, vrs, values)

    def set_boolean(self, vrs, values):
        self._set(super().set_boolean, "fmi2SetBoolean", Boolean, vrs, values)

    def set_string(self, vrs, values):
        self._set(super().set_string, "fmi2SetString", String, vrs, values)

    def time(self) -> float:
        """The FMU's time: that of its integrator's state, the start time before
        initialization (``fmi2LastSuccessfulTime``)."""
        return float(self._itg.t) if self._itg is not None else float(self._start_time)

    # -- FMU state ------------------------------------------------------------------------
    def _get_fmu_state(self):
        """Everything the continuation depends on: parameters, inputs and the
        integrator's whole state (:meth:`hfdi.Integrator.get_state`)."""
        try:
            return {"model": self.model_name, "bundle": self.bundle, "phase": self._phase,
                    "params": dict(self._params), "mparams": dict(self._mparams),
                    "start_time": self._start_time, "stop_time": self._stop_time,
                    "scales": list(self._scales),
                    "events": [list(self._event_count), list(self._event_time)],
                    "inputs": self._F_input.copy(), "applied": self._F_applied.copy(),
                    "integrator": None if self._itg is None else self._itg.get_state(),
                    "built": None if self._itg_key is None else
                    (dict(self._itg_key[0]), dict(self._itg_key[1]), self._itg_key[2],
                     self._itg_key[3])}
        except Exception as exc:
            self._reject(f"fmi2GetFMUstate failed: {exc!r}")

    def _set_fmu_state(self, state):
        # everything is read and checked before anything changes: a state that
        # is refused leaves the FMU as it was
        try:
            if not isinstance(state, dict) or state.get("model") != self.model_name \
                    or state.get("bundle") != self.bundle:
                raise FmuError(f"the state was not made by this FMU (model {self.model_name!r}, "
                               f"build {self.bundle})")
            params = _like("parameters", state["params"], self._params)
            mparams = _like("model parameters", state["mparams"], self._mparams)
            start_time, stop_time = state["start_time"], state["stop_time"]
            scales = state["scales"]
            if not (isinstance(scales, (list, tuple)) and len(scales) == 2 and all(
                    isinstance(x, float) and math.isfinite(x) and x >= 0 for x in scales)):
                raise FmuError("the state is malformed")
            events = state["events"]
            m = len(self._event_names)
            if not (isinstance(events, (list, tuple)) and len(events) == 2
                    and all(isinstance(x, (list, tuple)) and len(x) == m for x in events)
                    and all(isinstance(c, int) and not isinstance(c, bool)
                            and 0 <= c <= _INT32_MAX for c in events[0])
                    and all(isinstance(x, float) and math.isfinite(x) for x in events[1])):
                raise FmuError("the state is malformed (its event outputs)")
            inputs = np.array(state["inputs"], dtype=float)
            applied = np.array(state["applied"], dtype=float)
            phase = state["phase"]
            # inputs may be non-finite: the master may set any value, and a
            # step with it is discarded, not refused here
            if phase not in _PHASES or inputs.shape != (self._n,) \
                    or applied.shape != (self._n,) \
                    or not all(t is None or (isinstance(t, float) and math.isfinite(t))
                               for t in (start_time, stop_time)):
                raise FmuError("the state is malformed")
            saved = state["integrator"]
            # an initialized FMU has its integrator, one not yet initialized none:
            # a state that says otherwise (a damaged one) would leave the FMU
            # stepping without an integrator, or initializing with one
            if (phase == "stepping") != (saved is not None) and phase != "terminated":
                raise FmuError(f"the state is malformed: it is {_PHASES.get(phase, phase)} "
                               f"{'without' if saved is None else 'with'} an integrator")
            if isinstance(saved, bytes):
                saved = self._hfdi.IntegratorState.from_bytes(saved)
            itg = key = None
            if saved is not None:
                key = state["built"]
                key = (_like("parameters", key[0], self._params),
                       _like("model parameters", key[1], self._mparams), key[2], key[3])
                if not (isinstance(key[2], float) and math.isfinite(key[2])) or not (
                        key[3] is None or isinstance(key[3], float) and math.isfinite(key[3])
                        and key[3] > key[2]):
                    raise FmuError("the state is malformed")
                # the parameters an initialized FMU reports are those its
                # integrator was built with (they are fixed from then on)
                if (params, mparams, start_time, stop_time) != key:
                    raise FmuError("the state is inconsistent: its parameters or experiment "
                                   "differ from those its integrator was built with")
                if self._itg is not None and self._itg_key == key:
                    itg = self._itg
                else:
                    # The integrator checks its initial state, made with the inputs
                    # _held_input returns; set_state replaces that state, so it is
                    # made without inputs, which the model was valid with.
                    current, self._F_applied = self._F_applied, np.zeros(self._n)
                    try:
                        itg = self._make_integrator(*key)[1]
                    finally:
                        self._F_applied = current
                itg.set_state(saved)
            self._itg, self._itg_key = itg, key
            self._params, self._mparams = params, mparams
            self._start_time, self._stop_time = start_time, stop_time
            self._scales = (scales[0], scales[1])
            self._event_count, self._event_time = list(events[0]), list(events[1])
            self._F_input, self._F_applied = inputs, applied
            self._phase = phase
            self._cache = None
        except Exception as exc:
            self._reject(f"fmi2SetFMUstate: cannot restore the state: {exc}")

    def serialize_state(self, state) -> bytes:
        """``fmi2SerializeFMUstate``: the magic line, then data only
        (:mod:`hfdi.serial`): a JSON header (the FMU's parameters and phase),
        the inputs and the integrator's own bytes (``IntegratorState.to_bytes``)."""
        try:
            header = {key: state[key] for key in _STATE_HEADER}
            header["built"] = state["built"]
            arrays = {"inputs": np.asarray(state["inputs"], dtype=np.float64),
                      "applied": np.asarray(state["applied"], dtype=np.float64)}
            saved = state["integrator"]
            if saved is not None:
                # bytes when the state itself came from bytes (deserialize_state)
                arrays["integrator"] = np.frombuffer(
                    saved if isinstance(saved, bytes) else saved.to_bytes(), dtype=np.uint8)
            return _MAGIC + self._hfdi.serial.pack(header, arrays)
        except Exception as exc:
            self._reject(f"fmi2SerializeFMUstate: the state cannot be serialized: {exc!r}")

    def deserialize_state(self, data):
        """``fmi2DeSerializeFMUstate``: the state of :meth:`serialize_state`'s
        bytes. Nothing in them is ever run; the integrator's part stays bytes
        here, decoded and checked by ``fmi2SetFMUstate`` (:meth:`_set_fmu_state`)
        before anything changes."""
        data = bytes(data)
        if not data.startswith(_MAGIC):
            self._reject("fmi2DeSerializeFMUstate: the bytes are not a serialized hfdi FMU "
                         "state")
        try:
            header, arrays = self._hfdi.serial.unpack(data[len(_MAGIC):])
        except ValueError as exc:
            self._reject(f"fmi2DeSerializeFMUstate: the serialized state cannot be read: {exc}")
        if set(header) != set(_STATE_HEADER) | {"built"} or \
                set(arrays) - {"integrator"} != {"inputs", "applied"} or \
                any(arrays[key].dtype != np.float64 for key in ("inputs", "applied")):
            self._reject("fmi2DeSerializeFMUstate: the serialized state is malformed")
        built = header.pop("built")
        if built is not None:
            if not (isinstance(built, list) and len(built) == 4
                    and isinstance(built[0], dict) and isinstance(built[1], dict)):
                self._reject("fmi2DeSerializeFMUstate: the serialized state's integrator key "
                             "is malformed")
            built = (built[0], built[1], built[2], built[3])
        integrator = arrays.get("integrator")
        return dict(header, built=built, inputs=arrays["inputs"], applied=arrays["applied"],
                    integrator=None if integrator is None else integrator.tobytes())
