"""Rendering helpers: the samples-per-second line and the kernel compilation it leaves out."""
import re

import drjit as dr
import mitsuba as mi
import pytest

from mscloth.render import MAX_PASSES, SAMPLES_PER_PASS, KernelCompilation, pass_count, render_progressive, throughput_text


def _numbers(text):
    match = re.fullmatch(r"([0-9.]+) M samples/s \(render ([0-9.]+) s, plus ([0-9.]+) s kernel compilation\)", text)
    assert match, text
    return tuple(float(v) for v in match.groups())


def test_throughput_is_samples_over_render_seconds_without_compilation():
    # 3 M samples in 4.5 s of which 3 s compiled kernels: 2 M samples per second of rendering
    assert throughput_text(3_000_000, 4.5, 3.0) == "2.00 M samples/s (render 1.50 s, plus 3.0 s kernel compilation)"
    rate, render, compiling = _numbers(throughput_text(640 * 360 * 64, 7.25, 2.5))
    assert render == pytest.approx(4.75) and compiling == pytest.approx(2.5)
    assert rate == pytest.approx(640 * 360 * 64 / 4.75 / 1e6, abs=0.005)
    # without compilation the rate is over all the seconds
    assert _numbers(throughput_text(1_000_000, 2.0, 0.0))[0] == pytest.approx(0.5)
    # a compile time over the wall time (clock granularity) is clipped, never a negative render time
    assert throughput_text(10, 1.0, 2.0) == "rate not measurable (render 0.00 s, plus 1.0 s kernel compilation)"


def test_kernel_compilation_sees_a_new_kernel_and_restores_the_history_flag():
    had = dr.flag(dr.JitFlag.KernelHistory)
    with KernelCompilation() as compiling:
        x = dr.arange(mi.Float, 1000) * 0.123456789 + dr.sin(dr.arange(mi.Float, 1000))
        dr.eval(x)
    assert compiling.seconds > 0.0
    assert dr.flag(dr.JitFlag.KernelHistory) == had


def test_a_small_render_is_one_pass_and_a_large_one_several():
    # the first picture (320x180, 16 spp: 0.9 M samples) is one pass: each pass traces the
    # kernel again (~0.1 s), eight of them cost as much as the render
    assert pass_count(320 * 180, 16) == 1
    assert pass_count(512 * 512, 64) == round(512 * 512 * 64 / SAMPLES_PER_PASS) == 4
    assert pass_count(2048 * 2048, 256) == MAX_PASSES
    assert pass_count(4096 * 4096, 3) == 3          # never more passes than samples
    assert pass_count(1000 * 1000, 9) == 1          # 2 does not divide 9
    assert pass_count(10, 12, passes=5) == 4        # asked for: lowered to a divisor
    assert pass_count(10, 1, passes=0) == 1


def test_render_progressive_averages_its_passes(monkeypatch):
    scene = mi.load_dict({"type": "scene", "integrator": {"type": "path"},
                          "sensor": {"type": "perspective",
                                     "film": {"type": "hdrfilm", "width": 4, "height": 3}},
                          "sky": {"type": "constant"}})
    calls = []
    monkeypatch.setattr(mi, "render", lambda scene, spp, seed: calls.append((spp, seed)) or dr.full(mi.TensorXf, float(seed), (3, 4, 3)))
    image = render_progressive(scene, 12, passes=4, seed=10, quiet=True)
    assert calls == [(3, 10), (3, 11), (3, 12), (3, 13)]
    assert dr.allclose(image, 11.5)
    calls.clear()
    render_progressive(scene, 16, seed=0, quiet=True)
    assert calls == [(16, 0)]


def _multijitter_scene():
    return mi.load_dict({"type": "scene", "integrator": {"type": "path"},
                         "sensor": {"type": "perspective", "sampler": {"type": "multijitter"},
                                    "film": {"type": "hdrfilm", "width": 4, "height": 3}},
                         "sky": {"type": "constant"}})


def test_passes_keep_to_counts_the_sampler_takes(monkeypatch):
    # multijitter takes 528 for 512: eight passes of 4096 would render 4224 in all.
    from mscloth.render import samples_taken

    scene = _multijitter_scene()
    assert samples_taken(scene, 10) == 12 and samples_taken(scene, 512) == 528 and samples_taken(scene, 4096) == 4096
    calls = []
    monkeypatch.setattr(mi, "render", lambda scene, spp, seed: calls.append(spp) or dr.zeros(mi.TensorXf, (3, 4, 3)))
    render_progressive(scene, 4096, passes=8, quiet=True)
    assert sum(calls) == 4096 and all(samples_taken(scene, n) == n for n in calls), calls


def test_an_interrupt_stops_the_passes_after_the_one_it_interrupted(monkeypatch):
    # Mitsuba takes Ctrl-C during a render, logs it and swallows the signal (around a
    # Python integrator): the passes must stop there, not run on to a complete image.
    scene = _multijitter_scene()
    calls = []

    def render(scene, spp, seed):
        calls.append(seed)
        if calls == [0, 1]:  # Ctrl-C in the second pass of the first render
            mi.Log(mi.LogLevel.Warn, "Received interrupt signal, winding down..")
        return dr.zeros(mi.TensorXf, (3, 4, 3))

    monkeypatch.setattr(mi, "render", render)
    with pytest.raises(KeyboardInterrupt):
        render_progressive(scene, 16, passes=4, quiet=True)
    assert calls == [0, 1]
    render_progressive(scene, 16, passes=4, quiet=True)  # the next render is not stopped
    assert calls == [0, 1, 0, 1, 2, 3]
