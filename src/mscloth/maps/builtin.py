"""`resolve_pattern`: what the ``cloth`` BSDF's ``pattern`` names -> ClothMaps.

A pattern is a name (``plain``, ``twill-2-1``, ``satin-8-3``, ``jersey``, ``rib-2-2``...),
a ``.wif`` file, or a directory written by ``ClothMaps.save``. Results are cached in
memory: names per (name, resolution), files and directories per (path, modification
times), so editing them on disk is picked up. Cached ClothMaps have read-only arrays, so
sharing them is safe.
"""
from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Callable

from ..errors import ParameterError, PatternError
from ..patterns.named import NAMED, is_wif_path, named_pattern, pattern_names
from .cloth_maps import JSON_NAME, NPZ_NAME, ClothMaps
from .generate import generate_maps
from .generator_support import fit_width

#: Default sampling of generated patterns along u: texels per woven thread and per knit
#: wale (two legs, so 32 per leg as well), within [MIN, MAX] texels per tile side, but never
#: under MIN_TEXELS_PER_THREAD per thread or wale (up to LARGEST_DEFAULT_RESOLUTION).
#: Footprints cover many texels but near the camera, where 32 per thread still show the
#: yarn's cross-section and twist. Small repeats cost little: the plain weave keeps the 128^2
#: tile that tests and earlier images use, a one-wale jersey its 64 texels. The cap bounds the
#: tables' build, memory and disk (issue 22): a 24-thread WIF draft at 64 per thread was
#: 1024^2 texels, 40 s of tables and 442 MiB on disk; at 320^2 (13 texels per thread) its
#: full directional SAT fits max_table_mib (no rank compression) in ~120 MiB. Scenes that
#: come close give ``resolution``. Whatever these give is then moved into the widths the
#: tile takes (its generator's fewest texels per thread, the largest tile side, its aspect):
#: a 600-end draft gets 1200 texels, a 4-end x 1000-pick one a width its height allows.
DEFAULT_TEXELS_PER_THREAD, DEFAULT_TEXELS_PER_WALE = 32, 64
MIN_DEFAULT_RESOLUTION, MIN_DEFAULT_KNIT_RESOLUTION, MAX_DEFAULT_RESOLUTION = 128, 64, 320
MIN_TEXELS_PER_THREAD, LARGEST_DEFAULT_RESOLUTION = 8, 1024
_CACHE_SIZE = 8  # a 1024^2 tile is ~50 MB; keep the cache bounded

#: Pattern names accepted without arguments (each also takes arguments, see NAMED).
BUILTIN_PATTERNS = tuple(NAMED)


def default_resolution(pattern) -> int:
    """Texels along u for a generated pattern when the caller gives none: always one its
    tile takes (ResolutionError, saying why, if none does)."""
    wales = getattr(pattern, "n_wales", None)
    if wales:
        columns, per_column, least = wales, DEFAULT_TEXELS_PER_WALE, MIN_DEFAULT_KNIT_RESOLUTION
    else:
        columns = getattr(pattern, "n_warp", None) or 2
        per_column, least = DEFAULT_TEXELS_PER_THREAD, MIN_DEFAULT_RESOLUTION
    texels = min(MAX_DEFAULT_RESOLUTION, max(least, per_column * columns))
    preferred = int(min(LARGEST_DEFAULT_RESOLUTION, max(texels, MIN_TEXELS_PER_THREAD * columns)))
    shape = _tile_shape(pattern)
    return preferred if shape is None else fit_width(preferred, *shape)


def _tile_shape(pattern):
    """The tile's (aspect, counts, fewest texels, kinds) for its generator at its default
    parameters; None for what is neither a draft nor a knit (only its counts are known)."""
    from ..patterns.draft import Draft
    from ..patterns.knit import KnitPattern

    if isinstance(pattern, Draft):
        from .woven import tile_shape
    elif isinstance(pattern, KnitPattern):
        from .knit import tile_shape
    else:
        return None
    return tile_shape(pattern)


def _resolution_key(resolution):
    """Hashable form of a resolution (lists become tuples)."""
    return tuple(resolution) if isinstance(resolution, list) else resolution


@functools.lru_cache(maxsize=_CACHE_SIZE)
def _generated(spec: str, resolution, stamp: int) -> ClothMaps:
    # ``stamp`` (a WIF file's mtime, 0 for names) is only part of the cache key.
    pattern = named_pattern(spec)
    return generate_maps(pattern, default_resolution(pattern) if resolution is None else resolution)


@functools.lru_cache(maxsize=_CACHE_SIZE)
def _load_dir(path: str, stamp: tuple[int, int]) -> ClothMaps:
    return ClothMaps.load(path)


def resolve_pattern(spec: str | os.PathLike, resolution: int | tuple[int, int] | None = None,
                    locate: Callable[[str], str] | None = None) -> ClothMaps:
    """Maps for a pattern name, a ``.wif`` file or a maps directory.

    A pattern name wins over a same-named directory (write ``./plain`` for the directory).
    ``resolution`` (int: texels along u, or (H, W)) applies to generated patterns; for a
    directory it must be None or match the stored maps. ``locate`` maps a file or directory
    path to where it is (the ``cloth`` plugin passes Mitsuba's file resolver, so that paths
    in a scene file are relative to its directory); without it, paths are relative to the
    working directory.
    """
    if not isinstance(spec, (str, os.PathLike)):
        raise PatternError(f"pattern must be a pattern name, a .wif file or a maps directory, "
                           f"got {spec!r}")
    text = os.fspath(spec)
    resolution = _resolution_key(resolution)
    is_name = text.split("-")[0].lower() in NAMED
    path = Path(locate(text) if locate is not None and text and not is_name else text)
    if is_wif_path(text):
        if not path.is_file():
            raise PatternError(f"WIF file {text!r} does not exist{_where(text, locate)}")
        resolved = path.resolve()
        return _generated(str(resolved), resolution, _mtime_ns(resolved))
    if is_name:
        return _generated(text, resolution, 0)
    if text and path.is_dir():
        return _from_directory(text, path, resolution)
    if _looks_like_path(text):
        what = "is not a directory" if path.exists() else f"does not exist{_where(text, locate)}"
        raise PatternError(f"maps directory {text!r} {what}")
    raise PatternError(f"unknown pattern {text!r}: expected one of {pattern_names()}, "
                       "a .wif file or a maps directory")


def _looks_like_path(text: str) -> bool:
    """Whether a pattern that is neither a name nor an existing directory was meant as a path
    (then it is a missing directory, not an unknown name)."""
    separators = {os.sep, os.altsep or os.sep}
    return text.startswith((".", "~")) or any(sep in text for sep in separators)


def _where(text: str, locate) -> str:
    """Where a missing relative path was looked for, for its error message."""
    if Path(text).is_absolute():
        return ""
    return (" (relative to the scene file's directory or the working directory)" if locate is not None
            else f" (relative to the working directory {os.getcwd()})")


def _from_directory(text: str, path: Path, resolution) -> ClothMaps:
    resolved = path.resolve()
    stamp = tuple(_mtime_ns(resolved / name) for name in (NPZ_NAME, JSON_NAME))
    maps = _load_dir(str(resolved), stamp)
    if resolution is not None and _as_pair(resolution) != maps.resolution:
        raise PatternError(f"maps directory {text!r} has resolution {maps.resolution}, "
                           f"but resolution {resolution!r} was requested; omit "
                           "resolution or regenerate the maps")
    return maps


def _mtime_ns(path: Path) -> int:
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return -1  # missing file: the loader reports it


def _as_pair(resolution) -> tuple[int, int]:
    if isinstance(resolution, int) and not isinstance(resolution, bool):
        return (resolution, resolution)
    if isinstance(resolution, (tuple, list)) and len(resolution) == 2:
        return (resolution[0], resolution[1])
    raise ParameterError(f"resolution must be an int or an (H, W) pair of ints, "
                         f"got {resolution!r}")


def clear_cache() -> None:
    """Forget every cached pattern (e.g. to free memory)."""
    _generated.cache_clear()
    _load_dir.cache_clear()


__all__ = ["BUILTIN_PATTERNS", "DEFAULT_TEXELS_PER_THREAD", "DEFAULT_TEXELS_PER_WALE", "clear_cache", "default_resolution",
           "resolve_pattern"]
