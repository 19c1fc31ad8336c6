r"""The friction fit's least-squares problem: the exact simulator, read at the sample times.

The model of run i is

    ŷᵢ(t) = bᵢ + x₀ᵢ                  (t ≤ τᵢ, held),
    ŷᵢ(t) = bᵢ + X(t − τᵢ; θ, x₀ᵢ)     (t > τᵢ),

θ = (m, c, k, f_c), X the closed loop's response released from rest at x₀ᵢ, computed by
:func:`phoid.simulate` (exact plant propagation, exact stick–slip events; all runs in one
batched call) on a grid of step h = 1/f_s aligned with the delay, and read at the sample times
by the cubic Hermite interpolant of the simulated x and ẋ (:func:`hermite`; error
≤ h⁴‖x⁗‖/384, and O(h²·2f_c/m) within a step that holds a velocity reversal: both far below
the noise at practical sample rates). Under white Gaussian noise of sd sᵢ the likelihood is
maximised by minimising Σᵢ Σⱼ (yᵢⱼ − ŷᵢ(tⱼ))²/sᵢ² (:class:`Problem`). The Jacobian columns are:

* ∂ŷ/∂bᵢ = 1; ∂ŷ/∂τᵢ = −Ẋ(t − τᵢ) (the Hermite interpolant's derivative: the exact derivative of
  the model as evaluated), 0 while held;
* ∂ŷ/∂(m, c, k, f_c) by forward differences of batched simulations (step 10⁻⁵ of the scale);
* ∂ŷ/∂x₀ᵢ for free: the loop is positively homogeneous, X(t; λx₀, λf_c) = λX(t; x₀, f_c)
  (every term of the equation is linear in x except f_c sign(ẋ), which scales with f_c), so
  x₀ ∂X/∂x₀ + f_c ∂X/∂f_c = X.

A sampled (digital) controller (a :class:`phoid.DigitalPD`) replaces the delayed loop by the
hybrid one — zero-order hold, d-sample command delay, the loop's velocity estimator — simulated
exactly with stick–slip by the same :func:`phoid.simulate` (a whole number of steps per
controller sample), its clock started at each run's release.

Runs recorded with a known added mass Δmᵢ (the paper's added-mass trick) are simulated with the
plant m + Δmᵢ (one batched simulation per distinct Δm); θ keeps the mass without additions.

Runs whose command carries a known DC offset bᵢ in the direction of the controller's velocity
(the seed's "PD feedback augmented with a DC offset in the (alternating) direction of
oscillation", Discussion, last paragraph), u = −Pᵢx(t − Δt) − Dᵢẋ(t − Δt) + bᵢ sign(ẋ(t − Δt)),
are simulated with it (exactly, by the same simulator). The bias partly cancels the friction, so
such a run rings for many more cycles before it sticks. Homogeneity then scales the bias too,
X(t; λx₀, λf_c, λb) = λX(t; x₀, f_c, b), so x₀ ∂X/∂x₀ = X − f_c ∂X/∂f_c − b ∂X/∂b, the last term
by one more batched simulation with every bᵢ scaled by 1 + 10⁻⁵. Continuous loops have no jumps
in the model (the switch times move continuously with θ).

Memory and work are linear in the data: run i's nuisances (x₀ᵢ, bᵢ, τᵢ) touch only its own rows,
so the Jacobian is kept as its dense global columns plus three local columns per row
(:class:`BlockJacobian`), JᵀJ as a block-arrow matrix (:class:`Normal`), and each linear system
is solved through the Schur complement of its block-diagonal part (a 4 × 4 system plus one 3 × 3
per run).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BlockJacobian", "Normal", "Problem", "hermite"]

_FD_REL = 1e-5  # forward-difference step, relative to the parameter's scale


@dataclass(frozen=True)
class _PlantParams:
    """Duck-typed plant for :func:`phoid.simulate` (c, k may go negative in a fit)."""

    m: float
    c: float
    k: float
    fc: float


def hermite(X: np.ndarray, V: np.ndarray, h: float,
            u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cubic Hermite interpolant of grid values X, V (step h) and its derivative at u ≥ 0.

    Parameters
    ----------
    X, V : ndarray
        Position (m) and velocity (m/s) on the grid 0, h, 2h, ….
    h : float
        Grid step, s.
    u : ndarray
        Times since the grid's start, s (≥ 0).

    Returns
    -------
    value, derivative : ndarray
        The interpolant (m) and its derivative (m/s) at u.
    """
    z = u / h
    j = np.clip(np.floor(z).astype(np.int64), 0, X.size - 2)
    s = z - j
    x0, x1 = X[j], X[j + 1]
    v0, v1 = V[j] * h, V[j + 1] * h
    s2 = s * s
    s3 = s2 * s
    val = (2 * s3 - 3 * s2 + 1) * x0 + (s3 - 2 * s2 + s) * v0 + (3 * s2 - 2 * s3) * x1 \
        + (s3 - s2) * v1
    der = ((6 * s2 - 6 * s) * (x0 - x1) + (3 * s2 - 4 * s + 1) * v0 + (3 * s2 - 2 * s) * v1) / h
    return val, der


class Problem:
    """The weighted least-squares problem of the used runs.

    Parameter vector: the free globals among (m, c, k, f_c), then (x₀ᵢ, bᵢ, τᵢ) per run.

    Parameters
    ----------
    surveys : sequence of phoid.methods.friction.survey.Survey
        The runs' records (each weighted by 1/sd).
    t_end : array_like
        End of each run's fitted window, s.
    P, D : array_like
        Gains of each run, N/m and N s/m.
    delay : float
        Loop delay Δt, s (continuous loops).
    fs_sim : float
        Simulation rate 1/h, Hz.
    free : tuple of 4 bool
        Which of (m, c, k, f_c) are fitted.
    dm : array_like, optional
        Known added mass of each run, kg.
    digital : phoid.DigitalPD, optional
        The sampled controller, if any.
    bias : array_like, optional
        Known DC offset of each run's command, N.
    """

    def __init__(self, surveys, t_end, P, D, delay, fs_sim, free, dm=None, digital=None,
                 bias=None):
        self.t = []
        self.y = []
        for s, te in zip(surveys, t_end, strict=True):
            sel = s.t <= te
            self.t.append(s.t[sel])
            self.y.append(s.y[sel])
        self.w = np.array([1.0 / s.sd for s in surveys])
        self.t_end = np.asarray(t_end, dtype=float)
        self.P = np.asarray(P, dtype=float)
        self.D = np.asarray(D, dtype=float)
        self.delay = delay
        self.digital = digital
        # after this long at rest the loop's command is constant: the delay, or for a sampled
        # controller its d samples plus the sample in progress
        self.settle = delay if digital is None else digital.delay + digital.sample_time
        self.fs = fs_sim
        self.h = 1.0 / fs_sim
        self.free = tuple(free)  # which of (m, c, k, fc) are fitted
        self.ng = sum(self.free)
        self.B = len(surveys)
        # known added mass per run (the added-mass trick): run i's plant is m + Δmᵢ
        self.dm = np.zeros(self.B) if dm is None else np.asarray(dm, dtype=float)
        self.groups = [np.flatnonzero(self.dm == a) for a in np.unique(self.dm)]
        # known DC offset of each run's command in the direction of the velocity, N
        self.bias = np.zeros(self.B) if bias is None else np.asarray(bias, dtype=float)
        self.biased = bool(np.any(self.bias > 0))
        self.n = np.array([tt.size for tt in self.t])
        self.rows = np.concatenate([[0], np.cumsum(self.n)])

    # parameter vector <-> (theta, local)
    def split(self, p: np.ndarray, fixed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        theta = fixed.copy()
        theta[np.array(self.free)] = p[: self.ng]
        return theta, p[self.ng :].reshape(self.B, 3)

    def simulate(self, theta: np.ndarray, x0: np.ndarray, tau: np.ndarray,
                 bias_scale: float = 1.0):
        """X, V of every run released at x₀ᵢ (hold 0, grid step h); None if not simulable.

        One batched simulation per distinct added mass (run i's plant is m + Δmᵢ); each run's
        command carries its bias bᵢ (times ``bias_scale``)."""
        from phoid.simulation import simulate

        m, c, k, fc = (float(a) for a in theta)
        if not (m > 0 and fc >= 0):
            return None
        dur = max(float(np.max(self.t_end - tau)) + 3.0 * self.h, 4 * self.h)
        X = V = None
        for g in self.groups:
            plant = _PlantParams(m + float(self.dm[g[0]]), c, k, fc)
            g_ = self.digital
            loop = {"delay": self.delay} if g_ is None else {
                "sample_time": g_.sample_time, "delay_samples": g_.delay_samples,
                "velocity": g_.velocity, "cutoff": g_.cutoff}
            try:
                sim = simulate(plant, self.P[g], self.D[g], duration=dur, fs=self.fs,
                               x0=np.asarray(x0)[g], bias=bias_scale * self.bias[g], **loop)
            except ValueError:
                return None
            if not (np.all(np.isfinite(sim.x_true)) and np.all(np.isfinite(sim.v))):
                return None
            if X is None:
                X = np.empty((self.B, sim.x_true.shape[1]))
                V = np.empty_like(X)
            X[g], V[g] = sim.x_true, sim.v
        return X, V

    def model(self, local: np.ndarray, XV) -> tuple[list, list, list]:
        """Per run: model values, post-release mask, Hermite value and derivative."""
        X, V = XV
        vals, posts, herm = [], [], []
        for i in range(self.B):
            x0, b, tau = local[i]
            u = self.t[i] - tau
            post = u > 0
            hv, hd = hermite(X[i], V[i], self.h, np.maximum(u, 0.0))
            vals.append(b + np.where(post, hv, x0))
            posts.append(post)
            herm.append((hv, hd))
        return vals, posts, herm

    def residual(self, local: np.ndarray, XV) -> np.ndarray:
        vals, _, _ = self.model(local, XV)
        return np.concatenate([(self.y[i] - vals[i]) * self.w[i] for i in range(self.B)])

    def steps(self, theta: np.ndarray, local: np.ndarray) -> np.ndarray:
        """Forward-difference steps of (m, c, k, f_c): 10⁻⁵ of each one's scale."""
        m, c, k, fc = theta
        w2 = float(np.median(np.abs(k + self.P))) / m if m > 0 else 1.0
        w = math.sqrt(max(w2, 1e-12))
        kp = float(np.median(np.abs(k + self.P)))
        x0 = float(np.median(np.abs(local[:, 0])))
        scale = np.array([abs(m), max(abs(c), 0.05 * m * w), max(abs(k), 0.05 * m * w2),
                          max(fc, 1e-3 * kp * x0)])
        return _FD_REL * scale

    def global_columns(self, theta, local, XV) -> np.ndarray | None:
        """Unweighted ∂ŷ/∂(free globals) by forward differences, shape (N, ng); one batched
        simulation per column (a backward difference where the forward point cannot be
        simulated). With a bias, one more column: Σ bᵢ ∂ŷ/∂bᵢ (every bias scaled by 1 + 10⁻⁵),
        for the homogeneity relation of :meth:`jacobian`."""
        _, posts, herm = self.model(local, XV)
        steps = self.steps(theta, local)
        G = np.zeros((int(self.rows[-1]), self.ng + int(self.biased)))

        def fill(col, XVp, step):
            # column `col`: the difference quotient of each run's model after its release
            for i in range(self.B):
                u = np.maximum(self.t[i] - local[i, 2], 0.0)
                hv, _ = hermite(XVp[0][i], XVp[1][i], self.h, u)
                G[self.rows[i] : self.rows[i + 1], col] = np.where(
                    posts[i], (hv - herm[i][0]) / step, 0.0)
        col = 0
        for j in range(4):
            if not self.free[j]:
                continue
            th = theta.copy()
            th[j] += steps[j]
            hj = steps[j]
            XVp = self.simulate(th, local[:, 0], local[:, 2])
            if XVp is None:
                th[j] -= 2 * steps[j]
                hj = -steps[j]
                XVp = self.simulate(th, local[:, 0], local[:, 2])
                if XVp is None:
                    return None
            fill(col, XVp, hj)
            col += 1
        if self.biased:
            XVp = self.simulate(theta, local[:, 0], local[:, 2], bias_scale=1.0 + _FD_REL)
            if XVp is None:
                return None
            fill(col, XVp, _FD_REL)
        return G

    def jacobian(self, theta, local, XV, G: np.ndarray) -> BlockJacobian:
        """Weighted Jacobian: the global columns G (unweighted) and the exact local ones, by
        blocks (:class:`BlockJacobian`: memory linear in the data)."""
        _, posts, herm = self.model(local, XV)
        N = int(self.rows[-1])
        glob = np.empty((N, self.ng))
        loc = np.empty((N, 3))
        fc = theta[3]
        for i in range(self.B):
            r = slice(int(self.rows[i]), int(self.rows[i + 1]))
            x0 = local[i, 0]
            hv, hd = herm[i]
            post = posts[i]
            # homogeneity: x₀ ∂X/∂x₀ + f_c ∂X/∂f_c + b ∂X/∂b = X
            dfc = G[r, self.ng - 1] if self.free[3] else 0.0
            db = G[r, self.ng] if self.biased else 0.0
            dx0 = (hv - fc * dfc - db) / x0 if x0 != 0 else np.zeros_like(hv)
            wi = self.w[i]
            glob[r] = G[r, : self.ng] * wi
            loc[r, 0] = np.where(post, dx0, 1.0) * wi
            loc[r, 1] = wi
            loc[r, 2] = np.where(post, -hd, 0.0) * wi
        return BlockJacobian(glob, loc, self.rows.astype(np.intp))


# --------------------------------------------------------------------------------------------
# the Jacobian's block structure: globals dense, each run's (x₀ᵢ, bᵢ, τᵢ) on its own rows


@dataclass(frozen=True)
class BlockJacobian:
    """Weighted Jacobian of :class:`Problem` stored by blocks, in memory linear in the data.

    The columns of the ``ng`` globals are dense (``glob``, shape (N, ng)); the three columns of
    run i's local parameters (x₀ᵢ, bᵢ, τᵢ) are zero outside its rows, so they are kept as one
    (N, 3) array ``loc`` whose rows ``rows[i]:rows[i+1]`` belong to run i. The dense
    N × (ng + 3B) matrix, quadratic in the number of runs, is never formed.
    """

    glob: np.ndarray  # (N, ng)
    loc: np.ndarray  # (N, 3)
    rows: np.ndarray  # (B + 1,) row offsets of the runs

    @property
    def shape(self) -> tuple[int, int]:
        return (self.glob.shape[0], self.glob.shape[1] + 3 * (self.rows.size - 1))

    def tdot(self, r: np.ndarray) -> np.ndarray:
        """Jᵀr for a vector r of N rows (globals first, then (x₀ᵢ, bᵢ, τᵢ) per run)."""
        gl = self.glob.T @ r
        lr = self.loc * r[:, None]
        loc = np.add.reduceat(lr, self.rows[:-1], axis=0) if lr.shape[0] else lr
        return np.concatenate([gl, loc.ravel()])

    def dot(self, d: np.ndarray) -> np.ndarray:
        """J d for a parameter vector d."""
        ng = self.glob.shape[1]
        dl = d[ng:].reshape(-1, 3)
        per_row = np.repeat(dl, np.diff(self.rows), axis=0)  # (N, 3)
        return self.glob @ d[:ng] + np.einsum("nj,nj->n", self.loc, per_row)

    def normal(self) -> Normal:
        """The normal matrix JᵀJ by blocks."""
        g, lc, rows = self.glob, self.loc, self.rows
        start = rows[:-1]
        # per run: Σ over its rows of g ⊗ l (ng × 3) and l ⊗ l (3 × 3)
        gl = np.add.reduceat(g[:, :, None] * lc[:, None, :], start, axis=0)
        ll = np.add.reduceat(lc[:, :, None] * lc[:, None, :], start, axis=0)
        return Normal(g.T @ g, gl, ll)


@dataclass(frozen=True)
class Normal:
    """JᵀJ of a :class:`BlockJacobian`: the block-arrow matrix [[Agg, Agl], [Alg, diag(Allᵢ)]].

    ``gg`` (ng, ng); ``gl`` (B, ng, 3), run i's coupling of the globals with its locals; ``ll``
    (B, 3, 3), run i's locals. Linear systems are solved through the Schur complement of the
    block-diagonal part, S = Agg − Σᵢ Aglᵢ Allᵢ⁻¹ Alg ᵢ (ng × ng): O(B) memory and work.
    """

    gg: np.ndarray
    gl: np.ndarray
    ll: np.ndarray

    def diag(self) -> np.ndarray:
        return np.concatenate([np.diag(self.gg), np.einsum("bjj->bj", self.ll).ravel()])

    def quad(self, d: np.ndarray) -> float:
        """dᵀ (JᵀJ) d."""
        ng = self.gg.shape[0]
        dg, dl = d[:ng], d[ng:].reshape(-1, 3)
        return float(dg @ self.gg @ dg + 2.0 * np.einsum("i,bij,bj->", dg, self.gl, dl)
                     + np.einsum("bi,bij,bj->", dl, self.ll, dl))

    def solve(self, rhs: np.ndarray, lam: float = 0.0, keep: np.ndarray | None = None,
              floor: np.ndarray | None = None) -> np.ndarray:
        """Solve (A + λ diag A) δ = rhs over the globals ``keep`` (a boolean mask; the others
        held at δ = 0) and every local; raises numpy.linalg.LinAlgError when singular.

        ``floor`` is the diagonal used for the damping (default diag A)."""
        ng = self.gg.shape[0]
        dA = self.diag() if floor is None else floor
        keep = np.ones(ng, dtype=bool) if keep is None else keep
        kg = np.flatnonzero(keep)
        Mgg = self.gg[np.ix_(kg, kg)] + lam * np.diag(dA[:ng][kg])
        Mll = self.ll + lam * (np.eye(3)[None] * dA[ng:].reshape(-1, 1, 3))
        Mgl = self.gl[:, kg, :]  # (B, k, 3)
        rg, rl = rhs[:ng][kg], rhs[ng:].reshape(-1, 3)
        # Mll⁻¹ [Mlg, rl] per run in one batched solve
        Z = np.linalg.solve(Mll, np.concatenate([np.swapaxes(Mgl, 1, 2), rl[:, :, None]],
                                                axis=2))  # (B, 3, k + 1)
        S = Mgg - np.einsum("bik,bkj->ij", Mgl, Z[:, :, :-1])
        sg = rg - np.einsum("bik,bk->i", Mgl, Z[:, :, -1])
        dg = np.linalg.solve(S, sg)
        dl = Z[:, :, -1] - np.einsum("bkj,j->bk", Z[:, :, :-1], dg)
        out = np.zeros(rhs.size)
        out[kg] = dg
        out[ng:] = dl.ravel()
        return out

    def inv_globals(self) -> np.ndarray:
        """The globals' block of (JᵀJ)⁻¹: the inverse of the Schur complement."""
        Z = np.linalg.solve(self.ll, np.swapaxes(self.gl, 1, 2))  # (B, 3, ng)
        S = self.gg - np.einsum("bik,bkj->ij", self.gl, Z)
        return np.linalg.inv(S)
