"""Whether this machine's LLVM still folds the sign of ``select(|x| > 0, x, 0)`` wrongly
(docs/performance-log.md L67), and whether Mitsuba's ``uniform_hemisphere_to_square``
is still wrong for a direction with literal x, y and a computed z because of it. When
both print "right", ``sat_queries.hemisphere_to_square`` could give way to Mitsuba's map.

    .venv/bin/python bench/llvm_sign_fold.py
"""
from __future__ import annotations

import sys


def main() -> int:
    from common import setup_mitsuba
    mi = setup_mitsuba()
    import drjit as dr

    from mscloth.bsdf.sat_queries import hemisphere_to_square

    x = dr.opaque(mi.Float, -0.3, 8)
    folded = dr.select(dr.abs(x) > 0.0, x, 0.0) < 0.0  # -0.3 < 0: True
    print(f"select(|x| > 0, x, 0) < 0 at x = -0.3: {'right' if dr.all(folded) else 'WRONG (folded to false)'}")

    z = dr.opaque(mi.Float, 0.9, 8)
    s = 1.0 / (0.4 ** 2 + 0.81) ** 0.5
    w = mi.Vector3f(-0.4 * s, 0.0, z * s)
    expected = mi.scalar_rgb.warp.uniform_hemisphere_to_square(mi.scalar_rgb.Vector3f(-0.4 * s, 0.0, 0.9 * s))
    for name, square in (("mi.warp.uniform_hemisphere_to_square", mi.warp.uniform_hemisphere_to_square),
                         ("sat_queries.hemisphere_to_square", hemisphere_to_square)):
        y = square(w).y
        ok = dr.all(dr.abs(y - expected[1]) < 1e-6)
        print(f"{name} at (-0.4, 0, z computed): y = {y[0]:.6f}, expected {expected[1]:.6f}: "
              f"{'right' if ok else 'WRONG'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
