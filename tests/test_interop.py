"""phoid.interop: results exported to python-control, scipy.signal and pandas; pandas records in.

Expected values come from outside the code under test: numpy.roots of the plant's and the
loop's polynomials (eqs. 4 and 31), phoid.dynamics' certified roots of the delayed loop and the
exact roots of the sampled loop, python-control's own discretisation and feedback of the
sampled loop, and the Monte Carlo standard error of a sample covariance. Tests that need
python-control or pandas skip where they are missing (pytest.importorskip).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import phoid
from phoid import DelayedPD, DigitalPD, Estimate, Plant, characteristic_roots, digital_roots
from phoid.interop import LinearPlant, closed_loop, linear_plant, sample_plants, to_lti
from phoid.interop.control import PADE_RTOL, pade_order_for

ROOT = Path(__file__).resolve().parents[1]
PLANT = Plant(2.0, 1.0, 64.0)
P_GAINS = np.array([0.25, 8.5, 16.75, 25.0])
D_GAINS = np.array([0.6, 2.4, 4.2, 6.0])
# relative accuracy of a quadratic's or a low-degree polynomial's roots computed two ways
# (numpy's companion eigenvalues vs phoid's closed form): a few hundred ulps
ROOT_RTOL = 1e-12


def _pho(delay: float, seed: int = 7):
    sim = phoid.simulate(PLANT, P_GAINS, D_GAINS, delay=delay, duration=10.0, fs=1000.0,
                         x0=0.01, hold=0.2, noise=1e-6, rng=np.random.default_rng(seed))
    return sim, phoid.identify_data([(sim.t, sim.x[i]) for i in range(P_GAINS.size)], P_GAINS,
                                    D_GAINS, delay)


@pytest.fixture(scope="module")
def pho_delayed():
    return _pho(0.02)


@pytest.fixture(scope="module")
def pho_undelayed():
    return _pho(0.0)


def _sorted(z):
    z = np.asarray(z, dtype=complex)
    return z[np.lexsort((z.imag, z.real))]


# --------------------------------------------------------------------------------------------
# the plant


def test_plant_tf_poles_are_the_plants_roots(pho_delayed):
    control = pytest.importorskip("control")
    _, res = pho_delayed
    m, c, k = res.m.value, res.c.value, res.k.value
    G = res.to_control()
    assert isinstance(G, control.TransferFunction)
    want = _sorted(np.roots([m, c, k]))  # eq. (4), independently of phoid
    assert np.allclose(_sorted(G.poles()), want, rtol=ROOT_RTOL, atol=0)
    assert np.allclose(_sorted(Plant(m, c, k).roots), want, rtol=ROOT_RTOL, atol=0)
    # the covariance travels with it
    assert np.array_equal(G.phoid.cov, res.cov[:3, :3]) and G.phoid.kind == "plant"


def test_plant_dc_gain_and_step_final_value(pho_delayed):
    control = pytest.importorskip("control")
    _, res = pho_delayed
    k = res.k.value
    G = res.to_control()
    # static deflection under a unit force: x = F/k (eq. 1 at rest)
    assert control.dcgain(G) == pytest.approx(1.0 / k, rel=1e-12)
    # the step response settles to 1/k: after T the transient is below e^{-σT} of the step
    sigma = res.c.value / (2 * res.m.value)
    T = 25.0 / sigma  # e^{-25} ≈ 1.4e-11 of 1/k left, far below the 1e-8 asked
    resp = control.step_response(G, T=np.linspace(0.0, T, 20001))
    assert resp.outputs[-1] == pytest.approx(1.0 / k, rel=1e-8)


def test_state_space_has_states_x_and_v(pho_delayed):
    control = pytest.importorskip("control")
    _, res = pho_delayed
    m, c, k = res.m.value, res.c.value, res.k.value
    S = res.to_control(form="ss")
    assert isinstance(S, control.StateSpace)
    assert S.state_labels == ["x", "v"] and S.input_labels == ["F"]
    # d/dt (x, v) = (v, (F − c v − k x)/m): eq. (1) in state form
    assert np.allclose(S.A, [[0, 1], [-k / m, -c / m]], rtol=1e-15)
    assert np.allclose(S.B, [[0], [1 / m]], rtol=1e-15)
    assert np.allclose(_sorted(S.poles()), _sorted(np.roots([m, c, k])), rtol=ROOT_RTOL)


def test_scipy_lti_agrees_with_the_control_tf(pho_delayed):
    control = pytest.importorskip("control")
    _, res = pho_delayed
    w = np.array([0.1, 1.0, 5.0, 5.65, 30.0, 300.0])  # rad/s, around the resonance ω₀ ≈ 5.66
    G = res.to_control()
    resp = G.frequency_response(w)
    want = resp.magnitude.ravel() * np.exp(1j * resp.phase.ravel())
    _, H = res.to_lti().freqresp(w)
    assert np.allclose(H, want, rtol=1e-10, atol=0)
    # the state-space lti through its matrices, C (iωI − A)⁻¹ B + D (scipy's own freqresp of a
    # state space converts it to a transfer function, warning about its leading zero)
    ss = res.to_lti(form="ss")
    H = np.array([(ss.C @ np.linalg.solve(1j * wi * np.eye(2) - ss.A, ss.B) + ss.D)[0, 0]
                  for wi in w])
    assert np.allclose(H, want, rtol=1e-10, atol=0)
    # and both against the plant's own 1/(m s² + c s + k) at s = iω
    direct = 1.0 / (res.m.value * (1j * w) ** 2 + res.c.value * 1j * w + res.k.value)
    assert np.allclose(want, direct, rtol=1e-12, atol=0)
    del control


# --------------------------------------------------------------------------------------------
# closed loops


def test_closed_loop_without_delay_has_the_poles_of_eq31(pho_undelayed):
    pytest.importorskip("control")
    _, res = pho_undelayed
    m, c, k = res.m.value, res.c.value, res.k.value
    for i, (P, D) in enumerate(zip(P_GAINS, D_GAINS, strict=True)):
        T = res.closed_loop(i)
        # eq. (31): m s² + (c + D) s + (k + P) = 0
        want = _sorted(np.roots([m, c + D, k + P]))
        assert np.allclose(_sorted(T.poles()), want, rtol=ROOT_RTOL, atol=0)
        assert T.phoid.pade_order is None and T.phoid.P == P and T.phoid.D == D
    # by the run's file name too
    assert res.closed_loop(res.runs[2].file).phoid.P == P_GAINS[2]


def test_pade_loop_dominant_pole_converges_to_the_certified_root(pho_delayed):
    pytest.importorskip("control")
    _, res = pho_delayed
    m, c, k = res.m.value, res.c.value, res.k.value
    i = 3
    loop = DelayedPD(P_GAINS[i], D_GAINS[i], res.delay)
    exact = characteristic_roots(Plant(m, c, k), loop, count=2)[0]  # certified rightmost root
    errors = []
    for n in range(1, 6):
        T = res.closed_loop(i, pade_order=n)
        poles = np.asarray(T.poles())
        nearest = poles[np.argmin(np.abs(poles - exact))]
        errors.append(abs(nearest - exact) / abs(exact))
        # the approximate loop's rightmost pole is the dominant one (no spurious mode right of it)
        assert abs(poles[np.argmax(poles.real)].real - exact.real) <= 1e-2 * abs(exact)
        assert T.phoid.pole_error == pytest.approx(errors[-1], rel=1e-6, abs=1e-15)
    # the Padé error of e^{-x} at order n is ≈ (n!)²/((2n)!(2n+1)!) x^{2n+1}, x = |s*|Δt ≈ 0.14
    # here (each order gains ~3 decades), and the dominant root moves by that error times its
    # sensitivity |(Ds* + P)e^{-s*Δt} / f'(s*)| / |s*| (≈ 0.25 for this loop): 10× the Padé
    # error bounds the root's error with room, down to rounding (1e-12 for these coefficients)
    x = abs(exact) * res.delay
    for n, err in enumerate(errors, start=1):
        bound = math.factorial(n) ** 2 / (math.factorial(2 * n) * math.factorial(2 * n + 1))
        assert err < 10 * bound * x ** (2 * n + 1) + 1e-12, (n, err)
    assert errors[0] > errors[1] > errors[2] and errors[4] < 1e-11
    # the default order is the lowest meeting PADE_RTOL
    T = res.closed_loop(i)
    n0 = T.phoid.pade_order
    assert T.phoid.pole_error <= PADE_RTOL and (n0 == 1 or errors[n0 - 2] > PADE_RTOL)
    assert pade_order_for(m, c, k, P_GAINS[i], D_GAINS[i], res.delay)[0] == n0
    assert "Padé" in " ".join(T.phoid.notes)


def test_closed_loop_of_a_sampled_loop_is_the_exact_discrete_loop():
    control = pytest.importorskip("control")
    m, c, k = 2.0, 1.0, 64.0
    P, D, Ts, d, wc = 16.75, 4.2, 2e-3, 2, 300.0
    g = DigitalPD(P, D, sample_time=Ts, delay_samples=d, velocity="filtered", cutoff=wc)
    res = SimpleNamespace(
        m=Estimate(m, 1e-3, "kg"), c=Estimate(c, 1e-3, "N s/m"), k=Estimate(k, 1e-2, "N/m"),
        cov=np.diag([1e-6, 1e-6, 1e-4]), delay=g.delay, digital=g,
        runs=(SimpleNamespace(file="r1", P=P, D=D, added_mass=0.0),))
    T = closed_loop(res, 0)
    assert T.dt == Ts
    # its poles are phoid's exact roots of χ(z) (phoid.dynamics.digital)
    want = digital_roots(m, c, k, P, D, g).z[0]
    assert np.allclose(_sorted(T.poles()), _sorted(want), rtol=1e-9, atol=1e-12)
    # and it is python-control's own construction: the ZOH plant in a loop with the filtered
    # derivative K(z) = P + D c_f (z − 1)/(z − a) and d samples of delay, at a few frequencies
    a = math.exp(-wc * Ts)
    cf = (1 - a) / Ts
    Gz = control.sample_system(control.tf([1.0], [m, c, k]), Ts, "zoh")
    K = control.tf([P + D * cf, -(P * a + D * cf)], [1.0, -a], Ts)
    Zd = control.tf([1.0], [1.0] + [0.0] * d, Ts)
    ref = control.feedback(Gz, K * Zd)
    w = np.array([0.5, 5.0, 9.0, 50.0, 500.0])
    z = np.exp(1j * w * Ts)
    assert np.allclose(T(z), ref(z), rtol=1e-8, atol=0)
    assert T.phoid.sample_time == Ts and T.phoid.pade_order is None


def test_closed_loop_refuses_results_without_feedback_runs():
    pytest.importorskip("control")
    forced_like = SimpleNamespace(m=Estimate(2, 0.1, "kg"), c=Estimate(1, 0.1, "N s/m"),
                                  k=Estimate(64, 1, "N/m"), cov=np.eye(3) * 1e-2,
                                  runs=(SimpleNamespace(file="f1", omega=3.0),))
    with pytest.raises(ValueError, match="no feedback runs"):
        closed_loop(forced_like, 0)


# --------------------------------------------------------------------------------------------
# the covariance and the Monte Carlo sampler


def test_sampler_covariance_matches_the_results_within_monte_carlo_error(pho_delayed):
    _, res = pho_delayed
    n = 20000
    plants = res.sample_plants(n, np.random.default_rng(5))
    draws = np.array([[p.m, p.c, p.k] for p in plants])
    cov = res.cov[:3, :3]
    mean = np.array([res.m.value, res.c.value, res.k.value])
    # no draw can be rejected here: every estimate is > 1000 stderr from 0
    assert np.all(mean / np.sqrt(np.diag(cov)) > 1000)
    # the mean within 5 standard errors sqrt(Σii/n)
    assert np.all(np.abs(draws.mean(0) - mean) < 5 * np.sqrt(np.diag(cov) / n))
    # each element of the sample covariance has, for a normal sample, the standard error
    # sqrt((Σii Σjj + Σij²)/n); 5 of them: a false alarm has probability < 4e-6 over the six
    S = np.cov(draws, rowvar=False)
    se = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov**2) / n)
    assert np.all(np.abs(S - cov) < 5 * se), (S - cov) / se


def test_sampler_rejects_non_physical_draws_and_gives_up_when_most_are():
    near = LinearPlant(1.0, 0.01, 4.0, cov=np.diag([1e-4, 1e-4, 1e-2]))  # c only 1 sd from 0
    draws = near.draw(2000, 3)
    assert draws.shape == (2000, 3) and np.all(draws[:, 1] >= 0) and np.all(draws[:, 0] > 0)
    hopeless = LinearPlant(1.0, -5.0, 4.0, cov=np.diag([1e-4, 1.0, 1e-2]))  # P(c ≥ 0) ≈ 3e-7
    with pytest.raises(ValueError, match="too uncertain"):
        hopeless.draw(10, 1)
    with pytest.raises(ValueError, match="`n`"):
        near.draw(0)


def test_sampled_plants_as_systems(pho_delayed):
    control = pytest.importorskip("control")
    _, res = pho_delayed
    tfs = res.sample_plants(3, 11, form="tf")
    plants = res.sample_plants(3, 11)
    for G, p in zip(tfs, plants, strict=True):
        assert isinstance(G, control.TransferFunction)
        assert np.allclose(_sorted(G.poles()), _sorted(np.roots([p.m, p.c, p.k])),
                           rtol=ROOT_RTOL)
    assert len(sample_plants(res, 2, 1, form="lti")) == 2


# --------------------------------------------------------------------------------------------
# the other results


def _free(mass=None):
    t = np.arange(0.0, 10.0, 1e-3)
    x, _ = PLANT.free_response(t, 0.01)
    x = x + 1e-6 * np.random.default_rng(3).standard_normal(t.size)
    t = np.r_[-0.2 + t[:200], t + 1e-3 * 0]  # a held segment before the release
    x = np.r_[np.full(200, 0.01), x]
    keep = np.r_[np.diff(t) > 0, True]
    return phoid.identify_free_data([(t[keep], x[keep])], mass=mass)


def test_free_decay_needs_a_mass_or_says_per_unit_mass():
    pytest.importorskip("control")
    res = _free()
    with pytest.raises(ValueError, match="per_unit_mass"):
        res.to_control()
    G = res.to_control(per_unit_mass=True)
    # 1/(s² + 2σ s + ω₀²): the plant's poles, without its mass
    want = np.roots([1.0, 2 * res.sigma.value, res.k_over_m.value])
    assert np.allclose(_sorted(G.poles()), _sorted(want), rtol=ROOT_RTOL)
    assert G.phoid.plant.per_unit_mass and "per unit mass" in G.phoid.notes[0]
    with_mass = _free(mass=2.0)
    lp = linear_plant(with_mass)
    assert lp.m == 2.0 and lp.cov[0, 0] == 0.0
    # c = 2σm, k = ω₀²m: var c = 4m² var σ (eq. 3 with m given)
    assert lp.cov[1, 1] == pytest.approx(4 * 4.0 * with_mass.cov[0, 0], rel=1e-12)
    assert np.allclose(lp.values, [2.0, with_mass.c.value, with_mass.k.value], rtol=1e-15)


def test_friction_fit_exports_its_linear_part():
    pytest.importorskip("control")
    from phoid.methods.friction.results import FrictionFit, FrictionRun

    cov = np.arange(16.0).reshape(4, 4)
    cov = cov @ cov.T + np.eye(4)
    run = FrictionRun("r1", 8.5, 2.4, True, 0.2, 0.01, 0.0, 0.4, 5.6, None, -1, 10.0, 1000,
                      1e-6, 1e-6, added_mass=0.5)
    fit = FrictionFit(Estimate(2.0, 0.01, "kg"), Estimate(1.0, 0.01, "N s/m"),
                      Estimate(64.0, 0.1, "N/m"), Estimate(0.3, 0.01, "N"), cov, 0.0, (run,),
                      1.0, 10, 1e-6, True, 3, (2.0, 1.0, 64.0, 0.3))
    G = fit.to_control()
    assert np.array_equal(G.phoid.cov, cov[:3, :3])
    assert "fc = 0.3 N is dropped" in G.phoid.notes[0]
    T = fit.closed_loop("r1")
    # eq. (31) with the run's mass m + Δm = 2.5 kg: 2.5 s² + (1 + 2.4) s + (64 + 8.5)
    assert np.allclose(_sorted(T.poles()), _sorted(np.roots([2.5, 3.4, 72.5])), rtol=ROOT_RTOL)
    assert T.phoid.added_mass == 0.5 and "added mass" in T.phoid.notes[-1]


def test_tracking_result_covariance_by_parameter_name():
    # an IDIM fit names m and c "M" and "Fv"; fixed parameters (k here) have zero variance
    est = {"m": Estimate(2.0, 0.1, "kg"), "c": Estimate(1.0, 0.2, "N s/m"),
           "k": Estimate(0.0, 0.0, "N/m"), "fc": Estimate(0.5, 0.1, "N")}
    full = np.array([[1.0, 0.2, 0.3, 0.4], [0.2, 2.0, 0.5, 0.6], [0.3, 0.5, 3.0, 0.7],
                     [0.4, 0.6, 0.7, 4.0]])
    res = SimpleNamespace(estimates=est, fit=SimpleNamespace(free=("M", "Fv", "Fc", "OF"),
                                                             covariance=full), path=None)
    lp = linear_plant(res)
    assert np.array_equal(lp.cov, [[1.0, 0.2, 0.0], [0.2, 2.0, 0.0], [0.0, 0.0, 0.0]])
    assert lp.values.tolist() == [2.0, 1.0, 0.0] and "fc" in lp.notes[0]
    assert to_lti(res).den.tolist() == [1.0, 0.5, 0.0]  # 1/(2s² + s) normalised by scipy


# --------------------------------------------------------------------------------------------
# optional dependencies


def test_missing_python_control_is_one_clear_line(monkeypatch, pho_delayed):
    _, res = pho_delayed
    monkeypatch.setitem(sys.modules, "control", None)  # `import control` raises ImportError
    msg = "python-control is not installed: pip install 'phoid[control]'"
    for call in (res.to_control, lambda: res.closed_loop(0),
                 lambda: res.sample_plants(2, 1, form="tf")):
        with pytest.raises(ImportError) as info:
            call()
        assert str(info.value) == msg
    # scipy.signal needs no python-control
    assert res.to_lti().den.size == 3 and len(res.sample_plants(2, 1)) == 2


def test_missing_pandas_is_one_clear_line(monkeypatch, pho_delayed):
    _, res = pho_delayed
    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(ImportError, match=r"^pandas is not installed: pip install "
                                          r"'phoid\[pandas\]'$"):
        res.to_pandas()


def test_interop_imports_neither_control_nor_pandas_nor_scipy_signal():
    code = ("import sys, json, phoid, phoid.interop; print(json.dumps([m for m in "
            "('control', 'pandas', 'scipy.signal') if m in sys.modules]))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=ROOT, env={"PYTHONPATH": str(ROOT / "src"), "PATH": ""},
                       timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(r.stdout.strip().splitlines()[-1]) == []


# --------------------------------------------------------------------------------------------
# pandas out


def test_to_pandas_tables(pho_delayed):
    pd = pytest.importorskip("pandas")
    _, res = pho_delayed
    est, runs = res.to_pandas()
    assert isinstance(est, pd.DataFrame) and list(est.columns) == ["value", "stderr", "unit"]
    for q in "mck":
        e = getattr(res, q)
        assert est.loc[q, "value"] == e.value and est.loc[q, "stderr"] == e.stderr
        assert est.loc[q, "unit"] == e.unit
    assert len(runs) == len(res.runs) == P_GAINS.size
    assert runs["P"].tolist() == P_GAINS.tolist() and runs["file"].tolist() == [
        r.file for r in res.runs]
    assert runs["sigma"].tolist() == [r.sigma for r in res.runs]


# --------------------------------------------------------------------------------------------
# pandas in


def test_dataframe_with_timedelta_index_identifies_exactly_as_arrays():
    pd = pytest.importorskip("pandas")
    sim, _ = _pho(0.02)
    # whole nanoseconds (1 ms steps): the index holds the times exactly; t_i = n_i/1e9
    ns = np.round(sim.t * 1e9).astype(np.int64)
    t = (ns - ns[0]) / 1e9
    frames = [pd.DataFrame({"x": sim.x[i]}, index=pd.to_timedelta(ns, unit="ns"))
              for i in range(P_GAINS.size)]
    via_frames = phoid.identify_data(frames, P_GAINS, D_GAINS, 0.02)
    via_arrays = phoid.identify_data([(t, sim.x[i]) for i in range(P_GAINS.size)], P_GAINS,
                                     D_GAINS, 0.02)
    for q in "mck":
        assert getattr(via_frames, q) == getattr(via_arrays, q)
    assert np.array_equal(via_frames.cov, via_arrays.cov)
    # a Series and a DataFrame with a t column make the same run as the arrays
    run = phoid.run_from_arrays(t, sim.x[0], P=1.0, D=0.5)
    for table in (pd.Series(sim.x[0], index=pd.to_timedelta(ns, unit="ns")),
                  pd.DataFrame({"t": t, "x": sim.x[0]}), frames[0]):
        other = phoid.run_from_arrays(table, P=1.0, D=0.5)
        assert np.array_equal(other.t, run.t) and np.array_equal(other.x, run.x)


def test_datetime_index_is_seconds_from_the_first_sample():
    pd = pytest.importorskip("pandas")
    idx = pd.date_range("2026-01-01 12:00", periods=5, freq="250ms", tz="Europe/Paris")
    run = phoid.run_from_arrays(pd.Series(np.arange(5.0), index=idx))
    assert run.t.tolist() == [0.0, 0.25, 0.5, 0.75, 1.0]
    df = pd.DataFrame({"x": np.zeros(3), "u": np.ones(3)}, index=pd.Index([0.0, 0.1, 0.2]))
    run = phoid.run_from_arrays(df)
    assert run.u.tolist() == [1.0, 1.0, 1.0] and run.t.tolist() == [0.0, 0.1, 0.2]


@pytest.mark.parametrize(("table", "match"), [
    ("nonmonotonic", r"^data\[0\]: the index \(t\) is not strictly increasing at position 2"),
    ("nan", r"^data\[0\]: column 'x' has a non-finite value \(nan\) at position 1$"),
    ("no_x", r"^data\[0\]: missing column 'x'"),
    ("unknown", r"^data\[0\]: unknown column\(s\) 'y'"),
    ("range_index", r"^data\[0\]: the index \(t\) is the default 0, 1, 2"),
])
def test_bad_tables_are_one_line_errors_naming_argument_and_column(table, match):
    pd = pytest.importorskip("pandas")
    idx = pd.Index([0.0, 0.1, 0.05, 0.3])
    tables = {
        "nonmonotonic": pd.DataFrame({"x": np.zeros(4)}, index=idx),
        "nan": pd.DataFrame({"x": [0.0, np.nan, 0.0, 0.0]}, index=idx.sort_values()),
        "no_x": pd.DataFrame({"u": np.zeros(4)}, index=idx.sort_values()),
        "unknown": pd.DataFrame({"x": np.zeros(4), "y": np.zeros(4)}, index=idx.sort_values()),
        "range_index": pd.DataFrame({"x": np.zeros(4)}),
    }
    with pytest.raises(ValueError, match=match) as info:
        phoid.identify_data([tables[table]], [1.0], [0.5], 0.0)
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match=match.replace(r"data\[0\]", "t")):
        phoid.run_from_arrays(tables[table])


def test_tracking_identification_exports_m_c_k(tmp_path):
    # a tracking set of one run (a small axis, k = 0, under a 1 kHz PD loop; the recipe of
    # tests/test_tracking_cli.py), identified by IDIM-LS
    from phoid.dynamics.controller import SampledController
    from phoid.simulation.tracking import simulate_tracking

    ctrl = SampledController(sample_time=1e-3, P=4000.0, D=60.0, velocity="central-difference",
                             saturation=200.0, delay=0.4e-3)
    t = 1e-3 * np.arange(3000)
    r = 0.02 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * np.sin(2 * np.pi * 1.9 * t + 0.3)
    sim = simulate_tracking(Plant(2.0, 15.0, 0.0, 1.5), ctrl, r, offset=-0.3, x_init=[0.0])
    run = phoid.run_from_arrays(t, sim.x, r=r, u=sim.command, P=4000.0, D=60.0, index=1)
    phoid.write_experiment(tmp_path, [run], method="tracking", fixed={"k": 0.0},
                           loop={"sample_time": 1e-3, "velocity": "central-difference",
                                 "saturation": 200.0, "delay": 0.4e-3})
    res = phoid.identify(phoid.read_experiment(tmp_path), estimator="idim")
    lp = linear_plant(res)
    m, c = res.estimates["m"].value, res.estimates["c"].value
    assert lp.values.tolist() == [m, c, 0.0]
    # (m, c)'s block of the covariance the estimates carry (the adequacy's: robust where a
    # check failed, else the fit's own), by the fit's names; k fixed: zero variance
    i, j = res.fit.free.index("M"), res.fit.free.index("Fv")
    carried = res.fit.covariance if res.adequacy is None else res.adequacy.robust_cov
    assert lp.cov[0, 1] == carried[i, j] and lp.cov[2, 2] == 0.0
    assert math.sqrt(lp.cov[0, 0]) == res.estimates["m"].stderr
    G = to_lti(res)
    assert np.allclose(_sorted(G.poles), _sorted(np.roots([m, c, 0.0])), rtol=ROOT_RTOL,
                       atol=1e-12)
    pd = pytest.importorskip("pandas")
    est, runs = res.to_pandas()
    assert isinstance(runs, pd.DataFrame) and len(runs) == 1
    assert est.loc["fc", "value"] == res.estimates["fc"].value and est.loc["m", "unit"] == "kg"


def test_docstring_examples_run():
    pytest.importorskip("control")
    import doctest

    from phoid.interop import control as control_module
    from phoid.interop import plant as plant_module

    for module in (plant_module, control_module):
        result = doctest.testmod(module)
        assert result.attempted > 0 and result.failed == 0


def test_a_sampled_loops_identification_exports_its_measured_modes():
    pytest.importorskip("control")
    # the digital loop of tests/test_digital_identify.py: T_s = 2 ms, backward difference,
    # 3 samples of delay; plant m 1, c 2, k 100
    plant = Plant(1.0, 2.0, 100.0)
    P, D = np.linspace(20.0, 200.0, 4), np.linspace(0.5, 5.0, 4)
    loop = DigitalPD(0.0, 0.0, sample_time=0.002, delay_samples=3)
    sim = phoid.simulate(plant, P, D, duration=10.0, fs=500.0, x0=0.01, hold=0.2, noise=1e-5,
                         rng=np.random.default_rng(2), sample_time=0.002, delay_samples=3,
                         noise_in_loop=False)
    res = phoid.identify_data([(sim.t, sim.x[i]) for i in range(P.size)], P, D, None,
                              digital=loop)
    for i, run in enumerate(res.runs):
        T = res.closed_loop(i)
        assert T.dt == 0.002 and T.phoid.delay == 0.006
        s = T.phoid.dominant_pole  # ln(z)/T_s of the exported loop's dominant pole
        # the run's measured dominant mode (its own decay fit), within 5 of its stderrs
        assert abs(-s.real - run.sigma) < 5 * run.sigma_stderr, (i, s, run.sigma)
        assert abs(abs(s.imag) - run.omega_d) < 5 * run.omega_d_stderr, (i, s, run.omega_d)
