"""Release detection and the fitted window: when the held mass is let go, the held segment's
noise, and the checks a record must pass before any fit.

A record (t s, x m) starts with the mass held at a level; after its release it rings. The
release is found from the data (:func:`locate_release`): the departure from the held level, its
quadratic change point (the mass starts from rest) and a refinement with an even quartic.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from phoid import _validate as v
from phoid.fits.result import MIN_SAMPLES

__all__ = [
    "Clipping",
    "RecordStart",
    "check_record",
    "classify_start",
    "detect_release",
    "diff_noise",
    "find_clipping",
    "hold_sd",
    "impulse_peak_time",
    "locate_release",
    "med",
    "releases",
    "window",
]

#: release detection: the signal has left the held level when it is this many noise sds away
_RELEASE_NSD = 8.0


def check_record(t: ArrayLike, x: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``t`` (s) and ``x`` (m) as float64 arrays, checked for every fit: finite, 1-D, the same
    length, at least ``MIN_SAMPLES`` samples, t strictly increasing, x not constant, no
    magnitude beyond 1e100. Raises ValueError naming the argument and value otherwise."""
    t = v.finite_array("t", t, ndim=1)
    x = v.finite_array("x", x, ndim=1)
    if t.shape != x.shape:
        raise ValueError(f"`t` and `x` must have the same length; got {t.size} and {x.size}")
    if t.size < MIN_SAMPLES:
        raise ValueError(f"`x` must hold at least {MIN_SAMPLES} samples; got {t.size}")
    if not (t[1:] > t[:-1]).all():
        i = int(np.argmin(t[1:] > t[:-1]))
        raise ValueError(
            f"`t` must be strictly increasing; got t[{i}] = {t[i]:.9g} s, "
            f"t[{i + 1}] = {t[i + 1]:.9g} s"
        )
    if not x.max() > x.min():
        raise ValueError(f"`x` is constant ({x[0]:g} m): no motion to analyse")
    for name, a, unit in (("t", t, "s"), ("x", x, "m")):
        big = max(abs(float(a[0])), abs(float(a[-1])), float(np.abs(a).max()))
        if big > _MAX_MAGNITUDE:
            raise ValueError(f"`{name}` reaches {big:.3g} {unit}: beyond any record the fit "
                             f"can square without overflow (is it in {unit}?)")
    return t, x


# |t|, |x| beyond this overflow the fits' sums of squares (1e100² · samples ≪ 1.8e308) and are
# no position in m, or time in s, a rig records
_MAX_MAGNITUDE = 1e100


def med(a: np.ndarray) -> float:
    """Median (the upper middle value for an even count): cheaper than np.median."""
    k = a.size // 2
    return float(np.partition(a, k)[k])


def diff_noise(x: np.ndarray) -> float:
    """Robust white-noise sd from second differences (MAD; var Δ²x = 6 sd² for white noise).

    A smooth signal sampled fast contributes ~A(ω dt)² per difference, negligible at ≥ ~20
    samples per period against noise of a few parts in 10⁴ of the amplitude.
    """
    if x.size < 3:
        return 0.0
    d1 = x[1:] - x[:-1]  # np.diff(x, 2), without its per-call overhead
    d2 = d1[1:] - d1[:-1]
    mad = med(np.abs(d2 - med(d2)))
    if mad > 0:
        return 1.4826 * mad / math.sqrt(6.0)
    # quantised or noise-free records: most differences are exactly 0
    return float(np.sqrt(np.mean(d2 * d2) / 6.0))


# --------------------------------------------------------------------------------------------
# release


def hold_sd(x: np.ndarray, j: int) -> float | None:
    """sd of the held segment x[:j+1], if it has ≥ 10 samples and looks held (its sd is not
    above 1.5 times its second-difference noise: no motion)."""
    if j < 10:
        return None
    seg = x[: j + 1]
    d = seg - seg.sum() / seg.size  # np.std(seg, ddof=1), the same sums, fewer calls
    sd = math.sqrt(float(np.add.reduce(d * d)) / (seg.size - 1))
    return sd if sd <= 1.5 * diff_noise(seg) + 1e-300 else None


@dataclass(frozen=True)
class _Departure:
    """The release detection's first stage on one record: the held level (m), the threshold
    (m), the first sample ``i1`` from which the signal stays beyond it for 3 samples (None when
    there is none, or it is among the first 3), the prefix length searched, and the first
    sample the change point may take (0 but where the held noise is coloured), and whether it
    is (the threshold and level then come from the held segment's own sd and median)."""

    level: float
    thr: float
    i1: int | None
    m_search: int
    first: int = 0
    coloured: bool = False


def _departure(x: np.ndarray) -> _Departure:
    """The first sample from which x stays more than 8 noise sds from its held level for 3
    samples (a lone spike is no release), searched in growing prefixes."""
    n = x.size
    sd = diff_noise(x[:2048])
    n0 = max(3, min(20, n // 50))
    level = med(x[:n0])
    thr = max(_RELEASE_NSD * sd, 1e-6 * (float(x.max()) - float(x.min())))
    m_search = 2048
    while True:
        out = np.abs(x[:m_search] - level) > thr
        hits = np.flatnonzero(out[:-2] & out[1:-1] & out[2:])
        if hits.size or m_search >= n:
            break
        m_search *= 4
    m_search = min(m_search, n)
    i1 = int(hits[0]) if hits.size else None
    if i1 is not None and i1 > 2:
        # (a departure among the first 3 samples stays the record starting in motion: a
        # segment of smooth motion would pass for coloured noise below)
        moved = _lasting_departure(x, level, thr, i1)
        if moved != i1:
            i1, m_search = moved, n
        held = _coloured_hold(x, level, thr)
        if held is not None and _RELEASE_NSD * held[1] > thr:
            # the held segment's noise is coloured: its own sd sets the threshold and its
            # median the level; the departure is searched again with them
            level, thr, m_search = held[0], _RELEASE_NSD * held[1], n
            out = np.abs(x - level) > thr
            hits = np.flatnonzero(out[:-2] & out[1:-1] & out[2:])
            i1 = (_lasting_departure(x, level, thr, int(hits[0]))
                  if hits.size and hits[0] > 2 else None)
            if i1 is not None:
                # the change point is sought near the departure only: on a long stretch of
                # coloured noise the least-squares quadratic follows its slow wander. From rest
                # the signal takes about as long to the threshold as from there to 4 of them
                # (sample i2): 4 (i2 − i1) samples back (at least 16) hold the release
                far = np.flatnonzero(np.abs(x[i1:] - level) > 4.0 * thr)
                rise = int(far[0]) if far.size else i1
                first = max(0, i1 - max(4 * rise, 16))
                return _Departure(level, thr, i1, m_search, first, coloured=True)
    return _Departure(level, thr, i1 if i1 is not None and i1 > 2 else None, m_search)


#: a held segment whose sd exceeds its second-difference (white-noise) sd this many times holds
#: coloured noise (as :func:`hold_sd` calls a segment not held)
_COLOURED_RATIO = 1.5
#: … and moves rather than wanders where its sd exceeds its second-difference sd this many
#: times (AR(1) noise: about 4 at ρ = 0.9, 5.4 at 0.95, 12 at 0.99; smooth motion sampled
#: finely: hundreds and more)
_MOTION_RATIO = 20.0


def _coloured_hold(x: np.ndarray, level: float, thr: float) -> tuple[float, float] | None:
    """The held level (median) and sd of the segment before the release when its noise is
    coloured: its sd above 1.5 times its second-difference sd, which white noise of ≥ 16
    samples does not reach, yet below 20 times (smooth motion: a record that starts moving),
    and 8 sds short of the release's swing. None otherwise (white noise, fewer than 16 held
    samples, a segment that moves, or no excursion far from the level).

    The segment is found from the release's first swing, not from the departure (coloured
    noise crosses the white-noise threshold in the held segment itself): the first sample
    ``g`` a quarter of the largest excursion from ``level`` (at least 4 ``thr``), and the last
    sample ``h`` before it within a sixteenth of the excursion. From rest the signal leaves
    the level quadratically, so it takes about as long from the release to ``h`` as from ``h``
    to ``g``; the segment ends 3 (g − h) samples before ``g``.
    """
    dev = np.abs(x - level)
    far = max(4.0 * thr, _GONE * float(dev.max()))
    gone = np.flatnonzero(dev >= far)
    if not gone.size:
        return None
    g = int(gone[0])
    near = np.flatnonzero(dev[:g] < 0.25 * far)
    if not near.size:
        return None
    h = int(near[-1]) + 1
    seg = x[: max(g - 3 * (g - h), 0)]
    if seg.size < 16:
        return None
    sd = float(np.std(seg, ddof=1))
    white = diff_noise(seg)
    if not (_COLOURED_RATIO * white < sd < _MOTION_RATIO * white and _RELEASE_NSD * sd < far):
        return None
    return med(seg), sd


#: a departure is the release only if the signal then goes this fraction of the record's
#: largest excursion from the held level before it comes back within ``_BACK`` thresholds
_GONE = 0.25
_BACK = 0.25


def _lasting_departure(x: np.ndarray, level: float, thr: float, i1: int) -> int:
    """The first departure from sample ``i1`` on that is the release, not the noise wandering.

    A mass released from rest moves away from its held level monotonically until its first
    turning point, at least |x₀| (half the record's largest excursion) away. Noise does not:
    where it is coloured (low-frequency, e.g. AR(1) with ρ ≳ 0.8) the second-difference sd
    understates it several times, and the held segment itself crosses the threshold and then
    comes back. So a departure after which the signal returns within a quarter threshold of
    the level before it has gone a quarter of the largest excursion is skipped for the next
    one (3 samples beyond the threshold in a row, as before). With white noise the threshold
    is 8 sds and a departure never comes back that close: ``i1`` is kept. The scan moves
    forward at every step (at most one step per departure in the record).
    """
    dev = np.abs(x - level)
    far = max(4.0 * thr, _GONE * float(dev.max()))
    gone = np.flatnonzero(dev >= far)
    back = np.flatnonzero(dev <= _BACK * thr)
    out = dev > thr
    hits = np.flatnonzero(out[:-2] & out[1:-1] & out[2:])
    h = i1
    while True:
        g = gone[np.searchsorted(gone, h)] if gone.size and gone[-1] >= h else None
        b = back[np.searchsorted(back, h)] if back.size and back[-1] >= h else None
        if g is None or b is None or g < b:
            return h  # the signal goes far before it comes back
        later = hits[np.searchsorted(hits, b)] if hits.size and hits[-1] >= b else None
        if later is None:
            return i1  # no lasting departure in the record: keep the first one
        h = int(later)


#: samples (records × padded length) per batch of :func:`change_points`
_CHANGE_BATCH = 1 << 18


def change_points(ts: Sequence[np.ndarray], xs: Sequence[np.ndarray], i1s: Sequence[int]
                   ) -> list[int]:
    """The quadratic change point of each record, up to its departure sample i1.

    x = L for t < τ, L + a (t − τ)² after (a held mass starts from rest, so the motion leaves
    the held level quadratically); least squares over τ at the samples ≤ i1, τ on the samples.
    For every candidate j the sums over i ≥ j come from reverse cumulative sums of u^p and
    y u^p (u = t − t[i1], p = 0..4), so all candidates cost O(i1). The records are stacked,
    right-aligned (every record's sample i1 in the last column, zeros before its first sample,
    which enter only the sums of masked candidates) and done together; the cumulative sums run
    sample by sample, so a record gives the same candidate, bit for bit, alone or in a batch.
    """
    out = [0] * len(ts)
    order = sorted(range(len(ts)), key=lambda i: i1s[i])
    groups: list[list[int]] = [[]]
    for i in order:
        if groups[-1] and (len(groups[-1]) + 1) * (i1s[i] + 1) > _CHANGE_BATCH:
            groups.append([])
        groups[-1].append(i)
    for grp in groups if order else []:
        ms = np.array([i1s[i] + 1 for i in grp])
        W = int(ms.max())
        R = len(grp)
        P = np.zeros((R, 9, W))  # u^0..u^4, y u^0..u^2, y² (suffix sums of each below)
        for r, i in enumerate(grp):
            m = int(ms[r])
            P[r, 1, W - m:] = ts[i][:m] - ts[i][m - 1]
            P[r, 5, W - m:] = xs[i][:m]
        P[:, 0] = 1.0
        u, y = P[:, 1], P[:, 5]
        np.multiply(u, u, out=P[:, 2])
        np.multiply(P[:, 2], u, out=P[:, 3])
        np.multiply(P[:, 2], P[:, 2], out=P[:, 4])
        np.multiply(P[:, 1:3], y[:, None], out=P[:, 6:8])
        np.multiply(y, y, out=P[:, 8])
        Sp = np.cumsum(P[:, :, ::-1], axis=2)[:, :, ::-1]
        first = (W - ms)[:, None]
        s_y = np.take_along_axis(Sp[:, 5], first, axis=1)  # Σ y, Σ y² over the whole record
        s_yy = np.take_along_axis(Sp[:, 8], first, axis=1)
        u2, u3, u4 = P[:, 2], P[:, 3], P[:, 4]
        # q_i = (u_i − u_j)², Σq and Σq² over i ≥ j, Σ y q over i ≥ j
        s_q = Sp[:, 2] - 2 * u * Sp[:, 1] + u2 * Sp[:, 0]
        s_qq = (Sp[:, 4] - 4 * u * Sp[:, 3] + 6 * u2 * Sp[:, 2] - 4 * u3 * Sp[:, 1]
                + u4 * Sp[:, 0])
        s_yq = Sp[:, 7] - 2 * u * Sp[:, 6] + u2 * Sp[:, 5]
        det = ms[:, None] * s_qq - s_q**2
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            L = (s_qq * s_y - s_q * s_yq) / det
            a = (ms[:, None] * s_yq - s_q * s_y) / det
            sse = s_yy - L * s_y - a * s_yq
        valid = np.arange(W)[None, :] >= first
        sse = np.where(valid & np.isfinite(sse) & (det > 0), sse, np.inf)
        # (a record none of whose candidates is finite gets 0, as alone: its padding is not
        # a candidate)
        j0 = np.where(np.isfinite(sse.min(axis=1)), np.argmin(sse, axis=1) - first[:, 0], 0)
        for r, i in enumerate(grp):
            out[i] = int(j0[r])
    return out


def releases(ts: Sequence[np.ndarray], xs: Sequence[np.ndarray], refine: bool = True
              ) -> list[tuple[int, float | None]]:
    """:func:`locate_release` of many records, the change points of all of them in one batch."""
    deps = [_departure(x) for x in xs]
    live = [i for i, d in enumerate(deps) if d.i1 is not None]
    # (each from its departure's first candidate: 0 but where the held noise is coloured)
    cps = change_points([ts[i][deps[i].first:] for i in live],
                        [xs[i][deps[i].first:] for i in live],
                        [deps[i].i1 - deps[i].first for i in live])
    j0s = {i: j + deps[i].first for i, j in zip(live, cps, strict=True)}
    out: list[tuple[int, float | None]] = []
    for i, (t, x) in enumerate(zip(ts, xs, strict=True)):
        if i not in j0s:
            out.append((0, None))
            continue
        # (under coloured noise the even quartic follows the held segment's wander, early by
        # up to ~10 samples where the change point near the departure is within ~2: kept)
        j = j0s[i] if not refine or deps[i].coloured else _refine_release(t, x, deps[i], j0s[i])
        out.append((j, hold_sd(x, j)))
    return out


def locate_release(t: np.ndarray, x: np.ndarray, refine: bool = True) -> tuple[int, float | None]:
    """Index of the release sample and the sd of the held segment (None if too short).

    The departure from the held level (:func:`_departure`), its quadratic change point before
    it (:func:`change_points`) and, with ``refine``, a refinement with an even quartic
    (:func:`_refine_release`). ``refine=False`` stops after the change point (a few samples
    off, typically), for callers that refine the release with a model of their own."""
    return releases([t], [x], refine)[0]


def _refine_release(t: np.ndarray, x: np.ndarray, dep: _Departure, j0: int) -> int:
    """The release refined on a longer stretch (until 4× the threshold) with x = L + a u² +
    b u⁴, u = (t − τ)₊ (the free response from rest is even in u), over candidates within 16
    samples of the change point ``j0``."""
    n = x.size
    level, thr, i1, m_search = dep.level, dep.thr, dep.i1, dep.m_search
    assert i1 is not None
    far = np.flatnonzero(np.abs(x[i1:m_search] - level) > 4 * thr)
    i2 = i1 + int(far[0]) if far.size else min(n - 1, 2 * i1)
    w = 16
    cand = np.arange(max(j0 - w, dep.first), min(j0 + w, i1) + 1)
    lo = max(int(cand[0]) - 4 * w, dep.first)
    tt = t[lo : i2 + 1]
    yy = x[lo : i2 + 1]
    U = np.maximum(tt[None, :] - t[cand][:, None], 0.0) / max(t[i2] - t[lo], 1e-300)
    y0 = yy - level
    # U², U⁴, U⁶, U⁸ and their sums
    Q = np.empty((4, *U.shape))
    np.multiply(U, U, out=Q[0])
    np.multiply(Q[0], Q[0], out=Q[1])
    np.multiply(Q[1], Q[0], out=Q[2])
    np.multiply(Q[1], Q[1], out=Q[3])
    s2, s4, s6, s8 = Q.sum(axis=2)
    AtA = np.empty((cand.size, 3, 3))
    AtA[:, 0, 0] = yy.size
    AtA[:, 0, 1] = AtA[:, 1, 0] = s2
    AtA[:, 0, 2] = AtA[:, 2, 0] = AtA[:, 1, 1] = s4
    AtA[:, 1, 2] = AtA[:, 2, 1] = s6
    AtA[:, 2, 2] = s8
    Aty = np.empty((cand.size, 3))
    Aty[:, 0] = y0.sum()
    Aty[:, 1] = Q[0] @ y0
    Aty[:, 2] = Q[1] @ y0
    try:
        coef = np.linalg.solve(AtA, Aty[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return j0
    sse2 = float(y0 @ y0) - (coef * Aty).sum(1)
    return int(cand[np.argmin(sse2)])


def detect_release(t: ArrayLike, x: ArrayLike) -> float:
    """Time at which the held mass is let go, s.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, strictly increasing.
    x : array_like, shape (n,)
        Position, m.

    Returns
    -------
    float
        Release time, s: the last sample at the held level; ``t[0]`` when the record holds no
        held segment.

    Raises
    ------
    ValueError
        For unusable input, as :func:`fit_decay`.

    Notes
    -----
    The record's white-noise sd is estimated robustly from second differences. The signal has
    left the held level (the median of the first samples) when it stays more than 8 sds away
    for 3 samples. The release is then refined backwards by least squares over the change point
    τ of x = L (t < τ), x = L + a(t − τ)² (t ≥ τ) up to that sample — the mass starts from
    rest, so it leaves the held level quadratically — and then of x = L + a u² + b u⁴,
    u = (t − τ)₊, up to 32 noise sds, over candidates within 16 samples (its accuracy:
    docs/design-notes/fits.md, "detect_release").

    Coloured (low-frequency) noise, whose second differences understate it several times,
    crosses that threshold in the held segment itself. A departure after which the signal
    comes back near the level before it has gone a quarter of its largest excursion is
    therefore not the release; and where the held segment (ended well before the first swing)
    has an sd above 1.5 times its second-difference sd, its own sd and median set the threshold
    and the level, the change point is sought only near that departure, and the quartic
    refinement (which follows the noise's wander) is left out. With white noise neither step
    changes the result.
    """
    t, x = check_record(t, x)
    j, _ = locate_release(t, x)
    return float(t[j])


def window(t, x, release, skip, t_end, refine_release=True, detected=None):
    """The release (s), the held segment's sd (m, or None), the window's t and x, and the
    range of x over it (m).

    ``detected``: the release's sample and held sd when they were already detected (as
    :func:`locate_release` gives them), for ``release=None``."""
    skip = v.nonnegative("skip", skip, "s")
    if release is None:
        j, held = locate_release(t, x, refine_release) if detected is None else detected
        release = float(t[j])
    else:
        release = v.finite("release", release, "s")
        if not release < t[-1]:
            raise ValueError(
                f"`release` must be before the record's end t[-1] = {t[-1]:g} s; got {release:g}"
            )
        j = int(np.searchsorted(t, release, side="right")) - 1
        held = hold_sd(x, j)
    t0 = release + skip
    if t_end is None:
        t1 = float(t[-1])
    else:
        t1 = v.finite("t_end", t_end, "s")
        if not t1 > t0:
            raise ValueError(f"`t_end` must be > release + skip = {t0:g} s; got {t1:g}")
    # the sample at release + skip itself belongs to the window (tolerance: rounding of t)
    tol = 1e-9 * (abs(t0) + (t[-1] - t[0]) / t.size)
    i0 = int(np.searchsorted(t, t0 - tol, side="left"))
    i1 = int(np.searchsorted(t, t1 + tol, side="right"))
    nw = max(i1 - i0, 0)
    if nw < MIN_SAMPLES:
        raise ValueError(
            f"the window [release + skip, t_end] = [{t0:g}, {t1:g}] s holds {nw} samples; "
            f"at least {MIN_SAMPLES} are needed"
        )
    tw, xw = t[i0:i1], x[i0:i1]
    ptp = float(xw.max()) - float(xw.min())
    if not ptp > 0:
        raise ValueError(f"`x` is constant ({xw[0]:g} m) in the window [{t0:g}, {t1:g}] s")
    return release, held, tw, xw, ptp




# --------------------------------------------------------------------------------------------
# how a record starts: a release, an impulse (a kick from rest), or already moving

#: a kick's rest level and the level it settles to agree when they differ by at most this
#: fraction of the first swing (a release from x₀ settles |x₀| away, which is at least half its
#: first swing (1 + q)|x₀|, q ≤ 1 the half-cycle decay; a kick from rest settles where it began)
_SAME_LEVEL = 0.25
#: the tail still rings (its level is not yet known) when its half-spread exceeds this fraction
#: of the first swing
_SETTLED = 0.25
#: a turning point is passed once the signal has come back this many noise sds (or this
#: fraction of the swing, whichever is more)
_TURN_NSD = 6.0
_TURN_REL = 0.1
#: fewest samples in a flat run at the record's extreme that make it a clip, and how much
#: steeper than the run's flatness the signal must enter and leave it
_CLIP_RUN = 3
_CLIP_STEEP = 10.0


@dataclass(frozen=True)
class Clipping:
    """Samples of a record flat at its extreme (the sensor or the logger saturated).

    Attributes
    ----------
    level : float
        The value the signal is flat at (m, or the record's unit).
    runs : tuple of (int, int)
        First and last sample of each run of samples at ``level``.
    n_samples : int
        Clipped samples in all.
    last : int
        The last clipped sample: the fit starts after it.
    """

    level: float
    runs: tuple[tuple[int, int], ...]
    n_samples: int
    last: int


def find_clipping(x: np.ndarray) -> Clipping | None:
    """The runs of a record flat at its largest or smallest value, when the signal runs into
    them and out of them steeply: a clip.

    A run of at least 3 consecutive samples within ``tol`` of the record's maximum (or
    minimum), ``tol`` the record's resolution (its smallest nonzero step, at least 1e-9 of its
    range), makes that extreme a ceiling when the steps into and out of the run exceed 10
    ``tol`` and 3 noise sds: a smooth turning point, sampled finely, is flat at the top too,
    but it arrives there in steps of about the resolution, while a saturated signal hits its
    ceiling at speed; a sampled sine cannot hold 3 samples at one level with steep steps on
    both sides. Runs touching the record's ends do not qualify a ceiling (no step into or out
    of them). Every sample at a ceiling is then clipped. Returns None when there is none; else
    the side with more clipped samples.
    """
    n = x.size
    if n < _CLIP_RUN + 2:
        return None
    rng = float(x.max()) - float(x.min())
    if not rng > 0:
        return None
    steps = np.abs(np.diff(x))
    nz = steps[steps > 0]
    tol = max(float(nz.min()) if nz.size else 0.0, 1e-9 * rng)
    steep = max(_CLIP_STEEP * tol, 3.0 * diff_noise(x))
    best: Clipping | None = None
    for sgn in (1.0, -1.0):
        y = sgn * x
        top = float(y.max())
        at = y >= top - tol
        edges = np.diff(np.concatenate(([0], at.astype(np.int8), [0])))
        starts = np.flatnonzero(edges == 1)
        ends = np.flatnonzero(edges == -1) - 1
        pairs = list(zip(starts.tolist(), ends.tolist(), strict=True))
        if not any(b - a + 1 >= _CLIP_RUN and 0 < a and b < n - 1 and y[a] - y[a - 1] > steep
                   and y[b] - y[b + 1] > steep for a, b in pairs):
            continue
        # the level is a ceiling: every sample at it is clipped (noise splits a clipped
        # stretch into shorter runs at its edges, and later, smaller swings touch it briefly)
        runs = [(int(a), int(b)) for a, b in pairs]
        if runs:
            count = sum(b - a + 1 for a, b in runs)
            if best is None or count > best.n_samples:
                best = Clipping(level=sgn * top, runs=tuple(runs), n_samples=count,
                                last=max(b for _, b in runs))
    return best


def _turn(y: np.ndarray, i: int, margin: float) -> int | None:
    """The first maximum of y from sample i on: the running maximum's sample once y has fallen
    more than ``margin`` below it; None when y never falls back that far."""
    run = np.maximum.accumulate(y[i:])
    back = np.flatnonzero(y[i:] < run - margin)
    if not back.size:
        return None
    k = int(back[0])
    return i + int(np.argmax(y[i : i + k + 1]))


@dataclass(frozen=True)
class RecordStart:
    """How a record starts, with its evidence (:func:`classify_start`).

    Attributes
    ----------
    kind : str
        ``"release"`` (held displaced, let go from rest: the held level is not the level the
        motion settles to), ``"impulse"`` (a kick from rest at the equilibrium: the level before
        the kick is the level the motion settles to) or ``"none"`` (no quiet start: the record
        starts in motion, or its start is not quiet long enough to tell).
    index : int
        The release's or the kick's sample, as :func:`locate_release` puts it (0 for
        ``"none"``).
    time : float
        Its time, s.
    held_level : float or None
        Level before the motion starts (median of the quiet start), m; None without a quiet
        start.
    rest_level : float or None
        Level the motion settles to (median of the last quarter of the record after its largest
        excursion), m.
    noise_sd : float
        White-noise sd of the record (second differences), m.
    amplitude : float
        The largest excursion from the held level, m (the first swing).
    peak : int or None
        Its sample: for a kick, the first turning point, after which the response is free.
    shift_nsd, shift_rel : float
        |held − rest| in noise sds and as a fraction of ``amplitude``.
    tail_rel : float
        Half the spread (10–90 %) of the tail that gives ``rest_level``, over ``amplitude``: above
        0.25 the record still rings at its end and the rest level is not known from it.
    swing_ratio : float
        The second swing (from the largest excursion to the next turning point) over the
        first (from the held level to the largest excursion): q < 1 after a release from rest
        (the start is itself a turning point), 1 + q > 1 after a kick (q the half-cycle decay);
        nan when there is no second turning point.
    x0 : float
        held − rest: the displacement from the rest level at the start, m (≈ 0 for a kick).
    v0 : float
        Mean velocity over the first half of the first swing, m/s (the kick's velocity, roughly;
        a release starts from rest and gathers speed).
    fit_from : int
        The first sample a free response can model: the one after the kick's largest
        excursion for an impulse (and after any clipped sample); else the sample after any
        clipped sample (0 without one), the release's own start rule applying too.
    clipping : Clipping or None
        Samples flat at the record's extreme (:func:`find_clipping`).
    """

    kind: str
    index: int
    time: float
    held_level: float | None
    rest_level: float | None
    noise_sd: float
    amplitude: float
    peak: int | None
    shift_nsd: float
    shift_rel: float
    tail_rel: float
    swing_ratio: float
    x0: float
    v0: float
    fit_from: int
    clipping: Clipping | None = None

    def evidence(self, unit: str = "m") -> str:
        """One line of the evidence, in the user's words."""
        if self.held_level is None or self.rest_level is None:
            return "the record starts in motion (no quiet start)"
        sr = ("" if not math.isfinite(self.swing_ratio)
              else f"; second swing {self.swing_ratio:.2f}× the first")
        return (f"the level before the motion ({self.held_level:.4g} {unit}) and the level it "
                f"settles to ({self.rest_level:.4g} {unit}) differ by {self.shift_nsd:.3g} "
                f"noise sd, {self.shift_rel:.2f} of the first swing ({self.amplitude:.3g} "
                f"{unit}){sr}")


def classify_start(t: np.ndarray, x: np.ndarray,
                   detected: tuple[int, float | None] | None = None) -> RecordStart:
    """Whether a record starts with a release, an impulse (a kick from rest) or in motion.

    Parameters
    ----------
    t, x : ndarray
        The record (s, m), checked as :func:`check_record` does.
    detected : (int, float or None), optional
        :func:`locate_release`'s answer when it is already known.

    Returns
    -------
    RecordStart

    Notes
    -----
    Both a release and a kick begin with a quiet segment: at least 10 samples before the
    signal leaves its level by 8 noise sds (:func:`locate_release`'s departure). A release
    starts displaced, so the held level is |x₀| from the level the decay settles to; a kick
    starts at the equilibrium, so the two agree. The rest level is the median of the last
    quarter of the record after its largest excursion; where that tail still rings (its
    half-spread above 0.25 of the first swing), the swings decide instead: the start of a
    release is itself a turning point, so its second swing is q ≤ 1 times its first, while a
    kick's is 1 + q ≥ 1 times. A record is an impulse when, with a settled tail, the two levels
    differ by at most 0.25 of its first swing (a release's differ by at least 0.5:
    |x₀| against (1 + q)|x₀|), or, with a ringing tail, its second swing exceeds its first.
    Otherwise it is a release (:func:`locate_release` may still find no held segment to model
    when the quiet start is short or not still); without a quiet start it is ``"none"``.

    After a kick the response is free only once the force has ended. Every one-signed push
    shorter than the impulse response's time to its peak (a quarter of the period, lightly
    damped) keeps the velocity one-signed while it acts (the velocity's impulse response is
    positive until that peak), so the largest excursion — the first turning point — comes
    after the push: ``fit_from`` is the sample after it (and after any clipped sample, which is
    never free response; the sample after the peak, as in an accelerometer's record the peak is
    the blow itself).
    """
    n = x.size
    j, hsd = locate_release(t, x) if detected is None else detected
    held = hsd is not None and j >= 10
    clip = find_clipping(x)
    after_clip = 0 if clip is None else clip.last + 1
    dep = _departure(x)
    nsd = diff_noise(x[: dep.i1] if dep.i1 is not None and dep.i1 >= 10 else x)
    base = RecordStart(kind="release" if held else "none", index=j if held else 0,
                       time=float(t[j if held else 0]), held_level=None, rest_level=None,
                       noise_sd=nsd, amplitude=math.nan, peak=None, shift_nsd=math.nan,
                       shift_rel=math.nan, tail_rel=math.nan, swing_ratio=math.nan,
                       x0=math.nan, v0=math.nan, fit_from=after_clip, clipping=clip)
    if dep.i1 is None or dep.i1 < 10:
        return base
    i1 = dep.i1
    level = med(x[: i1 - 1])
    y = x - level
    sgn = 1.0 if y[i1] > 0 else -1.0
    p = i1 + int(np.argmax(np.abs(y[i1:])))
    amp = abs(float(y[p]))
    if not amp > 0:
        return base
    tail = x[p + 1 :][-max((n - p - 1) // 4, 0):] if n - p - 1 >= 8 else x[:0]
    if tail.size >= 8:
        rest = med(tail)
        lo, hi = np.quantile(tail, [0.1, 0.9])
        tail_rel = 0.5 * float(hi - lo) / amp
    else:
        rest, tail_rel = math.nan, math.inf
    shift = abs(level - rest) if math.isfinite(rest) else math.nan
    ps = 1.0 if y[p] > 0 else -1.0
    margin = max(_TURN_NSD * nsd, _TURN_REL * amp)
    e2 = _turn(-ps * y, p, margin)
    swing = abs(float(y[e2] - y[p])) / amp if e2 is not None else math.nan
    # the mean velocity over the first half of the first swing
    half = i1 + int(np.argmax(sgn * y[i1 : p + 1] >= 0.5 * amp)) if sgn == ps else i1
    k0 = max(i1 - 1, 0)
    v0 = float(y[half] - y[k0]) / float(t[half] - t[k0]) if half > k0 else math.nan
    if tail_rel <= _SETTLED:
        impulse = shift <= _SAME_LEVEL * amp
    else:
        impulse = math.isfinite(swing) and swing > 1.0
    kind = "impulse" if impulse else "release"
    index = j if j < i1 else i1 - 1
    fit_from = max(p + 1, after_clip) if impulse else after_clip
    return RecordStart(
        kind=kind, index=index, time=float(t[index]), held_level=level,
        rest_level=rest if math.isfinite(rest) else None, noise_sd=nsd, amplitude=amp,
        peak=p, shift_nsd=shift / nsd if nsd > 0 else math.inf, shift_rel=shift / amp,
        tail_rel=tail_rel, swing_ratio=swing, x0=level - rest, v0=v0, fit_from=fit_from,
        clipping=clip,
    )


def impulse_peak_time(sigma: float, w0sq: float) -> float:
    """Time from an ideal impulse to the free response's largest excursion, s.

    x(τ) ∝ e^{−στ} sin(ω_d τ)/ω_d peaks at τ = atan2(ω_d, σ)/ω_d (ω_d = √(ω₀² − σ²)); at
    critical damping at 1/σ; overdamped (rates λ₁ < λ₂) at ln(λ₂/λ₁)/(λ₂ − λ₁). Any one-signed
    push reaches its first turning point no sooner (the velocity's impulse response is positive
    until then). nan without a restoring spring (ω₀² ≤ 0) or, overdamped, without decay.
    """
    if not (w0sq > 0 and math.isfinite(sigma)):
        return math.nan
    q = sigma * sigma - w0sq
    if q < 0:
        wd = math.sqrt(-q)
        return math.atan2(wd, sigma) / wd
    if q == 0:
        return 1.0 / sigma if sigma > 0 else math.nan
    w = math.sqrt(q)
    lam1 = w0sq / (sigma + w) if sigma > 0 else math.nan  # σ − w, without the cancellation
    lam2 = sigma + w
    if not lam1 > 0:
        return math.nan
    return math.log(lam2 / lam1) / (lam2 - lam1)
