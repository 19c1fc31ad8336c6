"""The figures: each one's elements exist, and what they draw is what was fitted.

Sets: examples/paper-sample (the repository's PHO sample: 19 runs with a recorded u) and small
sets written by ``phoid simulate`` (forced, free, friction). The figures are made through the
public drawing functions of :mod:`phoid.reports.lines`, :mod:`phoid.reports.runs` and
:meth:`phoid.planning.result.Design.plot`, which return the matplotlib Figure; the file names
through :meth:`plot` of each result.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import phoid
from phoid.cli import app
from phoid.dynamics.loop import inverse_map
from phoid.io import read_experiment
from phoid.reports.figures import png_bytes, render_pngs, run_names
from phoid.reports.lines import (
    ELLIPSE_LEVELS,
    forced_lines_figure,
    mk_covariance,
    mk_ellipse_figure,
    pho_line_points,
    pho_lines_figure,
)
from phoid.reports.runs import (
    forced_run_figure,
    free_run_figure,
    friction_run_figure,
    pho_run_figure,
    residual_acf,
    stick_intervals,
)

runner = CliRunner()
SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "paper-sample"


@pytest.fixture(scope="module")
def gls():
    return phoid.identify(read_experiment(SAMPLE))


@pytest.fixture(scope="module")
def ols_uncompensated():
    return phoid.identify(read_experiment(SAMPLE), estimator="ols", compensate=False)


@pytest.fixture(scope="module")
def forced(tmp_path_factory):
    out = tmp_path_factory.mktemp("forced") / "sweep"
    r = runner.invoke(app, ["simulate", str(out), "--method", "forced", "--omega", "2:14:5",
                            "--duration", "12", "--fs", "250", "--noise", "1e-5", "--seed", "3"])
    assert r.exit_code == 0, r.output
    return phoid.identify(read_experiment(out))


@pytest.fixture(scope="module")
def free(tmp_path_factory):
    out = tmp_path_factory.mktemp("free") / "set"
    r = runner.invoke(app, ["simulate", str(out), "--method", "free", "--m", "1", "--c", "2",
                            "--k", "100", "--duration", "6", "--fs", "500", "--noise", "1e-5",
                            "--seed", "4"])
    assert r.exit_code == 0, r.output
    return phoid.identify(read_experiment(out))


@pytest.fixture(scope="module")
def friction_set(tmp_path_factory):
    """Three runs of a plant with Coulomb friction (the gains of identify_friction's docstring
    example), one of which sticks for good well before its record ends."""
    out = tmp_path_factory.mktemp("friction") / "set"
    r = runner.invoke(app, ["simulate", str(out), "--m", "1", "--c", "2", "--k", "100",
                            "--fc", "0.05", "--P", "0,100,200", "--D", "-1.6,0.6,2.8",
                            "--delay", "0.02", "--duration", "4", "--x0", "0.008",
                            "--noise", "1e-5", "--seed", "1"])
    assert r.exit_code == 0, r.output
    return out


@pytest.fixture(scope="module")
def friction(friction_set):
    from phoid.methods.friction import identify_friction_set

    return identify_friction_set(read_experiment(friction_set))


def _errorbars(ax):
    from matplotlib.container import ErrorbarContainer

    return [c for c in ax.containers if isinstance(c, ErrorbarContainer)]


def _points(container):
    line = container.lines[0]
    return np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)


def _fitted_line(ax):
    """The one plain Line2D of a line panel that is not an error bar's: the fitted line."""
    bar_lines = {id(ln) for c in _errorbars(ax) for ln in (c.lines[0], *c.lines[1])}
    lines = [ln for ln in ax.get_lines() if id(ln) not in bar_lines]
    assert len(lines) == 1
    return np.asarray(lines[0].get_xdata(), float), np.asarray(lines[0].get_ydata(), float)


# --------------------------------------------------------------------------------------------
# the eq. (35) and eq. (20) lines


@pytest.mark.parametrize("which", ["gls", "ols_uncompensated"])
def test_pho_lines_have_error_bars_residual_panels_and_the_line(which, request):
    ident = request.getfixturevalue(which)
    n_used = sum(r.used for r in ident.runs)
    fig = pho_lines_figure(ident)
    top = [ax for ax in fig.axes if "stderr" not in ax.get_ylabel()]
    low = [ax for ax in fig.axes if ax.get_ylabel() == "residual (stderr)"]
    assert len(top) == 2 and len(low) == 2
    for ax in (*top, *low):
        (bars,) = _errorbars(ax)
        assert _points(bars)[0].size == n_used
    for ax in top:
        assert len(_errorbars(ax)[0].lines[2]) == 2  # x and y error bars
    for ax in low:  # residual panel: ±1 bars (the residual's own stderr) around each point
        segs = _errorbars(ax)[0].lines[2][0].get_segments()
        assert all(abs(abs(s[1][1] - s[0][1]) - 2.0) < 1e-12 for s in segs)


@pytest.mark.parametrize("which", ["gls", "ols_uncompensated"])
def test_drawn_lines_pass_through_the_points_they_were_fitted_to(which, request):
    """The line drawn is the line fitted to the points drawn.

    OLS: each panel's line is the least-squares line of its own points (np.polyfit of the
    drawn points, degree 1; equal to rounding, 1e-9 relative). Without delay compensation
    the two lines' slopes differ (4.5 against 0.98 kg on this set), so a c′ line with the k′
    line's slope (what was drawn before) misses every point. GLS: the lines are the joint
    estimate's, slope m, intercepts −c and −k. In both, each residual panel's point is
    (y − line(x))/stderr with the line read off the figure.
    """
    ident = request.getfixturevalue(which)
    fig = pho_lines_figure(ident)
    top = [ax for ax in fig.axes if "stderr" not in ax.get_ylabel()]
    low = [ax for ax in fig.axes if ax.get_ylabel() == "residual (stderr)"]
    expected = pho_line_points(ident)
    for ax, axr, ln, intercept in zip(top, low, expected, (-ident.c.value, -ident.k.value),
                                      strict=True):
        x, y = _points(_errorbars(ax)[0])
        lx, ly = _fitted_line(ax)
        slope = (ly[-1] - ly[0]) / (lx[-1] - lx[0])
        icpt = ly[0] - slope * lx[0]
        if which == "ols_uncompensated":
            want = np.polyfit(x, y, 1)
            assert slope == pytest.approx(want[0], rel=1e-9)
            assert icpt == pytest.approx(want[1], rel=1e-9, abs=1e-9 * np.ptp(y))
        else:
            assert slope == pytest.approx(ident.m.value, rel=1e-9)
            assert icpt == pytest.approx(intercept, rel=1e-9)
        res = y - (slope * x + icpt)
        # the points scatter about the line: residuals change sign, none is beyond 1 % of
        # the points' spread (the old c' line was 3 N s/m, their whole spread, off)
        assert np.max(np.abs(res)) < 0.01 * np.ptp(y) or which == "ols_uncompensated"
        assert np.min(res) < 0 < np.max(res)
        _, z = _points(_errorbars(axr)[0])
        np.testing.assert_allclose(z * ln.residual_stderr, res, rtol=1e-6,
                                   atol=1e-9 * np.ptp(y))


def test_ols_uncompensated_slopes_differ():
    """The reason the old figure failed: the paper's uncompensated lines have different slopes
    (one line's slope is not the other's), so drawing 2mσ − c with m from the k′ line misses."""
    ident = phoid.identify(read_experiment(SAMPLE), estimator="ols", compensate=False)
    c_line, k_line = pho_line_points(ident)
    assert c_line.slope == pytest.approx(ident.fit.c_line.slope, rel=1e-12)
    assert k_line.slope == pytest.approx(ident.m.value, rel=1e-12)
    assert abs(c_line.slope - k_line.slope) > 1.0  # kg: 4.5 against 0.98 on this set


def test_residual_stderr_matches_monte_carlo(gls):
    """The delta-method stderr of c′ᵢ − (2mσᵢ − c) and k′ᵢ − (mω₀ᵢ² − k) against 20 000 draws
    of (σᵢ, ω_dᵢ) from N(estimate, the run's covariance), mapped through eq. (32)
    (inverse_map) at the result's delay. The sd of 20 000 draws is within 1.1 % of the truth
    at 2 sd (1/√(2·20000) = 0.5 %); the delta method's own error is below that, the errors
    being 1e-4 of σ and ω_d; hence 2 %."""
    lines = pho_line_points(gls)
    used = [r for r in gls.runs if r.used]
    rng = np.random.default_rng(0)
    for j in (0, len(used) // 2, len(used) - 1):
        r = used[j]
        draws = rng.multivariate_normal([r.sigma, r.omega_d], r.fit.cov[:2, :2], 20000)
        s, w = draws[:, 0], draws[:, 1]
        cp, kp = inverse_map(s, w, r.P, r.D, gls.delay)
        res_c = cp - (lines[0].slope * 2 * s + lines[0].intercept)
        res_k = kp - (lines[1].slope * (s**2 + w**2) + lines[1].intercept)
        assert np.std(res_c) == pytest.approx(lines[0].residual_stderr[j], rel=0.02)
        assert np.std(res_k) == pytest.approx(lines[1].residual_stderr[j], rel=0.02)
        assert np.std(2 * s) == pytest.approx(lines[0].xerr[j], rel=0.02)
        assert np.std(kp) == pytest.approx(lines[1].yerr[j], rel=0.02)


def test_forced_lines(forced):
    fig = forced_lines_figure(forced)
    top = [ax for ax in fig.axes if "stderr" not in ax.get_ylabel()]
    low = [ax for ax in fig.axes if ax.get_ylabel() == "residual (stderr)"]
    assert len(top) == 2 and len(low) == 2
    n = sum(r.used for r in forced.runs)
    m, c, k = forced.m.value, forced.c.value, forced.k.value
    for ax, (slope, icpt) in zip(top, ((-m, k), (c, 0.0)), strict=True):
        x, y = _points(_errorbars(ax)[0])
        assert x.size == n
        lx, ly = _fitted_line(ax)
        np.testing.assert_allclose(ly, slope * lx + icpt, rtol=1e-12, atol=1e-12)
    # R sin ρ = cω: the points are ω and Z.imag of each used run
    x, y = _points(_errorbars(top[1])[0])
    np.testing.assert_allclose(x, [r.omega for r in forced.runs if r.used])
    np.testing.assert_allclose(y, [r.Z.imag for r in forced.runs if r.used])


# --------------------------------------------------------------------------------------------
# the (m, k) ellipse


def _half_extents(e):
    """Half-extents along x and y of a matplotlib Ellipse (width, height, angle in degrees)."""
    a, b, th = e.width / 2, e.height / 2, math.radians(e.angle)
    return (math.hypot(a * math.cos(th), b * math.sin(th)),
            math.hypot(a * math.sin(th), b * math.cos(th)))


@pytest.mark.parametrize("which", ["gls", "forced", "friction"])
def test_mk_ellipse_is_the_covariance(which, request):
    """The Δχ² = q ellipse's shadow on each axis is ±√q stderr (a property of the ellipse
    xᵀC⁻¹x = q: its half-extent along axis i is √(q Cᵢᵢ)); centred on the estimate."""
    from matplotlib.patches import Ellipse

    res = request.getfixturevalue(which)
    fig = mk_ellipse_figure(res)
    (ax,) = fig.axes
    ells = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ells) == len(ELLIPSE_LEVELS) == 2
    C = np.asarray(res.cov)[np.ix_([0, 2], [0, 2])]
    for e, q in zip(ells, ELLIPSE_LEVELS, strict=True):
        hx, hy = _half_extents(e)
        assert hx == pytest.approx(math.sqrt(q * C[0, 0]), rel=1e-9)
        assert hy == pytest.approx(math.sqrt(q * C[1, 1]), rel=1e-9)
        assert e.center == pytest.approx((res.m.value, res.k.value))
    labels = [e.get_label() for e in ells]
    assert "39.3 %" in labels[0] and "86.5 %" in labels[1]


def test_mk_covariance_of_the_ols_route_has_the_line_correlation(ols_uncompensated):
    """m and k of the OLS route are the slope and −intercept of one line: their covariance is
    that line's, s²(AᵀA)⁻¹ with A = [x, 1] (computed here from the points) and s² the residual
    variance with n − 2 dof; cov(m, k) = −cov(slope, intercept)."""
    kl = ols_uncompensated.fit.k_line
    A = np.c_[kl.x, np.ones_like(kl.x)]
    _coef, rss, *_ = np.linalg.lstsq(A, kl.y, rcond=None)
    s2 = float(rss[0]) / (kl.x.size - 2)
    cov_ab = s2 * np.linalg.inv(A.T @ A)
    want = np.array([[cov_ab[0, 0], -cov_ab[0, 1]], [-cov_ab[0, 1], cov_ab[1, 1]]])
    np.testing.assert_allclose(mk_covariance(ols_uncompensated), want, rtol=1e-9)


# --------------------------------------------------------------------------------------------
# per-run figures


def _by_label(fig, ylabel):
    return [ax for ax in fig.axes if ax.get_ylabel() == ylabel]


def test_pho_run_figure_panels(gls):
    i = 4
    r = gls.runs[i]
    fig = pho_run_figure(gls, i)
    assert [len(_by_label(fig, lb)) for lb in ("x (mm)", "residual (mm)", "u (N)",
                                               "residual ACF (–)")] == [1, 1, 1, 1]
    # the u panel draws the recorded u of the run (examples/paper-sample records it), at
    # the samples decimate_line keeps: a subset of the record holding each pixel column's
    # extremes, and the record's own extremes
    (axu,) = _by_label(fig, "u (N)")
    u = read_experiment(SAMPLE).runs[i].u
    drawn = np.asarray(axu.get_lines()[0].get_ydata(), float)
    assert np.isin(drawn, u).all() and drawn.max() == u.max() and drawn.min() == u.min()
    # noise band: ±2 noise sd of the fit, in mm, on the residual panel
    (axr,) = _by_label(fig, "residual (mm)")
    band = [p for p in axr.patches if p.get_label().startswith("±2 noise sd")]
    assert len(band) == 1
    ys = band[0].get_path().transformed(band[0].get_patch_transform()).vertices[:, 1]
    assert max(ys) == pytest.approx(2e3 * r.fit.noise_sd) and min(ys) == pytest.approx(
        -2e3 * r.fit.noise_sd)
    # its legend gives the noise sd in the axis's unit (mm), as the fit stored it in m
    assert band[0].get_label() == f"±2 noise sd (sd {r.fit.noise_sd * 1e3:.3g} mm)"
    # autocorrelation: lag axis, and the white-noise band ±1.96/√n, n the fitted samples
    (axa,) = _by_label(fig, "residual ACF (–)")
    assert axa.get_xlabel() == "lag (s)"
    t = read_experiment(SAMPLE).runs[i].t
    n = int(np.count_nonzero((t >= r.fit.t_start) & (t <= r.fit.t_end)))
    (wb,) = [p for p in axa.patches if "1.96" in p.get_label()]
    ys = wb.get_path().transformed(wb.get_patch_transform()).vertices[:, 1]
    assert max(ys) == pytest.approx(1.96 / math.sqrt(n))


def test_pho_run_figure_without_u_has_no_u_panel(gls):
    fig = pho_run_figure(dataclasses.replace(gls, u=()), 0)
    assert not _by_label(fig, "u (N)") and len(fig.axes) == 3


def test_forced_and_free_run_figures(forced, free):
    fig = forced_run_figure(forced, 0)
    assert len(_by_label(fig, "F (N)")) == 1 and len(_by_label(fig, "residual ACF (–)")) == 1
    fig = free_run_figure(free, 0)
    assert len(fig.axes) == 3 and not _by_label(fig, "u (N)") and not _by_label(fig, "F (N)")
    assert len(_by_label(fig, "residual ACF (–)")) == 1


def test_residual_acf():
    """ρ̂(0) = 1; white noise within ±1.96/√n at ~95 % of lags; an AR(1) of φ = 0.6 gives
    ρ̂(j) ≈ 0.6ʲ (its autocorrelation), within 4/√n (sd of ρ̂ ≈ 1/√n)."""
    rng = np.random.default_rng(2)
    n = 20000
    w = rng.standard_normal(n)
    rho = residual_acf(w, 200)
    assert rho[0] == pytest.approx(1.0) and rho.size == 201
    assert np.mean(np.abs(rho[1:]) < 1.96 / math.sqrt(n)) > 0.9
    ar = np.empty(n)
    ar[0] = w[0]
    for j in range(1, n):
        ar[j] = 0.6 * ar[j - 1] + w[j]
    rho = residual_acf(ar, 5)
    np.testing.assert_allclose(rho, 0.6 ** np.arange(6), atol=4 / math.sqrt(n))
    # the definition, summed directly, on a short sequence
    x = rng.standard_normal(50)
    xc = x - x.mean()
    direct = [np.dot(xc[: 50 - j], xc[j:]) / np.dot(xc, xc) for j in range(10)]
    np.testing.assert_allclose(residual_acf(x, 9), direct, rtol=1e-10, atol=1e-12)


def test_stick_intervals():
    t = np.arange(10.0)
    v = np.array([0, 0, 1, 0, 0, 0, 2, 0, 3, 0.0])
    # before 'after' not counted; single zero samples (a velocity reversal) not counted
    assert stick_intervals(t, v, after=0.5) == [(3.0, 5.0)]
    assert stick_intervals(t, v, after=-1.0) == [(0.0, 1.0), (3.0, 5.0)]


# --------------------------------------------------------------------------------------------
# friction


def test_friction_model_is_the_fitted_model(friction):
    """FrictionFit.model reproduces the fit: its rms residual over each fitted window equals
    the run's residual_rms (same simulator, grid and interpolant; 1e-6 relative allows the
    different simulation lengths' rounding)."""
    for i, r in enumerate(friction.runs):
        if not r.used:
            continue
        t, x = friction.data[i]
        xm, _v = friction.model(i, t)
        sel = t <= r.t_end
        assert math.sqrt(np.mean((x[sel] - xm[sel]) ** 2)) == pytest.approx(
            r.residual_rms, rel=1e-6)


def test_friction_run_figure_marks_stick_intervals(friction):
    from matplotlib.patches import Polygon, Rectangle

    stuck = [i for i, r in enumerate(friction.runs) if r.used and r.stick_time is not None]
    assert stuck, "the set is made so that a run sticks before its record ends"
    i = stuck[0]
    r = friction.runs[i]
    fig = friction_run_figure(friction, i)
    (ax,) = _by_label(fig, "x (mm)")
    # axvspan draws a Rectangle (matplotlib ≥ 3.9) or a Polygon (3.8, the lower bound)
    spans = [p for p in ax.patches if isinstance(p, Rectangle | Polygon)
             and p.get_facecolor()[:3] != (1.0, 1.0, 1.0)]
    assert spans  # at least the final stick, shaded
    t, _x = friction.data[i]
    _xm, v = friction.model(i, t)
    want = stick_intervals(t, v, r.release)
    assert len(spans) == len(want)
    # the last interval runs from the run's stick time to the record's end; it starts at the
    # first sample whose interpolated velocity is exactly 0, i.e. after the first simulation
    # grid point at rest: within one grid step (here the sample interval) plus one sample
    dt = float(np.median(np.diff(t)))
    assert 0 <= want[-1][0] - r.stick_time <= 2.01 * dt and want[-1][1] == t[-1]
    assert any(ln.get_label().startswith("sticks for good") for ln in ax.get_lines())
    assert len(_by_label(fig, "fitted v (mm/s)")) == 1
    assert len(_by_label(fig, "residual ACF (–)")) == 1


def test_cli_friction_plots(friction_set, tmp_path):
    r = runner.invoke(app, ["identify", str(friction_set), "--friction", "--plots",
                            str(tmp_path / "p")])
    assert r.exit_code == 0, r.output
    names = sorted(p.name for p in (tmp_path / "p").glob("*.png"))
    assert names == ["mk-ellipse.png", "run01.png", "run02.png", "run03.png"]


# --------------------------------------------------------------------------------------------
# file names and the design figure


def test_run_names_without_repetition():
    assert run_names(["data/run01.csv.gz", "run02.csv"]) == ["run01.png", "run02.png"]
    # shared stems and reserved names get the run number
    assert run_names(["a/x.csv", "b/x.csv", "y.csv"]) == ["01-x.png", "02-x.png", "y.png"]
    assert run_names(["lines.csv", "z.csv"], ["lines.png", "mk-ellipse.png"]) == [
        "01-lines.png", "z.png"]


def test_identification_plot_names(gls, tmp_path):
    written = gls.plot(tmp_path / "p")
    names = [p.name for p in written]
    used = [r.file.split(".")[0] for r in gls.runs if r.fit is not None]
    assert names == [f"{s}.png" for s in used] + ["lines.png", "mk-ellipse.png"]
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in written)


@pytest.mark.parametrize("which", ["forced", "free", "friction"])
def test_run_figures_drawn_one_after_another_are_those_drawn_anew(which, request):
    # a set's run figures reuse one figure's axes (phoid.reports.runs.recycle): each must be
    # the bytes of the same run drawn on new axes. The first call below takes the figure a
    # previous test may have handed back; those after it are new ones (none is handed back)
    result = request.getfixturevalue(which)
    draw = {"forced": forced_run_figure, "free": free_run_figure,
            "friction": friction_run_figure}[which]
    used = [i for i, r in enumerate(result.runs) if r.used]
    assert used
    draw(result, used[0])
    anew = [png_bytes(draw(result, i)) for i in used]
    # each run twice over: from the second figure on, every one is drawn on reused axes
    again = list(render_pngs([functools.partial(draw, result, i) for i in used + used],
                             workers=1))
    assert again == anew + anew


def test_design_figure_has_a_colour_bar_and_legend():
    d = phoid.design(m=(1.5, 2.5), c=(0.5, 1.5), k=(50, 80), delay=0.1, runs=6)
    fig = d.plot()
    try:
        cbars = [ax for ax in fig.axes if ax.get_ylabel() == "run"]
        assert len(cbars) == 1
        assert [float(x) for x in cbars[0].get_yticks()] == [1, 2, 3, 4, 5, 6]
        labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert {"nominal plant", "plants of the prior", "stability boundary"} <= set(labels)
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


@pytest.mark.parametrize("unit", [r"$\foo$", "a$b$c"])
def test_a_sensor_unit_is_drawn_as_written(unit, tmp_path):
    # a declared sensor unit is the manifest's text: its "$" is no mathtext (an unknown
    # command ended the plot with matplotlib's parse error; "a$b$c" was drawn as a formula)
    out = tmp_path / "set"
    r = runner.invoke(app, ["simulate", str(out), "--method", "free", "--m", "1", "--c", "2",
                            "--k", "100", "--duration", "3", "--fs", "250", "--noise", "1e-5",
                            "--seed", "4"])
    assert r.exit_code == 0, r.output
    manifest = out / "experiment.toml"
    toml_unit = unit.replace("\\", "\\\\")  # a TOML basic string
    manifest.write_text(manifest.read_text() + f'\n[units]\nx = {{signal = "{toml_unit}"}}\n')
    result = phoid.identify(read_experiment(out))
    assert result.x_unit == unit
    fig = free_run_figure(result, 0)
    labels = [ax.get_ylabel() for ax in fig.axes[:2]]
    # what is drawn: plain text (no mathtext), the escaped "$" shown as "$" (matplotlib's
    # rule for "\$")
    from matplotlib.cbook import is_math_text

    assert not any(is_math_text(s) for s in labels)
    assert [s.replace(r"\$", "$") for s in labels] == [f"x ({unit})", f"residual ({unit})"]
    png_bytes(fig)  # drawn: no mathtext error
    for extra in ([], ["--friction"]):  # the free-friction figure's title names it too
        r = runner.invoke(app, ["identify", str(out), *extra, "--plots",
                                str(tmp_path / f"png{len(extra)}")])
        assert r.exit_code == 0, r.output
        assert (tmp_path / f"png{len(extra)}" / "run01.png").stat().st_size > 0
