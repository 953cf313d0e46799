"""The lobe calibrations of ``cloth`` BSDFs on disk (``calibration/<key>.npz`` in mscloth's
cache), so that loading a scene again does not measure them again.

A calibration is a deterministic function of the BSDF (fixed seeds), so a stored one is
exactly what measuring would give. The key covers everything the measurement reads: the
maps, the tables' build inputs, every shading parameter, the uv scales it was measured at,
the footprint estimator's tuning constants, the Mitsuba variant and the source code of the
BSDF and scattering packages (any change to them measures anew). Spatially varying
textures make the BSDF's key unknowable cheaply: such BSDFs are measured on every load.
Calibrations only steer which lobe a sample takes, never the estimate's expectation.
"""
from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..cache import default_cache_dir, mark_used, source_fingerprint

FORMAT = "mscloth-calibration/1"
SUBDIR = "calibration"


def calibration_key(maps_key: str, inputs: dict) -> str:
    """The cache key of a calibration: ``maps_key`` (a hash of the maps) and ``inputs``
    (JSON-able: parameters, build inputs, uv scales, tuning constants, variant)."""
    hs = hashlib.sha256()
    hs.update(f"{FORMAT}\n{source_fingerprint('bsdf', 'scattering', 'jit_arrays.py')}\n{maps_key}\n".encode())
    hs.update(json.dumps(inputs, sort_keys=True).encode())
    return hs.hexdigest()


def path_of(key: str, cache_dir=None) -> Path:
    return (default_cache_dir() if cache_dir is None else Path(cache_dir)) / SUBDIR / f"{key}.npz"


def load(key: str, cache_dir=None) -> dict | None:
    """The stored arrays of calibration ``key`` (``point``, and ``footprint_ratios``,
    ``footprint_factors`` for multi-scale BSDFs), or None when there is none or it is
    unreadable (then it is measured and written anew)."""
    path = path_of(key, cache_dir)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: np.array(data[name]) for name in data.files}
        if "point" not in arrays or not all(np.all(np.isfinite(a)) for a in arrays.values()):
            raise ValueError("missing or non-finite arrays")
    except Exception as exc:  # noqa: BLE001 (any damage: measure again)
        warnings.warn(f"mscloth: ignoring cached calibration {path}: {exc}", RuntimeWarning, stacklevel=3)
        return None
    mark_used(path)
    return arrays


def save(key: str, arrays: dict, cache_dir=None) -> None:
    """Store calibration ``key``; a cache that cannot be written only costs time."""
    path = path_of(key, cache_dir)

    try:
        atomic_write(path, lambda f: np.savez(f, **arrays))
    except OSError as exc:
        warnings.warn(f"mscloth: cannot write calibration cache {path}: {exc}", RuntimeWarning, stacklevel=3)
