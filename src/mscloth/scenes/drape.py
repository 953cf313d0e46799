"""A procedurally draped cloth: a square sheet lying over a sphere and falling in folds."""
from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np


def drape_mesh(name: str = "drape", radius: float = 0.5, size: float = 1.6, folds: int = 7,
               resolution: int = 128, centre=(0.0, 0.0, 0.0), uv_size: float = 1.0,
               fold_depth: float = 0.12) -> "mi.Mesh":
    """Triangle mesh (with UVs in [0, uv_size]^2: ``uv_size = size`` gives UVs in the
    sheet's rest lengths, as a cloth simulator's are) of a ``size`` x ``size`` sheet draped over a
    sphere of ``radius`` resting on the ground y = 0 at ``centre``: the part within 80% of the
    radius follows the sphere's cap, the rest falls towards the ground in ``folds`` radial
    folds of relative depth ``fold_depth``. Positions are a smooth function of the sheet coordinates, so the mesh is valid
    (no self-intersections for the defaults)."""
    n = resolution
    s, t = np.meshgrid(np.linspace(-1.0, 1.0, n), np.linspace(-1.0, 1.0, n), indexing="xy")
    r = np.hypot(s, t) * 0.5 * size                    # distance on the sheet from its centre
    theta = np.arctan2(t, s)
    r0 = 0.8 * radius
    cap = np.minimum(r, r0)
    top = radius + np.sqrt(np.maximum(radius * radius - cap * cap, 0.0)) + 0.01 * radius
    beyond = np.maximum(r - r0, 0.0)
    # Beyond the cap the sheet falls steeply, pulled in and rippled into folds.
    # (The 2% lift away from the sphere fades in from the centre: a constant one tore a
    # small hole with a nub at the sheet's centre.)
    rho = cap + beyond * (0.45 + fold_depth * np.sin(folds * theta)) + 0.02 * radius * np.minimum(r / r0, 1.0)
    height = top - beyond * 1.1
    ground = 0.005
    height = np.maximum(height, ground + 0.02 * beyond)
    x = centre[0] + rho * np.cos(theta)
    z = centre[2] + rho * np.sin(theta)
    y = centre[1] + height
    positions = np.stack([x, y, z], axis=-1).reshape(-1, 3).astype(np.float32)
    uvs = uv_size * np.stack([(s + 1.0) * 0.5, (t + 1.0) * 0.5], axis=-1).reshape(-1, 2).astype(np.float32)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="xy")
    v00 = (j * n + i).ravel()
    v10, v01, v11 = v00 + 1, v00 + n, v00 + n + 1
    faces = np.concatenate([np.stack([v00, v10, v11], axis=1), np.stack([v00, v11, v01], axis=1)]).astype(np.uint32)

    mesh = mi.Mesh(name, len(positions), len(faces), has_vertex_normals=True, has_vertex_texcoords=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(positions.ravel())
    params["vertex_texcoords"] = mi.Float(uvs.ravel())
    params["faces"] = mi.UInt32(faces.ravel())
    params.update()
    mesh.recompute_vertex_normals()
    return mesh


def drape_ply(directory, **kw) -> str:
    """Write :func:`drape_mesh` as a PLY file in ``directory`` (named by its parameters
    and this module's source, so a changed generator never reuses an old mesh; written
    once, atomically) and return its path."""
    import hashlib
    import os

    from ..atomic import atomic_path
    from ..cache import mark_used

    digest = hashlib.sha256(repr(sorted(kw.items())).encode())
    digest.update(Path(__file__).read_bytes())
    key = digest.hexdigest()[:12]
    path = os.path.join(str(directory), f"drape-{key}.ply")
    if not os.path.exists(path):
        with atomic_path(path) as tmp:
            drape_mesh(**kw).write_ply(tmp)
    else:
        mark_used(path)  # for `mscloth cache --clear --older-than`
    return path


__all__ = ["drape_mesh", "drape_ply"]
