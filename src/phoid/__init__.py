"""phoid — identify m, c, k (and f_c, Δt) of second-order systems by parametric oscillation.

The public API is re-exported here; see the module docstrings for the seed-paper equations each
function implements.
"""

from phoid.errors import ExperimentError, IdentificationError, PhoidError
from phoid.loop import (
    DelayedPD,
    LoopModes,
    alphas,
    characteristic_roots,
    forward_map,
    inverse_map,
    is_stable,
)
from phoid.plant import Plant, free_response

__version__ = "0.1.0"

__all__ = [
    "DelayedPD",
    "ExperimentError",
    "IdentificationError",
    "LoopModes",
    "PhoidError",
    "Plant",
    "__version__",
    "alphas",
    "characteristic_roots",
    "forward_map",
    "free_response",
    "inverse_map",
    "is_stable",
]
