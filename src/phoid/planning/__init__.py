"""Experiment design: gain schedules for a PHO experiment and the precision they promise.

``design`` proposes the gains (Pᵢ, Dᵢ) of a PHO experiment (seed eq. 23) from a prior guess of
the plant — each of m, c, k a value or a range — the loop (a delay, or a sampled loop's
``sample_time`` and ``delay_samples``) and the rig's limits; ``check`` evaluates given gains the
same way. Both return a :class:`Design`: per-run predicted modes, cycles, stability margins and
the **Cramér–Rao standard errors** of m, c, k (:mod:`phoid.planning.fisher`; for a sampled loop
with the noise in it, :mod:`phoid.planning.inloop_bound`) for the planned noise level and record
length.

Modules, from the bottom up: :mod:`~phoid.planning.fisher` (the Cramér–Rao bound),
:mod:`~phoid.planning.inloop_bound` (the bound of a digital set, the noise inside the loop),
:mod:`~phoid.planning.margins` (exact root counts and delay margins of the delayed loop),
:mod:`~phoid.planning.settings` (the conditions and the prior plant),
:mod:`~phoid.planning.evaluation` (the requirements on a run, evaluated over the prior grid),
:mod:`~phoid.planning.sampled` (a sampled loop's runs placed and evaluated exactly, margins in
samples, the prediction for the noise placement),
:mod:`~phoid.planning.render` (text report and figure), :mod:`~phoid.planning.schedule`
(schedule files), :mod:`~phoid.planning.result` (:class:`Design`, :class:`PlannedRun`),
:mod:`~phoid.planning.search` (:func:`design`) and :mod:`~phoid.planning.checking`
(:func:`check`, :func:`check_experiment`).
"""

from phoid.planning.checking import check, check_experiment
from phoid.planning.fisher import (
    CramerRao,
    cramer_rao,
    mode_information,
    mode_jacobian,
    power_sums,
    release_amplitude,
)
from phoid.planning.inloop_bound import InLoopBound, inloop_cramer_rao
from phoid.planning.margins import count_roots_right, delay_margin
from phoid.planning.result import Design, PlannedRun
from phoid.planning.schedule import read_schedule, schedule_target
from phoid.planning.search import MAX_RUNS, design
from phoid.planning.settings import DesignError, DesignSettings

__all__ = [
    "MAX_RUNS",
    "CramerRao",
    "Design",
    "DesignError",
    "DesignSettings",
    "InLoopBound",
    "PlannedRun",
    "check",
    "check_experiment",
    "count_roots_right",
    "cramer_rao",
    "delay_margin",
    "design",
    "inloop_cramer_rao",
    "mode_information",
    "mode_jacobian",
    "power_sums",
    "read_schedule",
    "release_amplitude",
    "schedule_target",
]
