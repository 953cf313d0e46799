"""bench/first_picture.py's reading of ``mscloth render`` output and its report (no rendering)."""
import importlib.util
import sys
from pathlib import Path

# bench/first_picture.py is a script beside the package, not part of it: loaded from its file.
_SPEC = importlib.util.spec_from_file_location(
    "bench_first_picture", Path(__file__).resolve().parents[1] / "bench" / "first_picture.py")
first_picture = importlib.util.module_from_spec(_SPEC)
sys.modules[_SPEC.name] = first_picture  # its dataclasses look their module up
_SPEC.loader.exec_module(first_picture)

OUTPUT = """mscloth precompute [near.bsdf, twill-2-2]: visibility (front) 1/64 directions
mscloth precompute [near.bsdf, twill-2-2]: tables built in 2.50 s, 19.3 MiB
mscloth precompute [far.bsdf, satin-5-2]: tables built in 3.25 s, 30.1 MiB
\x1b[31m2026-12-02 13:00:00 WARN  main  [Cloth] cloth [far.bsdf]: something odd
\x1b[0mmscloth render: sphere, 320x180, 16 spp, variant llvm_ad_rgb (loaded in 6.40 s)
render [###...........................] 1/8   0.5s elapsed,   3.5s left
wrote out/render.exr and out/render.png: 0.60 M samples/s (render 1.50 s, plus 4.2 s kernel compilation)
"""


def test_output_lines_give_loading_compilation_render_tables_and_warnings():
    run = first_picture.Run()
    for line in OUTPUT.splitlines(keepends=True):
        first_picture.parse_line(run, line, cpu_now=lambda: 7.5)
    assert (run.loading, run.cpu_loading) == (6.4, 7.5)
    assert (run.render, run.render_compile) == (1.5, 4.2)
    assert run.tables == [("near.bsdf, twill-2-2", 2.5, 19.3), ("far.bsdf, satin-5-2", 3.25, 30.1)]
    assert run.warnings == ["2026-12-02 13:00:00 WARN  main  [Cloth] cloth [far.bsdf]: something odd"]


def test_report_row_and_says_wall_times_are_inflated():
    run = first_picture.Run(wall=12.0, cpu=9.5, cpu_loading=7.5, loading=6.4,
                            render=1.5, render_compile=4.2, tables=[("a", 2.5, 19.3)],
                            peak_rss_mib=812.0, cache_mib=49.4)
    text = first_picture.table([("sphere", "cold", run), ("sphere", "warm", first_picture.Run(wall=2.0))],
                               (1.2, 1.0), 19, ["--cases", "sphere"])
    assert "| sphere | cold | 12.0 | 9.5 | 6.4 (7.5) | 4.2 | 1.50 | 2.5 s / 19 | 49 | 812 | none |" in text
    assert "| sphere | warm | 2.0 | 0.0 | ? (?) | ? | ? | none (cached) | 0 | 0 | none |" in text
    assert "shared machine inflates them" in text and "CPU seconds" in text
