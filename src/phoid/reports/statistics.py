"""Fit statistics of a result, in one place: covariance → correlation, their JSON blocks, and
their text (an lmfit-like ``[[Fit statistics]]`` and ``[[Correlations]]``).

Every identification result's ``summary()`` carries three blocks built here (docs/format.md,
docs/format-extensions.md):

``"covariance"``
    ``{"params": [names], "units": [unit of each parameter], "matrix": [[…]]}``: the estimated
    parameters' covariance; entry (i, j) is in ``units[i]·units[j]``.
``"correlation"``
    ``{"params": [names], "matrix": [[…]]}`` with ρᵢⱼ = Cᵢⱼ / √(Cᵢᵢ Cⱼⱼ) (dimensionless).
``"statistics"``
    ``{"chi2", "dof", "chi2_dof", "p_value", "of", "weighted"}``: the χ² of the fit named in
    ``of``, its degrees of freedom, χ²/dof (≈ 1 when the model explains the data to the noise
    it is weighted by), and P(χ²_dof ≥ χ²).

Numbers that are not finite (a variance the data cannot give, a parameter held fixed) are
``null``: the output is strict JSON. The text helpers read those same blocks, so the JSON and
the report never disagree.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from phoid._notation import notation

__all__ = [
    "correlation",
    "correlation_json",
    "correlation_lines",
    "covariance_json",
    "json_matrix",
    "json_number",
    "ratio_text",
    "statistics_json",
    "statistics_lines",
    "symbol",
]

#: Correlations below this (in absolute value) are left out of the ``[[Correlations]]`` block,
#: as lmfit's ``fit_report`` does with its default ``min_correl``.
MIN_CORREL = 0.1


def json_number(x: Any) -> float | None:
    """``float(x)``, or None when ``x`` is None or not finite (JSON has no NaN/Infinity)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def json_matrix(a: Any) -> list[list[float | None]]:
    """A 2-D array as nested lists of :func:`json_number`."""
    a = np.atleast_2d(np.asarray(a, dtype=float))
    return [[json_number(v) for v in row] for row in a.tolist()]


def correlation(cov: Any) -> np.ndarray:
    """Correlation matrix ρᵢⱼ = Cᵢⱼ / √(Cᵢᵢ Cⱼⱼ) of a covariance matrix.

    Parameters
    ----------
    cov : array_like, shape (p, p)
        Covariance (any units: ρ is dimensionless).

    Returns
    -------
    ndarray, shape (p, p)
        ρ, with ρᵢᵢ = 1; a row and column whose variance is not positive and finite (a fixed
        or undetermined parameter) are nan.
    """
    cov = np.atleast_2d(np.asarray(cov, dtype=float))
    d = np.diag(cov).copy()
    ok = np.isfinite(d) & (d > 0)
    sd = np.where(ok, np.sqrt(np.where(ok, d, 1.0)), np.nan)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        rho = cov / np.outer(sd, sd)
    rho = np.clip(rho, -1.0, 1.0)  # rounding can put |ρ| a few ulp above 1
    idx = np.flatnonzero(ok)
    rho[idx, idx] = 1.0
    return rho


def covariance_json(names: Sequence[str], units: Sequence[str], cov: Any) -> dict[str, Any]:
    """``{"params", "units", "matrix"}``: the covariance block of a summary (null where not
    finite); ``matrix[i][j]`` is in ``units[i]·units[j]``."""
    cov = np.atleast_2d(np.asarray(cov, dtype=float))
    if cov.shape != (len(names), len(names)) or len(units) != len(names):
        raise ValueError(f"covariance of shape {cov.shape} for parameters {list(names)} "
                         f"with units {list(units)}")
    return {"params": list(names), "units": list(units), "matrix": json_matrix(cov)}


def correlation_json(names: Sequence[str], cov: Any) -> dict[str, Any]:
    """``{"params", "matrix"}``: the correlation block of a summary (:func:`correlation` of
    ``cov``, null where a variance is not positive)."""
    return {"params": list(names), "matrix": json_matrix(correlation(cov))}


def statistics_json(chi2: float | None, dof: int | None, *, of: str, weighted: bool = True,
                    p_value: float | None = None, **extra: Any) -> dict[str, Any]:
    """``{"chi2", "dof", "chi2_dof", "p_value", "of", "weighted", …}``: the statistics block.

    Parameters
    ----------
    chi2 : float or None
        The fit's χ² = Σ rᵢ²/sᵢ² (``weighted``: each residual over its noise sd, so that
        χ² ~ χ²_dof when the model is right), or the plain residual sum of squares Σ rᵢ²
        (not ``weighted``: the noise is unknown, as in lmfit without weights; χ²/dof is then
        the residual variance, in the residual's unit squared).
    dof : int or None
        Degrees of freedom: residuals minus fitted parameters.
    of : str
        What χ² is of, in words (printed in the JSON and the report).
    weighted : bool
        See ``chi2``.
    p_value : float, optional
        P(χ²_dof ≥ χ²) (weighted only).
    **extra
        Further numbers (e.g. ``"rss"``, ``"n_residuals"``), copied (non-finite → null).
    """
    d = int(dof) if dof is not None else None
    c = json_number(chi2)
    red = c / d if c is not None and d is not None and d > 0 else None
    out = {"chi2": c, "dof": d, "chi2_dof": json_number(red),
           "p_value": json_number(p_value) if weighted else None,
           "of": of, "weighted": bool(weighted)}
    for key, value in extra.items():
        out[key] = value if isinstance(value, (str, bool)) or value is None \
            else json_number(value)
    return out


def _fmt(x: float | None, spec: str = ".6g") -> str:
    """A number of the block; a missing one (null in the JSON) in words."""
    return "not computed" if x is None else format(x, spec)


def statistics_lines(stats: Mapping[str, Any]) -> list[str]:
    """The ``[[Fit statistics]]`` block of a report from a summary's ``"statistics"``.

    A fit with no χ² (``chi2`` null, as the paper's OLS lines) gets one line saying so and
    why (its ``of``), not rows of nulls; a single missing number reads "not computed".

    Parameters
    ----------
    stats : mapping
        Read: ``chi2``, ``dof``, ``chi2_dof``, ``p_value``, ``of``, ``weighted``.

    Returns
    -------
    list of str
    """
    import textwrap

    def row(label: str, value: str) -> str:  # label column 15 wide in either notation
        return f"    {notation(label):<15}{value}"

    of = str(stats["of"])
    if stats.get("chi2") is None and stats.get("dof") is None:
        why = of.removeprefix("not computed:").strip()
        text = textwrap.wrap(f"not computed ({why})" if why else "not computed", 76) or [""]
        return ["[[Fit statistics]]", row("χ²", text[0]), *(f"{'':<19}{w}" for w in text[1:])]
    wrapped = textwrap.wrap(of, 76) or [""]
    lines = ["[[Fit statistics]]", row("χ² of", wrapped[0]),
             *(f"{'':<19}{w}" for w in wrapped[1:])]
    if stats.get("weighted", True):
        lines.append(row("χ²", _fmt(stats["chi2"])))
        lines.append(row("dof", _fmt(stats["dof"], "d")))
        lines.append(row("χ²/dof", _fmt(stats["chi2_dof"], ".4g"))
                     + ("" if stats.get("p_value") is None
                        else f"   (P(χ² ≥ this) = {stats['p_value']:.3g})"))
    else:
        lines.append(row("RSS", f"{_fmt(stats['chi2'])}   (unweighted: noise unknown)"))
        lines.append(row("dof", _fmt(stats["dof"], "d")))
        lines.append(row("RSS/dof", _fmt(stats["chi2_dof"], ".4g")))
    return lines


def correlation_lines(corr: Mapping[str, Any], min_correl: float = MIN_CORREL) -> list[str]:
    """The ``[[Correlations]]`` block of a report (lmfit's layout), from a summary's
    ``"correlation"``: every pair with |ρ| ≥ ``min_correl``, largest first.

    Parameters
    ----------
    corr : mapping
        Read: ``params`` (names) and ``matrix`` (ρ, null where undefined).
    min_correl : float
        Smallest |ρ| shown.

    Returns
    -------
    list of str
    """
    names, m = list(corr["params"]), corr["matrix"]
    pairs = [(names[i], names[j], m[i][j]) for i in range(len(names))
             for j in range(i + 1, len(names)) if m[i][j] is not None]
    shown = sorted((p for p in pairs if abs(p[2]) >= min_correl), key=lambda p: -abs(p[2]))
    lines = [f"[[Correlations]] (unreported correlations are < {min_correl:.3f})"]
    lines += [f"    C({symbol(a)}, {symbol(b)}) = {r:+.4f}" for a, b, r in shown]
    if not shown:
        lines.append("    (none)")
    return lines


#: how a parameter's JSON name is written in a report (σ is the decay rate)
SYMBOLS = {"sigma": "σ", "omega0": "ω₀", "omega_d": "ω_d", "zeta": "ζ", "c_over_m": "c/m",
           "k_over_m": "k/m", "fc_over_m": "f_c/m", "offset_force": "offset force",
           "chi2": "χ²"}


def symbol(name: str) -> str:
    """A parameter's JSON name as a report writes it (``sigma`` → σ, ``omega0`` → ω₀,
    ``c_over_m`` → c/m, in the report's notation); any other name as it is.

    >>> symbol("omega0"), symbol("m")
    ('ω₀', 'm')
    """
    return notation(SYMBOLS.get(name, name))


def ratio_text(ratio: float | None) -> str:
    """A residual/noise ratio for a table column: three decimals below 100 (``1.004``), three
    significant digits above (``1.89e+03``), ``-`` when undefined."""
    if ratio is None or not math.isfinite(ratio):
        return "-"
    return f"{ratio:.3f}" if abs(ratio) < 100 else f"{ratio:.3g}"
