"""phoid.dynamics: the maths of the plant and of its feedback loops (continuous and sampled).

Modules
-------
plant
    The second-order plant (seed eq. 1) and its free response.
quasipolynomial
    The delayed PD loop's characteristic function f(s) and its Newton refinement.
counting
    Certified counts of its roots right of an abscissa (the argument principle).
rightmost
    Its rightmost roots, certified; many runs by continuation; dominant roots.
loop
    The delayed PD loop (eq. 23): gains, roots, α₁, α₂ and the forward and inverse maps.
digital
    The sampled (digital) PD loop: exact characteristic polynomial, roots and modes.
controller
    The industrial sampled PD controller (reference, any velocity filter, fractional delay,
    saturation, command gain) and its linear closed-loop poles.
"""

from phoid.dynamics.controller import (
    VELOCITY_PRESETS,
    SampledController,
    closed_loop_poles,
    zoh_pieces,
)
from phoid.dynamics.counting import count_roots_right_of, count_roots_right_of_many
from phoid.dynamics.digital import (
    VELOCITY_ESTIMATORS,
    DigitalPD,
    DigitalRoots,
    ZOHPlant,
    characteristic_coefficients,
    digital_characteristic,
    digital_coefficients,
    digital_is_dominant,
    digital_is_stable,
    digital_modes,
    digital_residues,
    digital_roots,
    expm_stack,
    zoh_plant,
)
from phoid.dynamics.loop import (
    DelayedPD,
    LoopModes,
    alphas,
    characteristic_roots,
    forward_map,
    inverse_map,
    is_stable,
)
from phoid.dynamics.plant import (
    Plant,
    free_response,
    modal_basis,
    quadratic_roots,
)
from phoid.dynamics.quasipolynomial import characteristic
from phoid.dynamics.rightmost import dominant_roots, rightmost_roots, rightmost_roots_many

__all__ = [
    "VELOCITY_ESTIMATORS",
    "VELOCITY_PRESETS",
    "DelayedPD",
    "DigitalPD",
    "DigitalRoots",
    "LoopModes",
    "Plant",
    "SampledController",
    "ZOHPlant",
    "alphas",
    "characteristic",
    "characteristic_coefficients",
    "characteristic_roots",
    "closed_loop_poles",
    "count_roots_right_of",
    "count_roots_right_of_many",
    "digital_characteristic",
    "digital_coefficients",
    "digital_is_dominant",
    "digital_is_stable",
    "digital_modes",
    "digital_residues",
    "digital_roots",
    "dominant_roots",
    "expm_stack",
    "forward_map",
    "free_response",
    "inverse_map",
    "is_stable",
    "modal_basis",
    "quadratic_roots",
    "rightmost_roots",
    "rightmost_roots_many",
    "zoh_pieces",
    "zoh_plant",
]
