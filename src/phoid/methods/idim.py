"""Inverse dynamics identification by least squares (IDIM-LS) of a tracking record.

The robotics standard for an axis whose command is recorded: the plant model

    gtau·u = M q̈ + Fv q̇ + Fc sign(q̇) + OF

is linear in (M, Fv, Fc, OF), so with q̇ and q̈ obtained from the recorded position by a
zero-phase low-pass filter and central differences ("band-pass filtering"), and every column and
the force low-pass filtered and resampled together ("decimate process": the same linear filter
on both sides keeps the equation), the parameters are the ordinary least-squares solution
(Gautier; Janot, Gautier and Brunot, the EMPS benchmark). The filters follow MATLAB's
``filtfilt`` and ``decimate`` conventions exactly, so that the published reference numbers of a
benchmark are reproducible. ``scipy.signal`` is imported inside :func:`idim_ls` only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from phoid.methods.estimate import Estimate
from phoid.reports.display import NotebookDisplay

__all__ = ["IDIMFit", "idim_ls", "idim_ls_runs", "residual_filters"]

_NAMES = ("M", "Fv", "Fc", "OF")
_UNITS = ("kg", "N s/m", "N", "N")
_ALL_UNITS = {"M": "kg", "Fv": "N s/m", "Fc": "N", "OF": "N", "k": "N/m"}
_ALIASES = {"m": "M", "c": "Fv", "fc": "Fc", "offset": "OF"}  # phoid's names of the parameters
_DECIMATE_ORDER = 8  # MATLAB decimate's default Chebyshev I order
_DECIMATE_RIPPLE = 0.05  # dB
_UNIFORM_RTOL = 1e-3  # largest |Δt − mean Δt| / mean Δt accepted as a uniform grid


@dataclass(frozen=True, repr=False)
class IDIMFit(NotebookDisplay):
    """The result of :func:`idim_ls`.

    Attributes
    ----------
    M : Estimate
        Moving mass, kg.
    Fv : Estimate
        Viscous friction coefficient, N s/m.
    Fc : Estimate
        Coulomb friction force, N.
    OF : Estimate
        Constant offset force, N.
    covariance : numpy.ndarray
        The (4, 4) OLS covariance of (M, Fv, Fc, OF), σ² (XᵀX)⁻¹ with σ² = RSS/(n − p), in the
        products of their units.
    relative_error : float
        100·‖y − Xθ̂‖/‖y‖ of the decimated force y, %.
    condition_number : float
        2-norm condition number of the decimated regressor X.
    lag1_autocorrelation : float
        Σ eₖeₖ₊₁ / Σ eₖ² of the residual e (0 for white noise).
    n_samples : int
        Rows of the decimated regression.
    warnings : tuple of str
        What the user must know to read the stderrs.
    k : Estimate or None
        Stiffness, N/m, when fitted or fixed (:func:`idim_ls_runs`); None in the four-column
        regression.
    free : tuple of str
        The fitted parameters, in the order of ``covariance``.
    regressor : numpy.ndarray or None
        The decimated regressor X of the free parameters (rows of every record, stacked).
    target : numpy.ndarray or None
        The decimated force y the free parameters fit (the fixed ones' columns taken off).
    rows : tuple of int
        Rows of each record in ``regressor`` (in order).
    recipe : Mapping or None
        ``dt`` (s), ``cutoff`` (Hz), ``order``, ``decimation`` of each record's filters
        (the first record's ``dt``), for :func:`residual_filters`.
    """

    M: Estimate
    Fv: Estimate
    Fc: Estimate
    OF: Estimate
    covariance: np.ndarray
    relative_error: float
    condition_number: float
    lag1_autocorrelation: float
    n_samples: int
    warnings: tuple[str, ...] = ()
    k: Estimate | None = None
    free: tuple[str, ...] = _NAMES
    regressor: np.ndarray | None = field(default=None, repr=False)
    target: np.ndarray | None = field(default=None, repr=False)
    rows: tuple[int, ...] = ()
    recipe: Any = None

    @property
    def residual(self) -> np.ndarray | None:
        """y − Xθ̂ of the decimated regression (N), or None without the regression."""
        if self.regressor is None or self.target is None:
            return None
        theta = np.array([getattr(self, n).value for n in self.free])
        return self.target - self.regressor @ theta

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict: the four estimates, the fit statistics and the warnings."""
        return {
            "method": "idim-ls",
            "parameters": {name: getattr(self, name).to_dict() for name in _NAMES}
            | ({"k": self.k.to_dict()} if self.k is not None else {}),
            "free": list(self.free),
            "covariance": np.asarray(self.covariance, dtype=float).tolist(),
            "relative_error_percent": float(self.relative_error),
            "condition_number": float(self.condition_number),
            "lag1_autocorrelation": float(self.lag1_autocorrelation),
            "n_samples": int(self.n_samples),
            "warnings": list(self.warnings),
        }


def _filtfilt(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Zero-phase filtering with MATLAB ``filtfilt``'s conventions (along axis 0).

    MATLAB extends the record at each end by ``3·(nfilt − 1)`` samples, ``nfilt = max(len(b),
    len(a))``, reflected through the end sample (odd extension), and starts both passes from the
    filter's steady state scaled by the first sample; scipy's default pads ``3·nfilt`` samples.
    """
    from scipy import signal

    padlen = 3 * (max(len(a), len(b)) - 1)
    return signal.filtfilt(b, a, x, axis=0, padtype="odd", padlen=padlen)


def _decimate_filter(r: int) -> tuple[np.ndarray, np.ndarray]:
    """MATLAB ``decimate``'s anti-aliasing filter: Chebyshev I, order 8, 0.05 dB, cut-off 0.8/r.

    As MATLAB does, the order is lowered while the designed transfer function misses −0.05 dB at
    its cut-off by more than 1e−6 dB (a numerically broken design).
    """
    from scipy import signal

    order = _DECIMATE_ORDER
    while order > 0:
        b, a = signal.cheby1(order, _DECIMATE_RIPPLE, 0.8 / r)
        z = np.exp(-1j * math.pi * 0.8 / r)
        gain = abs(np.polyval(b[::-1], z) / np.polyval(a[::-1], z))
        if np.any(b != 0) and abs(20 * math.log10(gain) + _DECIMATE_RIPPLE) <= 1e-6:
            return b, a
        order -= 1
    raise ValueError(f"decimation: no usable anti-aliasing filter for factor {r}")


def _decimate(x: np.ndarray, r: int) -> np.ndarray:
    """MATLAB ``decimate(x, r)`` along axis 0: the filter of :func:`_decimate_filter` applied
    by :func:`_filtfilt`, then every r-th sample kept so that the last sample is kept
    (MATLAB keeps samples ``nbeg:r:nd``, 1-based, with ``nbeg = r − (r·ceil(nd/r) − nd)``)."""
    if r == 1:
        return x
    b, a = _decimate_filter(r)
    y = _filtfilt(b, a, x)
    nd = x.shape[0]
    nbeg = r - (r * (-(-nd // r)) - nd)
    return y[nbeg - 1::r]


def _trim_pair(trim) -> tuple[int, int]:
    """``trim`` as (samples dropped at the start, at the end), or a one-line ValueError."""
    pair = (trim, trim) if not isinstance(trim, (tuple, list)) else tuple(trim)
    if len(pair) != 2 or any(isinstance(k, bool) or not isinstance(k, (int, np.integer))
                             or k < 0 for k in pair):
        raise ValueError(f"trim: must be an integer >= 0 or a pair of them, got {trim!r}")
    return int(pair[0]), int(pair[1])


def _check(t, q, u, gain, cutoff, order, decimation, trim, sigma):
    """The inputs as float arrays and the sample interval, or a one-line ValueError."""
    arrays = {}
    for name, value in (("t", t), ("q", q), ("u", u)):
        arr = np.asarray(value, dtype=float)
        if arr.ndim != 1:
            raise ValueError(f"{name}: must be one-dimensional, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name}: contains non-finite values (NaN or inf)")
        arrays[name] = arr
    n = arrays["t"].size
    for name in ("q", "u"):
        if arrays[name].size != n:
            raise ValueError(f"{name}: length {arrays[name].size} differs from t's length {n}")
    if not (isinstance(gain, (int, float)) and math.isfinite(gain) and gain > 0):
        raise ValueError(f"gain: must be a finite number > 0 (N per unit of u), got {gain!r}")
    if sigma not in ("ols", "sample-std"):
        raise ValueError(f"sigma: must be 'ols' or 'sample-std', got {sigma!r}")
    start, end = _trim_pair(trim)
    for name, value, low in (("order", order, 1), ("decimation", decimation, 1)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{name}: must be an integer >= {low}, got {value!r}")
    if n < 2:
        raise ValueError(f"t: too short for the filter: {n} samples")
    steps = np.diff(arrays["t"])
    dt = (arrays["t"][-1] - arrays["t"][0]) / (n - 1)
    if not dt > 0 or np.max(np.abs(steps - dt)) > _UNIFORM_RTOL * dt:
        raise ValueError("t: must be uniformly increasing (non-uniform sample times)")
    if not (isinstance(cutoff, (int, float)) and 0 < cutoff < 0.5 / dt):
        raise ValueError(f"cutoff: must lie in (0, {0.5 / dt:g}) Hz (Nyquist), got {cutoff!r}")
    # MATLAB filtfilt needs more than 3·(nfilt − 1) samples; the decimation filter has nfilt = 9
    # and the regression p + 1 = 5 rows.
    need = max(3 * order + 1,
               start + end + max(3 * _DECIMATE_ORDER + 1 if decimation > 1 else 1,
                              4 * decimation + 1))
    if n < need:
        raise ValueError(f"t: too short for the filter/decimation: {n} samples, need at least "
                         f"{need} (order {order}, decimation {decimation}, trim {trim})")
    return arrays["t"], arrays["q"], arrays["u"], float(dt), (start, end)


def idim_ls(t: np.ndarray, q: np.ndarray, u: np.ndarray, *, gain: float, cutoff: float = 100.0,
            order: int = 4, decimation: int = 10, trim: int | tuple[int, int] = 50,
            sigma: str = "ols") -> IDIMFit:
    """Identify M, Fv, Fc, OF of ``gain·u = M q̈ + Fv q̇ + Fc sign(q̇) + OF`` by IDIM-LS.

    The recipe (Janot, Gautier and Brunot's EMPS benchmark):

    1. q filtered by a Butterworth low-pass of ``order`` at ``cutoff`` Hz, forward and backward
       (MATLAB ``filtfilt``: odd extension of 3·order samples, steady-state initial conditions);
    2. q̇ and q̈ by central differences of the filtered q and then of q̇ (``numpy.gradient``);
    3. ``trim`` samples dropped at each end (the filters' end transients), or ``trim =
       (start, end)`` samples at the start and at the end;
    4. the columns q̈, q̇, sign(q̇), 1 and the force ``gain·u`` each decimated by ``decimation``
       (MATLAB ``decimate``: Chebyshev I of order 8, 0.05 dB ripple, cut-off 0.8/decimation of
       Nyquist, forward–backward, the samples kept so that the last one is kept). The same
       linear filter on both sides keeps the model's equation, and it removes the noise above
       the useful band before the resampling;
    5. ordinary least squares θ̂ = argmin ‖y − Xθ‖, stderr = sqrt(diag(σ² (XᵀX)⁻¹)),
       σ² = RSS/(n − p), p = 4 (``sigma="ols"``, the unbiased estimate), or σ² the sample
       variance of the residual, Σ(eₖ − ē)²/(n − 1) (``sigma="sample-std"``: MATLAB's
       ``std(e)``, the convention of the EMPS benchmark's published script; with the constant
       column ē = 0, so the two differ by the factor (n − p)/(n − 1) only).

    The EMPS benchmark's published IDIM-LS (Janot, Gautier and Brunot) is reproduced to every
    printed digit by ``idim_ls(t, qm, vir, gain=gtau, trim=(49, 0), sigma="sample-std")``: its
    script keeps the samples 50:end (MATLAB, 1-based) of the record, which the diagonal of the
    QR factor of its regressor, printed in the benchmark's description, confirms (24 792 rows
    before the decimation).

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, uniformly spaced.
    q : array_like, shape (n,)
        Measured position, m.
    u : array_like, shape (n,)
        Recorded command (e.g. the amplifier voltage, V).
    gain : float
        Command gain, N per unit of u (N/V): the force is ``gain·u``.
    cutoff : float, optional
        Butterworth cut-off, Hz (below the Nyquist frequency).
    order : int, optional
        Butterworth order.
    decimation : int, optional
        Decimation factor (1: none).
    trim : int or (int, int), optional
        Samples dropped at each end before the decimation, or (at the start, at the end).
    sigma : {"ols", "sample-std"}, optional
        The residual scale of the stderrs: RSS/(n − p) or the sample variance (n − 1).

    Returns
    -------
    IDIMFit
        M (kg), Fv (N s/m), Fc (N), OF (N) with their OLS stderrs and covariance, the relative
        error of the fitted force (%), the regressor's condition number, the residual's lag-1
        autocorrelation and the warnings.

    Raises
    ------
    ValueError
        One line naming the argument: lengths differ, t not uniform, a record too short for the
        filters and the decimation, non-finite values, gain ≤ 0, a cut-off at or above Nyquist.

    Notes
    -----
    The OLS stderrs assume a white residual. The residual of a real record is mostly model
    error and strongly autocorrelated, and then the stderrs understate the uncertainty; the
    result says so in ``warnings`` with the residual's lag-1 autocorrelation.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(20000) * 1e-3
    >>> w1, w2 = 2 * np.pi * 0.37, 2 * np.pi * 1.13
    >>> q = 0.05 * np.sin(w1 * t) + 0.02 * np.sin(w2 * t + 0.4)
    >>> v = 0.05 * w1 * np.cos(w1 * t) + 0.02 * w2 * np.cos(w2 * t + 0.4)
    >>> a = -0.05 * w1**2 * np.sin(w1 * t) - 0.02 * w2**2 * np.sin(w2 * t + 0.4)
    >>> force = 95.0 * a + 200.0 * v + 20.0 * np.sign(v) - 3.0
    >>> fit = idim_ls(t, q, force / 35.0, gain=35.0)
    >>> [round(e.value, 2) for e in (fit.M, fit.Fv, fit.Fc, fit.OF)]
    [95.0, 200.0, 20.0, -3.0]
    """
    t, q, u, dt, (start, end) = _check(t, q, u, gain, cutoff, order, decimation, trim, sigma)
    X, y = _regression(t, q, gain * u, dt, cutoff, order, decimation, start, end)
    fit = _solve(X[:, :4], y, sigma, _NAMES, _UNITS, fixed={})
    return replace(fit, recipe={"dt": dt, "cutoff": float(cutoff), "order": int(order),
                                "decimation": int(decimation)})


def _regression(t, q, force, dt, cutoff, order, decimation, start, end):
    """The decimated regressor [q̈, q̇, sign q̇, 1, q] and force of one record (steps 1–4)."""
    from scipy import signal

    b, a = signal.butter(order, cutoff / (0.5 / dt))
    qf = _filtfilt(b, a, q)
    if not np.all(np.isfinite(qf)):
        # a high-order Butterworth in (b, a) form is numerically unstable (its poles crowd at
        # z = 1 for a low cut-off): the filtered position blows up
        raise ValueError(f"order: the Butterworth filter of order {order} at {cutoff:g} Hz is "
                         "numerically unstable at this sampling rate (the filtered position "
                         "is not finite); use a lower order")
    qd = np.gradient(qf, dt)
    qdd = np.gradient(qd, dt)
    keep = slice(start, t.size - end)
    columns = np.column_stack([qdd[keep], qd[keep], np.sign(qd[keep]), np.ones(t.size)[keep],
                               qf[keep]])
    return _decimate(columns, decimation), _decimate(force[keep], decimation)


def _solve(x, y, sigma, names, units, fixed) -> IDIMFit:
    """Step 5: ordinary least squares and the fit's statistics."""
    n, p = x.shape
    if not np.any(y):
        raise ValueError("force: the force to fit is zero at every sample (a recorded command "
                         "u of zeros?): it cannot determine " + ", ".join(names))
    # the force in units of a power of two near its largest value: exact (every product and
    # quotient scales by the same power of two, so the digits do not change), and the squares
    # of a force of 1e-300 N (command_gain 1e-300) no longer underflow to a zero norm
    scale = math.ldexp(1.0, math.frexp(float(np.max(np.abs(y))))[1])
    theta, _, rank, sv = np.linalg.lstsq(x, y / scale, rcond=None)
    if rank < p:
        raise ValueError(f"q: the record does not excite all of {', '.join(names)} "
                         f"(regressor rank {rank} < {p})")
    # values near the float range (a force of 1e300 N) overflow the statistics to inf/nan,
    # which the results report as undefined (null in JSON), not as a numpy warning
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        residual = y / scale - x @ theta
        rss = float(residual @ residual)
        sigma2 = rss / (n - p) if sigma == "ols" else float(np.var(residual, ddof=1))
        unit_covariance = sigma2 * np.linalg.inv(x.T @ x)
        covariance = unit_covariance * scale * scale
        # from the scaled covariance (a tiny force's stderr does not underflow to 0), and not
        # finite where the covariance overflowed, so that the two agree
        stderr = np.where(np.isfinite(np.diag(covariance)),
                          np.sqrt(np.diag(unit_covariance)) * scale, np.inf)
        relative_error = 100.0 * math.sqrt(rss) / float(np.linalg.norm(y / scale))
        theta = theta * scale
        condition = float(sv[0] / sv[-1])
        rho1 = float(residual[1:] @ residual[:-1] / rss) if rss > 0 else 0.0
    warnings = (
        f"the stderrs are ordinary least squares ones, which assume a white residual; the "
        f"residual's lag-1 autocorrelation is {rho1:.3f}, and where it is far from 0 the "
        f"stderrs understate the real uncertainty",
    )
    est = {name: Estimate(float(v), float(s), unit)
           for name, v, s, unit in zip(names, theta, stderr, units, strict=True)}
    for name, value in fixed.items():
        est[name] = Estimate(float(value), 0.0, _ALL_UNITS[name])
    return IDIMFit(est["M"], est["Fv"], est["Fc"], est["OF"], covariance=covariance,
                   relative_error=relative_error, condition_number=condition,
                   lag1_autocorrelation=rho1, n_samples=n, warnings=warnings,
                   k=est.get("k"), free=tuple(names), regressor=x, target=y, rows=(n,))


def idim_ls_runs(records, *, fixed=None, cutoff: float = 100.0, order: int = 4,
                 decimation: int = 10, trim: int | tuple[int, int] = 50,
                 sigma: str = "ols") -> IDIMFit:
    """IDIM-LS over several records of one axis, with known parameters held fixed.

    The regressor of each record (the recipe of :func:`idim_ls`) is stacked; the model is
    ``force = M q̈ + Fv q̇ + Fc sign(q̇) + OF + k q``, and the columns of the parameters in
    ``fixed`` move to the left-hand side (force − value·column). The stiffness column k·q is
    fitted only when ``k`` is not fixed (a positioning axis has none: fix ``k = 0`` to get the
    benchmark's four-column regression).

    Parameters
    ----------
    records : sequence of (t, q, force)
        Sample times (s, uniform), position (m) and applied force (N) of each record.
    fixed : mapping, optional
        Known parameters by name: ``m``/``M`` (kg), ``c``/``Fv`` (N s/m), ``fc``/``Fc`` (N),
        ``offset``/``OF`` (N), ``k`` (N/m).
    cutoff, order, decimation, trim, sigma
        As in :func:`idim_ls`.

    Returns
    -------
    IDIMFit
        A fixed parameter has its value and stderr 0; ``k`` is None unless fitted or fixed.
    """
    fixed = {_ALIASES.get(k, k): float(v) for k, v in (fixed or {}).items()}
    for key in fixed:
        if key not in _ALL_UNITS:
            raise ValueError(f"fixed: unknown parameter {key!r}")
    fixed_cols = dict(fixed)
    Xs, ys, dts = [], [], []
    for t, q, force in records:
        t, q, force, dt, (start, end) = _check(t, q, force, 1.0, cutoff, order, decimation,
                                               trim, sigma)
        X, y = _regression(t, q, force, dt, cutoff, order, decimation, start, end)
        Xs.append(X)
        ys.append(y)
        dts.append(dt)
    X = np.vstack(Xs)
    y = np.concatenate(ys)
    cols = [*_NAMES, "k"]
    for name, value in fixed_cols.items():
        y = y - value * X[:, cols.index(name)]
    free = [name for name in cols if name not in fixed_cols]
    if not free:
        raise ValueError("fixed: every parameter is fixed; nothing to fit")
    X = X[:, [cols.index(name) for name in free]]
    fit = _solve(X, y, sigma, free, [_ALL_UNITS[name] for name in free], fixed_cols)
    return replace(fit, rows=tuple(len(q) for q in ys),
                   recipe={"dt": dts[0], "cutoff": float(cutoff), "order": int(order),
                           "decimation": int(decimation)})


def residual_filters(dt: float, *, cutoff: float, order: int, decimation: int, M: float,
                     Fv: float, k: float = 0.0, length: int = 8192
                     ) -> tuple[np.ndarray, np.ndarray]:
    """How white noise reaches the residual of the decimated regression, before the
    subsampling.

    IDIM's residual y − Xθ of the right model holds the position's noise n, carried by the
    columns q̈, q̇ (and q) of the filtered position — −(M q̈ + Fv q̇ + k q) of it, through the
    Butterworth filter, the central differences and the decimation filter — and any noise of
    the force itself, through the decimation filter alone. Both are linear and time-invariant
    away from the record's ends: their impulse responses h give the residual's autocovariance
    at decimated lag j, σ² Σᵢ h(i) h(i + j·decimation), for white noise of variance σ².

    Parameters
    ----------
    dt : float
        Sample interval, s.
    cutoff, order, decimation : float, int, int
        The recipe's filters (:func:`idim_ls`).
    M, Fv, k : float
        The estimates the residual is taken at (kg, N s/m, N/m).
    length : int
        Samples of the responses (the filters' responses die out well within 8192 samples for
        a decimation up to 100).

    Returns
    -------
    (h_q, h_F) : ndarray, ndarray
        The residual's response, in N, to a unit position sample (1 m) and to a unit force
        sample (1 N), at the full rate.
    """
    from scipy import signal

    imp = np.zeros(length)
    imp[length // 2] = 1.0
    b, a = signal.butter(order, cutoff / (0.5 / dt))
    qf = _filtfilt(b, a, imp)
    qd = np.gradient(qf, dt)
    qdd = np.gradient(qd, dt)
    h_q = M * qdd + Fv * qd + k * qf
    if decimation > 1:
        bd, ad = _decimate_filter(decimation)
        h_q = _filtfilt(bd, ad, h_q)
        h_F = _filtfilt(bd, ad, imp)
    else:
        h_F = imp
    return h_q, h_F
