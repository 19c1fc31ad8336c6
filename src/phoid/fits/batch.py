"""Many dominant-mode decay fits at once: :func:`~phoid.fits.decay.fit_decay` on a batch of records.

An identification fits one decay per run (19 for the seed paper's sweep). One fit of 15 000
samples is a handful of Gauss–Newton evaluations, each a few dozen small numpy operations of
~10 µs: the per-call overhead, not the arithmetic, sets its cost. Here the records that share a
sampling step, a block size and a number of fast-mode columns are stacked (zero-padded to the
longest) and every stage of the fit — the tabulated evaluator's sums, the linear solve, the
Kaufman normal matrix, the step-halving Gauss–Newton, the exact-residual polish — runs on all of
them in one set of array operations, each record keeping its own iteration, step length and
stopping point. The arithmetic per record is that of :class:`phoid.fits.decay._Table`,
:func:`phoid.fits.decay._gauss_newton` and :func:`phoid.fits.decay._polish` (same sums, same
tests), so the results agree with fitting the records one by one to rounding (~1e−13 relative;
tests/test_decay_batch.py). Records that do not fit the scheme (non-uniform sampling, fewer
than 64 samples) and records whose start cannot be evaluated go through
:func:`phoid.fits.decay.fit_checked` one at a time.

The identification's first look at every run (:func:`phoid.fits.decay.start_decay`) is batched the
same way where it pays: the ESPRIT eigenproblems, shift-invariance solves and eigenvalues of all
runs are stacked (the same LAPACK routine per matrix, so the same numbers bit for bit).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from phoid.fits import decay as _d

__all__ = ["FitJob", "fit_decays", "start_decays"]


@dataclass(frozen=True)
class FitJob:
    """One record to fit: the arguments of :func:`phoid.fits.decay.fit_decay` (``t`` s, ``x`` m,
    ``release`` s, ``skip`` s, ``fast_roots`` 1/s, ``guess`` (σ 1/s, ω_d rad/s)). The record must
    have passed :func:`phoid.fits.decay.check_record` (float64, finite, t strictly increasing)."""

    t: np.ndarray
    x: np.ndarray
    release: float | None = None
    skip: float = 0.0
    fast_roots: np.ndarray | None = None
    guess: tuple[float, float] | None = None


def _block_size(n: int) -> int:
    """The table block size :class:`phoid.fits.decay._Table` uses for n samples."""
    return int(min(512, max(16, 2 ** round(math.log2(math.sqrt(n))))))


class _Batch:
    """The tabulated evaluator of :class:`phoid.fits.decay._Table` for R records at once.

    All records share the step ``dt``, the block size ``B`` and the number ``kc`` of fast
    columns; record i has n_i samples in nb_i blocks, zero-padded to the longest. The tables of
    a record are zero beyond its own blocks, so the padding enters no sum.
    """

    def __init__(self, preps: Sequence[_d._Prepared], dt: float, B: int):
        R = len(preps)
        self.R, self.B, self.dt = R, B, dt
        n = np.array([p.xw.size for p in preps])
        nb = -(-n // B)
        nbmax = int(nb.max())
        self.n, self.nb, self.nbmax = n, nb, nbmax
        flat = np.zeros((R, nbmax * B))
        for i, p in enumerate(preps):
            flat[i, : p.xw.size] = p.xw
        self.xs = [p.xw for p in preps]
        self.X = flat.reshape(R, nbmax, B)
        self.xx = np.array([float(x @ x) for x in self.xs])
        # rounding of the RSS expansion xᵀx − βᵀGx, allowed for when comparing steps
        self.floor = 1e-13 * self.xx + 1e-300
        self.sx = np.array([float(x.sum()) for x in self.xs])
        consts = _d._table_constants(B, nbmax, float(dt))
        self.j, self.b, self.jb = consts[2], consts[3], consts[4]
        self.Pw, self.Cm, self.Amap = consts[5], consts[6], consts[8]
        self.bvalid = self.b[None, :] < nb[:, None]
        self.last = nb - 1
        j0 = n - (nb - 1) * B  # first padding index of each record's last block
        self.padmask = (self.j[None, :] >= j0[:, None]).astype(float)
        bB = ((nb - 1) * B).astype(float)
        Cpad = np.zeros((R, 3, 3), complex)
        Cpad[:, 0, 0] = Cpad[:, 1, 1] = Cpad[:, 2, 2] = 1.0
        Cpad[:, 0, 1] = bB
        Cpad[:, 0, 2] = bB * bB
        Cpad[:, 1, 2] = 2.0 * bB
        self.Cpad = Cpad
        # fast-mode columns, zero beyond each record's own span
        kc = int(preps[0].fast.size + np.count_nonzero(preps[0].fast.imag))
        self.kc = kc
        self.lin, _lin_ix, self.perm, _pix = _d._lin_index(kc)
        self.m = 5 + kc
        self.dof = np.maximum(n - self.lin.size - 2, 1)
        if kc:
            # the columns of all records, zero beyond each record's own nf samples (FT: the
            # stacked (F; τF) for the cross sums with the damped mode), their Gram matrices,
            # Σ F and F x; ``cols`` the views of each record's own columns
            FT, nf = _fast_columns_many([p.tau for p in preps], [p.fast for p in preps], dt)
            C = FT[:, :kc]
            self.nf, self.nfmax = nf, FT.shape[2]
            self.cols = [C[i, :, : nf[i]] for i in range(R)]
            self.FF = C @ C.transpose(0, 2, 1)
            self.Fx = (C @ flat[:, : self.nfmax, None])[:, :, 0]  # (nf ≤ n: within flat)
            self.Fsum = C.sum(axis=2)
            self.FT = FT

    # -- the sums of one evaluation ------------------------------------------------------------

    def _tables(self, idx, sig, om):
        """e^{s dt j} (R', B) and e^{s dt B b} (R', nbmax), the latter zero beyond each record."""
        ls = (-sig + 1j * om) * self.dt
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            e = np.exp(ls[:, None] * self.jb[None, :])
        W = np.where(self.bvalid[idx], e[:, self.B:], 0.0)
        return e, e[:, : self.B], W

    def _data(self, idx, F, W):
        """Σ_n x_n w^n and Σ_n n x_n w^n per record ``idx`` (the records' blocked data; one
        stacked product when ``idx`` is every record, else record by record: no copy)."""
        Fm = np.empty((F.shape[0], self.B, 2), complex)
        Fm[:, :, 0] = F
        np.multiply(self.j[None, :], F, out=Fm[:, :, 1])
        Fv = Fm.view(float)
        if idx.size == self.R:
            Pm = (self.X @ Fv).view(complex)  # (R, nbmax, 2)
        else:
            Pm = np.empty((idx.size, self.nbmax, 2), complex)
            for k, i in enumerate(idx.tolist()):
                np.matmul(self.X[i], Fv[k], out=Pm[k].view(float))
        return self._sums(Pm, W)

    def _sums(self, Pm, W):
        """(Σ_b W_b P0_b, B Σ_b b W_b P0_b + Σ_b W_b P1_b) from the block products Pm."""
        P0 = Pm[:, :, 0]
        s0 = np.einsum("rb,rb->r", W, P0)
        s1 = self.B * np.einsum("rb,rb->r", self.b[None, :] * W, P0) + np.einsum(
            "rb,rb->r", W, Pm[:, :, 1])
        return s0, s1

    def evaluate(self, idx: np.ndarray, sig: np.ndarray, om: np.ndarray) -> dict:
        """The linear part solved at (σ, ω_d) per record ``idx``: a dict of arrays ``K``, ``Gx``,
        ``beta``, ``sse``, the tables ``F``, ``W``, (``sig``, ``om``) and ``ok`` (False where the
        model could not be evaluated: overflow, a singular linear part)."""
        B, r = self.B, idx.size
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            e, F, W = self._tables(idx, sig, om)
            T = np.empty((r, 3, e.shape[1]), complex)
            T[:, 0, :B] = F
            T[:, 0, B:] = W
            np.multiply(T[:, 0], T[:, 0], out=T[:, 1])
            T[:, 2] = T[:, 0].real * T[:, 0].real + T[:, 0].imag * T[:, 0].imag
            S = T @ self.Pw  # (record, table, [Σ j^p F_j, Σ b^p W_b])
            WF = S[:, :, 3:, None] * S[:, :, None, :3]
            mom = WF.reshape(r, 3, 9) @ self.Cm  # (record, table, p): Σ_n n^p w_t^n, padded
            # the last block's padding j ≥ j0: its partial sums, times that block's W
            Ps = (T[:, :, :B] * self.padmask[idx][:, None, :]) @ self.Pw[:B, :3]
            Wl = T[np.arange(r), :, B + self.last[idx]]
            mom -= Wl[:, :, None] * (Ps @ self.Cpad[idx])
            flat = mom.transpose(0, 2, 1).copy().view(float).reshape(r, 18)
            K5 = (flat @ self.Amap.T).reshape(r, 5, 5)
            K5[:, 0, 0] = self.n[idx]
            s0, s1 = self._data(idx, F, W)
            dt = self.dt
            Gx5 = np.stack([self.sx[idx], s0.real, s0.imag, s1.real * dt, s1.imag * dt], axis=1)
            kc = self.kc
            if kc:
                # Σ_n (F; τF)_n w^n over each record's fast samples, w^n = W_b F_j (n = bB + j)
                # (FT is zero beyond a record's nf; a w^n there that overflows is one of the
                # record's own samples, which makes its main sums overflow too: not ok either way)
                nfm = self.nfmax
                zh = (W[:, : -(-nfm // B), None] * F[:, None, :]).reshape(r, -1)[:, :nfm]
                FT = self.FT if r == self.R else self.FT[idx]
                Pc = FT @ np.ascontiguousarray(zh).view(float).reshape(r, nfm, 2)
                K = np.empty((r, 5 + kc, 5 + kc))
                K[:, :5, :5] = K5
                K[:, 0, 5:] = self.Fsum[idx]
                K[:, 1, 5:] = Pc[:, :kc, 0]
                K[:, 2, 5:] = Pc[:, :kc, 1]
                K[:, 3, 5:] = Pc[:, kc:, 0]
                K[:, 4, 5:] = Pc[:, kc:, 1]
                K[:, 5:, :5] = K[:, :5, 5:].transpose(0, 2, 1)
                K[:, 5:, 5:] = self.FF[idx]
                Gx = np.concatenate((Gx5, self.Fx[idx]), axis=1)
            else:
                K, Gx = K5, Gx5
            lin = self.lin
            ok = np.isfinite(K).all(axis=(1, 2)) & np.isfinite(Gx).all(axis=1)
            Kl = K[:, lin][:, :, lin]
            Gl = Gx[:, lin]
            d = np.sqrt(np.abs(np.diagonal(Kl, axis1=1, axis2=2)))
            ok &= (np.diagonal(Kl, axis1=1, axis2=2) > 0).all(axis=1)
        beta = np.full((r, lin.size), np.nan)
        if ok.any():
            dd = d[ok][:, :, None] * d[ok][:, None, :]
            beta[ok] = _solve_each(Kl[ok] / dd, Gl[ok] / d[ok]) / d[ok]
        ok &= np.isfinite(beta).all(axis=1)
        sse = np.maximum(self.xx[idx] - np.einsum("rk,rk->r", np.nan_to_num(beta), Gl), 0.0)
        return {"sig": sig, "om": om, "K": K, "Gx": Gx, "beta": beta, "sse": sse, "F": F,
                "W": W, "ok": ok}

    def residual(self, idx: np.ndarray, pt: dict) -> tuple[list[np.ndarray], np.ndarray]:
        """Residuals r (one array per record, sample by sample, no cancellation) and G r at the
        points ``pt``, record by record (each record's arrays stay in cache)."""
        beta, F, W = pt["beta"], pt["F"], pt["W"]
        coef = beta[:, 1] - 1j * beta[:, 2]
        B, dt = self.B, self.dt
        rs: list[np.ndarray] = []
        Pm = np.empty((idx.size, self.nbmax, 2), complex)
        Pm[:] = 0.0
        Gr = np.empty((idx.size, self.m))
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            for k, i in enumerate(idx.tolist()):
                n, nb = int(self.n[i]), int(self.nb[i])
                # Re((a − ib) W_b F_j) as one rank-2 real product, then x − it − x_off
                wc = W[k, :nb] * coef[k]
                R = np.stack((wc.real, -wc.imag), axis=1) @ np.stack((F[k].real, F[k].imag))
                np.subtract(self.X[i, :nb], R, out=R)
                R -= beta[k, 0]
                flat = R.reshape(-1)
                flat[n:] = 0.0  # the padding stays out of every sum
                r = flat[:n]
                if self.kc:
                    c = self.cols[i]
                    r[: c.shape[1]] -= beta[k, 3:] @ c
                    Gr[k, 5:] = c @ r[: c.shape[1]]
                Fm = np.empty((B, 2), complex)
                Fm[:, 0] = F[k]
                np.multiply(self.j, F[k], out=Fm[:, 1])
                np.matmul(R, Fm.view(float), out=Pm[k, :nb].view(float))
                Gr[k, 0] = r.sum()
                rs.append(r)
            s0, s1 = self._sums(Pm, W)
        Gr[:, 1], Gr[:, 2] = s0.real, s0.imag
        Gr[:, 3], Gr[:, 4] = s1.real * dt, s1.imag * dt
        return rs, Gr

    def normal(self, pt: dict, Gr: np.ndarray | None = None, minv: np.ndarray | None = None):
        """(JᵀJ)⁻¹ and Jᵀr per record, as :meth:`phoid.fits.decay._Point.normal` (parameters
        ordered linear …, σ, ω_d); ``minv`` given: only the new gradient ``Gr`` is rotated.
        Returns (Minv, g, ok)."""
        K, beta = pt["K"], pt["beta"]
        a, b = beta[:, 1], beta[:, 2]
        m = self.m
        G = (pt["Gx"] - np.einsum("rij,rj->ri", K[:, :, self.lin], beta)) if Gr is None else Gr
        perm = self.perm
        g = G[:, perm]
        g3, g4 = g[:, -2].copy(), g[:, -1].copy()
        g[:, -2] = -a * g3 - b * g4
        g[:, -1] = b * g3 - a * g4
        if minv is not None:
            return minv, g, np.isfinite(minv).all(axis=(1, 2))
        M = K[:, perm][:, :, perm]
        i, j = m - 2, m - 1
        ci, cj = M[:, :, i].copy(), M[:, :, j].copy()
        c3 = -a[:, None] * ci - b[:, None] * cj
        c4 = b[:, None] * ci - a[:, None] * cj
        M[:, :, i] = c3
        M[:, :, j] = c4
        M[:, i, :] = c3
        M[:, j, :] = c4
        k33, k34, k44 = ci[:, i], ci[:, j], cj[:, j]
        M[:, i, i] = a * a * k33 + 2 * a * b * k34 + b * b * k44
        M[:, j, j] = b * b * k33 - 2 * a * b * k34 + a * a * k44
        M[:, i, j] = M[:, j, i] = a * b * (k44 - k33) + (a * a - b * b) * k34
        diag = np.diagonal(M, axis1=1, axis2=2)
        ok = np.isfinite(M).all(axis=(1, 2)) & (diag > 0).all(axis=1)
        Minv = np.full_like(M, np.nan)
        if ok.any():
            d = np.sqrt(diag[ok])
            dd = d[:, :, None] * d[:, None, :]
            Minv[ok] = _inv_each(M[ok] / dd) / dd
        ok &= np.isfinite(Minv).all(axis=(1, 2))
        return Minv, g, ok


def _fast_columns_many(taus: Sequence[np.ndarray], roots: Sequence[np.ndarray], dt: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`phoid.fits.decay._fast_columns` of R records of uniform step ``dt`` (s) and the same
    number kc of columns, stacked with τ times them: (R, 2 kc, nf_max), zero beyond each
    record's own nf samples, and nf (R,). Every column is computed as there, element for
    element (the same exponentials, the same table products), so the columns are the same
    numbers bit for bit."""
    R = len(taus)
    nf = np.array([int(np.searchsorted(tau, tau[0] + 37.0 / min(-z.real for z in r.tolist()),
                                       side="right")) for tau, r in zip(taus, roots, strict=True)])
    nfm = int(nf.max())
    kc = int(roots[0].size + np.count_nonzero(roots[0].imag))
    TF = np.zeros((R, nfm))
    for i, tau in enumerate(taus):
        np.subtract(tau[: nf[i]], tau[0], out=TF[i, : nf[i]])
    out = np.empty((R, 2 * kc, nfm))
    # (record, first column, root) of every complex root of each kind and of every real root
    tab: list[tuple[int, int, complex]] = []
    direct: list[tuple[int, int, complex]] = []
    real: list[tuple[int, int, float]] = []
    for i, rr in enumerate(roots):
        col = 0
        for z in rr.tolist():
            if z.imag != 0:
                (tab if nf[i] > 256 else direct).append((i, col, z))
                col += 2
            else:
                real.append((i, col, z.real))
                col += 1
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        if tab:
            ii, cc, zz = (np.array(v) for v in zip(*tab, strict=True))
            ls = zz * dt
            Ft = np.exp(ls[:, None] * np.arange(64.0)[None, :])
            Wt = np.exp((ls * 64)[:, None] * np.arange(-(-nfm // 64), dtype=float)[None, :])
            e = (Wt[:, :, None] * Ft[:, None, :]).reshape(len(tab), -1)[:, :nfm]
            out[ii, cc] = e.real
            out[ii, cc + 1] = e.imag
        if direct:
            ii, cc, zz = (np.array(v) for v in zip(*direct, strict=True))
            e = np.exp(zz[:, None] * TF[ii])
            out[ii, cc] = e.real
            out[ii, cc + 1] = e.imag
        if real:
            ii, cc, zz = (np.array(v) for v in zip(*real, strict=True))
            out[ii, cc] = np.exp(zz[:, None] * TF[ii])
    # zero beyond nf (|e^{rτ}| ≤ 1 there: no overflow); τF is, as TF is
    out[:, :kc] *= (np.arange(nfm)[None, :] < nf[:, None])[:, None, :]
    np.multiply(out[:, :kc], TF[:, None, :], out=out[:, kc:])
    return out, nf


def _solve_each(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Solutions of the stacked systems A x = y; NaN rows for the singular ones."""
    try:
        return np.linalg.solve(A, y[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        out = np.full(y.shape, np.nan)
        for i in range(A.shape[0]):
            try:
                out[i] = np.linalg.solve(A[i], y[i])
            except np.linalg.LinAlgError:
                pass
        return out


def _inv_each(A: np.ndarray) -> np.ndarray:
    """Inverses of the stacked matrices A; NaN for the singular ones."""
    try:
        return np.linalg.inv(A)
    except np.linalg.LinAlgError:
        out = np.full(A.shape, np.nan)
        for i in range(A.shape[0]):
            try:
                out[i] = np.linalg.inv(A[i])
            except np.linalg.LinAlgError:
                pass
        return out


def _take(pt: dict, sel) -> dict:
    return {k: v[sel] for k, v in pt.items()}


def _put(pt: dict, sel, new: dict) -> None:
    for k, v in new.items():
        pt[k][sel] = v


def _step_se(Minv, g, sse, dof):
    """Gauss–Newton step (σ, ω_d) and its standard errors at residual variance sse/dof."""
    step = np.einsum("rij,rj->ri", Minv[:, -2:], g)
    var = sse / dof
    se0 = np.sqrt(np.maximum(Minv[:, -2, -2] * var, 0.0))
    se1 = np.sqrt(np.maximum(Minv[:, -1, -1] * var, 0.0))
    return step, se0, se1


def _gauss_newton(bt: _Batch, pt: dict, rtol_se: float = 0.05, maxit: int | None = None):
    """:func:`phoid.fits.decay._gauss_newton` for every record of ``pt`` (all evaluable), in lock
    step: each record stops on its own test. Returns (point, Minv (NaN where none), converged,
    iterations)."""
    maxit = _d._MAXIT if maxit is None else maxit
    R = bt.R
    Minv = np.full((R, bt.m, bt.m), np.nan)
    converged = np.zeros(R, bool)
    iters = np.zeros(R, int)
    act = np.arange(R)
    for it in range(maxit + 1):
        sub = _take(pt, act)
        Mi, g, ok = bt.normal(sub)
        Minv[act] = Mi
        iters[act] = it
        act, Mi, g, sub = act[ok], Mi[ok], g[ok], _take(sub, ok)
        if act.size == 0:
            break
        step, se0, se1 = _step_se(Mi, g, sub["sse"], bt.dof[act])
        scale = np.abs(sub["sig"]) + np.abs(sub["om"])
        done = (np.abs(step[:, 0]) <= np.maximum(rtol_se * se0, 1e-10 * scale)) & (
            np.abs(step[:, 1]) <= np.maximum(rtol_se * se1, 1e-10 * scale))
        converged[act[done]] = True
        keep = ~done
        act, step, scale, sub = act[keep], step[keep], scale[keep], _take(sub, keep)
        if act.size == 0 or it == maxit:
            break
        # step halving per record, all records still searching evaluated together
        lam = np.ones(act.size)
        moved = np.zeros(act.size, bool)
        search = np.arange(act.size)
        while search.size:
            rows = act[search]
            cand = bt.evaluate(rows, sub["sig"][search] + lam[search] * step[search, 0],
                               np.abs(sub["om"][search] + lam[search] * step[search, 1]))
            good = cand["ok"] & (cand["sse"] <= sub["sse"][search] + bt.floor[rows])
            _put(pt, rows[good], _take(cand, good))
            moved[search[good]] = True
            lam[search[~good]] *= 0.5
            search = search[~good & (lam[search] >= 2.0**-12)]
        # no descent: at the rounding floor if the step is tiny, else stuck
        stuck = ~moved
        tiny = (np.abs(step[:, 0]) <= 1e-6 * scale) & (np.abs(step[:, 1]) <= 1e-6 * scale)
        converged[act[stuck & tiny]] = True
        act = act[moved]
        if act.size == 0:
            break
    return pt, Minv, converged, iters


def _polish(bt: _Batch, pt: dict, Minv: np.ndarray, rtol_se: float = 0.05):
    """`decay._polish` on every record: the exact residual at the optimum and up to
    three more steps with the exact gradient. Returns (point, residuals, Minv)."""
    R = bt.R
    rows = np.arange(R)
    r, Gr = bt.residual(rows, pt)
    has = np.isfinite(Minv).all(axis=(1, 2))
    _m, g_all, _ok = bt.normal(pt, Gr, minv=Minv)
    act = rows[has]
    for _ in range(3):
        if act.size == 0:
            break
        sub = _take(pt, act)
        sse = np.array([float(r[i] @ r[i]) for i in act.tolist()])
        step, se0, se1 = _step_se(Minv[act], g_all[act], sse, np.maximum(bt.n[act] - bt.m, 1))
        tiny = 1e-15 * (np.abs(sub["sig"]) + np.abs(sub["om"]))
        small = (np.abs(step[:, 0]) <= np.maximum(rtol_se * se0, tiny)) & (
            np.abs(step[:, 1]) <= np.maximum(rtol_se * se1, tiny))
        act, step, sse, sub = act[~small], step[~small], sse[~small], _take(sub, ~small)
        if act.size == 0:
            break
        q = bt.evaluate(act, sub["sig"] + step[:, 0], np.abs(sub["om"] + step[:, 1]))
        ok = q["ok"]
        r2, Gr2 = bt.residual(act, q)
        ok &= np.array([float(x @ x) for x in r2]) <= sse
        M2, g2, okn = bt.normal(q, Gr2)
        ok &= okn
        sel = act[ok]
        _put(pt, sel, _take(q, ok))
        for k in np.flatnonzero(ok).tolist():
            r[int(act[k])] = r2[k]
        Minv[sel], g_all[sel] = M2[ok], g2[ok]
        act = sel
    return pt, r, Minv


def _group_key(prep: _d._Prepared) -> tuple | None:
    """Records fitted together share this key; None for one the batch does not take."""
    if prep.udt is None or prep.xw.size < 64:
        return None
    kc = int(prep.fast.size + np.count_nonzero(prep.fast.imag))
    return (float(prep.udt), _block_size(prep.xw.size), kc)


def fit_decays(jobs: Sequence[FitJob]) -> list[_d.DecayFit | str]:
    """:func:`phoid.fits.decay.fit_decay` of every job, the uniformly sampled ones batched.

    Parameters
    ----------
    jobs : sequence of FitJob
        The records (already checked) and their fit options.

    Returns
    -------
    list of DecayFit or str
        Per job its fit (``method == "mode-fit"``, as :func:`phoid.fits.decay.fit_decay` returns
        it), or the message of the ValueError, RuntimeError or LinAlgError that fitting it
        alone raises.
    """
    out: list[_d.DecayFit | str | None] = [None] * len(jobs)
    preps: dict[int, _d._Prepared] = {}
    groups: dict[tuple, list[int]] = {}
    alone: list[int] = []
    for i, job in enumerate(jobs):
        try:
            prep = _d._fit_prepare(job.t, job.x, release=job.release, skip=job.skip,
                                   fast_roots=job.fast_roots, guess=job.guess)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            out[i] = str(exc)
            continue
        preps[i] = prep
        key = _group_key(prep)
        if key is None:
            alone.append(i)
        else:
            groups.setdefault(key, []).append(i)
    for (dt, B, _kc), members in groups.items():
        for idx in _chunks(members, [preps[i].xw.size for i in members]):
            _fit_group(idx, [preps[i] for i in idx], dt, B, out, alone)
    for i in alone:
        job = jobs[i]
        try:
            out[i] = _d.fit_checked(job.t, job.x, release=job.release, skip=job.skip,
                                     fast_roots=job.fast_roots, guess=job.guess)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            out[i] = str(exc)
    return out  # type: ignore[return-value]


#: a batch holds at most about this many samples (its stacked copy of the data and the
#: residuals it keeps are then ≤ 8 MB each): long records are fitted in smaller batches, a
#: record of more samples alone, so the memory stays that of the one-by-one fits
_BATCH_SAMPLES = 1 << 20


def _chunks(members: list[int], sizes: list[int]) -> list[list[int]]:
    """``members`` cut into consecutive batches of at most ``_BATCH_SAMPLES`` samples."""
    out: list[list[int]] = [[]]
    total = 0
    for i, n in zip(members, sizes, strict=True):
        if out[-1] and total + n > _BATCH_SAMPLES:
            out.append([])
            total = 0
        out[-1].append(i)
        total += n
    return out


def _fit_group(idx: list[int], ps: list[_d._Prepared], dt: float, B: int, out: list,
               alone: list[int]) -> None:
    """Fit one batch of records (indices ``idx`` into ``out``); records whose start cannot be
    evaluated are appended to ``alone``."""
    bt = _Batch(ps, dt, B)
    rows = np.arange(len(idx))
    pt = bt.evaluate(rows, np.array([p.sigma for p in ps]), np.array([p.omega_d for p in ps]))
    ok = pt["ok"]
    # a start that cannot be evaluated: the one-record fit, with its fallback start
    alone.extend(i for i, good in zip(idx, ok.tolist(), strict=True) if not good)
    if not ok.any():
        return
    sel = np.flatnonzero(ok)
    if not ok.all():
        bt = _Batch([ps[j] for j in sel], dt, B)
        pt = bt.evaluate(np.arange(sel.size), pt["sig"][sel], pt["om"][sel])
    pt, Minv, converged, iters = _gauss_newton(bt, pt)
    pt, r, Minv = _polish(bt, pt, Minv)
    for row, j in enumerate(sel.tolist()):
        i = idx[j]
        try:
            out[i] = _d._fit_finish(ps[j], float(pt["sig"][row]), float(pt["om"][row]),
                                    pt["beta"][row], pt["K"][row], r[row],
                                    _minv_or_nan(Minv[row]), bool(converged[row]),
                                    int(iters[row]))
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            out[i] = str(exc)


def _minv_or_nan(M: np.ndarray) -> np.ndarray:
    return M if np.isfinite(M).all() else np.full_like(M, np.nan)


def start_decays(records: Sequence[tuple[np.ndarray, np.ndarray]], *, skip: float = 0.0,
                 refine: bool | str = True, coarse_release: bool = False
                 ) -> list[_d.DecayStart | str]:
    """:func:`phoid.fits.decay.start_decay` of every record (t s, x m), the ESPRIT stage stacked.

    Returns per record its DecayStart, or the message of the ValueError, RuntimeError or
    LinAlgError that starting it alone raises. Identical to calling
    :func:`phoid.fits.decay.start_decay` per record.
    """
    out: list[_d.DecayStart | str | None] = [None] * len(records)
    pres: dict[int, _d._StartInput] = {}
    checked: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for i, (t, x) in enumerate(records):
        try:
            checked[i] = _d.check_record(t, x)
        except ValueError as exc:
            out[i] = str(exc)
    # the releases' change points in one batch, the spectral periods in one FFT
    detected = dict(zip(checked, _d._releases([t for t, _ in checked.values()],
                                               [x for _, x in checked.values()],
                                               not coarse_release), strict=True))
    grids: dict[int, _d._StartGrid] = {}
    for i, (t, x) in checked.items():
        try:
            grids[i] = _d._start_grid(t, x, None, skip, not coarse_release, detected[i])
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            out[i] = str(exc)
    periods = _d._dominant_periods([g.xg for g in grids.values()])
    for (i, g), per in zip(grids.items(), periods, strict=True):
        pres[i] = _d._start_input(g, per)
    order = 3
    grams: dict[int, list[tuple[int, np.ndarray]]] = {}
    for i, pre in pres.items():
        L, HH = _d._esprit_gram(pre.y, order)
        grams.setdefault(L, []).append((i, HH))
    roots: dict[int, tuple] = {}
    for items in grams.values():
        ids = [i for i, _ in items]
        try:
            w, U = np.linalg.eigh(np.stack([HH for _, HH in items]))
        except np.linalg.LinAlgError:
            for i in ids:
                try:
                    pre = pres[i]
                    roots[i] = _d.esprit(pre.y, pre.q * pre.dt, order)
                except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
                    out[i] = str(exc)
            continue
        top = np.argsort(w, axis=1)[:, ::-1][:, :order]
        Us = np.take_along_axis(U, top[:, None, :], axis=2)  # (runs, L, order)
        v = Us[:, -1, :]
        normal = np.einsum("ri,ri->r", v, v) < 0.5
        Phi = np.empty((len(ids), order, order))
        if normal.any():
            A = Us[normal, :-1]
            At = A.transpose(0, 2, 1)
            try:
                Phi[normal] = np.linalg.solve(At @ A, At @ Us[normal, 1:])
            except np.linalg.LinAlgError:
                normal[:] = False
        for k in np.flatnonzero(~normal).tolist():
            try:
                Phi[k] = _d._esprit_phi(Us[k])
            except np.linalg.LinAlgError as exc:
                out[ids[k]] = str(exc)
                Phi[k] = np.nan
        good = np.isfinite(Phi).all(axis=(1, 2))
        z = np.full((len(ids), order), np.nan, complex)
        if good.any():
            try:
                z[good] = np.linalg.eigvals(Phi[good]).astype(complex)
            except np.linalg.LinAlgError:
                good[:] = False
        for k, i in enumerate(ids):
            if out[i] is not None:
                continue
            pre = pres[i]
            try:
                roots[i] = _d._esprit_roots(pre.y, pre.q * pre.dt, Us[k],
                                            z[k] if good[k] else None)
            except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
                out[i] = str(exc)
    for i, (s_, energy) in roots.items():
        try:
            out[i] = _d._start_finish(pres[i], s_, energy, refine)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            out[i] = str(exc)
    return out  # type: ignore[return-value]
