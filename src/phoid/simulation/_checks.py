"""Input checks and size limits of the simulator."""

from __future__ import annotations

from typing import Any

import numpy as np

from phoid import _validate as v

__all__ = ["MAX_SAMPLES", "MAX_STEPS", "batch_array", "broadcast_batch", "plant_params"]

#: most samples one simulation may hold, all runs together (runs × (hold + duration) × fs): each
#: costs about 64 bytes (positions, velocities, forces, noise), so the limit is about 3 GB
MAX_SAMPLES = 50_000_000
#: most internal steps one simulation may take, all runs together (runs × (hold + duration)/h,
#: h ≤ min(1/fs, Δt) the internal step): bounds the work of a very short delay or a stiff plant
MAX_STEPS = 200_000_000


def batch_array(name: str, value: Any, unit: str) -> np.ndarray:
    """``value`` as a finite scalar or 1-D array (ValueError naming ``name`` and ``unit``)."""
    a = v.finite_array(name, value)
    if a.ndim > 1:
        raise ValueError(f"`{name}` must be a scalar or 1-D array ({unit}); got shape {a.shape}")
    return a


def broadcast_batch(**arrays: np.ndarray) -> tuple[int, dict[str, np.ndarray]]:
    """The batch size B and every array broadcast to (B,) floats (equal lengths, B ≥ 1)."""
    sizes = {name: a.size for name, a in arrays.items() if a.ndim == 1}
    distinct = set(sizes.values())
    if len(distinct) > 1:
        desc = ", ".join(f"`{n}` has {s}" for n, s in sizes.items())
        raise ValueError(f"batch arrays must have equal length; got {desc}")
    B = distinct.pop() if distinct else 1
    if B == 0:
        raise ValueError("batch arrays must not be empty; got length 0")
    return B, {n: np.broadcast_to(a, (B,)).astype(float) for n, a in arrays.items()}


def plant_params(plant: Any) -> tuple[float, float, float, float]:
    """m (kg, > 0), c (N·s/m), k (N/m) and f_c (N, ≥ 0) of ``plant``, checked."""
    try:
        m, c, k = plant.m, plant.c, plant.k
        fc = getattr(plant, "fc", 0.0)
    except AttributeError:
        raise ValueError(
            f"`plant` must have attributes m, c, k (and fc), e.g. phoid.Plant; got {plant!r}"
        ) from None
    return (
        v.positive("m", m, "kg"),
        v.finite("c", c, "N·s/m"),
        v.finite("k", k, "N/m"),
        v.nonnegative("fc", fc, "N"),
    )
