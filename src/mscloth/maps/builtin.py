"""Built-in cloth patterns by name, and `resolve_pattern` (name or maps directory -> ClothMaps).

Results are cached in memory: builtins per (name, resolution), directories per (path, file
modification times), so editing a maps directory on disk is picked up. Cached `ClothMaps`
have read-only arrays, so sharing them is safe.
"""
from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Callable

from ..errors import ParameterError, PatternError
from ..patterns import weaves
from .cloth_maps import JSON_NAME, NPZ_NAME, ClothMaps
from .woven import woven_maps

DEFAULT_RESOLUTION = 128
_CACHE_SIZE = 8  # a 1024^2 tile is ~50 MB; keep the cache bounded


def _plain(resolution: int | tuple[int, int] | None = None) -> ClothMaps:
    """Plain weave, yarn_width 0.8, default 128x128."""
    return woven_maps(weaves.plain(), DEFAULT_RESOLUTION if resolution is None else resolution,
                      yarn_width=0.8)


BUILTIN_PATTERNS: dict[str, Callable[..., ClothMaps]] = {
    "plain": _plain,
}


def _resolution_key(resolution) -> int | tuple[int, int] | None:
    """Hashable form of a resolution (lists become tuples); validation is left to woven_maps."""
    if isinstance(resolution, list):
        return tuple(resolution)
    return resolution


@functools.lru_cache(maxsize=_CACHE_SIZE)
def _builtin(name: str, resolution) -> ClothMaps:
    return BUILTIN_PATTERNS[name](resolution)


@functools.lru_cache(maxsize=_CACHE_SIZE)
def _load_dir(path: str, stamp: tuple[int, int]) -> ClothMaps:
    # ``stamp`` (file mtimes) is only part of the cache key.
    return ClothMaps.load(path)


def resolve_pattern(spec: str | os.PathLike, resolution: int | tuple[int, int] | None = None
                    ) -> ClothMaps:
    """Maps for a builtin pattern name, or for a directory written by `ClothMaps.save`.

    A builtin name wins over a same-named directory (write ``./plain`` for the directory).
    ``resolution`` (int or (H, W)) applies to builtins; for a directory it must be None or
    match the stored maps, since silently returning another size would surprise the caller.
    """
    if not isinstance(spec, (str, os.PathLike)):
        raise PatternError(f"pattern must be a builtin name or a maps directory path, "
                           f"got {spec!r}")
    text = os.fspath(spec)
    if isinstance(spec, str) and text in BUILTIN_PATTERNS:
        try:
            return _builtin(text, _resolution_key(resolution))
        except TypeError:  # unhashable resolution: let the generator report it
            return BUILTIN_PATTERNS[text](resolution)

    path = Path(text)
    if text and path.is_dir():
        resolved = path.resolve()
        stamp = tuple(_mtime_ns(resolved / name) for name in (NPZ_NAME, JSON_NAME))
        maps = _load_dir(str(resolved), stamp)
        if resolution is not None:
            wanted = _as_pair(resolution)
            if wanted != maps.resolution:
                raise PatternError(f"maps directory {text!r} has resolution {maps.resolution}, "
                                   f"but resolution {resolution!r} was requested; omit "
                                   "resolution or regenerate the maps")
        return maps

    names = ", ".join(sorted(BUILTIN_PATTERNS))
    raise PatternError(f"unknown pattern {text!r}: expected one of {names}, or a maps "
                       "directory")


def _mtime_ns(path: Path) -> int:
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return -1  # missing file: ClothMaps.load reports it


def _as_pair(resolution) -> tuple[int, int]:
    if isinstance(resolution, int) and not isinstance(resolution, bool):
        return (resolution, resolution)
    if isinstance(resolution, (tuple, list)) and len(resolution) == 2:
        return (resolution[0], resolution[1])
    raise ParameterError(f"resolution must be an int or an (H, W) pair of ints, "
                         f"got {resolution!r}")


def clear_cache() -> None:
    """Forget every cached pattern (e.g. to free memory)."""
    _builtin.cache_clear()
    _load_dir.cache_clear()


__all__ = ["BUILTIN_PATTERNS", "DEFAULT_RESOLUTION", "resolve_pattern", "clear_cache"]
