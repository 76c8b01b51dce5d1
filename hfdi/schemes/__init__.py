"""The implicit one-step schemes, one file each, and their registry.

A scheme is a small immutable object and a *stage function*
``stage(h, index, params) -> Stage`` (docs/algorithm.md, "Decision: a scheme
is its stage function"); a new scheme is one file here and one line in
:data:`SCHEMES`.
"""
from __future__ import annotations

from .bathe import Bathe
from .base import Scheme
from .generalized_alpha import GeneralizedAlpha
from .hfdi import HFDI
from .newmark import Newmark

__all__ = ["Scheme", "Newmark", "Bathe", "HFDI", "GeneralizedAlpha", "SCHEMES",
           "PAPER_SCHEMES", "get_scheme"]

#: Every scheme by name.
SCHEMES = {"newmark": Newmark, "bathe": Bathe, "hfdi": HFDI,
           "generalized_alpha": GeneralizedAlpha}

#: The schemes of the paper's tables, in its order.
PAPER_SCHEMES = ("newmark", "bathe", "hfdi")


def get_scheme(scheme) -> Scheme:
    """A scheme object from a name (a key of :data:`SCHEMES`) or an object."""
    if isinstance(scheme, Scheme):
        return scheme
    if isinstance(scheme, str) and scheme.lower() in SCHEMES:
        return SCHEMES[scheme.lower()]()
    raise ValueError(f"scheme must be one of {sorted(SCHEMES)} or a hfdi.Scheme, got {scheme!r}")
