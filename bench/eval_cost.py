"""Time of one BSDF call of a scene's cloth, kernel by kernel, without the renderer around it:
``eval_pdf_sample_n`` (a sun's and a sky's direction and a sample, as ``clothpath`` calls it)
and one ``eval_pdf``, on lanes of pixel footprints laid out as a render's (rows of pixels a
footprint apart, a fixed spread of sizes and shears, random directions), multi-scale against brute force (the same
cloth with ``multiscale`` false) in interleaved rounds. A render's time per sample mixes in
tracing, the film and the integrator, and its rounds spread by 10-30% on this machine; the
kernels' own times (Dr.Jit's kernel history) spread by a few %, so pieces of the estimator
(visibility, residual texels, a second box) can be priced one against another.

    .venv/bin/python bench/eval_cost.py satin-plane --variant "no vis: --set visibility=false"

``--texels A,B`` sets the footprints' side lengths in texels (log-uniform between A and B).
"""
from __future__ import annotations

import argparse
import sys
import time

import drjit as dr
import numpy as np

from common import set_class_attributes, setup_mitsuba
from region_terms import parse_variant


def cloth_dict(scene: str) -> dict:
    """The ``cloth`` BSDF dictionary of a built-in scene's first cloth shape."""
    from mscloth.evaluation.regions import cloth_shape_keys
    from mscloth.scenes.builtin import SCENES
    scene_dict = SCENES[scene](64, 36)
    keys = cloth_shape_keys(scene_dict)
    for key, value in scene_dict.items():  # the first in the scene's order
        if key in keys:
            return dict(value["bsdf"])
    raise SystemExit(f"eval_cost.py: scene '{scene}' has no cloth shape")


def lanes(mi, n: int, side: tuple, tile: float, seed: int, spp: int = 16, width: int = 256):
    """``n`` lanes laid out as a render lays them: rows of ``width`` pixels of ``spp``
    samples each, neighbouring pixels a footprint apart in uv (so neighbouring lanes read
    neighbouring texels). Each row has one footprint: sides log-uniform in ``side`` texels
    (a tile of ``tile`` texels), a long edge 1-4x the short one (a grazing view), any turn;
    one view direction (down to grazing) and one sun direction; a second direction per lane
    over the sphere (the sky's sample) and the BSDF sample's random numbers."""
    rng = np.random.default_rng(seed)
    rows = -(-n // (width * spp))
    n = rows * width * spp
    row = np.arange(n) // (width * spp)
    pixel = (np.arange(n) // spp) % width
    a = np.exp(rng.uniform(np.log(side[0]), np.log(side[1]), rows)) / tile
    b = a * rng.uniform(1.0, 4.0, rows)
    turn = rng.uniform(0.0, np.pi, rows)
    c, s = np.cos(turn), np.sin(turn)
    dx = np.stack([a * c, a * s])[:, row]
    dy = np.stack([-b * s, b * c])[:, row]
    start = rng.random((2, rows))[:, row]
    jitter = rng.random((2, n)) - 0.5
    uv = start + dx * (pixel + jitter[0]) + dy * jitter[1]

    def direction(cos_lo, rows_only):
        m = rows if rows_only else n
        cos_t = rng.uniform(cos_lo, 1.0, m)
        phi = rng.uniform(0.0, 2 * np.pi, m)
        sin_t = np.sqrt(1 - cos_t ** 2)
        v = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t])
        return v[:, row] if rows_only else v

    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.uv = mi.Point2f(*(uv % 1.0))
    si.duv_dx = mi.Vector2f(*dx)
    si.duv_dy = mi.Vector2f(*dy)
    si.wi = mi.Vector3f(*direction(0.1, True))
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    sun = mi.Vector3f(*direction(0.1, True))
    sky = mi.warp.square_to_uniform_sphere(mi.Point2f(*rng.random((2, n))))
    return si, [sun, sky], mi.Float(rng.random(n)), mi.Point2f(*rng.random((2, n)))


def kernel_seconds(run) -> float:
    """Seconds the kernels launched by ``run()`` executed (Dr.Jit's kernel history)."""
    dr.kernel_history()  # clear
    run()
    dr.sync_thread()
    return sum(k.get("execution_time", 0.0) for k in dr.kernel_history()) * 1e-3


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--variant", action="append", default=[],
                        help="'LABEL: --attr NAME=VALUE --set NAME=VALUE ...'")
    parser.add_argument("--lanes", type=int, default=1 << 20)
    parser.add_argument("--texels", default="8,512", help="footprint sides in texels, 'MIN,MAX'")
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args(argv)
    mi = setup_mitsuba()

    side = tuple(float(v) for v in args.texels.split(","))
    base = cloth_dict(args.scene)
    variants = [("multi-scale", {}, {}), ("brute force", {}, {"multiscale": False})]
    variants += [parse_variant(v) for v in args.variant]
    ctx = mi.BSDFContext()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    setups = []
    for label, attrs, params in variants:
        saved = set_class_attributes(attrs)
        try:
            bsdf = mi.load_dict({**base, **params})
        finally:
            set_class_attributes(saved)
        # Texels per unit of uv along u: the tile's width times the cloth's uv_scale (without
        # it, a finely tiled cloth's footprints came out uv_scale times too large a side).
        tile = (float(np.array(bsdf.fibre.tile.width.f).ravel()[0])
                * float(np.array(bsdf.fibre.params.uv_scale).ravel()[0]))
        si, wo, s1, s2 = lanes(mi, args.lanes, side, tile, seed=5)
        dr.eval(si, wo, s1, s2)
        setups.append((label, attrs, bsdf, si, wo, s1, s2))

    def timing(attrs, bsdf, si, wo, s1, s2):
        saved = set_class_attributes(attrs)
        try:
            both = kernel_seconds(lambda: dr.eval(bsdf.eval_pdf_sample_n(ctx, si, wo, s1, s2)))
            ev = kernel_seconds(lambda: dr.eval(bsdf.eval_pdf(ctx, si, wo[0])))
        finally:
            set_class_attributes(saved)
        return both, ev

    for entry in setups:  # compile
        timing(*entry[1:])
    results = {label: [] for label, *_ in setups}
    t0 = time.perf_counter()
    for r in range(args.rounds):
        for label, *rest in setups:
            results[label].append(timing(*rest))
        print(f"round {r + 1}/{args.rounds} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    bf = np.array(results["brute force"])
    print(f"| {args.scene} cloth, {args.lanes} lanes, footprints {side[0]:g}-{side[1]:g} texels "
          f"| two directions and a sample, ms | / brute force (median, range) | one eval_pdf, ms | / brute force |")
    print("|---|---|---|---|---|")
    for label, values in results.items():
        v = np.array(values)
        cells = []
        for j in range(2):
            ratio = v[:, j] / bf[:, j]
            cells.append(f"{1e3 * np.median(v[:, j]):.1f} | {np.median(ratio):.2f}x "
                         f"({ratio.min():.2f}-{ratio.max():.2f})")
        print(f"| {label} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
