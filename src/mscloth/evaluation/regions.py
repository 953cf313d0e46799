"""The near / middle / far regions of ``mscloth compare``: cloth pixels away from edges,
split by camera distance.

The ``aov`` integrator renders camera distance (``depth``) and the shape hit
(``shape_index``) at each pixel centre (stratified sampler, no jitter). Pixels whose
centre sees a cloth shape are split into ``near`` / ``middle`` / ``far`` by equal
thirds of the *logarithm* of camera distance between the 1st and 99th percentile of the
cloth pixels' distances (a pixel's footprint on the cloth grows in proportion to
distance, so equal ratios of distance are equal steps in footprint size). Should a band
hold fewer than max(3, 0.5 %) of the cloth pixels, the split falls back to distance
terciles (a third of the cloth pixels each). Pixels without cloth (sky, floor) are in no
region.
"""
from __future__ import annotations

import gc
import math

import numpy as np

from ..errors import ClothError
from .renders import scene_dict

REGIONS = ("near", "middle", "far")


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



def cloth_shape_keys(scene: dict) -> set[str]:
    """The keys of a scene dictionary's shapes whose BSDF is a ``cloth``."""
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

    from ..loading import load_dict

    scene = scene_dict(name, width, height, multiscale=True)
    cloth_keys = cloth_shape_keys(scene)
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

