"""The render kernel of a scene: its size (Dr.Jit operations) and the time LLVM takes to
compile it, from an empty kernel cache, in a child process per run (issues 20, 22).

    .venv/bin/python bench/kernel_size.py satin [--runs 2] [--attr LOOP_TEXELS=false]

Renders ``mscloth render SCENE`` (320x180, 16 spp, the table cache of ``MSCLOTH_CACHE``)
with Dr.Jit's kernel history on and prints the kernels of over 3000 operations that the
render launched. Compile times count every other job on the machine; interleave variants
(run the script once per variant, alternately) to compare them.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

from common import parse_settings

CHILD = r"""
import json, sys
import drjit as dr
import mscloth
from mscloth import cli, render
sys.path.insert(0, "bench")
from common import set_class_attributes
set_class_attributes(json.loads(sys.argv[1]))
original = render.render_progressive

def recorded(*args, **kwargs):
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clears it
    out = original(*args, **kwargs)
    dr.eval(out)
    dr.sync_thread()
    for h in dr.kernel_history():
        if h.get("operation_count", 0) > 3000:
            seconds = (h.get("codegen_time", 0.0) + h.get("backend_time", 0.0)) / 1000.0
            print("KERNEL", json.dumps({"ops": h["operation_count"], "cache_hit": bool(h["cache_hit"]),
                                        "compile_s": round(seconds, 2)}), flush=True)
    return out

render.render_progressive = recorded
cli.main(sys.argv[2:])
"""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--res", default="320x180")
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--attr", action="append", default=[], help="NAME=VALUE (a class attribute)")
    args = parser.parse_args(argv)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    attrs = json.dumps(parse_settings(args.attr))
    for run in range(args.runs):
        with tempfile.TemporaryDirectory() as tmp:
            env = dict(os.environ, DRJIT_CACHE_DIR=os.path.join(tmp, "kernels"))
            cmd = [sys.executable, "-c", CHILD, attrs, "render", args.scene, "--res", args.res,
                   "--spp", str(args.spp), "--out", os.path.join(tmp, "out.exr")]
            done = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
            if done.returncode != 0:
                print(done.stderr[-2000:], file=sys.stderr)
                return done.returncode
            for line in done.stdout.splitlines():
                if line.startswith("KERNEL "):
                    k = json.loads(line[len("KERNEL "):])
                    print(f"{args.scene} run {run + 1}: {k['ops']} operations, compiled in {k['compile_s']:.2f} s"
                          f"{' (cache hit)' if k['cache_hit'] else ''}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
