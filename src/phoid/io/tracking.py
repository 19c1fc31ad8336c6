"""The keys of a tracking set (``method = "tracking"``): checked before any data is read.

A tracking set records a mass under a sampled PD position loop that follows a reference r:

    u_n = K·(P·(r_n − x_n) − D·v̂_n),    F_n = G·(sat(u_n) + w_n)

(docs/format.md, "Tracking sets"). Its manifest adds the top-level ``estimator`` and
``[fixed]``, the ``[loop]`` keys of the sampled controller, and per run the gains ``gain`` (K)
and ``command_gain`` (G) and the ``[run.columns]`` table that names the signals in the run's
file. The gains ``P``, ``D``, ``gain`` and ``command_gain`` may sit in ``[loop]`` (every run) or
in a ``[[run]]`` table (which overrides), each a number or the name of a scalar variable of the
run's file; :func:`tracking_run_spec` records which, and the reader resolves the names when it
reads the file. The velocity estimators are phoid's one list
(:data:`phoid.dynamics.velocity.VELOCITY_PRESETS`, and FIR coefficients).
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Mapping
from typing import Any

from phoid.dynamics.velocity import (
    VELOCITY_PRESETS,
    VelocityFilter,
    check_cutoff,
    estimator_taps,
    fir_problem,
)
from phoid.io._format import case_clash, checked_number, fail, kind_of, show, unknown_hint

__all__ = [
    "ESTIMATORS",
    "FIXED_KEYS",
    "MIN_TRACKING_SAMPLES",
    "RUN_GAINS",
    "TRACKING_COLUMNS",
    "TRACKING_LOOP_KEYS",
    "TRACKING_RUN_KEYS",
    "VELOCITY_PRESETS",
    "W_UNITS",
    "check_estimator",
    "check_fixed",
    "check_tracking_loop",
    "min_samples",
    "tracking_run_spec",
    "velocity_taps",
]

ESTIMATORS = ("auto", "idim", "output-error")
"""The values of a tracking set's top-level ``estimator`` key (default ``"auto"``)."""
FIXED_KEYS = ("m", "c", "k", "fc", "offset")
"""The keys of a tracking set's ``[fixed]`` table: parameters known, not estimated."""
TRACKING_LOOP_KEYS = ("sample_time", "velocity", "cutoff", "delay", "saturation", "P", "D",
                      "gain", "command_gain", "w_unit", "u_contains_w", "w_in_u_gain")
"""The ``[loop]`` keys of a tracking set."""
W_UNITS = ("command", "N")
"""``[loop] w_unit``: the additive input w in command units (F = G·(sat(u) + w), the default) or
in newtons, added to the force (F = G·sat(u) + w).

``[loop] u_contains_w`` (boolean) states whether each run's recorded u already holds w (u =
sat(u_c) + g·w, u_c the controller's output; the force is then G·u, w not added again) and
``[loop] w_in_u_gain`` (a number of magnitude 1e-30 … 1e30, command units per unit of w) the
gain g; the gain alone implies ``u_contains_w = true``. Neither given: measured from each run
that records u and w (:mod:`phoid.methods.tracking_semantics`)."""
W_GAIN_RANGE = (1e-30, 1e30)
"""The magnitudes ``[loop] w_in_u_gain`` may have (the format's range for physical numbers:
nothing on a rig scales a command by 1e30, and within it gain·w of a finite record stays
finite unless w itself is beyond 1e278)."""
RUN_GAINS = ("P", "D", "gain", "command_gain")
"""The gains: a number, or the name of a scalar variable of the run's file."""
TRACKING_RUN_KEYS = ("file", *RUN_GAINS, "columns")
"""The keys of a tracking set's ``[[run]]`` table."""
TRACKING_COLUMNS = ("t", "x", "r", "u", "w")
"""The signals of a tracking run, in the order they are kept: ``t``, ``x``, ``r`` needed,
``u`` (recorded command) and ``w`` (additive command input) optional."""
MIN_TRACKING_SAMPLES = 5
"""Fewest samples of a tracking run, whatever the estimator (:func:`min_samples`)."""

_GAIN_UNITS = {"P": "command units per m", "D": "command units per m/s",
               "gain": "K, dimensionless", "command_gain": "G, N per command unit"}


def check_estimator(where: str, value: Any) -> str:
    """The top-level ``estimator``: one of :data:`ESTIMATORS` (None: ``"auto"``)."""
    if value is None:
        return "auto"
    if value not in ESTIMATORS:
        fail(where, f"key 'estimator' must be one of {', '.join(map(repr, ESTIMATORS))}; "
                     f"got {show(value)}")
    return str(value)


def check_fixed(where: str, table: Any) -> dict[str, float]:
    """The ``[fixed]`` table: known m (kg, > 0), c (N·s/m, ≥ 0), k (N/m, ≥ 0), fc (N, ≥ 0),
    offset (N).

    Every value a finite number, within the plant model's range (a negative c or k cannot be
    simulated); an unknown key is an error (it would be silently ignored).
    """
    if table is None:
        return {}
    if not isinstance(table, Mapping):
        fail(where, f"'fixed' must be a table ([fixed]); got {kind_of(table)}")
    fwhere = f"{where}: [fixed]"
    case_clash(fwhere, table, FIXED_KEYS, "[fixed]")
    out: dict[str, float] = {}
    for key, value in table.items():
        if key not in FIXED_KEYS:
            fail(fwhere, f"unknown key {show(key)}: [fixed] holds only "
                          f"{', '.join(map(repr, FIXED_KEYS))}")
        minimum = {"m": 0.0, "c": 0.0, "k": 0.0, "fc": 0.0}.get(key)
        out[key] = checked_number(fwhere, key, value, minimum=minimum, strict=(key == "m"))
    return out


def velocity_taps(where: str, velocity: Any, cutoff: Any = None,
                  sample_time: float | None = None) -> int:
    """Check ``[loop] velocity`` and ``cutoff``; return the estimator's taps.

    ``velocity`` is a name of :data:`VELOCITY_PRESETS` (None: ``"backward-difference"``) or an
    array of finite FIR coefficients b_j (1/s), v̂_n = Σ_j b_j x_{n−j}: at least two, not all
    zero, summing to zero (:func:`phoid.dynamics.velocity.fir_problem`), whose taps are its
    length − 1 (:func:`phoid.dynamics.velocity.estimator_taps`). ``cutoff`` (rad/s, > 0, of
    magnitude 1e-30 … 1e30: :func:`phoid.dynamics.velocity.check_cutoff`) is required with
    ``"filtered"`` and refused otherwise; with the ``sample_time`` (s) of ``[loop]``, the
    estimator is built (:class:`phoid.dynamics.velocity.VelocityFilter`, the one validator)
    and a cut-off too low for the period is refused here, naming the key.
    """
    lwhere = f"{where}: [loop]"
    if velocity is None:
        velocity = "backward-difference"
    if isinstance(velocity, str):
        if velocity not in VELOCITY_PRESETS:
            fail(lwhere, f"key 'velocity' must be one of "
                          f"{', '.join(map(repr, VELOCITY_PRESETS))} or an array of FIR "
                          f"coefficients (1/s); got {show(velocity)}")
        taps = estimator_taps(velocity)
    elif isinstance(velocity, list | tuple):
        if not velocity:
            fail(lwhere, "key 'velocity' is an empty array; give the FIR coefficients b_0, "
                          "b_1, … (1/s) or a preset name")
        for j, b in enumerate(velocity):
            if isinstance(b, bool) or not isinstance(b, numbers.Real) \
                    or not math.isfinite(float(b)):
                fail(lwhere, f"key 'velocity': coefficient {j} must be a finite number; got "
                              f"{show(b)} ({kind_of(b)})")
        problem = fir_problem([float(b) for b in velocity])
        if problem is not None:
            fail(lwhere, f"key 'velocity' {problem}")
        taps = estimator_taps(velocity)
    else:
        fail(lwhere, f"key 'velocity' must be a preset name or an array of numbers; got "
                      f"{show(velocity)} ({kind_of(velocity)})")
    if velocity == "filtered":
        if cutoff is None:
            fail(lwhere, "key 'cutoff' (rad/s) is required with velocity = 'filtered'")
        try:
            check_cutoff(cutoff)
            if sample_time is not None:
                VelocityFilter(velocity, sample_time, cutoff)
        except ValueError as exc:
            fail(lwhere, re.sub(r"`(\w+)`", r"key '\1'", str(exc)))
    elif cutoff is not None:
        fail(lwhere, "key 'cutoff' applies only to velocity = 'filtered'")
    return taps


def min_samples(taps: int) -> int:
    """Fewest samples of a tracking run: ``taps + 1`` (one velocity estimate needs the current
    sample and ``taps`` earlier ones), and never fewer than :data:`MIN_TRACKING_SAMPLES`."""
    return max(taps + 1, MIN_TRACKING_SAMPLES)


def check_tracking_loop(where: str, loop: Mapping[str, Any]) -> tuple[int, dict[str, Any]]:
    """Check a tracking set's ``[loop]`` table.

    Returns the velocity estimator's taps and the loop-level gains (``P``, ``D``, ``gain``,
    ``command_gain`` that are given: a float, or the name of a scalar variable as a str).
    An unknown key is an error naming it.
    """
    lwhere = f"{where}: [loop]"
    case_clash(lwhere, loop, TRACKING_LOOP_KEYS, "[loop]")
    for key in loop:
        if key not in TRACKING_LOOP_KEYS:
            fail(lwhere, f"unknown key {show(key)} in a tracking set's [loop]: it holds "
                          f"{', '.join(map(repr, TRACKING_LOOP_KEYS))}")
    if "sample_time" in loop:
        checked_number(lwhere, "sample_time", loop["sample_time"], minimum=0.0, strict=True)
    if "delay" in loop:
        checked_number(lwhere, "delay", loop["delay"], minimum=0.0)
    if "saturation" in loop:
        checked_number(lwhere, "saturation", loop["saturation"], minimum=0.0, strict=True)
    if "w_unit" in loop and loop["w_unit"] not in W_UNITS:
        fail(lwhere, f"key 'w_unit' must be one of {', '.join(map(repr, W_UNITS))}; got "
                      f"{show(loop['w_unit'])}")
    if "u_contains_w" in loop and not isinstance(loop["u_contains_w"], bool):
        fail(lwhere, f"key 'u_contains_w' must be true or false (whether the recorded command u "
                      f"already holds the additive input w); got {show(loop['u_contains_w'])} "
                      f"({kind_of(loop['u_contains_w'])})")
    if "w_in_u_gain" in loop:
        g = checked_number(lwhere, "w_in_u_gain", loop["w_in_u_gain"])
        if g == 0.0:
            fail(lwhere, "key 'w_in_u_gain' (command units per unit of w) is 0: u would not "
                          "contain w; say so with u_contains_w = false instead")
        if not W_GAIN_RANGE[0] <= abs(g) <= W_GAIN_RANGE[1]:
            fail(lwhere, f"key 'w_in_u_gain' (command units per unit of w) must be of "
                          "magnitude 1e-30 … 1e30 (as every "
                          f"physical number of the format); got {g!r}")
        if loop.get("u_contains_w") is False:
            fail(lwhere, "key 'w_in_u_gain' is the gain with which u contains w, but "
                          "u_contains_w = false; remove one of them")
    taps = velocity_taps(where, loop.get("velocity"), loop.get("cutoff"),
                         float(loop["sample_time"]) if "sample_time" in loop else None)
    gains = {k: _gain(lwhere, k, loop[k]) for k in RUN_GAINS if k in loop}
    return taps, gains


def _gain(where: str, key: str, value: Any) -> float | str:
    """A gain: a finite number (``gain`` and ``command_gain`` non-zero), or a variable name."""
    if isinstance(value, str):
        if not value.strip():
            fail(where, f"key {key!r} is an empty string; give a number or the name of a "
                         "scalar variable of the run's file")
        return value
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        fail(where, f"key {key!r} must be a number or the name of a scalar variable of the "
                     f"run's file; got {show(value)} ({kind_of(value)})")
    v = float(value)
    if not math.isfinite(v):
        fail(where, f"key {key!r} must be finite; got {v}")
    if key in ("gain", "command_gain") and v == 0.0:
        fail(where, f"key {key!r} ({_GAIN_UNITS[key]}) is 0: the command would not reach the "
                     "plant")
    return v


def tracking_run_spec(rwhere: str, table: Mapping[str, Any], loop_gains: Mapping[str, Any],
                      container: bool) -> dict[str, Any]:
    """Check a tracking set's ``[[run]]`` table (its ``file`` is checked by the caller).

    Returns ``gains`` (each of :data:`RUN_GAINS` that the run or the loop gives: a float, or
    ``(name, where)``, a scalar variable to read from the file and the table that named it),
    ``columns`` (phoid name → name in the file, every one of :data:`TRACKING_COLUMNS`),
    ``explicit`` (the signals that ``[run.columns]`` names: they must be in the file) and
    ``extra`` (the table's unknown keys).
    """
    case_clash(rwhere, table, TRACKING_RUN_KEYS, "the run's table")
    for key in ("B", "omega", "added_mass", "bias"):
        if key in table:
            fail(rwhere, f"key {key!r} has no meaning in a tracking set (method = "
                          "\"tracking\"); remove it")
    gains: dict[str, Any] = {}
    for key in RUN_GAINS:
        if key in table:
            value, source = _gain(rwhere, key, table[key]), "[[run]]"
        elif key in loop_gains:
            value, source = loop_gains[key], "[loop]"
        else:
            continue
        if isinstance(value, str):
            if not container:
                fail(rwhere, f"key {key!r} ({source}) names the variable {show(value)}, but a "
                              "CSV file holds no scalar variables; give the number")
            value = (value, source)
        gains[key] = value
    for key in ("P", "D"):
        if key not in gains:
            fail(rwhere, f"missing key {key!r}: a tracking run needs the gains P and D, in "
                          "[[run]] or [loop], each a number or the name of a scalar variable "
                          f"of the run's file{unknown_hint(table, TRACKING_RUN_KEYS)}")
    columns = {k: k for k in TRACKING_COLUMNS}
    explicit: list[str] = []
    given = table.get("columns")
    if given is not None:
        cwhere = f"{rwhere}: [run.columns]"
        if not isinstance(given, Mapping):
            fail(rwhere, f"'columns' must be a table ([run.columns]); got {kind_of(given)}")
        case_clash(cwhere, given, TRACKING_COLUMNS, "[run.columns]")
        for key, name in given.items():
            if key not in TRACKING_COLUMNS:
                fail(cwhere, f"unknown key {show(key)}: [run.columns] maps "
                              f"{', '.join(map(repr, TRACKING_COLUMNS))} to names in the file")
            if not isinstance(name, str) or not name.strip():
                fail(cwhere, f"key {key!r} must be the (non-empty) name of a variable or "
                              f"column in the file; got {show(name)} ({kind_of(name)})")
            columns[key] = name
            explicit.append(key)
    # a name mapped twice: an error, except that an optional signal left at its default
    # name gives way (x = "u" means the file's u is the position, not a command)
    taken = {columns[k]: k for k in explicit}
    if len(taken) < len(explicit):
        twice = next(k for k in explicit if taken[columns[k]] != k)
        fail(rwhere, f"[run.columns] maps both {twice} and {taken[columns[twice]]} to "
                      f"{show(columns[twice])}")
    for key in [k for k in TRACKING_COLUMNS if k not in explicit]:
        if columns[key] in taken:
            if key in ("u", "w"):
                del columns[key]
            else:
                fail(rwhere, f"[run.columns] maps {taken[columns[key]]} to "
                              f"{show(columns[key])}, the default name of {key}: map {key} "
                              "to its own variable too")
    return {"gains": gains, "columns": columns, "explicit": explicit,
            "extra": {k: v for k, v in table.items() if k not in TRACKING_RUN_KEYS}}
