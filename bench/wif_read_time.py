"""How long ``read_wif`` takes on jacquard-sized drafts (performance log L70): a 2048 x 2048
twill on 1024 shafts (tie-up and treadling) and a 4096 x 4096 liftplan on 2048 shafts, written
to a temporary folder; the fastest of ``--rounds`` reads each. ``--src DIR`` reads with
another checkout's ``src`` (an older reader, for a before/after in one run).

    .venv/bin/python bench/wif_read_time.py
    .venv/bin/python bench/wif_read_time.py --src /tmp/worktree/src
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path


def twill_wif(n: int, shafts: int) -> str:
    """An n x n draft: end j on shaft j mod ``shafts``, pick i on treadle i mod ``shafts``,
    treadle t tied to shafts t..t+shafts/2 (a balanced twill)."""
    tieup = "\n".join(f"{t + 1}=" + ",".join(str((t + k) % shafts + 1) for k in range(shafts // 2))
                      for t in range(shafts))
    return "\n".join([
        "[WIF]", "Version=1.1", "Date=2026", "Developers=mscloth", "Source Program=bench",
        "[CONTENTS]", "WEAVING=true", "WARP=true", "WEFT=true", "THREADING=true", "TIEUP=true",
        "TREADLING=true",
        "[WEAVING]", f"Shafts={shafts}", f"Treadles={shafts}", "Rising Shed=true",
        "[WARP]", f"Threads={n}", "Units=mm", "Spacing=0.5",
        "[WEFT]", f"Threads={n}", "Units=mm", "Spacing=0.5",
        "[THREADING]", *(f"{j + 1}={j % shafts + 1}" for j in range(n)),
        "[TIEUP]", tieup,
        "[TREADLING]", *(f"{i + 1}={i % shafts + 1}" for i in range(n)), ""])


def liftplan_wif(n: int, shafts: int) -> str:
    """An n x n draft lifted by a liftplan: pick i lifts shafts i..i+shafts/2."""
    lifts = (",".join(str((i + k) % shafts + 1) for k in range(shafts // 2)) for i in range(n))
    return "\n".join([
        "[WIF]", "Version=1.1", "Date=2026", "Developers=mscloth", "Source Program=bench",
        "[CONTENTS]", "WEAVING=true", "WARP=true", "WEFT=true", "THREADING=true", "LIFTPLAN=true",
        "[WEAVING]", f"Shafts={shafts}", "Rising Shed=true",
        "[WARP]", f"Threads={n}", "Units=mm", "Spacing=0.5",
        "[WEFT]", f"Threads={n}", "Units=mm", "Spacing=0.5",
        "[THREADING]", *(f"{j + 1}={j % shafts + 1}" for j in range(n)),
        "[LIFTPLAN]", *(f"{i + 1}={s}" for i, s in enumerate(lifts)), ""])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--src", default=str(Path(__file__).resolve().parents[1] / "src"))
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    sys.path.insert(0, args.src)
    from mscloth.patterns.wif import read_wif

    cases = (("twill 2048 x 2048, 1024 shafts", twill_wif(2048, 1024)),
             ("liftplan 4096 x 4096, 2048 shafts", liftplan_wif(4096, 2048)))
    with tempfile.TemporaryDirectory() as tmp:
        print(f"read_wif from {args.src}, fastest of {args.rounds}:")
        for label, text in cases:
            path = Path(tmp) / "draft.wif"
            path.write_text(text)
            best = float("inf")
            for _ in range(args.rounds):
                started = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    draft = read_wif(path)
                best = min(best, time.perf_counter() - started)
            print(f"  {label}: {best:.2f} s (drawdown {draft.drawdown.shape[0]}x{draft.drawdown.shape[1]})",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
