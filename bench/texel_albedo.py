"""How a sky control variate's albedo table would have to be sampled (performance log L59):
the fibre-level BSDF's non-delta directional albedo A_t(wi) (the mean sample weight f |cos|
/ pdf) at texels of a built-in scene's cloth, by incident direction. Per direction: the
mean over the texels, their spread (what a footprint's A averages away and a texel's keeps)
and the error of reading A linearly between directions ``--step`` degrees apart in theta
(what a table of that spacing would cost in bias).

    .venv/bin/python bench/texel_albedo.py --scene plane --step 15
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from common import setup_mitsuba


def albedos(bsdf, tile: int, uvs: np.ndarray, wi, samples: int, seed: int) -> np.ndarray:
    """(texels, 3) mean sample weights at the texel centres ``uvs`` for direction ``wi``."""
    import mitsuba as mi

    from mscloth.validation import non_delta_context, sheared_interaction

    m = len(uvs)
    n = m * samples
    si = sheared_interaction(n, [0.5, 0.5], 0.0, 0.0, tile, wi)
    si.uv = mi.Point2f(np.repeat(uvs[:, 0], samples), np.repeat(uvs[:, 1], samples))
    rng = np.random.default_rng(seed)
    si.p = mi.Point3f(*(rng.uniform(0, 1, (3, n))))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    bs, w = bsdf.sample(non_delta_context(), si, sampler.next_1d(), sampler.next_2d())
    w = np.where(np.asarray(bs.pdf) > 0, np.asarray(w), 0.0)  # (3, n)
    return w.reshape(3, m, samples).mean(axis=2).T


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="plane", help="the built-in scene whose first cloth is measured")
    parser.add_argument("--texels", type=int, default=48)
    parser.add_argument("--samples", type=int, default=8192, help="sample weights per texel and direction")
    parser.add_argument("--step", type=float, default=15.0, help="the theta spacing of the table tried, degrees")
    args = parser.parse_args(argv)
    mi = setup_mitsuba()
    from eval_cost import cloth_dict

    spec = dict(cloth_dict(args.scene), uv_scale=1.0, multiscale=False)
    spec.pop("uv_scale_v", None)
    bsdf = mi.load_dict(spec)
    tile = bsdf.maps.resolution[1]
    rng = np.random.default_rng(1)
    uvs = (np.floor(rng.random((args.texels, 2)) * tile) + 0.5) / tile
    print(f"{args.scene}: {args.texels} texels of a {tile}-texel tile, {args.samples} samples each")
    print("| side | azimuth | theta | mean A (luminance) | spread between texels | "
          f"error read between {args.step:g} degrees |")
    print("|---|---|---|---|---|---|")
    lum = np.array([0.2126, 0.7152, 0.0722])
    for side in (1.0, -1.0):
        for phi in (0.0, 45.0, 90.0):
            thetas = np.arange(0.0, 85.0 + 1e-6, args.step / 2)
            a = []
            for k, theta in enumerate(thetas):
                t, p = np.radians(theta), np.radians(phi)
                wi = [float(np.sin(t) * np.cos(p)), float(np.sin(t) * np.sin(p)), side * float(np.cos(t))]
                a.append(albedos(bsdf, tile, uvs, wi, args.samples, 100 + k) @ lum)
            a = np.array(a)  # (thetas, texels)
            for k, theta in enumerate(thetas):
                mean = a[k].mean()
                spread = a[k].std() / max(mean, 1e-9)
                between = ""
                if k % 2 and k + 1 < len(thetas):  # halfway between two table directions
                    lerp = 0.5 * (a[k - 1] + a[k + 1])
                    between = f"{np.abs(lerp.mean() - mean) / max(mean, 1e-9):.2%} (footprint), " \
                              f"{np.sqrt(np.mean((lerp - a[k]) ** 2)) / max(mean, 1e-9):.2%} (texel RMS)"
                print(f"| {'front' if side > 0 else 'back'} | {phi:g} | {theta:g} | {mean:.4f} | {spread:.1%} | "
                      f"{between} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
