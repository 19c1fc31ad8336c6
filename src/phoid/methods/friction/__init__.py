r"""Coulomb friction: m, c, k and the kinetic friction force f_c from a PHO set (issue 6).

The model is the seed's plant (eq. 1) with kinetic friction, closed by the delayed PD loop of
eq. (23):

    m x''(t) + c x'(t) + k x(t) + f_c sign(x'(t)) = −[Dᵢ x'(t − Δt) + Pᵢ x(t − Δt)],

each run held at x₀ᵢ until its release at τᵢ and measured as yᵢ(t) = x(t) + bᵢ + noise (bᵢ a
sensor offset). Friction changes the free decay qualitatively: over each half-cycle the mass
oscillates about an equilibrium shifted by ∓f_c/(k + Pᵢ) (the static loop stiffness), so the
peak-to-peak height drops by a constant 4f_c/(k + Pᵢ) per cycle on top of the exponential decay,
and the motion stops (sticks) in finite time once the spring and feedback force fall below f_c.
A dominant-mode (viscous) fit of such a record takes the friction loss for damping: c comes out
far too large.

The decay is no longer a sum of exponentials, so the estimator fits the records themselves, by
maximum likelihood through the exact stick–slip simulator (:func:`identify_friction`);
:func:`friction_evidence` tests f_c = 0 by the score test at the viscous fit. Modules, along the
data path:

- :mod:`~phoid.methods.friction.survey`: a model-free look at each record (release, noise, end
  of motion, growth) and the recorded force u against the gains;
- :mod:`~phoid.methods.friction.setup`: the input checks and the starting point (the viscous
  identification, the envelopes);
- :mod:`~phoid.methods.friction.model`: the least-squares problem (batched simulation read by
  Hermite interpolation, the Jacobian by blocks);
- :mod:`~phoid.methods.friction.solver`: Levenberg–Marquardt;
- :mod:`~phoid.methods.friction.fit`: the two-stage fit, the runs set aside, the result
  (:func:`identify_friction`, :func:`identify_friction_set`);
- :mod:`~phoid.methods.friction.inloop`: with the sensor noise inside a digital loop, the
  output error of the plant with friction driven by the force the controller applied (chosen
  by the option, the manifest's ``[loop] noise`` or the data);
- :mod:`~phoid.methods.friction.evidence`: the score test (:func:`friction_evidence`);
- :mod:`~phoid.methods.friction.results`: :class:`FrictionRun`, :class:`FrictionFit`,
  :class:`FrictionEvidence`.
"""

from phoid.methods.friction.evidence import friction_evidence
from phoid.methods.friction.fit import identify_friction, identify_friction_set
from phoid.methods.friction.results import FrictionEvidence, FrictionFit, FrictionRun

__all__ = [
    "FrictionEvidence",
    "FrictionFit",
    "FrictionRun",
    "friction_evidence",
    "identify_friction",
    "identify_friction_set",
]
