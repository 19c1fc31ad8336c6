"""IDIM-LS (phoid.methods.idim): the EMPS record, exact recovery, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from phoid.methods import IDIMFit, idim_ls

EMPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "emps"
EMPS_FILE = EMPS / "DATA_EMPS.mat"
EMPS_ABSENT = (
    f"the EMPS record is absent ({EMPS_FILE}): it lies beside the checkout (../shared/data/emps) "
    "in CI, not in a clone")

# The benchmark's published IDIM-LS (EMPS README and description): value, stderr.
PUBLISHED = {"M": (95.1089, 0.1085), "Fv": (203.5034, 1.146), "Fc": (20.3935, 0.1012),
             "OF": (-3.1648, 0.0444)}
PUBLISHED_RELATIVE_ERROR = 4.0834  # %
PUBLISHED_CONDITION = 25.99


@pytest.fixture(scope="module")
def emps_fit() -> IDIMFit:
    if not EMPS_FILE.is_file():
        pytest.skip(EMPS_ABSENT)
    from scipy.io import loadmat

    data = loadmat(EMPS_FILE)
    return idim_ls(data["t"].ravel(), data["qm"].ravel(), data["vir"].ravel(),
                   gain=float(data["gtau"].ravel()[0]))


def test_emps_close_to_published(emps_fit: IDIMFit) -> None:
    """The documented recipe on the real record lands within a fifth of a published stderr of
    every published estimate, its stderrs within 2 %, its relative error within 2 % and its
    condition number within 0.1 % (the published digits themselves: next test)."""
    for name, (value, stderr) in PUBLISHED.items():
        est = getattr(emps_fit, name)
        assert abs(est.value - value) <= 0.2 * stderr, (name, est.value, value)
        assert est.stderr == pytest.approx(stderr, rel=0.02), (name, est.stderr, stderr)
    assert emps_fit.relative_error == pytest.approx(PUBLISHED_RELATIVE_ERROR, rel=0.02)
    assert emps_fit.condition_number == pytest.approx(PUBLISHED_CONDITION, rel=1e-3)
    assert emps_fit.lag1_autocorrelation > 0.5  # strongly autocorrelated: model error
    assert "lag-1 autocorrelation is 0.6" in emps_fit.warnings[0]
    summary = emps_fit.summary()
    assert set(summary["parameters"]) == {"M", "Fv", "Fc", "OF"}
    assert summary["parameters"]["M"]["unit"] == "kg"


@pytest.mark.xfail(strict=True, reason=(
    "the published digits are not reproduced yet: the recipe as documented (filtfilt and "
    "decimate with MATLAB's conventions, trim 50) gives M 95.1163 ± 0.1074, Fv 203.373 ± 1.136, "
    "Fc 20.409 ± 0.1004, OF −3.1700 ± 0.0440, 4.039 %, cond 26.006 on 2475 rows; the benchmark's "
    "printed error norm 108.7569 and deviation 2.1843 imply 2483 rows, so its script trims or "
    "aligns differently from the README's description"))
def test_emps_published_digits(emps_fit: IDIMFit) -> None:
    """M 95.1089 ± 0.1085 kg, Fv 203.5034 ± 1.146 N s/m, Fc 20.3935 ± 0.1012 N,
    OF −3.1648 ± 0.0444 N, 4.0834 %, condition 25.99: to every printed digit."""
    for name, (value, stderr) in PUBLISHED.items():
        est = getattr(emps_fit, name)
        assert round(est.value, 4) == value, name
        assert round(est.stderr, 4 if name != "Fv" else 3) == stderr, name
    assert round(emps_fit.relative_error, 4) == PUBLISHED_RELATIVE_ERROR
    assert round(emps_fit.condition_number, 2) == PUBLISHED_CONDITION


def _synthetic(n: int = 20000, dt: float = 1e-3):
    """A smooth two-tone trajectory and its exact force from the model (M 95 kg, Fv 200 N s/m,
    Fc 20 N, OF −3 N). The tones are well below the 100 Hz filter and the 40 Hz decimation
    cut-off, and no velocity zero falls on a sample (so sign(q̇) is unambiguous)."""
    t = np.arange(n) * dt
    w1, w2, phase = 2 * np.pi * 0.37, 2 * np.pi * 1.13, 0.4
    q = 0.05 * np.sin(w1 * t) + 0.02 * np.sin(w2 * t + phase)
    v = 0.05 * w1 * np.cos(w1 * t) + 0.02 * w2 * np.cos(w2 * t + phase)
    a = -0.05 * w1**2 * np.sin(w1 * t) - 0.02 * w2**2 * np.sin(w2 * t + phase)
    force = 95.0 * a + 200.0 * v + 20.0 * np.sign(v) - 3.0
    return t, q, force


def test_exact_recovery_noise_free() -> None:
    """Noise-free record: M, Fv, Fc, OF recovered to 1e-4 relative. The one error left is the
    bias of the central differences on a tone of angular frequency ω, a factor
    (sin ωT / ωT)² ≈ 1 − (ωT)²/3 on q̈ (1.7e-5 at 1.13 Hz, 1 ms; the Butterworth's passband
    loss at 1 Hz is ~1e-16), which the fit spreads over the four parameters: measured
    ≤ 1.6e-5, so 1e-4 holds with margin and still fails for any real error of the recipe
    (a sample offset or a wrong filter moves M by 1e-3 or more)."""
    t, q, force = _synthetic()
    fit = idim_ls(t, q, force / 35.0, gain=35.0)
    got = np.array([fit.M.value, fit.Fv.value, fit.Fc.value, fit.OF.value])
    np.testing.assert_allclose(got, [95.0, 200.0, 20.0, -3.0], rtol=1e-4)
    assert fit.relative_error < 1e-2
    assert fit.n_samples == -(-(t.size - 100) // 10)
    assert fit.covariance.shape == (4, 4)
    # no decimation: the same recovery
    fit1 = idim_ls(t, q, force, gain=1.0, decimation=1)
    got1 = np.array([fit1.M.value, fit1.Fv.value, fit1.Fc.value, fit1.OF.value])
    np.testing.assert_allclose(got1, [95.0, 200.0, 20.0, -3.0], rtol=1e-3)


@pytest.mark.parametrize(("change", "message"), [
    ({"q": np.zeros(10)}, "q: length 10 differs"),
    ({"u": np.zeros(10)}, "u: length 10 differs"),
    ({"t": "nonuniform"}, "t: must be uniformly increasing"),
    ({"q": "nan"}, "q: contains non-finite"),
    ({"u": "inf"}, "u: contains non-finite"),
    ({"gain": 0.0}, "gain: must be a finite number > 0"),
    ({"gain": -35.0}, "gain: must be a finite number > 0"),
    ({"cutoff": 600.0}, "cutoff: must lie in"),
    ({"decimation": 0}, "decimation: must be an integer >= 1"),
    ({"trim": -1}, "trim: must be an integer >= 0"),
    ({"short": 120}, "t: too short for the filter/decimation"),
    ({"q2d": True}, "q: must be one-dimensional"),
])
def test_bad_input(change: dict, message: str) -> None:
    t, q, force = _synthetic(2000)
    kwargs = {"gain": 35.0}
    u = force / 35.0
    if "short" in change:
        n = change["short"]
        t, q, u = t[:n], q[:n], u[:n]
    if "q2d" in change:
        q = np.stack([q, q])
    for name in ("gain", "cutoff", "decimation", "trim"):
        if name in change:
            kwargs[name] = change[name]
    if isinstance(change.get("t"), str):
        t = t.copy()
        t[1000:] += 0.5e-3
    if isinstance(change.get("q"), np.ndarray):
        q = change["q"]
    if isinstance(change.get("u"), np.ndarray):
        u = change["u"]
    if isinstance(change.get("q"), str):
        q = q.copy()
        q[5] = np.nan
    if isinstance(change.get("u"), str):
        u = u.copy()
        u[5] = np.inf
    with pytest.raises(ValueError, match=message) as info:
        idim_ls(t, q, u, **kwargs)
    assert "\n" not in str(info.value)


def test_scipy_signal_not_at_module_top() -> None:
    """phoid.methods.idim imports scipy.signal only inside its functions."""
    import ast

    import phoid.methods.idim as module

    tree = ast.parse(Path(module.__file__).read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Import):
            assert all(not a.name.startswith("scipy.signal") for a in node.names)
        if isinstance(node, ast.ImportFrom):
            assert not (node.module or "").startswith("scipy.signal")
            assert not (node.module == "scipy" and any(a.name == "signal" for a in node.names))
