r"""Coulomb friction (stick–slip) on the exact propagation, vectorised over the runs.

With f_c > 0 the exact propagation of :mod:`phoid.simulation._propagation` is used while the
mass slides (the friction force −f_c·s, s = ±1, is a constant added to the force polynomial).
After each block's trial propagation, the first step whose end velocity has the wrong sign is
located for every run, and inside that step the zero crossing of ẋ is found by a safeguarded
Newton iteration on the step's exact Taylor expansion (the step solution is entire; its series
is summed to rounding level). At ẋ = 0 the mass **sticks** if the sum g of all other forces
(spring, feedback, external) satisfies |g| ≤ f_c (static = kinetic = f_c), otherwise it
continues in the direction of g. While stuck, x is frozen and g is monitored (at 8 points per
step, then by root finding) until |g| > f_c; the mass then slides off in the direction of g.
All of this is vectorised over the runs; Python iterates per block and per friction event,
never per sample. With Δt = 0 the stick–slip motion is exact up to rounding (events located to
~1e−15 s). With Δt > 0, a step that contains an event is handed on to the delayed input of the
step Δt later through its exact one-sided end values, and the kink inside it is interpolated
across: a local error O(h²) per event.

The same bookkeeping locates the velocity reversals for the DC-offset bias (see
:mod:`phoid.simulation._continuous` and :mod:`phoid.simulation._sampled`), with f_c = 0 where
there is no friction.
"""

from __future__ import annotations

import numpy as np

from phoid.simulation._propagation import NQ, Engine, horner, poly_deriv, shift

__all__ = ["Friction", "friction_block", "initial_mode"]

_N_PROBE = 8  # probes per step when looking for velocity sign changes / unsticking


class Friction:
    """Stick–slip bookkeeping for one block of L steps (see the module docstring)."""

    def __init__(self, eng: Engine, grp: np.ndarray, fc: float,
                 fk: np.ndarray | None = None):
        self.eng = eng
        self.grp = grp
        self.fc = fc  # static threshold: the mass sticks while |g| ≤ f_c
        # force opposing a sliding mass, per run: f_c, less an undelayed bias b (Δt = 0, where
        # b sign(ẋ(t)) acts with the friction); the delayed bias enters through the steps' force
        self.fk = np.full(grp.size, fc) if fk is None else np.asarray(fk, dtype=float)
        self.A10 = eng.A[:, 1, 0]  # per group: g = f + m A10 x at v = 0
        self.probe = np.arange(1, _N_PROBE + 1) / _N_PROBE

    # ---- helpers -----------------------------------------------------------------------------
    def g_at(self, b, cb, xs, sig):
        """Sum of the non-friction forces at v = 0, x = xs: f(σ) − (k [+P]) xs."""
        return horner(cb, sig) + self.eng.m * self.A10[self.grp[b]] * xs

    def decide(self, b, cb, xs, sig):
        """Mode after ẋ reaches 0 at σ: 0 (stick) or ±1 (slide in the direction of g)."""
        g = self.g_at(b, cb, xs, sig)
        return np.where(np.abs(g) <= self.fc, 0, np.sign(g)).astype(np.int64)

    def stuck_coeffs(self, b, xs):
        c = np.zeros((b.size, NQ))
        c[:, 0] = -self.eng.m * self.A10[self.grp[b]] * xs
        return c

    # ---- root finding on polynomials in δ ∈ [lo, hi] --------------------------------------------
    @staticmethod
    def _root(coef, lo, hi, target=0.0):
        """A root of p(δ) = target in [lo, hi] where p(lo) − target, p(hi) − target differ in sign
        (or p(hi) = target). Safeguarded Newton; vectorised; coef (n, K)."""
        dcoef = poly_deriv(coef)
        flo = horner(coef, lo) - target
        x = 0.5 * (lo + hi)
        lo, hi = lo.copy(), hi.copy()
        for _ in range(100):
            fx = horner(coef, x) - target
            same = np.sign(fx) == np.sign(flo)
            lo = np.where(same, x, lo)
            flo = np.where(same, fx, flo)
            hi = np.where(same, hi, x)
            dfx = horner(dcoef, x)
            with np.errstate(all="ignore"):
                xn = x - fx / dfx
            bad = ~np.isfinite(xn) | (xn <= lo) | (xn >= hi)
            xn = np.where(bad, 0.5 * (lo + hi), xn)
            done = np.abs(xn - x) <= 1e-15 * np.maximum(1.0, np.abs(x))
            x = xn
            if np.all(done | (hi - lo <= 4e-16)):
                break
        return x

    # ---- sub-step resolution -------------------------------------------------------------------
    def resolve(self, b, cb, sig, y, mode, xs, pieces, seg=None):
        """Finish the steps of runs ``b`` from σ = ``sig`` (state ``y``, ``mode``) to σ = 1.

        cb (n, 6): base force polynomials of those steps. ``pieces``: one list per run that
        receives (σ_start, σ_end, mode, y_start, xs, bias) tuples. ``seg``: optional
        (ends (n, K + 1), values (n, K + 1)): the step is cut at σ = ends[:, j] (the last 1),
        and the constant ``values[:, j]`` (N, the delayed bias) is added to the force of
        segment j; a piece never crosses a cut. Returns y(1), mode, xs.
        """
        eng = self.eng
        y = y.copy()
        sig = sig.copy()
        mode = mode.copy()
        xs = xs.copy()
        yend = np.empty_like(y)
        n = b.size
        if seg is None:
            ends, vals = np.ones((n, 1)), np.zeros((n, 1))
        else:
            ends, vals = seg
        si = np.zeros(n, dtype=np.int64)  # current segment of each run
        todo = np.arange(n)
        for _ in range(64 + 2 * ends.shape[1]):
            if todo.size == 0:
                break
            nxt = []
            # -- stuck
            st = todo[mode[todo] == 0]
            if st.size:
                send, bz = ends[st, si[st]], vals[st, si[st]]
                cbs = cb[st].copy()
                cbs[:, 0] += bz
                span = send - sig[st]
                probe0 = np.concatenate([[0.0], self.probe])
                s_probe = sig[st, None] + span[:, None] * probe0[None, :]
                g = self.g_at(b[st, None], cbs[:, None, :], xs[st, None], s_probe)
                over = np.abs(g) > self.fc
                anyo = over.any(axis=1)
                for i in np.flatnonzero(~anyo):
                    r = st[i]
                    pieces[r].append((sig[r], send[i], 0, y[r].copy(), xs[r], bz[i]))
                    if send[i] >= 1.0:
                        yend[r] = (xs[r], 0.0)
                    else:  # on into the next segment, still stuck
                        sig[r] = send[i]
                        si[r] += 1
                        nxt.append(np.array([r]))
                hit = st[anyo]
                if hit.size:
                    q = np.argmax(over[anyo], axis=1)
                    s_hi = s_probe[anyo, q]
                    s_lo = np.where(q > 0, s_probe[anyo, np.maximum(q - 1, 0)], sig[hit])
                    direction = np.sign(g[anyo, q])
                    coef = cbs[anyo]
                    coef[:, 0] += eng.m * self.A10[self.grp[b[hit]]] * xs[hit]
                    s_un = np.where(
                        q > 0, self._root(coef, s_lo, s_hi, target=direction * self.fc), s_hi
                    )
                    for i, r in enumerate(hit):
                        pieces[r].append((sig[r], s_un[i], 0, y[r].copy(), xs[r], bz[anyo][i]))
                    sig[hit] = s_un
                    y[hit] = np.stack([xs[hit], np.zeros(hit.size)], axis=1)
                    mode[hit] = direction.astype(np.int64)
                    nxt.append(hit)
            # -- sliding
            sl = todo[mode[todo] != 0]
            if sl.size:
                send, bz = ends[sl, si[sl]], vals[sl, si[sl]]
                s = mode[sl].astype(float)
                cbs = cb[sl].copy()
                cbs[:, 0] += bz
                cw = cbs.copy()
                cw[:, 0] -= self.fk[b[sl]] * s
                q = shift(cw, sig[sl])
                a = eng.taylor(eng.A[self.grp[b[sl]]], y[sl], q)  # (n, nt, 2)
                span = send - sig[sl]
                dl = span[:, None] * self.probe[None, :]
                vv = horner(a[:, None, :, 1], dl)  # (n, probes)
                cross = s[:, None] * vv <= 0.0
                anyc = cross.any(axis=1)
                for i in np.flatnonzero(~anyc):
                    r = sl[i]
                    pieces[r].append((sig[r], send[i], int(mode[r]), y[r].copy(), xs[r], bz[i]))
                    ye = [horner(a[i, :, 0], span[i]), horner(a[i, :, 1], span[i])]
                    if send[i] >= 1.0:
                        yend[r] = ye
                    else:  # on into the next segment, still sliding
                        y[r] = ye
                        sig[r] = send[i]
                        si[r] += 1
                        nxt.append(np.array([r]))
                hit_i = np.flatnonzero(anyc)
                if hit_i.size:
                    qi = np.argmax(cross[hit_i], axis=1)
                    d_hi = dl[hit_i, qi]
                    d_lo = np.where(qi > 0, dl[hit_i, np.maximum(qi - 1, 0)], 0.0)
                    dstar = self._root(a[hit_i, :, 1], d_lo, d_hi)
                    hit = sl[hit_i]
                    xstar = horner(a[hit_i, :, 0], dstar)
                    s_new = sig[hit] + dstar
                    for i, r in enumerate(hit):
                        pieces[r].append((sig[r], s_new[i], int(mode[r]), y[r].copy(), xs[r],
                                          bz[hit_i[i]]))
                    newmode = self.decide(b[hit], cbs[hit_i], xstar, s_new)
                    stalled = (dstar <= 1e-13) & (newmode == mode[hit])
                    newmode = np.where(stalled, 0, newmode)  # no progress: the mass sticks
                    sig[hit] = s_new
                    y[hit] = np.stack([xstar, np.zeros(hit.size)], axis=1)
                    xs[hit] = xstar
                    mode[hit] = newmode
                    at_end = s_new >= send[hit_i] - 1e-14  # the reversal ends the segment
                    for i in np.flatnonzero(at_end):
                        r = hit[i]
                        pieces[r][-1] = (*pieces[r][-1][:1], send[hit_i[i]], *pieces[r][-1][2:])
                        sig[r] = send[hit_i[i]]
                    done = at_end & (send[hit_i] >= 1.0)
                    for r in hit[done]:
                        yend[r] = y[r]
                    si[hit[at_end & ~done]] += 1
                    nxt.append(hit[~done])
            todo = np.concatenate(nxt) if nxt else np.zeros(0, dtype=np.int64)
        else:  # pragma: no cover - chattering beyond 64 events in one step
            raise RuntimeError("friction events did not resolve within one step")
        return yend, mode, xs

    # ---- one block ---------------------------------------------------------------------------
    def block(self, cb, y0, mode, xs, cuts=None):
        """Advance all runs over the block's L steps (cb: (B, L, 6) base force polynomials).

        ``cuts``: optional {(run, step): (σ cuts (K,), bias values (K + 1,))}: steps inside
        which the delayed bias switches (their cb holds no bias; :meth:`resolve` cuts them).
        """
        eng = self.eng
        B, L, _ = cb.shape
        cuts = cuts or {}
        forced = np.zeros((B, L), dtype=bool)
        for r, st in cuts:
            forced[r, st] = True
        Y = np.empty((B, L + 1, 2))
        Y[:, 0] = y0
        ce = np.empty((B, L, NQ))
        splits: dict[tuple[int, int], list] = {}
        pos = np.zeros(B, dtype=np.int64)
        mode = mode.copy()
        xs = xs.copy()
        cur = y0.copy()
        for _ in range(100 * L + 100):
            act = pos < L
            if not act.any():
                break
            # ---------------- stuck runs: find the first step where |g| exceeds f_c
            st = np.flatnonzero(act & (mode == 0))
            if st.size:
                Lw = int(L - pos[st].min())
                idx = pos[st, None] + np.arange(Lw)[None, :]
                valid = idx < L
                idc = np.minimum(idx, L - 1)
                cw = cb[st[:, None], idc]  # (n, Lw, 6)
                s_probe = np.concatenate([[0.0], self.probe])
                g = horner(cw[:, :, None, :], s_probe[None, None, :])
                g = g + (eng.m * self.A10[self.grp[st]] * xs[st])[:, None, None]
                over = ((np.abs(g) > self.fc).any(axis=2) | forced[st[:, None], idc]) & valid
                anyo = over.any(axis=1)
                first = np.where(anyo, np.argmax(over, axis=1), Lw)
                for i, r in enumerate(st):
                    p0, n_st = pos[r], min(first[i], L - pos[r])
                    Y[r, p0 + 1 : p0 + n_st + 1] = (xs[r], 0.0)
                    ce[r, p0 : p0 + n_st] = self.stuck_coeffs(np.array([r]), xs[r : r + 1])
                    pos[r] = p0 + n_st
                ev = st[anyo]
                if ev.size:
                    self._event_steps(ev, cb, Y, ce, pos, mode, xs, splits, cuts)
            # ---------------- sliding runs: trial propagation to the block end
            sl = np.flatnonzero((pos < L) & (mode != 0))
            for gi in np.unique(self.grp[sl]) if sl.size else ():
                rows = sl[self.grp[sl] == gi]
                Lw = int(L - pos[rows].min())
                idx = pos[rows, None] + np.arange(Lw)[None, :]
                valid = idx < L
                idc = np.minimum(idx, L - 1)
                cw = cb[rows[:, None], idc].copy()
                cw[:, :, 0] -= (self.fk[rows] * mode[rows])[:, None]
                w = np.matmul(eng.K[gi], np.moveaxis(cw, 1, 2))
                cur = Y[rows, pos[rows]]
                Yw = np.moveaxis(eng.recur(gi, cur, w), 1, 2)
                bad = ((mode[rows, None] * Yw[:, 1:, 1] <= 0.0) | forced[rows[:, None], idc]) \
                    & valid
                anyb = bad.any(axis=1)
                first = np.where(anyb, np.argmax(bad, axis=1), Lw)
                for i, r in enumerate(rows):
                    p0, n_ok = pos[r], min(first[i], L - pos[r])
                    Y[r, p0 + 1 : p0 + n_ok + 1] = Yw[i, 1 : n_ok + 1]
                    ce[r, p0 : p0 + n_ok] = cw[i, :n_ok]
                    pos[r] = p0 + n_ok
                ev = rows[anyb]
                if ev.size:
                    self._event_steps(ev, cb, Y, ce, pos, mode, xs, splits, cuts)
        return Y, ce, splits, mode, xs

    def _event_steps(self, ev, cb, Y, ce, pos, mode, xs, splits, cuts):
        """Resolve step pos[r] of each run r in ``ev`` (it contains an event, or a switch of
        the delayed bias listed in ``cuts``) and advance pos."""
        e = pos[ev]
        cbe = cb[ev, e]
        pieces: list[list] = [[] for _ in ev]
        y0 = Y[ev, e]
        seg = None
        if cuts:
            K = 1 + max((cuts[(int(r), int(st))][0].size for r, st in zip(ev, e, strict=True)
                         if (int(r), int(st)) in cuts), default=0)
            ends, vals = np.ones((ev.size, K)), np.zeros((ev.size, K))
            for i, (r, st) in enumerate(zip(ev, e, strict=True)):
                cut = cuts.get((int(r), int(st)))
                if cut is not None:
                    nk = cut[0].size
                    ends[i, :nk] = cut[0]
                    vals[i, : nk + 1] = cut[1]
                    vals[i, nk + 1 :] = cut[1][-1]
            seg = (ends, vals)
        yend, mnew, xsnew = self.resolve(ev, cbe, np.zeros(ev.size), y0, mode[ev], xs[ev], pieces,
                                         seg)
        Y[ev, e + 1] = yend
        mode[ev] = mnew
        xs[ev] = xsnew
        for i, r in enumerate(ev):
            pc = pieces[i]
            if len(pc) == 1 and pc[0][2] != 0:
                # no event after all (rounding): an ordinary sliding step
                ce[r, e[i]] = cbe[i] - np.array([self.fk[r] * pc[0][2], 0, 0, 0, 0, 0])
            elif len(pc) == 1:
                ce[r, e[i]] = self.stuck_coeffs(np.array([r]), np.array([pc[0][4]]))[0]
            else:
                ce[r, e[i]] = np.nan  # never used: split steps are described by `splits`
                splits[(int(r), int(e[i]))] = pc
        pos[ev] = e + 1

    # ---- derivative data and dense output of a split step ----------------------------------
    def piece_state(self, r, cb_step, piece, sig):
        """State at σ (inside ``piece``) of run r; cb_step the step's base polynomial."""
        s0, _s1, md, y0, x_s, bz = piece
        if md == 0:
            return np.array([x_s, 0.0])
        cw = cb_step.copy()
        cw[0] += bz - self.fk[r] * md
        q = shift(cw[None, :], np.array([s0]))
        a = self.eng.taylor(self.eng.A[self.grp[[r]]], y0[None, :], q)[0]
        dl = sig - s0
        return np.array([horner(a[:, 0], dl), horner(a[:, 1], dl)])

    def end_derivs(self, r, cb_step, piece, sig):
        """(y, y', y'') at σ inside ``piece`` (one-sided), flattened to 6 numbers."""
        _, _, md, _, x_s, bz = piece
        if md == 0:
            return np.array([x_s, 0.0, 0.0, 0.0, 0.0, 0.0])
        A = self.eng.A[self.grp[r]]
        bvec = np.array([0.0, 1.0 / self.eng.m])
        cw = cb_step.copy()
        cw[0] += bz - self.fk[r] * md
        y = self.piece_state(r, cb_step, piece, sig)
        f = horner(cw, sig)
        fp = horner(poly_deriv(cw), sig) / self.eng.h
        y1 = A @ y + bvec * f
        y2 = A @ y1 + bvec * fp
        return np.concatenate([y, y1, y2])


def initial_mode(fr: Friction, y: np.ndarray, f0: np.ndarray) -> np.ndarray:
    """Friction mode at release: the sign of v₀, or the stick test at ẋ = 0 when v₀ = 0."""
    mode = np.sign(y[:, 1]).astype(np.int64)
    b = np.flatnonzero(mode == 0)
    if b.size:
        mode[b] = fr.decide(b, f0[b], y[b, 0], np.zeros(b.size))
    return mode


def friction_block(fr: Friction, cb, y, mode, xs, cuts=None):
    """Friction block in the component-major layout of the drivers."""
    Y, ce, splits, mode, xs = fr.block(np.moveaxis(cb, 1, 2), y, mode, xs, cuts)
    return np.moveaxis(Y, 2, 1), np.moveaxis(ce, 2, 1), splits, mode, xs
