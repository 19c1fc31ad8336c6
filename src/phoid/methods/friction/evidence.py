"""Evidence for friction: the score test of f_c = 0 at the viscous full-record fit.

With r the weighted residual of the best friction-free model, j the sensitivity of the model to
f_c at f_c = 0⁺ and Π the projection off the other parameters' columns,
z = jᵀr / (s·‖Πj‖) is standard normal when there is no friction (one-sided: friction only adds a
positive multiple of j). It needs the friction-free fit (fast: no stick–slip events) and one
simulation with friction, not the whole friction fit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from phoid._threads import single_blas_thread
from phoid.errors import IdentificationError
from phoid.methods.estimate import Estimate
from phoid.methods.friction.fit import fit_runs
from phoid.methods.friction.model import hermite
from phoid.methods.friction.results import FrictionEvidence
from phoid.methods.friction.setup import prepare

__all__ = ["friction_evidence"]


@single_blas_thread
def friction_evidence(
    data: Sequence[tuple[np.ndarray, np.ndarray]],
    P: np.ndarray,
    D: np.ndarray,
    delay: float | None,
    *,
    start: Sequence[float] | None = None,
    names: Sequence[str] | None = None,
    alpha: float = 1e-3,
    added_mass: Sequence[float] | None = None,
    digital: Any = None,
    bias: Sequence[float] | None = None,
) -> FrictionEvidence:
    """Score test of f_c = 0: is there Coulomb friction in a PHO set fitted as viscous?

    Fits the records by the friction-free model (full-record maximum likelihood, fast: no
    stick–slip events), then evaluates the profiled score of f_c at f_c = 0⁺ (module docstring):
    z = jᵀr/(s‖Πj‖), standard normal without friction.

    Parameters
    ----------
    data, P, D, delay, names, added_mass, digital, bias
        As for :func:`identify_friction`.
    start : sequence of float, optional
        Starting (m, c, k) for the viscous fit, e.g. a viscous identification's estimates
        (default: :func:`phoid.identify_data`).
    alpha : float, default 1e−3
        Significance level of ``detected``.

    Returns
    -------
    FrictionEvidence
    """
    from scipy import stats

    if not 0 < alpha < 1:
        raise ValueError(f"`alpha` must be in (0, 1); got {alpha!r}")
    if start is not None:
        start = tuple(start)[:3]
    setup = prepare(data, P, D, delay, start, names, need_fc=False, added_mass=added_mass,
                    digital=digital, bias=bias)
    n = len(setup.surveys)
    idx = [i for i in range(n) if setup.reasons[i] is None]
    theta = setup.start.copy()
    theta[3] = 0.0
    local = np.array([[setup.surveys[i].level - setup.offset[i], setup.offset[i],
                       setup.release[i]] for i in idx])
    prob, fixed, res = fit_runs(setup, idx, theta, local, (True, True, True, False), 40)
    theta_f, local_f = prob.split(res.p, fixed)
    # sensitivity to f_c at 0⁺ by a forward difference
    h = prob.steps(theta_f, local_f)[3]
    th = theta_f.copy()
    th[3] = h
    XVp = prob.simulate(th, local_f[:, 0], local_f[:, 2])
    if XVp is None:
        raise IdentificationError("the friction sensitivity cannot be simulated")
    _, posts, herm = prob.model(local_f, res.XV)
    jcol = []
    for i in range(prob.B):
        u = np.maximum(prob.t[i] - local_f[i, 2], 0.0)
        hv, _ = hermite(XVp[0][i], XVp[1][i], prob.h, u)
        jcol.append(np.where(posts[i], (hv - herm[i][0]) / h, 0.0) * prob.w[i])
    j = np.concatenate(jcol)
    J = res.J
    r = prob.residual(local_f, res.XV)
    dof = max(J.shape[0] - J.shape[1] - 1, 1)
    s2 = res.cost / dof
    A = J.normal()
    coef = A.solve(J.tdot(j))
    jp = j - J.dot(coef)  # Πj
    info = float(jp @ jp)
    score = float(jp @ r)
    z = score / math.sqrt(s2 * info) if info > 0 else 0.0
    p_value = float(stats.norm.sf(z))
    fc1 = score / info if info > 0 else 0.0
    se = np.sqrt(np.clip(np.diag(A.inv_globals())[:3] * s2, 0.0, None))
    warnings = [f"{setup.names[i]}: set aside: {setup.reasons[i]}" for i in range(n)
                if setup.reasons[i] is not None]
    if not res.converged:
        warnings.append("the viscous full-record fit did not converge")
    detected = p_value < alpha
    if detected:
        warnings.append(f"friction detected (score z = {z:.3g}, p = {p_value:.2g}; first "
                        f"estimate fc ≈ {fc1:.3g} N): fit it with identify_friction")
    return FrictionEvidence(
        z=float(z), p_value=p_value, detected=bool(detected),
        fc=Estimate(float(fc1), float(math.sqrt(s2 / info)) if info > 0 else None, "N"),
        m=Estimate(float(theta_f[0]), float(se[0]), "kg"),
        c=Estimate(float(theta_f[1]), float(se[1]), "N s/m"),
        k=Estimate(float(theta_f[2]), float(se[2]), "N/m"),
        chi2_red=float(res.cost / dof), warnings=tuple(warnings),
    )
