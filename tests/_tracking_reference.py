r"""An independent reference simulator of the sampled PD tracking loop (tests only).

It implements the contract of issue 17 (the loop of
:class:`phoid.dynamics.controller.SampledController`) a different way from the package:

    m ẍ + c ẋ + k x + f_c·sign(ẋ) + f0 = F(t),
    v̂_n from x_n, x_{n−1}, … ; u_n = K·(P·(r_n − x_n) − D·v̂_n);  F_n = G·(sat(u_n) + w_n),

F_n applied from t_n + τ on (zero-order hold), τ = dT + φ, 0 ≤ φ < T: on [t_n, t_n + φ) the
plant sees F_{n−d−1}, on [t_n + φ, t_{n+1}) F_{n−d}. Ideal Coulomb friction (static = kinetic
= f_c): at ẋ = 0 the mass sticks while |F − f0 − kx| ≤ f_c, otherwise it slips towards
sign(F − f0 − kx).

How it differs from the package
-------------------------------
* No matrix exponential. Within a piece of constant force and a slip direction s the motion
  obeys m ẍ + c ẋ + k x = F_e, F_e = F − f0 − s·f_c, whose solution is entire; it is summed as
  its Taylor series around the piece's start, x(t) = Σ a_j t^j with a_0 = x, a_1 = ẋ,
  a_{j+2} = (F_e δ_{j0} − c (j+1) a_{j+1} − k a_j) / (m (j+1)(j+2)), until two successive terms
  fall below the working precision.
* Arbitrary precision: every number is an mpmath ``mpf`` at ``precision`` decimal digits
  (default 40); the plain-float variant (``precision=None``) runs the same algorithm on Python
  floats, for long records.
* Reversals located by a safeguarded Newton iteration on v(t) = 0 (the derivative is the
  acceleration (F_e − c v − k x)/m), to the working precision. No reversal is missed: in a
  constant-force slip piece v solves the homogeneous equation m v'' + c v' + k v = 0, so it
  has at most one zero for real characteristic roots, and zeros π/ω_d apart for complex ones;
  the reference steps at most π/(2ω_d) at a time, so a zero lies inside a step exactly when
  the sign of s·v at the step's end is not positive.
* The controller: the presets written out as their definitions ((x_n − x_{n−1})/T,
  (x_n − x_{n−2})/(2T), the first-order recursion of the "filtered" one), FIR coefficient lists
  summed directly; the force queue is a dict indexed by n.

Initial state (the contract): x_init = (x_{−L+1}, …, x_0), older taps repeat the oldest; the
plant starts at (x_0, v0) at t_0; u_init = (u_{−J}, …, u_{−1}) oldest first, missing older ones
repeat the oldest given, default u_0 repeated; the forces before t_0 are G·sat(u_{−j}) (no w
before t_0). The "filtered" estimate's own history v̂_{−1} is the backward difference of the x
history, (x_{−1} − x_{−2})/T (its DC-consistent FIR value).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import mpmath
import numpy as np


@dataclass(frozen=True)
class Reference:
    """The reference record, plain float64 arrays of N samples (one per controller instant)."""

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    command: np.ndarray
    force: np.ndarray
    saturated: np.ndarray
    reversals: int  # velocity reversals (zeros of ẋ inside a slip piece) met
    stuck_pieces: int  # constant-force pieces spent (partly) stuck
    plant: tuple  # (m, c, k, f_c, f0) simulated


class _Float:
    """Plain-float arithmetic."""

    def __init__(self):
        self.eps = 2.0**-52

    def num(self, value):
        return float(value)

    def exp(self, value):
        return math.exp(value)

    def sqrt(self, value):
        return math.sqrt(value)

    pi = math.pi


class _Mp:
    """mpmath arithmetic at a fixed number of decimal digits (set by the caller's workdps)."""

    def __init__(self, digits):
        self.eps = mpmath.mpf(10) ** (-digits)

    def num(self, value):
        return mpmath.mpf(value)

    def exp(self, value):
        return mpmath.exp(value)

    def sqrt(self, value):
        return mpmath.sqrt(value)

    @property
    def pi(self):
        return +mpmath.pi


class _Plant:
    """Exact motion of m ẍ + c ẋ + k x + f_c sign(ẋ) + f0 = F under piecewise-constant F."""

    def __init__(self, ar, m, c, k, fc, f0):
        self.ar = ar
        self.m, self.c, self.k, self.fc, self.f0 = (ar.num(p) for p in (m, c, k, fc, f0))
        disc = 4 * self.m * self.k - self.c**2
        # longest step with at most one zero of v inside (see the module docstring)
        self.hmax = ar.pi / (2 * (ar.sqrt(disc) / (2 * self.m))) if disc > 0 else None
        self.reversals = 0
        self.stuck_pieces = 0

    def taylor(self, x, v, fe, t):
        """(x(t), v(t)) from (x, v) at 0 under m ẍ + c ẋ + k x = fe."""
        m, c, k, eps = self.m, self.c, self.k, self.ar.eps
        a_prev, a_cur = x, v  # a_j, a_{j+1}
        X = x + v * t
        V = v
        tp = t  # t^{j+1}
        small = 0
        for j in range(400):
            a_next = ((fe if j == 0 else 0) - c * (j + 1) * a_cur - k * a_prev) / (
                m * (j + 1) * (j + 2))
            term_v = (j + 2) * a_next * tp
            tp = tp * t
            term_x = a_next * tp
            X += term_x
            V += term_v
            a_prev, a_cur = a_cur, a_next
            scale = abs(X) + abs(V) * t
            if abs(term_x) <= eps * scale and abs(term_v) * t <= eps * scale:
                small += 1
                if small >= 2:
                    return X, V
            else:
                small = 0
        raise RuntimeError("Taylor series did not converge")

    def reversal(self, x, v, fe, h, s):
        """The zero t* ∈ (0, h] of v, given s·v(0) ≥ 0 > or = s·v(h)."""
        lo, hi = 0 * h, h
        t = h
        tol = 8 * self.ar.eps * h
        for _ in range(500):
            xt, vt = self.taylor(x, v, fe, t)
            if vt == 0:
                return t
            if s * vt > 0:
                lo = t
            else:
                hi = t
            acc = (fe - self.c * vt - self.k * xt) / self.m
            tn = t - vt / acc if acc != 0 else (lo + hi) / 2
            if not lo < tn < hi:
                tn = (lo + hi) / 2
            if abs(tn - t) <= tol or hi - lo <= tol:
                return tn
            t = tn
        raise RuntimeError("reversal not located")

    def advance(self, x, v, force, h):
        """State after h under the constant force, with stick–slip."""
        fc, k, f0 = self.fc, self.k, self.f0
        for _ in range(10_000):
            if h <= 0:
                return x, v
            if v == 0:
                net = force - f0 - k * x
                if abs(net) <= fc:  # stuck until the force changes (x, hence net, constant)
                    self.stuck_pieces += 1
                    return x, v
                s = 1 if net > 0 else -1
            else:
                s = 1 if v > 0 else -1
            fe = force - f0 - s * fc
            step = h if self.hmax is None or h <= self.hmax else self.hmax
            x1, v1 = self.taylor(x, v, fe, step)
            if s * v1 > 0:
                x, v, h = x1, v1, h - step
                continue
            ts = self.reversal(x, v, fe, step, s)
            x, _ = self.taylor(x, v, fe, ts)
            v = 0 * v
            h = h - ts
            self.reversals += 1
        raise RuntimeError("too many events in one piece")


def reference_tracking(m, c, k, fc, *, T, P, D, r, K=1.0, G=1.0, velocity="backward-difference",
                       cutoff=None, delay=0.0, saturation=None, offset=0.0, w=None, x_init=None,
                       v0=0.0, u_init=None, t0=0.0, precision=40) -> Reference:
    """Simulate the sampled tracking loop of the contract; see the module docstring.

    ``velocity`` is "backward-difference", "central-difference", "filtered" (with ``cutoff``,
    rad/s) or a sequence of FIR coefficients b_j (1/s). ``precision``: decimal digits of the
    mpmath arithmetic, or None for plain floats. Returns float64 arrays of len(r) samples.
    """
    with mpmath.workdps(precision or 15):
        ar = _Mp(precision) if precision else _Float()
        return _run(ar, m, c, k, fc, T, P, D, r, K, G, velocity, cutoff, delay, saturation,
                    offset, w, x_init, v0, u_init, t0)


def _run(ar, m, c, k, fc, T, P, D, r, K, G, velocity, cutoff, delay, saturation, offset, w,
         x_init, v0, u_init, t0):
    num = ar.num
    N = len(r)
    r = [num(float(val)) for val in r]
    w = [num(0)] * N if w is None else [num(float(val)) for val in w]
    plant = _Plant(ar, m, c, k, fc, offset)
    Tn, P, D, K, G = num(T), num(P), num(D), num(K), num(G)
    sat = None if saturation is None else num(saturation)
    d = math.floor(Fraction(delay) / Fraction(T))  # whole samples, exactly
    phi = num(delay) - d * Tn  # 0 ≤ φ < T
    hist = [num(float(val)) for val in (x_init if x_init is not None else [r[0]])]

    xs = {}  # x_n, n may be negative (the given history)
    for i, val in enumerate(hist):
        xs[i - len(hist) + 1] = val

    def xn(n):
        return xs[max(n, 1 - len(hist))]

    if isinstance(velocity, str):
        if velocity == "backward-difference":
            def vhat(n, prev):
                return (xn(n) - xn(n - 1)) / Tn
        elif velocity == "central-difference":
            def vhat(n, prev):
                return (xn(n) - xn(n - 2)) / (2 * Tn)
        elif velocity == "filtered":
            a = ar.exp(-num(cutoff) * Tn)

            def vhat(n, prev):
                if prev is None:  # the estimate's history: the FIR value at n − 1
                    prev = (xn(n - 1) - xn(n - 2)) / Tn
                return a * prev + (1 - a) * (xn(n) - xn(n - 1)) / Tn
        else:
            raise ValueError(velocity)
    else:
        b = [num(float(bj)) for bj in velocity]

        def vhat(n, prev):
            return sum((bj * xn(n - j) for j, bj in enumerate(b)), num(0))

    def clip(u):
        if sat is None:
            return u, False
        if u > sat:
            return sat, True
        if u < -sat:
            return -sat, True
        return u, False

    x, v = hist[-1], num(v0)
    forces = {}
    out = {key: [] for key in ("x", "v", "u", "F", "sat")}
    prev = None
    for n in range(N):
        xs[n] = x
        est = vhat(n, prev)
        prev = est
        u = K * (P * (r[n] - x) - D * est)
        us, flag = clip(u)
        forces[n] = G * (us + w[n])
        if n == 0:
            need = d + 1
            given = [num(float(val)) for val in u_init] if u_init is not None else [u]
            given = [given[0]] * max(0, need - len(given)) + given
            for j in range(1, need + 1):
                forces[-j] = G * clip(given[-j])[0]
        for key, val in (("x", x), ("v", v), ("u", u), ("F", forces[n]), ("sat", flag)):
            out[key].append(val)
        if n == N - 1:
            break
        if phi > 0:
            x, v = plant.advance(x, v, forces[n - d - 1], phi)
        x, v = plant.advance(x, v, forces[n - d], Tn - phi)
    t = [float(num(t0) + n * Tn) for n in range(N)]
    arr = {key: np.array([float(val) for val in vals]) for key, vals in out.items()}
    return Reference(t=np.array(t), x=arr["x"], v=arr["v"], command=arr["u"], force=arr["F"],
                     saturated=np.array(out["sat"], dtype=bool), reversals=plant.reversals,
                     stuck_pieces=plant.stuck_pieces, plant=(m, c, k, fc, offset))


def coulomb_oscillator(t: float, x0: float, omega: float, band: float) -> float:
    """Closed form of m ẍ + k x + f_c sign(ẋ) = 0 released at rest from x0 > band = f_c/k (m):
    half-cycle i is harmonic about (−1)^i·band (the friction opposes the motion), the amplitude
    shrinking by 2·band a half-cycle; the mass sticks at the first turning point inside
    |x| ≤ band. omega = √(k/m), rad/s."""
    half = math.pi / omega
    x_turn, i = x0, 0
    while abs(x_turn) > band:
        centre = band if x_turn > 0 else -band
        if t <= (i + 1) * half:
            return centre + (x_turn - centre) * math.cos(omega * (t - i * half))
        x_turn = 2 * centre - x_turn
        i += 1
    return x_turn
