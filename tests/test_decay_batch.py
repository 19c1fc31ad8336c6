"""Stacked decay fits and starts (phoid.fits.modal.fit_decays, phoid.fits.start.start_decays).

The fit has one implementation, for a stack of records; ``fit_decay`` of one record is a stack
of one (checked here to be exactly ``fit_decays`` of that one job). Where every expected value
comes from: the same record fitted alone, as a stack of one (itself checked against exact
modes, the Cramér–Rao bound and the independent sample set in tests/test_decay.py). In a stack
of mixed records a record's sums run over the stack's padded length, and BLAS blocks a long
reduction by its total length, so grouping and padding may move a result by rounding only:
the tolerance, 1e−6 of a standard error (1e−12 relative for noise-free records, whose standard
error is rounding itself), is far above that rounding (~1e−11 stderr here) and far below what
a different iteration or stopping decision would give (~0.05 stderr, the Gauss–Newton stopping
rule); every discrete outcome (errors, warnings, sample counts) must be equal.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from phoid._threads import single_blas_thread
from phoid.dynamics.loop import rightmost_roots
from phoid.fits import (
    FitJob,
    _stack,
    check_record,
    fit_decay,
    fit_decays,
    modal,
    release,
    start_decay,
    start_decays,
)
from phoid.io import read_experiment

TOL_SE = 1e-6  # of a standard error: rounding passes, a different iteration does not

# with one BLAS thread, as fit_decay and the identification run it (a threaded BLAS splits
# its reductions by the number of threads: other rounding)
fit_decays = single_blas_thread(fit_decays)


def _single(job: FitJob):
    """The job fitted alone, a stack of one; fit_decay gives exactly that."""
    alone = fit_decays([job])[0]
    try:
        public = fit_decay(job.t, job.x, release=job.release, skip=job.skip,
                           fast_roots=job.fast_roots, guess=job.guess)
    except ValueError as exc:
        public = str(exc)
    if isinstance(alone, str):
        assert public == alone
    else:
        assert not isinstance(public, str), public
        assert (public.sigma, public.omega_d, public.offset, public.residual_rms) == (
            alone.sigma, alone.omega_d, alone.offset, alone.residual_rms)
        np.testing.assert_array_equal(public.cov, alone.cov)
        assert public.warnings == alone.warnings
    return alone


def _assert_same(batch, single):
    if isinstance(single, str):
        assert batch == single
        return
    assert not isinstance(batch, str), batch
    for q in ("sigma", "omega_d"):
        se = getattr(single, f"{q}_stderr")
        a, b = getattr(batch, q), getattr(single, q)
        assert math.isfinite(se) == math.isfinite(getattr(batch, f"{q}_stderr"))
        if math.isfinite(se):
            # noise-free records: the stderr is rounding itself, 1e−12 relative is the floor
            assert abs(a - b) <= max(TOL_SE * se, 1e-12 * abs(b)), (q, a, b, se)
            assert getattr(batch, f"{q}_stderr") == pytest.approx(se, rel=1e-6, abs=1e-15)
        else:
            assert a == pytest.approx(b, rel=1e-9)
    assert batch.offset == pytest.approx(single.offset, rel=1e-9, abs=1e-15)
    assert batch.amplitude == pytest.approx(single.amplitude, rel=1e-9)
    assert batch.residual_rms == pytest.approx(single.residual_rms, rel=1e-9)
    assert batch.n_samples == single.n_samples and batch.release == single.release
    assert len(batch.fast_modes) == len(single.fast_modes)
    assert batch.warnings == single.warnings


def _checked(t, x):
    return check_record(t, x)


def test_sample_set_runs_stacked_as_each_alone(sample_set_path, truth):
    # the seed's 19-run sweep (jitcdde-made): every run from its release with the loop's two
    # slowest non-dominant modes (the identification's full fit), batched in one group
    exp = read_experiment(sample_set_path)
    m, c, k, delay = truth["m"], truth["c"], truth["k"], truth["delay"]
    jobs = []
    for r in exp.runs:
        t, x = _checked(r.t, r.x)
        roots = rightmost_roots(m, c, k, r.P, r.D, delay, count=6)
        modes = [z for z in roots if z.imag >= 0]
        jobs.append(FitJob(t, x, None, 0.0, np.array(modes[1:3]), None))
    out = fit_decays(jobs)
    for job, got in zip(jobs, out, strict=True):
        _assert_same(got, _single(job))


def _decay(t, sigma, omega, x0=0.01, offset=2e-4, fast=None):
    x = offset + x0 * np.exp(-sigma * t) * np.cos(omega * t)
    if fast is not None:
        x = x + 1e-3 * np.exp(fast * t)
    return x


@pytest.mark.parametrize("limit", [None, 10000])
def test_mixed_stack_matches_each_record_alone(limit, monkeypatch):
    # limit: the stack size cap (samples); 10 000 cuts every group into stacks of one or two
    # records, as long records are (memory stays that of the one-by-one fits)
    if limit is not None:
        monkeypatch.setattr(modal, "_BATCH_SAMPLES", limit)
    # records of different lengths, rates, fast-mode counts and kinds in one call: two sample
    # rates (two groups), lengths that differ within a group (zero-padded blocks), one record
    # without fast modes, a noise-free one (the polish takes its extra exact-gradient steps), a
    # growing one, non-uniform sampling of three lengths (a direct stack, zero-padded), a short
    # uniform record (< 64 samples: direct), a too-short window, and a start that overflows
    # (the fallback start, in a stack of its own)
    rng = np.random.default_rng(11)
    jobs = []
    for n, fs, sig, om in ((15000, 1000.0, 0.4, 9.0), (12345, 1000.0, 1.1, 14.0),
                           (9000, 1000.0, 0.2, 6.0), (4000, 500.0, 0.8, 11.0),
                           (3001, 500.0, 1.5, 20.0)):
        t = np.arange(n) / fs
        x = _decay(t, sig, om, fast=-30.0) + 1e-4 * rng.standard_normal(n)
        jobs.append(FitJob(*_checked(t, x), 0.0, 0.0, np.array([-30.0 + 0j]), (sig, om)))
    t = np.arange(8000) / 1000.0
    jobs.append(FitJob(*_checked(t, _decay(t, 0.7, 8.0) + 1e-4 * rng.standard_normal(t.size)),
                       0.0, 0.0, None, (0.69, 8.01)))
    jobs.append(FitJob(*_checked(t, _decay(t, 0.7, 8.0, fast=-40.0)), 0.0, 0.0,
                       np.array([-40.0 + 0j]), (0.7001, 7.999)))
    jobs.append(FitJob(*_checked(t, _decay(t, -0.05, 8.0) + 1e-4 * rng.standard_normal(t.size)),
                       0.0, 0.0, np.array([-40.0 + 0j]), (-0.05, 8.0)))
    for n in (8000, 6500, 5000):
        tj = np.sort(rng.uniform(0.0, n / 1000.0, n))
        jobs.append(FitJob(*_checked(tj, _decay(tj, 0.7, 8.0) + 1e-4 * rng.standard_normal(n)),
                           0.0, 0.0, None, (0.7, 8.0)))
    tj = np.sort(rng.uniform(0.0, 4.0, 4000))
    jobs.append(FitJob(*_checked(tj, _decay(tj, 0.9, 9.0) + 1e-4 * rng.standard_normal(4000)),
                       0.0, 0.0, np.array([-40.0 + 0j]), (0.9, 9.0)))
    ts = np.arange(60) / 20.0
    jobs.append(FitJob(*_checked(ts, _decay(ts, 0.3, 5.0)), 0.0, 0.0, None, (0.3, 5.0)))
    jobs.append(FitJob(*_checked(t, _decay(t, 0.7, 8.0)), 0.0, 7.995, None, (0.7, 8.0)))
    jobs.append(FitJob(*_checked(t, _decay(t, 0.7, 8.0) + 1e-4 * rng.standard_normal(t.size)),
                       0.0, 0.0, np.array([-40.0 + 0j]), (-1e4, 8.0)))
    out = fit_decays(jobs)
    assert isinstance(out[-2], str) and "at least" in out[-2]
    assert not isinstance(out[-1], str) and abs(out[-1].sigma - 0.7) < 0.05
    assert abs(out[-3].sigma - 0.3) < 1e-9 and abs(out[-3].omega_d - 5.0) < 1e-9
    for got in out[8:12]:  # the non-uniformly sampled records
        assert abs(got.sigma - 0.7 if got.omega_d < 8.5 else got.sigma - 0.9) < 0.05
    for job, got in zip(jobs, out, strict=True):
        _assert_same(got, _single(job))


def test_empty_batch():
    assert fit_decays([]) == []


def _single_start(t, x, **kw):
    try:
        return start_decay(t, x, **kw)
    except ValueError as exc:
        return str(exc)


def _assert_same_starts(got, want):
    # Both paths run the same LAPACK routine on the same matrices, and on x86-64 with OpenBLAS
    # they agree bit for bit. Another BLAS, kernel or SIMD width may round the stacked
    # (gufunc) and the single calls differently in the last bits, which the ESPRIT
    # eigenvalues amplify by their condition number (≲ 1e4 for these records): rel 1e-9 is
    # that with a 1e3 margin, while a mixed-up record, order or window moves a start by far
    # more than 1e-6. Discrete outcomes (errors, the oscillation verdict, the release sample)
    # must agree exactly.
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        if isinstance(w, str) or isinstance(g, str):
            assert g == w
            continue
        assert (g.oscillating, g.release, g.t_start, g.t_end) == (
            w.oscillating, w.release, w.t_start, w.t_end)
        for f in ("sigma", "omega_d", "offset", "noise_sd"):
            assert getattr(g, f) == pytest.approx(getattr(w, f), rel=1e-9, abs=1e-300), f


def test_start_decays_equal_one_by_one_starts(sample_set_path):
    # the first look (stacked ESPRIT eigenproblems, solves and eigenvalues: the same LAPACK
    # routine per matrix) gives the one-record starts (bit for bit on x86-64 OpenBLAS; to
    # rounding elsewhere, see _assert_same_starts).
    # Records: the sample set's 19 runs (held segment, release) and others of every kind the
    # first look meets: no held segment, non-uniform sampling, a non-oscillating decay, a short
    # record (a smaller ESPRIT order L), a constant record and one with NaN (error messages)
    exp = read_experiment(sample_set_path)
    recs = [(np.asarray(r.t, float), np.asarray(r.x, float)) for r in exp.runs]
    rng = np.random.default_rng(5)
    t = np.arange(6000) / 1000.0
    recs.append((t, _decay(t, 0.5, 7.0) + 1e-4 * rng.standard_normal(t.size)))
    tj = np.sort(rng.uniform(0.0, 6.0, 6000))
    recs.append((tj, _decay(tj, 0.5, 7.0) + 1e-4 * rng.standard_normal(tj.size)))
    recs.append((t, 0.01 * np.exp(-3.0 * t) + 1e-5 * rng.standard_normal(t.size)))
    ts = np.arange(80) / 100.0
    recs.append((ts, _decay(ts, 0.5, 30.0)))
    recs.append((t, np.zeros(t.size)))
    bad = _decay(t, 0.5, 7.0)
    bad[100] = np.nan
    recs.append((t, bad))
    for kw in ({"skip": 0.3, "refine": "auto", "coarse_release": True}, {"skip": 0.0}):
        got = start_decays(recs, **kw)
        want = [_single_start(t, x, **kw) for t, x in recs]
        _assert_same_starts(got, want)
        assert isinstance(got[-1], str) and isinstance(got[-2], str)
        assert not any(isinstance(g, str) for g in got[:-2])


def test_fast_columns_stacked_equal_each_alone():
    # the stacked fast-mode columns of a record are its columns alone, element for element
    # (the same exponentials and table products, whatever the other records), zero beyond its
    # nf, and they are e^{rτ} (real roots) or its real and imaginary parts (complex): to
    # 1e-12 of the envelope |e^{rτ}| (a tabulated entry's phase, up to ~10³ rad here, is
    # rounded differently from r τ's: ~10³ eps), while a wrong root, record or offset changes
    # entries at O(1). Records of different lengths, with complex roots tabulated (nf > 256)
    # and direct (nf ≤ 256, or no step given), real roots
    dt = 1e-3
    taus = [np.arange(n) * dt for n in (3000, 5000, 4000, 2000)]
    roots = [np.array([-40 + 300j, -9.0, -120.0]),
             np.array([-7.5, -55 + 80j, -300.0]),
             np.array([-200 + 900j, -210.0, -800.0]),  # nf = 185: computed directly
             np.array([-90 + 1j, -60.0, -61.0])]
    for step in (dt, None):
        FT, nf = _stack.fast_columns(taus, roots, step)
        assert FT.shape[1] == 2 * 4
        for i, (tau, r) in enumerate(zip(taus, roots, strict=True)):
            alone, (nf1,) = _stack.fast_columns([tau], [r], step)
            assert nf[i] == nf1
            np.testing.assert_array_equal(FT[i, :, :nf1], alone[0, :, :nf1])
            assert not FT[i, :, nf[i]:].any()
            cols, env = [], []
            for z in r.tolist():
                e = np.exp(z * tau[:nf1])
                cols += [e.real, e.imag] if z.imag else [e.real]
                env += [np.abs(e)] * (2 if z.imag else 1)
            want, tol = np.array(cols), 1e-12 * np.array(env)
            assert np.all(np.abs(FT[i, :4, :nf1] - want) <= tol)
            assert np.all(np.abs(FT[i, 4:, :nf1] - want * tau[:nf1]) <= tol * tau[:nf1])


def test_change_points_match_brute_force_least_squares():
    # the reverse-cumulative-sum change point of phoid.fits.release.change_points against the
    # straightforward one: for every candidate j a least-squares fit of x = L + a (t − t_j)₊²
    # over the samples ≤ i1 (np.linalg.lstsq), the smallest residual. Same index expected (the
    # sums differ only by rounding, ~1e−16 relative, the residuals of neighbouring candidates
    # by far more on these records: a clear quadratic departure in 1e−4 noise). Several records
    # in one batch, and each alone: same indices (a record's sums do not depend on the batch)
    rng = np.random.default_rng(11)
    ts, xs, i1s, want = [], [], [], []
    for n_hold, a in ((150, 40.0), (400, 15.0), (90, 80.0), (260, 25.0)):
        t = np.arange(n_hold + 200) * 1e-3
        tr = t[n_hold]
        x = 0.003 + a * np.maximum(t - tr, 0.0) ** 2 + 1e-4 * rng.standard_normal(t.size)
        i1 = n_hold + 60
        sse = []
        for j in range(i1 + 1):
            A = np.stack([np.ones(i1 + 1), np.maximum(t[: i1 + 1] - t[j], 0.0) ** 2], axis=1)
            res = np.linalg.lstsq(A, x[: i1 + 1], rcond=None)[1]
            sse.append(float(res[0]) if res.size else math.inf)
        ts.append(t)
        xs.append(x)
        i1s.append(i1)
        want.append(int(np.argmin(sse)))
    assert release.change_points(ts, xs, i1s) == want
    alone = [release.change_points([t], [x], [i])[0] for t, x, i in zip(ts, xs, i1s, strict=True)]
    assert alone == want


def test_change_points_of_a_record_without_finite_candidates_is_zero_in_a_batch():
    # a record whose every candidate's sums overflow (values ~1e200) has no finite residual;
    # alone its change point is 0 (the first candidate), and so it must be in a batch, where
    # the padding before it is no candidate (it gave a negative index, and an IndexError)
    t1 = np.arange(200) * 1e-3
    x1 = np.where(t1 >= 0.1, 1e200 * (t1 - 0.1) ** 2, 0.0)
    t2 = np.arange(400) * 1e-3
    x2 = 1e-3 + 5 * np.maximum(t2 - 0.2, 0) ** 2
    with np.errstate(over="ignore"):
        alone = release.change_points([t1], [x1], [150])
        both = release.change_points([t1, t2], [x1, x2], [150, 250])
    assert alone == [0]
    assert both[0] == 0
    assert both[1] == release.change_points([t2], [x2], [250])[0]
