"""phoid.simulation: the batched time-domain simulator of the PHO loop.

Modules
-------
response
    The public entry points :func:`simulate` (checks the inputs and dispatches) and
    :func:`release_response`.
result
    The :class:`Simulation` result.
_checks
    Input checks and size limits (:data:`MAX_SAMPLES`, :data:`MAX_STEPS`).
_propagation
    The exact step propagator of the plant and the polynomial helpers.
_continuous
    The continuous delayed loop (Δt > 0 and Δt = 0): grid, blocks, drivers.
_sampled
    The sampled (digital) control loop.
_stickslip
    Coulomb friction (stick–slip) on the exact propagation.
tracking
    The industrial sampled PD loop tracking a reference (:func:`simulate_tracking`), exact.
"""

from phoid.simulation._checks import MAX_SAMPLES, MAX_STEPS
from phoid.simulation.response import release_response, simulate
from phoid.simulation.result import Simulation
from phoid.simulation.tracking import ExactPlant, TrackingSimulation, simulate_tracking

__all__ = [
    "MAX_SAMPLES",
    "MAX_STEPS",
    "ExactPlant",
    "Simulation",
    "TrackingSimulation",
    "release_response",
    "simulate",
    "simulate_tracking",
]
