"""phoid.methods: each method turns an experiment's records into a result.

The dispatch by a set's ``method`` (``registry``, ``dispatch``), the base of every result
(``result_base``), ``pho`` (eq. 35 lines), the PHO pipeline (``identification``,
``pho_measure``, ``pho_release``, ``pho_checks``, ``pho_result``), the delay from a recorded
force (``udelay``), ``friction``, ``forced``, ``free`` (sharing ``_modal``), ``diagnose`` and
the inverse dynamics least squares of a tracking record (``idim``), the output-error fit of a
tracking record through the simulated loop (``tracking``), the identification of a tracking
set (``tracking_identification``) and the validation of a simulated tracking record against
the recorded one (``tracking_validation``).
The names below are imported from their modules on first use (:mod:`phoid._lazy`), so that the
PHO path does not load the forced and friction methods.
"""

from typing import TYPE_CHECKING

from phoid._lazy import lazy_exports

if TYPE_CHECKING:  # the real imports, for type checkers and IDEs
    from phoid.io.loop import DIGITAL_KEYS, read_digital_loop
    from phoid.methods.diagnose import (
        SIGN_CONVENTION,
        probable_cause,
    )
    from phoid.methods.dispatch import identify_set
    from phoid.methods.estimate import Estimate
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
    from phoid.methods.free import (
        FreeIdentification,
        FreeRun,
        identify_free,
        identify_free_data,
    )
    from phoid.methods.friction import (
        FrictionEvidence,
        FrictionFit,
        FrictionRun,
        friction_evidence,
        identify_friction,
        identify_friction_set,
    )
    from phoid.methods.identification import identify_pho, identify_pho_data
    from phoid.methods.idim import IDIMFit, idim_ls, idim_ls_runs
    from phoid.methods.pho import (
        LineFit,
        MCKFit,
        delay_profile,
        fit_lines,
        fit_modes,
    )
    from phoid.methods.pho_checks import refuse_bias
    from phoid.methods.pho_measure import measure_modes
    from phoid.methods.pho_result import Identification, RunMode
    from phoid.methods.result_base import PlantResult, ResultBase
    from phoid.methods.tracking import (
        TrackingFit,
        TrackingRecord,
        controller_commands,
        fit_tracking,
        fit_tracking_runs,
        replay,
    )
    from phoid.methods.tracking_identification import (
        TrackingIdentification,
        TrackingReplay,
        identify_tracking,
        replay_set,
        run_controller,
    )
    from phoid.methods.tracking_validation import (
        SignalError,
        TrackingValidation,
        validate_tracking,
    )
    from phoid.methods.udelay import (
        UDelayFit,
        URun,
        check_u,
        combine,
        fit_run,
        u_skip,
        with_u,
    )

_EXPORTS = {
    "SIGN_CONVENTION": "phoid.methods.diagnose",
    "probable_cause": "phoid.methods.diagnose",
    "ForcedIdentification": "phoid.methods.forced",
    "ForcedRun": "phoid.methods.forced",
    "ResponseFit": "phoid.methods.forced",
    "fit_response": "phoid.methods.forced",
    "identify_forced": "phoid.methods.forced",
    "identify_forced_data": "phoid.methods.forced",
    "simulate_forced": "phoid.methods.forced",
    "two_frequency": "phoid.methods.forced",
    "FreeIdentification": "phoid.methods.free",
    "FreeRun": "phoid.methods.free",
    "identify_free": "phoid.methods.free",
    "identify_free_data": "phoid.methods.free",
    "FrictionEvidence": "phoid.methods.friction",
    "FrictionFit": "phoid.methods.friction",
    "FrictionRun": "phoid.methods.friction",
    "friction_evidence": "phoid.methods.friction",
    "identify_friction": "phoid.methods.friction",
    "identify_friction_set": "phoid.methods.friction",
    "identify_pho": "phoid.methods.identification",
    "identify_pho_data": "phoid.methods.identification",
    "IDIMFit": "phoid.methods.idim",
    "idim_ls": "phoid.methods.idim",
    "idim_ls_runs": "phoid.methods.idim",
    "TrackingFit": "phoid.methods.tracking",
    "TrackingRecord": "phoid.methods.tracking",
    "controller_commands": "phoid.methods.tracking",
    "fit_tracking": "phoid.methods.tracking",
    "fit_tracking_runs": "phoid.methods.tracking",
    "replay": "phoid.methods.tracking",
    "TrackingIdentification": "phoid.methods.tracking_identification",
    "TrackingReplay": "phoid.methods.tracking_identification",
    "identify_tracking": "phoid.methods.tracking_identification",
    "replay_set": "phoid.methods.tracking_identification",
    "run_controller": "phoid.methods.tracking_identification",
    "Estimate": "phoid.methods.estimate",
    "LineFit": "phoid.methods.pho",
    "MCKFit": "phoid.methods.pho",
    "delay_profile": "phoid.methods.pho",
    "fit_lines": "phoid.methods.pho",
    "fit_modes": "phoid.methods.pho",
    "DIGITAL_KEYS": "phoid.io.loop",
    "read_digital_loop": "phoid.io.loop",
    "refuse_bias": "phoid.methods.pho_checks",
    "measure_modes": "phoid.methods.pho_measure",
    "Identification": "phoid.methods.pho_result",
    "PlantResult": "phoid.methods.result_base",
    "ResultBase": "phoid.methods.result_base",
    "identify_set": "phoid.methods.dispatch",
    "RunMode": "phoid.methods.pho_result",
    "SignalError": "phoid.methods.tracking_validation",
    "TrackingValidation": "phoid.methods.tracking_validation",
    "validate_tracking": "phoid.methods.tracking_validation",
    "UDelayFit": "phoid.methods.udelay",
    "URun": "phoid.methods.udelay",
    "check_u": "phoid.methods.udelay",
    "combine": "phoid.methods.udelay",
    "fit_run": "phoid.methods.udelay",
    "u_skip": "phoid.methods.udelay",
    "with_u": "phoid.methods.udelay",
}

__getattr__, __dir__ = lazy_exports(__name__, globals(), _EXPORTS)

__all__ = [
    "DIGITAL_KEYS",
    "SIGN_CONVENTION",
    "Estimate",
    "ForcedIdentification",
    "ForcedRun",
    "FreeIdentification",
    "FreeRun",
    "FrictionEvidence",
    "FrictionFit",
    "FrictionRun",
    "IDIMFit",
    "Identification",
    "LineFit",
    "MCKFit",
    "PlantResult",
    "ResponseFit",
    "ResultBase",
    "RunMode",
    "SignalError",
    "TrackingFit",
    "TrackingIdentification",
    "TrackingRecord",
    "TrackingReplay",
    "TrackingValidation",
    "UDelayFit",
    "URun",
    "check_u",
    "combine",
    "controller_commands",
    "delay_profile",
    "fit_lines",
    "fit_modes",
    "fit_response",
    "fit_run",
    "fit_tracking",
    "fit_tracking_runs",
    "friction_evidence",
    "identify_forced",
    "identify_forced_data",
    "identify_free",
    "identify_free_data",
    "identify_friction",
    "identify_friction_set",
    "identify_pho",
    "identify_pho_data",
    "identify_set",
    "identify_tracking",
    "idim_ls",
    "idim_ls_runs",
    "measure_modes",
    "probable_cause",
    "read_digital_loop",
    "refuse_bias",
    "replay",
    "replay_set",
    "run_controller",
    "simulate_forced",
    "two_frequency",
    "u_skip",
    "validate_tracking",
    "with_u",
]
