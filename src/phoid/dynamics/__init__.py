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
zoh
    The plant's zero-order-hold discretisation over one controller period.
velocity
    The velocity estimators of a sampled controller (the one list of presets, and FIR).
digital
    The sampled (digital) PD loop: exact characteristic polynomial, roots and modes.
controller
    The industrial sampled PD controller (reference, any velocity filter, fractional delay,
    saturation, command gain) and its linear closed-loop poles.
"""

from phoid.dynamics.controller import (
    SampledController,
    closed_loop_poles,
    zoh_pieces,
)
from phoid.dynamics.counting import count_roots_right_of, count_roots_right_of_many
from phoid.dynamics.digital import (
    VELOCITY_ESTIMATORS,
    DigitalPD,
    DigitalRoots,
    characteristic_coefficients,
    digital_characteristic,
    digital_coefficients,
    digital_is_dominant,
    digital_is_stable,
    digital_modes,
    digital_residues,
    digital_roots,
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
from phoid.dynamics.velocity import (
    FIRST_ORDER_PRESETS,
    VELOCITY_PRESETS,
    VelocityFilter,
    estimator_taps,
)
from phoid.dynamics.zoh import ZOHPlant, expm_stack, zoh_plant

__all__ = [
    "FIRST_ORDER_PRESETS",
    "VELOCITY_ESTIMATORS",
    "VELOCITY_PRESETS",
    "DelayedPD",
    "DigitalPD",
    "DigitalRoots",
    "LoopModes",
    "Plant",
    "SampledController",
    "VelocityFilter",
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
    "estimator_taps",
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
