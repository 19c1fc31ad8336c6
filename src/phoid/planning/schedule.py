"""Schedule files: where a designed ``experiment.toml`` goes, and reading one back.

A schedule is a ``phoid/1`` manifest skeleton (gains, the loop — ``[loop] delay``, or a sampled
loop's ``sample_time``, ``delay_samples``, ``velocity``, ``noise`` — and the ``[design]`` table,
no data) as :meth:`phoid.planning.result.Design.write` writes it; ``phoid simulate --schedule``,
``phoid run`` and the check of a skeleton read it with :func:`read_schedule`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from phoid._output import OutputFolder
from phoid.errors import ExperimentError, PhoidError
from phoid.io.manifest import read_manifest  # regular files only, size and nesting limited
from phoid.planning.settings import DesignError

__all__ = ["read_schedule", "schedule_target"]


def schedule_target(path: str | Path, *, overwrite: bool) -> tuple[OutputFolder, str]:
    """The folder and file name :meth:`Design.write` writes to, checked (nothing written).

    The CLI calls it before designing, so that a file in the way is refused before the work.
    """
    path = Path(path)
    if path.is_dir() or not path.suffix:
        folder, name = path, "experiment.toml"
    else:
        folder, name = path.parent, path.name
    out = OutputFolder(folder, overwrite=overwrite, error=DesignError)
    out.check([name])
    return out, name


def read_schedule(path: str | Path) -> dict[str, Any]:
    """Gains, delay and recording settings of a designed ``experiment.toml`` (no data needed).

    Parameters
    ----------
    path : str or Path
        The skeleton manifest or its folder.

    Returns
    -------
    dict
        ``P``, ``D`` (ndarrays), ``delay`` (s or None), ``files`` (names of the runs) and, from
        the ``[design]`` table when present, ``fs``, ``duration``, ``noise``, ``amplitude``.
        A sampled loop's plan (``[loop] sample_time``) adds ``sample_time`` (s),
        ``delay_samples``, ``velocity``, ``cutoff`` (rad/s or None) and ``noise_placement``
        (``[loop] noise``: ``"in-loop"``, ``"outside"`` or None), with ``delay`` =
        ``delay_samples`` × ``sample_time`` (the command delay, s, as a host running the plan
        at 1/``fs`` = T reads it).

    Raises
    ------
    DesignError
        One line naming the file, run and key for anything missing or malformed.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "experiment.toml"
    try:
        doc = read_manifest(str(path), path)
    except ExperimentError as exc:
        raise DesignError(str(exc)) from None
    runs = doc.get("run")
    if not isinstance(runs, list) or not runs:
        raise DesignError(f"{path}: no [[run]] tables with gains P and D")
    P, D, files = [], [], []
    for i, r in enumerate(runs, start=1):
        if not isinstance(r, Mapping):
            raise DesignError(f"{path}: run {i}: not a table")
        for key, out in (("P", P), ("D", D)):
            val = r.get(key)
            if isinstance(val, bool) or not isinstance(val, (int, float)) \
                    or not math.isfinite(val):
                raise DesignError(f"{path}: run {i}: key '{key}' must be a finite number; "
                                  f"got {val!r}")
            out.append(float(val))
        files.append(str(r.get("file", f"run{i:02d}.csv")))
    loop = doc.get("loop", {})
    delay = loop.get("delay") if isinstance(loop, Mapping) else None
    if delay is not None and (isinstance(delay, bool) or not isinstance(delay, (int, float))
                              or not math.isfinite(delay) or delay < 0):
        raise DesignError(f"{path}: [loop] delay must be a finite number ≥ 0 s; got {delay!r}")
    out: dict[str, Any] = {"P": np.array(P), "D": np.array(D),
                           "delay": None if delay is None else float(delay), "files": files}
    if isinstance(loop, Mapping) and "sample_time" in loop:
        out.update(_sampled_loop(path, loop))
    des = doc.get("design", {})
    if isinstance(des, Mapping):
        for key in ("fs", "duration", "noise", "amplitude"):
            val = des.get(key)
            if isinstance(val, (int, float)) and not isinstance(val, bool) \
                    and math.isfinite(val) and val > 0:
                out[key] = float(val)
    return out


def _sampled_loop(path: Path, loop: Mapping[str, Any]) -> dict[str, Any]:
    """A plan's digital ``[loop]`` checked as a set's is (:mod:`phoid.io.loop`), one line."""
    from types import SimpleNamespace

    from phoid.io.loop import read_digital_loop, read_noise_placement

    if "delay" in loop:
        raise DesignError(f"{path}: [loop] delay and [loop] sample_time: a sampled loop's delay "
                          "is delay_samples (whole periods of sample_time); give one or the "
                          "other")
    plan = SimpleNamespace(loop=dict(loop), path=path, runs=())
    try:
        digital = read_digital_loop(plan)
        noise = read_noise_placement(plan)
    except PhoidError as exc:
        raise DesignError(str(exc)) from None
    return {"sample_time": digital.sample_time, "delay_samples": digital.delay_samples,
            "velocity": digital.velocity, "cutoff": digital.cutoff, "noise_placement": noise,
            "delay": digital.delay}
