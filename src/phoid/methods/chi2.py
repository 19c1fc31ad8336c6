"""The χ² distribution's tail and quantile, exact to rounding, without scipy.special.

The PHO pipeline tests a weighted least-squares fit at the 99.9 % level (χ² > its upper 0.1 %
quantile means the model does not explain the data within the stated noise). Importing
``scipy.special`` for that one number costs more than the identification itself, so the few
lines below compute it from the regularized incomplete gamma function.
"""

from __future__ import annotations

import math

__all__ = ["chi2_isf", "chi2_sf", "gamma_p", "gamma_q"]

_LN_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_EPS = 1e-16        # relative size of the last term kept in a series or continued fraction
_TINY = 1e-300      # Lentz's guard against a zero denominator
_MAX_TERMS = 100_000


def _stirling_rest(a: float) -> float:
    """ln Γ(a) − [(a − ½) ln a − a + ½ ln 2π] for a ≥ 10, by its asymptotic series."""
    r = 1.0 / (a * a)
    return (1.0 / 12 - r * (1.0 / 360 - r * (1.0 / 1260 - r * (1.0 / 1680 - r / 1188)))) / a


def _log_prefactor(a: float, x: float) -> float:
    """ln(xᵃ e⁻ˣ / Γ(a)), written for large a as −a (u − ln(1 + u)) + ½ ln(a / 2π) − rest(a)
    with u = (x − a)/a, so that the terms of size a ln a do not cancel in rounding."""
    if a < 10.0 or x < 0.5 * a:  # far below the mode the direct form does not cancel
        return a * math.log(x) - x - math.lgamma(a)
    u = (x - a) / a
    return -a * (u - math.log1p(u)) + 0.5 * math.log(a) - _LN_SQRT_2PI - _stirling_rest(a)


def _lower_series(a: float, x: float) -> float:
    """P(a, x) by its power series, for x < a + 1."""
    term = total = 1.0 / a
    ap = a
    for _ in range(_MAX_TERMS):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * math.exp(_log_prefactor(a, x))


def _upper_fraction(a: float, x: float) -> float:
    """Q(a, x) by its continued fraction (modified Lentz), for x ≥ a + 1."""
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return h * math.exp(_log_prefactor(a, x))


def _check_gamma_args(a: float, x: float) -> None:
    if not (math.isfinite(a) and a > 0):
        raise ValueError(f"a must be a finite number > 0, got {a!r}")
    if not (x >= 0 and not math.isnan(x)):
        raise ValueError(f"x must be ≥ 0, got {x!r}")


def gamma_p(a: float, x: float) -> float:
    """The regularized lower incomplete gamma function P(a, x).

    .. math:: P(a, x) = \\frac{1}{\\Gamma(a)} \\int_0^x t^{a-1} e^{-t}\\, dt
              = \\frac{x^a e^{-x}}{\\Gamma(a)} \\sum_{n\\ge0} \\frac{x^n}{a (a+1) \\cdots (a+n)}

    The series is summed for x < a + 1 (its terms then shrink at once); otherwise P = 1 − Q
    with Q from the continued fraction of :func:`gamma_q` (Press et al., *Numerical Recipes*,
    3rd ed., §6.2). The prefactor is formed in logarithms with Stirling's series for large a.

    Parameters
    ----------
    a : float
        Shape, > 0.
    x : float
        Upper limit of the integral, ≥ 0.

    Returns
    -------
    float
        P(a, x) in [0, 1], to a few units of rounding.

    Examples
    --------
    >>> round(gamma_p(1.0, 2.0), 12)  # 1 − e⁻²
    0.864664716763
    """
    _check_gamma_args(a, x)
    if x == 0:
        return 0.0
    if math.isinf(x):
        return 1.0
    if x < a + 1.0:
        return min(1.0, _lower_series(a, x))
    return 1.0 - _upper_fraction(a, x)


def gamma_q(a: float, x: float) -> float:
    """The regularized upper incomplete gamma function Q(a, x) = 1 − P(a, x).

    .. math:: Q(a, x) = \\frac{1}{\\Gamma(a)} \\int_x^\\infty t^{a-1} e^{-t}\\, dt
              = \\frac{x^a e^{-x}}{\\Gamma(a)}\\;
                \\cfrac{1}{x + 1 - a - \\cfrac{1\\,(1 - a)}{x + 3 - a - \\cfrac{2\\,(2 - a)}
                {x + 5 - a - \\cdots}}}

    The continued fraction (evaluated by the modified Lentz method) is used for x ≥ a + 1,
    where it converges fast and Q is computed without cancellation; for x < a + 1, Q = 1 − P
    with P from the series of :func:`gamma_p` (there Q > 0.08, so nothing is lost). Reference:
    Press et al., *Numerical Recipes*, 3rd ed., §6.2.

    Parameters
    ----------
    a : float
        Shape, > 0.
    x : float
        Lower limit of the integral, ≥ 0.

    Returns
    -------
    float
        Q(a, x) in [0, 1], to a few units of rounding.

    Examples
    --------
    >>> round(gamma_q(1.0, 2.0), 12)  # e⁻²
    0.135335283237
    """
    _check_gamma_args(a, x)
    if x == 0:
        return 1.0
    if math.isinf(x):
        return 0.0
    if x < a + 1.0:
        return max(0.0, 1.0 - _lower_series(a, x))
    return _upper_fraction(a, x)


def _check_dof(dof: float) -> float:
    dof = float(dof)
    if not (math.isfinite(dof) and dof > 0):
        raise ValueError(f"dof must be a finite number > 0, got {dof!r}")
    return dof


def chi2_sf(x: float, dof: float) -> float:
    """The χ² distribution's survival function, Pr(χ²_dof > x) = Q(dof/2, x/2).

    Parameters
    ----------
    x : float
        The value of χ², ≥ 0.
    dof : float
        Degrees of freedom, > 0.

    Returns
    -------
    float
        The upper-tail probability (scipy's ``chdtrc(dof, x)``).

    Examples
    --------
    >>> round(chi2_sf(2.0, 2), 12)  # e⁻¹
    0.367879441171
    """
    return gamma_q(0.5 * _check_dof(dof), 0.5 * float(x))


def _normal_isf(p: float) -> float:
    """z with Pr(N(0, 1) > z) = p, to ~5e-4 (Abramowitz & Stegun 26.2.23): a start only."""
    q = min(p, 1.0 - p)
    t = math.sqrt(-2.0 * math.log(q))
    z = t - (2.515517 + t * (0.802853 + t * 0.010328)) / (
        1.0 + t * (1.432788 + t * (0.189269 + t * 0.001308)))
    return z if p <= 0.5 else -z


def chi2_isf(p: float, dof: float) -> float:
    """The χ² distribution's upper-tail quantile: the x with Pr(χ²_dof > x) = p.

    Solves Q(k/2, x/2) = p (k = dof) for x; this is ``scipy.stats.chi2.isf(p, dof)``
    = ``scipy.special.chdtri(dof, p)``. The start is Wilson and Hilferty's cube-root normal
    approximation,

    .. math:: x_0 = k \\left(1 - \\frac{2}{9k} + z_p \\sqrt{\\frac{2}{9k}}\\right)^3,

    with z_p the normal upper quantile (or, in the far lower tail of small k, the leading term
    of the series, P ≈ (x/2)^{k/2} / Γ(k/2 + 1)). It is refined by Newton's method on the
    logarithm of the smaller tail, T(x) = Q or P, whose derivative is ∓f(x)/T with f the χ²
    density; a step that leaves the bracket kept from the iterates is replaced by bisection,
    so the iteration always converges. It stops after a Newton step below 1e-12 of x: the
    convergence being quadratic, the error left is then far below the rounding of T, so the
    result is exact to the accuracy of T (a few units of rounding), ~1e-13 relative.
    References: E. B. Wilson and M. M. Hilferty, PNAS 17 (1931) 684; Press et al.,
    *Numerical Recipes*, 3rd ed., §6.2 and §6.14.

    Parameters
    ----------
    p : float
        The upper-tail probability, in (0, 1).
    dof : float
        Degrees of freedom, > 0.

    Returns
    -------
    float
        The quantile x ≥ 0.

    Raises
    ------
    ValueError
        If p is not in (0, 1) or dof is not a finite number > 0.

    Examples
    --------
    >>> round(chi2_isf(0.05, 1), 9)
    3.841458821
    >>> round(chi2_isf(0.001, 10), 9)
    29.588298445
    """
    k = _check_dof(dof)
    p = float(p)
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must be in (0, 1), got {p!r}")
    a = 0.5 * k
    upper = p <= 0.5
    t = p if upper else 1.0 - p   # the smaller tail's probability (1 − p is exact for p > ½)
    ln_t = math.log(t)

    def tail(x: float) -> float:
        return gamma_q(a, 0.5 * x) if upper else gamma_p(a, 0.5 * x)

    def log_density(x: float) -> float:   # ln f(x), f(x) = (x/2)^a e^(-x/2) / (x Γ(a))
        return _log_prefactor(a, 0.5 * x) - math.log(x)

    c = 2.0 / (9.0 * k)
    x = k * (1.0 - c + _normal_isf(p) * math.sqrt(c)) ** 3
    small = 2.0 * math.exp((math.log(t) + math.lgamma(a + 1.0)) / a)  # P ≈ (x/2)^a/Γ(a+1)
    if not upper and (x <= 0 or small < x):
        x = small
    if not x > 0:
        x = small if small > 0 else k
    # the bracket [lo, hi]: tail(lo) and tail(hi) on either side of t
    lo, hi = 0.0, math.inf
    for _ in range(400):
        tx = tail(x)
        if tx == t:
            return x
        if (tx > t) == upper:
            lo = x
        else:
            hi = x
        if tx > 0:
            ln_tx = math.log(tx)
            ratio = ln_tx - log_density(x)     # ln(T/f)
            step = (ln_tx - ln_t) * math.exp(ratio) if ratio < 700 else math.nan
            new = x + step if upper else x - step
        else:
            new = math.nan
        if abs(new - x) <= 1e-12 * x:   # quadratic convergence: the error is now ~1e-24
            return new
        if not lo < new < hi:   # Newton left the bracket: bisect (or grow an open bracket)
            new = 2.0 * x if math.isinf(hi) else 0.5 * (lo + hi)
        if abs(new - x) <= 1e-15 * x:
            return new
        x = new
    return x
