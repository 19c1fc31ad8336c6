"""phoid.fits."""

from phoid.fits.batch import (
    FitJob,
    fit_decays,
    start_decays,
)
from phoid.fits.decay import (
    DecayFit,
    DecayStart,
    detect_release,
    fit_decay,
    logdec,
    start_decay,
)

__all__ = [
    "DecayFit",
    "DecayStart",
    "FitJob",
    "detect_release",
    "fit_decay",
    "fit_decays",
    "logdec",
    "start_decay",
    "start_decays",
]
