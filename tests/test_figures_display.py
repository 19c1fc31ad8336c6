"""Figures drawn for what the eye can see, and labelled in one notation (issue 30).

A long record is drawn through each pixel column's extremes (``decimate_line``) and its
residual as each column's min–max band and mean (``column_envelope``): the tests check that
nothing the full drawing would show is lost (a single spike stays), that a short record is
drawn sample by sample, that the fit line does not cover the record, that every label carries
the axis's unit and the notation of the text reports (σ the decay rate, ω_d as mathtext), and
that drawing the figures leaves the result unchanged. Records are written out here (an exact
damped cosine with seeded Gaussian noise), or the repository's examples/paper-sample.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

import phoid
from phoid.batch.drift_plot import axis_label, trend_figure
from phoid.cli import app
from phoid.reports.figures import DPI, figure1_panel, png_bytes
from phoid.reports.lines import mk_ellipse_figure, pho_lines_figure
from phoid.reports.runs import (
    COLUMNS,
    column_envelope,
    decimate_line,
    display_unit,
    pho_run_figure,
    run_figure,
)

SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "paper-sample"
runner = CliRunner()


@pytest.fixture(scope="module")
def gls():
    return phoid.identify(phoid.read_experiment(SAMPLE))


def _decay(n: int, spike_at: int | None = None, spike: float = 0.0):
    """t (s, 1 kHz), the exact decay 10 mm·e^(−0.4t)·cos(6t) (m), the record with 0.1 mm
    white noise (seed 4) and, at ``spike_at``, one sample ``spike`` m off."""
    t = np.arange(n) * 1e-3
    model = 0.01 * np.exp(-0.4 * t) * np.cos(6.0 * t)
    x = model + 1e-4 * np.random.default_rng(4).standard_normal(n)
    if spike_at is not None:
        x[spike_at] += spike
    return t, x, model


def _columns_direct(t, y, columns):
    """Each occupied column's (min, max, mean), by a loop over the columns: the definition
    (columns of equal width over [t₀, t₁], the last one closed)."""
    t0, t1 = t.min(), t.max()
    col = np.minimum(((t - t0) / ((t1 - t0) / columns)).astype(int), columns - 1)
    out = [(y[col == c].min(), y[col == c].max(), y[col == c].mean())
           for c in range(columns) if np.any(col == c)]
    return np.array(out).T


def _ylabel(fig, start):
    (ax,) = [a for a in fig.axes if a.get_ylabel().startswith(start)]
    return ax


# --------------------------------------------------------------------------------------------
# decimation


def test_column_envelope_is_each_columns_min_max_and_mean_and_keeps_a_spike():
    t, x, model = _decay(15000, spike_at=7000, spike=2e-3)
    r = x - model
    tc, lo, hi, mean = column_envelope(t, r, 300)
    want = _columns_direct(t, r, 300)
    np.testing.assert_array_equal(lo, want[0])
    np.testing.assert_array_equal(hi, want[1])
    np.testing.assert_allclose(mean, want[2], rtol=1e-12, atol=1e-18)  # summation order
    assert tc.size == 300 and np.all(np.diff(tc) > 0)
    # the spike (20 noise sd) is its column's maximum and the envelope's
    assert hi.max() == r[7000] == r.max()


def test_decimate_line_keeps_each_columns_extremes_in_time_order():
    t, x, _ = _decay(15000, spike_at=123, spike=-3e-3)
    td, xd = decimate_line(t, x, 500)
    assert td.size <= 4 * 500 and np.all(np.diff(td) > 0)
    assert np.isin(td, t).all()
    lo, hi, _mean = _columns_direct(t, x, 500)
    _tc, lo_d, hi_d, _m = column_envelope(td, xd, 500, (t.min(), t.max()))
    np.testing.assert_array_equal(lo_d, lo)
    np.testing.assert_array_equal(hi_d, hi)
    assert t[123] in td  # the spike (30 noise sd down) is its column's minimum
    # a short record (≤ 4 samples per column) is returned whole
    _ts, xs = decimate_line(t[:1000], x[:1000], 500)
    np.testing.assert_array_equal(xs, x[:1000])


# --------------------------------------------------------------------------------------------
# the run figure


def test_run_figure_residual_panel_shows_one_spike_and_draws_few_points():
    n = 15000
    t, x, model = _decay(n, spike_at=9000, spike=2e-3)
    sel = np.ones(n, dtype=bool)
    fig = run_figure(t, x, sel, model, noise_sd=1e-4, title="spike", model_label="model",
                     markers=[(0.0, "release")])
    axr = _ylabel(fig, "residual (mm)")
    (band,) = [c for c in axr.collections if "min–max" in c.get_label()]
    ys = np.concatenate([p.vertices[:, 1] for p in band.get_paths()])
    resid_mm = (x - model) * 1e3
    assert ys.max() == pytest.approx(resid_mm.max(), rel=1e-12)
    assert ys.max() == pytest.approx(resid_mm[9000], rel=1e-12)
    assert ys.min() == pytest.approx(resid_mm.min(), rel=1e-12)
    # what the eye can see: at most 4 points per pixel column in any line of the time panels
    for ax in fig.axes[:-1]:
        for ln in ax.get_lines():
            assert len(ln.get_xdata()) <= 4 * COLUMNS + 2
        assert all(p.vertices.shape[0] <= 4 * COLUMNS + 8 for c in ax.collections
                   for p in c.get_paths())


def test_short_record_is_drawn_sample_by_sample():
    t, x, model = _decay(400)
    fig = run_figure(t, x, np.ones(400, dtype=bool), model, noise_sd=1e-4, title="short",
                     model_label="model")
    ax = _ylabel(fig, "x (mm)")
    (rec,) = [ln for ln in ax.get_lines() if ln.get_label() == "record"]
    assert rec.get_marker() == "." and rec.get_linestyle() == "None"
    np.testing.assert_allclose(rec.get_ydata(), x * 1e3, rtol=1e-15)
    axr = _ylabel(fig, "residual (mm)")
    (res,) = [ln for ln in axr.get_lines() if ln.get_label() == "residual"]
    np.testing.assert_allclose(res.get_ydata(), (x - model) * 1e3, rtol=1e-12, atol=1e-15)


def test_fit_line_does_not_hide_the_record(gls):
    fig = pho_run_figure(gls, 0)
    ax = _ylabel(fig, "x (mm)")
    (rec,) = [ln for ln in ax.get_lines() if ln.get_label() == "record"]
    (fit,) = [ln for ln in ax.get_lines() if ln.get_label().startswith("fitted")]
    # thinner than the record and see-through, and no band filled over the record
    assert fit.get_linewidth() < rec.get_linewidth() and fit.get_alpha() < 1
    assert not ax.collections


@pytest.mark.parametrize(("x_unit", "shown", "scale"),
                         [("m", "mm", 1e3), ("rad", "mrad", 1e3), ("V", "V", 1.0)])
def test_noise_legend_and_labels_in_the_axis_unit(x_unit, shown, scale):
    t, x, model = _decay(3000)
    fig = run_figure(t, x, np.ones(3000, dtype=bool), model, noise_sd=1e-4, title="u",
                     model_label="model", x_unit=x_unit)
    assert display_unit(x_unit) == (scale, shown)
    _ylabel(fig, f"x ({shown})")
    axr = _ylabel(fig, f"residual ({shown})")
    texts = [tx.get_text() for tx in axr.get_legend().get_texts()]
    assert f"±2 noise sd (sd {1e-4 * scale:.3g} {shown})" in texts


def test_pho_run_title_writes_omega_d_as_mathtext(gls):
    fig = pho_run_figure(gls, 0)
    (title,) = [tx.get_text() for tx in fig.texts]
    assert r"$\omega_d$" in title and "ω_d" not in title and "\n" not in title


# --------------------------------------------------------------------------------------------
# units and notation in every figure


def _trend():
    days = [f"2026-01-0{d}T00:00:00Z" for d in range(1, 8)]

    def chart(name, base):
        pts = [SimpleNamespace(order=d, value=base * (1 + 0.01 * j), stderr=0.002 * base,
                               baseline=j < 3, flagged=j == 6) for j, d in enumerate(days)]
        return SimpleNamespace(name=name, points=pts, baseline=base, baseline_stderr=0.001)

    unit = SimpleNamespace(unit="axis-1", ordered_by="time",
                           charts=[chart("omega0", 5.6), chart("zeta", 0.05), chart("m", 2.0)])
    return SimpleNamespace(by="unit", threshold=3.0, units=[unit]), unit


def _paper_result():
    def line(slope, intercept):
        x = np.linspace(0.8, 2.0, 5)
        return SimpleNamespace(x=x, y=slope * x + intercept, slope=slope, intercept=intercept)

    both = SimpleNamespace(c_line=line(2.0, -1.0), k_line=line(2.0, -64.0))
    return SimpleNamespace(with_compensation=both, without_compensation=both)


def test_every_axis_label_carries_a_unit(gls):
    trend, unit = _trend()
    figs = [pho_run_figure(gls, 3), pho_lines_figure(gls), mk_ellipse_figure(gls),
            figure1_panel(_paper_result(), "a"), figure1_panel(_paper_result(), "b"),
            trend_figure(trend, unit)]
    for fig in figs:
        for ax in fig.axes:
            for label in (ax.get_xlabel(), ax.get_ylabel()):
                # a label names its unit in parentheses; a time axis of dates says UTC
                assert not label or (label.endswith(")") and "(" in label), label


def test_lines_figure_is_one_line_mathtext_and_readable_at_half_width(gls):
    fig = pho_lines_figure(gls)
    title = fig.get_suptitle()
    assert "\n" not in title and r"$\omega_d$" in title and "ω_d" not in title
    assert not any("ω_d" in ax.get_xlabel() for ax in fig.axes)
    # the HTML report shows it in half of a 1200 px page (about 560 px): at that scale
    # (a 9-inch figure at 120 dpi shrunk by 0.52) ticks stay ≥ 9 px high, legends ≥ 8 px
    width_px = fig.get_figwidth() * DPI
    shrink = 560 / width_px
    for ax in fig.axes:
        for tick in ax.get_yticklabels() + ax.get_xticklabels():
            assert tick.get_fontsize() * DPI / 72 * shrink >= 9
        legend = ax.get_legend()
        if legend is not None:
            assert all(tx.get_fontsize() * DPI / 72 * shrink >= 8
                       for tx in legend.get_texts())


def test_figure1a_names_c_viscous_damping():
    fig = figure1_panel(_paper_result(), "a")
    title = fig.axes[0].get_title()
    assert "viscous damping" in title and "friction" not in title


def test_trend_labels_use_the_reports_notation():
    assert axis_label("omega0") == "ω₀ (rad/s)"
    assert axis_label("zeta") == "ζ (–)"
    trend, unit = _trend()
    fig = trend_figure(trend, unit)
    assert [ax.get_ylabel() for ax in fig.axes] == ["ω₀ (rad/s)", "ζ (–)", "m (kg)"]
    texts = [tx.get_text() for lg in fig.legends for tx in lg.get_texts()]
    assert "±3 stderr limits" in texts and not any("σ" in tx for tx in texts)


# --------------------------------------------------------------------------------------------
# the files and the result


def test_png_has_the_figures_size(gls):
    fig = pho_run_figure(gls, 0)
    data = png_bytes(fig)
    im = Image.open(io.BytesIO(data))
    assert im.format == "PNG"
    assert im.size == (round(fig.get_figwidth() * DPI), round(fig.get_figheight() * DPI))


def test_identify_json_is_the_same_with_plots(tmp_path):
    plain = runner.invoke(app, ["identify", str(SAMPLE), "--json"])
    plotted = runner.invoke(app, ["identify", str(SAMPLE), "--json", "--plots",
                                  str(tmp_path / "p")])
    assert plain.exit_code == 0 and plotted.exit_code == 0, plotted.output
    assert json.loads(plotted.stdout) == json.loads(plain.stdout)
    n_runs = len(json.loads(plain.stdout)["runs"])
    assert len(list((tmp_path / "p").glob("*.png"))) == n_runs + 2
    assert math.isfinite(json.loads(plain.stdout)["m"]["value"])
