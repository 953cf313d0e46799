"""mscloth's on-disk cache: where it is, what is in it, and removing entries.

``$MSCLOTH_CACHE``, else ``~/.cache/mscloth``, holds what mscloth can always make again:
multi-scale tables (``tables-<key>.npz`` and its ``.json`` sidecar), the brute-force
references of ``mscloth compare`` (``references/``), and the meshes and cloth maps of
built-in scenes (``scenes/``: ``<name>-<key>.ply`` files, ``<name>-<key>/`` maps directories),
the cloths' lobe calibrations (``calibration/<key>.npz``, a few KiB each) and the sky
shares ``clothpath``'s pilot measured (``sky_shares/<key>.json``, a few hundred bytes).
Their keys change with the maps, the parameters and (references, calibrations, shares) the code,
so entries nothing reads any more pile up: one 512² tile's full directional SAT is 1 GiB.

A load marks an entry as used (its files' modification time), so
``mscloth cache --clear --older-than DAYS`` removes what has not been used for that long.
Only files named the way mscloth names them are listed or removed (and the leftovers of
writes that were killed half-way); anything else in the directory is left alone.
"""
from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

__all__ = ["CacheEntry", "cache_entries", "default_cache_dir", "mark_used", "remove_entries", "source_fingerprint"]


def default_cache_dir() -> Path:
    """$MSCLOTH_CACHE, else ~/.cache/mscloth; a ClothError when it (or a folder above it) is
    a file, said once here rather than as "[Errno 20] Not a directory" wherever it is used."""
    from .errors import ClothError

    env = os.environ.get("MSCLOTH_CACHE")
    root = Path(env) if env else Path.home() / ".cache" / "mscloth"
    existing = root
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        named = f"MSCLOTH_CACHE={env}" if env else f"the cache folder {root}"
        what = "names a file" if existing == root else f"lies under {existing}, a file"
        raise ClothError(f"{named} {what}, not a folder: point MSCLOTH_CACHE at a folder")
    return root


@lru_cache(maxsize=8)
def source_fingerprint(*parts: str) -> str:
    """SHA-256 of mscloth's sources ``parts`` (paths in the package: a directory stands for
    its ``*.py`` files), by name and content: what a cached result was computed by."""
    root = Path(__file__).resolve().parent
    paths = []
    for part in parts:
        path = root / part
        paths += path.glob("*.py") if path.is_dir() else [path]
    hs = hashlib.sha256()
    for path in sorted(paths):
        hs.update(path.name.encode())
        hs.update(path.read_bytes())
    return hs.hexdigest()


# (kind, sub-directory, entry name pattern, file suffixes). A table's .npz and .json make
# one entry. Atomic writes (mscloth.atomic) go through ".<stem>.<8 random characters><suffix>"
# temporaries beside the target, left behind only by a killed process.
_KINDS = (
    ("tables", "", r"tables-[0-9a-f]{64}", (".npz", ".json")),
    ("references", "references", r"[a-z0-9_][a-z0-9_-]*-\d+x\d+-\d+spp-[0-9a-f]{16}", (".npz",)),
    ("scene meshes", "scenes", r"[a-z0-9_]+-[0-9a-f]{12}", (".ply",)),
    ("calibrations", "calibration", r"[0-9a-f]{64}", (".npz",)),
    ("sky shares", "sky_shares", r"[0-9a-f]{64}", (".json",)),
)
# (kind, sub-directory, entry name pattern) of entries that are directories (every file in
# one is part of the entry): the maps of built-in scenes, written as
# ".<name>.<8 random characters>" and renamed when complete (mscloth.scenes.builtin.scene_maps).
_DIRECTORY_KINDS = (
    ("scene maps", "scenes", r"[a-z0-9_]+-[0-9a-f]{12}"),
)


@dataclass(frozen=True)
class CacheEntry:
    """One cached item: its kind, name (the file stem), files, bytes, and when it was last
    used (the newest modification time of its files, seconds since the epoch)."""

    kind: str
    name: str
    paths: tuple[Path, ...]
    size: int
    last_used: float
    unfinished: bool = False  # a temporary of an interrupted write
    directory: Path | None = None  # the directory that holds ``paths``, for directory entries


def _match(pattern: str, suffixes: tuple[str, ...], filename: str):
    """(stem, unfinished?) if ``filename`` is an entry file of this kind, else None."""
    ext = "|".join(re.escape(s) for s in suffixes)
    done = re.fullmatch(rf"({pattern})({ext})", filename)
    if done:
        return done.group(1), False
    temporary = re.fullmatch(rf"\.({pattern})\.[a-z0-9_]{{8}}({ext})", filename)
    if temporary:
        return temporary.group(1), True
    return None


def cache_entries(cache_dir=None) -> list[CacheEntry]:
    """Every mscloth entry in ``cache_dir`` (default: :func:`default_cache_dir`), by kind
    then name; an empty list when the directory does not exist."""
    root = default_cache_dir() if cache_dir is None else Path(cache_dir)
    entries = []
    for kind, sub, pattern, suffixes in _KINDS:
        directory = root / sub if sub else root
        if not directory.is_dir():
            continue
        groups: dict[tuple[str, bool], list[Path]] = {}
        for path in sorted(directory.iterdir()):
            found = _match(pattern, suffixes, path.name)
            if found is not None and path.is_file():
                groups.setdefault(found, []).append(path)
        for (name, unfinished), paths in sorted(groups.items()):
            stats = [p.stat() for p in paths]
            entries.append(CacheEntry(kind, name, tuple(paths), sum(s.st_size for s in stats),
                                      max(s.st_mtime for s in stats), unfinished))
    for kind, sub, pattern in _DIRECTORY_KINDS:
        directory = root / sub
        if not directory.is_dir():
            continue
        for path in sorted(directory.iterdir()):
            found = _match(pattern, ("",), path.name)
            if found is None or not path.is_dir():
                continue
            paths = tuple(sorted(p for p in path.iterdir() if p.is_file()))
            stats = [p.stat() for p in paths] or [path.stat()]
            entries.append(CacheEntry(kind, found[0], paths, sum(s.st_size for s in stats) if paths else 0,
                                      max(s.st_mtime for s in stats), found[1], path))
    return entries


def remove_entries(entries) -> int:
    """Delete the entries' files (those already gone are skipped) and the directories of
    directory entries once empty; return the bytes freed."""
    freed = 0
    for entry in entries:
        for path in entry.paths:
            try:
                size = path.stat().st_size
                path.unlink()
            except FileNotFoundError:
                continue
            freed += size
        if entry.directory is not None:
            try:
                entry.directory.rmdir()
            except OSError:  # gone already, or holds a file written since it was listed
                pass
    return freed


def mark_used(*paths) -> None:
    """Set the files' modification time to now: the entry was just used. A read-only cache
    is fine (nothing to do then)."""
    for path in paths:
        try:
            os.utime(path)
        except OSError:
            pass
