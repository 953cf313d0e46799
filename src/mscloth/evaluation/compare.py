"""``mscloth compare``: multi-scale vs brute-force cloth, equal-error speed-up per distance.

What is compared. One built-in scene rendered twice with the same ``clothpath``
integrator: *multi-scale* (the scene as it is; every ``cloth`` BSDF shades the whole
pixel footprint) and *brute force* (every ``cloth`` BSDF with ``"multiscale": False``:
fibre-level shading of one texel per sample, anti-aliased only by more samples per
pixel). The reference is brute force at high spp (default 1024), cached on disk.

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

Errors. relMSE against the reference contains the reference's own noise, alike for both
methods; the speed-up compares each method's own error, relMSE minus that noise
(:class:`.speedup.ReferenceNoise`), and keeps the uncorrected figure beside it.

Regions (:mod:`.regions`), errors (:mod:`.metrics`), the reference (:mod:`.references`), the
speed-up and when a region is too small for it (:mod:`.speedup`), the report (:mod:`.report`).
"""
from __future__ import annotations

import gc
import importlib.util
import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from .. import __version__, setup_mitsuba
from ..atomic import check_writable
from ..errors import ClothError
from .metrics import RELMSE_EPS, flip_map, relmse_map
from .references import reference_image
from .regions import REGIONS, depth_and_cloth, region_masks
from .renders import BRUTEFORCE_SEED, MULTISCALE_SEED, scene_dict, timed_render
from .speedup import (MIN_REGION_PIXELS, ReferenceNoise, closest_in_time, equal_error_time, few_pixels_warning,
                      time_at)

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
        # (r.spp: the count the sampler took, the curve's time and error are at it)
        point = {"spp": r.spp, "seed": r.seed, "seconds": seconds, "compile_seconds": r.compile_seconds,
                 **evaluate(r.image), "image": r.image}
        points.append(point)
        if not quiet:
            errs = "  ".join(f"{g} {point['relmse'][g]:.3g}" for g in REGIONS)
            print(f"  {label:12s} {r.spp:5d} spp  {seconds:7.3f} s (+{r.compile_seconds:.1f} s compile)  "
                  f"relMSE {errs}   [{spent:.2f}/{budget:.2f} s]", flush=True)
        spp, k = spp * 2, k + 1
    return points


# --------------------------------------------------------------------------- the comparison

#: What the comparison needs beyond the renderer, the ``evaluation`` extra: {module: package}.
EVALUATION_EXTRA = {"matplotlib": "matplotlib", "flip_evaluator": "flip-evaluator"}


def check_evaluation_extra() -> None:
    """Raise ClothError naming the packages of the ``evaluation`` extra (plots, FLIP) that are
    not installed: the renderer does without them, the comparison does not."""
    missing = [package for module, package in EVALUATION_EXTRA.items() if importlib.util.find_spec(module) is None]
    if missing:
        raise ClothError(f"mscloth compare needs {' and '.join(missing)}, not installed: "
                         "pip install 'mscloth[evaluation]'")


def region_figures(points_ms, points_bf, spp_ms_chosen, noise) -> tuple[dict, int, int]:
    """Per region of :data:`.regions.REGIONS`, the equal-error speed-up and what it is made of,
    from the two curves (lists of ``{"spp", "seconds", "relmse": {region: ...}, "flip":
    {region: ...}}`` points, in order of spp): multi-scale's point is its last at or below
    ``spp_ms_chosen``, brute force's the one closest to it in time; ``noise`` is each region's
    :class:`.speedup.ReferenceNoise`. Returns ``(figures, ms_index, bf_index)``: the figures by
    region and the indices of the two points they compare.

    The speed-up compares own errors (relMSE minus the reference's noise). Brute-force points
    whose own error the reference cannot resolve are left out of its curve (the speed-up then
    extrapolates past the last resolved one); a multi-scale error it cannot resolve counts as
    the resolution, so its speed-up is a lower bound, flagged ``reference_limited``.
    ``speedup_uncorrected`` is the same figure on the errors against the reference as they are."""
    out = {}
    ms_index = max(i for i, p in enumerate(points_ms) if p["spp"] <= spp_ms_chosen)
    ms = points_ms[ms_index]
    bf_times = [p["seconds"] for p in points_bf]
    bf_index = closest_in_time(bf_times, ms["seconds"])
    bf = points_bf[bf_index]
    timed = bruteforce_timing(points_bf)
    for g in REGIONS:
        ref_noise = noise[g]
        raw_target = max(ms["relmse"][g], 1e-30)
        # The samples brute force needs, from its error-vs-spp curve (no timing in it).
        spp_raw, raw_extrapolated = equal_error_time([p["spp"] for p in points_bf],
                                                     [max(p["relmse"][g], 1e-30) for p in points_bf], raw_target)
        own_target = ref_noise.own_error(ms["relmse"][g])
        resolved = [(p["spp"], own) for p in points_bf if (own := ref_noise.own_error(p["relmse"][g])) is not None]
        if resolved:
            target = ref_noise.resolution if own_target is None else own_target
            spp_equal, extrapolated = equal_error_time(*zip(*resolved), target)
        else:  # brute force's first point is already within the reference's noise: nothing to subtract from
            target, spp_equal, extrapolated = raw_target, spp_raw, raw_extrapolated
        t_equal, t_raw = time_at(spp_equal, *timed), time_at(spp_raw, *timed)
        same = min(points_bf, key=lambda p: (abs(math.log(p["spp"] / ms["spp"])), p["spp"]))
        out[g] = {
            "speedup": t_equal / ms["seconds"],
            "extrapolated": bool(extrapolated),
            "reference_limited": bool(resolved) and own_target is None,
            "speedup_uncorrected": t_raw / ms["seconds"],
            "relmse_multiscale": ms["relmse"][g],
            "relmse_multiscale_own": target,
            "relmse_bruteforce": bf["relmse"][g],
            "relmse_reference": ref_noise.relmse,
            "relmse_reference_standard_error": ref_noise.standard_error,
            "flip_multiscale": ms["flip"][g],
            "flip_bruteforce": bf["flip"][g],
            "spp_multiscale": ms["spp"],
            "spp_bruteforce": bf["spp"],
            "seconds_multiscale": ms["seconds"],
            "seconds_bruteforce": bf["seconds"],
            "seconds_bruteforce_equal_error": t_equal,
            "spp_bruteforce_equal_error": spp_equal,
            "spp_bruteforce_equal_error_uncorrected": spp_raw,
            # diagnostics: brute force at (or nearest to) multi-scale's spp -- error per sample
            # and cost per sample, the two factors of the speed-up
            "spp_bruteforce_equal_spp": same["spp"],
            "relmse_bruteforce_equal_spp": same["relmse"][g],
            "seconds_bruteforce_equal_spp": same["seconds"],
            "curve_multiscale": _curve(points_ms, g, ref_noise),
            "curve_bruteforce": _curve(points_bf, g, ref_noise),
        }
    return out, ms_index, bf_index


def bruteforce_timing(points) -> tuple[list, list]:
    """(sample counts, seconds) that price brute force at any count
    (:func:`.speedup.time_at`): its curve's renders at powers of two where it has two or
    more, else all of them. Mitsuba renders other counts (the ``multijitter`` sampler rounds
    32 up to 35, 128 to 132, 512 to 528) at 1.5-1.7x the time per sample of the powers of
    two around them, a cost brute force need not pay."""
    powers = [p for p in points if p["spp"] & (p["spp"] - 1) == 0]
    chosen = powers if len(powers) >= 2 else points
    return [p["spp"] for p in chosen], [p["seconds"] for p in chosen]


def _curve(points, region: str, ref_noise) -> list[dict]:
    """One region's convergence curve; ``relmse_own``: the error minus the reference's noise
    (None where it cannot resolve it)."""
    return [{"spp": p["spp"], "seconds": p["seconds"], "relmse": p["relmse"][region],
             "relmse_own": ref_noise.own_error(p["relmse"][region]), "flip": p["flip"][region]} for p in points]


def summary_lines(result: dict, spp_multiscale: int, spp_bruteforce: int) -> list[str]:
    """The terminal's table of speed-ups and errors per region, with its footnotes: a region
    with too few pixels (:func:`few_pixels_warning`) is marked ``!`` and warned about."""
    lines = [f"{'region':8s} {'speed-up':>10s} {'MS relMSE':>10s} {'BF relMSE':>10s} {'MS FLIP':>8s} "
             f"{'BF FLIP':>8s}   (multi-scale {spp_multiscale} spp vs brute force {spp_bruteforce} spp "
             "at equal time)"]
    warnings_ = {g: few_pixels_warning(result["regions"]["pixels"][g]) for g in REGIONS}
    for g in REGIONS:
        r = result[g]
        bound = ">" if r.get("reference_limited") else " "
        lines.append(f"{g:8s}{bound}{r['speedup']:9.2f}x{'*' if r['extrapolated'] else ' '} "
                     f"{r['relmse_multiscale']:10.3g} "
                     f"{r['relmse_bruteforce']:10.3g} {r['flip_multiscale']:8.4f} {r['flip_bruteforce']:8.4f}"
                     + ("  !" if warnings_[g] else ""))
    if any(result[g]["extrapolated"] for g in REGIONS):
        lines.append("* extrapolated beyond brute force's measured curve (its last slope, at least error ~ 1/time)")
    if any(result[g].get("reference_limited") for g in REGIONS):
        lines.append("> a lower bound: multi-scale's error is within the reference's own noise "
                     "(render a reference of more samples, --reference-spp)")
    lines += [f"! warning: {g}: {text}" for g, text in warnings_.items() if text]
    return lines


def run_compare(name: str, width: int, height: int, budget: float = 60.0, reference_spp: int = 1024,
                out_dir: Path | None = None, json_path: Path | None = None, spp_multiscale: int = 16,
                quiet: bool = False, sampler: str | None = None) -> dict:
    """Run the whole comparison; write the report (and JSON); return the JSON dictionary.
    ``sampler``: both methods' pixel sampler (default: the scene's own,
    :data:`.scenes.pixel_sampler.DEFAULT_PIXEL_SAMPLER`)."""
    from ..scenes.builtin import SCENES
    from ..scenes.pixel_sampler import DEFAULT_PIXEL_SAMPLER

    if name not in SCENES:
        raise ClothError(f"unknown scene {name!r}: expected one of {', '.join(SCENES)}")
    if not (isinstance(budget, (int, float)) and math.isfinite(budget) and budget > 0):
        raise ClothError(f"--budget must be a positive number of seconds, got {budget}")
    if reference_spp < 2 or reference_spp % 2:
        raise ClothError(f"--reference-spp must be an even number >= 2, got {reference_spp}")
    if spp_multiscale < 1:
        raise ClothError(f"multi-scale spp must be >= 1, got {spp_multiscale}")
    check_evaluation_extra()
    out_dir = Path(out_dir) if out_dir is not None else Path("out") / f"compare-{name}"
    check_writable(out_dir)
    if json_path is not None:
        json_path = Path(json_path)
        if json_path.is_dir():
            raise ClothError(f"--json {json_path} is a directory; name a file")
        check_writable(json_path.parent)

    variant = setup_mitsuba()
    from ..loading import load_dict

    say = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    say(f"mscloth compare: {name}, {width}x{height}, budget {budget:g} s, reference {reference_spp} spp, "
        f"sampler {sampler or DEFAULT_PIXEL_SAMPLER}, variant {variant}")
    started = time.perf_counter()

    depth, cloth = depth_and_cloth(name, width, height)
    masks, region_info = region_masks(depth, cloth)
    say("regions (" + region_info["method"] + "): " + ", ".join(f"{g} {int(masks[g].sum())} px" for g in REGIONS)
        + f" of {width * height}")

    ref, ref_var, cached = reference_image(name, width, height, reference_spp, quiet=quiet)
    ref_noise_map = (ref_var / (ref.astype(np.float64) ** 2 + RELMSE_EPS)).mean(axis=-1)
    noise = {g: ReferenceNoise.of_region(ref_noise_map, masks[g]) for g in REGIONS}

    def evaluate(image):
        rel = relmse_map(image, ref)
        flip = flip_map(image, ref)
        return {"relmse": {g: float(rel[masks[g]].mean()) for g in REGIONS},
                "flip": {g: float(flip[masks[g]].mean()) for g in REGIONS}}

    say(f"multi-scale: 1 .. {spp_multiscale} spp, at most {budget / 2:g} s")
    scene = load_dict(scene_dict(name, width, height, multiscale=True, sampler=sampler))
    points_ms = convergence_curve(scene, "multi-scale", MULTISCALE_SEED, spp_multiscale, budget / 2, evaluate,
                                  quiet=quiet)
    del scene
    gc.collect()
    bf_budget = budget - sum(p["seconds"] for p in points_ms)
    bf_max = max(2, reference_spp // 4)
    say(f"brute force: 1 .. {bf_max} spp, at most {max(bf_budget, 0):.3g} s")
    scene = load_dict(scene_dict(name, width, height, multiscale=False, sampler=sampler))
    points_bf = convergence_curve(scene, "brute force", BRUTEFORCE_SEED, bf_max, bf_budget, evaluate, quiet=quiet)
    del scene
    gc.collect()

    regions, ms_index, bf_index = region_figures(points_ms, points_bf, spp_multiscale, noise)
    result = {
        "scene": name,
        "resolution": [width, height],
        "reference_spp": reference_spp,
        "reference_cached": cached,
        "budget_seconds": budget,
        "sampler": sampler or DEFAULT_PIXEL_SAMPLER,
        "variant": variant,
        "mscloth_version": __version__,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        **regions,
        "regions": {"method": region_info["method"], "distance_thresholds": region_info["thresholds"],
                    "pixels_used": "the same cloth shape at the pixel centre and its 8 neighbours' (no edges)",
                    "pixels": {g: int(masks[g].sum()) for g in REGIONS}, "cloth_pixels": int(cloth.sum()),
                    "min_pixels": MIN_REGION_PIXELS,
                    "warnings": {g: few_pixels_warning(int(masks[g].sum())) for g in REGIONS}},
        "metrics": {
            "relmse": f"mean over region pixels and RGB of (img-ref)^2/(ref^2+{RELMSE_EPS:g})",
            "flip": "flip_evaluator LDR-FLIP of sRGB-encoded images clipped to [0,1], mean over region pixels",
            "seconds": "wall time of one mi.render at that spp minus Dr.Jit kernel compilation",
            "speedup": "brute-force seconds at the spp it needs to reach multi-scale's own relMSE (relMSE minus "
                       "the reference's noise), read off its own-relMSE-vs-spp curve (log-log interpolation; beyond "
                       "it, its last slope or -1, whichever is steeper) and priced linearly between its renders at "
                       "powers of two / multi-scale seconds",
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
        from ..atomic import atomic_write

        text = json.dumps(result, indent=2, allow_nan=False) + "\n"
        atomic_write(json_path, lambda f: f.write(text.encode()))
    result["elapsed_seconds"] = time.perf_counter() - started
    if not quiet:
        print("\n".join(summary_lines(result, points_ms[ms_index]["spp"], points_bf[bf_index]["spp"])))
        print(f"wrote {report}" + (f" and {json_path}" if json_path else "")
              + f" in {result['elapsed_seconds']:.1f} s")
    return result
