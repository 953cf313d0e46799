"""`ClothMaps`: the per-texel maps of one seamless cloth tile, validated, saved and loaded.

Tile frame: x = +u (increasing column), y = +v (increasing row), z = macro-surface normal.
Texel (r, c) covers u in [c/W, (c+1)/W) and v in [r/H, (r+1)/H). Lengths (``height``) are in
units of the tile width, i.e. u spans [0, 1) across the tile.

On disk a maps directory holds ``maps.npz`` (every array, uncompressed, exact) and
``maps.json`` (format version, shape, generator metadata).
"""
from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write
from ..errors import MapsError

FORMAT_VERSION = 1
NPZ_NAME = "maps.npz"
JSON_NAME = "maps.json"
ARRAY_FIELDS = ("tangent", "normal", "height", "gap", "yarn_id", "albedo")
UNIT_TOLERANCE = 1e-3


def _float_array(name: str, value: Any, shape_text: str) -> np.ndarray:
    """Return ``value`` as a finite float32 array (a private copy) or raise MapsError."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiu":
        raise MapsError(f"ClothMaps.{name}: expected shape {shape_text} float, "
                        f"got dtype {arr.dtype}")
    # Private, read-only copy: maps are shared through caches, so nobody may edit them.
    arr = np.array(arr, dtype=np.float32, copy=True)
    if not np.all(np.isfinite(arr)):
        raise MapsError(f"ClothMaps.{name}: expected finite values, found NaN or inf")
    return arr


def _check_shape(name: str, arr: np.ndarray, expected: tuple, shape_text: str, kind: str) -> None:
    if arr.shape != expected:
        raise MapsError(f"ClothMaps.{name}: expected shape {shape_text} {kind}, got {arr.shape}")


def _check_unit(name: str, arr: np.ndarray) -> None:
    length = np.linalg.norm(arr.astype(np.float64), axis=-1)
    worst = float(np.max(np.abs(length - 1.0))) if length.size else 0.0
    if worst > UNIT_TOLERANCE:
        raise MapsError(f"ClothMaps.{name}: expected unit vectors (|length - 1| <= "
                        f"{UNIT_TOLERANCE}), worst |length - 1| is {worst:.3g}")


def _normalise_meta(meta: Any) -> dict:
    """Return ``meta`` in the form it has after a JSON round trip, or raise MapsError.

    Normalising at construction (tuples become lists, ...) makes save/load exact for meta too.
    """
    if not isinstance(meta, dict):
        raise MapsError(f"ClothMaps.meta: expected a dict, got {type(meta).__name__}")
    try:
        return json.loads(json.dumps(meta, allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise MapsError(f"ClothMaps.meta: expected JSON-serialisable values ({exc})") from None


@dataclass(frozen=True, eq=False)
class ClothMaps:
    """Maps of one seamless, periodic cloth tile (see module docstring for the frame).

    Attributes:
        tangent: (H, W, 3) float32, unit fibre tangent; may point out of the plane.
        normal: (H, W, 3) float32, unit yarn-surface normal with z > 0.
        height: (H, W) float32, surface height in tile-width units.
        gap: (H, W) float32 in {0, 1}; 1 = yarn, 0 = hole between yarns.
        yarn_id: (H, W) int32; -1 exactly where gap == 0, else the visible yarn's id (>= 0).
        albedo: (H, W, 3) float32 in [0, 1], linear per-yarn colour.
        meta: JSON-serialisable dict (generator name and its parameters).

    Arrays are stored as private read-only copies, so instances can be shared (cached) safely.
    """

    tangent: np.ndarray
    normal: np.ndarray
    height: np.ndarray
    gap: np.ndarray
    yarn_id: np.ndarray
    albedo: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        tangent = _float_array("tangent", self.tangent, "(H, W, 3)")
        if tangent.ndim != 3 or tangent.shape[2] != 3 or 0 in tangent.shape:
            raise MapsError(f"ClothMaps.tangent: expected shape (H, W, 3) float with H, W >= 1, "
                            f"got {tangent.shape}")
        hw = tangent.shape[:2]
        _check_unit("tangent", tangent)

        normal = _float_array("normal", self.normal, "(H, W, 3)")
        _check_shape("normal", normal, hw + (3,), f"{hw + (3,)}", "float")
        _check_unit("normal", normal)
        if not np.all(normal[..., 2] > 0):
            raise MapsError("ClothMaps.normal: expected z > 0 everywhere, "
                            f"min z is {float(normal[..., 2].min()):.3g}")

        height = _float_array("height", self.height, "(H, W)")
        _check_shape("height", height, hw, f"{hw}", "float")

        gap = np.asarray(self.gap)
        if gap.dtype.kind not in "biuf":
            raise MapsError(f"ClothMaps.gap: expected shape {hw} values in {{0, 1}}, "
                            f"got dtype {gap.dtype}")
        _check_shape("gap", gap, hw, f"{hw}", "values in {0, 1}")
        if not np.all((gap == 0) | (gap == 1)):
            raise MapsError("ClothMaps.gap: expected values in {0, 1} only")
        gap = np.array(gap, dtype=np.float32, copy=True)

        yarn_id = np.asarray(self.yarn_id)
        if yarn_id.dtype.kind not in "iu":
            raise MapsError(f"ClothMaps.yarn_id: expected shape {hw} integer, "
                            f"got dtype {yarn_id.dtype}")
        _check_shape("yarn_id", yarn_id, hw, f"{hw}", "integer")
        if yarn_id.size and (yarn_id.min() < -1 or yarn_id.max() > np.iinfo(np.int32).max):
            raise MapsError("ClothMaps.yarn_id: expected -1 (gap) or an id in "
                            f"[0, 2**31 - 1], got range [{yarn_id.min()}, {yarn_id.max()}]")
        yarn_id = np.array(yarn_id, dtype=np.int32, copy=True)
        if not np.array_equal(yarn_id == -1, gap == 0):
            raise MapsError("ClothMaps.yarn_id: expected -1 exactly where gap == 0 "
                            "(and an id >= 0 where gap == 1)")

        albedo = _float_array("albedo", self.albedo, "(H, W, 3)")
        _check_shape("albedo", albedo, hw + (3,), f"{hw + (3,)}", "float")
        if albedo.size and (albedo.min() < 0 or albedo.max() > 1):
            raise MapsError("ClothMaps.albedo: expected values in [0, 1], got range "
                            f"[{float(albedo.min()):.3g}, {float(albedo.max()):.3g}]")

        meta = _normalise_meta(self.meta)
        for name, arr in zip(ARRAY_FIELDS, (tangent, normal, height, gap, yarn_id, albedo)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "meta", meta)

    @property
    def resolution(self) -> tuple[int, int]:
        """(H, W): rows and columns of the tile."""
        return tuple(int(n) for n in self.tangent.shape[:2])

    # ------------------------------------------------------------------ saving
    def save(self, directory: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write ``maps.npz`` and ``maps.json`` into ``directory`` (created if needed).

        Refuses (MapsError) when either file already exists, unless ``overwrite`` is true.
        Each file is written to a temporary file in the same directory and moved into place
        with ``os.replace``, so a crash never leaves a half-written map. Returns the directory.
        """
        directory = Path(directory)
        if directory.exists() and not directory.is_dir():
            raise MapsError(f"cannot save cloth maps to {directory}: it exists and is not a "
                            "directory")
        targets = [directory / NPZ_NAME, directory / JSON_NAME]
        if not overwrite:
            existing = [str(p) for p in targets if p.exists()]
            if existing:
                raise MapsError(f"refusing to overwrite existing {', '.join(existing)}; "
                                "pass overwrite=True to replace")
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise MapsError(f"cannot create maps directory {directory}: {exc}") from None

        arrays = {name: getattr(self, name) for name in ARRAY_FIELDS}
        header = {"format_version": FORMAT_VERSION, "shape": list(self.resolution),
                  "arrays": list(ARRAY_FIELDS), "meta": self.meta}
        try:
            atomic_write(targets[0], lambda f: np.savez(f, **arrays))
            atomic_write(targets[1],
                          lambda f: f.write((json.dumps(header, indent=2) + "\n").encode()))
        except OSError as exc:
            raise MapsError(f"cannot write cloth maps to {directory}: {exc}") from None
        return directory

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(cls, directory: str | os.PathLike) -> "ClothMaps":
        """Load maps written by :meth:`save`; raise MapsError naming whatever is wrong."""
        directory = Path(directory)
        if not directory.is_dir():
            raise MapsError(f"maps directory {directory} does not exist or is not a directory")
        npz_path, json_path = directory / NPZ_NAME, directory / JSON_NAME
        for path in (npz_path, json_path):
            if not path.is_file():
                raise MapsError(f"maps directory {directory} has no {path.name} "
                                "(expected a directory written by ClothMaps.save)")

        try:
            header = json.loads(json_path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise MapsError(f"cannot read {json_path}: {exc}") from None
        if not isinstance(header, dict) or not isinstance(header.get("meta", {}), dict):
            raise MapsError(f"{json_path}: expected a JSON object with a 'meta' object")
        version = header.get("format_version")
        if version != FORMAT_VERSION:
            raise MapsError(f"{json_path}: unsupported format_version {version!r}, "
                            f"expected {FORMAT_VERSION}")

        arrays = {}
        try:
            with np.load(npz_path, allow_pickle=False) as npz:
                for name in ARRAY_FIELDS:
                    if name not in npz.files:
                        raise MapsError(f"{npz_path} has no array '{name}' "
                                        f"(expected {', '.join(ARRAY_FIELDS)})")
                    arrays[name] = npz[name]
        except MapsError:
            raise
        except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as exc:
            raise MapsError(f"cannot read {npz_path}: corrupt or truncated file ({exc})") from None

        shape = header.get("shape")
        maps = cls(meta=header.get("meta", {}), **arrays)
        if shape is not None and list(maps.resolution) != shape:
            raise MapsError(f"{json_path}: shape {shape} does not match the arrays in "
                            f"{npz_path.name}, which are {list(maps.resolution)}")
        return maps


__all__ = ["ClothMaps", "FORMAT_VERSION", "NPZ_NAME", "JSON_NAME", "ARRAY_FIELDS"]
