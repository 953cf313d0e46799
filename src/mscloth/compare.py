"""``mscloth compare``: multi-scale vs brute-force cloth, equal-error speed-up per distance.

What is compared. One built-in scene rendered twice with the same ``clothpath``
integrator: *multi-scale* (the scene as it is; every ``cloth`` BSDF shades the whole
pixel footprint) and *brute force* (every ``cloth`` BSDF with ``"multiscale": False``:
fibre-level shading of one texel per sample, anti-aliased only by more samples per
pixel). The reference is brute force at high spp (default 1024), cached on disk.

Regions. The ``aov`` integrator renders camera distance (``depth``) and the shape hit
(``shape_index``) at each pixel centre (stratified sampler, no jitter). Pixels whose
centre sees a cloth shape are split into ``near`` / ``middle`` / ``far`` by equal
thirds of the *logarithm* of camera distance between the 1st and 99th percentile of the
cloth pixels' distances (a pixel's footprint on the cloth grows in proportion to
distance, so equal ratios of distance are equal steps in footprint size). Should a band
hold fewer than max(3, 0.5 %) of the cloth pixels, the split falls back to distance
terciles (a third of the cloth pixels each). Pixels without cloth (sky, floor) are in no
region.

Errors. Per region, relMSE = mean over the region's pixels and the RGB channels of
(img - ref)^2 / (ref^2 + 1e-2); FLIP (NVIDIA's ``flip_evaluator``, LDR mode) on both
images clipped to [0, 1] and sRGB-encoded (exactly what the PNGs show), the FLIP error map
averaged over the region. The reference's own noise is estimated from its two
independent halves, Var(mean) ~ (A - B)^2 / 4, and reported as ``relmse_reference`` (the
floor under every measured relMSE).

Time. Each curve point is one ``mi.render`` at 1, 2, 4, ... spp with its own seed.
``seconds`` is its wall time (tracing, kernel execution, read-back) minus the time Dr.Jit
spent compiling kernels during it (``dr.kernel_history``'s codegen + backend times):
every new spp value compiles a new kernel (a few seconds for the multi-scale BSDF), a
one-off cost that does not scale with the image. Each point is rendered three times with
the same spp and seed (the same image) and keeps the shortest time: a shared machine only
adds time, and single timings varied by +-30% between runs. The budget counts all these
renders: multi-scale gets at most half of it and stops at ``spp_multiscale`` (default 16),
brute force gets the rest and stops at reference spp / 4 (beyond that the reference's
noise dominates). A point is only started when three times twice the previous point's
time still fits; each curve has at least two points.

Speed-up. For each region: the time brute force needs to reach multi-scale's relMSE at
its chosen spp, read off brute force's relMSE-vs-seconds curve, interpolated linearly in
log-log between the two points around the first crossing, divided by multi-scale's
seconds. When brute force never gets down to that error (or is already below it at its
first point), the time is extrapolated from its last (first) point with the Monte Carlo
slope -1 (error ~ 1/time) and flagged ``extrapolated: true``.
"""
from __future__ import annotations

import gc
import functools
import hashlib
import io
import json
import math
import os
import platform
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .atomic import check_writable
from .cache import default_cache_dir, mark_used
from .errors import ClothError

REGIONS = ("near", "middle", "far")
RELMSE_EPS = 1e-2
#: Seeds: reference halves, multi-scale and brute-force curve points never share one.
REFERENCE_SEEDS = (1_000_000, 2_000_000)
MULTISCALE_SEED = 10_000
BRUTEFORCE_SEED = 20_000


class ReferenceCacheWarning(UserWarning):
    """A cached reference image was unreadable or did not match; it is rendered again."""


# --------------------------------------------------------------------------- metrics

def relmse_map(img: np.ndarray, ref: np.ndarray, eps: float = RELMSE_EPS) -> np.ndarray:
    """Per-pixel relative squared error, mean over channels: mean_c (img-ref)^2 / (ref^2 + eps)."""
    img = np.asarray(img, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    if img.shape != ref.shape:
        raise ValueError(f"image shape {img.shape} differs from the reference's {ref.shape}")
    err = (img - ref) ** 2 / (ref ** 2 + eps)
    return err.mean(axis=-1) if err.ndim == 3 else err


def relmse(img: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None, eps: float = RELMSE_EPS) -> float:
    """mean((img - ref)^2 / (ref^2 + eps)) over the pixels in ``mask`` (all if None) and channels."""
    per_pixel = relmse_map(img, ref, eps)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if not mask.any():
            raise ValueError("empty region mask")
        per_pixel = per_pixel[mask]
    return float(per_pixel.mean())


def to_srgb8(img: np.ndarray) -> np.ndarray:
    """Linear RGB -> sRGB in [0, 1] (clipped), the transform of the PNGs."""
    x = np.clip(np.asarray(img, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def flip_map(img: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """FLIP error map (H, W) of ``img`` against ``ref``: LDR-FLIP of the sRGB-encoded, clipped images."""
    import flip_evaluator

    error, _, _ = flip_evaluator.evaluate(to_srgb8(ref).astype(np.float32), to_srgb8(img).astype(np.float32),
                                          "LDR", applyMagma=False, computeMeanError=False)
    return np.asarray(error, dtype=np.float64).reshape(ref.shape[:2])


# --------------------------------------------------------------------------- regions

def region_masks(depth: np.ndarray, cloth: np.ndarray, min_fraction: float = 0.005):
    """Split cloth pixels into near / middle / far by camera distance.

    Equal thirds of log(distance) between the 1st and 99th percentile of the cloth pixels'
    distances; falls back to distance terciles (equal pixel counts) when a band would hold
    fewer than max(3, ``min_fraction`` of the cloth pixels). Returns
    ({region: bool mask}, {"method": ..., "thresholds": [t1, t2]}).
    """
    depth = np.asarray(depth, dtype=np.float64)
    cloth = np.asarray(cloth, dtype=bool) & np.isfinite(depth) & (depth > 0)
    d = depth[cloth]
    if d.size < 3:
        raise ClothError(f"only {d.size} pixel(s) show cloth at this resolution; "
                         "need at least 3 to split into near / middle / far")
    min_pixels = max(3, math.ceil(min_fraction * d.size))
    lo, hi = np.percentile(np.log(d), [1.0, 99.0])
    method = "log-distance thirds"
    t1, t2 = math.exp(lo + (hi - lo) / 3), math.exp(lo + 2 * (hi - lo) / 3)
    counts = [(d < t1).sum(), ((d >= t1) & (d < t2)).sum(), (d >= t2).sum()]
    if hi - lo < 1e-9 or min(counts) < min(min_pixels, d.size // 3):
        method = "distance terciles"
        order = np.sort(d)
        t1, t2 = order[d.size // 3], order[(2 * d.size) // 3]
    masks = {"near": cloth & (depth < t1), "middle": cloth & (depth >= t1) & (depth < t2),
             "far": cloth & (depth >= t2)}
    if any(not m.any() for m in masks.values()):
        # Ties (many pixels at one distance): fall back to rank order.
        flat = np.flatnonzero(cloth)
        ranks = flat[np.argsort(depth.ravel()[flat], kind="stable")]
        parts = np.array_split(ranks, 3)
        masks = {}
        for name, part in zip(REGIONS, parts):
            m = np.zeros(depth.size, dtype=bool)
            m[part] = True
            masks[name] = m.reshape(depth.shape)
        method = "distance rank terciles"
        t1, t2 = float(depth.ravel()[parts[1][0]]), float(depth.ravel()[parts[2][0]])
    return masks, {"method": method, "thresholds": [float(t1), float(t2)]}


# --------------------------------------------------------------------------- speed-up

def equal_error_time(seconds, errors, target: float) -> tuple[float, bool]:
    """Seconds a method needs to reach error ``target``, from its (seconds, error) curve.

    Linear interpolation in log-log between the points around the first crossing below
    ``target``; if the curve never gets there (or starts below it), extrapolation from
    its last (first) point with slope -1 (error ~ 1/time). Returns (seconds, extrapolated).
    """
    t = np.asarray(seconds, dtype=np.float64)
    e = np.asarray(errors, dtype=np.float64)
    if t.size == 0 or t.size != e.size:
        raise ValueError("need a non-empty curve with as many errors as times")
    if not (target > 0 and np.all(t > 0) and np.all(e > 0)):
        raise ValueError("times, errors and the target error must be positive")
    order = np.argsort(t, kind="stable")
    t, e = t[order], e[order]
    below = np.flatnonzero(e <= target)
    if below.size == 0:
        return float(t[-1] * e[-1] / target), True
    i = int(below[0])
    if i == 0:
        return float(t[0] * e[0] / target), True
    lt0, lt1 = math.log(t[i - 1]), math.log(t[i])
    le0, le1 = math.log(e[i - 1]), math.log(e[i])
    frac = (math.log(target) - le0) / (le1 - le0)
    return float(math.exp(lt0 + frac * (lt1 - lt0))), False


def closest_in_time(seconds, target: float) -> int:
    """Index of the curve point whose time is closest to ``target`` (in log time)."""
    t = np.asarray(seconds, dtype=np.float64)
    return int(np.argmin(np.abs(np.log(t) - math.log(target))))


# --------------------------------------------------------------------------- scenes

def _setup_mitsuba() -> str:
    import mitsuba as mi

    from . import default_variant, register

    if mi.variant() is None:
        mi.set_variant(default_variant())
    register()
    return mi.variant()


def scene_dict(name: str, width: int, height: int, multiscale: bool) -> dict:
    """A built-in scene's dictionary; brute force (``multiscale=False``) differs only in its cloth BSDFs."""
    from .scenes.builtin import builtin_scene, set_cloth_parameters

    scene = builtin_scene(name, width, height)
    if set_cloth_parameters(scene, multiscale=multiscale) == 0:
        raise ClothError(f"scene {name!r} has no cloth BSDF to compare")
    return scene


def _cloth_shape_keys(scene: dict) -> set[str]:
    return {key for key, node in scene.items()
            if isinstance(node, dict) and isinstance(node.get("bsdf"), dict) and node["bsdf"].get("type") == "cloth"}


def away_from_edges(ids: np.ndarray) -> np.ndarray:
    """Pixels whose 8 neighbours show the same shape as they do (at the pixel centres).

    A pixel on a silhouette or on the border between two shapes mixes both in its box
    filter: its samples' spread is that edge's anti-aliasing noise, the same whichever BSDF
    shades the cloth. Regions leave such pixels out, so that they measure the shading."""
    ids = np.asarray(ids)
    h, w = ids.shape
    pad = np.pad(ids, 1, mode="edge")
    same = np.ones((h, w), dtype=bool)
    for dy in range(3):
        for dx in range(3):
            same &= pad[dy:dy + h, dx:dx + w] == ids
    return same


def depth_and_cloth(name: str, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera distance (H, W) and a mask (H, W) of the cloth pixels away from edges
    (:func:`away_from_edges`), from the pixel centres."""
    import drjit as dr
    import mitsuba as mi

    from .loading import load_dict

    scene = scene_dict(name, width, height, multiscale=True)
    cloth_keys = _cloth_shape_keys(scene)
    # Shapes only need identities here, so no cloth tables are built: a plain diffuse BSDF
    # each, all different (Mitsuba merges meshes that share an identical BSDF into one shape).
    for i, node in enumerate(scene.values()):
        if isinstance(node, dict) and "bsdf" in node:
            node["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, i / 1000]}}
    scene["integrator"] = {"type": "aov", "aovs": "dd:depth,si:shape_index"}
    scene["sensor"]["sampler"] = {"type": "stratified", "sample_count": 1, "jitter": False}
    loaded = load_dict(scene)
    aov = np.array(mi.render(loaded, spp=1, seed=0))
    shapes = {shape.id(): shape for shape in loaded.shapes()}
    if not cloth_keys <= set(shapes):
        raise ClothError(f"scene {name!r}: cloth shapes {sorted(cloth_keys - set(shapes))} "
                         "cannot be told apart in the shape_index AOV")
    # shape_index holds the shape's registry id, which a ShapePtr reinterpreted as UInt32 gives
    cloth_ids = [int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shapes[key]))[0]) for key in cloth_keys]
    depth = aov[..., 0].astype(np.float64)
    ids = np.rint(aov[..., 1]).astype(np.int64)
    cloth = np.isin(ids, cloth_ids) & (depth > 0) & away_from_edges(ids)
    del loaded
    gc.collect()
    return depth, cloth


@dataclass
class Render:
    spp: int
    seed: int
    seconds: float          # wall time minus JIT compilation
    compile_seconds: float  # JIT compilation during the call
    image: np.ndarray = field(repr=False)


def timed_render(scene, spp: int, seed: int) -> Render:
    """One ``mi.render`` read back to NumPy; time without the kernel compilation it triggered."""
    import drjit as dr
    import mitsuba as mi

    gc.collect()  # see render.render_progressive: no plugin freed mid-trace
    dr.sync_thread()
    had_history = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clear
    try:
        start = time.perf_counter()
        image = np.array(mi.render(scene, spp=spp, seed=seed))[..., :3]
        wall = time.perf_counter() - start
        history = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, had_history)
    compile_ms = sum(k.get("codegen_time", 0.0) + k.get("backend_time", 0.0) for k in history)
    compile_s = min(compile_ms / 1000.0, wall)
    return Render(spp, seed, max(wall - compile_s, 1e-6), compile_s, image.astype(np.float32))


# --------------------------------------------------------------------------- reference

@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 of mscloth's Python sources: a changed renderer (a fixed bias, a better
    sampler with a lower noise floor) never reuses a reference it did not render."""
    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def reference_key(name: str, width: int, height: int, spp: int) -> str:
    """SHA-256 of what determines the reference: the scene (its XML text, so an edited
    built-in scene never reuses an old reference), resolution, spp, mscloth version and
    sources (:func:`code_digest`)."""
    from .scenes.builtin import builtin_scene
    from .scenes.xml_export import scene_to_xml

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

    from .loading import load_dict
    from .render import render_progressive

    scene = load_dict(scene_dict(name, width, height, multiscale=False))
    half = spp // 2
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
    from .atomic import atomic_write

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


# --------------------------------------------------------------------------- curves

#: Renders per curve point for its time (the shortest counts).
TIMING_REPEATS = 3


def convergence_curve(scene, label: str, seed0: int, max_spp: int, budget: float,
                      evaluate, min_points: int = 2, quiet: bool = False, repeats: int = TIMING_REPEATS) -> list[dict]:
    """Render at 1, 2, 4, ... spp (seed0 + k) until ``max_spp`` or ``budget`` seconds are used.

    A point is started only while the time spent plus twice the previous point's time fits
    the budget (always at least ``min_points``). ``evaluate(image)`` returns the per-region
    errors stored with each point. Each point is timed ``repeats`` times (the same spp and
    seed, so the same image) and keeps the shortest: a shared machine only ever adds time.
    """
    points = []
    spent = 0.0
    spp, k = 1, 0
    while spp <= max_spp:
        if len(points) >= min_points and spent + 2 * repeats * points[-1]["seconds"] > budget:
            break
        r = timed_render(scene, spp, seed0 + k)
        spent += r.seconds
        seconds = r.seconds
        for _ in range(repeats - 1):
            again = timed_render(scene, spp, seed0 + k).seconds
            spent += again
            seconds = min(seconds, again)
        point = {"spp": spp, "seed": r.seed, "seconds": seconds, "compile_seconds": r.compile_seconds,
                 **evaluate(r.image), "image": r.image}
        points.append(point)
        if not quiet:
            errs = "  ".join(f"{g} {point['relmse'][g]:.3g}" for g in REGIONS)
            print(f"  {label:12s} {spp:5d} spp  {seconds:7.3f} s (+{r.compile_seconds:.1f} s compile)  "
                  f"relMSE {errs}   [{spent:.2f}/{budget:.2f} s]", flush=True)
        spp, k = spp * 2, k + 1
    return points


# --------------------------------------------------------------------------- the comparison

def _region_figures(points_ms, points_bf, spp_ms_chosen, floor) -> dict:
    out = {}
    ms_index = max(i for i, p in enumerate(points_ms) if p["spp"] <= spp_ms_chosen)
    ms = points_ms[ms_index]
    bf_times = [p["seconds"] for p in points_bf]
    bf_index = closest_in_time(bf_times, ms["seconds"])
    bf = points_bf[bf_index]
    for g in REGIONS:
        target = ms["relmse"][g]
        t_equal, extrapolated = equal_error_time(bf_times, [max(p["relmse"][g], 1e-30) for p in points_bf],
                                                 max(target, 1e-30))
        # spp brute force would need at that time, from its measured seconds per spp
        per_spp = np.median([p["seconds"] / p["spp"] for p in points_bf])
        same = min(points_bf, key=lambda p: (abs(math.log(p["spp"] / ms["spp"])), p["spp"]))
        out[g] = {
            "speedup": t_equal / ms["seconds"],
            "extrapolated": bool(extrapolated),
            "relmse_multiscale": target,
            "relmse_bruteforce": bf["relmse"][g],
            "relmse_reference": floor[g],
            "flip_multiscale": ms["flip"][g],
            "flip_bruteforce": bf["flip"][g],
            "spp_multiscale": ms["spp"],
            "spp_bruteforce": bf["spp"],
            "seconds_multiscale": ms["seconds"],
            "seconds_bruteforce": bf["seconds"],
            "seconds_bruteforce_equal_error": t_equal,
            "spp_bruteforce_equal_error": t_equal / per_spp,
            # diagnostics: brute force at (or nearest to) multi-scale's spp -- error per sample
            # and cost per sample, the two factors of the speed-up
            "spp_bruteforce_equal_spp": same["spp"],
            "relmse_bruteforce_equal_spp": same["relmse"][g],
            "seconds_bruteforce_equal_spp": same["seconds"],
            "curve_multiscale": [{"spp": p["spp"], "seconds": p["seconds"], "relmse": p["relmse"][g],
                                  "flip": p["flip"][g]} for p in points_ms],
            "curve_bruteforce": [{"spp": p["spp"], "seconds": p["seconds"], "relmse": p["relmse"][g],
                                  "flip": p["flip"][g]} for p in points_bf],
        }
    return out, ms_index, bf_index


def run_compare(name: str, width: int, height: int, budget: float = 60.0, reference_spp: int = 1024,
                out_dir: Path | None = None, json_path: Path | None = None, spp_multiscale: int = 16,
                quiet: bool = False) -> dict:
    """Run the whole comparison; write the report (and JSON); return the JSON dictionary."""
    from .scenes.builtin import SCENES

    if name not in SCENES:
        raise ClothError(f"unknown scene {name!r}: expected one of {', '.join(SCENES)}")
    if not (isinstance(budget, (int, float)) and math.isfinite(budget) and budget > 0):
        raise ClothError(f"--budget must be a positive number of seconds, got {budget}")
    if reference_spp < 2 or reference_spp % 2:
        raise ClothError(f"--reference-spp must be an even number >= 2, got {reference_spp}")
    if spp_multiscale < 1:
        raise ClothError(f"multi-scale spp must be >= 1, got {spp_multiscale}")
    out_dir = Path(out_dir) if out_dir is not None else Path("out") / f"compare-{name}"
    check_writable(out_dir)
    if json_path is not None:
        json_path = Path(json_path)
        if json_path.is_dir():
            raise ClothError(f"--json {json_path} is a directory; name a file")
        check_writable(json_path.parent)

    variant = _setup_mitsuba()
    from .loading import load_dict

    say = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    say(f"mscloth compare: {name}, {width}x{height}, budget {budget:g} s, reference {reference_spp} spp, "
        f"variant {variant}")
    started = time.perf_counter()

    depth, cloth = depth_and_cloth(name, width, height)
    masks, region_info = region_masks(depth, cloth)
    say("regions (" + region_info["method"] + "): " + ", ".join(f"{g} {int(masks[g].sum())} px" for g in REGIONS)
        + f" of {width * height}")

    ref, ref_var, cached = reference_image(name, width, height, reference_spp, quiet=quiet)
    floor = {g: float((ref_var / (ref.astype(np.float64) ** 2 + RELMSE_EPS)).mean(axis=-1)[masks[g]].mean())
             for g in REGIONS}

    def evaluate(image):
        rel = relmse_map(image, ref)
        flip = flip_map(image, ref)
        return {"relmse": {g: float(rel[masks[g]].mean()) for g in REGIONS},
                "flip": {g: float(flip[masks[g]].mean()) for g in REGIONS}}

    say(f"multi-scale: 1 .. {spp_multiscale} spp, at most {budget / 2:g} s")
    scene = load_dict(scene_dict(name, width, height, multiscale=True))
    points_ms = convergence_curve(scene, "multi-scale", MULTISCALE_SEED, spp_multiscale, budget / 2, evaluate,
                                  quiet=quiet)
    del scene
    gc.collect()
    bf_budget = budget - sum(p["seconds"] for p in points_ms)
    bf_max = max(2, reference_spp // 4)
    say(f"brute force: 1 .. {bf_max} spp, at most {max(bf_budget, 0):.3g} s")
    scene = load_dict(scene_dict(name, width, height, multiscale=False))
    points_bf = convergence_curve(scene, "brute force", BRUTEFORCE_SEED, bf_max, bf_budget, evaluate, quiet=quiet)
    del scene
    gc.collect()

    regions, ms_index, bf_index = _region_figures(points_ms, points_bf, spp_multiscale, floor)
    result = {
        "scene": name,
        "resolution": [width, height],
        "reference_spp": reference_spp,
        "reference_cached": cached,
        "budget_seconds": budget,
        "variant": variant,
        "mscloth_version": __version__,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        **regions,
        "regions": {"method": region_info["method"], "distance_thresholds": region_info["thresholds"],
                    "pixels_used": "the same cloth shape at the pixel centre and its 8 neighbours' (no edges)",
                    "pixels": {g: int(masks[g].sum()) for g in REGIONS}, "cloth_pixels": int(cloth.sum())},
        "metrics": {
            "relmse": f"mean over region pixels and RGB of (img-ref)^2/(ref^2+{RELMSE_EPS:g})",
            "flip": "flip_evaluator LDR-FLIP of sRGB-encoded images clipped to [0,1], mean over region pixels",
            "seconds": "wall time of one mi.render at that spp minus Dr.Jit kernel compilation",
            "speedup": "brute-force seconds to reach multi-scale's relMSE (log-log interpolation of its "
                       "relMSE-vs-seconds curve; slope -1 extrapolation if outside it) / multi-scale seconds",
        },
        "compile_seconds": {"multiscale": sum(p["compile_seconds"] for p in points_ms),
                            "bruteforce": sum(p["compile_seconds"] for p in points_bf)},
    }

    from .report import write_report

    images = {"reference": ref, "multiscale": points_ms[ms_index]["image"],
              "bruteforce": points_bf[bf_index]["image"]}
    say(f"writing the report to {out_dir} ...")
    report = write_report(out_dir, result, images, masks, depth)
    result["report"] = str(report)
    if json_path is not None:
        from .atomic import atomic_write

        text = json.dumps(result, indent=2, allow_nan=False) + "\n"
        atomic_write(json_path, lambda f: f.write(text.encode()))
    result["elapsed_seconds"] = time.perf_counter() - started
    if not quiet:
        print(f"{'region':8s} {'speed-up':>10s} {'MS relMSE':>10s} {'BF relMSE':>10s} {'MS FLIP':>8s} "
              f"{'BF FLIP':>8s}   (multi-scale {points_ms[ms_index]['spp']} spp vs brute force "
              f"{points_bf[bf_index]['spp']} spp at equal time)")
        for g in REGIONS:
            r = result[g]
            print(f"{g:8s} {r['speedup']:9.2f}x{'*' if r['extrapolated'] else ' '} {r['relmse_multiscale']:10.3g} "
                  f"{r['relmse_bruteforce']:10.3g} {r['flip_multiscale']:8.4f} {r['flip_bruteforce']:8.4f}")
        if any(result[g]["extrapolated"] for g in REGIONS):
            print("* extrapolated with error ~ 1/time beyond brute force's measured curve")
        print(f"wrote {report}" + (f" and {json_path}" if json_path else "")
              + f" in {result['elapsed_seconds']:.1f} s")
    return result
