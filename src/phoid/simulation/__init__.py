"""phoid.simulation."""

from phoid.simulation.core import (
    Simulation,
    simulate,
)

__all__ = [
    "Simulation",
    "simulate",
]
