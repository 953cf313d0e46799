"""The error budget's estimators (noise per sample, squared bias) on images of known
statistics, and one small run on a built-in scene."""
import numpy as np
import pytest

from mscloth.evaluation.error_budget import LIGHTS, noise_only_speedup
from mscloth.evaluation.metrics import RELMSE_EPS, per_sample_noise, squared_bias
from mscloth.evaluation.regions import REGIONS

SHAPE = (40, 50, 3)


def test_per_sample_noise_recovers_the_variance_of_one_sample():
    """k renders of n spp, each pixel Gaussian with per-sample variance s^2: the estimate's
    pixel mean is s^2 / (ref^2 + eps) within 5 standard errors of a sample variance over
    k - 1 degrees of freedom and all pixels."""
    rng = np.random.default_rng(1)
    k, spp, s2 = 6, 4, 0.09
    ref = np.full(SHAPE, 0.5)
    images = ref + rng.normal(0.0, np.sqrt(s2 / spp), (k,) + SHAPE)
    estimate = per_sample_noise(images, spp, ref).mean()
    expected = s2 / (0.25 + RELMSE_EPS)
    se = expected * np.sqrt(2.0 / (k - 1) / (SHAPE[0] * SHAPE[1] * SHAPE[2]))
    assert abs(estimate - expected) <= 5.0 * se, (estimate, expected)
    with pytest.raises(ValueError, match="expected"):
        per_sample_noise(images[:1], spp, ref)


@pytest.mark.parametrize("bias", [0.0, 0.05])
def test_squared_bias_is_unbiased_whatever_the_noise_of_the_halves_and_the_reference(bias):
    """Halves with noise 0.1 (20x the squared bias) and a noisy reference: the estimate's
    mean is bias^2 / (ref^2 + eps) within 5 standard errors (the noise terms cancel in
    expectation; without the corrections it would be ~40x off)."""
    rng = np.random.default_rng(2)
    truth = np.full(SHAPE, 0.5)
    sd, ref_sd = 0.1, 0.03
    a = truth + bias + rng.normal(0.0, sd, SHAPE)
    b = truth + bias + rng.normal(0.0, sd, SHAPE)
    ref = truth + rng.normal(0.0, ref_sd, SHAPE)
    per_pixel = squared_bias(a, b, ref, np.full(SHAPE, ref_sd ** 2))
    expected = (bias ** 2 / (truth ** 2 + RELMSE_EPS)).mean()
    se = per_pixel.std() / np.sqrt(per_pixel.size)
    assert abs(per_pixel.mean() - expected) <= 5.0 * se + 0.05 * expected, (per_pixel.mean(), expected, se)
    naive = ((0.5 * (a + b) - ref) ** 2 / (ref ** 2 + RELMSE_EPS)).mean()
    assert naive > expected + 20.0 * se  # the corrections matter


def test_noise_only_speedup_is_the_noise_ratio_over_the_time_ratio():
    noise = {"multiscale": {"both": 0.02}, "bruteforce": {"both": 0.1}}
    assert noise_only_speedup(noise, 2.5) == pytest.approx(2.0)


def test_budget_of_a_small_plane_separates_lights_and_methods(monkeypatch, tmp_path):
    """End to end at 48x27: every region has finite noise for both methods and each light,
    and a bias for each case; under the sun alone brute force is noisier than multi-scale
    near and in the middle (the weave's noise is what multi-scale shading removes; at the
    horizon the sheen covers the weave, so there is nothing to remove there)."""
    from mscloth.evaluation.error_budget import error_budget

    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path / "cache"))
    budget = error_budget("plane", 48, 27, noise_renders=4, noise_spp=2, bias_spp=8,
                          reference_spp=8, quiet=True)
    assert set(budget) == set(REGIONS)
    for g in REGIONS:
        for method in ("multiscale", "bruteforce"):
            values = budget[g]["noise"][method]
            assert set(values) == set(LIGHTS)
            assert all(np.isfinite(v) and v >= 0.0 for v in values.values())
        assert set(budget[g]["bias"]) == {"multiscale", "bruteforce"}
        assert all(np.isfinite(v) for v in budget[g]["bias"].values())
    sun = [budget[g]["noise"] for g in ("near", "middle")]
    assert all(n["bruteforce"]["sun"] > n["multiscale"]["sun"] for n in sun), sun


def test_region_time_renders_each_region_s_box_alone(monkeypatch, tmp_path):
    """Each region's crop is the bounding box of its pixels, and region_time renders that box
    alone (an image of the crop's size) with both methods: positive seconds, and the ratio
    of the rounds' medians."""
    from mscloth import setup_mitsuba
    from mscloth.evaluation.error_budget import lit_scene, region_crops, region_time
    from mscloth.evaluation.regions import depth_and_cloth, region_masks
    from mscloth.evaluation.renders import timed_render

    setup_mitsuba()  # lit_scene loads clothpath (run alone, no other test has)
    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path / "cache"))
    masks = region_masks(*depth_and_cloth("plane", 48, 27))[0]
    crops = region_crops("plane", 48, 27)
    for g in REGIONS:
        x, y, w, h = crops[g]
        inside = np.zeros_like(masks[g])
        inside[y:y + h, x:x + w] = True
        assert masks[g][inside].any() and not masks[g][~inside].any()
        # Tight: each edge row and column of the box holds a pixel of the region.
        box = masks[g][y:y + h, x:x + w]
        assert box[0].any() and box[-1].any() and box[:, 0].any() and box[:, -1].any()
    x, y, w, h = crops["near"]
    image = timed_render(lit_scene("plane", 48, 27, True, crop=crops["near"]), 1, 0).image
    assert image.shape[:2] == (h, w)
    timing = region_time("plane", 48, 27, spp=1, rounds=2)
    for g in REGIONS:
        t = timing[g]
        assert t["multiscale"] > 0.0 and t["bruteforce"] > 0.0 and len(t["ratios"]) == 2
        assert t["ratio"] == pytest.approx(float(np.median(t["ratios"])))


def test_interleaved_rounds_call_each_render_once_per_round_in_order():
    """Round after round, every render once in the given order: a drifting machine then
    moves one round's values together."""
    from mscloth.evaluation.error_budget import interleaved_rounds

    calls = []

    def render(label):
        def call(r):
            calls.append((label, r))
            return 10 * r + len(calls)
        return call

    values = interleaved_rounds({"a": render("a"), "b": render("b")}, 3)
    assert calls == [("a", 0), ("b", 0), ("a", 1), ("b", 1), ("a", 2), ("b", 2)]
    assert values == {"a": [1, 13, 25], "b": [2, 14, 26]}


def test_timed_scenes_are_loaded_alone_and_freed():
    """with_scene_alone hands ``use`` the loaded scene and frees it afterwards: no cloth BSDF
    of it is left registered, whose code every later render would trace (a timed brute-force
    render paid ~25 ms for a multi-scale scene loaded beside it)."""
    import gc

    import mitsuba as mi

    from mscloth import setup_mitsuba
    from mscloth.evaluation.renders import with_scene_alone

    setup_mitsuba()
    scene_dict = {"type": "scene", "cloth": {"type": "rectangle", "bsdf": {"type": "cloth", "multiscale": False}}}

    def cloth_bsdfs():
        gc.collect()
        return sum(1 for o in gc.get_objects() if type(o).__name__ == "ClothBSDF")

    before = cloth_bsdfs()
    seen = with_scene_alone(lambda: mi.load_dict(scene_dict), lambda scene: (len(scene.shapes()), cloth_bsdfs()))
    assert seen == (1, before + 1)
    assert cloth_bsdfs() == before
