"""Hostile inputs of issue 27: free-decay fits in extreme time and x units, the known mass's
bounds and overflow, option values routed through the registry, a path given to
:func:`phoid.identify`, a flag given as None.

Every record is generated here (:func:`phoid.dynamics.plant.free_response`: σ = 0.1 1/s,
ω₀ = 10 rad/s, x₀ = 0.01 m, 4000 samples at 200 Hz, white noise of sd 1e-5 m from a fixed
seed); the expected σ, ω₀ in another unit are those of the same record in seconds and metres,
scaled (σ·s, ω₀·s for t·s; unchanged for x·s).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import phoid
from phoid._validate import overflow_warnings
from phoid.cli import app
from phoid.dynamics.plant import free_response
from phoid.errors import IdentificationError
from phoid.io import read_experiment
from phoid.methods.estimate import Estimate
from phoid.methods.free import identify_free_data
from phoid.methods.free_friction import identify_free_friction_data


def _record() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(27)
    t = np.arange(4000) / 200.0
    x, _ = free_response(t, 0.1, 100.0, 0.01, 0.0)
    return t, x + 1e-5 * rng.standard_normal(t.size)


def _set(folder: Path, t: np.ndarray, x: np.ndarray, extra: str = "") -> Path:
    folder.mkdir()
    rows = "\n".join(f"{a!r},{b!r}" for a, b in zip(t.tolist(), x.tolist(), strict=True))
    (folder / "r.csv").write_text("t,x\n" + rows + "\n")
    (folder / "experiment.toml").write_text(f'method = "free"\n{extra}\n[[run]]\nfile = "r.csv"\n')
    return folder


#: misfit words the fit would say for a record it cannot follow (none is true here)
_FALSE = ("misfit", "amplitude", "did not converge", "disagree")


@pytest.mark.parametrize("scale", [1e-25, 1e-10, 1e10, 1e25])
def test_free_fit_is_time_scale_free(scale):
    # the same record with t in another unit: σ, ω₀ scale by 1/scale (σ·scale, ω₀·scale the
    # same). Tolerance 1e-7 relative: the fit works in units of a power of two near the span,
    # so only the last bits of t differ (observed ≤ 1e-10); before the fix σ·scale was off by
    # 1 % to 70 % with a false "amplitude-dependent stiffness" misfit
    t, x = _record()
    ref = identify_free_data([(t, x)])
    res = identify_free_data([(t * scale, x)])
    assert res.sigma.value * scale == pytest.approx(ref.sigma.value, rel=1e-7)
    assert res.omega0.value * scale == pytest.approx(ref.omega0.value, rel=1e-7)
    assert res.sigma.stderr * scale == pytest.approx(ref.sigma.stderr, rel=1e-4)
    assert not [w for w in res.warnings if any(word in w for word in _FALSE)]


@pytest.mark.parametrize("scale", [1e-25, 1e25])
def test_free_friction_fit_is_time_scale_free(scale):
    # as above with --friction (least_squares stops at a relative change of 1e-8: tolerance
    # 1e-6 relative); before the fix 1e-30 Hz failed "JᵀJ is singular"
    t, x = _record()
    ref = identify_free_friction_data([(t, x)])
    res = identify_free_friction_data([(t * scale, x)])
    assert res.sigma.value * scale == pytest.approx(ref.sigma.value, rel=1e-6)
    assert res.omega0.value * scale == pytest.approx(ref.omega0.value, rel=1e-6)


@pytest.mark.parametrize("scale", [1e-25, 1e25])
def test_free_fits_are_x_scale_free(scale):
    # x in another unit within 1e-30 … 1e30: σ and ω₀ unchanged (tolerance as above)
    t, x = _record()
    ref = identify_free_data([(t, x)])
    res = identify_free_data([(t, x * scale)])
    assert res.sigma.value == pytest.approx(ref.sigma.value, rel=1e-7)
    assert res.omega0.value == pytest.approx(ref.omega0.value, rel=1e-7)
    assert res.runs[0].noise_sd / scale == pytest.approx(ref.runs[0].noise_sd, rel=1e-6)
    fr = identify_free_friction_data([(t, x * scale)])
    assert fr.sigma.value == pytest.approx(identify_free_friction_data([(t, x)]).sigma.value,
                                           rel=1e-6)


@pytest.mark.parametrize(("tscale", "xscale", "field"), [
    (1e-33, 1.0, "sample step of t"), (1e40, 1.0, "sample step of t"),
    (1.0, 1e302, "x reaches"), (1.0, 1e-300, "x reaches")])
def test_out_of_range_units_are_refused_in_one_line(tmp_path, tscale, xscale, field):
    # outside 1e-30 … 1e30 (step in s, largest |x|) σ, ω₀² or x's squares leave the floating
    # point: refused, naming the manifest, the run, the field and the cure
    t, x = _record()
    folder = _set(tmp_path / "s", t[:400] * tscale, x[:400] * xscale)
    for friction in ([], ["--friction"]):
        out = CliRunner().invoke(app, ["identify", str(folder), *friction])
        assert out.exit_code == 2, out.output
        line = out.output.strip()
        assert "\n" not in line and "Traceback" not in line and "Warning" not in line
        assert "experiment.toml" in line and "r.csv" in line and field in line
        assert "1e-30 … 1e30" in line and "[units]" in line


@pytest.mark.parametrize("bad", ["-2", "nan", "inf", "1e308", "1e-320", "0"])
def test_bad_mass_names_the_set_and_the_option(tmp_path, bad):
    t, x = _record()
    folder = _set(tmp_path / "s", t[:800], x[:800])
    out = CliRunner().invoke(app, ["identify", str(folder), "--mass", bad])
    assert out.exit_code == 2
    assert "experiment.toml" in out.output and "--mass" in out.output
    assert "1e-30 … 1e30 kg" in out.output
    exp = read_experiment(folder)
    with pytest.raises(IdentificationError, match=r"experiment\.toml: `mass` must be"):
        phoid.identify(exp, mass=float(bad))
    with pytest.raises(IdentificationError, match=r"experiment\.toml: `mass` must be"):
        phoid.identify(exp, mass=float(bad), friction=True)


def test_manifest_mass_out_of_range_names_the_manifest(tmp_path):
    t, x = _record()
    folder = _set(tmp_path / "s", t[:800], x[:800], extra="mass = 1e300")
    with pytest.raises(IdentificationError, match=r"experiment\.toml: mass \(the manifest's\)"):
        phoid.identify(read_experiment(folder))


def test_mass_at_the_bound_gives_finite_c_and_k():
    # mass 1e30 kg (the bound): c = 2σm, k = ω₀²m, f_c = a·m all finite, no null
    t, x = _record()
    res = identify_free_friction_data([(t, x)], mass=1e30)
    summary = res.summary()
    for key in ("c", "k"):
        assert summary[key]["value"] is not None and summary[key]["stderr"] is not None
    assert summary["c"]["value"] == pytest.approx(2 * res.sigma.value * 1e30, rel=1e-12)


def test_an_overflowing_product_is_warned():
    # a product the floating point cannot hold is reported null, and says why
    est = Estimate(math.inf, math.inf, "N/m")
    ws = overflow_warnings(1e30, [("k = ω₀²m", est, 1e300)])
    assert len(ws) == 1 and "k = ω₀²m" in ws[0] and "overflows" in ws[0]
    assert overflow_warnings(1.0, [("k = ω₀²m", Estimate(1.0, 0.1, "N/m"), 1.0)]) == []


def test_identify_accepts_a_path(tmp_path):
    t, x = _record()
    folder = _set(tmp_path / "s", t[:800], x[:800])
    ref = phoid.identify(read_experiment(folder))
    for given in (str(folder), folder, os.fspath(folder / "experiment.toml")):
        assert phoid.identify(given).sigma.value == ref.sigma.value
    with pytest.raises(TypeError, match=r"needs an ExperimentSet .* or the path"):
        phoid.identify(3)


@pytest.mark.parametrize(("keyword", "value"), [("compensate", None), ("compensate", "no"),
                                                ("friction", None), ("friction", 1)])
def test_a_flag_must_be_a_bool(tmp_path, keyword, value):
    # None is not "not given" for a bool option: refused like any other non-bool
    t, x = _record()
    folder = _set(tmp_path / "s", t[:800], x[:800])
    with pytest.raises(IdentificationError,
                       match=rf"experiment\.toml: `{keyword}` must be True or False"):
        phoid.identify(read_experiment(folder), **{keyword: value})
