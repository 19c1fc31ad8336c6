"""phoid.io."""

from phoid.io.experiment import (
    FORMAT,
    MANIFEST,
    METHODS,
    ExperimentSet,
    Run,
    read_experiment,
    read_manifest,
    run_from_arrays,
    write_experiment,
)

__all__ = [
    "FORMAT",
    "MANIFEST",
    "METHODS",
    "ExperimentSet",
    "Run",
    "read_experiment",
    "read_manifest",
    "run_from_arrays",
    "write_experiment",
]
