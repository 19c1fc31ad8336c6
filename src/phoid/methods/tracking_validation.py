"""Validation of a simulated tracking record against the recorded one: relative errors, residuals.

The measure is the EMPS benchmark's (Janot, Gautier and Brunot, "Data Set and Reference Models
of EMPS", eq. (11), p. 4): "it is common to assess the quality of the identification results by
computing the relative error given by relerr = 100·‖y − ŷ‖/‖y‖, where y is the (N × 1) vector
of measurements; and ŷ is the (N × 1) vector of estimation", applied to the simulated system:
"all the relative errors between the simulated data and the measured ones are calculated with
(11), e.g. when comparing the measured and the simulated positions, one has ŷ = qs and y = qm
where qs is the simulated position" (p. 4). The benchmark's simulation script compares the
position, the velocity, the acceleration and the force over the samples 50:end (MATLAB, 1-based),
dropping the first 49 for the filters' start transient; its measured velocity is the central
difference of the position filtered forward and backward by a 4th-order Butterworth low-pass at
100 Hz, its simulated velocity the plant's own, and its measured force ``gtau·vir``. The
tracking error e = x − r is added here (not in the benchmark): its residual is the position's,
but its norm is that of what the loop did not follow, so its relative error does not depend on
where the origin of x lies. Nothing here depends on how the simulated record was obtained.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from phoid.methods.idim import _filtfilt
from phoid.reports.display import NotebookDisplay

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["SignalError", "TrackingValidation", "validate_tracking"]

_UNIFORM_RTOL = 1e-3  # largest |Δt − mean Δt| / mean Δt accepted as a uniform grid
_DIVERGED = 100.0  # %, a relative error above it: the simulation has left the record
_VELOCITY = ("butterworth-central", "central-difference")


@dataclass(frozen=True)
class SignalError:
    """How far one simulated signal lies from its measurement, over the compared window.

    Attributes
    ----------
    name : str
        ``"position"``, ``"tracking error"``, ``"velocity"`` or ``"force"``.
    unit : str
        SI unit of ``rms`` and ``measured_rms``: ``"m"``, ``"m/s"`` or ``"N"``.
    relative_error : float
        100·‖y − ŷ‖/‖y‖, %, y measured, ŷ simulated (EMPS eq. 11); inf when the simulation is not
        finite in the window, NaN when ‖y‖ = 0.
    rms : float
        Root mean square of the residual y − ŷ, in ``unit``.
    measured_rms : float
        Root mean square of y, in ``unit``.
    """

    name: str
    unit: str
    relative_error: float
    rms: float
    measured_rms: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict; a value that is not finite is null (JSON has no NaN)."""

        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        return {"unit": self.unit, "relative_error_percent": num(self.relative_error),
                "rms": num(self.rms), "measured_rms": num(self.measured_rms)}


@dataclass(frozen=True, repr=False)
class TrackingValidation(NotebookDisplay):
    """The result of :func:`validate_tracking`: the two records side by side and their errors.

    Attributes
    ----------
    t : numpy.ndarray, shape (n,)
        The record's sample times, s.
    x, x_sim : numpy.ndarray, shape (n,)
        Measured and simulated position, m.
    r : numpy.ndarray, shape (n,)
        Reference position, m.
    v, v_sim : numpy.ndarray, shape (n,)
        Measured velocity (``velocity_estimator`` applied to x) and the simulated plant's
        velocity, m/s.
    force : numpy.ndarray or None, shape (n,)
        Measured force G·(sat(u) + w) (sat: the clip to ±saturation when given; G·sat(u) where
        u already contains w), N; None without u.
    force_sim : numpy.ndarray, shape (n,)
        Simulated force, N.
    window : (int, int)
        The compared samples, ``start:stop`` (0-based, stop exclusive).
    velocity_estimator : str
        How ``v`` was obtained from x, in words.
    errors : tuple of SignalError
        Position, tracking error, velocity and (with u) force, in that order.
    saturated : numpy.ndarray of bool or None, shape (n,)
        Where the simulated command saturated (from ``sim.saturated``), or None.
    warnings : tuple of str
        What the numbers do not show by themselves.
    """

    t: np.ndarray
    x: np.ndarray
    x_sim: np.ndarray
    r: np.ndarray
    v: np.ndarray
    v_sim: np.ndarray
    force: np.ndarray | None
    force_sim: np.ndarray
    window: tuple[int, int]
    velocity_estimator: str
    errors: tuple[SignalError, ...]
    saturated: np.ndarray | None = None
    warnings: tuple[str, ...] = ()

    def error(self, name: str) -> SignalError | None:
        """The :class:`SignalError` of ``name`` (e.g. ``"force"``), or None when not compared."""
        return next((e for e in self.errors if e.name == name), None)

    @property
    def departs(self) -> bool:
        """Whether the simulated position has left the record: the tracking error's relative
        error is above 100 % (the residual is larger than what the loop did not follow) or not
        finite — the case the warnings call "the simulation diverges"."""
        e = self.error("tracking error")
        return e is not None and not e.relative_error <= _DIVERGED

    @property
    def e(self) -> np.ndarray:
        """Measured tracking error x − r, m."""
        return self.x - self.r

    @property
    def e_sim(self) -> np.ndarray:
        """Simulated tracking error x_sim − r, m."""
        return self.x_sim - self.r

    @property
    def position_residual(self) -> np.ndarray:
        """x − x_sim, m: the residual of the position and of the tracking error alike."""
        return self.x - self.x_sim

    @property
    def velocity_residual(self) -> np.ndarray:
        """v − v_sim, m/s."""
        return self.v - self.v_sim

    @property
    def force_residual(self) -> np.ndarray | None:
        """force − force_sim, N (None without a measured force)."""
        return None if self.force is None else self.force - self.force_sim

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict: per signal its relative error (%) and RMS residual, and the warnings."""
        start, stop = self.window
        return {
            "method": "tracking-validation",
            "relative_error": "100*norm(y - y_sim)/norm(y)",
            "window": {"start": int(start), "stop": int(stop),
                       "t_start": float(self.t[start]), "t_end": float(self.t[stop - 1])},
            "velocity_estimator": self.velocity_estimator,
            "signals": {e.name: e.to_dict() for e in self.errors},
            "saturated_samples": (None if self.saturated is None
                                  else int(np.count_nonzero(self.saturated))),
            "warnings": list(self.warnings),
        }

    def report(self) -> str:
        """Plain-text report (:func:`phoid.reports.tracking.tracking_text`)."""
        from phoid.reports.tracking import tracking_text

        return tracking_text(self)

    def plot(self, path: str | Path | None = None, *, overwrite: bool = False) -> Any:
        """The figure of :func:`phoid.reports.tracking.plot_tracking`: a PNG at ``path``
        (returns the Path) or, with ``path=None``, the matplotlib Figure."""
        from phoid.reports.tracking import plot_tracking

        return plot_tracking(self, path, overwrite=overwrite)


def _vector(name: str, value: Any, n: int | None, *, finite: bool = True) -> np.ndarray:
    """``value`` as a 1-D float array of length ``n`` (any when None), or a one-line ValueError."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name}: must be one-dimensional, got shape {arr.shape}")
    if n is not None and arr.size != n:
        raise ValueError(f"{name}: length {arr.size} differs from t's length {n}")
    if finite and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains non-finite values (NaN or inf)")
    return arr


def _trim_window(trim: Any, n: int) -> tuple[int, int]:
    """``trim`` = (dropped at the start, at the end) as the window ``(start, stop)``."""
    pair = (trim, trim) if not isinstance(trim, (tuple, list)) else tuple(trim)
    if len(pair) != 2 or any(isinstance(k, bool) or not isinstance(k, (int, np.integer))
                             or k < 0 for k in pair):
        raise ValueError(f"trim: must be an integer >= 0 or a pair of them, got {trim!r}")
    start, stop = int(pair[0]), n - int(pair[1])
    if stop - start < 2:
        raise ValueError(f"trim: {trim!r} leaves {max(stop - start, 0)} of {n} samples "
                         f"(at least 2 needed)")
    return start, stop


def _measured_velocity(x: np.ndarray, dt: float, velocity: str, cutoff: float,
                       order: int) -> tuple[np.ndarray, str]:
    """The measured velocity and its estimator's description."""
    if velocity == "central-difference":
        return np.gradient(x, dt), "central differences of x"
    from scipy import signal

    b, a = signal.butter(order, cutoff / (0.5 / dt))
    return (np.gradient(_filtfilt(b, a, x), dt),
            f"central differences of x low-passed forward-backward (Butterworth order {order},"
            f" {cutoff:g} Hz)")


def _signal_error(name: str, unit: str, y: np.ndarray, y_sim: np.ndarray,
                  sel: slice) -> SignalError:
    """Relative error and RMS residual of ``y_sim`` against ``y`` over ``sel``."""
    y, y_sim = y[sel], y_sim[sel]
    n = y.size
    norm_y = _norm(y)
    if not np.all(np.isfinite(y_sim)):
        rms = rel = math.inf
    else:
        norm_r = _norm(y - y_sim)
        rms = norm_r / math.sqrt(n)
        rel = 100.0 * norm_r / norm_y if norm_y > 0 else math.nan
    return SignalError(name, unit, rel, rms, norm_y / math.sqrt(n))


def _norm(y: np.ndarray) -> float:
    """‖y‖₂ computed as s·‖y/s‖₂ with s = max |y|, so that it does not overflow for large
    values (numpy's sqrt(y·y) does from |y| ≈ 1e154)."""
    s = float(np.max(np.abs(y), initial=0.0))
    if s == 0.0 or not math.isfinite(s):
        return s
    return s * float(np.linalg.norm(y / s))


def _check_scalars(command_gain: Any, saturation: Any, velocity: Any, cutoff: Any,
                   order: Any) -> None:
    """One-line ValueErrors for the scalar options."""
    if isinstance(command_gain, bool) or not isinstance(command_gain, (int, float)) \
            or not math.isfinite(command_gain) or command_gain == 0:
        raise ValueError(f"command_gain: must be a finite nonzero number (N per command unit), "
                         f"got {command_gain!r}")
    if saturation is not None and (isinstance(saturation, bool)
                                   or not isinstance(saturation, (int, float))
                                   or not saturation > 0):
        raise ValueError(f"saturation: must be a number > 0 (command units) or None, "
                         f"got {saturation!r}")
    if velocity not in _VELOCITY:
        raise ValueError(f"velocity: must be one of {', '.join(map(repr, _VELOCITY))}, "
                         f"got {velocity!r}")
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1:
        raise ValueError(f"order: must be an integer >= 1, got {order!r}")
    if isinstance(cutoff, bool) or not isinstance(cutoff, (int, float)) \
            or not math.isfinite(cutoff) or cutoff <= 0:
        raise ValueError(f"cutoff: must be a finite number > 0 (Hz), got {cutoff!r}")


def validate_tracking(t: Any, x: Any, r: Any, sim: Any, *, u: Any = None, w: Any = None,
                      command_gain: float = 1.0, saturation: float | None = None,
                      velocity: str = "butterworth-central", cutoff: float = 100.0,
                      order: int = 4, trim: int | tuple[int, int] = (49, 0),
                      u_contains_w: bool = False) -> TrackingValidation:
    """Compare a simulated tracking record with the measured one, as the EMPS benchmark does.

    For each signal y (measured) and ŷ (simulated), over the samples ``start:stop`` that
    ``trim`` leaves,

        relative error = 100·‖y − ŷ‖/‖y‖  (%),    RMS residual = ‖y − ŷ‖/√N  (SI units)

    (the benchmark's eq. (11), "Data Set and Reference Models of EMPS", p. 4), for

    * the position: y = x, ŷ = sim.x (m);
    * the tracking error: y = x − r, ŷ = sim.x − r (m) — the same residual as the position's,
      normalised by what the loop did not follow rather than by the distance from the origin;
    * the velocity: y = the velocity estimated from x (below), ŷ = sim.v, the simulated plant's
      velocity (m/s);
    * the force, when ``u`` is given: y = G·(sat(u) + w), ŷ = sim.force (N), G the command gain
      and sat the clip to ±``saturation`` (none when None), the loop's force law; with
      ``u_contains_w`` (the recorded u already holds w) y = G·(sat(u − w) + w), which is G·u
      while the controller's part does not saturate.

    The velocity is estimated as the benchmark's simulation script does: x filtered forward and
    backward by a Butterworth low-pass of ``order`` at ``cutoff`` Hz (MATLAB ``filtfilt``'s
    padding), then central differences (``velocity="butterworth-central"``), or central
    differences of x alone (``"central-difference"``). Both are zero-phase, so they lag the
    plant velocity by nothing and sim.v is the fair comparison: the controller's own estimate
    (x_n − x_{n−2})/(2T) lags by one sample, and against it a true velocity would show an error
    a·T at acceleration a.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, uniformly increasing.
    x : array_like, shape (n,)
        Measured position, m.
    r : array_like, shape (n,)
        Reference position, m.
    sim : object
        The simulated record, sampled at the same n instants: read ``t`` (s), ``x`` (m), ``v``
        (m/s), ``force`` (N), each shape (n,), and ``saturated`` ((n,) bool, optional). A
        :class:`phoid.simulation.tracking.TrackingSimulation` is one.
    u : array_like or None, shape (n,)
        Recorded command, command units (e.g. V); None: no force comparison.
    w : array_like or None, shape (n,)
        Recorded additive command input as the plant receives it, command units (needs ``u``).
    command_gain : float
        G, N per command unit (e.g. the EMPS ``gtau``, N/V).
    saturation : float or None
        Clip of the recorded command, command units (None: u is taken as applied).
    velocity : {"butterworth-central", "central-difference"}
        The estimator of the measured velocity.
    cutoff : float
        Butterworth cut-off, Hz (below the Nyquist frequency 1/(2Δt)).
    order : int
        Butterworth order.
    trim : int or (int, int)
        Samples left out of the errors at the start and at the end (an int: at both ends). The
        default (49, 0) is the benchmark's: it compares the samples 50:end (MATLAB, 1-based).
    u_contains_w : bool, default False
        Whether the recorded ``u`` already holds ``w`` (then ``w`` is not added again;
        :func:`~phoid.methods.tracking_semantics.measure_w_in_u` tells from the record).

    Returns
    -------
    TrackingValidation
        Relative errors and RMS residuals per signal, the records side by side, the residual
        arrays and the warnings: the simulated command saturates, the simulation is not finite,
        or a relative error exceeds 100 % (the simulation has left the record).

    Raises
    ------
    ValueError
        One line naming the argument: lengths differ, a record not one-dimensional or not
        finite, t not uniform or sim.t not on t's instants (more than half a sample apart), w
        without u, a cut-off at or above Nyquist, a record too short for the filter or the
        trim.

    Examples
    --------
    >>> import numpy as np
    >>> from types import SimpleNamespace
    >>> t = np.arange(1000) * 1e-3
    >>> r = 0.1 * np.sin(2 * np.pi * t)
    >>> x = r - 0.001 * np.cos(2 * np.pi * t)
    >>> v = np.gradient(x, 1e-3)
    >>> sim = SimpleNamespace(t=t, x=x + 1e-5, v=v, force=np.zeros_like(t))
    >>> val = validate_tracking(t, x, r, sim, trim=0)
    >>> round(val.error("position").rms, 9)
    1e-05
    """
    t = _vector("t", t, None)
    n = t.size
    x = _vector("x", x, n)
    r = _vector("r", r, n)
    _check_scalars(command_gain, saturation, velocity, cutoff, order)
    sim_t = _vector("sim.t", sim.t, n)
    x_sim = _vector("sim.x", sim.x, n, finite=False)
    v_sim = _vector("sim.v", sim.v, n, finite=False)
    f_sim = _vector("sim.force", sim.force, n, finite=False)
    if n < 3:
        raise ValueError(f"t: too short: {n} samples (at least 3 needed)")
    dt = (t[-1] - t[0]) / (n - 1)
    if not dt > 0 or np.max(np.abs(np.diff(t) - dt)) > _UNIFORM_RTOL * dt:
        raise ValueError("t: must be uniformly increasing (non-uniform sample times)")
    off = float(np.max(np.abs(sim_t - t)))
    if not off <= 0.5 * dt:
        raise ValueError(f"sim.t: the simulated samples lie up to {off:g} s from t's "
                         f"(more than half the sample interval {dt:g} s)")
    if velocity == "butterworth-central":
        if not cutoff < 0.5 / dt:
            raise ValueError(f"cutoff: must lie below the Nyquist frequency {0.5 / dt:g} Hz, "
                             f"got {cutoff!r}")
        if n <= 3 * order:
            raise ValueError(f"t: too short for the velocity filter: {n} samples, need more "
                             f"than {3 * order} (order {order})")
    start, stop = _trim_window(trim, n)
    sel = slice(start, stop)
    if not isinstance(u_contains_w, (bool, np.bool_)):
        raise ValueError(f"u_contains_w: must be True or False, got {u_contains_w!r}")

    force = None
    if w is not None and u is None:
        raise ValueError("w: an additive command input needs the recorded command u")
    if u is not None:
        command = _vector("u", u, n)
        if saturation is not None:
            command = np.clip(command, -saturation, saturation)
        if w is not None:
            wv = _vector("w", w, n)
            if not u_contains_w:
                command = command + wv
        force = command_gain * command

    v, estimator = _measured_velocity(x, dt, velocity, float(cutoff), int(order))
    errors = [_signal_error("position", "m", x, x_sim, sel),
              _signal_error("tracking error", "m", x - r, x_sim - r, sel),
              _signal_error("velocity", "m/s", v, v_sim, sel)]
    if force is not None:
        errors.append(_signal_error("force", "N", force, f_sim, sel))

    saturated = getattr(sim, "saturated", None)
    if saturated is not None:
        saturated = np.asarray(saturated, dtype=bool)
        if saturated.shape != (n,):
            raise ValueError(f"sim.saturated: shape {saturated.shape} differs from t's ({n},)")
    warnings = _warnings(t, x_sim, v_sim, f_sim, errors, saturated)
    return TrackingValidation(t=t, x=x, x_sim=x_sim, r=r, v=v, v_sim=v_sim, force=force,
                              force_sim=f_sim, window=(start, stop), velocity_estimator=estimator,
                              errors=tuple(errors), saturated=saturated, warnings=warnings)


def _warnings(t: np.ndarray, x_sim: np.ndarray, v_sim: np.ndarray, f_sim: np.ndarray,
              errors: list[SignalError], saturated: np.ndarray | None) -> tuple[str, ...]:
    """What the relative errors do not say by themselves."""
    out = []
    bad = ~(np.isfinite(x_sim) & np.isfinite(v_sim) & np.isfinite(f_sim))
    if bad.any():
        out.append(f"the simulation is not finite from t = {t[np.argmax(bad)]:g} s on: it has "
                   f"diverged")
    if saturated is not None and saturated.any():
        k = int(np.count_nonzero(saturated))
        out.append(f"the simulated command saturates at {k} of {saturated.size} samples "
                   f"({100.0 * k / saturated.size:.3g} %), first at t = "
                   f"{t[np.argmax(saturated)]:g} s")
    for e in errors:
        if math.isnan(e.relative_error):
            out.append(f"the measured {e.name} is zero in the compared window: its relative "
                       f"error is undefined")
        elif e.relative_error > _DIVERGED and math.isfinite(e.relative_error):
            out.append(f"the simulated {e.name} departs from the record: relative error "
                       f"{e.relative_error:.4g} % > {_DIVERGED:g} % (the simulation diverges)")
    return tuple(out)
