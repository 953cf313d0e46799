"""The brute-force reference of ``mscloth compare``: rendered at high spp in two independent
halves (their difference estimates its own noise), cached on disk under a key of everything
that determines it, verified when read back."""
from __future__ import annotations

import functools
import gc
import hashlib
import io
import warnings
from pathlib import Path

import numpy as np

from .. import __version__
from ..cache import default_cache_dir, mark_used
from ..errors import ClothError
from .renders import REFERENCE_SEEDS, scene_dict


class ReferenceCacheWarning(UserWarning):
    """A cached reference image was unreadable or did not match; it is rendered again."""


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 of mscloth's Python sources: a changed renderer (a fixed bias, a better
    sampler with a lower noise floor) never reuses a reference it did not render."""
    root = Path(__file__).resolve().parents[1]  # the whole package, not only evaluation/
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def reference_key(name: str, width: int, height: int, spp: int) -> str:
    """SHA-256 of what determines the reference: the scene (its XML text, so an edited
    built-in scene never reuses an old reference), resolution, spp, mscloth version and
    sources (:func:`code_digest`)."""
    from ..scenes.builtin import builtin_scene
    from ..scenes.xml_export import scene_to_xml

    scene = scene_to_xml(builtin_scene(name, width, height))
    text = (f"mscloth-reference|scene={name}|res={width}x{height}|spp={spp}|version={__version__}"
            f"|code={code_digest()}|xml={scene}")
    return hashlib.sha256(text.encode()).hexdigest()


def reference_path(name: str, width: int, height: int, spp: int) -> Path:
    key = reference_key(name, width, height, spp)
    return default_cache_dir() / "references" / f"{name}-{width}x{height}-{spp}spp-{key[:16]}.npz"


class _BadReference(Exception):
    pass


def _load_reference(path: Path, key: str, shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as data:
            stored_key = str(data["key"])
            image = np.array(data["image"], dtype=np.float32)
            variance = np.array(data["variance"], dtype=np.float32)
    except Exception as error:  # truncated zip, garbage, missing arrays ...
        raise _BadReference(f"unreadable ({type(error).__name__}: {error})") from None
    if stored_key != key:
        raise _BadReference("key mismatch")
    if image.shape != shape or variance.shape != shape:
        raise _BadReference(f"shape {image.shape} / {variance.shape}, expected {shape}")
    if not (np.all(np.isfinite(image)) and np.all(np.isfinite(variance)) and np.all(variance >= 0)):
        raise _BadReference("non-finite or negative values")
    return image, variance


def _render_reference(name: str, width: int, height: int, spp: int, quiet: bool) -> tuple[np.ndarray, np.ndarray]:
    """Brute force at ``spp`` in two independent halves: (mean image, per-pixel variance of the mean)."""
    import mitsuba as mi

    from ..loading import load_dict
    from ..render import render_progressive, samples_taken

    scene = load_dict(scene_dict(name, width, height, multiscale=False))
    # Each half at a count the scene's sampler takes (multijitter rounds 512 up to 528):
    # asked for another, Mitsuba would round it with a warning on every pass.
    half = samples_taken(scene, spp // 2)
    if half != spp // 2 and not quiet:
        print(f"reference: the scene's sampler takes {half} samples per pixel for each half, not "
              f"{spp // 2} ({2 * half} in all)", flush=True)
    halves = []
    for i, seed in enumerate(REFERENCE_SEEDS):
        img = render_progressive(scene, half, seed=seed, label=f"reference {i + 1}/2 ({half} spp)", quiet=quiet)
        halves.append(np.array(mi.TensorXf(img), dtype=np.float64)[..., :3])
    del scene
    gc.collect()
    a, b = halves
    return ((a + b) / 2).astype(np.float32), ((a - b) ** 2 / 4).astype(np.float32)


def reference_image(name: str, width: int, height: int, spp: int = 1024, quiet: bool = False):
    """The brute-force reference (image, variance of its mean, came_from_cache).

    Cached under ``default_cache_dir()/references`` keyed by :func:`reference_key`; the
    file is verified on load (key, shape, finite values) and rendered again, with a
    :class:`ReferenceCacheWarning`, when it does not pass.
    """
    if spp < 2 or spp % 2:
        raise ClothError(f"--reference-spp must be an even number >= 2, got {spp}")
    from ..atomic import atomic_write

    key = reference_key(name, width, height, spp)
    path = reference_path(name, width, height, spp)
    shape = (height, width, 3)
    if path.exists():
        try:
            image, variance = _load_reference(path, key, shape)
            mark_used(path)  # for `mscloth cache --clear --older-than`
            if not quiet:
                print(f"reference: cached {path}", flush=True)
            return image, variance, True
        except _BadReference as why:
            warnings.warn(f"cached reference {path} is bad ({why}); rendering it again",
                          ReferenceCacheWarning, stacklevel=2)
    if not quiet:
        print(f"reference: brute force, {spp} spp at {width}x{height} (cached afterwards in {path.parent})",
              flush=True)
    image, variance = _render_reference(name, width, height, spp, quiet)
    buffer = io.BytesIO()
    np.savez(buffer, key=np.array(key), image=image, variance=variance)
    try:
        atomic_write(path, lambda f: f.write(buffer.getvalue()))
    except OSError as error:  # an unwritable cache costs time, not the result
        warnings.warn(f"could not cache the reference in {path}: {error}", ReferenceCacheWarning, stacklevel=2)
    return image, variance, False
