"""Tracking sets (method = "tracking", docs/format.md "Tracking sets"): the MATLAB, HDF5 and
Parquet readers, [run.columns], gains resolved from scalar variables, and every bad input.

Every file is written here, into tmp_path, by the libraries users write them with
(scipy.io.savemat, h5py, pyarrow), so the expected values are the arrays the test wrote; the
EMPS record (../shared/data/emps, beside the checkout) is read through a manifest made in
tmp_path, and its expected values are the benchmark's published ones (its README and
description), skipped with the reason where it is absent.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

import phoid.io
import phoid.io.limits
from phoid.errors import ExperimentError
from phoid.io import read_experiment, run_from_arrays, write_experiment

h5py = pytest.importorskip("h5py", reason="h5py (the io extra) is needed for the HDF5 tests")
pa = pytest.importorskip("pyarrow", reason="pyarrow (the io extra) is needed for Parquet")
import pyarrow.parquet as pq  # noqa: E402  (after the importorskip)

ROOT = Path(__file__).resolve().parents[1]
EMPS_FILE = ROOT.parent / "shared" / "data" / "emps" / "DATA_EMPS.mat"
EMPS_ABSENT = (f"the EMPS record is absent ({EMPS_FILE}): it lies beside the checkout "
               "(../shared/data/emps) in CI, not in a clone")

N = 50
T = 0.001
HEAD = 'format = "phoid/1"\nmethod = "tracking"\n'


def signals(n: int = N, seed: int = 0) -> dict[str, np.ndarray]:
    """A made-up record (the reader does not care what the signals mean)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * T
    r = 0.01 * np.sin(2 * np.pi * t)
    return {"t": t, "x": r + 1e-4 * rng.standard_normal(n), "r": r,
            "u": rng.standard_normal(n), "w": 0.1 * rng.standard_normal(n)}


def write_manifest(folder: Path, body: str, head: str = HEAD) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "experiment.toml"
    path.write_text(head + body, encoding="utf-8")
    return path


def read_error(folder: Path) -> str:
    with pytest.raises(ExperimentError) as info:
        read_experiment(folder)
    message = str(info.value)
    assert "\n" not in message  # one line
    return message


def savemat(path: Path, data: dict, column: bool = True) -> None:
    """A MATLAB v5 file; vectors N×1 (MATLAB's column vectors) or 1×N."""
    out = {k: (np.asarray(v).reshape(-1, 1) if column else np.asarray(v).reshape(1, -1))
           if np.ndim(v) == 1 else v for k, v in data.items()}
    scipy.io.savemat(path, out)


def save_mat73(path: Path, data: dict) -> None:
    """A MATLAB v7.3 file as MATLAB writes one: a 512-byte header ("MATLAB 7.3 MAT-file"),
    then HDF5; each variable a dataset with its MATLAB_class, stored transposed (an N×1 vector
    as a 1×N dataset)."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, v in data.items():
            v = np.asarray(v, dtype=float)
            ds = f.create_dataset(name, data=v.reshape(1, -1) if v.ndim == 1 else v.T)
            ds.attrs["MATLAB_class"] = np.bytes_("double")
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: test HDF5 schema 1.00 .")


def save_parquet(path: Path, data: dict, meta: dict | None = None) -> None:
    table = pa.table({k: np.asarray(v) for k, v in data.items()})
    if meta:
        table = table.replace_schema_metadata({k: str(v) for k, v in meta.items()})
    pq.write_table(table, path)


# --------------------------------------------------------------------------------------------
# every reader, the column mapping, the scalars


@pytest.mark.parametrize("column", [True, False], ids=["Nx1", "1xN"])
def test_mat_v5_mapped_columns_and_scalars(tmp_path, column):
    s = signals()
    savemat(tmp_path / "rec.mat", {"time": s["t"], "qm": s["x"], "qg": s["r"], "vir": s["u"],
                                   "kp": np.array([[160.18]]), "kv": np.array([[243.45]]),
                                   "gtau": np.array([[35.15]])}, column)
    write_manifest(tmp_path, '''
[loop]
sample_time = 0.001
velocity = "central-difference"
command_gain = "gtau"
[[run]]
file = "rec.mat"
P = "kp"
D = 1.0
gain = "kv"
[run.columns]
t = "time"
x = "qm"
r = "qg"
u = "vir"
''')
    exp = read_experiment(tmp_path)
    run = exp.runs[0]
    assert exp.method == "tracking" and exp.estimator == "auto" and dict(exp.fixed) == {}
    for key, name in (("t", "t"), ("x", "x"), ("r", "r"), ("u", "u")):
        np.testing.assert_array_equal(getattr(run, key), s[name])  # savemat stores doubles
        assert getattr(run, key).ndim == 1 and not getattr(run, key).flags.writeable
    assert run.w is None  # not mapped, and no variable 'w' in the file
    assert (run.P, run.D, run.gain, run.command_gain) == (160.18, 1.0, 243.45, 35.15)
    assert exp.loop["command_gain"] == "gtau"  # the loop table as written


def test_mat_v73(tmp_path):
    s = signals()
    save_mat73(tmp_path / "rec.mat", {**s, "kp": [[3.5]]})
    assert (tmp_path / "rec.mat").read_bytes().startswith(b"MATLAB 7.3")
    write_manifest(tmp_path, '[[run]]\nfile = "rec.mat"\nP = "kp"\nD = 0.25\n')
    run = read_experiment(tmp_path).runs[0]
    for key in ("t", "x", "r", "u", "w"):
        np.testing.assert_array_equal(getattr(run, key), s[key])
    assert run.P == 3.5 and run.D == 0.25 and run.gain == 1.0 and run.command_gain == 1.0


def test_hdf5_nested_paths_and_scalar_shapes(tmp_path):
    s = signals()
    with h5py.File(tmp_path / "rec.h5", "w") as f:
        g = f.create_group("rig/axis1")
        g["time"] = s["t"]
        g["pos"] = s["x"].reshape(-1, 1)  # N×1
        g["ref"] = s["r"].reshape(1, -1)  # 1×N
        f["P"] = 2.0  # shape ()
        f["gains/D"] = np.array([[0.5]])  # 1×1
        f["K"] = np.array([4.0])  # (1,)
    write_manifest(tmp_path, '''
[[run]]
file = "rec.h5"
P = "P"
D = "gains/D"
gain = "K"
command_gain = 2.5
[run.columns]
t = "rig/axis1/time"
x = "rig/axis1/pos"
r = "/rig/axis1/ref"
''')
    run = read_experiment(tmp_path).runs[0]
    np.testing.assert_array_equal(run.x, s["x"])
    np.testing.assert_array_equal(run.r, s["r"])
    assert (run.P, run.D, run.gain, run.command_gain) == (2.0, 0.5, 4.0, 2.5)
    assert run.u is None and run.w is None


def test_hdf5_integer_signal_is_converted(tmp_path):
    s = signals()
    counts = np.round(s["x"] / 1e-6).astype(np.int32)  # an encoder's counts
    with h5py.File(tmp_path / "rec.hdf5", "w") as f:
        f["t"], f["x"], f["r"] = s["t"], counts, s["r"]
    write_manifest(tmp_path, '[[run]]\nfile = "rec.hdf5"\nP = 1\nD = 0\n')
    run = read_experiment(tmp_path).runs[0]
    assert run.x.dtype == np.float64
    np.testing.assert_array_equal(run.x, counts.astype(float))


def test_parquet_columns_and_metadata_scalars(tmp_path):
    s = signals()
    save_parquet(tmp_path / "rec.parquet", {"t": s["t"], "pos": s["x"], "r": s["r"],
                                            "w": s["w"]}, {"kp": "12.5", "gtau": " 35.15 "})
    write_manifest(tmp_path, '''
[loop]
command_gain = "gtau"
[[run]]
file = "rec.parquet"
P = "kp"
D = 0.1
[run.columns]
x = "pos"
''')
    run = read_experiment(tmp_path).runs[0]
    np.testing.assert_array_equal(run.x, s["x"])
    np.testing.assert_array_equal(run.w, s["w"])  # at its own name: read when present
    assert run.P == 12.5 and run.command_gain == 35.15


def test_csv_run_uses_the_mapping(tmp_path):
    s = signals()
    table = np.column_stack([s["t"], s["x"], s["r"], s["u"]])
    text = "time,pos,ref,cmd\n" + "\n".join(",".join(map(repr, row)) for row in table.tolist())
    (tmp_path / "rec.csv").write_text(text + "\n")
    write_manifest(tmp_path, '''
[loop]
gain = 3.0
[[run]]
file = "rec.csv"
P = 5
D = 0.2
[run.columns]
t = "time"
x = "pos"
r = "ref"
u = "cmd"
''')
    run = read_experiment(tmp_path).runs[0]
    for key in ("t", "x", "r", "u"):
        np.testing.assert_array_equal(getattr(run, key), s[key])  # repr round-trips
    assert run.gain == 3.0 and run.command_gain == 1.0


def test_run_keys_override_the_loop_and_loop_names_resolve_per_run(tmp_path):
    # the same loop-level name resolves in each run's own file
    for i, g in ((1, 10.0), (2, 20.0)):
        s = signals(seed=i)
        savemat(tmp_path / f"r{i}.mat", {**s, "G": np.array([[g]])})
    write_manifest(tmp_path, '''
[loop]
P = 7.0
D = 0.5
command_gain = "G"
[[run]]
file = "r1.mat"
[[run]]
file = "r2.mat"
P = 9.0
command_gain = 4.0
''')
    a, b = read_experiment(tmp_path).runs
    assert (a.P, a.D, a.command_gain) == (7.0, 0.5, 10.0)
    assert (b.P, b.D, b.command_gain) == (9.0, 0.5, 4.0)


def test_one_hdf5_file_holds_several_runs(tmp_path):
    with h5py.File(tmp_path / "all.h5", "w") as f:
        for i in (1, 2):
            s = signals(seed=i)
            for k in ("t", "x", "r"):
                f[f"run{i}/{k}"] = s[k]
    body = "".join(f'''
[[run]]
file = "all.h5"
P = 1
D = 1
[run.columns]
t = "run{i}/t"
x = "run{i}/x"
r = "run{i}/r"
''' for i in (1, 2))
    write_manifest(tmp_path, body)
    a, b = read_experiment(tmp_path).runs
    np.testing.assert_array_equal(b.x, signals(seed=2)["x"])
    assert not np.array_equal(a.x, b.x)
    # the same mapping twice: one recording listed twice
    write_manifest(tmp_path, body.replace("run2/", "run1/"))
    assert "is already used by run 1" in read_error(tmp_path)


def test_same_signals_in_two_files_are_refused(tmp_path):
    s = signals()
    savemat(tmp_path / "a.mat", s)
    save_mat73(tmp_path / "b.mat", s)
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n'
                             '[[run]]\nfile = "b.mat"\nP = 1\nD = 1\n')
    assert "same content" in read_error(tmp_path)


def test_fixed_estimator_and_loop_are_kept(tmp_path):
    savemat(tmp_path / "a.mat", signals())
    write_manifest(tmp_path, '''
estimator = "output-error"
[fixed]
m = 2.5
k = 0
offset = -3.1
[loop]
sample_time = 0.001
velocity = [500.0, 0.0, -500.0]
delay = 0.00037
saturation = 10
[[run]]
file = "a.mat"
P = 1
D = 1
''')
    exp = read_experiment(tmp_path)
    assert exp.estimator == "output-error"
    assert dict(exp.fixed) == {"m": 2.5, "k": 0.0, "offset": -3.1}
    assert exp.loop["velocity"] == (500.0, 0.0, -500.0) and exp.delay == 0.00037


def test_write_and_read_back_a_tracking_set(tmp_path):
    s = signals()
    (tmp_path / "src").mkdir()
    savemat(tmp_path / "src" / "a.mat", {**s, "kp": np.array([[2.0]])})
    write_manifest(tmp_path / "src", '''
estimator = "idim"
[fixed]
k = 0
[loop]
velocity = "central-difference"
command_gain = 35.0
[[run]]
file = "a.mat"
P = "kp"
D = 1
''')
    exp = read_experiment(tmp_path / "src")
    write_experiment(tmp_path / "out", exp)
    back = read_experiment(tmp_path / "out")
    a, b = exp.runs[0], back.runs[0]
    for key in ("t", "x", "r", "u", "w"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    assert (b.P, b.D, b.gain, b.command_gain) == (2.0, 1.0, 1.0, 35.0)
    assert back.estimator == "idim" and dict(back.fixed) == {"k": 0.0}
    assert back.loop["velocity"] == "central-difference"


def test_run_from_arrays_tracking_fields():
    s = signals()
    run = run_from_arrays(s["t"], s["x"], r=s["r"], w=s["w"], P=1.0, D=2.0, gain=3.0,
                          command_gain=4.0)
    assert run.r.flags.writeable is False and run.gain == 3.0
    with pytest.raises(ExperimentError, match="column 'r' has 3 samples but 't' has 50"):
        run_from_arrays(s["t"], s["x"], r=[0, 0, 0])
    with pytest.raises(ExperimentError, match="'command_gain' is 0"):
        run_from_arrays(s["t"], s["x"], command_gain=0.0)
    with pytest.raises(ExperimentError, match="'r' belongs to tracking runs"):
        phoid.io.ExperimentSet(path="x/experiment.toml", runs=(run,), method="pho")


# --------------------------------------------------------------------------------------------
# bad input: one line naming the file, the run and the field


def test_missing_variable_lists_the_file(tmp_path):
    s = signals()
    savemat(tmp_path / "DATA.mat", {"t": s["t"], "qm": s["x"], "qg": s["r"], "vir": s["u"],
                                    "kp": np.array([[1.0]]), "kv": np.array([[1.0]]),
                                    "gtau": np.array([[1.0]])})
    write_manifest(tmp_path, '[[run]]\nfile = "DATA.mat"\nP = 1\nD = 1\n'
                             '[run.columns]\nx = "qmm"\nr = "qg"\n')
    assert read_error(tmp_path).endswith(
        "run 1 (DATA.mat): no variable 'qmm' for x; the file has: gtau, kp, kv, qg, qm, t, vir")


def test_missing_scalar_and_mapped_optional_signal(tmp_path):
    savemat(tmp_path / "a.mat", signals())
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = "kp"\nD = 1\n')
    assert "run 1 (a.mat): no variable 'kp' for P; the file has: r, t, u, w, x" \
        in read_error(tmp_path)
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n'
                             '[run.columns]\nu = "vir"\n')
    assert "no variable 'vir' for u" in read_error(tmp_path)


def test_missing_reference_in_csv(tmp_path):
    (tmp_path / "a.csv").write_text("t,x\n0,0\n1,1\n2,2\n3,3\n4,4\n")
    write_manifest(tmp_path, '[[run]]\nfile = "a.csv"\nP = 1\nD = 1\n')
    assert "run 1 (a.csv): missing column 'r'; the header names 't', 'x'" \
        in read_error(tmp_path)


def test_parquet_missing_scalar_names_the_metadata(tmp_path):
    save_parquet(tmp_path / "a.parquet", signals(), {"kv": "2"})
    write_manifest(tmp_path, '[[run]]\nfile = "a.parquet"\nP = "x"\nD = 1\n')
    msg = read_error(tmp_path)
    assert "no scalar 'x' for P in the file's key-value metadata" in msg
    assert "('x' is a column, not a scalar)" in msg and msg.endswith("the metadata has: kv")


@pytest.mark.parametrize(("where", "key"), [("[[run]]", "P"), ("[[run]]", "D"),
                                            ("[loop]", None)])
def test_gain_missing(tmp_path, where, key):
    savemat(tmp_path / "a.mat", signals())
    body = ('[[run]]\nfile = "a.mat"\nD = 1\n' if key == "P" else
            '[[run]]\nfile = "a.mat"\nP = 1\n' if key == "D" else
            '[loop]\nP = 1\n[[run]]\nfile = "a.mat"\n')
    write_manifest(tmp_path, body)
    missing = key or "D"
    assert f"run 1 (a.mat): missing key '{missing}': a tracking run needs the gains P and D" \
        in read_error(tmp_path)


def test_scalar_not_1x1(tmp_path):
    savemat(tmp_path / "a.mat", {**signals(), "kp": np.array([[1.0, 2.0, 3.0]])})
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = "kp"\nD = 1\n')
    assert "run 1 (a.mat): variable 'kp' for P is a 1×3 array, not a scalar (1×1)" \
        in read_error(tmp_path)


def test_matrix_signal_is_refused(tmp_path):
    s = signals()
    savemat(tmp_path / "a.mat", {**s, "x": np.column_stack([s["x"], s["x"]])})
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    assert "variable 'x' for x is a 50×2 array, not a vector (N×1 or 1×N)" \
        in read_error(tmp_path)


@pytest.mark.parametrize("key", ["r", "u", "w"])
def test_signal_of_another_length(tmp_path, key):
    s = signals()
    s[key] = s[key][:-3]
    savemat(tmp_path / "a.mat", s)
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    assert f"variable '{key}' for {key} has 47 samples but 't' for t has 50" \
        in read_error(tmp_path)


@pytest.mark.parametrize("fmt", ["mat", "h5", "parquet"])
def test_non_finite_value(tmp_path, fmt):
    s = signals()
    s["x"][17] = np.nan
    if fmt == "mat":
        savemat(tmp_path / "a.mat", s)
    elif fmt == "h5":
        with h5py.File(tmp_path / "a.h5", "w") as f:
            for k, v in s.items():
                f[k] = v
    else:
        save_parquet(tmp_path / "a.parquet", s)
    write_manifest(tmp_path, f'[[run]]\nfile = "a.{fmt}"\nP = 1\nD = 1\n')
    what = {"mat": "variable", "h5": "dataset", "parquet": "column"}[fmt]
    assert f"run 1 (a.{fmt}): {what} 'x' for x has a non-finite value at index 17: nan" \
        in read_error(tmp_path)


def test_non_finite_scalar(tmp_path):
    savemat(tmp_path / "a.mat", {**signals(), "kp": np.array([[np.inf]])})
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = "kp"\nD = 1\n')
    assert "variable 'kp' for P is not finite: inf" in read_error(tmp_path)


def test_parquet_null_value(tmp_path):
    s = signals()
    table = pa.table({k: pa.array(v, mask=(np.arange(N) == 4) if k == "r" else None)
                      for k, v in s.items()})
    pq.write_table(table, tmp_path / "a.parquet")
    write_manifest(tmp_path, '[[run]]\nfile = "a.parquet"\nP = 1\nD = 1\n')
    assert "column 'r' has a missing (null) value at index 4" in read_error(tmp_path)


def test_t_not_strictly_increasing(tmp_path):
    s = signals()
    s["t"][20] = s["t"][19]
    savemat(tmp_path / "a.mat", s)
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    assert "variable 't' for t is not strictly increasing at index 20" in read_error(tmp_path)


@pytest.mark.parametrize(("velocity", "need"), [
    ('"central-difference"', 5),  # taps 2: 3 samples per estimate; the floor of 5 rules
    ("[1.0, 0, 0, 0, 0, 0, 0, -1.0]", 8),  # 8 FIR coefficients: taps 7, 8 samples
])
def test_too_few_samples(tmp_path, velocity, need):
    savemat(tmp_path / "a.mat", signals(n=need - 1))
    write_manifest(tmp_path, f'[loop]\nvelocity = {velocity}\n'
                             '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    msg = read_error(tmp_path)
    assert f"run 1 (a.mat): {need - 1} samples; a tracking run needs at least {need}" in msg
    assert "velocity estimator uses" in msg
    savemat(tmp_path / "a.mat", signals(n=need))
    assert read_experiment(tmp_path).runs[0].n == need  # the minimum itself is accepted


@pytest.mark.parametrize(("body", "expected"), [
    ('[[run]]\nfile = "a.mat"\nP = true\nD = 1\n',
     "run 1 (a.mat): key 'P' must be a number or the name of a scalar variable"),
    ('[[run]]\nfile = "a.mat"\nP = 1\nD = 1\ngain = 0\n', "key 'gain' (K, dimensionless) is 0"),
    ('[[run]]\nfile = "a.mat"\nP = 1\nD = 1\ncommand_gain = ""\n',
     "key 'command_gain' is an empty string"),
    ('[loop]\nvelocity = 3\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "[loop]: key 'velocity' must be a preset name or an array of numbers"),
    ('[loop]\nvelocity = "forward"\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "key 'velocity' must be one of 'backward-difference', 'central-difference', 'filtered'"),
    ('[loop]\nvelocity = "filtered"\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "key 'cutoff' (rad/s) is required with velocity = 'filtered'"),
    ('[loop]\ncutoff = 100.0\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "key 'cutoff' applies only to velocity = 'filtered'"),
    ('[loop]\nsaturation = -1\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "[loop]: key 'saturation' must be > 0"),
    ('[loop]\nsample_time = "1ms"\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "[loop]: key 'sample_time' must be a number"),
    ('[loop]\ndelay = -0.001\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "key 'delay' must be ≥ 0 s"),
    ('[loop]\ndelay_samples = 1\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "[loop]: unknown key 'delay_samples' in a tracking set's [loop]"),
    ('[loop]\nSaturation = 1\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "did you mean 'saturation'?"),
    ('estimator = "ls"\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "key 'estimator' must be one of 'auto', 'idim', 'output-error'; got 'ls'"),
    ('[fixed]\nm = 0\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n', "[fixed]: key 'm' must be > 0"),
    ('[fixed]\nfc = -1\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "[fixed]: key 'fc' must be ≥ 0"),
    ('[fixed]\nmass = 1\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
     "[fixed]: unknown key 'mass'"),
    ('fixed = 3\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n', "'fixed' must be a table"),
    ('mass = 2\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n', "give the known mass as [fixed] m"),
    ('[[run]]\nfile = "a.mat"\nP = 1\nD = 1\nbias = 0.5\n',
     "key 'bias' has no meaning in a tracking set"),
    ('[[run]]\nfile = "a.mat"\nP = 1\nD = 1\ncolumns = "x"\n', "'columns' must be a table"),
    ('[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n[run.columns]\nv = "x"\n',
     "[run.columns]: unknown key 'v'"),
    ('[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n[run.columns]\nx = 3\n',
     "[run.columns]: key 'x' must be the (non-empty) name"),
    ('[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n[run.columns]\nx = "q"\nr = "q"\n',
     "[run.columns] maps both x and r to 'q'"),
    ('[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n[run.columns]\nx = "r"\n',
     "[run.columns] maps x to 'r', the default name of r"),
])
def test_bad_keys(tmp_path, body, expected):
    savemat(tmp_path / "a.mat", signals())
    write_manifest(tmp_path, body)
    msg = read_error(tmp_path)
    assert expected in msg, msg
    assert msg.startswith(str(tmp_path / "experiment.toml"))


def test_optional_default_gives_way_to_explicit_mapping(tmp_path):
    # the file's "u" is the position: u is then not read as the command
    s = signals()
    savemat(tmp_path / "a.mat", {"t": s["t"], "u": s["x"], "r": s["r"]})
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n[run.columns]\nx = "u"\n')
    run = read_experiment(tmp_path).runs[0]
    np.testing.assert_array_equal(run.x, s["x"])
    assert run.u is None


def test_idim_needs_u(tmp_path):
    s = signals()
    del s["u"]
    savemat(tmp_path / "a.mat", s)
    write_manifest(tmp_path, 'estimator = "idim"\n[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    assert "run 1 (a.mat): estimator = 'idim' needs the recorded command u" \
        in read_error(tmp_path)


def test_variable_name_in_a_csv_run(tmp_path):
    (tmp_path / "a.csv").write_text("t,x,r\n0,0,0\n1,1,1\n")
    write_manifest(tmp_path, '[loop]\ncommand_gain = "gtau"\n'
                             '[[run]]\nfile = "a.csv"\nP = 1\nD = 1\n')
    assert ("run 1 (a.csv): key 'command_gain' ([loop]) names the variable 'gtau', but a CSV "
            "file holds no scalar variables") in read_error(tmp_path)


@pytest.mark.parametrize(("name", "maker", "expected"), [
    ("a.mat", "parquet", "the data file is a Parquet file by its content, although its name "
                         "ends in .mat"),
    ("a.h5", "mat5", "the data file is a MATLAB v5 file by its content, although its name ends "
                     "in .h5"),
    ("a.parquet", "h5", "the data file is an HDF5 file by its content, although its name ends "
                        "in .parquet"),
    ("a.mat", "text", "the data file is not a MATLAB v5/v7 or v7.3 file"),
    ("a.hdf5", "text", "the data file is not an HDF5 file (it lacks the HDF5 signature)"),
    ("a.parquet", "text", "the data file is not a Parquet file"),
    ("a.mat", "empty", "the data file is empty"),
])
def test_content_must_match_the_suffix(tmp_path, name, maker, expected):
    s = signals()
    path = tmp_path / name
    if maker == "parquet":
        save_parquet(path, s)
    elif maker == "mat5":
        with open(path, "wb") as f:
            scipy.io.savemat(f, s)
    elif maker == "h5":
        with h5py.File(path, "w") as f:
            f["t"] = s["t"]
    else:
        path.write_bytes(b"" if maker == "empty" else b"t,x,r\n0,0,0\n")
    write_manifest(tmp_path, f'[[run]]\nfile = "{name}"\nP = 1\nD = 1\n')
    assert f"run 1 ({name}): {expected}" in read_error(tmp_path)


def test_corrupt_mat_is_one_line(tmp_path):
    savemat(tmp_path / "a.mat", signals())
    data = bytearray((tmp_path / "a.mat").read_bytes())
    (tmp_path / "a.mat").write_bytes(bytes(data[:300]))  # truncated after the header
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    assert "run 1 (a.mat): " in read_error(tmp_path)


def test_text_variable_is_refused(tmp_path):
    savemat(tmp_path / "a.mat", {**signals(), "kp": "160"})
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = "kp"\nD = 1\n')
    assert "variable 'kp' for P is a MATLAB char array, not real numbers" \
        in read_error(tmp_path)


def test_hdf5_group_and_string_dataset_are_refused(tmp_path):
    s = signals()
    with h5py.File(tmp_path / "a.h5", "w") as f:
        for k, v in s.items():
            f[k] = v
        f["grp/y"] = s["x"]
        f["name"] = "axis 1"
    write_manifest(tmp_path, '[[run]]\nfile = "a.h5"\nP = 1\nD = 1\n[run.columns]\nx = "grp"\n')
    assert "'grp' is a group, not a dataset" in read_error(tmp_path)
    write_manifest(tmp_path, '[[run]]\nfile = "a.h5"\nP = "name"\nD = 1\n')
    assert "dataset 'name' for P holds object, not real numbers" in read_error(tmp_path)


def test_hdf5_external_link_is_refused(tmp_path):
    s = signals()
    outside = tmp_path / "outside.h5"
    with h5py.File(outside, "w") as f:
        f["x"] = s["x"]
    (tmp_path / "set").mkdir()
    with h5py.File(tmp_path / "set" / "a.h5", "w") as f:
        f["t"], f["r"] = s["t"], s["r"]
        f["x"] = h5py.ExternalLink(str(outside), "x")
    write_manifest(tmp_path / "set", '[[run]]\nfile = "a.h5"\nP = 1\nD = 1\n')
    assert "'x' is an external link" in read_error(tmp_path / "set")


def test_paths_stay_inside_the_folder(tmp_path):
    savemat(tmp_path / "a.mat", signals())
    write_manifest(tmp_path / "set", '[[run]]\nfile = "../a.mat"\nP = 1\nD = 1\n')
    assert "escapes the set's folder ('..' is not allowed)" in read_error(tmp_path / "set")
    os.symlink(tmp_path / "a.mat", tmp_path / "set" / "link.mat")
    write_manifest(tmp_path / "set", '[[run]]\nfile = "link.mat"\nP = 1\nD = 1\n')
    assert "escapes the set's folder (it resolves to" in read_error(tmp_path / "set")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes need a POSIX system")
def test_named_pipe_is_refused(tmp_path):
    os.mkfifo(tmp_path / "a.mat")
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    assert "is a named pipe (FIFO), not a regular file" in read_error(tmp_path)


def test_unknown_suffix_in_a_tracking_set(tmp_path):
    write_manifest(tmp_path, '[[run]]\nfile = "a.txt"\nP = 1\nD = 1\n')
    assert "file 'a.txt' must end in .csv, .csv.gz, .mat, .h5, .hdf5, .parquet" \
        in read_error(tmp_path)


@pytest.mark.parametrize(("name", "module"), [("a.h5", "h5py"), ("a.parquet", "pyarrow")])
def test_missing_optional_package(tmp_path, monkeypatch, name, module):
    s = signals()
    if module == "h5py":
        with h5py.File(tmp_path / name, "w") as f:
            f["t"] = s["t"]
    else:
        save_parquet(tmp_path / name, s)
    write_manifest(tmp_path, f'[[run]]\nfile = "{name}"\nP = 1\nD = 1\n')
    # a None entry in sys.modules makes the import fail, as if the package were not installed
    for mod in [m for m in sys.modules if m == module or m.startswith(module + ".")]:
        monkeypatch.setitem(sys.modules, mod, None)
    monkeypatch.setitem(sys.modules, module, None)
    msg = read_error(tmp_path)
    assert f"run 1 ({name}): reading" in msg and f"needs the Python package {module}" in msg
    assert msg.endswith("pip install 'phoid[io]'")


def test_limits_apply_to_containers(tmp_path, monkeypatch):
    s = signals()
    savemat(tmp_path / "a.mat", s)
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    monkeypatch.setattr(phoid.io.limits, "MAX_SET_ROWS", N - 1)
    assert "phoid's limit for one set (MAX_SET_ROWS)" in read_error(tmp_path)
    monkeypatch.setattr(phoid.io.limits, "MAX_SET_ROWS", 10**9)
    monkeypatch.setattr(phoid.io.limits, "MAX_LINES", N - 1)
    assert "(49, MAX_LINES)" in read_error(tmp_path)
    monkeypatch.setattr(phoid.io.limits, "MAX_LINES", 10**9)
    size = (tmp_path / "a.mat").stat().st_size
    monkeypatch.setattr(phoid.io.limits, "MAX_DATA_BYTES", size - 1)
    assert "the data file is larger than" in read_error(tmp_path)


def test_values_read_are_bounded_like_a_decompressed_file(tmp_path, monkeypatch):
    # a compressed MATLAB file of smooth signals: the values (5 × 2000 × 8 bytes) outweigh the
    # file, and MAX_DATA_BYTES bounds what is read, not only the file's size
    t = np.arange(2000) * T
    data = {"t": t, "x": np.zeros_like(t), "r": np.zeros_like(t), "u": np.ones_like(t),
            "w": np.zeros_like(t)}
    scipy.io.savemat(tmp_path / "a.mat", {k: v.reshape(-1, 1) for k, v in data.items()},
                     do_compression=True)
    size = (tmp_path / "a.mat").stat().st_size
    assert size < 5 * 2000 * 8
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    monkeypatch.setattr(phoid.io.limits, "MAX_DATA_BYTES", size)
    assert "the signals read would take more than" in read_error(tmp_path)
    monkeypatch.setattr(phoid.io.limits, "MAX_DATA_BYTES", 5 * 2000 * 8)
    assert read_experiment(tmp_path).runs[0].n == 2000


# --------------------------------------------------------------------------------------------
# the other methods keep their meaning


@pytest.mark.parametrize(("top", "run", "key"), [
    ('estimator = "idim"\n', "", "estimator"),
    ("[fixed]\nk = 0\n", "", "fixed"),
    ("", "gain = 2.0\n", "gain"),
    ("", "command_gain = 2.0\n", "command_gain"),
    ("", '[run.columns]\nx = "q"\n', "columns"),
])
def test_tracking_keys_are_refused_in_a_pho_set(tmp_path, top, run, key):
    (tmp_path / "a.csv").write_text("t,x\n0,0\n1,1\n")
    head = 'format = "phoid/1"\nmethod = "pho"\n'
    write_manifest(tmp_path, top + f'[[run]]\nfile = "a.csv"\nP = 1\nD = 1\n{run}', head)
    assert (f"key '{key}' belongs to tracking sets (method = \"tracking\"); this set's method "
            "is 'pho'") in read_error(tmp_path)


def test_containers_are_read_in_tracking_sets_only(tmp_path):
    savemat(tmp_path / "a.mat", signals())
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n',
                   'format = "phoid/1"\nmethod = "pho"\n')
    assert ("must end in .csv or .csv.gz (MATLAB, HDF5 and Parquet files are read in tracking "
            "sets only)") in read_error(tmp_path)


def test_a_pho_csv_with_an_r_column_is_read_as_before(tmp_path):
    (tmp_path / "a.csv").write_text("t,x,r,u\n0,0,5,1\n1,1,5,1\n")
    write_manifest(tmp_path, '[[run]]\nfile = "a.csv"\nP = 1\nD = 1\n',
                   'format = "phoid/1"\nmethod = "pho"\n')
    run = read_experiment(tmp_path).runs[0]
    assert run.r is None and run.gain is None and run.u is not None
    assert read_experiment(tmp_path).estimator is None


# --------------------------------------------------------------------------------------------
# the real record: EMPS, through the repository's example manifest


def test_emps_record(tmp_path):
    if not EMPS_FILE.is_file():
        pytest.skip(EMPS_ABSENT)
    # a copy, not a link: the data file must lie inside the set's folder after links resolve
    shutil.copyfile(EMPS_FILE, tmp_path / "DATA_EMPS.mat")
    shutil.copyfile(ROOT / "examples" / "emps" / "experiment.toml",
                    tmp_path / "experiment.toml")
    exp = read_experiment(tmp_path)
    assert exp.method == "tracking" and dict(exp.fixed) == {"k": 0.0}
    assert exp.loop["velocity"] == "central-difference" and exp.loop["saturation"] == 10.0
    run = exp.runs[0]
    # the benchmark's description and ../shared/data/emps/README.md: 24 841 samples at 1 kHz,
    # kp = 160.18, kv = 243.45, gtau = 35.15 N/V (printed to those digits: rel 1e-4)
    assert run.n == 24_841
    # 1 kHz: 24.84 s over 24 840 steps; the stored t jitters by ±2e-8 s (steps of 0.99998 and
    # 1.00002 ms, a property of the file), hence the mean step and a 1e-4 band per step
    assert (run.t[-1] - run.t[0]) / (run.n - 1) == pytest.approx(1e-3, rel=1e-12)
    assert np.allclose(np.diff(run.t), 1e-3, rtol=1e-4, atol=0)
    assert run.P == pytest.approx(160.18, rel=1e-4)
    assert run.gain == pytest.approx(243.45, rel=1e-4)
    assert run.command_gain == pytest.approx(35.15, rel=1e-4)
    assert run.D == 1.0 and run.w is None
    # the signals are the file's own (read independently here with scipy)
    data = scipy.io.loadmat(EMPS_FILE)
    for key, name in (("t", "t"), ("x", "qm"), ("r", "qg"), ("u", "vir")):
        np.testing.assert_array_equal(getattr(run, key), data[name].ravel())
    # the command stays within the ±10 V saturation the manifest declares
    assert np.abs(run.u).max() <= 10.0 + 1e-9


def test_tracking_run_replace_keeps_the_checks():
    s = signals()
    run = run_from_arrays(s["t"], s["x"], r=s["r"], P=1.0, D=1.0)
    exp = phoid.io.ExperimentSet(path="a/experiment.toml", runs=(run,), method="tracking")
    assert exp.estimator == "auto"
    with pytest.raises(ExperimentError, match="missing column 'r'"):
        phoid.io.ExperimentSet(path="a/experiment.toml",
                               runs=(dataclasses.replace(run, r=None),), method="tracking")


# --------------------------------------------------------------------------------------------
# damaged MATLAB v5 files: an error, never a crash


def _read_in_child(folder: Path) -> subprocess.CompletedProcess:
    """read_experiment in a child process: a reader that crashed (a segmentation fault in a
    library) fails this test instead of ending the test session."""
    code = ("import sys; from phoid.io import read_experiment\n"
            "from phoid.errors import ExperimentError\n"
            f"try: read_experiment({str(folder)!r})\n"
            "except ExperimentError as e: print(e, file=sys.stderr); sys.exit(3)\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT / "src"), *filter(None, [os.environ.get("PYTHONPATH")])]))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, timeout=120)


def test_invalid_value_type_in_a_mat_file_is_an_error(tmp_path):
    s = signals()
    scipy.io.savemat(tmp_path / "a.mat", {"t": s["t"].reshape(-1, 1), "x": s["x"], "r": s["r"]})
    data = bytearray((tmp_path / "a.mat").read_bytes())
    # the layout of the first variable, 't' (MAT-file format, v5): the 128-byte header, the
    # miMATRIX tag (8), the array flags (16), the dimensions (8 + 2·4), the name as a small
    # element (8), then the tag of its values, whose first byte is the type: miDOUBLE = 9
    at = 128 + 8 + 16 + 16 + 8
    assert data[at] == 9 and data[at - 4:at - 3] == b"t"
    data[at] = 40  # no such type: scipy 1.17's loadmat indexes past its table and crashes
    (tmp_path / "a.mat").write_bytes(bytes(data))
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    child = _read_in_child(tmp_path)
    assert child.returncode == 3, (child.returncode, child.stderr[-500:])
    assert ("run 1 (a.mat): variable 't': its real values have the invalid MATLAB data type "
            "40") in child.stderr
    data[at] = 9  # the values' byte count must match the dimensions, too
    data[at + 4] += 8
    (tmp_path / "a.mat").write_bytes(bytes(data))
    assert "its real values take 408 bytes, but its dimensions 50×1 need 400" \
        in read_error(tmp_path)


def test_damaged_compressed_mat_is_an_error(tmp_path):
    scipy.io.savemat(tmp_path / "a.mat", signals(), do_compression=True)
    data = bytearray((tmp_path / "a.mat").read_bytes())
    data[128 + 8 + 2: 128 + 8 + 40] = bytes(38)  # zeros over the first compressed stream
    (tmp_path / "a.mat").write_bytes(bytes(data))
    write_manifest(tmp_path, '[[run]]\nfile = "a.mat"\nP = 1\nD = 1\n')
    child = _read_in_child(tmp_path)
    assert child.returncode == 3, (child.returncode, child.stderr[-500:])
    assert "run 1 (a.mat): the MATLAB file's compressed element at byte 128 is damaged" \
        in child.stderr
