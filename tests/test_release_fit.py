"""The release refit's vectorised pieces against the plain computations they replace.

pho_release.interp_uniform against np.interp; simulation.release_response against
simulate; pho_release.model_releases with the uniform-sampling shortcut (one g per run,
simulated at the data's rate) against its general path (every candidate's own t − τ,
interpolated on a grid 4 times finer).
"""

from __future__ import annotations

import numpy as np
import pytest

import phoid.methods.pho_release as ident
from phoid import Plant, simulate
from phoid.fits import start_decay
from phoid.simulation import release_response

EPS = np.finfo(float).eps


def test_interp_uniform_matches_np_interp():
    rng = np.random.default_rng(7)
    n, ng = 5, 400
    rate = rng.uniform(500.0, 5000.0, n)
    fp = rng.standard_normal((n, ng)).cumsum(axis=1)
    span = (ng - 1) / rate
    # points before the grid's start, inside, on nodes, on the last node and beyond the end
    x = rng.uniform(-0.2, 1.2, (n, 3, 50)) * span[:, None, None]
    x[:, 0, :5] = (np.arange(5) * 37)[None, :] / rate[:, None]
    x[:, 0, 5] = span
    x[:, 0, 6] = 2 * span
    got = ident.interp_uniform(x, rate, fp)
    ref = np.stack([np.interp(x[r], np.arange(ng) / rate[r], fp[r]) for r in range(n)])
    # both interpolate linearly between the same nodes; they differ only in the rounding of
    # the position inside the interval (x·rate carries ≤ ~ng·ε of a node spacing, the
    # nodes i/rate their own ulp), times the step between neighbouring values
    step = np.max(np.abs(np.diff(fp, axis=1)))
    assert np.max(np.abs(got - ref)) <= 8 * ng * EPS * step + 4 * EPS * np.max(np.abs(fp))
    assert got.shape == x.shape
    assert np.array_equal(got[:, 0, 6], fp[:, -1]) and np.all(got[x < 0] == np.repeat(
        fp[:, :1], x[0].size, axis=1).reshape(x.shape)[x < 0])


@pytest.mark.parametrize(("plant", "D", "delay", "fs"), [
    (Plant(0.5, 40.0, 20.0), (-38.4, -30.0), 0.005, 1000.0),  # 5 steps per delay: products
    (Plant(1.0, 10.0, 0.0), (-4.0, 3.0), 0.01, 1000.0),  # 10
    (Plant(1.0, 10.0, 0.0), (-4.0, 3.0), 0.01, 4000.0),  # 40: simulate's own recursion
    (Plant(2.0, 1.0, 64.0), (0.6, 6.0), 0.1, 1000.0),  # 100
])
def test_release_response_matches_simulate(plant, D, delay, fs):
    P = np.linspace(50.0, 300.0, 6)
    D = np.linspace(*D, 6)
    x = release_response(plant, P, D, delay=delay, duration=0.25, fs=fs)
    ref = simulate(plant, P, D, delay=delay, duration=0.25, fs=fs, x0=1.0).x_true
    assert x.shape == ref.shape
    # the same scheme and grid; the block products sum Φ^j w directly where simulate runs
    # the Cayley–Hamilton recursion, whose rounding is amplified by 1/|λ₁ − λ₂| (≈ 50 here):
    # simulate itself moves by ~1e−12 between grids 4× apart; 1e−12 of x₀ is that rounding
    assert np.max(np.abs(x - ref)) <= 1e-12
    with pytest.raises(ValueError, match="fs"):
        release_response(plant, P, D, delay=delay, duration=0.25, fs=5.0)


def test_uniform_shortcut_matches_the_general_path(monkeypatch):
    plant = Plant(0.5, 40.0, 20.0)
    P = 50.0 + 72.0 * np.arange(8)
    D = -38.4 + 0.6 * np.arange(8)
    sim = simulate(plant, P, D, delay=0.005, duration=2.0, fs=1000.0, x0=0.005, hold=0.2,
                   noise=5e-5, rng=np.random.default_rng(3))
    data = [(sim.t, sim.x[i]) for i in range(P.size)]
    fits = [start_decay(t, x, skip=0.015, coarse_release=True) for t, x in data]
    args = (data, fits, (0.5, 40.0, 20.0), P, D, 0.005)
    fast = ident.model_releases(*args)
    monkeypatch.setattr(ident, "uniform_step", lambda *a: None)  # no span counts as uniform
    general = ident.model_releases(*args)
    assert all(f is not None for f in fast) and [f is None for f in general] == [False] * 8
    # the same fit; g on the data's grid or interpolated on one 4× finer differs by simulate's
    # rounding (~1e−12 of x₀), which moves the parabola's vertex by far less than 1 ns
    assert np.max(np.abs(np.subtract(fast, general))) < 1e-9
    assert np.max(np.abs(np.subtract(fast, 0.2))) < 0.5e-3  # within half a sample
