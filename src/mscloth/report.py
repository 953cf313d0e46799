"""The HTML report of ``mscloth compare``: images, insets, heat maps, convergence plots, a table.

Every file is written atomically (temporary file + rename) and ``report.html`` last, so a
reader never sees a half-written page, and never one that names an image not yet there.
All images are files beside ``report.html``, referenced relatively.
"""
from __future__ import annotations

import html
import io
import time
from pathlib import Path

import numpy as np

from .atomic import atomic_path, atomic_write
from .compare import REGIONS, relmse_map, to_srgb8

REGION_COLOURS = {"near": (0.90, 0.25, 0.20), "middle": (0.20, 0.75, 0.30), "far": (0.25, 0.45, 0.95)}
METHOD_LABELS = {"reference": "reference (brute force)", "multiscale": "multi-scale",
                 "bruteforce": "brute force, equal time"}


def _save_png(path: Path, rgb01: np.ndarray) -> None:
    from PIL import Image

    data = np.clip(np.rint(np.asarray(rgb01) * 255.0), 0, 255).astype(np.uint8)
    with atomic_path(path) as tmp:
        Image.fromarray(data).save(tmp, format="PNG")


def _save_figure(path: Path, figure) -> None:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=100)
    atomic_write(path, lambda f: f.write(buffer.getvalue()))


def upscale_nearest(img: np.ndarray, factor: int) -> np.ndarray:
    """Each pixel repeated ``factor`` times along both axes."""
    return np.repeat(np.repeat(img, factor, axis=0), factor, axis=1)


def inset_box(mask: np.ndarray) -> tuple[int, int, int]:
    """(y0, x0, side) of a square crop around a region: its size, capped at a third of the image."""
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    extent = max(ys.max() - ys.min() + 1, xs.max() - xs.min() + 1) + 4
    side = int(min(h, w, max(8, min(extent, max(16, min(h, w) // 3)))))
    cy, cx = np.median(ys), np.median(xs)
    k = int(np.argmin((ys - cy) ** 2 + (xs - cx) ** 2))  # a region pixel near its middle
    y0 = int(np.clip(ys[k] - side // 2, 0, h - side))
    x0 = int(np.clip(xs[k] - side // 2, 0, w - side))
    return y0, x0, side


def _heat_maps(out: Path, images: dict, files: dict, cloth: np.ndarray) -> dict:
    from matplotlib import colormaps
    from matplotlib.colors import LogNorm
    from matplotlib.figure import Figure

    ref = images["reference"]
    maps = {m: relmse_map(images[m], ref) for m in ("multiscale", "bruteforce")}
    values = np.concatenate([v[cloth] for v in maps.values()])  # the scale fits the cloth's errors
    positive = values[values > 0]
    if positive.size:
        vmin, vmax = np.percentile(positive, [2.0, 99.5])
    else:
        vmin, vmax = 1e-6, 1.0
    vmax = max(vmax, vmin * 10)
    norm = LogNorm(vmin=vmin, vmax=vmax, clip=True)
    cmap = colormaps["inferno"]
    for method, err in maps.items():
        rgba = cmap(norm(np.maximum(err, vmin)))
        _save_png(out / f"heat_{method}.png", rgba[..., :3])
        files[f"heat_{method}"] = f"heat_{method}.png"
    figure = Figure(figsize=(6.0, 0.9))
    axis = figure.add_axes([0.05, 0.5, 0.9, 0.3])
    from matplotlib.cm import ScalarMappable

    figure.colorbar(ScalarMappable(norm=norm, cmap=cmap), cax=axis, orientation="horizontal",
                    label="per-pixel relative squared error (img-ref)^2/(ref^2+0.01)")
    _save_figure(out / "heat_colorbar.png", figure)
    files["heat_colorbar"] = "heat_colorbar.png"
    return files


def _convergence_plot(out: Path, result: dict) -> str:
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter

    figure = Figure(figsize=(13.5, 7.5), layout="constrained")
    axes = figure.subplots(2, 3, squeeze=False)
    for col, g in enumerate(REGIONS):
        r = result[g]
        for row, metric in enumerate(("relmse", "flip")):
            ax = axes[row][col]
            for key, label, style in (("curve_bruteforce", "brute force", "o-"),
                                      ("curve_multiscale", "multi-scale", "s-")):
                curve = r[key]
                ax.plot([p["seconds"] for p in curve], [p[metric] for p in curve], style, label=label, ms=4)
                for p in curve:
                    ax.annotate(str(p["spp"]), (p["seconds"], p[metric]), textcoords="offset points",
                                xytext=(3, 3), fontsize=6, alpha=0.7)
            ax.plot([r["seconds_multiscale"]], [r[f"{metric}_multiscale"]], "*", ms=14, color="C1",
                    label=f"multi-scale, {r['spp_multiscale']} spp")
            if metric == "relmse":
                target = r["relmse_multiscale"]
                ax.axhline(target, color="C1", ls="--", lw=0.8)
                ax.plot([r["seconds_bruteforce_equal_error"]], [target], "D", ms=7,
                        mfc="none" if r["extrapolated"] else "C0", mec="C0",
                        label="brute force, equal error" + (" (extrapolated)" if r["extrapolated"] else ""))
                if r["relmse_reference"] > 0:
                    ax.axhline(r["relmse_reference"], color="grey", ls=":", lw=0.8, label="reference noise")
                ax.set_title(f"{g}: speed-up {r['speedup']:.2f}x" + (" (extrapolated)" if r["extrapolated"] else ""))
            values = [p[metric] for k in ("curve_bruteforce", "curve_multiscale") for p in r[k]]
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(NullFormatter())
            if min(values) > 0:
                ax.set_yscale("log")
            ax.set_xlabel("seconds (without kernel compilation)")
            ax.set_ylabel("relMSE" if metric == "relmse" else "FLIP (LDR)")
            ax.grid(True, which="both", alpha=0.3)
            if col == 0:
                ax.legend(fontsize=7)
    _save_figure(out / "convergence.png", figure)
    return "convergence.png"


def _fmt(value, digits=3) -> str:
    return f"{value:.{digits}g}"


def write_report(out_dir, result: dict, images: dict, masks: dict, depth: np.ndarray) -> Path:
    """Write ``out_dir/report.html`` and its images; return the HTML's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    srgb = {m: to_srgb8(images[m]) for m in ("reference", "multiscale", "bruteforce")}
    for method, img in srgb.items():
        _save_png(out / f"{method}.png", img)
        files[method] = f"{method}.png"

    # Regions: reference dimmed, each region tinted, inset boxes outlined.
    overlay = 0.35 * srgb["reference"]
    boxes = {}
    for g in REGIONS:
        colour = np.array(REGION_COLOURS[g])
        overlay[masks[g]] = 0.45 * srgb["reference"][masks[g]] + 0.55 * colour
        boxes[g] = inset_box(masks[g])
    for g, (y0, x0, side) in boxes.items():
        colour = np.array(REGION_COLOURS[g])
        overlay[y0, x0:x0 + side] = overlay[y0 + side - 1, x0:x0 + side] = colour
        overlay[y0:y0 + side, x0] = overlay[y0:y0 + side, x0 + side - 1] = colour
    _save_png(out / "regions.png", overlay)
    files["regions"] = "regions.png"

    for g, (y0, x0, side) in boxes.items():
        factor = max(1, 256 // side)
        for method, img in srgb.items():
            name = f"inset_{g}_{method}.png"
            _save_png(out / name, upscale_nearest(img[y0:y0 + side, x0:x0 + side], factor))
            files[name] = name

    _heat_maps(out, images, files, np.logical_or.reduce([masks[g] for g in REGIONS]))
    files["convergence"] = _convergence_plot(out, result)

    h, w = images["reference"].shape[:2]
    display_w = max(w, min(480, 4 * w))
    esc = html.escape

    def img_tag(name, alt, width=None):
        width = f' width="{width}"' if width else ""
        return f'<img src="{esc(files[name])}" alt="{esc(alt)}"{width}>'

    rows = []
    for g in REGIONS:
        r = result[g]
        rows.append(
            "<tr>" + "".join(f"<td>{c}</td>" for c in (
                f'<span class="swatch" style="background:rgb{tuple(int(255 * c) for c in REGION_COLOURS[g])}"></span>{g}',
                result["regions"]["pixels"][g],
                f"<b>{r['speedup']:.2f}x</b>" + (" (extrapolated)" if r["extrapolated"] else ""),
                r["spp_multiscale"], _fmt(r["seconds_multiscale"]), _fmt(r["relmse_multiscale"]),
                _fmt(r["flip_multiscale"]),
                r["spp_bruteforce"], _fmt(r["seconds_bruteforce"]), _fmt(r["relmse_bruteforce"]),
                _fmt(r["flip_bruteforce"]),
                _fmt(r["seconds_bruteforce_equal_error"]), f"{r['spp_bruteforce_equal_error']:.0f}",
                f"{_fmt(r['relmse_bruteforce_equal_spp'])} ({r['spp_bruteforce_equal_spp']} spp)",
                _fmt(r["relmse_reference"]))) + "</tr>")
    thresholds = result["regions"]["distance_thresholds"]
    metrics = result["metrics"]
    side_by_side = "".join(
        f"<figure>{img_tag(m, METHOD_LABELS[m], display_w)}<figcaption>{esc(METHOD_LABELS[m])}"
        + (f", {result[REGIONS[0]]['spp_multiscale']} spp" if m == "multiscale" else "")
        + (f", {result[REGIONS[0]]['spp_bruteforce']} spp" if m == "bruteforce" else "")
        + (f", {result['reference_spp']} spp" if m == "reference" else "")
        + "</figcaption></figure>" for m in ("reference", "multiscale", "bruteforce"))
    insets = "".join(
        "<tr><th>" + esc(g) + "</th>" + "".join(
            f"<td>{img_tag(f'inset_{g}_{m}.png', f'{g}: {METHOD_LABELS[m]}')}</td>"
            for m in ("reference", "multiscale", "bruteforce")) + "</tr>" for g in REGIONS)
    page = f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>mscloth compare: {esc(result['scene'])}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; color: #222; }}
img {{ image-rendering: pixelated; }}
figure {{ display: inline-block; margin: 0 1em 1em 0; vertical-align: top; }}
table {{ border-collapse: collapse; }}
td, th {{ border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: right; }}
.swatch {{ display: inline-block; width: 0.8em; height: 0.8em; margin-right: 0.3em; }}
.insets td, .insets th {{ text-align: center; }}
.note {{ color: #555; font-size: 0.9em; max-width: 60em; }}
</style>
</head>
<body>
<h1>Multi-scale vs brute-force cloth: <code>{esc(result['scene'])}</code></h1>
<p class="note">{w}x{h} pixels; reference: brute force, {result['reference_spp']} spp; budget
{result['budget_seconds']:g} s; Mitsuba variant <code>{esc(result['variant'])}</code>;
mscloth {esc(result['mscloth_version'])}; {esc(result['machine'])}; {time.strftime('%Y-%m-%d %H:%M')}.</p>

<h2>Figures per region</h2>
<table>
<tr><th>region</th><th>pixels</th><th>speed-up at equal error</th>
<th>MS spp</th><th>MS s</th><th>MS relMSE</th><th>MS FLIP</th>
<th>BF spp (equal time)</th><th>BF s</th><th>BF relMSE</th><th>BF FLIP</th>
<th>BF s to MS error</th><th>BF spp to MS error</th><th>BF relMSE at MS spp</th>
<th>reference noise relMSE</th></tr>
{''.join(rows)}
</table>
<p class="note">MS = multi-scale <code>cloth</code>, BF = brute force (the same scene with
<code>"multiscale": false</code>: fibre-level shading, supersampled). relMSE: {esc(metrics['relmse'])}.
FLIP: {esc(metrics['flip'])}. Seconds: {esc(metrics['seconds'])}. Speed-up: {esc(metrics['speedup'])}.
Regions: pixels whose centre and 8 neighbours' centres see the same cloth shape (pixels on
silhouettes and seams carry the edge's anti-aliasing noise, the same for both methods), split by camera
distance ({esc(result['regions']['method'])};
thresholds {thresholds[0]:.3g} and {thresholds[1]:.3g} scene units).
Kernel compilation (excluded): multi-scale {result['compile_seconds']['multiscale']:.1f} s,
brute force {result['compile_seconds']['bruteforce']:.1f} s.</p>

<h2>Images</h2>
{side_by_side}
<figure>{img_tag('regions', 'regions', display_w)}<figcaption>regions: near (red), middle (green),
far (blue), boxes: the insets</figcaption></figure>

<h2>Insets (nearest-neighbour zoom)</h2>
<table class="insets">
<tr><th></th><th>reference</th><th>multi-scale</th><th>brute force, equal time</th></tr>
{insets}
</table>

<h2>Error heat maps</h2>
<figure>{img_tag('heat_multiscale', 'multi-scale error', display_w)}<figcaption>multi-scale</figcaption></figure>
<figure>{img_tag('heat_bruteforce', 'brute-force error', display_w)}<figcaption>brute force, equal time</figcaption></figure>
<br>{img_tag('heat_colorbar', 'colour scale')}

<h2>Convergence</h2>
{img_tag('convergence', 'error vs seconds, per region')}
<p class="note">Log-log error against render seconds; numbers next to the points are spp.
Star: the multi-scale image in the table; diamond: where brute force reaches its relMSE
(hollow: extrapolated with error ~ 1/time).</p>
</body>
</html>
"""
    report = out / "report.html"
    atomic_write(report, lambda f: f.write(page.encode("utf-8")))
    return report
