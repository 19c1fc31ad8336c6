#!/usr/bin/env python3
"""Fuzz phoid's readers: the manifest (TOML) and the data files (CSV, gzip, MATLAB, HDF5,
Parquet).

Each input is one byte that picks the target, then the bytes the target gets:

- 0: the bytes are ``experiment.toml`` of a set whose three data files are valid;
- 1: the bytes are a run's data file ``run02.csv`` (plain);
- 2: the bytes are a run's data file ``run02.csv.gz``, gzip-compressed here;
- 3: the bytes are a run's data file ``run02.csv.gz`` as they are (raw gzip streams);
- 4: the bytes are a schedule read by ``phoid.planning.read_schedule``;
- 5, 6, 7: the bytes are the data file of a tracking set's run, ``run01.mat``, ``run01.h5``
  or ``run01.parquet`` (its gain ``P`` the file's scalar ``kp``; needs h5py and pyarrow for
  6 and 7, and the v7.3 ``.mat`` files).

The target writes the files into a temporary folder and reads the set with
:func:`phoid.read_experiment`. Refusing the input with :class:`phoid.errors.PhoidError` (one
printable line naming the manifest) is the expected outcome for bad input; any other exception,
a multi-line or non-printable message, or a set that reads but breaks the reader's own
invariants (read-only float64 columns of equal length, t strictly increasing) is a finding,
and so is a crash of the interpreter (a library's segmentation fault).

Run with atheris (coverage-guided libFuzzer, Linux x86-64 wheels)::

    python fuzz/fuzz_readers.py CORPUS_DIR fuzz/seeds -max_total_time=600

or, where atheris is not installed, with the built-in random mutator (deterministic per seed)::

    python fuzz/fuzz_readers.py --mutate --seconds 600 --seed 1

See docs/fuzzing.md.
"""

from __future__ import annotations

import argparse
import gzip
import os
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np  # noqa: F401  (imported before instrumentation: not worth instrumenting)

HERE = Path(__file__).resolve().parent
SEEDS = HERE / "seeds"

try:
    import atheris
except ImportError:  # pragma: no cover - depends on the platform
    atheris = None

if atheris is not None and "--mutate" not in sys.argv:
    with atheris.instrument_imports(include=["phoid", "tomllib", "gzip", "_compression"]):
        import phoid.io as pio
        import phoid.planning as planning
else:
    import phoid.io as pio
    import phoid.planning as planning

from phoid.errors import PhoidError

MANIFEST = b"""title = "fuzz"
method = "pho"
[loop]
delay = 0.01
[[run]]
file = "run01.csv"
P = 1.0
D = 0.5
[[run]]
file = "run02.csv"
P = 2.0
D = 0.5
[[run]]
file = "run03.csv.gz"
P = 3.0
D = 0.5
"""


def _csv(amplitude: float) -> bytes:
    t = [i * 1e-3 for i in range(20)]
    return ("t,x,u\n" + "".join(f"{a!r},{amplitude * (1 - a)!r},{-a!r}\n" for a in t)).encode()


TRACKING = {5: ".mat", 6: ".h5", 7: ".parquet"}
MODES = 8


def _tracking_manifest(suffix: str) -> bytes:
    return (f'method = "tracking"\n[[run]]\nfile = "run01{suffix}"\nP = "kp"\nD = 0.5\n'
            ).encode()


GOOD = {"run01.csv": _csv(1.0), "run02.csv": _csv(2.0),
        "run03.csv.gz": gzip.compress(_csv(3.0), mtime=0)}
WORK = Path(tempfile.mkdtemp(prefix="phoid-fuzz-"))


def _check_message(exc: BaseException) -> None:
    msg = str(exc)
    if not msg or not msg.isprintable():
        raise AssertionError(f"message not one printable line: {msg!r}")
    if len(msg) > 2100:
        raise AssertionError(f"message of {len(msg)} characters")


def _check_set(exp: pio.ExperimentSet) -> None:
    for run in exp.runs:
        n = run.t.size
        for a in (run.t, run.x, run.u, run.F, run.r, run.w):
            if a is None:
                continue
            assert a.dtype == np.float64 and a.ndim == 1 and a.size == n
            assert not a.flags.writeable and np.isfinite(a).all()
        assert n >= 2 and (np.diff(run.t) > 0).all()
        assert run.name.isprintable()


def one_input(data: bytes) -> None:
    """The fuzz target: one input, as described in the module docstring."""
    if not data:
        return
    mode, body = data[0] % MODES, data[1:]
    folder = WORK / "set"
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir()
    files = dict(GOOD)
    manifest = MANIFEST
    if mode in TRACKING:
        manifest = _tracking_manifest(TRACKING[mode])
        files = {f"run01{TRACKING[mode]}": body}
    elif mode in (0, 4):
        manifest = body
    elif mode == 1:
        files["run02.csv"] = body
    else:
        files.pop("run02.csv")
        files["run02.csv.gz"] = gzip.compress(body, mtime=0) if mode == 2 else body
        manifest = manifest.replace(b'"run02.csv"', b'"run02.csv.gz"')
    (folder / "experiment.toml").write_bytes(manifest)
    for name, content in files.items():
        (folder / name).write_bytes(content)
    try:
        if mode == 4:
            planning.read_schedule(folder)
        else:
            _check_set(pio.read_experiment(folder))
    except PhoidError as exc:
        _check_message(exc)


def seeds() -> list[bytes]:
    """The seed corpus (fuzz/seeds), one input per file."""
    return [p.read_bytes() for p in sorted(SEEDS.iterdir()) if p.is_file()]


def mutate(rng: random.Random, data: bytes, pool: list[bytes]) -> bytes:
    """A libFuzzer-like byte mutation: flips, inserts, deletes, repeats, splices."""
    b = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        op = rng.randrange(7)
        i = rng.randrange(len(b) + 1)
        if op == 0 and b:
            b[min(i, len(b) - 1)] ^= 1 << rng.randrange(8)
        elif op == 1:
            b[i:i] = bytes([rng.choice(b"\x00\n\r,.-+eE[]{}=\"'#\\ 0123456789\xff\x1f\x8b")])
        elif op == 2 and b:
            del b[i:i + rng.randint(1, 16)]
        elif op == 3 and b:
            j = rng.randrange(len(b))
            chunk = b[j:j + rng.randint(1, 32)]
            b[i:i] = chunk * rng.randint(1, 64)
        elif op == 4:
            other = rng.choice(pool)
            j = rng.randrange(len(other) + 1)
            b[i:] = other[j:]
        elif op == 5 and len(b) > 1:
            b[0] = rng.randrange(MODES)
        else:
            b[i:i] = rng.choice([b"nan", b"inf", b"1e400", b"\n\n", b"[[run]]\n", b"t,x\n",
                                 b"\xef\xbb\xbf", b"\r\n", b"=[[[[", b"{a={b=", b"..", b"/"])
    return bytes(b[: 1 << 16])


def run_mutator(seconds: float, seed: int) -> int:
    """Mutation fuzzing without atheris; returns the number of inputs tried."""
    rng = random.Random(seed)
    pool = seeds()
    end = time.monotonic() + seconds
    n = 0
    while time.monotonic() < end:
        data = mutate(rng, rng.choice(pool), pool)
        try:
            one_input(data)
        except Exception:
            crash = HERE / f"crash-mutate-{seed}-{n}"
            crash.write_bytes(data)
            print(f"finding after {n} inputs; input saved to {crash}", file=sys.stderr)
            raise
        if n % 7 == 0:
            pool.append(data)
            if len(pool) > 2000:
                pool.pop(rng.randrange(len(seeds()), len(pool)))
        n += 1
    return n


def main() -> None:
    if atheris is not None and "--mutate" not in sys.argv:
        atheris.Setup(sys.argv, one_input)
        atheris.Fuzz()
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mutate", action="store_true", help="use the built-in mutator")
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=0)
    args, rest = parser.parse_known_args()
    for arg in rest:  # libFuzzer's options (from `make fuzz`) where atheris is missing
        if arg.startswith("-max_total_time="):
            args.seconds = float(arg.split("=", 1)[1])
    why = "--mutate" if atheris is not None else "atheris is not installed"
    print(f"built-in mutator ({why}), {args.seconds:g} s", file=sys.stderr)
    try:
        n = run_mutator(args.seconds, args.seed)
    finally:
        shutil.rmtree(WORK, ignore_errors=True)
    print(f"{n} inputs in {args.seconds:g} s, no finding")


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    main()
