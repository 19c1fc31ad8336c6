"""The identified plant and each run's closed loop as python-control and scipy.signal systems.

The plant (seed eq. 1 without friction) from the force F (N) to the position x (m),

    G(s) = 1 / (m s² + c s + k),      state space  d/dt (x, v) = A (x, v) + B F,  y = x,
    A = [[0, 1], [−k/m, −c/m]],  B = (0, 1/m),  C = (1, 0),  D = 0        (states x in m,
                                                                          v = ẋ in m/s).

A run's closed loop is the loop of eq. (23) with an external force F added at the plant:

    m x'' + c x' + k x = F(t) − [D ẋ(t − Δt) + P x(t − Δt)],
    T(s) = 1 / (m s² + c s + k + (D s + P) e^{−sΔt}),

whose poles are the loop's characteristic roots; with Δt = 0 those of
m s² + (c + D) s + (k + P) (eq. 31). The delay is replaced by the diagonal Padé approximant
e^{−sΔt} ≈ N_n(s)/D_n(s) (:func:`control.pade`), T_n(s) = D_n / ((m s² + c s + k) D_n +
(D s + P) N_n). For a sampled loop (:class:`phoid.dynamics.DigitalPD`) the closed loop is
discrete and exact: from a force sequence F_n held over [nT_s, (n+1)T_s) to x_n = x(nT_s),

    T(z) = z^d (z − a) N(z) / χ(z),

with N(z) the plant's zero-order-hold numerator and χ the loop's characteristic polynomial
(:mod:`phoid.dynamics.digital`).

python-control is optional (``pip install 'phoid[control]'``) and imported inside the functions
that need it; :func:`to_lti` needs only scipy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from phoid.interop.plant import LinearPlant, linear_plant

__all__ = ["ExportInfo", "closed_loop", "pade_order_for", "require_control", "to_control",
           "to_lti"]

FORMS = ("tf", "ss")
#: the default Padé order is the lowest that puts the approximate loop's dominant pole within
#: this relative distance of the certified dominant root (far below any estimate's stderr)
PADE_RTOL = 1e-6
#: the highest Padé order tried (python-control's coefficients lose accuracy beyond ~10)
PADE_MAX_ORDER = 10


def require_control() -> Any:
    """The ``control`` module, or an ImportError of one line saying how to install it."""
    try:
        import control
    except ImportError:
        raise ImportError(
            "python-control is not installed: pip install 'phoid[control]'") from None
    return control


@dataclass(frozen=True)
class ExportInfo:
    """What an exported system is, carried as its ``phoid`` attribute.

    Attributes
    ----------
    kind : str
        ``"plant"`` or ``"closed loop"``.
    plant : LinearPlant
        The identified plant with the covariance of (m, c, k) (``plant.cov``) and its
        Monte Carlo draws (``plant.draw``).
    input, output : str
        The signals and their units.
    states : tuple of str
        The state-space form's states (empty for a transfer function).
    run : str
        The run of a closed loop ("" for the plant).
    P, D : float
        The run's gains, N/m and N s/m (nan for the plant).
    delay : float
        The loop delay Δt, s (0 for the plant; d·T_s for a sampled loop).
    added_mass : float
        The run's known added mass, kg (the loop's mass is m + added_mass).
    sample_time : float or None
        T_s of a sampled loop's discrete-time system (None: continuous time).
    pade_order : int or None
        The Padé order that replaced the delay (None: no delay, or a sampled loop).
    pade_error : float
        |N_n(s*)/D_n(s*) · e^{s*Δt} − 1|: the approximant's relative error at the loop's
        certified dominant root s* (0 when exact).
    dominant_root : complex or None
        The exact loop's dominant (rightmost) root s*, 1/s (certified for the delayed loop,
        :func:`phoid.dynamics.characteristic_roots`; ln(z*)/T_s for a sampled loop).
    dominant_pole : complex or None
        The exported system's pole nearest to s*, 1/s.
    notes : tuple of str
        The approximations and what was left out.
    """

    kind: str
    plant: LinearPlant
    input: str
    output: str
    states: tuple[str, ...] = ()
    run: str = ""
    P: float = math.nan
    D: float = math.nan
    delay: float = 0.0
    added_mass: float = 0.0
    sample_time: float | None = None
    pade_order: int | None = None
    pade_error: float = 0.0
    dominant_root: complex | None = None
    dominant_pole: complex | None = None
    notes: tuple[str, ...] = ()

    @property
    def cov(self) -> np.ndarray:
        """The (3, 3) covariance of (m, c, k) (``plant.cov``)."""
        return self.plant.cov

    @property
    def pole_error(self) -> float:
        """|dominant_pole − dominant_root| / |dominant_root| (0 when exact; nan if unknown)."""
        if self.dominant_root is None or self.dominant_pole is None:
            return math.nan
        return abs(self.dominant_pole - self.dominant_root) / max(abs(self.dominant_root),
                                                                   1e-300)


def _check_form(form: str) -> str:
    if form not in FORMS:
        raise ValueError(f"`form` must be one of {FORMS}; got {form!r}")
    return form


def _as_plant(obj: Any, per_unit_mass: bool) -> LinearPlant:
    return obj if isinstance(obj, LinearPlant) else linear_plant(obj,
                                                                 per_unit_mass=per_unit_mass)


def _signals(plant: LinearPlant) -> tuple[str, str]:
    if plant.per_unit_mass:
        return "F/m (N/kg)", "x (m)"
    return "F (N)", "x (m)"


def state_matrices(m: float, c: float, k: float) -> tuple[np.ndarray, ...]:
    """A, B, C, D of the plant with states (x, v): x in m, v = ẋ in m/s, input F in N."""
    A = np.array([[0.0, 1.0], [-k / m, -c / m]])
    B = np.array([[0.0], [1.0 / m]])
    C = np.array([[1.0, 0.0]])
    return A, B, C, np.zeros((1, 1))


def to_control(result: Any, *, form: str = "tf", per_unit_mass: bool = False) -> Any:
    """The identified plant G(s) = 1/(m s² + c s + k) as a python-control system.

    Parameters
    ----------
    result : object
        A result (:func:`phoid.interop.plant.linear_plant` lists the kinds) or a
        :class:`LinearPlant`.
    form : {"tf", "ss"}
        A :class:`control.TransferFunction`, or a :class:`control.StateSpace` with states
        ``x`` (m) and ``v`` (m/s), input ``F`` (N) and output ``x`` (m).
    per_unit_mass : bool, default False
        A free decay without a known mass: 1/(s² + (c/m)s + k/m), input F/m.

    Returns
    -------
    control.TransferFunction or control.StateSpace
        With the attribute ``phoid`` (:class:`ExportInfo`: the covariance of (m, c, k) as
        ``.phoid.cov``, the notes); arithmetic on the system returns plain python-control
        objects without it.

    Raises
    ------
    ImportError
        When python-control is not installed.

    Examples
    --------
    >>> import numpy as np
    >>> from phoid.interop.plant import LinearPlant
    >>> G = to_control(LinearPlant(2.0, 1.0, 64.0, cov=np.diag([1e-4, 1e-4, 1e-2])))
    >>> float(G.dcgain()), float(G.phoid.cov[2, 2])
    (0.015625, 0.01)
    """
    control = require_control()
    _check_form(form)
    plant = _as_plant(result, per_unit_mass)
    inp, out = _signals(plant)
    if form == "tf":
        sys = control.tf([1.0], [plant.m, plant.c, plant.k], inputs=["F"], outputs=["x"])
        states: tuple[str, ...] = ()
    else:
        sys = control.ss(*state_matrices(plant.m, plant.c, plant.k), inputs=["F"],
                         outputs=["x"], states=["x", "v"])
        states = ("x (m)", "v (m/s)")
    sys.phoid = ExportInfo("plant", plant, inp, out, states=states, notes=plant.notes)
    return sys


def to_lti(result: Any, *, form: str = "tf", per_unit_mass: bool = False) -> Any:
    """The identified plant as a :class:`scipy.signal.lti` (no python-control needed).

    ``form="tf"`` gives ``lti([1], [m, c, k])``, ``"ss"`` the state space of
    :func:`to_control` (states x, v). The system carries ``phoid`` (:class:`ExportInfo`).

    Examples
    --------
    >>> import numpy as np
    >>> from phoid.interop.plant import LinearPlant
    >>> L = to_lti(LinearPlant(2.0, 1.0, 64.0, cov=np.zeros((3, 3))))
    >>> L.den.tolist(), L.phoid.input
    ([1.0, 0.5, 32.0], 'F (N)')
    """
    from scipy.signal import lti

    _check_form(form)
    plant = _as_plant(result, per_unit_mass)
    inp, out = _signals(plant)
    if form == "tf":
        sys = lti([1.0], [plant.m, plant.c, plant.k])
        states: tuple[str, ...] = ()
    else:
        sys = lti(*state_matrices(plant.m, plant.c, plant.k))
        states = ("x (m)", "v (m/s)")
    sys.phoid = ExportInfo("plant", plant, inp, out, states=states, notes=plant.notes)
    return sys


# --------------------------------------------------------------------------------------------
# closed loops


def _pick_run(result: Any, run: int | str) -> Any:
    runs = tuple(getattr(result, "runs", ()))
    if not runs or not all(hasattr(r, "P") and hasattr(r, "D") for r in runs):
        raise ValueError(f"{type(result).__name__} has no feedback runs (gains P, D): only "
                         "a PHO or friction result has closed loops")
    if isinstance(run, (int, np.integer)) and not isinstance(run, bool):
        if not -len(runs) <= run < len(runs):
            raise ValueError(f"`run` {run} is out of range: the result has {len(runs)} runs")
        return runs[run]
    names = [getattr(r, "file", getattr(r, "name", "")) for r in runs]
    if run in names:
        return runs[names.index(run)]
    raise ValueError(f"`run` {run!r} is neither an index nor a run of the result "
                     f"({', '.join(map(repr, names[:5]))}{', …' if len(names) > 5 else ''})")


def _pade(delay: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    num, den = require_control().pade(delay, n)
    return np.asarray(num, dtype=float), np.asarray(den, dtype=float)


def _delayed_loop(m, c, k, P, D, delay, n):
    """Numerator and denominator of T_n(s) (module docstring), highest power first."""
    num_p, den_p = _pade(delay, n)
    den = np.polyadd(np.polymul([m, c, k], den_p), np.polymul([D, P], num_p))
    return den_p, den


def _nearest(poles: np.ndarray, s: complex) -> complex:
    return complex(poles[np.argmin(np.abs(poles - s))])


def pade_order_for(m: float, c: float, k: float, P: float, D: float, delay: float, *,
                   rtol: float = PADE_RTOL) -> tuple[int, complex]:
    """The lowest Padé order whose loop has its dominant pole within ``rtol`` of the true one.

    Parameters
    ----------
    m, c, k : float
        The loop's plant (kg, N s/m, N/m).
    P, D : float
        Gains (N/m, N s/m).
    delay : float
        Δt, s (> 0).
    rtol : float
        Relative distance |p_n − s*|/|s*| accepted.

    Returns
    -------
    order : int
        In 1 … :data:`PADE_MAX_ORDER` (the highest when none reaches ``rtol``).
    root : complex
        The certified dominant root s*, 1/s (:func:`phoid.dynamics.characteristic_roots`).
    """
    from phoid.dynamics import rightmost_roots

    root = complex(rightmost_roots(m, c, k, P, D, delay, count=2)[0])
    for n in range(1, PADE_MAX_ORDER + 1):
        _, den = _delayed_loop(m, c, k, P, D, delay, n)
        if abs(_nearest(np.roots(den), root) - root) <= rtol * abs(root):
            return n, root
    return PADE_MAX_ORDER, root


def _digital_loop(control, plant: LinearPlant, mass: float, P: float, D: float, g: Any):
    from phoid.dynamics import characteristic_coefficients, digital_roots, zoh_plant

    zp = zoh_plant(mass, plant.c, plant.k, g.sample_time)
    a, d = g.filter_pole, g.delay_samples
    den = characteristic_coefficients(zp, np.array([P]), np.array([D]), a, g.filter_gain, d)[0]
    # z^d (z − a) N(z), N(z) = b₁ z + b₀
    num = np.polymul(np.polymul(np.r_[1.0, np.zeros(d)], [1.0, -a]), [zp.b1, zp.b0])
    sys = control.tf(num, den, g.sample_time, inputs=["F"], outputs=["x"])
    roots = digital_roots(mass, plant.c, plant.k, P, D, g)
    root = complex(roots.dominant[0])
    poles = np.log(np.asarray(sys.poles(), dtype=complex)) / g.sample_time
    return sys, root, _nearest(poles, root)


def closed_loop(result: Any, run: int | str, *, pade_order: int | None = None,
                form: str = "tf", rtol: float = PADE_RTOL) -> Any:
    """The closed loop of one run, from an external force F (N) to the position x (m).

    Parameters
    ----------
    result : object
        A result with feedback runs (``runs`` with ``P``, ``D``, optionally ``added_mass``),
        a ``delay`` (s) and optionally ``digital`` (a :class:`phoid.dynamics.DigitalPD`):
        a PHO identification or a friction fit (its linear part).
    run : int or str
        The run: its index in ``result.runs`` or its file (name).
    pade_order : int, optional
        The Padé order replacing a continuous delay; by default the lowest that puts the
        approximate loop's dominant pole within ``rtol`` of the certified dominant root
        (:func:`pade_order_for`). Checked always, used only for a continuous delay (a loop
        without delay and a sampled loop are exact).
    form : {"tf", "ss"}
        Transfer function, or its state-space realisation (states unnamed).
    rtol : float
        The default order's tolerance (:data:`PADE_RTOL`).

    Returns
    -------
    control.TransferFunction or control.StateSpace
        Continuous (T(s); T_n(s) with a delay) or, for a sampled loop, discrete with
        ``dt`` = T_s (T(z)); ``phoid`` (:class:`ExportInfo`) holds the run, the Padé order,
        its error at the dominant root and the distance of the exported dominant pole from
        the exact one.

    Raises
    ------
    ValueError
        For a result without feedback runs, an unknown run, a per-unit-mass plant or a bad
        ``pade_order``.
    ImportError
        When python-control is not installed.
    """
    control = require_control()
    _check_form(form)
    if not (isinstance(rtol, (int, float)) and 0 < rtol < 1):
        raise ValueError(f"`rtol` must be a number in (0, 1); got {rtol!r}")
    if pade_order is not None and (
            isinstance(pade_order, bool) or not isinstance(pade_order, (int, np.integer))
            or not 1 <= pade_order <= PADE_MAX_ORDER):
        raise ValueError(f"`pade_order` must be a whole number in 1 … {PADE_MAX_ORDER}; got "
                         f"{pade_order!r}")
    r = _pick_run(result, run)
    plant = linear_plant(result)
    P, D = float(r.P), float(r.D)
    added = float(getattr(r, "added_mass", 0.0) or 0.0)
    mass = plant.m + added
    name = str(getattr(r, "file", getattr(r, "name", "")))
    digital = getattr(result, "digital", None)
    delay = float(getattr(result, "delay", 0.0) or 0.0)
    notes = list(plant.notes)
    if getattr(result, "delay_stderr", None) is not None and digital is None:
        notes.append(f"the delay is the estimated {delay:.6g} ± {result.delay_stderr:.2g} s; "
                     "its uncertainty is not in the covariance of (m, c, k)")
    if added:
        notes.append(f"the run's added mass {added:.6g} kg is part of the loop's mass")
    order: int | None = None
    pade_error = 0.0
    sample_time = None
    if digital is not None:
        sys, root, pole = _digital_loop(control, plant, mass, P, D, digital)
        sample_time = float(digital.sample_time)
        delay = float(digital.delay)
        notes.append("sampled loop: exact discrete-time closed loop, input F held over each "
                     "sample (zero-order hold), output x at the controller's instants")
    elif delay == 0.0:
        sys = control.tf([1.0], [mass, plant.c + D, plant.k + P], inputs=["F"], outputs=["x"])
        root = complex(sys.poles()[np.argmax(np.asarray(sys.poles()).real)])
        pole = root
    else:
        if pade_order is None:
            order, root = pade_order_for(mass, plant.c, plant.k, P, D, delay, rtol=rtol)
        else:
            from phoid.dynamics import rightmost_roots

            order = int(pade_order)
            root = complex(rightmost_roots(mass, plant.c, plant.k, P, D, delay, count=2)[0])
        num, den = _delayed_loop(mass, plant.c, plant.k, P, D, delay, order)
        sys = control.tf(num, den, inputs=["F"], outputs=["x"])
        pole = _nearest(np.roots(den), root)
        num_p, den_p = _pade(delay, order)
        pade_error = float(abs(np.polyval(num_p, root) / np.polyval(den_p, root)
                               * np.exp(root * delay) - 1.0))
        notes.append(f"the delay {delay:.6g} s is a Padé approximant of order {order}: relative "
                     f"error {pade_error:.2g} at the dominant root, which the loop's pole "
                     f"matches to {abs(pole - root) / abs(root):.2g}")
    if getattr(r, "used", True) is False:
        notes.append(f"run {name} was set aside by the identification (its warnings say why)")
    if root.real > 0:
        notes.append(f"the loop is unstable: its dominant root {root:.4g} 1/s has a positive "
                     "real part")
    if form == "ss":
        sys = control.ss(sys, inputs=["F"], outputs=["x"])
    sys.phoid = ExportInfo(
        "closed loop", plant, "F (N)", "x (m)", run=name, P=P, D=D, delay=delay,
        added_mass=added, sample_time=sample_time, pade_order=order, pade_error=pade_error,
        dominant_root=root, dominant_pole=pole, notes=tuple(notes))
    return sys
