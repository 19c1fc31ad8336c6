"""The host's checks before anything moves: its options, the plan, each run's configuration.

:func:`plan_configs` reads a plan (``phoid design --out``) and makes each run's ``CONFIG``
fields, checking every option and what the plan and the options make against the limits of
the controller and the reader (docs/rig-protocol.md, "Limits of the host"); :class:`RigError`
is the host's one-line error, :func:`clip` the one-line form of any text it prints or records.

Each run's configuration: the plan's P and D, K = G = 1 and its loop — a sampled loop's plan
(``phoid design --sample-time T --delay-samples d``) its ``[loop] sample_time``,
``delay_samples``, ``velocity`` (and ``cutoff``, sent as the filter's pole e^(−ω_c T)), recorded
at [design] fs = 1/T; a continuous loop's plan T = 1/fs, backward-difference velocity and
d = Δt/T whole samples of command delay (its ``[loop] delay``) —, the hold at
the plan's release amplitude A with a stiff, about critically damped loop on the plan's prior
(hold_P = 3 k, hold_D = 2√(m (k + hold_P)) − c, at least 0) for about seven of its slowest time
constants — its reference x_start = A (1 + k/hold_P), the prior's k (the middle of a range), so
that it settles at A, where hold_P (x_start − x) = k x —, position limits ±3A and the growth
bound 2.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from phoid.errors import PhoidError
from phoid.io.limits import MAX_LINES, MAX_SET_ROWS
from phoid.io.manifest import read_manifest
from phoid.planning.schedule import read_schedule

__all__ = ["MANIFEST", "MAX_COUNT", "MAX_TIMEOUT", "RigError", "check_names", "clip", "option",
           "plan_configs", "variant"]

MANIFEST = "experiment.toml"
# the limits of the host (docs/rig-protocol.md, "Limits of the host")
MAX_COUNT = 2**31 - 1  # samples of one run, hold + run + 1: a C long of 32 bits (an MCU's)
MAX_DELAY = 2**15 - 1  # samples of command delay: a C int of 16 bits
MIN_SAMPLE_TIME = 1e-9  # s: the controller's shortest sample time
MAX_TIMEOUT = 86400.0  # s: the longest --timeout (a day)


class RigError(PhoidError):
    """Bad input to the host (plan, port, limits, a refusal of the rig): one line."""


def clip(text: object, limit: int) -> str:
    """``text`` as one line of printable ASCII (the rest escaped), at most ``limit`` characters."""
    line = "".join(ch if " " <= ch <= "~" else ch.encode("unicode_escape").decode("ascii")
                   for ch in " ".join(str(text)[:limit + 1].split()))
    return line if len(line) <= limit else line[:limit - 3] + "..."


def option(name: str, value: Any, ok: Callable[[float], bool], what: str) -> float:
    """``value`` as a float when it is a finite number with ``ok(value)``; else one RigError."""
    try:
        num = math.nan if isinstance(value, (bool, str)) else float(value)
    except (TypeError, ValueError, OverflowError):
        num = math.nan
    if not (math.isfinite(num) and ok(num)):
        raise RigError(f"{name} must be {what}; got {clip(value, 60)}; nothing was sent")
    return num


def _options(pmax: Any, dmax: Any, hold_p: Any, hold_d: Any, hold: Any, x_limit: Any,
             u_max: Any, growth_limit: Any) -> dict[str, float | None]:
    """Every limit option checked (finite, in range), by its name; one RigError otherwise."""
    checks: dict[str, tuple[str, Any, Callable[[float], bool], str]] = {
        "pmax": ("--pmax", pmax, lambda v: v >= 0, "a finite number >= 0 (N/m)"),
        "dmax": ("--dmax", dmax, lambda v: v >= 0, "a finite number >= 0 (N s/m)"),
        "hold_p": ("--hold-p", hold_p, lambda v: v > 0, "a finite number > 0 (N/m)"),
        "hold_d": ("--hold-d", hold_d, lambda v: v >= 0, "a finite number >= 0 (N s/m)"),
        "hold": ("--hold", hold, lambda v: v > 0, "a finite number of seconds > 0"),
        "x_limit": ("--x-limit", x_limit, lambda v: v > 0, "a finite number > 0 (m)"),
        "u_max": ("--u-max", u_max, lambda v: v > 0, "a finite number > 0 (N)"),
        "growth_limit": ("growth_limit", growth_limit, lambda v: v == 0 or v >= 1,
                         "0 (off) or a finite number >= 1"),
    }
    return {key: None if val is None else option(name, val, ok, what)
            for key, (name, val, ok, what) in checks.items()}


def _prior_value(prior: Mapping[str, Any], key: str, pick: Callable, least: float
                 ) -> float | None:
    """The prior's ``key`` (a value or ``[lo, hi]`` through ``pick``) when finite and > least."""
    val = prior.get(key)
    if isinstance(val, list) and len(val) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in val):
        val = float(pick([float(v) for v in val]))  # overflow: inf, refused below
    if isinstance(val, (int, float)) and not isinstance(val, bool) and math.isfinite(val) \
            and val > least:
        return float(val)
    return None


def variant(name: str, kind: str) -> str:
    """``run03.csv`` → ``run03.KIND.csv`` (``aborted``, ``incomplete``)."""
    return f"{name[:-4]}.{kind}{name[-4:]}"


def check_names(manifest: Path, files: list[str]) -> None:
    """The plan's file names: plain ``*.csv`` names, none the same as another's or a variant."""
    seen: dict[str, int] = {}
    for i, name in enumerate(files, start=1):
        if (not name.lower().endswith(".csv") or len(name) > 200 or name.startswith(".")
                or any(ch in name for ch in "/\\:") or not name.isprintable()
                or name.lower() in (".csv", MANIFEST)):
            raise RigError(f"{manifest}: run {i}: file {clip(name, 80)!r} must be a plain file "
                           "name ending in .csv (no folder, not hidden, at most 200 "
                           "characters); nothing was sent")
        for each in (name, variant(name, "aborted"), variant(name, "incomplete")):
            other = seen.setdefault(each.casefold(), i)
            if other != i:
                raise RigError(f"{manifest}: runs {other} and {i} would both write "
                               f"{clip(each, 80)!r}; give each run its own file name")


def _continuous_loop(manifest: Path, sched: Mapping[str, Any]) -> float:
    """A continuous loop's plan: the controller's period T = 1/fs (s), checked."""
    fs = sched["fs"]
    T = 1.0 / fs
    if not (math.isfinite(T) and MIN_SAMPLE_TIME <= T <= MAX_TIMEOUT):
        raise RigError(f"{manifest}: [design] fs = {fs:g} Hz: the sample time 1/fs must be "
                       f"from {MIN_SAMPLE_TIME:g} s to {MAX_TIMEOUT:g} s (a day)")
    return T


def _delay_samples(manifest: Path, sched: Mapping[str, Any], T: float) -> int:
    """A continuous loop's plan: its ``[loop] delay`` in whole samples of T (0 without one)."""
    fs = sched["fs"]
    delay = sched["delay"] if sched["delay"] is not None else 0.0
    ds = delay * fs
    if not (math.isfinite(ds) and ds <= MAX_DELAY):
        raise RigError(f"{manifest}: [loop] delay = {delay:g} s is more than {MAX_DELAY} "
                       f"samples at fs = {fs:g} Hz")
    d = round(ds)
    if abs(d - ds) > 1e-6 * max(1.0, d):
        raise RigError(f"{manifest}: [loop] delay = {delay:g} s is not a whole number of "
                       f"samples at fs = {fs:g} Hz (T = {T:g} s); design the rig's loop with "
                       "--sample-time and --delay-samples")
    return d


def _sampled_loop(manifest: Path, loop: Mapping[str, Any], sched: Mapping[str, Any]
                  ) -> tuple[float, int, dict[str, Any]]:
    """A sampled loop's plan (``[loop] sample_time``, ``delay_samples``, ``velocity``,
    ``cutoff``): the controller's period T (s), its delay d (samples) and its velocity
    estimator's CONFIG fields (``velocity``, ``filter_pole``), each checked as ``phoid
    identify`` reads them (:func:`phoid.io.loop.read_digital_loop`), and the record's rate
    ``[design] fs`` = 1/T: a rig records once per controller period."""
    from types import SimpleNamespace

    from phoid.io.loop import read_digital_loop
    from phoid.rig.native import VELOCITIES

    span = np.array([0.0, sched["duration"]])
    try:
        dig = read_digital_loop(SimpleNamespace(path=manifest, loop=dict(loop),
                                                runs=(SimpleNamespace(t=span),)))
    except PhoidError as exc:
        raise RigError(f"not a plan: {exc}") from None
    assert dig is not None  # sample_time is there
    T, d, fs = float(dig.sample_time), int(dig.delay_samples), sched["fs"]
    if not (MIN_SAMPLE_TIME <= T <= MAX_TIMEOUT):
        raise RigError(f"{manifest}: [loop] sample_time = {T:g} s must be from "
                       f"{MIN_SAMPLE_TIME:g} s to {MAX_TIMEOUT:g} s (a day)")
    if not abs(fs * T - 1.0) <= 1e-9:
        raise RigError(f"{manifest}: [design] fs = {fs:g} Hz records {fs * T:.6g} samples per "
                       f"controller period ([loop] sample_time = {T:g} s); a rig records its "
                       "loop once per period: design with --fs 1/sample_time (the default)")
    if d > MAX_DELAY:
        raise RigError(f"{manifest}: [loop] delay_samples = {d} is more than {MAX_DELAY} "
                       "samples")
    delay = sched["delay"]  # read_schedule's check: a finite number >= 0, or None
    if delay is not None and not abs(delay - d * T) <= 1e-9 * T:
        raise RigError(f"{manifest}: [loop] delay = {delay:g} s is not delay_samples x "
                       f"sample_time = {d * T:g} s; give one or the other")
    code = VELOCITIES.get(dig.velocity) if isinstance(dig.velocity, str) else None
    if code is None:
        raise RigError(f"{manifest}: [loop] velocity = {clip(dig.velocity, 60)}: the rig's "
                       f"controller runs {', '.join(VELOCITIES)} only")
    velocity: dict[str, Any] = {"velocity": code}
    if dig.velocity == "filtered":
        velocity["filter_pole"] = float(dig.filter_pole)
    return T, d, velocity


def plan_configs(plan: str | Path, *, pmax: float | None = None, dmax: float | None = None,
                 hold_p: float | None = None, hold_d: float | None = None,
                 hold: float | None = None, x_limit: float | None = None,
                 u_max: float | None = None, growth_limit: float = 2.0
                 ) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The plan and each run's controller configuration (CONFIG fields); nothing is sent.

    Every option must be finite and in its range, and what the plan and the options make
    must fit the controller and the reader (docs/rig-protocol.md, "Limits of the host").

    Returns
    -------
    (plan, configs)
        ``plan``: the schedule (:func:`phoid.planning.read_schedule`) with ``path``,
        ``delay_samples``, ``design`` (its ``[design]`` table); ``configs``: one dict of
        CONFIG fields per run.

    Raises
    ------
    RigError
        One line naming the option, or the plan, run and field: an option that is not a
        finite number in its range, no plan, not a plan, no ``fs``, a delay that is not a
        whole number of samples, a gain beyond ``pmax``/``dmax``, a run too long.
    """
    opts = _options(pmax, dmax, hold_p, hold_d, hold, x_limit, u_max, growth_limit)
    path = Path(plan)
    manifest = path / MANIFEST if path.is_dir() else path
    if not manifest.is_file():
        raise RigError(f"{manifest}: no such plan (write one with `phoid design --out`)")
    try:
        str(manifest.resolve()).encode("utf-8")
    except UnicodeEncodeError:
        raise RigError(f"{clip(manifest.resolve(), 300)}: the plan's path is not UTF-8 text, "
                       "and the set's manifest (UTF-8 TOML) records it; rename its folder; "
                       "nothing was sent") from None
    try:
        sched = read_schedule(manifest)
        doc = read_manifest(str(manifest), manifest)
    except (PhoidError, ValueError) as exc:
        raise RigError(f"not a plan: {exc}") from None
    design = doc.get("design") if isinstance(doc.get("design"), Mapping) else {}
    for key in ("fs", "duration", "amplitude"):
        if key not in sched:
            raise RigError(f"{manifest}: not a plan of `phoid design --out`: [design] {key} "
                           "is missing")
    check_names(manifest, sched["files"])
    fs, amp = sched["fs"], sched["amplitude"]
    loop = doc.get("loop") if isinstance(doc.get("loop"), Mapping) else {}
    if "sample_time" in loop:  # a sampled loop's plan (design --sample-time): its own loop
        T, d, velocity = _sampled_loop(manifest, loop, sched)
    else:  # a continuous loop's plan: T = 1/fs, its delay a whole number of samples
        T = _continuous_loop(manifest, sched)
        d, velocity = _delay_samples(manifest, sched, T), {"velocity": 0}
    for i, (P, D) in enumerate(zip(sched["P"], sched["D"], strict=True), start=1):
        if opts["pmax"] is not None and abs(P) > opts["pmax"]:
            raise RigError(f"{manifest}: run {i}: |P| = {abs(P):g} N/m exceeds the rig's limit "
                           f"--pmax {opts['pmax']:g}; nothing was sent")
        if opts["dmax"] is not None and abs(D) > opts["dmax"]:
            raise RigError(f"{manifest}: run {i}: |D| = {abs(D):g} N·s/m exceeds the rig's "
                           f"limit --dmax {opts['dmax']:g}; nothing was sent")
    prior = design.get("prior") if isinstance(design.get("prior"), Mapping) else {}
    m = _prior_value(prior, "m", lambda v: math.sqrt(abs(v[0] * v[1])), 0.0) or 1.0
    c = _prior_value(prior, "c", min, -math.inf) or 0.0
    k = _prior_value(prior, "k", max, -math.inf) or 0.0
    k = max(k, 0.0)
    k_mid = max(_prior_value(prior, "k", lambda v: 0.5 * v[0] + 0.5 * v[1], -math.inf) or 0.0,
                0.0)
    with np.errstate(all="ignore"):
        hP = 3.0 * k if opts["hold_p"] is None else opts["hold_p"]
        if opts["hold_p"] is None and not hP + k > 0:
            hP = 16.0 * m
        hD = max(0.0, 2.0 * math.sqrt(m * (k + hP)) - c) if opts["hold_d"] is None \
            else opts["hold_d"]
        hold_s = opts["hold"]
        if hold_s is None:
            slow = 1.0
            coef = [m, c + hD, k + hP]
            if all(math.isfinite(v) for v in coef):
                poles = np.roots(coef)
                if poles.size and np.all(np.isfinite(poles)) and np.all(poles.real < 0):
                    slow = float(np.min(np.abs(poles.real)))
            hold_s = min(30.0, max(0.5, 7.0 / slow))
        # the hold loop settles where hold_P (x_start - x) = k x: its reference is set so that
        # the mass is held (and released) at the plan's amplitude A on the prior's k
        x_ref = amp * (1.0 + k_mid / hP) if hP > 0 else math.inf
    n_hold, n_run = hold_s * fs, sched["duration"] * fs
    most = min(MAX_COUNT - 2, MAX_LINES - 1)  # the controller's count; the reader's rows
    if not (math.isfinite(n_run) and round(n_run) <= most):
        raise RigError(f"{manifest}: [design] duration = {sched['duration']:g} s at fs = "
                       f"{fs:g} Hz is {n_run:.6g} samples; a run holds at most {most}")
    n_run = max(2, round(n_run))
    if not (math.isfinite(n_hold) and round(n_hold) + n_run + 1 <= MAX_COUNT):
        what = "--hold" if opts["hold"] is not None else "the default --hold"
        raise RigError(f"{what} {hold_s:g} s at fs = {fs:g} Hz is {n_hold:.6g} samples; with "
                       f"the run's {n_run} the hold, run and last sample must be at most "
                       f"{MAX_COUNT} (a 32-bit count); nothing was sent")
    if n_run * len(sched["files"]) > MAX_SET_ROWS:
        raise RigError(f"{manifest}: {len(sched['files'])} runs of {n_run} samples are more "
                       f"rows than phoid reads in one set ({MAX_SET_ROWS})")
    x_lim = 3.0 * amp if opts["x_limit"] is None else opts["x_limit"]
    if not (math.isfinite(x_lim) and x_lim > amp):
        what = "--x-limit" if opts["x_limit"] is not None else "the default --x-limit (3 A)"
        raise RigError(f"{what} {x_lim:g} m must be finite and larger than the plan's release "
                       f"amplitude A ([design] amplitude = {amp:g} m); nothing was sent")
    if math.isfinite(x_ref) and not x_ref < x_lim:
        raise RigError(f"the hold loop's reference x_start = A (1 + k/hold_P) = {x_ref:g} m "
                       f"(which holds the mass at the plan's amplitude A = {amp:g} m against "
                       f"the prior's k = {k_mid:g} N/m with hold_P = {hP:g} N/m) is beyond the "
                       f"position limit {x_lim:g} m; give a stiffer --hold-p or a larger "
                       "--x-limit; nothing was sent")
    base = {
        "sample_time": T, "gain": 1.0, "command_gain": 1.0, **velocity, "delay_samples": d,
        "hold_P": float(hP), "hold_D": float(hD), "x_start": float(x_ref),
        "hold_samples": max(1, round(n_hold)), "run_samples": n_run,
        "x_min": -x_lim, "x_max": x_lim, "growth_limit": opts["growth_limit"],
    }
    if opts["u_max"] is not None:
        base["u_max"] = opts["u_max"]
    source = {"hold_P": "--hold-p (default: 3 k of the plan's prior)",
              "x_start": "--hold-p (the hold's reference A (1 + k/hold_P))",
              "hold_D": "--hold-d (default: from the plan's prior m, c, k)"}
    for key, val in base.items():
        if not math.isfinite(val):
            raise RigError(f"{manifest}: the hold loop's {key} = {val} is not finite; set "
                           f"{source.get(key, key)}; nothing was sent")
    configs = [dict(base, P=float(P), D=float(D))
               for P, D in zip(sched["P"], sched["D"], strict=True)]
    sched.update(path=manifest, delay_samples=d, design=dict(design))
    return sched, configs
