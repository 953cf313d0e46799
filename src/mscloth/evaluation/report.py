"""The HTML report of ``mscloth compare``: images, insets, heat maps, convergence plots, a table.

Every file is written atomically (temporary file + rename) and ``report.html`` last, so a
reader never sees a half-written page, and never one that names an image not yet there.
All images are files beside ``report.html``, referenced relatively.
"""
from __future__ import annotations

import html
import io
import math
import time
from pathlib import Path

import numpy as np

from ..atomic import atomic_path, atomic_write
from .metrics import relmse_map, to_srgb8
from .regions import REGIONS
from .speedup import MIN_REGION_PIXELS, few_pixels_warning, speedup_relative_error

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
    figure.savefig(buffer, format="png", dpi=FIGURE_DPI)
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


#: Resolution of the plots (pixels per inch of figsize).
FIGURE_DPI = 100
#: Width of the convergence figure in pixels: inside a 1200-pixel-wide window less the
#: page's margins, so it is shown at its own size there (the page scales it down in narrower
#: ones, see ``img`` in the style sheet).
CONVERGENCE_WIDTH_PX = 1100
#: Height of one row of panels (one region: relMSE and FLIP side by side), in pixels.
CONVERGENCE_ROW_PX = 340


def _tick_label(value, _position=None) -> str:
    return f"{value:.3g}"


#: Rank of each mantissa of log-axis ticks, roundest first (see :func:`log_ticks`).
_MANTISSA_RANK = {1: 0, 2: 1, 5: 1, 3: 2, 4: 2, 6: 3, 7: 3, 8: 3, 9: 3}
#: Labelled ticks on a log axis stay at least this fraction of its span apart (at most ~7).
_TICK_SPACING = 1.0 / 6.0


def log_ticks(lo: float, hi: float) -> list[float]:
    """Major ticks for a log axis showing [lo, hi] (0 < lo < hi), however short the span.

    Matplotlib labels the powers of ten, and an axis spanning less than a decade may hold
    none. Here: every m x 10^k (m = 1..9) inside, taken roundest first (1, then 2 and 5, then
    the rest) while it stays :data:`_TICK_SPACING` of the span (in log) from those taken; when
    that gives fewer than three, round numbers in linear steps if they give more (a span
    of less than a mantissa step)."""
    from matplotlib.ticker import MaxNLocator

    lo, hi = min(lo, hi), max(lo, hi)
    span = math.log10(hi / lo)
    candidates = []
    for k in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1):
        candidates += [(rank, m * 10.0 ** k) for m, rank in _MANTISSA_RANK.items()
                       if lo * (1 - 1e-9) <= m * 10.0 ** k <= hi * (1 + 1e-9)]
    taken = []
    for _, t in sorted(candidates):
        if all(abs(math.log10(t / u)) >= _TICK_SPACING * span for u in taken):
            taken.append(t)
    if len(taken) < 3:
        linear = [t for t in MaxNLocator(nbins=4).tick_values(lo, hi) if lo <= t <= hi and t > 0]
        if len(linear) > len(taken):
            taken = linear
    return sorted(taken)


def label_log_axis(axis, lo: float, hi: float) -> None:
    """Labelled major ticks (:func:`log_ticks`) on a log ``axis`` showing [lo, hi]; minor
    ticks stay, unlabelled."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter

    axis.set_major_locator(FixedLocator(log_ticks(lo, hi)))
    axis.set_major_formatter(FuncFormatter(_tick_label))
    axis.set_minor_locator(LogLocator(base=10.0, subs="auto", numticks=10))
    axis.set_minor_formatter(NullFormatter())


def convergence_figure(result: dict):
    """Error against seconds, per region: one row per region, relMSE left and FLIP right (a
    row of six panels did not fit a browser window). Log axes with labelled ticks
    (:func:`label_log_axis`); a region with too few pixels says so in red in its title."""
    from matplotlib.figure import Figure

    rows, cols = len(REGIONS), 2
    figure = Figure(figsize=(CONVERGENCE_WIDTH_PX / FIGURE_DPI, rows * CONVERGENCE_ROW_PX / FIGURE_DPI),
                    dpi=FIGURE_DPI, layout="constrained")
    axes = figure.subplots(rows, cols, squeeze=False)
    for row, g in enumerate(REGIONS):
        r = result[g]
        warning = few_pixels_warning(result["regions"]["pixels"][g])
        for col, metric in enumerate(("relmse", "flip")):
            ax = axes[row][col]
            for key, label, style in (("curve_bruteforce", "brute force", "o-"),
                                      ("curve_multiscale", "multi-scale", "s-")):
                curve = r[key]
                ax.plot([p["seconds"] for p in curve], [p[metric] for p in curve], style, label=label, ms=4)
                for p in curve:
                    ax.annotate(str(p["spp"]), (p["seconds"], p[metric]), textcoords="offset points",
                                xytext=(3, 3), fontsize=7, alpha=0.7)
            ax.plot([r["seconds_multiscale"]], [r[f"{metric}_multiscale"]], "*", ms=14, color="C1",
                    label=f"multi-scale, {r['spp_multiscale']} spp")
            title = f"{g}: " + ("relMSE" if metric == "relmse" else "FLIP")
            if metric == "relmse":
                # The speed-up compares own errors (relMSE minus the reference's noise): dotted.
                for key, colour in (("curve_bruteforce", "C0"), ("curve_multiscale", "C1")):
                    own = [(p["seconds"], p["relmse_own"]) for p in r[key] if p.get("relmse_own")]
                    if own:
                        ax.plot(*zip(*own), ":", color=colour, lw=1.0,
                                label="own error (minus reference noise)" if colour == "C0" else None)
                target = r.get("relmse_multiscale_own", r["relmse_multiscale"])
                ax.axhline(target, color="C1", ls="--", lw=0.8)
                ax.plot([r["seconds_bruteforce_equal_error"]], [target], "D", ms=7,
                        mfc="none" if r["extrapolated"] else "C0", mec="C0",
                        label="brute force, equal error" + (" (extrapolated)" if r["extrapolated"] else ""))
                if r["relmse_reference"] > 0:
                    ax.axhline(r["relmse_reference"], color="grey", ls=":", lw=0.8, label="reference noise")
                title = (f"{g}: speed-up {'> ' if r.get('reference_limited') else ''}{r['speedup']:.2f}x"
                         + (" (extrapolated)" if r["extrapolated"] else ""))
            if warning:
                pixels = result["regions"]["pixels"][g]
                title += f"\n! too few pixels ({pixels}): about \u00b1{100 * speedup_relative_error(pixels):.0f} %"
            ax.set_title(title, fontsize=10, color="#b00000" if warning else "black")
            ax.set_xscale("log")
            values = [p[metric] for k in ("curve_bruteforce", "curve_multiscale") for p in r[k]]
            if min(values) > 0:
                ax.set_yscale("log")
            ax.set_xlabel("seconds (without kernel compilation)")
            ax.set_ylabel("relMSE" if metric == "relmse" else "FLIP (LDR)")
            ax.grid(True, which="both", alpha=0.3)
            if row == 0:
                ax.legend(fontsize=7)
    for ax in figure.axes:  # the limits are final once everything is plotted
        label_log_axis(ax.xaxis, *ax.get_xlim())
        if ax.get_yscale() == "log":
            label_log_axis(ax.yaxis, *ax.get_ylim())
    return figure


def _convergence_plot(out: Path, result: dict) -> str:
    _save_figure(out / "convergence.png", convergence_figure(result))
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

    def img_tag(name, alt, width=None, css_class=None):
        width = f' width="{width}"' if width else ""
        css_class = f' class="{css_class}"' if css_class else ""
        return f'<img src="{esc(files[name])}" alt="{esc(alt)}"{width}{css_class}>'

    rows = []
    for g in REGIONS:
        r = result[g]
        pixels = result["regions"]["pixels"][g]
        warning = few_pixels_warning(pixels)
        warning = (f'<br><span class="warning" title="{esc(warning)}">&#9888; too few pixels ({pixels} &lt; '
                   f'{MIN_REGION_PIXELS}): about &plusmn;{100 * speedup_relative_error(pixels):.0f} %</span>'
                   if warning else "")
        rows.append(
            "<tr>" + "".join(f"<td>{c}</td>" for c in (
                f'<span class="swatch" style="background:rgb{tuple(int(255 * c) for c in REGION_COLOURS[g])}"></span>{g}',
                result["regions"]["pixels"][g],
                f"<b>{'&gt; ' if r.get('reference_limited') else ''}{r['speedup']:.2f}x</b>"
                + (" (extrapolated)" if r["extrapolated"] else "")
                + f"<br><small>{r.get('speedup_uncorrected', r['speedup']):.2f}x uncorrected</small>" + warning,
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
img {{ image-rendering: pixelated; max-width: 100%; height: auto; }}
img.plot {{ image-rendering: auto; }}
.wide {{ max-width: 100%; overflow-x: auto; }}
.warning {{ color: #b00000; font-size: 0.85em; display: inline-block; max-width: 16em; text-align: left; }}
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
<div class="wide"><table>
<tr><th>region</th><th>pixels</th><th>speed-up at equal error</th>
<th>MS spp</th><th>MS s</th><th>MS relMSE</th><th>MS FLIP</th>
<th>BF spp (equal time)</th><th>BF s</th><th>BF relMSE</th><th>BF FLIP</th>
<th>BF s to MS own error</th><th>BF spp to MS own error</th><th>BF relMSE at MS spp</th>
<th>reference noise relMSE</th></tr>
{''.join(rows)}
</table></div>
<p class="note">MS = multi-scale <code>cloth</code>, BF = brute force (the same scene with
<code>"multiscale": false</code>: fibre-level shading, supersampled). relMSE: {esc(metrics['relmse'])}.
FLIP: {esc(metrics['flip'])}. Seconds: {esc(metrics['seconds'])}. Speed-up: {esc(metrics['speedup'])}.
Regions: pixels whose centre and 8 neighbours' centres see the same cloth shape (pixels on
silhouettes and seams carry the edge's anti-aliasing noise, the same for both methods), split by camera
distance ({esc(result['regions']['method'])};
thresholds {thresholds[0]:.3g} and {thresholds[1]:.3g} scene units). A region of fewer than
{MIN_REGION_PIXELS} pixels is flagged: its speed-up's relative standard error is about 2/sqrt(pixels).
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
<br>{img_tag('heat_colorbar', 'colour scale', css_class='plot')}

<h2>Convergence</h2>
{img_tag('convergence', 'error vs seconds, per region', css_class='plot')}
<p class="note">Log-log error against render seconds, one row per region; numbers next to the points are spp.
Star: the multi-scale image in the table. Dotted: each method's own error, relMSE minus the
reference's noise (grey line), which the speed-up compares; dashed: multi-scale's own error;
diamond: where brute force's own error reaches it (hollow: extrapolated with its last slope, at least
error ~ 1/time). "&gt;": multi-scale's error is within the reference's noise, the speed-up a lower
bound. "uncorrected": the speed-up on relMSE against the reference as it is.</p>
</body>
</html>
"""
    report = out / "report.html"
    atomic_write(report, lambda f: f.write(page.encode("utf-8")))
    return report
