"""phoid.methods."""

from phoid.methods.diagnose import (
    SIGN_CONVENTION,
    probable_cause,
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
from phoid.methods.pho import (
    Estimate,
    LineFit,
    MCKFit,
    delay_profile,
    fit_lines,
    fit_modes,
)
from phoid.methods.pho_checks import DIGITAL_KEYS, read_digital_loop, refuse_bias
from phoid.methods.pho_measure import measure_modes
from phoid.methods.pho_result import Identification, RunMode
from phoid.methods.udelay import (
    UDelayFit,
    URun,
    check_u,
    combine,
    fit_run,
    u_skip,
    with_u,
)

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
    "Identification",
    "LineFit",
    "MCKFit",
    "ResponseFit",
    "RunMode",
    "UDelayFit",
    "URun",
    "check_u",
    "combine",
    "delay_profile",
    "fit_lines",
    "fit_modes",
    "fit_response",
    "fit_run",
    "friction_evidence",
    "identify_forced",
    "identify_forced_data",
    "identify_free",
    "identify_free_data",
    "identify_friction",
    "identify_friction_set",
    "identify_pho",
    "identify_pho_data",
    "measure_modes",
    "probable_cause",
    "read_digital_loop",
    "refuse_bias",
    "simulate_forced",
    "two_frequency",
    "u_skip",
    "with_u",
]
