"""The independent tracking-loop reference (tests/_tracking_reference.py) checked on its own.

Before it judges phoid.simulation.tracking, the reference is held against what does not come
from it: closed forms (a free damped oscillator; the Coulomb oscillator, whose half-cycles are
harmonic about ±f_c/k and which sticks at the first turning point inside the dead band),
phoid.simulate's exact digital release loop, and itself at another precision.
"""

from __future__ import annotations

import mpmath
import numpy as np
import pytest
from _tracking_reference import coulomb_oscillator, reference_tracking

from phoid import Plant, simulate

EPS = np.finfo(float).eps


def _ulps(values: np.ndarray) -> float:
    """One unit in the last place of the largest |value| (float64)."""
    return float(np.spacing(np.max(np.abs(values))))


def test_free_damped_oscillator_matches_closed_form() -> None:
    """No control (P = D = 0), no friction: x(t) = A e^{λ₁t} + B e^{λ₂t}, λ the roots of
    m λ² + c λ + k = 0, evaluated in mpmath at 40 digits. Both sides carry 30+ digits, so they
    agree to the float64 rounding of the result: 2 ulps of max |x|."""
    m, c, k, x0, v0, T, N = 2.0, 1.0, 64.0, 0.01, 0.05, 1e-3, 1500
    ref = reference_tracking(m, c, k, 0.0, T=T, P=0.0, D=0.0, r=np.zeros(N), x_init=[x0], v0=v0)
    with mpmath.workdps(40):
        root = mpmath.sqrt(mpmath.mpc(c * c - 4 * m * k))
        lam1, lam2 = (-c + root) / (2 * m), (-c - root) / (2 * m)
        B = (mpmath.mpf(v0) - lam1 * x0) / (lam2 - lam1)
        A = mpmath.mpf(x0) - B
        tn = [n * mpmath.mpf(T) for n in range(N)]
        exact = np.array([float(mpmath.re(A * mpmath.exp(lam1 * t) + B * mpmath.exp(lam2 * t)))
                          for t in tn])
        speed = np.array([float(mpmath.re(A * lam1 * mpmath.exp(lam1 * t)
                                          + B * lam2 * mpmath.exp(lam2 * t))) for t in tn])
    assert np.max(np.abs(ref.x - exact)) <= 2 * _ulps(exact)
    assert np.max(np.abs(ref.v - speed)) <= 2 * _ulps(speed)
    # zeros of ẋ are π/ω_d ≈ 0.56 s apart, so the 1 ms grid sees each as one sign change
    assert ref.reversals == np.count_nonzero(np.diff(np.sign(speed))) == 3



@pytest.mark.parametrize("T", [1e-3, 0.13, 0.5])
def test_coulomb_oscillator_matches_closed_form(T: float) -> None:
    """m = 1 kg, k = 100 N/m, c = 0, f_c = 0.5 N (band 5 mm) from 27.5 mm at rest: turning
    points −17.5, 7.5, 2.5 mm, stuck from t = 3π/10 s on. Periods T up to 0.5 s, longer than a
    half-cycle (π/10 s), check that every reversal inside a long piece is found. The closed form
    is float64 (a cosine of ωt, a few ulps of 27.5 mm), hence 1e-16 m."""
    N = round(1.3 / T) + 1
    ref = reference_tracking(1.0, 0.0, 100.0, 0.5, T=T, P=0.0, D=0.0, r=np.zeros(N),
                             x_init=[0.0275])
    exact = np.array([coulomb_oscillator(n * T, 0.0275, 10.0, 0.005) for n in range(N)])
    assert np.max(np.abs(ref.x - exact)) <= 1e-16
    assert ref.x[-1] == pytest.approx(0.0025, abs=1e-17) and ref.v[-1] == 0.0
    assert ref.reversals == 3


def _tracking_case(precision):
    """EMPS-like plant tracking a sine (reversals and sticking), fractional delay."""
    T, N = 1e-3, 1500
    r = 0.02 * np.sin(2 * np.pi * np.arange(N) * T)
    return reference_tracking(95.0, 200.0, 0.0, 20.0, T=T, P=160.18, D=1.0, K=243.45, G=35.15,
                              velocity="central-difference", r=r, offset=-3.0, delay=0.3e-3,
                              precision=precision)


def test_precisions_agree() -> None:
    """30 and 40 digits: the same float64 numbers (2 ulps); plain floats (same algorithm, the
    float64 rounding of ~10 operations a step through a stable loop, 1500 steps): within
    1500·ε·max|x|·8 ≈ 4e-14 m, the N·ε·scale bound with a margin of 8 for the operations."""
    hi, mid, lo = _tracking_case(40), _tracking_case(30), _tracking_case(None)
    assert hi.reversals >= 3 and hi.stuck_pieces >= 3  # the case does reverse and stick
    assert np.max(np.abs(hi.x - mid.x)) <= 2 * _ulps(hi.x)
    assert np.max(np.abs(hi.force - mid.force)) <= 2 * _ulps(hi.force)
    assert np.max(np.abs(hi.x - lo.x)) <= 8 * len(hi.x) * EPS * np.max(np.abs(hi.x))


@pytest.mark.parametrize("fc", [0.0, 0.3])
@pytest.mark.parametrize("d", [0, 2])
@pytest.mark.parametrize("velocity, cutoff", [("backward-difference", None), ("filtered", 300.0)])
def test_release_matches_phoid_simulate(fc: float, d: int, velocity: str, cutoff) -> None:
    """phoid.simulate's sampled loop (hold = 0, f_s = 1/T) is the contract's loop with r = 0,
    K = G = 1, τ = d·T, x history x₀, u history −P x₀. phoid.simulate is float64 through the
    loop's modes; over N = 3000 steps its rounding is bounded by 32·N·ε·max|x| (the N·ε·scale
    bound, margin 32 for the operations per step and the modal sums; measured ≈ 4e-14 m of the
    ≈ 2.6e-13 m bound)."""
    T, N, P, D = 1e-3, 3000, 30.0, 1.5
    sim = simulate(Plant(2.0, 1.0, 64.0, fc), P, D, duration=N * T, fs=1 / T, x0=0.01, v0=0.05,
                   sample_time=T, delay_samples=d, velocity=velocity, cutoff=cutoff)
    ref = reference_tracking(2.0, 1.0, 64.0, fc, T=T, P=P, D=D, r=np.zeros(N),
                             velocity=velocity, cutoff=cutoff, delay=d * T, x_init=[0.01],
                             v0=0.05, precision=None)
    tol = 32 * N * EPS * np.max(np.abs(ref.x))
    assert np.max(np.abs(sim.x_true[0] - ref.x)) <= tol
    if fc > 0:
        assert ref.stuck_pieces > 0
