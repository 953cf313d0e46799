"""Time to the first picture (issue 22): ``mscloth render`` cold and warm, in subprocesses.

Cold: an empty table cache (``MSCLOTH_CACHE``) and an empty Dr.Jit kernel cache
(``DRJIT_CACHE_DIR``), both fresh temporary directories. Warm: the same command again on
the caches the cold run filled. Cases: the ``sphere`` scene, and a sphere dressed in a WIF
pattern (default /work/shared/data/wif/2229.wif if present, else the first .wif in
tests/data), from a small XML scene written here.

Per run: wall seconds split into loading (imports, maps, tables, and the cloths' calibration,
whose kernels compile on Mitsuba's loader threads, out of sight of Dr.Jit's per-thread
kernel history), the render's kernel compilation and the render (as the CLI prints them),
plus start-up (imports) measured once on its own; CPU seconds (user + sys of the child) of
loading and in all; the tables' build times (their progress lines); the table cache on
disk; the child's peak RSS; and any warning printed.

    .venv/bin/python bench/first_picture.py [--cases sphere,wif] [--wif FILE] [--nice 19] [--out FILE]
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RES, SPP = "320x180", 16
DEFAULT_WIF = Path("/work/shared/data/wif/2229.wif")

#: The WIF case: one cloth sphere under a sky and a sun, the pattern 24 tiles around it.
WIF_SCENE = """<scene version="3.0.0">
    <integrator type="clothpath"/>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="320"/><integer name="height" value="180"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.5, 0.58, 0.72"/></emitter>
    <emitter type="directional"><vector name="direction" value="0.5, -0.5, -0.7"/>
        <rgb name="irradiance" value="3.0, 2.8, 2.5"/></emitter>
    <shape type="sphere">
        <bsdf type="cloth">
            <string name="pattern" value="{wif}"/>
            <float name="uv_scale" value="24"/>
            <float name="sheen_thickness" value="0.3"/>
        </bsdf>
    </shape>
</scene>
"""

_LOADED = re.compile(r"mscloth render: .*\(loaded in ([\d.]+) s\)")
_RENDERED = re.compile(r"\(render ([\d.]+) s, plus ([\d.]+) s kernel compilation\)")
_TABLES = re.compile(r"mscloth precompute \[(.*?)\]: tables built in ([\d.]+) s, ([\d.]+) MiB")
#: Colours of Mitsuba's log lines (its reset can begin the next line in a shared pipe).
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_WARNING = re.compile(r"warning|\bWARN\b", re.IGNORECASE)


@dataclass
class Run:
    """What one ``mscloth render`` printed and cost."""

    wall: float = 0.0
    cpu: float = 0.0
    cpu_loading: float | None = None    # CPU seconds when the "loaded" line came
    loading: float | None = None
    render: float | None = None
    render_compile: float | None = None
    tables: list = field(default_factory=list)   # (label, seconds, MiB)
    warnings: list = field(default_factory=list)
    peak_rss_mib: float = 0.0
    cache_mib: float = 0.0
    returncode: int = 0


def parse_line(run: Run, line: str, cpu_now=None) -> None:
    """Fold one output line of ``mscloth render`` into ``run``; ``cpu_now()`` is called for the
    child's CPU seconds when the "loaded" line arrives."""
    line = _ANSI.sub("", line).rstrip("\n")
    if m := _LOADED.search(line):
        run.loading = float(m.group(1))
        run.cpu_loading = cpu_now() if cpu_now is not None else None
    elif m := _RENDERED.search(line):
        run.render, run.render_compile = float(m.group(1)), float(m.group(2))
    elif m := _TABLES.search(line):
        run.tables.append((m.group(1), float(m.group(2)), float(m.group(3))))
    elif _WARNING.search(line):
        run.warnings.append(line.strip())


def _child_cpu(pid: int) -> float | None:
    """user + sys CPU seconds of a running process so far (Linux /proc), else None."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def _dir_mib(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) / 2**20


#: The package measured: this checkout's src/ unless --src names another (e.g. an older commit's
#: ``git archive`` for a before/after comparison).
SRC = ROOT / "src"


def _env(cache: Path, kernels: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(SRC), env.get("PYTHONPATH")]))
    env["MSCLOTH_CACHE"] = str(cache)
    env["DRJIT_CACHE_DIR"] = str(kernels)
    return env


def run_child(argv: list, env: dict, niceness: int, echo: bool = False) -> tuple[Run, float, float]:
    """Run ``argv``; returns (parsed run, wall seconds, CPU seconds) with peak RSS filled in."""
    run = Run()
    started = time.perf_counter()
    proc = subprocess.Popen(argv, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, preexec_fn=(lambda: os.nice(niceness)) if niceness else None)
    for line in proc.stdout:                # universal newlines: progress bars' \r split too
        if echo:
            sys.stderr.write(line)
        parse_line(run, line, lambda: _child_cpu(proc.pid))
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    run.wall = time.perf_counter() - started
    run.cpu = usage.ru_utime + usage.ru_stime
    run.peak_rss_mib = usage.ru_maxrss / 1024.0         # KiB on Linux
    run.returncode = proc.returncode
    return run, run.wall, run.cpu


def start_up(niceness: int) -> tuple[float, float]:
    """(wall, CPU) seconds of importing Mitsuba and mscloth and choosing the variant."""
    with tempfile.TemporaryDirectory(prefix="mscloth-bench-") as tmp:
        env = _env(Path(tmp) / "cache", Path(tmp) / "kernels")
        code = "import mscloth; mscloth.setup_mitsuba()"
        _, wall, cpu = run_child([sys.executable, "-c", code], env, niceness)
    return wall, cpu


def measure_case(case: str, wif: Path | None, niceness: int, echo: bool = False) -> list[tuple[str, Run]]:
    """[("cold", Run), ("warm", Run)] of one case."""
    runs = []
    with tempfile.TemporaryDirectory(prefix="mscloth-bench-") as tmp:
        tmp = Path(tmp)
        cache, kernels = tmp / "cache", tmp / "kernels"
        cache.mkdir()
        kernels.mkdir()
        if case == "sphere":
            scene = ["sphere", "--res", RES]
        else:
            xml = tmp / "wif.xml"
            xml.write_text(WIF_SCENE.format(wif=Path(wif).resolve()))
            scene = [str(xml)]
        argv = [sys.executable, "-m", "mscloth", "render", *scene, "--spp", str(SPP),
                "--out", str(tmp / "render.exr"), "--force"]  # the warm run writes it again
        for state in ("cold", "warm"):
            run, _, _ = run_child(argv, _env(cache, kernels), niceness, echo)
            run.cache_mib = _dir_mib(cache)
            if run.returncode:
                raise SystemExit(f"first_picture: {' '.join(argv)} failed ({run.returncode})")
            runs.append((state, run))
    return runs


def _f(value, fmt="{:.1f}") -> str:
    return "?" if value is None else fmt.format(value)


def table(rows, startup: tuple[float, float], niceness: int, argv) -> str:
    """The Markdown report of measured rows [(case, state, Run)]."""
    lines = [f"## First picture ({time.strftime('%Y-%m-%d')}, `mscloth render ... --res {RES} --spp {SPP}`)", "",
             f"Command: `bench/first_picture.py {' '.join(argv)}` (child processes at nice {niceness}). "
             "Cold: empty table cache and empty Dr.Jit kernel cache; warm: the same command again. "
             "Wall seconds count every other job on the machine (a shared machine inflates them); "
             "CPU seconds (user + sys of the child) are less affected. Start-up (imports) measured on "
             f"its own: {startup[0]:.1f} s wall, {startup[1]:.1f} s CPU, part of loading below. Issue 22's "
             "targets (2 quiet cores): sphere <= 6 s cold, <= 2 s warm; WIF <= 10 s cold, <= 150 MiB "
             "on disk, <= 1 GiB peak memory, no warning warm.", "",
             "| case | cache | wall s | CPU s | loading s (CPU s): maps, tables, calibration | render's kernel "
             "compilation s | render s | tables built (s, MiB) | table cache MiB | peak RSS MiB | warnings |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for case, state, r in rows:
        built = ", ".join(f"{s:.1f} s / {m:.0f}" for _, s, m in r.tables) or "none (cached)"
        warned = "; ".join(sorted(set(w[:120] for w in r.warnings))) or "none"
        lines.append(f"| {case} | {state} | {r.wall:.1f} | {r.cpu:.1f} | {_f(r.loading)} ({_f(r.cpu_loading)}) "
                     f"| {_f(r.render_compile)} | {_f(r.render, '{:.2f}')} | {built} | {r.cache_mib:.0f} "
                     f"| {r.peak_rss_mib:.0f} | {warned} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="sphere,wif", help="comma-separated: sphere, wif")
    parser.add_argument("--wif", default=None, help="the WIF case's pattern file")
    parser.add_argument("--nice", type=int, default=0, help="niceness of the child processes")
    parser.add_argument("--echo", action="store_true", help="show the children's output")
    parser.add_argument("--src", default=None, help="the package's src/ directory to measure (default: this checkout's)")
    parser.add_argument("--out", help="also append the Markdown table to this file")
    args = parser.parse_args(argv)
    if args.src:
        global SRC
        SRC = Path(args.src).resolve()
    cases = [c for c in args.cases.split(",") if c]
    wif = Path(args.wif) if args.wif else (DEFAULT_WIF if DEFAULT_WIF.is_file()
                                          else next(iter(sorted((ROOT / "tests" / "data").rglob("*.wif"))), None))
    if "wif" in cases and (wif is None or not wif.is_file()):
        raise SystemExit(f"first_picture: no WIF file for the wif case ({args.wif or DEFAULT_WIF}); give --wif")
    startup = start_up(args.nice)
    rows = []
    for case in cases:
        if case not in ("sphere", "wif"):
            raise SystemExit(f"first_picture: unknown case {case!r} (sphere, wif)")
        for state, run in measure_case(case, wif, args.nice, args.echo):
            rows.append((case if case == "sphere" else f"wif ({wif.name})", state, run))
            print(f"{case} {state}: {run.wall:.1f} s wall, {run.cpu:.1f} s CPU", file=sys.stderr, flush=True)
    text = table(rows, startup, args.nice, argv if argv is not None else sys.argv[1:])
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from common import emit

    emit(text, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
