"""Derivatives of position functions: jets (truncated Taylor numbers, :mod:`.jet`), tapes traced
from a function (:mod:`.tracing`), finite-difference stencils (:mod:`.stencil`)."""

#: how the engine takes the derivatives of the position functions: the seed's central
#: differences (an O(Δ²) error in q̈) or exact ones (jets, generated kernels)
SCHEMES = ("central", "autodiff")

__all__ = ["SCHEMES"]
