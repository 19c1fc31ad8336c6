r"""The sampled PD loop tracking a reference, simulated exactly (stick–slip included).

The loop is :class:`~phoid.dynamics.controller.SampledController`'s: at each controller instant
t_n = t₀ + nT the controller reads x_n, estimates the velocity, issues
F_n = G·(sat(K·(P·(r_n − x_n) − D·v̂_n)) + w_n) (or, with the additive input w in the command,
F_n = G·sat(K·(P·(r_n − x_n) − D·v̂_n) + w_n)), and the plant

    m ẍ + c ẋ + k x + f_c sign(ẋ) + f₀ = F(t)            (seed eq. 1, Coulomb friction, offset)

sees F_{n−d−1} on [t_n, t_n + φ) and F_{n−d} on [t_n + φ, t_{n+1}) (command delay τ = dT + φ).

Exactness. The force is piecewise constant, so between events each piece is propagated by its
zero-order-hold map y ← Φ(h) y + Γ(h)(F − f₀ − f_c s)
(:func:`~phoid.dynamics.controller.zoh_pieces`,
s = sign of the motion). Friction is ideal Coulomb with static = kinetic = f_c. When the velocity
reaches zero inside a piece at t*, the mass sticks for the rest of the piece if
|F − f₀ − k x(t*)| ≤ f_c, and otherwise moves on in the direction of that force; a stuck mass
breaks away at the start of the first piece whose force exceeds f_c. Zero crossings are located
in closed form for k = 0 (v(t) is then one exponential, monotone within a piece:
t* = −ln(v_∞/(v_∞ − v₀))/λ with λ = c/m, v_∞ = F_net/c) and by bracketing root finding on the
exact flow otherwise (the velocity's extremum inside a piece, where the acceleration changes
sign, is checked so that a double crossing is not missed; this needs the piece shorter than half
a damped period of the plant, T·ω_d < π). With f_c = 0 no event exists and each piece is one
map. The recorded x_n, v_n are the plant's state at the instants, to rounding (≈ N·ε relative).

Cost. Each controller period depends on the one before through the friction's state and the
saturation, so the loop over periods is sequential: scalar Python arithmetic on precomputed
maps, ≈ 1.2–1.6 µs per period (30–40 ms for a 25 000-sample record); events cost a root solve
each.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phoid import _validate as v
from phoid._progress import task
from phoid.dynamics.controller import SampledController, zoh_pieces
from phoid.simulation._checks import plant_params

__all__ = ["ExactPlant", "TrackingSimulation", "simulate_tracking"]


@dataclass(frozen=True, eq=False)
class TrackingSimulation:
    """A simulated tracking record (one sample per controller instant).

    Attributes
    ----------
    t : numpy.ndarray, shape (N,)
        Controller instants t₀ + nT, s.
    x : numpy.ndarray, shape (N,)
        Plant position at the instants, m.
    v : numpy.ndarray, shape (N,)
        Plant velocity at the instants, m/s.
    command : numpy.ndarray, shape (N,)
        Controller output u_n before saturation, command units (w_n included when
        ``w_in_command``).
    force : numpy.ndarray, shape (N,)
        F_n = G·(sat(u_n) + w_n), or G·sat(u_n) when ``w_in_command``, N (applied τ later).
    saturated : numpy.ndarray of bool, shape (N,)
        Where |u_n| exceeded the saturation.
    r : numpy.ndarray, shape (N,)
        The reference, m.
    stuck : int
        Number of controller periods in which the mass was stuck at some point.
    reversals : int
        Number of velocity reversals (zero crossings that did not stick).
    controller : SampledController
    plant : tuple of float
        (m, c, k, f_c, f₀) simulated: kg, N·s/m, N/m, N, N.
    w_in_command : bool
        Whether w was added into the command, before the saturation.
    """

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    command: np.ndarray
    force: np.ndarray
    saturated: np.ndarray
    r: np.ndarray
    stuck: int
    reversals: int
    controller: SampledController
    plant: tuple[float, float, float, float, float]
    w_in_command: bool = False


def simulate_tracking(
    plant,
    controller: SampledController,
    r,
    *,
    offset: float = 0.0,
    w=None,
    x_init=None,
    v0: float = 0.0,
    u_init=None,
    w_init=None,
    w_in_command: bool = False,
    t0: float = 0.0,
) -> TrackingSimulation:
    """Simulate the sampled PD loop driven by a reference (module docstring: model, exactness).

    Parameters
    ----------
    plant : phoid.Plant
        Mass ``m`` (kg), damping ``c`` (N·s/m), stiffness ``k`` (N/m), Coulomb friction ``fc``
        (N, static = kinetic).
    controller : SampledController
        The loop: period, gains, estimator, delay, saturation, command gain.
    r : array_like, shape (N,)
        Reference position at the N controller instants, m (N ≥ 1).
    offset : float, default 0
        Constant offset force f₀, N, on the resisting side (m ẍ + … + f₀ = F).
    w : array_like, shape (N,), optional
        Additive command input w_n (command units), added after the saturation and held and
        delayed with the command.
    x_init : array_like, optional
        Positions at and before the start, oldest first (x_{−L+1}, …, x₀), m; x₀ = x_init[-1] is
        the plant's position at t₀. Missing older taps repeat the oldest value. Default [r[0]].
    v0 : float, default 0
        Plant velocity at t₀, m/s.
    u_init : array_like, optional
        Commands u_{−J}, …, u_{−1} (before saturation) issued before t₀, oldest first, which the
        delay still applies after t₀; earlier ones repeat the oldest. Default: u₀ repeated (the
        controller had been issuing its first command).
    w_init : array_like, optional
        The additive inputs issued with ``u_init`` (command units, oldest first, aligned with
        its last values; earlier ones repeat the oldest). Default 0: the commands before t₀
        carried no additive input.
    w_in_command : bool, default False
        Where w enters: after the saturation (False: F_n = G·(sat(u_n) + w_n)), or into the
        command itself, clipped with it (True: u_n = K·(…) + w_n, F_n = G·sat(u_n); a
        controller that adds the input to its output, whose recorded u then holds w).
    t0 : float, default 0
        Time of the first instant, s.

    Returns
    -------
    TrackingSimulation

    Raises
    ------
    ValueError
        Naming the argument, for non-finite or mis-shaped inputs.
    """
    m, c, k, fc = plant_params(plant)
    ctrl = controller
    if not isinstance(ctrl, SampledController):
        raise ValueError(f"`controller` must be a SampledController; got {type(ctrl).__name__}")
    r = _vector("r", r)
    N = r.size
    w = np.zeros(N) if w is None else _vector("w", w, N)
    xh = np.array([r[0]]) if x_init is None else _vector("x_init", x_init)
    v0 = v.finite("v0", v0, "m/s")
    f0 = v.finite("offset", offset, "N")
    t0 = v.finite("t0", t0, "s")
    T = ctrl.sample_time
    d, phi = ctrl.delay_split
    b, a = ctrl.velocity_filter()
    nb, na = b.size, a.size
    G, K, P, D = ctrl.command_gain, ctrl.gain, ctrl.P, ctrl.D
    umax = math.inf if ctrl.saturation is None else ctrl.saturation

    # history: the x taps before x₀ (the oldest repeated) and the estimator's own past outputs
    pad = nb + na
    xhist = np.concatenate((np.full(pad, xh[0]), xh))
    xs = [float(q) for q in xhist[-nb:-1]]  # x_{−nb+1}, …, x_{−1}
    vhat_hist = _filter_history(b, a, xhist[:-1], na - 1)  # v̂_{−na+1}, …, v̂_{−1}

    def first_command() -> float:
        acc = b[0] * xhist[-1] + sum(b[j] * xhist[-1 - j] for j in range(1, nb))
        acc -= sum(a[i] * vhat_hist[-i] for i in range(1, na))
        return K * (P * (r[0] - xhist[-1]) - D * acc / a[0])

    if d >= N + (0 if u_init is None else np.size(u_init)):
        raise ValueError(
            f"the command delay τ = {ctrl.delay:g} s is {d} periods, longer than the record and "
            f"its command history ({N} instants of {T:g} s): no command would reach the plant"
        )
    if u_init is None:
        uh = np.full(d + 1, first_command())
    else:
        uh = _vector("u_init", u_init)
        if uh.size < d + 1:
            uh = np.concatenate((np.full(d + 1 - uh.size, uh[0]), uh))
    wh = np.zeros(uh.size)
    if w_init is not None:
        wi = _vector("w_init", w_init)
        if wi.size:
            k = min(wi.size, wh.size)
            wh[wh.size - k:] = wi[wi.size - k:]
            wh[: wh.size - k] = wi[0]
    if w_in_command:
        Fpast = [G * min(max(float(q) + float(p), -umax), umax)
                 for q, p in zip(uh[-(d + 1):], wh[-(d + 1):], strict=True)]
    else:
        Fpast = [G * (min(max(float(q), -umax), umax) + float(p))
                 for q, p in zip(uh[-(d + 1):], wh[-(d + 1):], strict=True)]
    # w after the saturation (added to the clipped command) or in the command (clipped with it)
    w_after = [0.0] * N if w_in_command else w.tolist()
    w_before = w.tolist() if w_in_command else [0.0] * N

    pieces = [phi, T - phi] if phi > 0 else [T]
    body = ExactPlant(plant, offset=f0, x0=float(xh[-1]), v0=v0)
    maps = [body.zoh_map(h) for h in pieces]

    x_out = np.empty(N)
    v_out = np.empty(N)
    u_out = np.empty(N)
    F_out = np.empty(N)
    sat = np.zeros(N, dtype=bool)
    x, vel = body.x, body.v
    # applied-force queue: F_{n−d−1}, …, F_{n−1} before F_n is issued
    queue = list(Fpast)
    rl = r.tolist()
    b0 = float(b[0])
    bl = [float(q) for q in b[1:]]
    al = [float(q) / float(a[0]) for q in a[1:]]
    inv_a0 = 1.0 / float(a[0])
    stuck_periods = 0
    mask = _CHUNK_MASK
    with task("simulating the tracking loop: samples", total=N,
              show=N >= _LONG_SAMPLES) as advance:
        for n in range(N):
            if not -_BIG < x < _BIG:  # also NaN
                raise ValueError(
                    f"the simulated loop diverged: |x| > {_BIG:g} m at t = {t0 + n * T:g} s "
                    f"(sample {n}); the loop is unstable for these parameters and gains"
                )
            if not n & mask and n:
                advance(mask + 1)  # the progress bar, once per 4096 samples
            x_out[n] = x
            v_out[n] = vel
            acc = b0 * x
            for j, bj in enumerate(bl):
                acc += bj * xs[-1 - j]
            acc *= inv_a0
            for i, ai in enumerate(al):
                acc -= ai * vhat_hist[-1 - i]
            if al:
                vhat_hist.append(acc)
                del vhat_hist[0]
            if bl:
                xs.append(x)
                del xs[0]
            u = K * (P * (rl[n] - x) - D * acc) + w_before[n]
            u_out[n] = u
            if u > umax:
                us = umax
                sat[n] = True
            elif u < -umax:
                us = -umax
                sat[n] = True
            else:
                us = u
            F = G * (us + w_after[n])
            F_out[n] = F
            queue.append(F)
            if n == N - 1:
                break
            # forces of this period: F_{n−d−1} then F_{n−d} (one piece when φ = 0)
            forces = (queue[-d - 2], queue[-d - 1]) if phi > 0 else (queue[-d - 1],)
            del queue[0]
            stuck_here = False
            for mp, Fa in zip(maps, forces, strict=True):
                stuck_here |= body.hold(mp, Fa)
            x, vel = body.x, body.v
            stuck_periods += stuck_here
    if not np.all(np.isfinite(x_out)) or not np.all(np.isfinite(F_out)):
        raise ValueError("the simulated loop diverged (non-finite values): the loop is unstable "
                         "for these parameters and gains")
    t = t0 + T * np.arange(N)
    return TrackingSimulation(
        t=t, x=x_out, v=v_out, command=u_out, force=F_out, saturated=sat, r=r,
        stuck=int(stuck_periods), reversals=int(body.reversals), controller=ctrl,
        plant=(m, c, k, fc, f0), w_in_command=bool(w_in_command),
    )


class ExactPlant:
    """The plant m ẍ + c ẋ + k x + f_c sign(ẋ) + f₀ = F advanced exactly under held forces.

    The state (x, v) moves through intervals of constant applied force F by the zero-order-hold
    maps of :func:`~phoid.dynamics.controller.zoh_pieces`, with Coulomb friction's stick and
    slip located inside an interval (module docstring); an underdamped plant's intervals are cut
    into at most quarter damped periods. :func:`simulate_tracking` drives one with its
    controller; a rig simulator or a test drives one sample by sample.

    Parameters
    ----------
    plant : phoid.Plant
        m (kg), c (N·s/m), k (N/m), f_c (N).
    offset : float, default 0
        Constant offset force f₀, N (resisting side).
    x0, v0 : float, default 0
        Initial position (m) and velocity (m/s).

    Attributes
    ----------
    x, v : float
        The current position (m) and velocity (m/s).
    reversals : int
        Velocity reversals so far (zero crossings that did not stick).
    """

    def __init__(self, plant, *, offset: float = 0.0, x0: float = 0.0, v0: float = 0.0):
        m, c, k, fc = plant_params(plant)
        self._m, self._c, self._k, self._fc = m, c, k, fc
        self._f0 = v.finite("offset", offset, "N")
        self.x = v.finite("x0", x0, "m")
        self.v = v.finite("v0", v0, "m/s")
        self._s = 0 if self.v == 0.0 else (1 if self.v > 0 else -1)  # 0: stuck
        self._flow = _Flow(m, c, k, self._f0, fc)
        wd2 = k / m - (c / (2 * m)) ** 2
        self._wd = math.sqrt(wd2) if wd2 > 0 else 0.0
        self._maps: dict[float, tuple] = {}
        self.reversals = 0

    def zoh_map(self, h: float) -> tuple:
        """The map of an interval of length h (s), cached: Φ, Γ of its sub-pieces and their
        count (at most a quarter damped period each)."""
        mp = self._maps.get(h)
        if mp is not None:
            return mp
        quarter = math.pi / (2 * self._wd) if self._wd > 0 else math.inf
        reps = max(1, math.ceil(h / quarter))
        if reps > MAX_SUBSTEPS:
            raise ValueError(
                f"the plant oscillates at ω_d = {self._wd:.4g} rad/s, {reps} quarter periods in "
                f"an interval of {h:g} s (at most {MAX_SUBSTEPS}): far faster than the loop can "
                "sample; check m, c, k"
            )
        Phi, Gam = zoh_pieces(self._m, self._c, self._k, [h / reps])
        P_, g = Phi[0], Gam[0]
        mp = (float(P_[0, 0]), float(P_[0, 1]), float(P_[1, 0]), float(P_[1, 1]),
              float(g[0]), float(g[1]), h / reps, reps)
        self._maps[h] = mp
        return mp

    def advance(self, force: float, duration: float) -> bool:
        """Hold the applied force ``force`` (N) for ``duration`` (s); True if the mass stuck."""
        if duration <= 0:
            return False
        return self.hold(self.zoh_map(duration), float(force))

    def hold(self, mp: tuple, Fa: float) -> bool:
        """:meth:`advance` with a map from :meth:`zoh_map` (the simulator's inner loop)."""
        p00, p01, p10, p11, g0, g1, h, reps = mp
        x, vel, s = self.x, self.v, self._s
        fc, f0, k = self._fc, self._f0, self._k
        flow = self._flow
        stuck_here = False
        for _ in range(reps):
            if fc == 0.0:
                fn = Fa - f0
                x, vel = p00 * x + p01 * vel + g0 * fn, p10 * x + p11 * vel + g1 * fn
                continue
            if s == 0:
                g = Fa - f0 - k * x
                if -fc <= g <= fc:
                    stuck_here = True
                    continue
                s = 1 if g > 0 else -1
            fn = Fa - f0 - fc * s
            x1 = p00 * x + p01 * vel + g0 * fn
            v1 = p10 * x + p11 * vel + g1 * fn
            if s * v1 > 0 and (k == 0.0 or not flow.may_cross(x, vel, x1, v1, fn, s)):
                x, vel = x1, v1
                continue
            x, vel, s, events, stuck = flow.piece(x, vel, s, Fa, h)
            self.reversals += events
            stuck_here |= stuck
        self.x, self.v, self._s = x, vel, s
        return stuck_here


class _Flow:
    """Exact motion under a constant net force, and the friction events inside one piece."""

    def __init__(self, m, c, k, f0, fc):
        self.m, self.c, self.k, self.f0, self.fc = m, c, k, f0, fc

    def state(self, x, v, fn, t):
        """(x, v) after time t under the constant net force fn (N), moving."""
        m, c, k = self.m, self.c, self.k
        if t <= 0.0:
            return x, v
        if k == 0.0:
            if c == 0.0:
                acc = fn / m
                return x + v * t + 0.5 * acc * t * t, v + acc * t
            lam = c / m
            vinf = fn / c
            e = math.exp(-lam * t)
            one_minus = -math.expm1(-lam * t)
            return x + vinf * t + (v - vinf) * one_minus / lam, vinf + (v - vinf) * e
        Phi, Gam = zoh_pieces(m, c, k, [t])
        return (float(Phi[0, 0, 0] * x + Phi[0, 0, 1] * v + Gam[0, 0] * fn),
                float(Phi[0, 1, 0] * x + Phi[0, 1, 1] * v + Gam[0, 1] * fn))

    def accel(self, x, v, fn):
        return (fn - self.k * x - self.c * v) / self.m

    def may_cross(self, x, v, x1, v1, fn, s) -> bool:
        """k ≠ 0: whether the velocity could touch zero inside although it ends with sign s."""
        return s * self.accel(x, v, fn) < 0 < s * self.accel(x1, v1, fn)

    def crossing(self, x, v, fn, s, h) -> float | None:
        """First t in (0, h] at which s·v(t) ≤ 0, or None (exact to rounding)."""
        m, c, k = self.m, self.c, self.k
        if k == 0.0:  # v(t) is monotone in the piece: one crossing at most, in closed form
            if s * v <= 0.0:  # starts at rest: moves with s only if the force pushes that way
                return 0.0 if s * fn <= 0.0 else None
            if s * self.state(x, v, fn, h)[1] > 0.0:
                return None
            if c == 0.0:
                return min(h, -v * m / fn)
            vinf = fn / c
            t = -math.log(vinf / (vinf - v)) / (c / m)
            return min(h, max(t, 0.0))
        from scipy.optimize import brentq

        def vel(t):
            return self.state(x, v, fn, t)[1] * s

        def acc(t):
            xx, vv = self.state(x, v, fn, t)
            return self.accel(xx, vv, fn) * s

        if vel(0.0) <= 0.0:
            return 0.0 if s * fn - s * k * x <= 0.0 else None
        lo = 0.0
        if acc(0.0) < 0.0 < acc(h):  # the velocity has a minimum inside: look there first
            te = brentq(acc, 0.0, h, xtol=1e-15 * h, rtol=1e-15)
            if vel(te) <= 0.0:
                return brentq(vel, 0.0, te, xtol=1e-15 * h, rtol=1e-15)
            lo = te
        if vel(h) <= 0.0:
            return brentq(vel, lo, h, xtol=1e-15 * h, rtol=1e-15)
        return None

    def piece(self, x, v, s, F, h):
        """Propagate through one piece of constant applied force F with events.

        Returns (x, v, s, reversals, stuck): the state at the piece's end, the motion's sign
        (0 while stuck), the number of reversals and whether the mass stuck in it.
        """
        fc, f0, k = self.fc, self.f0, self.k
        left = h
        reversals = 0
        stuck = False
        for _ in range(64):  # each pass ends the piece, sticks, or reverses once
            if s == 0:
                g = F - f0 - k * x
                if -fc <= g <= fc:
                    return x, 0.0, 0, reversals, True
                s = 1 if g > 0 else -1
            fn = F - f0 - fc * s
            tc = self.crossing(x, v, fn, s, left)
            if tc is None:
                x, v = self.state(x, v, fn, left)
                return x, v, s, reversals, stuck
            x, _ = self.state(x, v, fn, tc)
            v = 0.0
            left -= tc
            g = F - f0 - k * x
            if -fc <= g <= fc:
                return x, 0.0, 0, reversals, True
            if (g > 0) == (s > 0):  # pushed on in the same direction: a touch, not a stop
                x, v = self.state(x, 0.0, fn, left)
                return x, v, s, reversals, stuck
            s = -s
            reversals += 1
            if left <= 0.0:
                return x, 0.0, s, reversals, stuck
        raise RuntimeError("more than 64 friction events in one piece")  # pragma: no cover


def _filter_history(b, a, x, keep) -> list[float]:
    """The estimator's ``keep`` outputs before the start, v̂_{−keep}, …, v̂_{−1}.

    Each is the filter's DC-normalised FIR value on the history, Σ_j b_j x_{−i−j} / Σ a (for
    ``"filtered"`` the backward difference (x_{−i} − x_{−i−1})/T); x before the history repeats
    its oldest value, so a history at rest gives v̂ = 0.
    """
    if keep <= 0:
        return []
    dc = float(np.sum(a))
    out = []
    for i in range(keep, 0, -1):
        n = x.size - i  # index of x_{−i} in x (x ends with x_{−1})
        out.append(float(sum(b[j] * x[max(n - j, 0)] for j in range(b.size))) / dc)
    return out


MAX_SUBSTEPS = 1000  # quarter damped periods per piece: a plant this much faster than T is an error
_BIG = 1e150  # m: a simulated position beyond this is a diverging loop, not a machine


def _vector(name, value, size=None) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"`{name}` must be a non-empty 1-D array; got shape {arr.shape}")
    if size is not None and arr.size != size:
        raise ValueError(f"`{name}` must have the length of `r`, {size}; got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"`{name}` must be finite; it has {int(np.sum(~np.isfinite(arr)))} "
                         "non-finite values")
    return arr
_LONG_SAMPLES = 1_000_000  # samples from which simulate_tracking shows a progress bar (~1.5 s)
_CHUNK_MASK = 4095  # the bar advances once per 4096 samples
