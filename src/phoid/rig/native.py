r"""The rig's C controller (``phoid/rig/c``), compiled with the machine's C compiler and bound.

The controller is C99 (``phoid_ctrl.h``, ``phoid_ctrl.c``; their README is the contract): a
fixed-rate step u = K·(P·(r − x) − D·v̂) with phoid's velocity estimators, a whole-sample command
delay and the run state machine IDLE → HOLD → RUN → DONE (FAULT on a safety trip). This module
compiles the two files into a shared library inside a folder the caller names (the compiler's
own temporary files too), loads it with :mod:`ctypes` and wraps it thinly: :class:`Controller`
steps one sample at a time, exactly as a microcontroller would.

The compiler is ``$CC`` when set, else the first of ``cc``, ``gcc``, ``clang`` on the PATH;
flags ``-std=c99 -ffp-contract=off -O2 -fPIC -shared -Wall -Wextra -Werror`` (``-std=c99
-ffp-contract=off``: no fused multiply-adds, so the double build is bit-identical to phoid's
model). Without one, :class:`CompilerNotFoundError` says so in one line; nothing else in phoid
needs a compiler.

The controller's real type is chosen at compile time (``PHOID_REAL``): ``real="double"`` (the
default, phoid's arithmetic) or ``real="float"`` (``-DPHOID_REAL=float``, what a microcontroller
with a single-precision FPU runs), so that a test can step the float build on the host.
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import operator
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from phoid._output import OutputFolder
from phoid.dynamics.velocity import VelocityFilter
from phoid.errors import PhoidError

__all__ = [
    "CFLAGS",
    "SOURCES",
    "CompilerNotFoundError",
    "Controller",
    "Event",
    "build_library",
    "find_compiler",
    "load_library",
]

C_DIR = Path(__file__).parent / "c"
SOURCES = (C_DIR / "phoid_ctrl.h", C_DIR / "phoid_ctrl.c")
CFLAGS = ("-std=c99", "-ffp-contract=off", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra",
          "-Werror")
# the controller's real types (PHOID_REAL): the ctypes type, the extra compiler flags, the
# largest finite value (a value beyond it is refused rather than rounded to inf)
REALS: dict[str, tuple[type, tuple[str, ...], float]] = {
    "double": (ctypes.c_double, (), 1.7976931348623157e308),
    "float": (ctypes.c_float, ("-DPHOID_REAL=float",), 3.4028234663852886e38),
}

STATES = ("idle", "hold", "run", "done", "fault")
# the C enum phoid_velocity (phoid_ctrl.h) of each of phoid's presets: the controller computes
# their coefficients itself, as phoid.dynamics.velocity defines them (a filtered one from the pole
# a = exp(-cutoff·T) that VelocityFilter gives); tests/test_velocity_model.py checks both
VELOCITIES = {"backward-difference": 0, "central-difference": 1, "filtered": 2}

# phoid_init's error codes (phoid_ctrl.h, enum phoid_error): the field and what it must be
_ERRORS = {
    -2: ("sample_time", "must be finite and >= 1e-9 (s; PHOID_MIN_SAMPLE_TIME)"),
    -3: ("velocity", "must be 'backward-difference', 'central-difference' or 'filtered' "
                     "(0, 1, 2)"),
    -4: ("filter_pole", "must be in [0, 1) (a = exp(-cutoff·T))"),
    -5: ("delay_samples", "must be a whole number from 0 to the controller's PHOID_MAX_DELAY"),
    -6: ("P, D, gain, hold_P, hold_D", "must be finite"),
    -7: ("command_gain", "must be finite and > 0 (N per command unit)"),
    -8: ("x_min, x_max", "must satisfy x_min < x_max (m)"),
    -9: ("x_start", "must be finite and within [x_min, x_max] (m)"),
    -10: ("u_max", "must be > 0 (command units)"),
    -11: ("growth_limit", "must be 0 (off) or finite and >= 1"),
    -12: ("stall_samples, stall_epsilon", "must be stall_samples from 0 to 2147483647 and "
                                          "stall_epsilon finite and >= 0 (m)"),
    -13: ("hold_samples, run_samples", "must be hold_samples from 0 and run_samples from 1, "
                                       "to 2147483647 (PHOID_MAX_COUNT)"),
    -15: ("has_force", "must be 0 (no force sensor) or 1 (a force with every sample)"),
}


class CompilerNotFoundError(PhoidError):
    """No C compiler: the rig's controller cannot be built (the rest of phoid works)."""


def _config_fields(real: type) -> list[tuple[str, type]]:
    """The fields of ``phoid_config`` with ``phoid_real`` = ``real``."""
    return [
        ("sample_time", real),
        ("P", real),
        ("D", real),
        ("gain", real),
        ("command_gain", real),
        ("velocity", ctypes.c_int),
        ("filter_pole", real),
        ("delay_samples", ctypes.c_int),
        ("hold_P", real),
        ("hold_D", real),
        ("x_start", real),
        ("hold_samples", ctypes.c_long),
        ("run_samples", ctypes.c_long),
        ("x_min", real),
        ("x_max", real),
        ("u_max", real),
        ("growth_limit", real),
        ("stall_samples", ctypes.c_long),
        ("stall_epsilon", real),
        ("has_force", ctypes.c_int),
    ]


class _Config(ctypes.Structure):
    """ctypes mirror of ``phoid_config``, double build (checked against ``phoid_config_size()``)."""

    _fields_ = _config_fields(ctypes.c_double)


class _ConfigFloat(ctypes.Structure):
    """ctypes mirror of ``phoid_config``, float build."""

    _fields_ = _config_fields(ctypes.c_float)


class _Event(ctypes.Structure):
    """ctypes mirror of ``phoid_event``, double build."""

    _fields_ = [("index", ctypes.c_ulonglong), ("code", ctypes.c_int),
                ("value", ctypes.c_double)]


class _EventFloat(ctypes.Structure):
    """ctypes mirror of ``phoid_event``, float build."""

    _fields_ = [("index", ctypes.c_ulonglong), ("code", ctypes.c_int),
                ("value", ctypes.c_float)]


_STRUCTS: dict[str, tuple[type[ctypes.Structure], type[ctypes.Structure]]] = {
    "double": (_Config, _Event), "float": (_ConfigFloat, _EventFloat)}


def _real(real: object) -> str:
    """``real`` checked: ``"double"`` or ``"float"`` (ValueError naming the option)."""
    if not isinstance(real, str) or real not in REALS:
        raise ValueError(f"`real` must be one of {', '.join(REALS)} (the controller's "
                         f"PHOID_REAL); got {real!r}")
    return real


_INT_FIELDS = {"velocity", "delay_samples", "hold_samples", "run_samples", "stall_samples",
               "has_force"}


def _int_range(key: str) -> tuple[int, int]:
    """The values the C type of ``phoid_config.<key>`` holds on this machine."""
    ctype = dict(_Config._fields_)[key]
    bits = 8 * ctypes.sizeof(ctype)
    return -(1 << (bits - 1)), (1 << (bits - 1)) - 1


@dataclass(frozen=True)
class Event:
    """One entry of the controller's event log.

    Attributes
    ----------
    index : int
        Sample index at which it took effect (the first sample of the new state; for a fault,
        the sample at which it tripped and from which the command is 0).
    code : int
        The C event code (``enum phoid_event_code``).
    name : str
        Its name: ``"start"``, ``"release"``, ``"done"``, ``"clip"``, ``"fault-position"``,
        ``"fault-growth"``, ``"fault-stall"``, ``"fault-input"``, ``"fault-host"``, ``"clear"``,
        ``"fault-command"``.
    value : float
        The code's value (the position at a release, m; the unclipped command of a clip, …).
    """

    index: int
    code: int
    name: str
    value: float


def find_compiler() -> list[str] | None:
    """The C compiler's command: ``$CC`` (split like a shell) or cc, gcc, clang on the PATH."""
    env = os.environ.get("CC", "").strip()
    if env:
        cmd = shlex.split(env)
        return cmd if shutil.which(cmd[0]) else None
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return [path]
    return None


def _suffix() -> str:
    if sys.platform == "darwin":
        return ".dylib"
    return ".dll" if os.name == "nt" else ".so"


def build_library(folder: str | Path, real: str = "double") -> Path:
    """Compile the controller into a shared library inside ``folder``; its path.

    ``real`` is the controller's real type, ``"double"`` (default) or ``"float"``
    (``-DPHOID_REAL=float``). The file is named after a hash of the sources, the compiler
    command and the flags, so an existing library of the same build is reused. The compiler
    writes only inside ``folder`` (its temporary files go to a temporary subfolder there,
    ``TMPDIR``), and the library is put in place atomically (:class:`phoid._output.OutputFolder`).

    Raises
    ------
    ValueError
        When ``real`` is neither ``"double"`` nor ``"float"``.
    CompilerNotFoundError
        When no C compiler is found.
    PhoidError
        When the compiler fails (its first error line), or the folder is not writable.
    """
    flags = (*CFLAGS, *REALS[_real(real)][1])
    cc = find_compiler()
    if cc is None:
        raise CompilerNotFoundError(
            "the rig's controller needs a C compiler (set CC, or install cc, gcc or clang); "
            "the rest of phoid works without one"
        )
    key = hashlib.sha256()
    for part in (*cc, *flags):
        key.update(part.encode() + b"\0")
    for src in SOURCES:
        key.update(src.read_bytes())
    tag = "" if real == "double" else f"{real}-"
    name = f"phoid_ctrl-{tag}{key.hexdigest()[:16]}{_suffix()}"
    out = OutputFolder(folder, overwrite=True)
    target = out.path(name)
    if target.is_file() and not target.is_symlink():
        return target
    out.check([name])
    os.makedirs(out.folder, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.folder, prefix=".phoid-cc-") as tmp:
        lib = Path(tmp) / f"lib{_suffix()}"
        cmd = [*cc, *flags, "-o", str(lib), str(SOURCES[1])]
        env = {**os.environ, "TMPDIR": tmp, "TMP": tmp, "TEMP": tmp}
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
        if proc.returncode != 0 or not lib.is_file():
            first = next((ln for ln in (proc.stderr or proc.stdout).splitlines()
                          if "error" in ln), (proc.stderr or "no output").strip()[:200])
            raise PhoidError(f"compiling the rig's controller with {cc[0]} failed: {first}")
        return out.write(name, lib.read_bytes())


_LIBRARIES: dict[str, ctypes.CDLL] = {}


def load_library(folder: str | Path, real: str = "double") -> ctypes.CDLL:
    """Build (when needed) and load the controller library in ``folder``, with its signatures.

    ``real``: the controller's real type, ``"double"`` (default) or ``"float"``; the library's
    ``phoid_real_size()`` and ``phoid_config_size()`` are checked against the binding's.
    """
    path = build_library(folder, real)
    key = os.path.realpath(path)
    if key in _LIBRARIES:
        return _LIBRARIES[key]
    lib = ctypes.CDLL(key)
    P = ctypes.c_void_p
    R = REALS[real][0]
    config, event = _STRUCTS[real]
    sig = {
        "phoid_config_default": (None, [ctypes.POINTER(config)]),
        "phoid_init": (ctypes.c_int, [P, ctypes.POINTER(config)]),
        "phoid_step": (R, [P, R, R]),
        "phoid_step_force": (R, [P, R, R, R]),
        "phoid_force": (R, [P]),
        "phoid_start": (ctypes.c_int, [P]),
        "phoid_release": (ctypes.c_int, [P]),
        "phoid_abort": (None, [P, R]),
        "phoid_clear_fault": (None, [P]),
        "phoid_state": (ctypes.c_int, [P]),
        "phoid_sample_index": (ctypes.c_ulonglong, [P]),
        "phoid_set_sample_index": (ctypes.c_int, [P, ctypes.c_ulonglong]),
        "phoid_velocity": (R, [P]),
        "phoid_clips": (ctypes.c_ulong, [P]),
        "phoid_events_lost": (ctypes.c_ulong, [P]),
        "phoid_pop_event": (ctypes.c_int, [P, ctypes.POINTER(event)]),
        "phoid_event_name": (ctypes.c_char_p, [ctypes.c_int]),
        "phoid_config_size": (ctypes.c_ulong, []),
        "phoid_ctrl_size": (ctypes.c_ulong, []),
        "phoid_real_size": (ctypes.c_int, []),
    }
    for fname, (res, args) in sig.items():
        fn = getattr(lib, fname)
        fn.restype = res
        fn.argtypes = args
    if lib.phoid_real_size() != ctypes.sizeof(R):
        raise PhoidError(f"{path}: phoid_real has {lib.phoid_real_size()} bytes, the "
                         f"binding expects {ctypes.sizeof(R)} ({real}); rebuild the library")
    if lib.phoid_config_size() != ctypes.sizeof(config):
        raise PhoidError(f"{path}: phoid_config has {lib.phoid_config_size()} bytes, the "
                         f"binding expects {ctypes.sizeof(config)}; rebuild the library")
    _LIBRARIES[key] = lib
    return lib


def _checked_fields(config: Mapping[str, object], sample_time: float) -> dict[str, float | int]:
    """The fields of a controller configuration checked and converted: known names, whole
    numbers within their C type for the count fields, numbers for the real ones, a velocity
    preset's name as its code, ``cutoff`` (rad/s) as ``filter_pole`` (ValueError naming the
    field). ``sample_time``: the build's default, for a ``cutoff`` without one."""
    names = {f[0] for f in _Config._fields_}
    items = dict(config)
    if "cutoff" in items:
        if "filter_pole" in items:
            raise ValueError("give `cutoff` (rad/s) or `filter_pole`, not both")
        cutoff = items.pop("cutoff")
        T = items.get("sample_time", sample_time)
        items["filter_pole"] = VelocityFilter("filtered", T, cutoff).filter_pole
    out: dict[str, float | int] = {}
    for key, value in items.items():
        if key not in names:
            raise ValueError(f"unknown controller field `{key}`; the fields are "
                             f"{', '.join(sorted(names | {'cutoff'}))}")
        if key == "velocity" and isinstance(value, str):
            if value not in VELOCITIES:
                raise ValueError(f"`velocity` must be one of {', '.join(VELOCITIES)}; "
                                 f"got {value!r}")
            value = VELOCITIES[value]
        try:
            if key in _INT_FIELDS:
                if isinstance(value, bool) or int(value) != value:
                    raise TypeError
                number: float | int = int(value)
            else:
                number = float(value)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"controller field `{key}` must be a "
                             f"{'whole number' if key in _INT_FIELDS else 'number'}; "
                             f"got {value!r}") from None
        if key in _INT_FIELDS:
            lo, hi = _int_range(key)
            if not lo <= number <= hi:  # ctypes would wrap it silently (2**64 → 0)
                raise ValueError(f"controller field `{key}` must be a whole number from "
                                 f"{lo} to {hi} (its C type); got {value!r}")
        out[key] = number
    return out


def _init_error(err: int, cfg: ctypes.Structure, given: Mapping[str, float | int],
                real: str) -> str:
    """The one-line message of a configuration phoid_init refused with ``err``: the field,
    its rule and the value given (with the value the build holds when rounding changed it)."""
    field, what = _ERRORS.get(err, ("config", "is refused"))
    shown = []
    for f in (f.strip() for f in field.split(",")):
        held = getattr(cfg, f, None)
        value = given.get(f, held)
        shown.append(f"{f}={value!r}" if held == value or held is None
                     else f"{f}={value!r} (the {real} build holds {held!r})")
    return (f"controller config: `{field}` {what}; got {', '.join(shown)} "
            f"(phoid_init error {err})")


def _check_in_double(items: Mapping[str, float | int], defaults: ctypes.Structure,
                     folder: str | Path) -> None:
    """Check a configuration with the double build's phoid_init before it is rounded to a
    narrower real (ValueError as the double build words it): the fields not given take
    ``defaults`` (the narrower build's own, which a double holds exactly)."""
    lib = load_library(folder, "double")
    cfg = _Config()
    for name, _ in _Config._fields_:
        setattr(cfg, name, getattr(defaults, name))
    for key, value in items.items():
        setattr(cfg, key, value)
    buf = ctypes.create_string_buffer(int(lib.phoid_ctrl_size()))
    err = lib.phoid_init(ctypes.cast(buf, ctypes.c_void_p), ctypes.byref(cfg))
    if err != 0:
        raise ValueError(_init_error(err, cfg, items, "double"))


class Controller:
    """The compiled C controller, one instance (``phoid_ctrl``), stepped from Python.

    Parameters
    ----------
    config : mapping
        Fields of ``phoid_config`` (phoid_ctrl.h; unnamed fields keep
        ``phoid_config_default``'s values): ``sample_time`` (s), ``P`` (command units/m),
        ``D`` (command units/(m/s)), ``gain`` K, ``command_gain`` G, ``velocity`` (a preset
        name of :data:`phoid.dynamics.velocity.VELOCITY_PRESETS` or 0, 1, 2),
        ``filter_pole`` a = exp(−ω_c T) or ``cutoff`` ω_c (rad/s, converted to the pole of
        :class:`phoid.dynamics.velocity.VelocityFilter`, which checks it), ``delay_samples``,
        ``hold_P``, ``hold_D``, ``x_start`` (m), ``hold_samples``, ``run_samples``, ``x_min``,
        ``x_max`` (m), ``u_max`` (command units), ``growth_limit``, ``stall_samples``,
        ``stall_epsilon`` (m), ``has_force`` (1: a force sensor is declared, every
        :meth:`step` must bring a finite ``force``).
    folder : str or Path
        Where the library is built (or found, when built before).
    real : {"double", "float"}
        The controller's real type (``PHOID_REAL``): ``"double"`` (default) or ``"float"``,
        the build a microcontroller with a single-precision FPU runs. In the float build the
        real fields, x, r and the force are rounded to float on their way in. The
        configuration is checked as given by the double build's ``phoid_init`` first (the
        float build refuses what the double build refuses), then rounded: a finite value that
        rounds to infinity (beyond ±FLT_MAX by more than half a unit) or a non-zero value that
        rounds to 0 is refused, naming the field, and the float ``phoid_init`` checks the
        rounded values (``x_min`` < ``x_max`` may not survive the rounding).

    Raises
    ------
    ValueError
        For an unknown field or a value of the wrong type (or, float build, one float cannot
        hold), an unknown ``real``, or when ``phoid_init`` refuses the configuration (the
        message names the field).
    CompilerNotFoundError
        When no C compiler is found.
    """

    def __init__(self, config: Mapping[str, object], folder: str | Path,
                 real: str = "double") -> None:
        self.real = _real(real)
        self._lib = load_library(folder, real)
        self._event = _STRUCTS[real][1]
        cfg = _STRUCTS[real][0]()
        self._lib.phoid_config_default(ctypes.byref(cfg))
        items = _checked_fields(config, cfg.sample_time)
        if real != "double":
            # The configuration as given is checked by the double build's phoid_init first
            # (the build's own defaults for the fields not given), then rounded: the float
            # build refuses what the double build refuses (growth_limit 1 - 1e-9, which
            # rounds to 1.0), and rounding only adds refusals, each named as such below.
            _check_in_double(items, cfg, folder)
        largest = REALS[real][2]
        for key, value in items.items():
            if key in _INT_FIELDS:
                setattr(cfg, key, value)
                continue
            rounded = REALS[real][0](value).value
            if math.isfinite(value) and not math.isfinite(rounded):
                raise ValueError(f"controller field `{key}` must be within ±{largest!r} (the "
                                 f"{real} build's largest finite value; it rounds to "
                                 f"{rounded!r} there); got {value!r}")
            if value != 0.0 and rounded == 0.0:  # 0 means "none" or "off" to several fields
                raise ValueError(f"controller field `{key}` is too small for the {real} build "
                                 f"(it rounds to 0 there); got {value!r}")
            setattr(cfg, key, value)
        self.config = cfg
        self._buf = ctypes.create_string_buffer(int(self._lib.phoid_ctrl_size()))
        self._ptr = ctypes.cast(self._buf, ctypes.c_void_p)
        err = self._lib.phoid_init(self._ptr, ctypes.byref(cfg))
        if err != 0:
            raise ValueError(_init_error(err, cfg, items, real))

    def step(self, x: float, r: float = 0.0, force: float | None = None) -> float:
        """One sample: position x (m), reference r (m) → the command to apply now.

        ``force`` is the measured force on the plant, N (``phoid_step_force``): stored
        (:attr:`force`), not used by the loop; with ``has_force`` = 1 a missing or non-finite
        force faults the controller (``fault-input``, value 1). ``None``: ``phoid_step``.
        """
        if force is None:
            return self._lib.phoid_step(self._ptr, x, r)
        return self._lib.phoid_step_force(self._ptr, x, r, force)

    @property
    def force(self) -> float:
        """The measured force given with the last sample, N (NaN when none was given)."""
        return float(self._lib.phoid_force(self._ptr))

    def start(self) -> None:
        """IDLE or DONE → HOLD from the next sample on (ValueError in another state)."""
        if self._lib.phoid_start(self._ptr) != 0:
            raise ValueError(f"the controller cannot start in state {self.state!r}")

    def release(self) -> None:
        """Release at the next sample (HOLD only; ValueError in another state)."""
        if self._lib.phoid_release(self._ptr) != 0:
            raise ValueError(f"the controller cannot release in state {self.state!r}")

    def abort(self, reason: float = 0.0) -> None:
        """Abort from the host: FAULT with the event ``fault-host`` (value ``reason``)."""
        self._lib.phoid_abort(self._ptr, reason)

    def clear_fault(self) -> None:
        """FAULT → IDLE (no effect in another state)."""
        self._lib.phoid_clear_fault(self._ptr)

    @property
    def state(self) -> str:
        """``"idle"``, ``"hold"``, ``"run"``, ``"done"`` or ``"fault"``."""
        return STATES[self._lib.phoid_state(self._ptr)]

    @property
    def index(self) -> int:
        """The index of the next sample (samples stepped since the start)."""
        return int(self._lib.phoid_sample_index(self._ptr))

    def set_index(self, n: int) -> None:
        """Set the index of the next sample (``phoid_set_sample_index``; IDLE only).

        For a controller that numbers its samples from an outside clock, and for tests of the
        64-bit counter (reaching 2³² by stepping would take 2³² calls).

        Raises
        ------
        ValueError
            When ``n`` is not a whole number from 0 to 2⁶⁴ − 1, or the state is not IDLE.
        """
        try:
            if isinstance(n, bool):
                raise TypeError
            index = operator.index(n)  # int and integer types (numpy's), not 3.0 or "3"
        except TypeError:
            index = -1
        if not 0 <= index < 1 << 64:
            raise ValueError(f"the sample index must be a whole number from 0 to 2**64 - 1; "
                             f"got {n!r}")
        if self._lib.phoid_set_sample_index(self._ptr, index) != 0:
            raise ValueError(f"the controller's sample index can be set in state 'idle' only; "
                             f"it is {self.state!r}")

    @property
    def velocity(self) -> float:
        """The velocity estimate v̂ of the last sample, m/s."""
        return float(self._lib.phoid_velocity(self._ptr))

    @property
    def clips(self) -> int:
        """Commands clipped to ±u_max so far."""
        return int(self._lib.phoid_clips(self._ptr))

    @property
    def events_lost(self) -> int:
        """Events overwritten in the log before they were read."""
        return int(self._lib.phoid_events_lost(self._ptr))

    def events(self) -> list[Event]:
        """Pop the logged events, oldest first."""
        out = []
        ev = self._event()
        while self._lib.phoid_pop_event(self._ptr, ctypes.byref(ev)):
            out.append(Event(int(ev.index), int(ev.code),
                             self._lib.phoid_event_name(ev.code).decode(), float(ev.value)))
        return out
