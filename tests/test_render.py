"""Rendering helpers: the samples-per-second line and the kernel compilation it leaves out."""
import re

import drjit as dr
import mitsuba as mi
import pytest

from mscloth.render import KernelCompilation, throughput_text


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
