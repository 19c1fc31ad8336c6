"""phoid.fits: the per-record fits of a free decay.

The data path of one record (t s, x m): :mod:`~phoid.fits.release` finds the release and the
window, :mod:`~phoid.fits.start` the start (spectral period, ESPRIT, a Gauss–Newton
confirmation), :mod:`~phoid.fits.modal` the maximum-likelihood dominant-mode fit (one
implementation, for stacks of records: :mod:`~phoid.fits._stack` evaluates the model,
:mod:`~phoid.fits._solver` runs Gauss–Newton), :mod:`~phoid.fits.decrement` the logarithmic
decrement; both return a :class:`~phoid.fits.result.DecayFit`.
"""

from phoid.fits.decrement import logdec
from phoid.fits.modal import FitJob, fit_checked, fit_decay, fit_decays
from phoid.fits.release import check_record, detect_release, diff_noise, locate_release
from phoid.fits.result import MIN_CYCLES, MIN_SAMPLES, DecayFit, is_clipped
from phoid.fits.start import DecayStart, esprit, start_decay, start_decays, uniform_step

__all__ = [
    "MIN_CYCLES",
    "MIN_SAMPLES",
    "DecayFit",
    "DecayStart",
    "FitJob",
    "check_record",
    "detect_release",
    "diff_noise",
    "esprit",
    "fit_checked",
    "fit_decay",
    "fit_decays",
    "is_clipped",
    "locate_release",
    "logdec",
    "start_decay",
    "start_decays",
    "uniform_step",
]
