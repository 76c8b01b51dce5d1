"""The compiled hat-pulse load (imports numba): :func:`hfdi.models.loads.hat_load`
compiled, with no pulse the zero load. A model with another load history
writes its own kernel of signature :data:`hfdi.compiled.signatures.LOAD`
(docs/compiled.md)."""
from __future__ import annotations

from ..models.kernels import compiled
from ..models.loads import hat_load as _hat_load
from ..models.loads import hat_load_params

__all__ = ["hat_load", "hat_load_params"]

hat_load = compiled(_hat_load)
