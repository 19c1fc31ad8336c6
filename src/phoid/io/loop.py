"""A PHO set's ``[loop]`` read: the digital controller and where the sensor noise sits.

The reader (:mod:`phoid.io.reading`) keeps the whole ``[loop]`` table of a ``pho`` set and checks
only ``delay``; the identification reads the rest here (docs/format.md, "``[loop]`` keys"):

- :func:`read_digital_loop`: ``sample_time``, ``delay_samples``, ``velocity`` and ``cutoff`` as a
  :class:`phoid.dynamics.digital.DigitalPD`, each key checked by type and range and against the
  records, and any other key refused;
- :func:`read_noise_placement`: ``noise = "in-loop" | "outside"``, where the sensor noise sits
  relative to the loop: ``"in-loop"``, the controller reads the recorded, noisy position (a
  digital rig); ``"outside"``, it acts on the true position; absent, not stated.

Every problem raises :class:`phoid.errors.IdentificationError` with one line naming the
manifest, ``[loop]`` and the key. A tracking set's ``[loop]`` is another table
(:mod:`phoid.io.tracking`), without these keys.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from phoid.dynamics.digital import DigitalPD, timing_problem
from phoid.dynamics.velocity import FIRST_ORDER_PRESETS, VELOCITY_PRESETS, estimator_taps
from phoid.errors import IdentificationError

__all__ = [
    "DIGITAL_KEYS",
    "DIGITAL_VELOCITIES",
    "MAX_DELAY_SAMPLES",
    "NOISE_PLACEMENTS",
    "PHO_LOOP_KEYS",
    "PHO_VELOCITIES",
    "read_digital_loop",
    "read_noise_placement",
]

DIGITAL_KEYS = ("sample_time", "delay_samples", "velocity", "cutoff")
"""The digital loop's ``[loop]`` keys: each needs ``sample_time``."""
NOISE_PLACEMENTS = ("in-loop", "outside")
"""The values of ``[loop] noise``: the sensor noise inside the loop (the controller reads the
recorded position) or outside it (the controller acts on the true position)."""
PHO_LOOP_KEYS = ("delay", *DIGITAL_KEYS, "noise")
"""Every key of a PHO set's ``[loop]``; another is refused by name."""
DIGITAL_VELOCITIES = FIRST_ORDER_PRESETS
"""The first-order estimators of :mod:`phoid.dynamics.velocity` (what the design's settings
take, :mod:`phoid.planning.settings`)."""
PHO_VELOCITIES = VELOCITY_PRESETS
"""The estimators a PHO set's digital loop takes (``[loop] velocity``): every preset of
:mod:`phoid.dynamics.velocity` (``phoid simulate`` writes each): the in-loop route rebuilds the
force from any of them, and the modal route's exact modes and release model
(:func:`phoid.simulation.simulate`) take each."""

#: the longest command delay of a digital loop phoid identifies, in controller periods: each
#: evaluation of the loop's roots is an eigenvalue problem of order delay_samples + 3 per run
#: (about 1 s at 1000); a real controller's delay is a few periods
MAX_DELAY_SAMPLES = 1000


def _table(experiment: Any) -> tuple[dict[str, Any], str]:
    """The set's ``[loop]`` as a dict, and ``"<manifest>: [loop]"`` for messages."""
    return dict(getattr(experiment, "loop", {}) or {}), f"{experiment.path}: [loop]"


def read_noise_placement(experiment: Any) -> str | None:
    """The manifest's ``[loop] noise``: ``"in-loop"``, ``"outside"``, or None when absent.

    ``"in-loop"``: the controller reads the recorded, noisy position (a digital rig: its noise
    and quantisation enter the loop); ``"outside"``: the controller acts on the true position;
    absent: not stated (the identification chooses by the data).

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        The set (its ``path`` and ``loop``).

    Returns
    -------
    str or None
        One of :data:`NOISE_PLACEMENTS`, or None.

    Raises
    ------
    phoid.errors.IdentificationError
        For any other value (another string, a number, a boolean, …), one line naming the
        manifest, ``[loop] noise`` and the allowed values.
    """
    loop, where = _table(experiment)
    if "noise" not in loop:
        return None
    value = loop["noise"]
    if not isinstance(value, str) or value not in NOISE_PLACEMENTS:
        raise IdentificationError(
            f"{where} noise must be one of {', '.join(map(repr, NOISE_PLACEMENTS))} (where the "
            f"sensor noise sits: read by the controller, or outside the loop); got "
            f"{_shown(value)}")
    return value


def read_digital_loop(experiment: Any) -> DigitalPD | None:
    """The manifest's digital loop ([loop] sample_time, …) as a DigitalPD, or None.

    Every key is checked by type and range, one line naming the manifest and the key:
    ``sample_time`` a number > 0 (s), ``delay_samples`` a whole number from 0 to
    :data:`MAX_DELAY_SAMPLES`, ``velocity`` one of :data:`PHO_VELOCITIES`, ``cutoff`` a
    number > 0 (rad/s), ``noise`` (:func:`read_noise_placement`); a key not in
    :data:`PHO_LOOP_KEYS` is refused; and against the records
    (:func:`phoid.dynamics.digital.timing_problem`): no sample time, command delay or velocity
    filter time constant longer than the longest record.

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        The set (its ``path``, ``loop`` and ``runs``).

    Returns
    -------
    phoid.dynamics.digital.DigitalPD or None
        Gains 0 (each run has its own); None without ``sample_time`` (a continuous loop).

    Raises
    ------
    phoid.errors.IdentificationError
        One line naming the manifest, ``[loop]`` and the key.
    """
    loop, where = _table(experiment)
    unknown = sorted(set(loop) - set(PHO_LOOP_KEYS), key=str)
    if unknown:
        raise IdentificationError(
            f"{where} {unknown[0]}: unknown key (known: {', '.join(PHO_LOOP_KEYS)})")
    read_noise_placement(experiment)
    if "sample_time" not in loop:
        extra = [key for key in DIGITAL_KEYS if key in loop]
        if extra:
            raise IdentificationError(
                f"{where} {extra[0]}: needs [loop] sample_time (s), the controller's sampling "
                "period"
            )
        return None
    T = _loop_number(where, "sample_time", loop["sample_time"], "s")
    d = loop.get("delay_samples", 0)
    whole = isinstance(d, numbers.Integral) or (isinstance(d, float) and d.is_integer())
    if isinstance(d, bool) or not whole or not 0 <= d <= 2**62:
        raise IdentificationError(
            f"{where} delay_samples must be a whole number ≥ 0 (controller periods); got "
            f"{_shown(d)}")
    if d > MAX_DELAY_SAMPLES:
        raise IdentificationError(
            f"{where} delay_samples = {int(d)}: phoid models a command delay of at most "
            f"{MAX_DELAY_SAMPLES} controller periods (the loop's polynomial has degree "
            "delay_samples + 3, its roots cost the cube of that)")
    velocity = loop.get("velocity", "backward-difference")
    if not isinstance(velocity, str) or velocity not in PHO_VELOCITIES:
        raise IdentificationError(
            f"{where} velocity must be one of {', '.join(map(repr, PHO_VELOCITIES))}; got "
            f"{_shown(velocity)}")
    cutoff = loop.get("cutoff")
    if cutoff is not None:
        cutoff = _loop_number(where, "cutoff", cutoff, "rad/s")
    spans = []
    for r in getattr(experiment, "runs", ()):
        t = getattr(r, "t", None)
        if t is not None and np.size(t) >= 2:
            spans.append(float(t[-1]) - float(t[0]))
    # the records first: a cut-off 1e6 times too low is a unit mistake the records show, before
    # the filter's own rounding check
    if spans:
        problem = timing_problem(T, int(d), cutoff if velocity == "filtered" else None,
                                 estimator_taps(velocity), max(spans), velocity)
        if problem is not None:
            raise IdentificationError(f"{where} {problem[0]}{problem[1]}")
    try:
        return DigitalPD(P=0.0, D=0.0, sample_time=T, delay_samples=int(d),
                         velocity=velocity, cutoff=cutoff)
    except (ValueError, TypeError) as exc:
        raise IdentificationError(f"{where}: {exc}") from None


def _loop_number(where: str, key: str, value: Any, unit: str) -> float:
    """A [loop] number > 0 (a TOML number, not a string or a boolean), or one line."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise IdentificationError(
            f"{where} {key} must be a number > 0 ({unit}); got {_shown(value)}")
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise IdentificationError(f"{where} {key} must be a finite number > 0 ({unit}); got {v:g}")
    return v


def _shown(value: Any) -> str:
    """A manifest value as messages quote it: repr, cut, with its TOML kind."""
    kind = {bool: "a boolean", str: "a string", int: "an integer", float: "a number",
            list: "an array", dict: "a table"}.get(type(value), type(value).__name__)
    text = repr(value)
    return f"{text[:40] + '…' if len(text) > 40 else text} ({kind})"
