"""phoid.interop: results where users look — python-control, scipy.signal and pandas.

Modules
-------
plant
    The identified linear plant of any result and its covariance (:class:`LinearPlant`).
control
    The plant and each run's closed loop as python-control systems (Padé for a delay, exact
    discrete time for a sampled loop) and as :class:`scipy.signal.lti`.
sampling
    Monte Carlo plants drawn with the result's covariance.
tables
    Estimates and runs as pandas DataFrames.

python-control and pandas are optional and imported only inside the functions that use them.
"""

from phoid.interop.control import ExportInfo, closed_loop, require_control, to_control, to_lti
from phoid.interop.plant import LinearPlant, linear_plant
from phoid.interop.sampling import sample_plants
from phoid.interop.tables import Frames, estimates_frame, require_pandas, runs_frame, to_pandas

__all__ = [
    "ExportInfo",
    "Frames",
    "LinearPlant",
    "closed_loop",
    "estimates_frame",
    "linear_plant",
    "require_control",
    "require_pandas",
    "runs_frame",
    "sample_plants",
    "to_control",
    "to_lti",
    "to_pandas",
]
