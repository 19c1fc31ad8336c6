r"""Does the recorded command u already contain the additive input w? Measured from the record.

A tracking run may record both the controller's command u and an additive input w (test
pulses, a disturbance injected into the command). Two recording conventions exist, and the
data file rarely says which:

* **u is the controller's output alone** (phoid's default, docs/format.md): the plant's force
  is F = G·(sat(u) + g₀·w), with g₀ = 1 (w in command units) or 1/G (``[loop] w_unit = "N"``);
* **u already holds w**: the recorded u is u_c + g·w, u_c the controller's own output, and the
  force is F = G·sat(u) (the input added by the controller, clipped with its output). The EMPS
  benchmark's validation record is one: its ``vir`` holds the pulses of ``pulses_N`` (1.0139 V
  per unit of "pulses_N"), although its description gives them "in N", and where its u_c
  would pass −10 V the recorded vir, pulse included, does not saturate. Adding w once more
  would count it twice.

The controller law tells them apart, as the pho checks of u against the gains do: with the
loop's gains and velocity estimator, u_c = K·(P·(r − x) − D·v̂) is computed from the recorded
x and r (:func:`~phoid.methods.tracking.controller_commands`), and d = u − u_c is regressed on
w over the samples where w ≠ 0 (least squares through the origin: d = g·w):

* g ≈ 0 (within the law's own misfit): u does not contain w;
* g clearly non-zero and g·w explains d far above its misfit there and where w = 0: u contains
  w with gain g (command units per unit of w).

The stderr of g is Newey–West (:func:`~phoid.fits.hac.hac_covariance`, each stretch of w ≠ 0
a record of its own): the law's misfit is model error and autocorrelated. Samples where u_c
or u reaches the saturation (where the two may differ by the clip) and the estimator's start
are left out. A set may state the convention (``[loop] u_contains_w``, ``[loop] w_in_u_gain``); a
statement the record contradicts gets a warning (:func:`command_input_semantics`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from phoid.dynamics.controller import SampledController
from phoid.fits.hac import hac_covariance
from phoid.io.tracking import W_GAIN_RANGE
from phoid.methods.tracking import controller_commands

__all__ = ["CommandInput", "WInU", "command_input_semantics", "measure_w_in_u"]

MIN_SAMPLES = 10
"""Fewest usable samples with w ≠ 0 for a measurement."""
SIGNIFICANT = 5.0
"""|g|/stderr above which the gain is non-zero (and, below 3, zero)."""
EXPLAINS = 3.0
"""g·w must explain d this many times above the law's misfit for "contains"."""
LAW_MISFIT = 0.25
"""rms(u − u_c)/rms(u_c) where w = 0 above which the controller law does not describe u."""
GAIN_RTOL = 0.01
"""A stated gain is contradicted when it is > 3 stderr and > 1 % from the measured one."""


@dataclass(frozen=True)
class WInU:
    """The measurement of :func:`measure_w_in_u` (units: command units for u, w's own for w).

    Attributes
    ----------
    status : str
        ``"contains"`` (u holds g·w), ``"absent"`` (u does not hold w) or ``"undetermined"``.
    gain : float
        g of d = u − u_c ≈ g·w over the samples where w ≠ 0 (command units per unit of w); NaN
        when not computed.
    stderr : float
        Its Newey–West stderr (NaN when not computed).
    samples : int
        Samples used where w ≠ 0.
    rest_samples : int
        Samples used where w = 0.
    rms_fit : float
        rms of d − g·w where w ≠ 0 (command units).
    rms_rest : float or None
        rms of d where w = 0 (the controller law's own misfit), None when w is never 0.
    rms_u : float
        rms of the recorded u over the samples used.
    reason : str
        Why the status is ``"undetermined"`` (``""`` otherwise).
    """

    status: str
    gain: float
    stderr: float
    samples: int
    rest_samples: int
    rms_fit: float
    rms_rest: float | None
    rms_u: float
    reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict; a value that is not finite is null."""

        def num(v: float | None) -> float | None:
            return float(v) if v is not None and math.isfinite(v) else None

        return {"status": self.status, "gain": num(self.gain), "stderr": num(self.stderr),
                "samples": int(self.samples), "rest_samples": int(self.rest_samples),
                "rms_fit": num(self.rms_fit), "rms_rest": num(self.rms_rest),
                "rms_u": num(self.rms_u), "reason": self.reason or None}

    def describe(self) -> str:
        """The measurement in words (for the warnings)."""
        rest = ("" if self.rms_rest is None
                else f", {_g(self.rms_rest)} where w = 0 ({self.rest_samples} samples)")
        return (f"u − u_controller = {_g(self.gain)}·w ± {_g(self.stderr)} (Newey–West) on the "
                f"{self.samples} samples where w ≠ 0 (rms residual {_g(self.rms_fit)}{rest}, "
                f"against {_g(self.rms_u)} rms of u; command units)")


@dataclass(frozen=True)
class CommandInput:
    """How a run's additive input w reaches the plant, and what the record says about it.

    The applied input, in command units, is ``gain·w``: F = G·(sat(u) + gain·w) with u the
    controller's output (``contains`` False), or F = G·sat(u) with u = u_c + gain·w, the
    controller's output u_c with the input added (``contains`` True).

    Attributes
    ----------
    contains : bool
        Whether the recorded u already holds gain·w.
    gain : float
        Command units per unit of w.
    source : str
        Of ``contains``: ``"stated"`` (``[loop] u_contains_w``), ``"measured"`` (from the
        record) or ``"default"`` (neither: u taken as the controller's output alone).
    gain_source : str
        Of ``gain``: ``"stated"`` (``[loop] w_in_u_gain``), ``"measured"`` or ``"default"``
        (1, or 1/G with ``[loop] w_unit = "N"``).
    measured : WInU or None
        The measurement (None when the run records no u).
    warning : str or None
        What the user should know, in words (the convention taken from the record, or a
        statement the record contradicts), without the run's name.
    """

    contains: bool
    gain: float
    source: str
    gain_source: str
    measured: WInU | None = None
    warning: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: ``u_contains_w``, ``gain``, ``source``, ``gain_source`` and
        ``measured`` (:meth:`WInU.to_dict` or null)."""
        return {"u_contains_w": bool(self.contains), "gain": float(self.gain),
                "source": self.source, "gain_source": self.gain_source,
                "measured": None if self.measured is None else self.measured.to_dict()}

    def applied(self, w: Any) -> np.ndarray:
        """The input the plant receives, ``gain·w`` in command units.

        Raises
        ------
        ValueError
            When ``gain·w`` overflows (beyond the largest double, about 1.8e308) where ``w``
            is finite: one line naming the gain (``[loop] w_in_u_gain`` when stated, else
            where it came from), the largest ``|w|`` and their product, not blaming w.
        """
        w = np.asarray(w, dtype=float)
        with np.errstate(over="ignore", invalid="ignore"):
            out = self.gain * w
        bad = ~np.isfinite(out) & np.isfinite(w)
        if np.any(bad):
            wmax = float(np.max(np.abs(w[bad])))
            what = {"stated": "[loop] w_in_u_gain",
                    "measured": "the gain measured from the record (u − u_controller on w)",
                    "default": "the default gain (1, or 1/command_gain with [loop] w_unit = "
                               "\"N\")"}[self.gain_source]
            raise ValueError(
                f"the applied input gain·w overflows at {int(np.count_nonzero(bad))} "
                f"sample(s): {what} = {self.gain:.5g} times |w| up to {wmax:.5g} is beyond "
                "the largest double (about 1.8e308): is the gain, or w's unit, right?")
        return out


def _g(v: float | None) -> str:
    return "nan" if v is None or not math.isfinite(v) else f"{v:.5g}"


def _rms(a: np.ndarray) -> float:
    """Root mean square, scaled by a power of two so that neither a tiny (1e-300) nor a huge
    (1e300) signal under- or overflows its squares; NaN for no samples."""
    if not a.size:
        return math.nan
    s = _power_of_two(float(np.max(np.abs(a))))
    return s * float(np.sqrt(np.mean((a / s) ** 2)))


#: magnitudes whose squares (or products with each other) leave the doubles' range
_HUGE = 1e150


def _power_of_two(v: float) -> float:
    """The power of two nearest ``v`` (> 0, finite) from above or below: dividing by it is
    exact; 1 for 0 or a value that is not finite."""
    if not (v > 0 and math.isfinite(v)):
        return 1.0
    return math.ldexp(1.0, math.frexp(v)[1])


def _magnitude_reason(w: np.ndarray, d: np.ndarray) -> str:
    """Why the regression of d = u − u_c on w could not be computed in floating point, in
    words: a signal too small (its products underflow to 0) or too large (they overflow),
    named with its largest magnitude."""
    wmax = float(np.max(np.abs(w))) if w.size else math.nan
    dmax = float(np.max(np.abs(d))) if d.size else math.nan
    ask = "are the signals' units right?"
    if not math.isfinite(dmax) or dmax > _HUGE:
        return (f"u − u_controller is too large to compute with (up to {dmax:.3g} command "
                f"units: the arithmetic overflows; {ask})")
    if wmax > _HUGE:
        return (f"w is too large to compute with (|w| up to {wmax:.3g}: the arithmetic "
                f"overflows; {ask})")
    if wmax < 1.0 / _HUGE:
        return (f"w is too small to compute with (|w| at most {wmax:.3g} against u − "
                f"u_controller up to {dmax:.3g} command units: the arithmetic underflows; "
                f"{ask})")
    return (f"the gain of u − u_controller on w overflows (|w| at most {wmax:.3g} against "
            f"u − u_controller up to {dmax:.3g} command units; {ask})")


def _segments(mask: np.ndarray) -> list[slice]:
    """The stretches where ``mask`` is True, as slices."""
    edges = np.diff(np.concatenate(([0], mask.view(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [slice(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def measure_w_in_u(u: Any, w: Any, x: Any, r: Any, controller: SampledController, *,
                   unit_gain: float = 1.0) -> WInU:
    """Measure whether the recorded command u already contains the additive input w.

    Parameters
    ----------
    u, w, x, r : array_like, shape (N,)
        Recorded command (command units), additive input (its own unit), position (m) and
        reference (m) at the controller's instants.
    controller : SampledController
        The loop that ran: its gains, velocity estimator and saturation.
    unit_gain : float, default 1
        The gain g₀ with which w would enter u if u held it in w's declared unit (1 for
        command units, 1/G for newtons): the size of the effect that "absent" must rule out.

    Returns
    -------
    WInU
        The gain g of u − u_c ≈ g·w, its stderr, the misfits, and the verdict (module
        docstring): ``"contains"``, ``"absent"`` or ``"undetermined"`` with its reason.
    """
    with np.errstate(all="ignore"):  # absurd magnitudes overflow: said as undetermined
        return _measure(np.asarray(u, dtype=float), np.asarray(w, dtype=float),
                        np.asarray(x, dtype=float), np.asarray(r, dtype=float), controller,
                        float(unit_gain))


def _measure(u: np.ndarray, w: np.ndarray, x: np.ndarray, r: np.ndarray,
             controller: SampledController, unit_gain: float) -> WInU:
    """:func:`measure_w_in_u` on float arrays, under ``np.errstate(all="ignore")``."""
    uc = controller_commands(x, r, controller)
    d = u - uc
    usable = np.isfinite(d) & np.isfinite(uc)
    usable[: max(controller.taps, 1)] = False
    clipped = 0
    if controller.saturation is not None:
        inside = (np.abs(uc) < controller.saturation) & (np.abs(u) < controller.saturation)
        clipped = int(np.count_nonzero(usable & ~inside & (w != 0)))
        usable &= inside
    on = usable & (w != 0)
    rest = usable & (w == 0)
    n_on, n_rest = int(np.count_nonzero(on)), int(np.count_nonzero(rest))
    rms_u = _rms(u[usable])
    rms_rest = _rms(d[rest]) if n_rest else None

    def undetermined(reason: str, gain: float = math.nan, stderr: float = math.nan,
                     rms_fit: float = math.nan) -> WInU:
        return WInU("undetermined", gain, stderr, n_on, n_rest, rms_fit, rms_rest, rms_u,
                    reason)

    if n_on < MIN_SAMPLES:
        left = (f"; {clipped} more where u or the controller's command reaches the "
                f"saturation ±{controller.saturation:g} are left out" if clipped else "")
        return undetermined(f"w is non-zero at only {n_on} usable sample(s) (at least "
                            f"{MIN_SAMPLES} are needed{left})")
    wo, do = w[on], d[on]
    if not (np.max(np.abs(wo)) <= _HUGE and np.max(np.abs(do)) <= _HUGE):
        return undetermined(_magnitude_reason(wo, do))
    # w scaled by a power of two (exact) for the sums, so that a w of 1e-300 or 1e300 does
    # not under- or overflow its square; the gain is then wo·do/(wo·wo) unscaled
    scale = _power_of_two(float(np.max(np.abs(wo))))
    ws = wo / scale
    wsws = float(ws @ ws)  # > 0: w ≠ 0 there, and |ws| ≥ 1/2 at its largest
    gain = float(ws @ do) / wsws / scale
    e = d - gain * w
    rms_fit = _rms(e[on])
    if not (math.isfinite(gain) and math.isfinite(rms_fit)):
        return undetermined(_magnitude_reason(wo, do))
    if abs(gain) > W_GAIN_RANGE[1]:
        # w far too small for the u it would be in: no physical gain (the stated one's range)
        return undetermined(
            f"w is too small against u − u_controller to be in it with a physical gain (|w| "
            f"at most {float(np.max(np.abs(wo))):.3g}, a gain of {_g(gain)} beyond "
            f"{W_GAIN_RANGE[1]:.0e}; are the signals' units right?)", gain, math.nan, rms_fit)
    segs = _segments(on)
    try:
        cov = hac_covariance([w[s, None] for s in segs], [e[s] for s in segs])
        stderr = float(math.sqrt(max(float(cov.robust[0, 0]), 0.0)))
    except (ValueError, np.linalg.LinAlgError):
        stderr = math.nan
    if not math.isfinite(stderr):
        stderr = rms_fit / (math.sqrt(wsws) * scale)
    rms_uc_rest = _rms(uc[rest]) if n_rest else math.nan
    if rms_rest is not None and rms_rest > LAW_MISFIT * max(rms_uc_rest, 1e-300):
        return undetermined(
            f"the controller law does not reproduce the recorded u where w = 0 (u − u_controller"
            f" has {_g(rms_rest)} rms against {_g(rms_uc_rest)} for u_controller): check P, D, "
            "gain and [loop] velocity, or the column mapped to u", gain, stderr, rms_fit)
    noise = max(rms_fit, rms_rest or 0.0)
    w_rms = _rms(wo)
    explained = abs(gain) * w_rms
    if abs(gain) > SIGNIFICANT * stderr and explained > EXPLAINS * noise:
        status, reason = "contains", ""
    elif (abs(gain) <= 3.0 * stderr or explained < noise) \
            and abs(unit_gain) * w_rms > EXPLAINS * noise:
        status, reason = "absent", ""
    else:
        return undetermined(
            f"w is too small against the controller law's misfit to tell ({_g(w_rms)} rms of w "
            f"where it is non-zero, misfit {_g(noise)} command units)", gain, stderr, rms_fit)
    return WInU(status, gain, stderr, n_on, n_rest, rms_fit, rms_rest, rms_u, reason)


def command_input_semantics(loop: Any, u: Any, w: Any, x: Any, r: Any,
                            controller: SampledController) -> CommandInput | None:
    """How one run's w reaches the plant: stated by ``[loop]``, else measured, else default.

    Parameters
    ----------
    loop : mapping
        The set's ``[loop]`` table as written (``u_contains_w``, ``w_in_u_gain``, ``w_unit``
        read; the reader has checked their types).
    u, w, x, r : array_like or None
        The run's recorded signals (u and w may be None).
    controller : SampledController
        The run's loop.

    Returns
    -------
    CommandInput or None
        None when the run records no w (nothing to apply).

    Raises
    ------
    ValueError
        ``[loop] u_contains_w = true`` (or ``w_in_u_gain``) on a run that records no u or no w.
    """
    stated = loop.get("u_contains_w")
    stated_gain = loop.get("w_in_u_gain")
    if stated is None and stated_gain is not None:
        stated = True
    if w is None:
        if stated:
            raise ValueError("[loop] u_contains_w is true (or w_in_u_gain is given), but the run "
                             "records no w ([run.columns] w)")
        return None
    if stated and u is None:
        raise ValueError("[loop] u_contains_w is true (or w_in_u_gain is given), but the run "
                         "records no u ([run.columns] u): there is no recorded command that "
                         "could contain w")
    newtons = loop.get("w_unit", "command") == "N"
    unit_gain = 1.0 / controller.command_gain if newtons else 1.0
    unit = "N" if newtons else "command units"
    m = None if u is None else measure_w_in_u(u, w, x, r, controller, unit_gain=unit_gain)
    if stated is None:
        if m is None or not np.any(np.asarray(w) != 0):  # no u, or no w to apply: nothing said
            return CommandInput(False, unit_gain, "default", "default")
        if m.status == "contains":
            text = (f"the recorded command u already contains the additive input w: "
                    f"{m.describe()}; phoid takes the force as G·sat(u), u = u_controller + "
                    f"{_g(m.gain)}·w, not adding w a second time (state it: [loop] u_contains_w "
                    f"= true){_unit_note(m.gain, unit_gain, unit, controller)}")
            return CommandInput(True, m.gain, "measured", "measured", m, text)
        if m.status == "absent":
            return CommandInput(False, unit_gain, "measured", "default", m)
        text = (f"whether the recorded command u already contains the additive input w cannot "
                f"be told from the record: {m.reason}; phoid takes u as the controller's output "
                "alone, F = G·(sat(u) + w) (state it: [loop] u_contains_w = true or false)")
        return CommandInput(False, unit_gain, "default", "default", m, text)
    if not stated:
        text = None
        if m is not None and m.status == "contains":
            text = (f"[loop] u_contains_w = false, but the record says u already contains w: "
                    f"{m.describe()}; w is counted twice in the force (remove the key or set "
                    "it to true)")
        return CommandInput(False, unit_gain, "stated", "default", m, text)
    if stated_gain is not None:
        gain, gain_source = float(stated_gain), "stated"
    elif m is not None and m.status == "contains":
        gain, gain_source = m.gain, "measured"
    else:
        gain, gain_source = unit_gain, "default"
    text = None
    if gain_source == "default" and m is not None and m.status == "undetermined":
        text = (f"[loop] u_contains_w = true, but the gain with which u holds w cannot be "
                f"measured from the record: {m.reason}; {_g(gain)} is taken (state it: [loop] "
                "w_in_u_gain)")
    if m is not None and m.status == "absent":
        text = (f"[loop] u_contains_w = true, but the record says u does not contain w: "
                f"{m.describe()}; the force leaves w out (remove the key or set it to false)")
    elif m is not None and m.status == "contains" and gain_source == "stated" \
            and abs(gain - m.gain) > max(3.0 * m.stderr, GAIN_RTOL * abs(m.gain)):
        text = (f"[loop] w_in_u_gain = {_g(gain)}, but the record says {m.describe()} "
                f"(remove the key to use the measured gain)")
    return CommandInput(True, gain, "stated", gain_source, m, text)


def _unit_note(gain: float, unit_gain: float, unit: str, ctrl: SampledController) -> str:
    """A hint when the measured gain is far (beyond a factor 2) from w's declared unit's."""
    ratio = abs(gain / unit_gain) if unit_gain else math.inf
    if 0.5 <= ratio <= 2.0:
        return ""
    if unit == "N":
        return (f"; w in N would enter u as 1/G = {_g(unit_gain)} per N, not {_g(gain)}: w is "
                "more likely in command units ([loop] w_unit)")
    other = 1.0 / ctrl.command_gain
    hint = (" — as a force in N would (1/G = " + _g(other) + "): [loop] w_unit = \"N\"?"
            if 0.5 <= abs(gain / other) <= 2.0 else "")
    return f"; w enters u with gain {_g(gain)}, not 1 as an input in command units would{hint}"
