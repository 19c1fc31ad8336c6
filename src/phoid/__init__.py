"""phoid — identify m, c, k (and f_c, Δt) of second-order systems by parametric oscillation.

The public API is re-exported here; see the module docstrings for the seed-paper equations each
function implements.

>>> import phoid
>>> result = phoid.identify(phoid.read_experiment("../shared/data/paper-sample"))  # doctest: +SKIP
>>> print(result.report())  # doctest: +SKIP
"""

from phoid.decay import DecayFit, detect_release, fit_decay, logdec
from phoid.errors import ExperimentError, IdentificationError, PhoidError
from phoid.identification import Identification, RunMode, identify, identify_data
from phoid.io import ExperimentSet, Run, read_experiment, run_from_arrays, write_experiment
from phoid.loop import (
    DelayedPD,
    LoopModes,
    alphas,
    characteristic_roots,
    forward_map,
    inverse_map,
    is_stable,
)
from phoid.pho import Estimate, MCKFit, fit_lines, fit_modes
from phoid.plant import Plant, free_response
from phoid.simulation import Simulation, simulate

__version__ = "0.1.0"

__all__ = [
    "DecayFit",
    "DelayedPD",
    "Estimate",
    "ExperimentError",
    "ExperimentSet",
    "Identification",
    "IdentificationError",
    "LoopModes",
    "MCKFit",
    "PhoidError",
    "Plant",
    "Run",
    "RunMode",
    "Simulation",
    "__version__",
    "alphas",
    "characteristic_roots",
    "detect_release",
    "fit_decay",
    "fit_lines",
    "fit_modes",
    "forward_map",
    "free_response",
    "identify",
    "identify_data",
    "inverse_map",
    "is_stable",
    "logdec",
    "read_experiment",
    "run_from_arrays",
    "simulate",
    "write_experiment",
]
