"""Monte Carlo plants: (m, c, k) drawn from the estimates' normal with the result's covariance."""

from __future__ import annotations

from typing import Any

import numpy as np

from phoid.interop.control import to_control, to_lti
from phoid.interop.plant import LinearPlant, linear_plant

__all__ = ["SAMPLE_FORMS", "sample_plants"]

SAMPLE_FORMS = ("plant", "tf", "ss", "lti")


def sample_plants(result: Any, n: int, rng: np.random.Generator | int | None = None, *,
                  form: str = "plant", per_unit_mass: bool = False) -> list[Any]:
    """``n`` plants drawn from N((m̂, ĉ, k̂), cov) of a result, for Monte Carlo analyses.

    Draws outside the physical region (m ≤ 0, c < 0 or k < 0, which
    :class:`phoid.dynamics.Plant` refuses) are rejected and drawn again
    (:meth:`phoid.interop.plant.LinearPlant.draw`): the sample is the normal truncated to that
    region, equal to it when the estimates are many stderr from 0.

    Parameters
    ----------
    result : object
        A result (:func:`phoid.interop.plant.linear_plant`) or a :class:`LinearPlant`.
    n : int
        Number of plants, 1 … :data:`phoid.interop.plant.MAX_DRAWS`.
    rng : numpy.random.Generator or int, optional
        Random generator or seed.
    form : {"plant", "tf", "ss", "lti"}
        Each plant as a :class:`phoid.dynamics.Plant`, a python-control transfer function or
        state space (:func:`phoid.interop.control.to_control`), or a
        :class:`scipy.signal.lti`.
    per_unit_mass : bool, default False
        A free decay without a mass: draw (c/m, k/m) with m = 1.

    Returns
    -------
    list
        ``n`` plants, in drawing order.
    """
    if form not in SAMPLE_FORMS:
        raise ValueError(f"`form` must be one of {SAMPLE_FORMS}; got {form!r}")
    plant = result if isinstance(result, LinearPlant) else linear_plant(
        result, per_unit_mass=per_unit_mass)
    draws = plant.draw(n, rng)
    if form == "plant":
        from phoid.dynamics import Plant

        return [Plant(*map(float, row)) for row in draws]
    out = []
    for row in draws:
        one = LinearPlant(*map(float, row), cov=np.zeros((3, 3)),
                          per_unit_mass=plant.per_unit_mass,
                          notes=("a Monte Carlo draw", *plant.notes), source=plant.source)
        out.append(to_lti(one, form="tf") if form == "lti" else to_control(one, form=form))
    return out
