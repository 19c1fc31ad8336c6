"""Stacked evaluators of the damped-mode model: its linear part solved at (σ, ω_d) for R
records at once.

The model of one record over its window, τ = t − t₀ (s), is (eq. 15 with an offset)

    x = x_off + a C + b S + Σ c_j F_j,   C, S = e^{−στ} cos ω_dτ, e^{−στ} sin ω_dτ,

with F the optional fixed non-dominant mode columns (:func:`fast_columns`). The basis rows are
G = [1, C, S, τC, τS, F₁ … F_k]; the linear parameters (x_off, a, b, c …) are rows 0, 1, 2,
5 …, and ∂/∂σ = −(aτC + bτS), ∂/∂ω_d = bτC − aτS. At every (σ, ω_d) a stack forms K = G Gᵀ
and G x per record, solves the linear part (variable projection), and gives the normal
equations of the full Jacobian for Kaufman's Gauss–Newton step
(:func:`phoid.fits._solver.gauss_newton`).

Two kinds of stack share that algebra and differ only in how the sums are formed:

:class:`TableStack`
    uniform sampling τ_n = n dt (≥ 64 samples): every sum Σ_n n^p e^{sτ_n} (p ≤ 2) and
    Σ_n y_n n^p e^{sτ_n} (p ≤ 1) factorises over n = bB + j into √n-long exponential tables,
    so one (σ, ω_d) costs one pass over x and no transcendental function per sample.
:class:`DirectStack`
    any sampling: the basis is formed sample by sample.

Records of a stack are zero-padded to the longest; the padding enters no sum, so a record's
numbers do not depend on the others in its stack beyond rounding (a BLAS product over a padded
axis may block the same sum differently). A single record is a stack of one.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "DirectStack",
    "Stack",
    "TableStack",
    "block_size",
    "every",
    "fast_columns",
    "inv_each",
    "lin_index",
    "make_stack",
    "solve_each",
    "stack_key",
    "table_constants",
]


@functools.lru_cache(maxsize=16)
def lin_index(k: int) -> tuple[np.ndarray, np.ndarray]:
    """For k fast columns: the linear parameters' rows ``lin`` (0, 1, 2, 5 … 4 + k) and the
    parameter order (lin …, 3, 4) of the normal equations (σ, ω_d last)."""
    lin = np.array([0, 1, 2, *range(5, 5 + k)])
    perm = np.array([*lin.tolist(), 3, 4])
    for a in (lin, perm):
        a.setflags(write=False)
    return lin, perm


def block_size(n: int) -> int:
    """The table block size B for n samples: the power of two nearest √n, within 16 … 512."""
    return int(min(512, max(16, 2 ** round(math.log2(math.sqrt(n))))))


def stack_key(n: int, udt: float | None, kc: int) -> tuple:
    """Records that can share a stack share this key: n samples, uniform step ``udt`` (s, None
    if the sampling is not uniform), kc fast columns. Uniform records of ≥ 64 samples go to a
    :class:`TableStack` (same step and block size), the others to a :class:`DirectStack`."""
    if udt is not None and n >= 64:
        return ("table", float(udt), block_size(n), kc)
    return ("direct", kc)


def make_stack(taus: Sequence[np.ndarray], xs: Sequence[np.ndarray], udt: float | None,
               roots: Sequence[np.ndarray] | None = None) -> Stack:
    """The stack of the records (τ s, x m), which must share one :func:`stack_key`; ``roots``:
    each record's fast roots (1/s), none by default."""
    if roots is None:
        roots = [np.zeros(0, complex)] * len(xs)
    if stack_key(xs[0].size, udt, 0)[0] == "table":
        return TableStack(taus, xs, roots, float(udt))  # type: ignore[arg-type]
    return DirectStack(taus, xs, roots)


def every(a: np.ndarray) -> bool:
    """Whether every element of the boolean array ``a`` is True (cheaper than ``a.all()``
    on the few elements of a stack's per-record flags)."""
    return np.count_nonzero(a) == a.size


def n_columns(roots: np.ndarray) -> int:
    """Fast-mode columns of the roots: one per real root, two per complex one."""
    return int(roots.size + np.count_nonzero(roots.imag))


#: R = [[−a, −b], [b, −a]] from the linear parameters (x_off, a, b, …): their indices, signs
_ROT = np.array([1, 2, 2, 1])
_ROT_SIGN = np.array([-1.0, -1.0, 1.0, -1.0])


class Stack:
    """What both kinds of stack share: the data, the fast-mode columns, the linear solve and
    the normal equations. Subclasses supply the damped-mode sums (``_base``, ``_head``) and the
    exact residual (``residual``).

    Parameters
    ----------
    taus, xs : sequence of ndarray
        Per record τ (s, from its first sample) and x (m).
    roots : sequence of ndarray
        Per record its fast roots (1/s), all with the same number of columns.
    width : int
        Padded length of the stacked data (≥ every record's length).
    dt : float or None
        Uniform step (s) for tabulated fast columns, None for direct ones.
    """

    def __init__(self, taus: Sequence[np.ndarray], xs: Sequence[np.ndarray],
                 roots: Sequence[np.ndarray], width: int, dt: float | None):
        R = len(xs)
        self.R = R
        n = np.array([x.size for x in xs])
        self.n = n
        self.taus = list(taus)
        self.xs = list(xs)
        self.roots = list(roots)
        flat = np.zeros((R, width))
        for i, x in enumerate(xs):
            flat[i, : x.size] = x
        self.flat = flat
        self.xx = np.array([float(x @ x) for x in xs])
        # rounding of the RSS expansion xᵀx − βᵀGx, allowed for when comparing steps
        self.floor = 1e-13 * self.xx + 1e-300
        self.sx = np.array([float(x.sum()) for x in xs])
        kc = n_columns(roots[0])
        self.kc = kc
        self.lin, self.perm = lin_index(kc)
        self.m = 5 + kc
        self.dof = np.maximum(n - self.lin.size - 2, 1)
        if kc:
            # the columns of all records, zero beyond each record's own nf samples (FT: the
            # stacked (F; τF) for the cross sums with the damped mode), their Gram matrices,
            # Σ F and F x; ``cols`` the views of each record's own columns
            FT, nf = fast_columns(taus, roots, dt)
            C = FT[:, :kc]
            self.nf, self.nfmax = nf, FT.shape[2]
            self.cols = [C[i, :, : nf[i]] for i in range(R)]
            self.FF = C @ C.transpose(0, 2, 1)
            self.Fx = (C @ flat[:, : self.nfmax, None])[:, :, 0]  # (nf ≤ n: within flat)
            self.Fsum = C.sum(axis=2)
            self.FT = FT

    def subset(self, rows: np.ndarray) -> Stack:
        """A stack of the records ``rows`` only (of the same kind)."""
        sel = rows.tolist()
        return self._like([self.taus[i] for i in sel], [self.xs[i] for i in sel],
                          [self.roots[i] for i in sel])

    def _like(self, taus, xs, roots) -> Stack:  # pragma: no cover - abstract
        raise NotImplementedError

    def _base(self, idx: np.ndarray, sig: np.ndarray, om: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, dict, np.ndarray | None]:  # pragma: no cover
        """K and G x of the rows 1, C, S, τC, τS (r, 5, 5), (r, 5); what ``residual`` keeps
        of the point; e^{sτ} over the fast columns' span (r, nfmax) when there are any."""
        raise NotImplementedError

    def residual(self, idx: np.ndarray, pt: dict
                 ) -> tuple[list[np.ndarray], np.ndarray]:  # pragma: no cover
        """Residuals r = x − model (m, one array per record, sample by sample, no
        cancellation) and G r at the points ``pt`` of the records ``idx``."""
        raise NotImplementedError

    def evaluate(self, idx: np.ndarray, sig: np.ndarray, om: np.ndarray) -> dict:
        """The linear part solved at (σ 1/s, ω_d rad/s) per record ``idx``.

        Returns a dict of arrays, one row per record: ``sig``, ``om``, ``K`` = G Gᵀ, ``Gx``,
        ``beta`` (x_off, a, b, c …), ``sse`` (the residual sum of squares at the linear
        optimum, xᵀx − βᵀ(Gx)_lin), ``ok`` (False where the model could not be evaluated:
        overflow, a singular linear part) and what the stack's ``residual`` needs.
        """
        r = idx.size
        kc = self.kc
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            K5, Gx5, keep, zh = self._base(idx, sig, om)
            if kc:
                # Σ_n (F; τF)_n e^{sτ_n} over each record's fast samples (FT is zero beyond a
                # record's nf; an e^{sτ} there that overflows is one of the record's own
                # samples, which makes its main sums overflow too: not ok either way)
                nfm = self.nfmax
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
                lin = self.lin
                Kl = K[:, lin][:, :, lin]
                Gl = Gx[:, lin]
            else:
                K, Gx = K5, Gx5
                Kl, Gl = K[:, :3, :3], Gx[:, :3]
            # the linear part of every record, equilibrated to a unit diagonal (a record whose
            # sums overflowed or whose diagonal is not positive gives NaN here: not ok)
            d = np.sqrt(Kl.diagonal(axis1=1, axis2=2))
            beta = solve_each(Kl / (d[:, :, None] * d[:, None, :]), Gl / d) / d
            ok = (np.isfinite(K).all(axis=(1, 2)) & np.isfinite(Gx).all(axis=1)
                  & np.isfinite(beta).all(axis=1))
        if every(ok):
            bz = beta
        else:
            beta[~ok] = np.nan
            bz = np.where(ok[:, None], beta, 0.0)
        xx = self.xx if r == self.R else self.xx[idx]
        sse = np.maximum(xx - (bz[:, None, :] @ Gl[:, :, None])[:, 0, 0], 0.0)
        pt = {"sig": sig, "om": om, "K": K, "Gx": Gx, "beta": beta, "sse": sse, "ok": ok}
        pt.update(keep)
        return pt

    def normal(self, pt: dict, Gr: np.ndarray | None = None, minv: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(JᵀJ)⁻¹ and Jᵀr per record at the points ``pt``, parameters ordered (linear …, σ,
        ω_d), J = T G with T = [[I, 0], [0, R]], R = [[−a, −b], [b, −a]] acting on the rows
        τC, τS (the derivatives of the model in σ, ω_d). ``Gr``: G r from the exact residual
        (default: Gx − K β, the gradient at the linear optimum); with ``minv`` given only the
        new gradient is rotated. Returns (Minv, g, ok), Minv NaN where the normal matrix is
        singular."""
        K, beta = pt["K"], pt["beta"]
        r, m, kc = K.shape[0], self.m, self.kc
        if Gr is None:
            Kb = K[:, :, self.lin] if kc else K[:, :, :3]
            Gr = pt["Gx"] - (Kb @ beta[:, :, None])[:, :, 0]
        # T: the identity but for the rows τC, τS (3, 4), rotated by R
        T = np.zeros((r, m, m))
        T.reshape(r, m * m)[:, :: m + 1] = 1.0
        T[:, 3:5, 3:5] = (beta[:, _ROT] * _ROT_SIGN).reshape(r, 2, 2)  # [[−a, −b], [b, −a]]
        g = (T @ Gr[:, :, None])[:, :, 0]
        if kc:
            g = g[:, self.perm]
        if minv is not None:
            return minv, g, np.isfinite(minv).all(axis=(1, 2))
        M = T @ K @ T.transpose(0, 2, 1)
        if kc:
            M = M[:, self.perm][:, :, self.perm]
        # equilibrated to a unit diagonal; a diagonal entry that is not positive or finite
        # makes the record's inverse NaN: not ok
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            d = np.sqrt(M.diagonal(axis1=1, axis2=2))
            dd = d[:, :, None] * d[:, None, :]
            Minv = inv_each(M / dd) / dd
        ok = np.isfinite(Minv).all(axis=(1, 2))
        if not every(ok):
            Minv[~ok] = np.nan
        return Minv, g, ok



class TableStack(Stack):
    """Uniformly sampled records τ_n = n dt, all with the same step ``dt`` (s) and block size
    B: every sum over n = bB + j of n^p e^{sτ_n} and y_n n^p e^{sτ_n} from the tables
    F_j = e^{s dt j} (j < B) and W_b = e^{s dt B b} (b < nb).

    With w = e^{s dt}: K from the moments Σ_n n^p w_t^n (p ≤ 2) of w_t = w, w², |w|²
    (C² = (|z|² + Re z²)/2, S² = (|z|² − Re z²)/2, CS = Im z²/2 for z = e^{sτ}), each
    Σ_b W_b b^{p_b} · Σ_j F_j j^{p_j} combined; the tables of w² and |w|² are those of w
    squared. The zero padding of a record's last block is taken off with that block's partial
    sums; the tables are zero beyond a record's own blocks.
    """

    def __init__(self, taus: Sequence[np.ndarray], xs: Sequence[np.ndarray],
                 roots: Sequence[np.ndarray], dt: float):
        n = np.array([x.size for x in xs])
        B = block_size(int(n[0]))
        nb = -(-n // B)
        nbmax = int(nb.max())
        super().__init__(taus, xs, roots, nbmax * B, dt)
        R = self.R
        self.B, self.dt = B, dt
        self.nb, self.nbmax = nb, nbmax
        self.X = self.flat.reshape(R, nbmax, B)
        consts = table_constants(B, nbmax, float(dt))
        self.j, self.b, self.jb = consts[2], consts[3], consts[4]
        self.Pw, self.Cm, self.Amap = consts[5], consts[6], consts[8]
        self.bvalid, self.last, self.PadC, self.full = _padding(B, nbmax, tuple(n.tolist()))

    def _like(self, taus, xs, roots):
        return TableStack(taus, xs, roots, self.dt)

    def _tables(self, idx, sig, om, out=None):
        """The table e^{s dt [j; B b]} (r, B + nbmax) (into ``out``), its F_j = e^{s dt j}
        (r, B) and W_b = e^{s dt B b} (r, nbmax), W zero beyond each record's blocks."""
        ls = (-sig + 1j * om) * self.dt
        e = np.exp(ls[:, None] * self.jb, out=out)
        if not self.full:
            e[:, self.B:] = np.where(self.bvalid[idx], e[:, self.B:], 0.0)
        return e, e[:, : self.B], e[:, self.B:]

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
        WW = np.empty((W.shape[0], 2, W.shape[1]), complex)
        WW[:, 0] = W
        np.multiply(W, self.b, out=WW[:, 1])
        Q = WW @ Pm  # (record, [W, bW], [P0, P1])
        return Q[:, 0, 0], self.B * Q[:, 1, 0] + Q[:, 0, 1]

    def _base(self, idx, sig, om):
        B, r = self.B, idx.size
        sel = slice(None) if r == self.R else idx
        T = np.empty((r, 3, B + self.nbmax), complex)
        e, F, W = self._tables(idx, sig, om, out=T[:, 0])
        np.multiply(e, e, out=T[:, 1])
        np.multiply(e, e.conj(), out=T[:, 2])  # |w|², imaginary part exactly 0
        S = T @ self.Pw  # (record, table, [Σ j^p F_j, Σ b^p W_b])
        WF = S[:, :, 3:, None] * S[:, :, None, :3]
        mom = WF.reshape(r, 3, 9) @ self.Cm  # (record, table, p): Σ_n n^p w_t^n, padded
        # the last block's padding j ≥ j0: its partial sums, times that block's W
        Wl = T[:, :, -1] if self.full else T[np.arange(r), :, B + self.last[idx]]
        mom -= Wl[:, :, None] * (T[:, :, :B] @ self.PadC[sel])
        K5 = (mom.view(float).reshape(r, 18) @ self.Amap).reshape(r, 5, 5)
        K5[:, 0, 0] = self.n[sel]
        s0, s1 = self._data(idx, F, W)
        dt = self.dt
        Gx5 = np.empty((r, 5))
        Gx5[:, 0] = self.sx[sel]
        Gc = Gx5[:, 1:].view(complex)
        Gc[:, 0] = s0
        np.multiply(s1, dt, out=Gc[:, 1])
        zh = None
        if self.kc:
            # w^n = W_b F_j (n = bB + j) over the fast columns' span
            nfm = self.nfmax
            zh = (W[:, : -(-nfm // B), None] * F[:, None, :]).reshape(r, -1)[:, :nfm]
        return K5, Gx5, {"F": F, "W": W}, zh

    def residual(self, idx, pt):
        """Residuals r (m, one array per record, sample by sample, no cancellation) and G r at
        the points ``pt``, formed in blocks (a C + b S = Re((a − ib) W_b F_j)), record by
        record (each record's arrays stay in cache)."""
        beta, F, W = pt["beta"], pt["F"], pt["W"]
        coef = beta[:, 1] - 1j * beta[:, 2]
        B, r = self.B, idx.size
        rs: list[np.ndarray] = []
        Pm = np.zeros((r, self.nbmax, 2), complex)
        Gr = np.empty((r, self.m))
        # (F_j, j F_j) per record, for the block products of the residual
        Fm = np.empty((r, B, 2), complex)
        Fm[:, :, 0] = F
        np.multiply(self.j, F, out=Fm[:, :, 1])
        Fv = Fm.view(float)
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            for k, i in enumerate(idx.tolist()):
                n, nb = int(self.n[i]), int(self.nb[i])
                # Re((a − ib) W_b F_j) as one rank-2 real product, then x − it − x_off
                wc = W[k, :nb] * coef[k]
                wv = np.empty((nb, 2))
                wv[:, 0] = wc.real
                np.negative(wc.imag, out=wv[:, 1])
                R = wv @ F[k].view(float).reshape(B, 2).T
                np.subtract(self.X[i, :nb], R, out=R)
                R -= beta[k, 0]
                flat = R.reshape(-1)
                flat[n:] = 0.0  # the padding stays out of every sum
                r_ = flat[:n]
                if self.kc:
                    c = self.cols[i]
                    r_[: c.shape[1]] -= beta[k, 3:] @ c
                    Gr[k, 5:] = c @ r_[: c.shape[1]]
                np.matmul(R, Fv[k], out=Pm[k, :nb].view(float))
                Gr[k, 0] = r_.sum()
                rs.append(r_)
            s0, s1 = self._sums(Pm, W)
        Gc = Gr[:, 1:5].view(complex)
        Gc[:, 0] = s0
        np.multiply(s1, self.dt, out=Gc[:, 1])
        return rs, Gr


@functools.lru_cache(maxsize=64)
def _padding(B: int, nbmax: int, ns: tuple[int, ...]):
    """The padding of a :class:`TableStack` of records of ``ns`` samples in blocks of B:
    which blocks are a record's own (record, block), each record's last block, the map from
    the table F to the sums Σ j^p F_j over the last block's padding j ≥ j0 shifted to
    n = (nb − 1)B + j (record, j, p), and whether no record has padding blocks."""
    n = np.array(ns)
    nb = -(-n // B)
    R = n.size
    b = np.arange(nbmax)
    j = np.arange(B)
    bvalid = b[None, :] < nb[:, None]
    j0 = n - (nb - 1) * B  # first padding index of each record's last block
    padmask = (j[None, :] >= j0[:, None]).astype(float)
    bB = ((nb - 1) * B).astype(float)
    Cpad = np.zeros((R, 3, 3), complex)
    Cpad[:, 0, 0] = Cpad[:, 1, 1] = Cpad[:, 2, 2] = 1.0
    Cpad[:, 0, 1] = bB
    Cpad[:, 0, 2] = bB * bB
    Cpad[:, 1, 2] = 2.0 * bB
    jpow = np.stack((np.ones(B), j, j * j), axis=1)
    PadC = (padmask[:, :, None] * jpow[None, :, :]) @ Cpad
    last = nb - 1
    for arr in (bvalid, last, PadC):
        arr.setflags(write=False)
    return bvalid, last, PadC, bool((nb == nbmax).all())


class DirectStack(Stack):
    """Records of any sampling: the basis e^{sτ} is formed sample by sample, per record over
    its own τ (s) (zero-padded to the longest record; the padding is masked out of every sum).
    """

    def __init__(self, taus: Sequence[np.ndarray], xs: Sequence[np.ndarray],
                 roots: Sequence[np.ndarray]):
        n = np.array([x.size for x in xs])
        nmax = int(n.max())
        super().__init__(taus, xs, roots, nmax, None)
        T = np.zeros((self.R, nmax))
        for i, tau in enumerate(taus):
            T[i, : tau.size] = tau
        self.T = T
        self.mask = (np.arange(nmax)[None, :] < n[:, None]).astype(float)

    def _like(self, taus, xs, roots):
        return DirectStack(taus, xs, roots)

    def _base(self, idx, sig, om):
        r = idx.size
        T = self.T if r == self.R else self.T[idx]
        mask = self.mask if r == self.R else self.mask[idx]
        z = np.exp((-sig + 1j * om)[:, None] * T)
        z *= mask  # (the padding's τ = 0: e^{sτ} = 1 there, never overflows)
        G = np.empty((r, 5, T.shape[1]))
        G[:, 0] = mask
        G[:, 1] = z.real
        G[:, 2] = z.imag
        np.multiply(T, G[:, 1], out=G[:, 3])
        np.multiply(T, G[:, 2], out=G[:, 4])
        X = self.flat if r == self.R else self.flat[idx]
        K5 = G @ G.transpose(0, 2, 1)
        Gx5 = (G @ X[:, :, None])[:, :, 0]
        zh = z[:, : self.nfmax] if self.kc else None
        return K5, Gx5, {}, zh

    def residual(self, idx, pt):
        """Residuals r (m, one array per record, sample by sample) and G r at the points
        ``pt``, record by record."""
        beta = pt["beta"]
        rs: list[np.ndarray] = []
        Gr = np.empty((idx.size, self.m))
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            for k, i in enumerate(idx.tolist()):
                tau, x = self.taus[i], self.xs[i]
                z = np.exp(complex(-pt["sig"][k], pt["om"][k]) * tau)
                C, S = z.real, z.imag
                r = x - (beta[k, 0] + beta[k, 1] * C + beta[k, 2] * S)
                if self.kc:
                    c = self.cols[i]
                    r[: c.shape[1]] -= beta[k, 3:] @ c
                    Gr[k, 5:] = c @ r[: c.shape[1]]
                tr = tau * r
                Gr[k, :5] = (r.sum(), C @ r, S @ r, C @ tr, S @ tr)
                rs.append(r)
        return rs, Gr


@functools.lru_cache(maxsize=32)
def table_constants(B: int, nb: int, dt: float):
    """Per-shape constants of :class:`TableStack` (cached: every record of a set shares them)."""
    # j^p and b^p, p = 0, 1, 2, from one table of the larger range
    m = max(B, nb)
    pw = np.empty((m, 3))
    pw[:, 0] = 1.0
    pw[:, 1] = np.arange(m, dtype=float)
    np.multiply(pw[:, 1], pw[:, 1], out=pw[:, 2])
    jpow, bpow = pw[:B], pw[:nb]
    j, b = jpow[:, 1], bpow[:, 1]
    # exponents of one table [F_j; W_b] = e^{s dt [j; B b]} and its power sums in one
    # product: Pw is block diagonal (j^p on the first B rows, b^p on the next nb)
    jb = np.concatenate((j, B * b))
    Pw = np.zeros((B + nb, 6), complex)
    Pw[:B, :3] = jpow
    Pw[B:, 3:] = bpow
    # Σ_n n^p w^n = Σ_{p_b, p_j} c · (Σ_b b^{p_b} W_b)(Σ_j j^{p_j} F_j), n = bB + j
    Cm = np.zeros((3, 3, 3))
    Cm[0, 0, 0] = 1.0
    Cm[1, 0, 1], Cm[0, 1, 1] = B, 1.0
    Cm[2, 0, 2], Cm[1, 1, 2], Cm[0, 2, 2] = B * B, 2.0 * B, 1.0
    Cm = Cm.reshape(9, 3).astype(complex)
    bB = float((nb - 1) * B)
    Cpad = np.array([[1.0, bB, bB * bB], [0.0, 1.0, 2.0 * bB], [0.0, 0.0, 1.0]], complex)
    # K (flattened 5 × 5) as a linear map of the moments' real and imaginary parts,
    # index 6p + 2t + c for moment p of table t (w = e^{s dt}, e^{2s dt}, e^{−2σ dt}), part c
    A = np.zeros((25, 18))

    def put(i, k, terms):
        for coef, p_, t_, c_ in terms:
            A[5 * i + k, 6 * p_ + 2 * t_ + c_] = coef
            A[5 * k + i, 6 * p_ + 2 * t_ + c_] = coef

    h, h1, h2 = 0.5, 0.5 * dt, 0.5 * dt * dt
    put(0, 1, [(1.0, 0, 0, 0)])
    put(0, 2, [(1.0, 0, 0, 1)])
    put(0, 3, [(dt, 1, 0, 0)])
    put(0, 4, [(dt, 1, 0, 1)])
    put(1, 1, [(h, 0, 2, 0), (h, 0, 1, 0)])
    put(1, 2, [(h, 0, 1, 1)])
    put(1, 3, [(h1, 1, 2, 0), (h1, 1, 1, 0)])
    put(1, 4, [(h1, 1, 1, 1)])
    put(2, 2, [(h, 0, 2, 0), (-h, 0, 1, 0)])
    put(2, 3, [(h1, 1, 1, 1)])
    put(2, 4, [(h1, 1, 2, 0), (-h1, 1, 1, 0)])
    put(3, 3, [(h2, 2, 2, 0), (h2, 2, 1, 0)])
    put(3, 4, [(h2, 2, 1, 1)])
    put(4, 4, [(h2, 2, 2, 0), (-h2, 2, 1, 0)])
    # the same map for the moments laid out (table t, power p, part c): index 6t + 2p + c,
    # transposed for a right product
    At = np.ascontiguousarray(A.reshape(25, 3, 3, 2).transpose(0, 2, 1, 3).reshape(25, 18).T)
    out = (jpow, bpow, j, b, jb, Pw, Cm, Cpad, At)
    for arr in out:
        arr.setflags(write=False)
    return out


def fast_columns(taus: Sequence[np.ndarray], roots: Sequence[np.ndarray], dt: float | None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The fast-mode columns of R records with the same number kc of columns, stacked with
    τ times them: (R, 2 kc, nf_max), zero beyond each record's own nf samples, and nf (R,).

    A real root r (1/s) gives the column e^{rτ}, a complex one the real and imaginary parts of
    e^{rτ}, τ = t − t₀ (s), over the samples where some column is above 10⁻¹⁶ of its start
    (τ ≤ 37/min(−Re r)). With ``dt`` (uniform sampling, τ = n dt) a complex root over more
    than 256 samples is tabulated, e^{r dt (64 b + j)} = W_b F_j; else every entry is one
    exponential. An entry does not depend on the other records of the stack."""
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
                (tab if nf[i] > 256 and dt is not None else direct).append((i, col, z))
                col += 2
            else:
                real.append((i, col, z.real))
                col += 1
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        if tab:
            ii, cc, zz = (np.array(v) for v in zip(*tab, strict=True))
            ls = zz * float(dt)  # type: ignore[arg-type]
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


def solve_each(A: np.ndarray, y: np.ndarray) -> np.ndarray:
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


def inv_each(A: np.ndarray) -> np.ndarray:
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
