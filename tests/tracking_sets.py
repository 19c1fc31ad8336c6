"""The small tracking set several test files identify (one helper, not a copy per file).

The axis of tests/test_tracking_cli.py: m = 2 kg, c = 15 N s/m, fc = 1.5 N, an offset force of
-0.3 N and k = 0 (fixed), under a 1 kHz PD loop (P = 4000 N/m, D = 60 N s/m, central-difference
velocity, saturation 200 N, 0.4 ms delay) following two sines, the command u recorded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import phoid.io
from phoid.dynamics.controller import SampledController
from phoid.dynamics.plant import Plant
from phoid.simulation.tracking import simulate_tracking

#: the set's [loop] table
LOOP = {"sample_time": 1e-3, "velocity": "central-difference", "saturation": 200.0,
        "delay": 0.4e-3}


def write_tracking_set(folder: Path, n: int = 3000, noise: float = 0.0, seed: int = 0) -> Path:
    """Write the set of one run of ``n`` samples into ``folder``; ``noise``: the sd (m) of the
    white sensor noise added to x (drawn with ``numpy.random.default_rng(seed)``). Returns
    ``folder``."""
    ctrl = SampledController(sample_time=1e-3, P=4000.0, D=60.0, velocity="central-difference",
                             saturation=200.0, delay=0.4e-3)
    t = 1e-3 * np.arange(n)
    r = 0.02 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * np.sin(2 * np.pi * 1.9 * t + 0.3)
    sim = simulate_tracking(Plant(2.0, 15.0, 0.0, 1.5), ctrl, r, offset=-0.3, x_init=[0.0])
    x = sim.x + noise * np.random.default_rng(seed).standard_normal(n) if noise else sim.x
    run = phoid.io.run_from_arrays(t, x, r=r, u=sim.command, P=4000.0, D=60.0, index=1)
    phoid.io.write_experiment(folder, [run], method="tracking", fixed={"k": 0.0}, loop=LOOP)
    return folder
