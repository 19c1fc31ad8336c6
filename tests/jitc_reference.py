"""Independent reference for eq. (23): the delayed PD loop integrated by jitcdde.

Used by tests/test_simulate.py and bench/bench_simulate.py (test/bench-only dependency).

m x'' + c x' + k x = −[D x'(t − Δt) + P x(t − Δt)], released at t = 0 from x = x₀, ẋ = 0 with
the constant past x(t ≤ 0) = x₀.

How the release is handled (jitcdde's "initial discontinuities"): the constant past has a zero
derivative, while the DDE's acceleration right after the release is −(k + P)x₀/m. jitcdde's
Bogacki–Shampine stepper takes the first stage of a step from the derivative stored with the last
anchor, so the past is closed with :meth:`jitcdde.jitcdde.adjust_diff`: a zero-amplitude jump of
width 1e−6·Δt that gives the anchor at t = 0 the DDE's derivative (the past deviates from the
constant x₀ by ≈ a₀·width² ≈ 1e−13·x₀ and only inside that width). After that, every step is
clipped so that the integration lands exactly on each multiple of Δt (where the release kink
re-appears in the delayed term) and on each requested output time, so no step straddles a kink
and no output is extrapolated.

The compiled module (m, c, k, P, D are control parameters, Δt is compiled in) is cached per
delay in the system temporary directory, so only the first use per machine pays the
≈0.5 s compile.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import sys
import tempfile
import time
import warnings

import numpy as np

__all__ = ["compile_module", "jitcdde_reference"]

_RTOL = 1e-10


def _symbols():
    import symengine

    return symengine.symbols("m c k P D")


def _module_path(delay: float) -> str:
    import jitcdde

    key = f"{jitcdde.__file__}|{getattr(jitcdde, '__version__', '')}|{sys.version}|{delay!r}"
    tag = hashlib.sha1(key.encode()).hexdigest()[:12]
    return os.path.join(tempfile.gettempdir(), "phoid-jitcdde", f"phoid_ref_{tag}.so")


def compile_module(delay: float) -> tuple[str, float]:
    """Path of the compiled jitcdde module for this delay, and the seconds spent compiling.

    Compiles (and caches) on first use; 0.0 seconds when the cached module was reused.
    """
    path = _module_path(delay)
    if os.path.isfile(path):
        return path, 0.0
    from jitcdde import jitcdde, t, y
    from jitcxde_common.modules import get_module_path

    m, c, k, P, D = _symbols()
    f = [y(1), (-c * y(1) - k * y(0) - D * y(1, t - delay) - P * y(0, t - delay)) / m]
    t0 = time.perf_counter()
    name = os.path.splitext(os.path.basename(path))[0]  # must match the file name
    with warnings.catch_warnings():
        # compiler chatter from setuptools/jitcxde_common (also filtered in pyproject.toml for
        # pytest; repeated here for the benchmark, which runs outside pytest)
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", UserWarning)
        dde = jitcdde(f, control_pars=[m, c, k, P, D], verbose=False)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        try:
            # jitcxde builds the C module with setuptools in the working directory, which would
            # read the project's own pyproject.toml: build in the cache folder instead
            with contextlib.chdir(os.path.dirname(path)):
                dde.compile_C(simplify=False, modulename=name)
            src = get_module_path(dde._modulename, dde._tmpfile())
            tmp = path + f".{os.getpid()}.tmp"
            shutil.copy(src, tmp)
            os.replace(tmp, path)  # atomic: parallel test workers never see half a file
        finally:
            if getattr(dde, "_tmpdir", None) is not None:
                dde._tmpdir.cleanup()
                dde._tmpdir = None
    return path, time.perf_counter() - t0


_LOADED: dict[str, object] = {}


def _integrator(delay: float):
    path, _ = compile_module(delay)
    if path not in _LOADED:
        from jitcdde import jitcdde

        m, c, k, P, D = _symbols()
        _LOADED[path] = jitcdde(
            n=2,
            module_location=path,
            control_pars=[m, c, k, P, D],
            delays=[delay],
            max_delay=delay,
            verbose=False,
        )
    return _LOADED[path]


def jitcdde_reference(
    m: float,
    c: float,
    k: float,
    P: float,
    D: float,
    delay: float,
    x0: float,
    t: np.ndarray,
    *,
    rtol: float = _RTOL,
    return_velocity: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Position x(t) (m) of eq. (23) released at t = 0 from x₀ (ẋ = 0, constant past x₀).

    Parameters
    ----------
    m, c, k : float
        Plant (kg, N·s/m, N/m).
    P, D : float
        Gains (N/m, N·s/m).
    delay : float
        Loop delay Δt, s (> 0).
    x0 : float
        Release position, m.
    t : array_like
        Output times since release, s, non-decreasing and ≥ 0.
    rtol : float, default 1e-10
        Relative tolerance; the absolute tolerance is rtol·|x₀| for both x and ẋ.
    return_velocity : bool, default False
        Also return ẋ(t).
    """
    t = np.asarray(t, dtype=float)
    dde = _integrator(delay)
    dde.purge_past()
    dde.constant_past([x0, 0.0], time=0.0)
    dde.set_parameters(m, c, k, P, D)
    atol = rtol * abs(x0)
    dde.set_integration_parameters(
        atol=atol, rtol=rtol, first_step=min(1e-5, delay / 4), max_step=delay / 4, min_step=1e-14
    )
    dde.adjust_diff(shift_ratio=1e-6)
    kinks = np.arange(1, int(np.floor(t[-1] / delay)) + 1) * delay if t.size else np.zeros(0)
    targets = np.union1d(t[t > 0], kinks)
    x = np.empty(t.size)
    xd = np.empty(t.size)
    DDE = dde.DDE
    out_at = {float(tt): i for i, tt in enumerate(t)}
    for i in np.flatnonzero(t == 0):
        x[i], xd[i] = x0, 0.0
    for tg in targets:
        while DDE.get_t() < tg - 1e-13:
            if dde.try_single_step(min(dde.dt, tg - DDE.get_t())):
                DDE.accept_step()
        i = out_at.get(float(tg))
        if i is not None:
            st = DDE.get_recent_state(tg)
            x[i], xd[i] = st[0], st[1]
        DDE.forget(delay)
    # repeated output times
    if np.unique(t).size != t.size:
        for i, tt in enumerate(t):
            j = out_at[float(tt)]
            x[i], xd[i] = x[j], xd[j]
    return (x, xd) if return_velocity else x
