"""m, c, k from measured modes: eq. (35) OLS lines and the weighted fit through exact roots."""

import numpy as np
import pytest

from phoid import IdentificationError, Plant, forward_map
from phoid.methods.pho import fit_lines, fit_modes

IDX = np.arange(19)
P1, D1 = 0.25 + 1.375 * IDX, 0.6 + 0.3 * IDX  # Table 1 sweep (ERRATA 6)
TRUE = np.array([2.0, 1.0, 64.0])
MODES = forward_map(Plant(*TRUE), P1, D1, 0.1)


def run_cov(sd_sigma=1e-3, sd_omega=7e-4, rho=0.3, n=19):
    cov = np.zeros((n, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = sd_sigma**2, sd_omega**2
    cov[:, 0, 1] = cov[:, 1, 0] = rho * sd_sigma * sd_omega
    return cov


@pytest.mark.parametrize("delay", [0.0, 0.1])
def test_exact_modes_give_exact_parameters(delay):
    # exact roots in, exact parameters out: 1e-10 allows only rounding
    modes = forward_map(Plant(*TRUE), P1, D1, delay)
    for fit in (
        fit_lines(modes.sigma, modes.omega_d, P1, D1, delay),
        fit_modes(modes.sigma, modes.omega_d, run_cov(), P1, D1, delay),
    ):
        np.testing.assert_allclose([fit.m, fit.c, fit.k], TRUE, rtol=1e-10)


def test_overdamped_plant_and_mass_damper():
    # plants that never oscillate alone (zeta ~ 6.3 and k = 0) made to ring by negative D
    for plant, P, D, delay in [
        (Plant(0.5, 40.0, 20.0), np.linspace(100, 600, 8), np.linspace(-38, -30, 8), 0.005),
        (Plant(1.0, 10.0, 0.0), np.linspace(50, 400, 8), np.linspace(-9, -5, 8), 0.01),
    ]:
        modes = forward_map(plant, P, D, delay)
        assert np.all(modes.omega_d > 0) and np.all(modes.sigma > 0)
        fit = fit_modes(modes.sigma, modes.omega_d, run_cov(n=8), P, D, delay)
        np.testing.assert_allclose([fit.m, fit.c, fit.k], [plant.m, plant.c, plant.k],
                                   rtol=1e-9, atol=1e-9)


def test_weighted_fit_is_calibrated():
    # Monte Carlo with known per-run Gaussian errors: z = (estimate - truth) / stderr must be
    # N(0, 1): sd within 0.85-1.15 for 300 replicas (sd of a sample sd ~ 1/sqrt(600) = 0.04,
    # so +-15 % is > 3.5 sigma), |mean| < 0.25 (3.5 / sqrt(300) * 1.15), and all |z| < 4.5.
    rng = np.random.default_rng(20261122)
    cov = run_cov()
    L = np.linalg.cholesky(cov[0])
    z = []
    for _ in range(300):
        e = rng.standard_normal((19, 2)) @ L.T
        f = fit_modes(MODES.sigma + e[:, 0], MODES.omega_d + e[:, 1], cov, P1, D1, 0.1)
        z.append((np.array([f.m, f.c, f.k]) - TRUE) / f.stderr)
    z = np.array(z)
    assert np.all(np.abs(z.std(axis=0) - 1) < 0.15)
    assert np.all(np.abs(z.mean(axis=0)) < 0.25)
    assert np.abs(z).max() < 4.5


def test_weighted_fit_beats_ols_on_noisy_modes():
    # with unequal run precision the weighted fit must have a smaller spread than OLS lines
    rng = np.random.default_rng(7)
    sd = np.linspace(1e-4, 5e-3, 19)
    cov = np.zeros((19, 2, 2))
    cov[:, 0, 0] = cov[:, 1, 1] = sd**2
    gls, ols = [], []
    for _ in range(150):
        e = rng.standard_normal((19, 2)) * sd[:, None]
        s, w = MODES.sigma + e[:, 0], MODES.omega_d + e[:, 1]
        g = fit_modes(s, w, cov, P1, D1, 0.1)
        o = fit_lines(s, w, P1, D1, 0.1)
        gls.append([g.m, g.c, g.k])
        ols.append([o.m, o.c, o.k])
    assert np.all(np.std(gls, axis=0) < np.std(ols, axis=0))


def test_misfit_inflates_stderr_and_warns():
    # runs made with a different delay than assumed: chi2 far above its dof
    modes = forward_map(Plant(*TRUE), P1, D1, 0.12)
    f = fit_modes(modes.sigma, modes.omega_d, run_cov(1e-5, 1e-5), P1, D1, 0.1)
    assert any("disagree" in w for w in f.warnings)
    assert f.chi2 / f.dof > 10


def test_same_gains_and_no_runs_are_errors():
    s = MODES.sigma[:1].repeat(3)
    w = MODES.omega_d[:1].repeat(3)
    with pytest.raises(IdentificationError, match="same gains"):
        fit_lines(s, w, [1.0, 1.0, 1.0], [0.5, 0.5, 0.5], 0.1)
    with pytest.raises(IdentificationError, match="no usable runs"):
        fit_modes([], [], np.zeros((0, 2, 2)), [], [], 0.1)


def test_converges_when_a_parameter_is_zero():
    # k = 0 (mass-damper, eq. 9): convergence is judged on the experiment's scale of k, not on
    # k itself, so exact modes with rounding-level covariance still converge (to 1e-9 of P's)
    plant = Plant(1.0, 10.0, 0.0)
    P, D = np.linspace(50, 400, 8), np.linspace(-9, -5, 8)
    modes = forward_map(plant, P, D, 0.01)
    fit = fit_modes(modes.sigma, modes.omega_d, run_cov(1e-14, 1e-14, n=8), P, D, 0.01)
    assert abs(fit.m - 1.0) < 1e-9 and abs(fit.c - 10.0) < 1e-8 and abs(fit.k) < 1e-9 * 400
    assert not fit.warnings  # the numerical floor keeps chi2 honest at rounding level
