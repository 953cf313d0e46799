"""Where the error of ``mscloth compare`` comes from: noise per sample, split by light, and
the bias each method converges to.

The equal-error speed-up of multi-scale over brute-force shading is bounded by two things
``compare`` alone does not separate:

* **Noise per sample.** Relative MSE of an n-spp image is bias^2 + v / n. The per-sample
  noise v is measured from independent renders, for each method with the scene's full
  lighting and with the sun or the sky alone. Multi-scale shading removes the noise of the
  weave (visible under the sun); the noise of sampling the sky's directions is there for
  both methods.
* **Bias.** Multi-scale shading is not brute force: its probes are boxes standing for the
  pixel's parallelogram (which they cannot tile where it is turned against the texel
  grid), and rank-compressed directional tables keep their compression error. The squared
  bias per region is estimated from two independent halves of a high-spp render against
  the reference.

With noise alone (no bias), the equal-error speed-up would be
(v_bruteforce / v_multiscale) / (time per sample, multi-scale / brute force): the bound the
benchmark reports next to the measured speed-up.

* **Time per sample** (:func:`interleaved_time`), the two methods' renders interleaved in
  rounds: a shared machine's speed drifts by tens of percent within minutes, and
  ``compare`` renders one method's curve after the other's. Of the whole frame, and per
  region (:func:`region_time`): ``compare`` times whole frames, so a region's speed-up
  carries the whole frame's time ratio. Rendering only the bounding box of a region's
  pixels (a film crop) gives the region's own ratio: multi-scale's extra work is where the
  footprints are shaded whole, not everywhere.

The estimators (noise per sample, squared bias) are in :mod:`.metrics`.
"""
from __future__ import annotations

import gc

import numpy as np

from .. import setup_mitsuba
from .metrics import per_sample_noise, squared_bias
from .references import reference_image
from .regions import REGIONS, depth_and_cloth, region_masks
from .renders import scene_dict, timed_render, with_scene_alone

#: Lighting cases: the built-in scenes' emitter keys left in.
LIGHTS = {"both": ("sun", "sky"), "sun": ("sun",), "sky": ("sky",)}
#: Seeds of the budget's renders (apart from compare's and the reference's).
NOISE_SEED = 30_000
BIAS_SEEDS = (40_000, 50_000)


def lit_scene(name, width, height, multiscale, lights=LIGHTS["both"], max_depth=None, crop=None, **cloth):
    """Scene ``name`` (multi-scale or brute force) with only the emitters ``lights``, the
    cloth parameters ``cloth`` and, if given, the integrator's ``max_depth`` (2: direct
    light only) and the film's ``crop`` (x, y, width, height in pixels), loaded."""
    from ..loading import load_dict
    from ..scenes.builtin import set_cloth_parameters

    scene = scene_dict(name, width, height, multiscale)
    for key in LIGHTS["both"]:
        if key not in lights:
            del scene[key]
    if cloth:
        set_cloth_parameters(scene, **cloth)
    if max_depth is not None:
        scene["integrator"]["max_depth"] = max_depth
    if crop is not None:
        film = scene["sensor"]["film"]
        film["crop_offset_x"], film["crop_offset_y"], film["crop_width"], film["crop_height"] = (int(c) for c in crop)
    return load_dict(scene)


#: Defaults of :func:`error_budget` (``make bench`` quotes them).
#: Noise per sample is measured at the count ``compare`` reads multi-scale's error at (16):
#: under a stratified pixel sampler it depends on the count (satin-plane, middle: 0.123 at
#: 4 spp, 0.0126 at 16; docs/performance-log.md L24).
NOISE_RENDERS, NOISE_SPP, BIAS_SPP = 4, 16, 256


def error_budget(name: str, width: int, height: int, noise_renders: int = NOISE_RENDERS,
                 noise_spp: int = NOISE_SPP, bias_spp: int = BIAS_SPP, reference_spp: int = 1024,
                 quiet: bool = False) -> dict:
    """Per region of scene ``name``: per-sample noise of both methods under each lighting
    case (``noise``: {method: {light: value}}), and the squared bias of each method with the
    scene's lights (``bias``: {"multiscale": value, "bruteforce": value}), all in relMSE
    units against ``compare``'s cached reference."""
    setup_mitsuba()
    say = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    masks = region_masks(*depth_and_cloth(name, width, height))[0]
    ref, ref_var, _ = reference_image(name, width, height, reference_spp, quiet=True)

    def per_region(pixel_map):
        return {g: float(pixel_map[masks[g]].mean()) for g in REGIONS}

    def render(scene, spp, seed):
        return timed_render(scene, spp, seed).image

    noise = {"multiscale": {}, "bruteforce": {}}
    bias = {}
    for method, multiscale in (("multiscale", True), ("bruteforce", False)):
        for light, keys in LIGHTS.items():
            scene = lit_scene(name, width, height, multiscale, keys)
            images = [render(scene, noise_spp, NOISE_SEED + k) for k in range(noise_renders)]
            noise[method][light] = per_region(per_sample_noise(images, noise_spp, ref))
            say(f"  {name} {method} {light}: per-sample noise "
                + ", ".join(f"{g} {noise[method][light][g]:.3g}" for g in REGIONS))
            if light == "both":  # the scene as the benchmark shades it: its bias too
                a, b = (render(scene, bias_spp // 2, seed) for seed in BIAS_SEEDS)
                bias[method] = per_region(squared_bias(a, b, ref, ref_var))
                say(f"  {name} {method}: squared bias " + ", ".join(f"{g} {bias[method][g]:.3g}" for g in REGIONS))
            del scene
    gc.collect()
    return {g: {"noise": {m: {light: noise[m][light][g] for light in LIGHTS} for m in noise},
                "bias": {m: bias[m][g] for m in bias}} for g in REGIONS}


def region_crops(name: str, width: int, height: int) -> dict:
    """{region: (x, y, width, height)}: the bounding box in pixels of each region's pixels
    (:func:`.regions.region_masks`); a film crop renders it alone."""
    masks = region_masks(*depth_and_cloth(name, width, height))[0]
    crops = {}
    for g in REGIONS:
        rows, cols = np.flatnonzero(masks[g].any(axis=1)), np.flatnonzero(masks[g].any(axis=0))
        crops[g] = (int(cols[0]), int(rows[0]), int(cols[-1] + 1 - cols[0]), int(rows[-1] + 1 - rows[0]))
    return crops


def interleaved_rounds(renders: dict, rounds: int) -> dict:
    """{label: [one value per round]}: each of ``renders`` (label: a function of the round's
    number) called once per round, in order, round after round. The machine's drift moves a
    round's values together, so ratios within a round are steadier than any one time."""
    values = {label: [] for label in renders}
    for r in range(rounds):
        for label, render in renders.items():
            values[label].append(render(r))
    return values


def interleaved_renders(name: str, width: int, height: int, spps=(NOISE_SPP,), rounds: int = 3,
                        crop=None) -> dict:
    """Seconds of each render of scene ``name`` with its sun and sky (the film's ``crop``
    alone if given), multi-scale and brute force at each of ``spps`` (or a {method: counts}
    dictionary), after a render of each that compiles, in :func:`interleaved_rounds`:
    {method: {samples taken: [seconds, one per round]}} (a stratified sampler takes some
    counts up: 32 -> 35).

    Each round loads one method's scene, renders its counts and frees it before the other
    method's: Dr.Jit traces a virtual call into every registered instance, so with both
    scenes loaded each render also traced the other method's BSDFs (brute force's renders
    paid ~25 ms for multi-scale's: +35% of a 16-spp frame of satin-plane; performance log
    L51). A reloaded scene finds its kernels in Dr.Jit's cache."""
    setup_mitsuba()
    methods = ("multiscale", "bruteforce")
    counts = spps if isinstance(spps, dict) else {m: spps for m in methods}

    def each_count(method, seed):
        """``method``'s scene loaded alone, each of its counts rendered: [Render]."""
        def use(scene):
            timed_render(scene, 1, 1)  # its kernels (cached after the first load) and tables warm
            return [timed_render(scene, spp, seed) for spp in counts[method]]
        return with_scene_alone(lambda: lit_scene(name, width, height, method == "multiscale", crop=crop), use)

    taken = {m: [r.spp for r in each_count(m, 1)] for m in methods}  # compiles
    seconds = interleaved_rounds({m: lambda r, m=m: [x.seconds for x in each_count(m, 100 + r)] for m in methods},
                                 rounds)
    return {m: {t: [per_round[i] for per_round in seconds[m]] for i, t in enumerate(taken[m])} for m in methods}


def interleaved_time(name: str, width: int, height: int, spp: int = NOISE_SPP, rounds: int = 3,
                     crop=None) -> dict:
    """Seconds per sample per pixel (per sample taken) of multi-scale and brute force
    (:func:`interleaved_renders` at ``spp``): {"multiscale", "bruteforce": medians over the
    rounds, "ratio": the median of the rounds' ratios multi-scale / brute force, "ratios":
    each round's}."""
    seconds = {}
    for m, by_count in interleaved_renders(name, width, height, (spp,), rounds, crop).items():
        (taken, values), = by_count.items()  # a stratified sampler may take more than spp
        seconds[m] = np.asarray(values) / taken
    ratios = [float(a / b) for a, b in zip(seconds["multiscale"], seconds["bruteforce"])]
    return {"multiscale": float(np.median(seconds["multiscale"])), "bruteforce": float(np.median(seconds["bruteforce"])),
            "ratio": float(np.median(ratios)), "ratios": ratios}


def region_time(name: str, width: int, height: int, spp: int = NOISE_SPP, rounds: int = 3) -> dict:
    """{region: :func:`interleaved_time` of the bounding box of the region's pixels alone}."""
    setup_mitsuba()  # before region_crops renders
    return {g: interleaved_time(name, width, height, spp, rounds, crop)
            for g, crop in region_crops(name, width, height).items()}


def noise_only_speedup(noise: dict, seconds_ratio: float) -> float:
    """The equal-error speed-up without bias: brute force's per-sample noise over
    multi-scale's, divided by multi-scale's time per sample over brute force's."""
    return noise["bruteforce"]["both"] / max(noise["multiscale"]["both"], 1e-30) / seconds_ratio
