"""What ``mscloth compare`` renders: a built-in scene, multi-scale or brute force, and one
timed ``mi.render`` of it (see :mod:`.compare` for what the time leaves out)."""
from __future__ import annotations

import gc
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ClothError
from ..mitsuba_log import errors_only

#: Seeds: reference halves, multi-scale and brute-force curve points never share one.
REFERENCE_SEEDS = (1_000_000, 2_000_000)
MULTISCALE_SEED = 10_000
BRUTEFORCE_SEED = 20_000


def scene_dict(name: str, width: int, height: int, multiscale: bool, sampler: str | None = None) -> dict:
    """A built-in scene's dictionary; brute force (``multiscale=False``) differs only in its
    cloth BSDFs. ``sampler``: the pixel sampler (default: the scene's own)."""
    from ..scenes.builtin import builtin_scene, set_cloth_parameters
    from ..scenes.pixel_sampler import set_pixel_sampler

    scene = builtin_scene(name, width, height)
    if set_cloth_parameters(scene, multiscale=multiscale) == 0:
        raise ClothError(f"scene {name!r} has no cloth BSDF to compare")
    if sampler is not None:
        set_pixel_sampler(scene, sampler)
    return scene


@dataclass
class Render:
    spp: int                # the count the sampler took (stratified ones round some up)
    seed: int
    seconds: float          # wall time minus JIT compilation
    compile_seconds: float  # JIT compilation during the call
    image: np.ndarray = field(repr=False)


def with_scene_alone(load, use):
    """``use(scene)`` for a scene ``load()`` loads, the scene freed afterwards (``use`` keeps
    no reference to it). Timings of one scene's renders need it alone in memory: Dr.Jit
    traces a virtual call into every registered instance, so each render would also trace
    the BSDFs of every other loaded scene (docs/performance-log.md L51)."""
    scene = load()
    try:
        return use(scene)
    finally:
        del scene
        gc.collect()


def timed_render(scene, spp: int, seed: int) -> Render:
    """One ``mi.render`` read back to NumPy; time without the kernel compilation it triggered.
    A stratified sampler may take more than ``spp`` samples (multijitter: 32 -> 35); the
    result records the count taken, and Mitsuba's warning about it is not printed."""
    import mitsuba as mi

    from ..render import KernelCompilation

    gc.collect()  # see render.render_progressive: no plugin freed mid-trace
    with KernelCompilation() as compiling, errors_only():
        start = time.perf_counter()
        image = np.array(mi.render(scene, spp=spp, seed=seed))[..., :3]
        wall = time.perf_counter() - start
    compile_s = min(compiling.seconds, wall)
    taken = int(scene.sensors()[0].sampler().sample_count()) if scene.sensors() else spp
    return Render(taken, seed, max(wall - compile_s, 1e-6), compile_s, image.astype(np.float32))

