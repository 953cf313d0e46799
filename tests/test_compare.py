"""`mscloth compare`: metrics, regions, speed-up interpolation, reference cache, the report."""
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import mscloth
from mscloth.errors import ClothError
from mscloth.evaluation import compare, references, speedup
from mscloth.evaluation.metrics import relmse
from mscloth.evaluation.references import ReferenceCacheWarning, reference_image, reference_path
from mscloth.evaluation.regions import REGIONS, region_masks
from mscloth.evaluation.speedup import ReferenceNoise, closest_in_time, equal_error_time, time_at

mscloth.register()

RESULT_KEYS = ("speedup", "relmse_multiscale", "relmse_bruteforce", "spp_multiscale", "spp_bruteforce",
               "seconds_multiscale", "seconds_bruteforce", "flip_multiscale", "flip_bruteforce")


def run_cli(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "mscloth", *args], capture_output=True, text=True, timeout=timeout)


# ----------------------------------------------------------------------------- metrics, regions

def test_relmse_known_values_and_mask():
    ref = np.ones((4, 6, 3))
    ref[:, 3:] = 0.0  # right half black
    img = ref + 0.1
    mask = np.zeros((4, 6), dtype=bool)
    mask[:, :3] = True
    # (0.1)^2 / (1 + 0.01) on the left, (0.1)^2 / (0 + 0.01) = 1 on the right
    assert relmse(img, ref, mask) == pytest.approx(0.01 / 1.01, rel=1e-12)
    assert relmse(img, ref, ~mask) == pytest.approx(1.0, rel=1e-12)
    assert relmse(img, ref) == pytest.approx((0.01 / 1.01 + 1.0) / 2, rel=1e-12)
    # one channel off by 0.3 in one pixel of the mask: mean over 3 pixels x 3 channels
    img2 = ref.copy()
    img2[0, 0, 1] += 0.3
    first_column = np.zeros((4, 6), dtype=bool)
    first_column[:, 0] = True
    assert relmse(img2, ref, first_column) == pytest.approx(0.09 / 1.01 / 12, rel=1e-12)
    with pytest.raises(ValueError):
        relmse(img, ref, np.zeros((4, 6), dtype=bool))


def test_region_masks_split_cloth_by_log_distance_and_exclude_the_rest():
    depth = np.zeros((10, 16))
    cloth = np.zeros((10, 16), dtype=bool)
    depth[:5, :] = 1.0          # 80 near pixels
    depth[5:8, :] = 4.0         # 48 middle pixels
    depth[8:, :5] = 16.0        # 10 far pixels
    depth[8:, 5:] = 2.0         # 22 pixels of floor at a "near" distance: not cloth
    cloth[:8, :] = True
    cloth[8:, :5] = True
    masks, info = region_masks(depth, cloth)
    assert info["method"] == "log-distance thirds"
    assert [int(masks[g].sum()) for g in REGIONS] == [80, 48, 10]
    assert np.all(depth[masks["near"]] == 1.0) and np.all(depth[masks["middle"]] == 4.0)
    assert np.all(depth[masks["far"]] == 16.0)
    assert not any(masks[g][8:, 5:].any() for g in REGIONS)
    t1, t2 = info["thresholds"]
    assert t1 == pytest.approx(16 ** (1 / 3)) and t2 == pytest.approx(16 ** (2 / 3))


def test_region_masks_fall_back_to_terciles_when_a_band_is_empty():
    depth = np.concatenate([np.linspace(1.0, 1.2, 500), np.linspace(8.0, 9.6, 500)]).reshape(20, 50)
    masks, info = region_masks(depth, np.ones_like(depth, dtype=bool))
    assert info["method"] == "distance terciles"
    counts = [int(masks[g].sum()) for g in REGIONS]
    assert sum(counts) == 1000 and max(counts) - min(counts) <= 1
    assert depth[masks["near"]].max() < depth[masks["middle"]].min() <= depth[masks["middle"]].max() \
        < depth[masks["far"]].min()


# ----------------------------------------------------------------------------- speed-up

def test_equal_error_time_is_exact_on_power_laws_and_flags_extrapolation():
    t = np.array([0.1, 0.2, 0.4, 0.8, 1.6])
    c = 0.05
    for target_t in (0.13, 0.3, 1.0):
        seconds, extrapolated = equal_error_time(t, c / t, c / target_t)
        assert seconds == pytest.approx(target_t, rel=1e-12) and not extrapolated
    # error ~ t^-2 is a line in log-log too
    seconds, _ = equal_error_time(t, c / t ** 2, c / 0.5 ** 2)
    assert seconds == pytest.approx(0.5, rel=1e-12)
    # never reached: slope -1 from the last point
    seconds, extrapolated = equal_error_time(t, c / t, c / 6.4)
    assert extrapolated and seconds == pytest.approx(6.4, rel=1e-12)
    seconds, extrapolated = equal_error_time(t, 2 * c / t, c / 6.4)  # last point (1.6, 2c/1.6)
    assert extrapolated and seconds == pytest.approx(12.8, rel=1e-12)
    # never reached on a curve falling faster than 1/t: its last stretch's slope, not -1
    seconds, extrapolated = equal_error_time(t, c / t ** 2, c / 3.2 ** 2)
    assert extrapolated and seconds == pytest.approx(3.2, rel=1e-12)
    # ... but never flatter than -1: a curve levelling off extrapolates with error ~ 1/t
    seconds, extrapolated = equal_error_time(t, c / t ** 0.5, c / 1.6 ** 0.5 / 4)
    assert extrapolated and seconds == pytest.approx(6.4, rel=1e-12)
    # already below at the first point: slope -1 backwards
    seconds, extrapolated = equal_error_time(t, c / t, c / 0.05)
    assert extrapolated and seconds == pytest.approx(0.05, rel=1e-12)
    # the first crossing counts, in time order whatever the input order
    seconds, _ = equal_error_time([0.4, 0.1, 0.2], [0.1, 1.0, 0.5], 0.25)
    frac = (math.log(0.25) - math.log(0.5)) / (math.log(0.1) - math.log(0.5))
    assert seconds == pytest.approx(0.2 * 2 ** frac, rel=1e-12)
    assert closest_in_time([0.01, 0.1, 1.0], 0.2) == 1 and closest_in_time([0.01, 0.1, 1.0], 0.5) == 2


def test_time_at_is_linear_between_the_renders_around_the_count():
    """A render's fixed cost plus its cost per sample: linear between the two timed renders
    around the count, on the line through the nearest two beyond them; timing noise that
    makes a render the faster one costs no sample anything."""
    assert time_at(16, (16, 64), (0.2, 0.68)) == pytest.approx(0.2)
    assert time_at(256, (16, 64), (0.2, 0.68)) == pytest.approx(0.04 + 0.01 * 256)
    assert time_at(4, (64, 16), (0.68, 0.2)) == pytest.approx(0.04 + 0.01 * 4)
    assert time_at(1000, (16, 64), (0.3, 0.29)) == pytest.approx(0.3)
    # Three renders, the cost per sample higher between the last two: each stretch its own.
    counts, seconds = (16, 35, 64), (0.2, 0.39, 0.97)
    assert time_at(20, counts, seconds) == pytest.approx(0.2 + 0.01 * 4)
    assert time_at(50, counts, seconds) == pytest.approx(0.39 + 0.02 * 15)
    assert time_at(100, counts, seconds) == pytest.approx(0.97 + 0.02 * 36)
    assert time_at(8, counts, seconds) == pytest.approx(0.2 - 0.01 * 8)
    for bad_counts, bad_seconds in (((16, 16), (0.2, 0.3)), ((16,), (0.2,)), ((16, 32), (0.2,))):
        with pytest.raises(ValueError, match="two or more different sample counts"):
            time_at(8, bad_counts, bad_seconds)


def _synthetic_points(times, errors_per_region, spps):
    return [{"spp": s, "seconds": t, "compile_seconds": 0.0, "seed": i,
             "relmse": {g: e[g] for g in REGIONS}, "flip": {g: 0.1 for g in REGIONS}}
            for i, (s, t, e) in enumerate(zip(spps, times, errors_per_region))]


def test_region_figures_give_the_exact_ratio_on_c_over_t_curves():
    c = {"near": 0.01, "middle": 0.05, "far": 0.2}
    bf_t = [0.01 * 2 ** k for k in range(8)]
    bf = _synthetic_points(bf_t, [{g: c[g] / t for g in REGIONS} for t in bf_t], [2 ** k for k in range(8)])
    # multi-scale at 16 spp takes 0.1 s and reaches errors brute force gets in 3x, 7x, 50x that time
    wanted = {"near": 3.0, "middle": 7.0, "far": 50.0}
    ms_t = [0.02, 0.04, 0.06, 0.08, 0.1, 0.2]
    ms_err = [{g: 10.0 for g in REGIONS}] * 4 + [{g: c[g] / (0.1 * wanted[g]) for g in REGIONS},
                                                  {g: 1e-9 for g in REGIONS}]
    ms = _synthetic_points(ms_t, ms_err, [1, 2, 4, 8, 16, 32])
    exact = {g: ReferenceNoise(0.0, 0.0) for g in REGIONS}
    figures, ms_index, bf_index = compare.region_figures(ms, bf, 16, exact)
    assert ms_index == 4 and bf_t[bf_index] == 0.08  # closest to 0.1 s in log time
    for g in REGIONS:
        assert figures[g]["speedup"] == pytest.approx(wanted[g], rel=1e-9)
        assert figures[g]["spp_multiscale"] == 16 and figures[g]["spp_bruteforce"] == 8
        # the samples brute force needs, read off its error-vs-spp curve (1 spp = 0.01 s)
        assert figures[g]["spp_bruteforce_equal_error"] == pytest.approx(10.0 * wanted[g], rel=1e-9)
        assert figures[g]["extrapolated"] is (0.1 * wanted[g] > bf_t[-1])
        assert figures[g]["speedup_uncorrected"] == pytest.approx(wanted[g], rel=1e-9)
        assert not figures[g]["reference_limited"]
    assert figures["far"]["extrapolated"] and not figures["near"]["extrapolated"]


def test_region_figures_compare_own_errors_with_the_references_noise_taken_out():
    """Both methods' relMSE against a noisy reference holds its noise r: brute force's c/spp + r,
    multi-scale's e + r. The speed-up must be brute force's samples to reach e, not e + r; brute
    force's points within the reference's resolution leave its curve, and a multi-scale error
    the reference cannot resolve gives a flagged lower bound."""
    r = 4e-5
    spps = [2 ** k for k in range(9)]  # 1 .. 256; 1 spp takes 0.01 s
    c = {"near": 0.2, "middle": 0.05, "far": 0.02}
    bf = _synthetic_points([0.01 * n for n in spps], [{g: c[g] / n + r for g in REGIONS} for n in spps], spps)
    own = {"near": c["near"] / 40, "middle": c["middle"] / 2000, "far": 1e-6}
    ms = _synthetic_points([0.16], [{g: own[g] + r for g in REGIONS}], [16])
    noise = {g: ReferenceNoise(r, 1e-6) for g in REGIONS}
    figures, _, _ = compare.region_figures(ms, bf, 16, noise)
    # near: inside brute force's curve, 40 spp = 0.4 s
    assert figures["near"]["spp_bruteforce_equal_error"] == pytest.approx(40, rel=1e-9)
    assert figures["near"]["speedup"] == pytest.approx(0.4 / 0.16, rel=1e-9)
    # far above the reference's noise, subtracting it changes little
    assert figures["near"]["speedup_uncorrected"] == pytest.approx(figures["near"]["speedup"], rel=0.01)
    # middle: 2000 spp, past brute force's last point (256), extrapolated with its slope -1
    assert figures["middle"]["extrapolated"] and not figures["middle"]["reference_limited"]
    assert figures["middle"]["spp_bruteforce_equal_error"] == pytest.approx(2000, rel=1e-9)
    # uncorrected, the reference's noise makes brute force reach multi-scale's error sooner
    assert figures["middle"]["speedup_uncorrected"] < 0.5 * figures["middle"]["speedup"]
    # far: brute force's own error at 256 spp (7.8e-5) is resolved, multi-scale's 1e-6 is not
    # (3 standard errors = 3e-6): the speed-up is the one to reach 3e-6, a lower bound
    assert figures["far"]["reference_limited"] and figures["far"]["relmse_multiscale_own"] == pytest.approx(3e-6)
    assert figures["far"]["spp_bruteforce_equal_error"] == pytest.approx(c["far"] / 3e-6, rel=1e-9)
    assert [p["relmse_own"] is None for p in figures["far"]["curve_multiscale"]] == [True]
    assert figures["near"]["curve_bruteforce"][-1]["relmse_own"] == pytest.approx(c["near"] / 256, rel=1e-9)
    lines = compare.summary_lines({**figures, "regions": {"pixels": {g: 1000 for g in REGIONS}}}, 16, 16)
    assert lines[3].startswith("far     >") and any(line.startswith("> a lower bound") for line in lines)


def test_bruteforce_is_priced_by_its_renders_at_powers_of_two():
    """Mitsuba renders counts other than powers of two (multijitter's 35, 132) at 1.5-1.7x the
    time per sample: brute force's time at the count it needs comes from its powers of two."""
    spps = [1, 2, 4, 8, 16, 35, 64, 132, 256]
    seconds = [0.02 + 0.001 * n * (1.6 if n & (n - 1) else 1.0) for n in spps]
    bf = _synthetic_points(seconds, [{g: 0.1 / n for g in REGIONS} for n in spps], spps)
    ms = _synthetic_points([0.05], [{g: 0.1 / 100 for g in REGIONS}], [16])
    figures, _, _ = compare.region_figures(ms, bf, 16, {g: ReferenceNoise(0.0, 0.0) for g in REGIONS})
    for g in REGIONS:
        assert figures[g]["spp_bruteforce_equal_error"] == pytest.approx(100, rel=1e-9)
        assert figures[g]["seconds_bruteforce_equal_error"] == pytest.approx(0.02 + 0.001 * 100, rel=1e-9)
    assert compare.bruteforce_timing(bf) == ([1, 2, 4, 8, 16, 64, 256], [seconds[i] for i in (0, 1, 2, 3, 4, 6, 8)])
    # fewer than two powers of two: every render prices it
    assert compare.bruteforce_timing(bf[4:6]) == ([16, 35], seconds[4:6])


def test_reference_noise_of_a_region_from_the_per_pixel_estimates():
    """The subtraction's standard error: sqrt(2) std / sqrt(n) of the per-pixel estimates, which
    also sets which errors count as resolved; checked against the spread of what it subtracts."""
    rng = np.random.default_rng(7)
    variance = rng.exponential(2e-5, (60, 50))  # the reference mean's true relative variance per pixel
    estimate = variance * rng.chisquare(1, variance.shape)  # (A - B)^2 / 4 of Gaussian halves
    mask = np.zeros_like(variance, bool)
    mask[10:40] = True
    noise = ReferenceNoise.of_region(estimate, mask)
    values = estimate[mask]
    assert noise.relmse == pytest.approx(values.mean(), rel=1e-12)
    assert noise.standard_error == pytest.approx(math.sqrt(2) * values.std(ddof=1) / math.sqrt(values.size), rel=1e-12)
    assert noise.own_error(noise.relmse + 2 * noise.standard_error) is None
    assert noise.own_error(noise.relmse + 4 * noise.standard_error) == pytest.approx(4 * noise.standard_error)
    # over 1500 pixels, the realised noise in an image's relMSE minus another estimate of it
    v = variance[mask]
    differences = [(v * (rng.chisquare(1, v.size) - rng.chisquare(1, v.size))).mean() for _ in range(400)]
    assert np.std(differences) == pytest.approx(noise.standard_error, rel=0.25)
    with pytest.raises(ValueError, match="empty"):
        ReferenceNoise.of_region(estimate, np.zeros_like(mask))


# ----------------------------------------------------------------------------- reference cache

def test_reference_cache_miss_hit_and_corrupt_file_recomputed(tmp_path, monkeypatch):
    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path / "cache"))
    path = reference_path("sphere", 16, 9, 2)
    assert str(path).startswith(str(tmp_path / "cache" / "references"))
    image, variance, cached = reference_image("sphere", 16, 9, 2, quiet=True)  # a real render
    assert not cached and path.is_file()
    assert image.shape == variance.shape == (9, 16, 3) and image.mean() > 0.01 and np.all(variance >= 0)

    calls = []

    def fake_render(name, w, h, spp, quiet):
        calls.append((name, w, h, spp))
        return np.full((h, w, 3), 0.25, np.float32), np.zeros((h, w, 3), np.float32)

    monkeypatch.setattr(references, "_render_reference", fake_render)
    again, again_var, cached = reference_image("sphere", 16, 9, 2, quiet=True)
    assert cached and not calls and np.array_equal(again, image) and np.array_equal(again_var, variance)

    # other spp, other resolution: other keys, misses
    assert reference_path("sphere", 16, 9, 4) != path and reference_path("sphere", 18, 9, 2) != path
    assert not reference_image("sphere", 16, 9, 4, quiet=True)[2] and len(calls) == 1

    path.write_bytes(b"not an npz file")
    with pytest.warns(ReferenceCacheWarning, match="rendering it again"):
        fresh, _, cached = reference_image("sphere", 16, 9, 2, quiet=True)
    assert not cached and len(calls) == 2 and np.all(fresh == 0.25)
    assert reference_image("sphere", 16, 9, 2, quiet=True)[2]  # the rewritten file is good

    # a readable file of the wrong shape is recomputed too
    np.savez(path.with_suffix(".tmp.npz"), key=np.array(references.reference_key("sphere", 16, 9, 2)),
             image=np.zeros((9, 15, 3), np.float32), variance=np.zeros((9, 15, 3), np.float32))
    os.replace(path.with_suffix(".tmp.npz"), path)
    with pytest.warns(ReferenceCacheWarning, match="shape"):
        assert not reference_image("sphere", 16, 9, 2, quiet=True)[2]
    assert len(calls) == 3
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temporary files left


# ----------------------------------------------------------------------------- report on synthetic data

def _synthetic_result(w=40, h=24):
    rng = np.random.default_rng(1)
    ref = rng.uniform(0.05, 0.8, (h, w, 3)).astype(np.float32)
    images = {"reference": ref, "multiscale": ref * 1.05, "bruteforce": ref + rng.normal(0, 0.05, ref.shape)}
    depth = np.tile(np.linspace(1.0, 20.0, w), (h, 1))
    masks, info = region_masks(depth, np.ones((h, w), dtype=bool))
    bf_t = [0.01 * 2 ** k for k in range(5)]
    bf = _synthetic_points(bf_t, [{g: 0.01 / t for g in REGIONS} for t in bf_t], [1, 2, 4, 8, 16])
    ms = _synthetic_points([0.05, 0.1], [{g: 0.2 for g in REGIONS}, {g: 0.05 for g in REGIONS}], [1, 2])
    figures, _, _ = compare.region_figures(ms, bf, 16, {g: ReferenceNoise(0.001, 1e-5) for g in REGIONS})
    result = {"scene": "synthetic", "resolution": [w, h], "reference_spp": 64, "budget_seconds": 1.0,
              "variant": "none", "mscloth_version": mscloth.__version__, "machine": "test", **figures,
              "regions": {"method": info["method"], "distance_thresholds": info["thresholds"],
                          "pixels": {g: int(masks[g].sum()) for g in REGIONS}, "cloth_pixels": w * h},
              "metrics": {"relmse": "r", "flip": "f", "seconds": "s", "speedup": "x"},
              "compile_seconds": {"multiscale": 0.0, "bruteforce": 0.0}}
    return result, images, masks, depth


def _img_sources(html_text):
    return re.findall(r'<img[^>]*\ssrc="([^"]+)"', html_text)


def test_report_references_only_existing_files_and_is_never_half_written(tmp_path, monkeypatch):
    from mscloth.evaluation import report

    result, images, masks, depth = _synthetic_result()
    page = report.write_report(tmp_path / "r", result, images, masks, depth)
    sources = _img_sources(page.read_text())
    assert len(sources) >= 3 + 1 + 9 + 3 + 1  # side by side, regions, insets, heat maps + bar, convergence
    for src in sources:
        assert not os.path.isabs(src) and (page.parent / src).is_file(), src
    inset = np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(page.parent / "inset_far_reference.png"))
    assert inset.shape[0] == inset.shape[1] and inset.shape[0] >= 64  # square, zoomed

    def broken(*args, **kwargs):
        raise RuntimeError("plot failed")

    monkeypatch.setattr(report, "_convergence_plot", broken)
    with pytest.raises(RuntimeError):
        report.write_report(tmp_path / "s", result, images, masks, depth)
    assert not (tmp_path / "s" / "report.html").exists()
    assert not [p for p in (tmp_path / "s").iterdir() if p.name.startswith(".")]


def test_few_pixels_threshold_gives_a_warning_below_it_only():
    assert speedup.MIN_REGION_PIXELS == 400  # 2/sqrt(N) = 10 % relative standard error of a speed-up
    assert speedup.few_pixels_warning(400) is None and speedup.few_pixels_warning(10_000) is None
    text = speedup.few_pixels_warning(100)
    assert "only 100 pixels" in text and "about 20 %" in text  # 2/sqrt(100)
    assert "only 399 pixels" in speedup.few_pixels_warning(399)


def test_terminal_summary_and_report_warn_beside_the_speedup_of_a_small_region(tmp_path):
    from mscloth.evaluation import report

    result, images, masks, depth = _synthetic_result()
    assert [result["regions"]["pixels"][g] for g in REGIONS] == [96, 240, 624]
    lines = compare.summary_lines(result, 2, 8)
    rows = {line.split()[0]: line for line in lines[1:4]}
    assert rows["near"].endswith("!") and rows["middle"].endswith("!") and not rows["far"].endswith("!")
    assert [line for line in lines if line.startswith("! warning:")] == [
        f"! warning: near: {speedup.few_pixels_warning(96)}", f"! warning: middle: {speedup.few_pixels_warning(240)}"]
    page = report.write_report(tmp_path / "r", result, images, masks, depth).read_text()
    cells = re.findall(r"<td><b>[0-9.]+x</b>(.*?)</td>", page)
    assert len(cells) == 3
    assert "too few pixels (96 &lt; 400): about &plusmn;20 %" in cells[0] and "(240 &lt; 400)" in cells[1]
    assert "warning" not in cells[2]


def _narrow_result():
    """Curves spanning less than a decade in seconds, relMSE and FLIP, with no power of ten inside."""
    result, images, masks, depth = _synthetic_result()
    bf_t, ms_t = [0.2, 0.3, 0.45, 0.6], [0.25, 0.5]
    bf = [{"spp": 2 ** i, "seconds": t, "compile_seconds": 0.0, "seed": i,
           "relmse": {g: 0.016 / t for g in REGIONS}, "flip": {g: 0.4 - 0.2 * t for g in REGIONS}}
          for i, t in enumerate(bf_t)]
    ms = [{"spp": 2 ** i, "seconds": t, "compile_seconds": 0.0, "seed": i, "relmse": {g: e for g in REGIONS},
           "flip": {g: f for g in REGIONS}} for i, (t, e, f) in enumerate(zip(ms_t, (0.05, 0.03), (0.3, 0.25)))]
    figures, _, _ = compare.region_figures(ms, bf, 2, {g: ReferenceNoise(0.02, 1e-4) for g in REGIONS})
    result.update(figures)
    return result


def _tick_labels_in_view(axis, lo, hi):
    """The non-empty labels of the major and minor ticks that are drawn (inside [lo, hi])."""
    texts = []
    for locs, formatter in ((axis.get_majorticklocs(), axis.get_major_formatter()),
                            (axis.get_minorticklocs(), axis.get_minor_formatter())):
        inside = [v for v in locs if lo * (1 - 1e-9) <= v <= hi * (1 + 1e-9)]
        texts += [t for t in formatter.format_ticks(inside) if t.strip()]
    return texts


def test_convergence_figure_fits_1200_px_with_a_row_per_region_and_labelled_log_axes():
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from mscloth.evaluation import report

    for result in (_synthetic_result()[0], _narrow_result()):
        figure = report.convergence_figure(result)
        canvas = FigureCanvasAgg(figure)
        canvas.draw()
        width, height = canvas.get_width_height()
        assert width <= 1200 - 48  # inside a 1200-px window less the page's 1.5em margins
        assert len(figure.axes) == 6
        for ax in figure.axes:  # all six panels inside the figure, each at least 300 px wide
            box = ax.get_window_extent()
            assert box.x0 >= 0 and box.x1 <= width and box.y0 >= 0 and box.y1 <= height and box.width >= 300
            for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
                assert axis.get_scale() == "log"
                labels = _tick_labels_in_view(axis, lo, hi)
                assert len(labels) >= 2, (ax.get_title(), axis.axis_name, (lo, hi), labels)
        rows = sorted({round(ax.get_window_extent().y0) for ax in figure.axes})
        assert len(rows) == 3  # one row per region
    # the narrow curves stay inside one decade (0.1 .. 1 s): no power of ten to label
    lo, hi = report.convergence_figure(_narrow_result()).axes[0].get_xlim()
    assert 0.1 < lo < hi < 1.0


def test_log_ticks_prefer_round_values_and_do_not_crowd():
    from mscloth.evaluation.report import log_ticks

    assert log_ticks(0.06, 0.33) == pytest.approx([0.06, 0.1, 0.2, 0.3])  # not 0.06, 0.07, 0.08, 0.09, 0.1, ...
    assert log_ticks(0.2, 0.7) == pytest.approx([0.2, 0.3, 0.4, 0.5, 0.7])
    assert log_ticks(1e-4, 1.0) == pytest.approx([1e-4, 1e-3, 1e-2, 1e-1, 1.0])
    assert log_ticks(0.31, 0.45) == pytest.approx([0.32, 0.36, 0.4, 0.44])  # less than a mantissa step: linear


def test_label_log_axis_labels_spans_from_a_fraction_of_a_step_to_many_decades():
    from matplotlib.figure import Figure

    from mscloth.evaluation.report import label_log_axis

    for lo, hi in ((0.031, 0.034), (0.31, 0.45), (0.2, 0.7), (0.03, 0.8), (1e-5, 3.0), (1e-9, 1e3)):
        ax = Figure().add_subplot()
        ax.set_xscale("log")
        ax.set_xlim(lo, hi)
        label_log_axis(ax.xaxis, lo, hi)
        labels = _tick_labels_in_view(ax.xaxis, lo, hi)
        assert 2 <= len(labels) <= 12, ((lo, hi), labels)
        assert all(lo * (1 - 1e-9) <= float(t) <= hi * (1 + 1e-9) for t in labels), labels


# ----------------------------------------------------------------------------- end to end

@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    root = tmp_path_factory.mktemp("compare")
    result = run_cli("compare", "sphere", "--res", "48x27", "--budget", "0.2", "--reference-spp", "16",
                     "--out", str(root / "report"), "--json", str(root / "figures.json"))
    return root, result


def test_compare_sphere_writes_json_for_three_regions_and_the_report(compared):
    root, result = compared
    assert result.returncode == 0, result.stderr[-3000:]
    assert "speed-up" in result.stdout and "reference" in result.stderr  # progress shown
    data = json.loads((root / "figures.json").read_text())
    assert data["scene"] == "sphere" and data["resolution"] == [48, 27] and data["sampler"] == "multijitter"
    for g in REGIONS:
        region = data[g]
        for key in RESULT_KEYS:
            assert isinstance(region[key], (int, float)) and math.isfinite(region[key]), (g, key)
            assert region[key] > 0, (g, key)
        assert isinstance(region["extrapolated"], bool)
        assert len(region["curve_multiscale"]) >= 2 and len(region["curve_bruteforce"]) >= 2
        assert [p["spp"] for p in region["curve_bruteforce"]][:2] == [1, 2]
        assert all(math.isfinite(p["relmse"]) and p["seconds"] > 0 for p in region["curve_multiscale"])
        assert data["regions"]["pixels"][g] > 0
    # 48x27 holds about a hundred pixels per region: each speed-up is flagged, on the terminal too
    for g in REGIONS:
        pixels = data["regions"]["pixels"][g]
        assert pixels < speedup.MIN_REGION_PIXELS and data["regions"]["warnings"][g] == speedup.few_pixels_warning(pixels)
        assert f"! warning: {g}: only {pixels} pixels" in result.stdout
    report = root / "report" / "report.html"
    assert report.is_file()
    for src in _img_sources(report.read_text()):
        assert (report.parent / src).is_file(), src
    for name in ("reference.png", "multiscale.png", "bruteforce.png", "convergence.png", "heat_multiscale.png",
                 "inset_near_multiscale.png", "inset_far_bruteforce.png"):
        assert (report.parent / name).stat().st_size > 0, name


def test_report_page_loads_in_headless_chromium(compared, tmp_path):
    root, result = compared
    assert result.returncode == 0, result.stderr[-3000:]
    chromium = "/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else shutil.which("chromium")
    if chromium is None:
        pytest.fail("chromium is not installed (/usr/bin/chromium): install it with `apt-get install -y chromium` "
                    "to check the compare report in a browser")
    report = (root / "report" / "report.html").resolve()
    browser = subprocess.run(
        [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}",
         "--enable-logging=stderr", "--v=0", "--dump-dom", report.as_uri()],
        capture_output=True, text=True, timeout=120)
    assert browser.returncode == 0, browser.stderr[-3000:]
    dom = browser.stdout
    assert "<table" in dom and "speed-up" in dom, dom[:500]
    sources = _img_sources(dom)
    assert len(sources) >= 17, sources
    for src in sources:
        assert (report.parent / src).is_file(), src
    for marker in ("Uncaught", "ERROR:CONSOLE"):
        assert marker not in browser.stderr, browser.stderr[-3000:]


#: Appended to a copy of the report: once everything has loaded, the page's layout as JSON in <pre id="layout">.
LAYOUT_PROBE = """<script>
window.addEventListener("load", () => {
  const width = document.documentElement.clientWidth;
  const images = [...document.images];
  const pre = document.createElement("pre");
  pre.id = "layout";
  pre.textContent = JSON.stringify({innerWidth: window.innerWidth, clientWidth: width,
    scrollWidth: document.documentElement.scrollWidth, images: images.length,
    unloaded: images.filter(i => !i.complete || i.naturalWidth === 0).map(i => i.getAttribute("src")),
    overflowing: images.filter(i => i.getBoundingClientRect().right > width + 0.5)
                       .map(i => i.getAttribute("src") + " ends at " + i.getBoundingClientRect().right)});
  document.body.appendChild(pre);
});
</script>"""


def test_report_fits_a_1200_px_window_in_headless_chromium(compared, tmp_path):
    """At 1200 px wide every image lies inside the window (convergence.png did not: 1350 px
    of six panels in a row), nothing scrolls sideways, and each speed-up of this small render
    carries its few-pixels warning."""
    root, result = compared
    assert result.returncode == 0, result.stderr[-3000:]
    chromium = "/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else shutil.which("chromium")
    if chromium is None:
        pytest.fail("chromium is not installed (/usr/bin/chromium): install it with `apt-get install -y chromium` "
                    "to check the compare report in a browser")
    probe = tmp_path / "report"
    shutil.copytree(root / "report", probe)
    page = (probe / "report.html").read_text()
    assert "max-width: 100%" in page  # images scale to the page
    (probe / "report.html").write_text(page.replace("</body>", LAYOUT_PROBE + "</body>"))
    browser = subprocess.run(
        [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}",
         "--window-size=1200,900", "--virtual-time-budget=10000", "--dump-dom", (probe / "report.html").as_uri()],
        capture_output=True, text=True, timeout=120)
    assert browser.returncode == 0, browser.stderr[-3000:]
    found = re.search(r'<pre id="layout">(.*?)</pre>', browser.stdout)
    assert found, browser.stdout[-2000:]
    layout = json.loads(found.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    assert layout["innerWidth"] == 1200 and layout["images"] >= 17 and not layout["unloaded"], layout
    assert not layout["overflowing"] and layout["scrollWidth"] <= layout["clientWidth"], layout
    cells = re.findall(r"<td><b>[0-9.]+x</b>(.*?)</td>", browser.stdout)
    assert len(cells) == 3 and all(re.search(r"too few pixels \(\d+ &lt; 400\)", c) for c in cells), cells


# ----------------------------------------------------------------------------- bad input

def test_compare_without_the_evaluation_extra_says_what_to_install(monkeypatch, tmp_path):
    """matplotlib and flip-evaluator are an optional extra: without one, compare stops before
    writing or rendering anything and names it."""
    monkeypatch.setitem(compare.EVALUATION_EXTRA, "no_such_module_of_mscloth", "no-such-package")
    with pytest.raises(ClothError, match=r"needs no-such-package, not installed: pip install 'mscloth\[evaluation\]'"):
        compare.run_compare("sphere", 16, 9, out_dir=tmp_path / "out", quiet=True)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, message", [
    (["nosuchscene"], "unknown scene 'nosuchscene'"),
    (["sphere", "--budget", "0"], "--budget must be a positive number"),
    (["sphere", "--budget", "-5"], "--budget must be a positive number"),
    (["sphere", "--budget", "soon"], "--budget must be a positive number"),
    (["sphere", "--reference-spp", "3"], "--reference-spp must be an even number"),
    (["sphere", "--out", "{file}/sub"], "cannot write to"),
    (["sphere", "--json", "{dir}"], "is a directory"),
    (["sphere", "--json", "{file}"], "a_file exists; pass --force to overwrite"),
    (["x.xml"], "compare takes a built-in scene name (swatch, plane"),
    (["x.xml"], "an XML scene cannot be compared yet"),
    (["sphere", "--variant", "scalar_rgb"], "compare needs a JIT variant"),  # not mi.ShapePtr's AttributeError
])
def test_bad_input_gives_one_line_and_nonzero_exit(args, message, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    args = [a.format(file=blocker, dir=tmp_path) for a in args]
    result = run_cli("compare", *args, "--res", "16x9", timeout=120)
    assert result.returncode != 0
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("mscloth: error:") and message in lines[0], result.stderr


def test_convergence_curve_records_the_count_the_sampler_took(capfd):
    """Stratified samplers round some counts up (multijitter: 32 -> 35); the curve's time
    and error are at the count taken, and its rounding warning is not printed per repeat."""
    import mitsuba as mi

    scene = mi.load_dict({"type": "scene", "integrator": {"type": "path"}, "shape": {"type": "sphere"},
                          "sensor": {"type": "perspective", "sampler": {"type": "multijitter"},
                                     "film": {"type": "hdrfilm", "width": 8, "height": 8}}})
    zero = {g: 0.0 for g in REGIONS}
    points = compare.convergence_curve(scene, "test", 1, 32, 1e9, lambda image: {"relmse": zero, "flip": zero},
                                       quiet=True, repeats=2)
    assert [p["spp"] for p in points] == [1, 2, 4, 8, 16, 35]
    assert "rounded" not in capfd.readouterr().err


def test_reference_halves_render_the_count_the_sampler_takes_without_its_warning(tmp_path, monkeypatch, capfd):
    """A reference of 256 spp under multijitter: each half at the 132 samples the sampler
    takes for 128, said once, and Mitsuba's rounding warning not printed per pass (it was,
    in red, and the count printed was the one asked for)."""
    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path / "cache"))
    image, variance, cached = reference_image("sphere", 8, 6, 256)
    out, err = capfd.readouterr()
    assert not cached and np.all(np.isfinite(image)) and np.all(variance >= 0)
    assert "takes 132 samples per pixel for each half, not 128 (264 in all)" in out
    assert "(132 spp)" in out + err and "rounded" not in err + out


def test_builtin_scenes_sample_pixels_with_a_stratified_sampler_that_can_be_changed():
    from mscloth.evaluation.renders import scene_dict
    from mscloth.scenes.builtin import SCENES, builtin_scene
    from mscloth.scenes.pixel_sampler import DEFAULT_PIXEL_SAMPLER, set_pixel_sampler

    assert DEFAULT_PIXEL_SAMPLER == "multijitter"
    for name in SCENES:
        assert builtin_scene(name, 16, 9)["sensor"]["sampler"]["type"] == DEFAULT_PIXEL_SAMPLER
    assert scene_dict("satin", 16, 9, True, sampler="independent")["sensor"]["sampler"] == {"type": "independent"}
    with pytest.raises(ClothError, match="unknown sampler 'sobol': expected one of multijitter, independent"):
        set_pixel_sampler(builtin_scene("satin", 16, 9), "sobol")
