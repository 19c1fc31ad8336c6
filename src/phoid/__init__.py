"""phoid — identify m, c, k (and f_c, Δt) of second-order systems by parametric oscillation.

The public API is re-exported here; see the module docstrings for the seed-paper equations each
function implements, and docs/equations.md for those equations and their corrections (ERRATA
1–6) explained.

>>> import phoid
>>> # from the repository's root: the example set in examples/ (examples/README.md)
>>> result = phoid.identify(phoid.read_experiment("examples/paper-sample"))  # doctest: +SKIP
>>> print(result.report())  # doctest: +SKIP
"""

from phoid.dynamics.digital import DigitalPD, DigitalRoots, digital_modes, digital_roots
from phoid.dynamics.loop import (
    DelayedPD,
    LoopModes,
    alphas,
    characteristic_roots,
    forward_map,
    inverse_map,
    is_stable,
)
from phoid.dynamics.plant import Plant, free_response
from phoid.errors import ExperimentError, IdentificationError, OutputError, PhoidError
from phoid.fits import DecayFit, detect_release, fit_decay, logdec
from phoid.io.experiment import (
    ExperimentSet,
    Run,
    read_experiment,
    run_from_arrays,
    write_experiment,
)
from phoid.methods.forced import (
    ForcedIdentification,
    ForcedRun,
    ResponseFit,
    fit_response,
    identify_forced,
    identify_forced_data,
    simulate_forced,
    two_frequency,
)
from phoid.methods.free import FreeIdentification, FreeRun, identify_free, identify_free_data
from phoid.methods.friction import FrictionFit, friction_evidence, identify_friction
from phoid.methods.identification import Identification, RunMode, identify, identify_data
from phoid.methods.pho import Estimate, MCKFit, fit_lines, fit_modes
from phoid.planning.fisher import CramerRao, cramer_rao
from phoid.planning.sweep import Design, DesignError, PlannedRun, design
from phoid.simulation.core import Simulation, simulate

__version__ = "0.1.0"

__all__ = [
    "CramerRao",
    "DecayFit",
    "DelayedPD",
    "Design",
    "DesignError",
    "DigitalPD",
    "DigitalRoots",
    "Estimate",
    "ExperimentError",
    "ExperimentSet",
    "ForcedIdentification",
    "ForcedRun",
    "FreeIdentification",
    "FreeRun",
    "FrictionFit",
    "Identification",
    "IdentificationError",
    "LoopModes",
    "MCKFit",
    "OutputError",
    "PhoidError",
    "PlannedRun",
    "Plant",
    "ResponseFit",
    "Run",
    "RunMode",
    "Simulation",
    "__version__",
    "alphas",
    "characteristic_roots",
    "cramer_rao",
    "design",
    "detect_release",
    "digital_modes",
    "digital_roots",
    "fit_decay",
    "fit_lines",
    "fit_modes",
    "fit_response",
    "forward_map",
    "free_response",
    "friction_evidence",
    "identify",
    "identify_data",
    "identify_forced",
    "identify_forced_data",
    "identify_free",
    "identify_free_data",
    "identify_friction",
    "inverse_map",
    "is_stable",
    "logdec",
    "read_experiment",
    "run_from_arrays",
    "simulate",
    "simulate_forced",
    "two_frequency",
    "write_experiment",
]
