"""phoid — identify m, c, k (and f_c, Δt) of second-order systems by parametric oscillation.

The public API is re-exported here; see the module docstrings for the seed-paper equations each
function implements, and docs/equations.md for those equations and their corrections (ERRATA
1–6) explained. The names are imported on first use (PEP 562), so ``import phoid`` is cheap and
loads numpy, scipy or matplotlib only when a function needs them.

>>> import phoid
>>> # from the repository's root: the example set in examples/ (examples/README.md)
>>> result = phoid.identify(phoid.read_experiment("examples/paper-sample"))  # doctest: +SKIP
>>> print(result.report())  # doctest: +SKIP
"""

from typing import TYPE_CHECKING

from phoid._lazy import lazy_exports

if TYPE_CHECKING:  # the real imports, for type checkers and IDEs; at run time see __getattr__
    from phoid._progress import progress
    from phoid.api import identify, identify_data
    from phoid.batch.drift import Trend, trend
    from phoid.batch.engine import identify_many
    from phoid.batch.rehearsal import Rehearsal, rehearse
    from phoid.dynamics import (
        DelayedPD,
        DigitalPD,
        DigitalRoots,
        LoopModes,
        Plant,
        SampledController,
        alphas,
        characteristic_roots,
        digital_modes,
        digital_roots,
        forward_map,
        free_response,
        inverse_map,
        is_stable,
    )
    from phoid.errors import ExperimentError, IdentificationError, OutputError, PhoidError
    from phoid.fits import DecayFit, detect_release, fit_decay, logdec
    from phoid.interop import (
        ExportInfo,
        Frames,
        LinearPlant,
        closed_loop,
        linear_plant,
        sample_plants,
        to_control,
        to_lti,
        to_pandas,
    )
    from phoid.io import (
        ExperimentSet,
        Run,
        read_experiment,
        run_from_arrays,
        write_experiment,
    )
    from phoid.methods import (
        Estimate,
        ForcedIdentification,
        ForcedRun,
        FreeIdentification,
        FreeRun,
        FrictionFit,
        Identification,
        MCKFit,
        ResponseFit,
        RunMode,
        fit_lines,
        fit_modes,
        fit_response,
        friction_evidence,
        identify_forced,
        identify_forced_data,
        identify_free,
        identify_free_data,
        identify_friction,
        simulate_forced,
        two_frequency,
    )
    from phoid.methods.idim import idim_ls
    from phoid.methods.tracking import fit_tracking
    from phoid.methods.tracking_identification import identify_tracking, replay_set
    from phoid.methods.tracking_validation import validate_tracking
    from phoid.planning import (
        CramerRao,
        Design,
        DesignError,
        InLoopBound,
        PlannedRun,
        cramer_rao,
        design,
        inloop_cramer_rao,
    )
    from phoid.simulation import Simulation, TrackingSimulation, simulate, simulate_tracking

__version__ = "0.1.0"

# each public name -> the (sub)package that exports it; imported on first use (PEP 562), so that
# `import phoid` stays cheap and `phoid --help` does not pay for numpy, scipy or matplotlib
_LAZY: dict[str, str] = {
    "DigitalPD": "phoid.dynamics",
    "DigitalRoots": "phoid.dynamics",
    "digital_modes": "phoid.dynamics",
    "digital_roots": "phoid.dynamics",
    "DelayedPD": "phoid.dynamics",
    "LoopModes": "phoid.dynamics",
    "alphas": "phoid.dynamics",
    "characteristic_roots": "phoid.dynamics",
    "forward_map": "phoid.dynamics",
    "inverse_map": "phoid.dynamics",
    "is_stable": "phoid.dynamics",
    "Plant": "phoid.dynamics",
    "free_response": "phoid.dynamics",
    "ExperimentError": "phoid.errors",
    "IdentificationError": "phoid.errors",
    "OutputError": "phoid.errors",
    "PhoidError": "phoid.errors",
    "DecayFit": "phoid.fits",
    "detect_release": "phoid.fits",
    "fit_decay": "phoid.fits",
    "logdec": "phoid.fits",
    "ExperimentSet": "phoid.io",
    "Run": "phoid.io",
    "read_experiment": "phoid.io",
    "run_from_arrays": "phoid.io",
    "write_experiment": "phoid.io",
    "ForcedIdentification": "phoid.methods",
    "ForcedRun": "phoid.methods",
    "ResponseFit": "phoid.methods",
    "fit_response": "phoid.methods",
    "identify_forced": "phoid.methods",
    "identify_forced_data": "phoid.methods",
    "simulate_forced": "phoid.methods",
    "two_frequency": "phoid.methods",
    "FreeIdentification": "phoid.methods",
    "FreeRun": "phoid.methods",
    "identify_free": "phoid.methods",
    "identify_free_data": "phoid.methods",
    "FrictionFit": "phoid.methods",
    "friction_evidence": "phoid.methods",
    "identify_friction": "phoid.methods",
    "Identification": "phoid.methods",
    "RunMode": "phoid.methods",
    "identify": "phoid.api",
    "identify_data": "phoid.api",
    "identify_many": "phoid.batch.engine",
    "Estimate": "phoid.methods",
    "MCKFit": "phoid.methods",
    "fit_lines": "phoid.methods",
    "fit_modes": "phoid.methods",
    "CramerRao": "phoid.planning",
    "cramer_rao": "phoid.planning",
    "InLoopBound": "phoid.planning",
    "inloop_cramer_rao": "phoid.planning",
    "Design": "phoid.planning",
    "DesignError": "phoid.planning",
    "PlannedRun": "phoid.planning",
    "design": "phoid.planning",
    "Simulation": "phoid.simulation",
    "simulate": "phoid.simulation",
    "SampledController": "phoid.dynamics",
    "TrackingSimulation": "phoid.simulation",
    "simulate_tracking": "phoid.simulation",
    "fit_tracking": "phoid.methods",
    "idim_ls": "phoid.methods",
    "identify_tracking": "phoid.methods",
    "replay_set": "phoid.methods",
    "validate_tracking": "phoid.methods",
    "ExportInfo": "phoid.interop",
    "Frames": "phoid.interop",
    "LinearPlant": "phoid.interop",
    "closed_loop": "phoid.interop",
    "linear_plant": "phoid.interop",
    "sample_plants": "phoid.interop",
    "to_control": "phoid.interop",
    "to_lti": "phoid.interop",
    "to_pandas": "phoid.interop",
    "progress": "phoid._progress",
    "Rehearsal": "phoid.batch.rehearsal",
    "rehearse": "phoid.batch.rehearsal",
    "Trend": "phoid.batch.drift",
    "trend": "phoid.batch.drift",
}

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
    "ExportInfo",
    "ForcedIdentification",
    "ForcedRun",
    "Frames",
    "FreeIdentification",
    "FreeRun",
    "FrictionFit",
    "Identification",
    "IdentificationError",
    "InLoopBound",
    "LinearPlant",
    "LoopModes",
    "MCKFit",
    "OutputError",
    "PhoidError",
    "PlannedRun",
    "Plant",
    "Rehearsal",
    "ResponseFit",
    "Run",
    "RunMode",
    "SampledController",
    "Simulation",
    "TrackingSimulation",
    "Trend",
    "__version__",
    "alphas",
    "characteristic_roots",
    "closed_loop",
    "cramer_rao",
    "design",
    "detect_release",
    "digital_modes",
    "digital_roots",
    "fit_decay",
    "fit_lines",
    "fit_modes",
    "fit_response",
    "fit_tracking",
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
    "identify_many",
    "identify_tracking",
    "idim_ls",
    "inloop_cramer_rao",
    "inverse_map",
    "is_stable",
    "linear_plant",
    "logdec",
    "progress",
    "read_experiment",
    "rehearse",
    "replay_set",
    "run_from_arrays",
    "sample_plants",
    "simulate",
    "simulate_forced",
    "simulate_tracking",
    "to_control",
    "to_lti",
    "to_pandas",
    "trend",
    "two_frequency",
    "validate_tracking",
    "write_experiment",
]


__getattr__, __dir__ = lazy_exports(__name__, globals(), _LAZY)

del TYPE_CHECKING
