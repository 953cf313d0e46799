"""`make bench`'s report writer: the tables it writes from measured rows (no rendering)."""
import importlib.util
from pathlib import Path

import pytest

# bench/benchmark.py is a script beside the package, not part of it: loaded from its file.
_SPEC = importlib.util.spec_from_file_location(
    "bench_benchmark", Path(__file__).resolve().parents[1] / "bench" / "benchmark.py")
benchmark = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(benchmark)
write_results = benchmark.write_results


def region(speedup, spp_bf_curve, reference_limited=False):
    return {"speedup": speedup, "relmse_multiscale": 0.004, "relmse_bruteforce": 0.002,
            "relmse_multiscale_own": 0.0035, "relmse_reference": 0.0005, "reference_limited": reference_limited,
            "spp_bruteforce_equal_error_uncorrected": 16.0,
            "spp_multiscale": 16, "spp_bruteforce": 64, "seconds_multiscale": 0.12,
            "seconds_bruteforce": 0.14, "relmse_bruteforce_equal_spp": 0.006,
            "seconds_bruteforce_equal_spp": 0.04, "spp_bruteforce_equal_spp": 16,
            "spp_bruteforce_equal_error": 48.0,
            "curve_bruteforce": [{"spp": s, "relmse": 0.1 / s, "seconds": 0.01 * s} for s in spp_bf_curve]}


BUDGET = {"noise": {"multiscale": {"sun": 0.01, "sky": 0.05, "both": 0.04},
                    "bruteforce": {"sun": 0.2, "sky": 0.1, "both": 0.12}},
          "bias": {"multiscale": 1e-3, "bruteforce": 1e-6}}
#: A region's own time per sample (its crop rendered alone): ratio 1.5, rounds 1.4-1.7.
TIME = {"multiscale": 0.015, "bruteforce": 0.01, "ratio": 1.5, "ratios": [1.4, 1.5, 1.7]}
#: The whole frame in interleaved rounds at 16 and 64 spp: time ratios 1.5, 2, 3 at 16 spp
#: (neither compare's 0.12 s / 0.04 s = 3 nor the region's own); brute force 0.01 s a render
#: plus 0.000625 s a sample, so 0.04 s at the 48 spp it needs to reach multi-scale's error.
#: At 4 spp too: a sample alone (16 spp minus 4) takes multi-scale 0.015 / 0.02 / 0.03 s over
#: 12 samples against brute force's 0.0075 s: 2 / 2.67 / 4.
FRAME = {"multiscale": {4: [0.015, 0.02, 0.03], 16: [0.03, 0.04, 0.06], 64: [0.09, 0.12, 0.18]},
         "bruteforce": {4: [0.0125, 0.0125, 0.0125], 16: [0.02, 0.02, 0.02], 64: [0.05, 0.05, 0.05]}}


def scene_rows(speedup, spp_bf_curve, reference_limited=False):
    return {**{g: region(speedup, spp_bf_curve, reference_limited) for g in ("near", "middle", "far")},
            "frame_time": FRAME}


def test_results_page_has_every_table_and_the_split_of_the_speed_up(tmp_path):
    out = tmp_path / "RESULTS.md"
    # The cost column is the measured median of per-round ratios, not seconds / seconds.
    cost = [("cloth (mscloth, multi-scale)", 2.4, 1.7, 9.5, (8.7, 11.25)), ("principled (Mitsuba)", 0.24, 17.0, 1.0, (1.0, 1.0))]
    compare = [("plane", scene_rows(0.4, (1, 16, 256))), ("sphere", scene_rows(0.3, (1, 16, 64), True))]
    write_results(out, "make bench", "llvm_ad_rgb", cost, "256x256, 64 spp", [("plain", 0.4, (1024, 1024))],
                  1024, table_rows=[(512, 32, 0, 10.0, 1078.0, 1028.0), (512, 32, 64, 17.0, 115.0, 65.0),
                                    (256, 16, 0, 1.4, 77.0, 65.0)],
                  ccv_rows=[(2.0, [0.6, -0.2, 0.77], [-0.1, 0.7, 0.7], [(0.02, 0.009), (0.05, 0.009), (-0.01, 0.008)])],
                  compare_rows=compare, budget_rows=[("plane", {g: dict(BUDGET, time=TIME) for g in ("near", "middle", "far")})],
                  call_rows=[("cloth (mscloth, multi-scale)", 0.27, 16.1), ("principled (Mitsuba)", 0.018, 1.0)],
                  call_setup="2097152 shading points")
    text = out.read_text()
    assert "| cloth (mscloth, multi-scale) | 2.400 | 1.70 | 9.50x | 8.70-11.25x |" in text
    assert "### The BSDFs alone (2097152 shading points)" in text
    assert "| cloth (mscloth, multi-scale) | 270.0 | 16.10x |" in text
    # The default under max_table_mib: rank 64 for 512^2 at 32^2 bins, the full table at 256^2, 16^2.
    assert "| 512x512 | 32 | rank 64 (`direction_rank`) = default | 17.0 | 115 | 65 |" in text
    assert "| 512x512 | 32 | full | 10.0 | 1078 | 1028 |" in text
    assert "| 256x256 | 16 | full = default | 1.4 | 77 | 65 |" in text
    # The speed-up at the interleaved times: brute force's 0.04 s at 48 spp over multi-scale's
    # 0.03, 0.04, 0.06 s; the rounds' time ratios at 16 spp; brute force at multi-scale's spp and at 256 spp (or a note that the
    # curve stopped short).
    # Uncorrected (the reference's noise left in): brute force needs 16 spp, 0.02 s.
    assert ("| plane | near | 0.40x | 1.00x (0.67-1.33) | 0.50x | 2.00 (1.50-3.00) | 2.67 (2.00-4.00) "
            "| 16 / 0.004 / 0.0035 / 0.12 "
            "| 0.0005 | 64 / 0.002 / 0.14 | 0.006 / 0.04 | 0.000391 |") in text
    # Multi-scale's error within the reference's noise: lower bounds.
    assert "| sphere | far | > 0.30x | > 1.00x (0.67-1.33) |" in text and "not reached |" in text
    assert "| 16 | [0.6, -0.2, 0.77] | [-0.1, 0.7, 0.7] | +0.020 +- 0.009 | +0.050 +- 0.009 | -0.010 +- 0.008 |" in text
    # The error budget: noise per light and method, the interleaved time ratio 2, noise-only
    # speed-up (0.12 / 0.04) / 2 = 1.5, the speed-up at the interleaved time, and the ratios
    # spelled out.
    assert ("| plane | middle | 0.01 / 0.05 / 0.04 | 0.2 / 0.1 / 0.12 | 2.00 | 1.50x | 1.00x "
            "| 0.001 / 1e-06 |") in text
    assert "20x under the sun alone" in text and "2x brute force's" in text
    assert "is largest in plane's near region, 0.001 / 1e-06 (multiscale / bruteforce)" in text
    # Per scene and region: speed-up, bias, noise of both methods (sun and sky), time per
    # sample of both (0.12 s / 16 spp, 0.04 s / 16 spp), the noise-only speed-up at the
    # interleaved frame ratio ((0.12 / 0.04) / 2 = 1.5), the region's own time ratio and the
    # noise-only speed-up at it ((0.12 / 0.04) / 1.5 = 2); scenes without a budget say so.
    assert "| plane | middle | 0.40x | 0.001 | 0.04 / 0.12 | 7.5 / 2.5 | 1.50x | 1.50 (1.40-1.70) | 2.00x |" in text
    assert ("| sphere | far | 0.30x | not measured | not measured | 7.5 / 2.5 | not measured | not measured "
            "| not measured |") in text
    assert text.index("## Per scene and region") < text.index("## Why: noise per sample and bias")


def test_scenes_only_page_leaves_out_the_other_sections(tmp_path):
    out = tmp_path / "RESULTS.md"
    compare = [("satin", scene_rows(2.0, (1, 16)))]
    write_results(out, "python bench/benchmark.py --scenes satin --scenes-only", "llvm_ad_rgb", [], "", [], 1024,
                  compare_rows=compare, budget_rows=[("satin", {g: BUDGET for g in ("near", "middle", "far")})],
                  compare_res=(64, 36), compare_budget=5.0)
    text = out.read_text()
    assert "## Multi-scale vs brute force (`mscloth compare`, 64x36, budget 5 s)" in text
    assert "| satin | far | 2.00x | 0.001 | 0.04 / 0.12 | 7.5 / 2.5 | 1.50x |" in text
    assert "(`mscloth.evaluation.error_budget`, 64x36)" in text
    for absent in ("## Per-sample cost", "## Multi-scale tables", "## Control-variate bias", "## Map generation"):
        assert absent not in text


def test_scene_and_comparison_options_are_checked(capsys):
    import pytest

    for bad, message in ((["--scenes", "satin,nosuch"], "expected comma-separated built-in scenes"),
                         (["--compare-res", "wide"], "WIDTHxHEIGHT"),
                         (["--compare-budget", "0"], "--compare-budget")):
        with pytest.raises(SystemExit) as exit_info:
            benchmark.main(bad)
        assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_frame_counts_time_both_methods_at_a_quarter_of_the_spp_too():
    # Brute force in steps of 4 up to its curve's last count (powers of two multijitter keeps),
    # both methods also at 4 spp, whose difference to 16 prices a sample without the render's
    # fixed cost; none at a count with no whole quarter.
    counts = benchmark.frame_counts(scene_rows(1.0, (1, 16, 256)))
    assert counts == {"multiscale": (4, 16), "bruteforce": (4, 16, 64, 256)}
    assert benchmark.marginal_time_ratios(scene_rows(1.0, (1, 16))) == pytest.approx([2.0, 0.02 / 0.0075, 4.0])
    odd = scene_rows(1.0, (1, 16))
    for g in ("near", "middle", "far"):
        odd[g] = dict(odd[g], spp_multiscale=6)
    assert benchmark.frame_counts(odd)["multiscale"] == (6,)
    assert benchmark.marginal_time_ratios(odd) is None
