"""phoid.planning."""

from phoid.planning.fisher import (
    CramerRao,
    cramer_rao,
    mode_information,
    mode_jacobian,
    power_sums,
    release_amplitude,
)
from phoid.planning.sweep import (
    Design,
    DesignError,
    DesignSettings,
    PlannedRun,
    check,
    check_experiment,
    count_roots_right,
    delay_margin,
    design,
    read_schedule,
)

__all__ = [
    "CramerRao",
    "Design",
    "DesignError",
    "DesignSettings",
    "PlannedRun",
    "check",
    "check_experiment",
    "count_roots_right",
    "cramer_rao",
    "delay_margin",
    "design",
    "mode_information",
    "mode_jacobian",
    "power_sums",
    "read_schedule",
    "release_amplitude",
]
