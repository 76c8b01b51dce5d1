"""HFDI: an adaptive predictor–corrector time integrator for ``M u'' + C u' + f(u) = p(t)``.

Implements the Newmark (average acceleration), Bathe (two sub-steps), HFDI and
generalized-α schemes with the 4th-order extrapolation predictor, the Newton
corrector and the iteration-count step-size rule of "A predictor–corrector
time integration algorithm for dynamic analysis of nonlinear systems" (2020),
and error control beside it.
"""
from . import models, spectral
from .controller import (DEFAULT_RTOL, Combined, Controller, ErrorControl, FixedStep,
                         IterationCount, IterationCountController)
from .dense import Solution
from .evaluation import ModelError, State
from .integrate import integrate
from .integrator import Integrator
from .integrator_state import IntegratorState
from .messages import Status
from .result import Result, Statistics, global_error_ratio
from .schemes import (HFDI, PAPER_SCHEMES, SCHEMES, Bathe, GeneralizedAlpha, Newmark, Scheme,
                      get_scheme)
from .system import (DerivativeCheck, HeldLoad, LinearSystem, SecondOrderSystem, System,
                     check_derivatives)

__version__ = "0.1.0"

__all__ = [
    "integrate", "Integrator", "IntegratorState", "Result", "Statistics", "Status", "State",
    "global_error_ratio",
    "Scheme", "Newmark", "Bathe", "HFDI", "GeneralizedAlpha", "SCHEMES", "PAPER_SCHEMES",
    "get_scheme", "Controller", "ErrorControl", "IterationCount", "Combined", "FixedStep",
    "IterationCountController", "DEFAULT_RTOL", "Solution",
    "SecondOrderSystem", "System", "LinearSystem", "HeldLoad", "check_derivatives",
    "DerivativeCheck", "ModelError", "models", "spectral",
]
