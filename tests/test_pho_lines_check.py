"""The eq. (35) lines' own adequacy check (phoid.methods.pho_lines_check): the paper's OLS lines
warn when their points lie off the lines by more than the runs measured them — with the loop
delay left out (--no-compensation) they name that cause and give the compensated numbers.

The example set (examples/paper-sample) is simulated with m = 2 kg, c = 1 N s/m, k = 64 N/m and a
0.1 s loop delay (examples/make_paper_sample.py, the seed's Table 1 plant).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from phoid.io import read_experiment
from phoid.methods.identification import identify_pho
from phoid.methods.pho_lines_check import check_lines

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "paper-sample"


@pytest.fixture(scope="module")
def sample():
    return read_experiment(SAMPLE)


def _lines_warnings(res):
    return [w for w in res.warnings if "eq. (35) points lie off" in w]


def test_uncompensated_lines_warn_and_name_the_delay(sample):
    res = identify_pho(sample, estimator="ols", compensate=False)
    # the uncompensated m is about half the truth (the seed's Table 1 shows the same bias)
    assert abs(res.m.value - 2.0) > 10 * res.m.stderr
    (w,) = _lines_warnings(res)
    assert "loop delay (0.1 s) is left out (--no-compensation)" in w
    # the compensated m it quotes is the truth within 3 of its stderr (simulation: m = 2 kg)
    mm = re.search(r"compensated m = ([0-9.]+) ± ([0-9.]+) kg", w)
    assert mm, w
    assert abs(float(mm.group(1)) - 2.0) < 3 * float(mm.group(2))
    assert "the compensated lines fit" in w


def test_compensated_lines_do_not_warn(sample):
    res = identify_pho(sample, estimator="ols")
    assert _lines_warnings(res) == []
    assert abs(res.m.value - 2.0) < 3 * res.m.stderr


def test_wrong_delay_makes_the_lines_misfit(sample):
    # a delay of half the rig's: the compensated points no longer lie on straight lines
    res = identify_pho(sample, estimator="ols", delay=0.05)
    (w,) = _lines_warnings(res)
    assert "likely causes: a loop delay that is not the rig's" in w


def test_check_lines_chi2_is_about_dof_on_exact_lines():
    # points built exactly on the lines, then moved by their stated error: χ²/dof ≈ 1
    rng = np.random.default_rng(1)
    m, c, k, n = 2.0, 1.0, 64.0, 400
    P = np.linspace(0.5, 40.0, n)
    D = np.linspace(0.5, 6.0, n)
    sigma = (c + D) / (2 * m)                       # no delay: c′ = D, k′ = P (eq. 35)
    w0sq = (k + P) / m
    wd = np.sqrt(w0sq - sigma**2)
    sd = 1e-4
    cov = np.tile(np.diag([sd**2, sd**2]), (n, 1, 1))
    s_obs = sigma + sd * rng.standard_normal(n)
    w_obs = wd + sd * rng.standard_normal(n)
    chk = check_lines(s_obs, w_obs, cov, P, D, 0.0, compensate=True, added_mass=np.zeros(n),
                      m_c=m, m=m, c=c, k=k)
    assert chk is not None and not chk.misfit
    # χ²_dof has sd √(2/dof) ≈ 0.07 relative at dof = 398: 5 sd band
    for chi2 in (chk.chi2_c, chk.chi2_k):
        assert abs(chi2 / chk.dof - 1.0) < 5 * np.sqrt(2.0 / chk.dof)


def test_check_lines_needs_three_runs():
    cov = np.tile(np.eye(2) * 1e-8, (2, 1, 1))
    assert check_lines(np.array([0.4, 0.5]), np.array([5.7, 5.8]), cov, np.array([1.0, 2.0]),
                       np.array([0.6, 0.9]), 0.1, compensate=True, added_mass=np.zeros(2),
                       m_c=2.0, m=2.0, c=1.0, k=64.0) is None
