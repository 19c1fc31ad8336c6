"""Forced harmonic (sine-sweep) identification (``method = "forced"``), seed eqs. (16)–(22).

Each run applies one sinusoidal force F(t) = B sin(ωt − θ) (eq. 16) and records x(t) and F(t).
Once the start-up transient has died the response is x_p = C sin(ωt − φ) (eq. 17), and eq. (18)
gives, per frequency (eq. 20; ERRATA 3 in docs/equations.md: R in N/m, C in m),

    k − mω² = R cos ρ,    cω = R sin ρ,    R = B/C,  ρ = φ − θ   (eq. 21).

In complex form R e^{iρ} = F̂/x̂, the ratio of the force and displacement phasors, i.e. the
dynamic stiffness k − mω² + icω.

Modules, along the data path:

- :mod:`~phoid.methods.forced.force`: ω, B, θ and the analysed window of each run's F;
- :mod:`~phoid.methods.forced.pipeline`: the response with its start-up transient modelled,
  R and ρ per run, then m, c, k (:func:`identify_forced`, :func:`identify_forced_data`);
- :mod:`~phoid.methods.forced.stiffness`: eq. (20) by generalised least squares
  (:func:`fit_response`) and the seed's two-frequency formulas of eq. (22)
  (:func:`two_frequency`);
- :mod:`~phoid.methods.forced.results`: :class:`ForcedRun`, :class:`ForcedIdentification`;
- :mod:`~phoid.methods.forced.sweep`: simulated sine sweeps (:func:`simulate_forced`).
"""

from phoid.methods.forced.pipeline import identify_forced, identify_forced_data
from phoid.methods.forced.results import ForcedIdentification, ForcedRun
from phoid.methods.forced.stiffness import ResponseFit, fit_response, two_frequency
from phoid.methods.forced.sweep import simulate_forced

__all__ = [
    "ForcedIdentification",
    "ForcedRun",
    "ResponseFit",
    "fit_response",
    "identify_forced",
    "identify_forced_data",
    "simulate_forced",
    "two_frequency",
]
