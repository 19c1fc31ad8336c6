"""The identified linear plant m x'' + c x' + k x = F of any result, with its covariance.

Results are taken by duck typing (the attributes each kind carries are listed in
:func:`linear_plant`), so :mod:`phoid.interop` imports no method. The Monte Carlo draws of
:meth:`LinearPlant.draw` are the estimates' normal distribution, restricted to the plants
:class:`phoid.dynamics.Plant` accepts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

__all__ = ["MAX_DRAWS", "LinearPlant", "linear_plant"]

_UNITS = ("kg", "N s/m", "N/m")
# the names an estimator may give m, c and k (IDIM-LS uses the EMPS benchmark's M and Fv)
_ALIASES = {"m": 0, "M": 0, "c": 1, "Fv": 1, "k": 2}
# draws tried per requested plant before the sampler gives up (acceptance below 1 %)
_MAX_TRIES_PER_DRAW = 100
#: the most plants one :meth:`LinearPlant.draw` gives: 10⁷ draws of (m, c, k) are 240 MB of
#: float64 (and as much again for the normal deviates); more is a mistake, or wants batches
MAX_DRAWS = 10**7


@dataclass(frozen=True)
class LinearPlant:
    """A linear plant m x'' + c x' + k x = F (seed eq. 1 without friction) and its covariance.

    Attributes
    ----------
    m, c, k : float
        Mass (kg), viscous damping (N s/m), stiffness (N/m). For a per-unit-mass plant
        ``m`` is 1 and ``c``, ``k`` are c/m (1/s) and k/m (1/s²).
    cov : ndarray, shape (3, 3)
        Covariance of (m, c, k) in the products of their units; a parameter that was given,
        not estimated, has zero variance; nan entries where the data give no standard error
        (the plant exports, :meth:`draw` refuses).
    per_unit_mass : bool
        True when only c/m and k/m are known (a free decay without a mass): the plant is then
        1/(s² + (c/m) s + k/m), input force per unit mass (N/kg = m/s²).
    notes : tuple of str
        What the export leaves out or assumes (e.g. a Coulomb friction force dropped).
    source : str
        Where the result came from.

    Examples
    --------
    >>> import numpy as np
    >>> p = LinearPlant(2.0, 1.0, 64.0, cov=np.diag([1e-4, 1e-4, 1e-2]))
    >>> p.poles.round(4)
    array([-0.25+5.6513j, -0.25-5.6513j])
    >>> p.draw(3, rng=1).shape
    (3, 3)
    """

    m: float
    c: float
    k: float
    cov: np.ndarray = field(repr=False)
    per_unit_mass: bool = False
    notes: tuple[str, ...] = ()
    source: str = ""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.m) and self.m > 0):
            raise ValueError(f"the plant's mass must be finite and > 0 kg; got m = {self.m!r}")
        for name in ("c", "k"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"the plant's {name} must be finite; got "
                                 f"{name} = {getattr(self, name)!r}")
        cov = np.array(self.cov, dtype=float)
        if cov.shape != (3, 3):
            raise ValueError(f"`cov` must be the (3, 3) covariance of (m, c, k); got "
                             f"shape {cov.shape}")
        if np.isinf(cov).any():
            raise ValueError("`cov` of (m, c, k) has an infinite entry; an unknown one is nan")
        cov.setflags(write=False)
        object.__setattr__(self, "cov", cov)

    @property
    def names(self) -> tuple[str, str, str]:
        """The parameters' names: ("m", "c", "k"), or ("m", "c/m", "k/m") per unit mass."""
        return ("m", "c/m", "k/m") if self.per_unit_mass else ("m", "c", "k")

    @property
    def units(self) -> tuple[str, str, str]:
        """Their SI units."""
        return ("1", "1/s", "1/s^2") if self.per_unit_mass else _UNITS

    @property
    def values(self) -> np.ndarray:
        """(m, c, k) as an array."""
        return np.array([self.m, self.c, self.k])

    @property
    def poles(self) -> np.ndarray:
        """The roots of m s² + c s + k = 0, 1/s (eq. 4), rightmost first."""
        from phoid.dynamics import quadratic_roots

        return quadratic_roots(self.m, self.c, self.k)

    def draw(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """``n`` draws of (m, c, k) from N(estimates, cov), non-physical draws rejected.

        A draw is kept when it is a plant :class:`phoid.dynamics.Plant` accepts: m > 0,
        c ≥ 0 and k ≥ 0; the others are drawn again. The kept draws are therefore the normal
        distribution truncated to that region: their mean and covariance are the estimates'
        only when the rejected probability is negligible (an estimate many stderr from 0).

        Parameters
        ----------
        n : int
            Number of plants (≥ 1).
        rng : numpy.random.Generator or int, optional
            The random generator, or a seed for one.

        Returns
        -------
        ndarray, shape (n, 3)
            The kept (m, c, k) draws, in drawing order.

        Raises
        ------
        ValueError
            For ``n`` < 1 or > :data:`MAX_DRAWS`, an unknown (nan) covariance, or when fewer
            than 1 % of the draws are physical.
        """
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"`n` must be a whole number ≥ 1; got {n!r}")
        if n > MAX_DRAWS:
            raise ValueError(f"`n` = {n} plants is more than {MAX_DRAWS:.0e} (the draws alone "
                             f"would take {24 * n / 2**30:.3g} GiB); draw in batches")
        if not np.all(np.isfinite(self.cov)):
            raise ValueError("the covariance of (m, c, k) is unknown (nan: the data give no "
                             "standard errors), so no plants can be drawn from it")
        rng = np.random.default_rng(rng)
        # a square root of the covariance that also serves a singular one (a given mass)
        w, V = np.linalg.eigh(0.5 * (self.cov + self.cov.T))
        root = V * np.sqrt(np.clip(w, 0.0, None))
        mean = self.values
        kept: list[np.ndarray] = []
        count, tried = 0, 0
        while count < n:
            batch = max(n - count, 16)
            z = rng.standard_normal((batch, 3))
            draws = mean + z @ root.T
            ok = (draws[:, 0] > 0) & (draws[:, 1] >= 0) & (draws[:, 2] >= 0)
            kept.append(draws[ok])
            count += int(ok.sum())
            tried += batch
            if count < n and tried > _MAX_TRIES_PER_DRAW * n:
                raise ValueError(
                    f"only {count} of {tried} draws of (m, c, k) were physical (m > 0, c ≥ 0, "
                    "k ≥ 0): the estimates are too uncertain for a normal sample of plants")
        return np.concatenate(kept)[:n]


def _estimate(obj: Any, name: str) -> tuple[float, float]:
    est = getattr(obj, name)
    value = float(est.value)
    stderr = float("nan") if est.stderr is None else float(est.stderr)
    return value, stderr


def _tracking(result: Any) -> LinearPlant:
    est: Mapping[str, Any] = result.estimates
    values = [float(est[q].value) for q in "mck"]
    fit = result.fit
    free = tuple(getattr(fit, "free", ()))
    # the covariance the estimates carry: the adequacy's robust one where a check failed
    # (its white-noise one where every check passed), in the fit's order of free parameters
    adequacy = getattr(result, "adequacy", None)
    full = np.asarray(getattr(fit, "covariance", np.zeros((0, 0))) if adequacy is None
                      else adequacy.robust_cov, dtype=float)
    cov = np.zeros((3, 3))
    idx = [(i, _ALIASES[name]) for i, name in enumerate(free) if name in _ALIASES]
    for i, a in idx:
        for j, b in idx:
            cov[a, b] = full[i, j]
    return LinearPlant(*values, cov=cov, source=str(getattr(result, "path", "") or ""),
                       notes=("the linear plant only: the Coulomb friction fc, the offset "
                              "force and the loop's delay are not part of it",))


def _free(result: Any, per_unit_mass: bool) -> LinearPlant:
    cov_free = np.asarray(result.cov, dtype=float)  # of (σ, ω₀²)
    src = str(getattr(result, "source", ""))
    if getattr(result, "m", None) is not None and getattr(result, "c", None) is not None:
        m = float(result.m.value)
        # c = 2σm, k = ω₀²m with m given (zero variance)
        J = np.array([[0.0, 0.0], [2.0 * m, 0.0], [0.0, m]])
        return LinearPlant(m, float(result.c.value), float(result.k.value),
                           cov=J @ cov_free @ J.T, source=src,
                           notes=("the mass is the given one (zero variance)",))
    if not per_unit_mass:
        raise ValueError(
            "a free decay determines c/m and k/m only: identify it with a known mass "
            "(identify_free(..., mass=)) or pass per_unit_mass=True for 1/(s² + (c/m)s + k/m)")
    J = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]])
    return LinearPlant(1.0, float(result.c_over_m.value), float(result.k_over_m.value),
                       cov=J @ cov_free @ J.T, per_unit_mass=True, source=src,
                       notes=("per unit mass: input F/m (N/kg), the mass is unknown",))


def linear_plant(result: Any, *, per_unit_mass: bool = False) -> LinearPlant:
    """The linear plant of a result, with the (3, 3) covariance of (m, c, k).

    Parameters
    ----------
    result : object
        A result, by duck typing:

        * ``estimates`` (a mapping with ``m``, ``c``, ``k``) and ``fit`` (``free``,
          ``covariance``): a tracking identification; fc, offset and delay are dropped;
        * ``k_over_m`` and ``cov`` of (σ, ω₀²): a free decay; with a known mass (``m``,
          ``c``, ``k`` set) c = 2σm and k = ω₀²m, else only with ``per_unit_mass``;
        * otherwise ``m``, ``c``, ``k`` estimates and ``cov`` whose leading (3, 3) block is
          that of (m, c, k) (PHO, forced, friction; a friction fit's fc is dropped).
    per_unit_mass : bool, default False
        For a free decay without a mass: export 1/(s² + (c/m)s + k/m) (m = 1, fixed).

    Returns
    -------
    LinearPlant

    Raises
    ------
    ValueError
        For a free decay without a mass (and ``per_unit_mass`` False), or a result with
        no finite m > 0.
    """
    if isinstance(getattr(result, "estimates", None), Mapping):
        return _noted(_tracking(result))
    if hasattr(result, "k_over_m"):
        return _noted(_free(result, per_unit_mass))
    for name in ("m", "c", "k", "cov"):
        if getattr(result, name, None) is None:
            raise ValueError(f"`result` has no {name!r}: not an identification result "
                             f"({type(result).__name__})")
    values = [_estimate(result, q)[0] for q in "mck"]
    cov = np.asarray(result.cov, dtype=float)[:3, :3]
    notes: tuple[str, ...] = ()
    if getattr(result, "fc", None) is not None:
        notes = (f"the linear part only: the Coulomb friction fc = {result.fc.value:.6g} N "
                 "is dropped",)
    return _noted(LinearPlant(*values, cov=cov, notes=notes,
                              source=str(getattr(result, "source", ""))))


def _noted(plant: LinearPlant) -> LinearPlant:
    """``plant`` with a note when its covariance is unknown (nan entries)."""
    if np.all(np.isfinite(plant.cov)):
        return plant
    return replace(plant, notes=(*plant.notes, "the covariance of (m, c, k) is unknown (nan): "
                                 "the data give no standard errors"))
