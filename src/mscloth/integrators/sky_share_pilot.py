"""How much of a uniform sky ``clothpath``'s control variate should take whole in a scene:
the share c of ``sky_share`` auto, from a short pilot render.

The control variate adds c times t = L_env (A - w) at a camera ray's first hit (A: the
BSDF's table albedo, w: its sampled direction's weight). The share that leaves a pixel the
least noise is c* = -Cov(F, T) / Var(T), F the pixel's estimate without it and T the
mean of t over the pixel's samples: 1 where every sampled direction sees the sky (an open
plane), less where a floor or a fold hides part of it (the floor's light varies with the
direction, not as the sky's). What c* takes off a pixel's variance, 1 - Var(F + c* T) /
Var(F), is weighed against what reading the table costs (a frame 6-18% longer,
performance log L65): below ``MIN_VARIANCE_CUT`` (a sun that outshines the sky, cloth whose
sampled weights barely vary) the share is 0 and no table is read. The cut is the one of the
pixels the share changes: those where a sample read a table (a floor's or the sky's pixels
add noise the share cannot touch, and would dilute it by how much of the frame they fill).

The pilot renders ``PILOT_PIXELS`` random pixels of the frame with the render's own sampler
and sample count, three times with independent seeds: the noise that counts is the pixel
estimate's, stratification included, not how the image varies across the frame, so the
statistics come from two renders' differences (E[(x1 - x2)(y1 - y2)] / 2 = Cov(x, y)); each
pixel weighs by 1 / (M^2 + ``RELMSE_EPS``), M its value in the third render: its relative
error as ``make bench`` measures it (``mscloth.evaluation.metrics``), without tying the weight
to the noise it weighs.

The pilot reads small tables of A (``PILOT_MAX_MIB``, cells a few times coarser): the share
comes from noise within pixels, which a cell's mean barely changes, so a scene that takes
none builds no full table (one within ``PILOT_MARGIN`` of taking one is measured again on
the full tables). Shares are kept in this process and on disk (``sky_shares/`` of
the table cache, a few hundred bytes each, keyed by the scene's description, the spp, the
variant and the code): a scene rendered again, in any process, runs no pilot."""
from __future__ import annotations

import hashlib
import json
import re
import warnings
from collections import OrderedDict
from dataclasses import asdict, dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from ..mitsuba_log import errors_only

#: Pixels of the pilot, each rendered three times at the render's sample count: its cuts vary
#: by +-0.01-0.015 between seeds on the built-in scenes (+-0.02-0.03 with 4096; L61).
PILOT_PIXELS = 8192
#: Its seeds (a scene gets the same share on every render).
PILOT_SEED = 7_919
#: The least cut in the relative variance of the pixels that read a table for which the
#: table is read. Its reads make a frame 6-18% longer (p; 16-37% before the table was laid
#: out by planes and skipped after first hits, L65), so it pays from a cut of p / (1 + p) =
#: 0.06-0.15; the satin plane's share lost at a make bench cut of 0.10-0.21 (p = 0.35 then).
#: Kept above that: the pilot's cut spreads by 0.02-0.05 between seeds, and the scenes it
#: keeps off (satin-plane 0.08-0.12, the sphere 0.08-0.13) would gain a few per cent at
#: most. The built-in scenes at 16 spp (performance log L64): swatch 0.19, drape 0.25, satin
#: 0.32, denim 0.38, plane 0.95 take it.
MIN_VARIANCE_CUT = 0.16
#: A cut this close under ``MIN_VARIANCE_CUT`` on the small tables is measured again on the
#: full ones (small tables' cuts ran from 0.017 lower to 0.095 higher on the built-in
#: scenes, L63: the drape 0.113 against 0.130).
PILOT_MARGIN = 0.03
#: The size of the pilot's tables of A (MiB; the full ones' ``sky_albedo.MAX_MIB``): cells
#: 32 times larger in area, built in a few hundred ms.
PILOT_MAX_MIB = 4.0
#: The pixels' weight is 1 / (M^2 + RELMSE_EPS), as in make bench's relMSE
#: (``mscloth.evaluation.metrics.RELMSE_EPS``, which a test keeps equal): a dark pixel's
#: error counts as absolute, not as a huge relative one.
RELMSE_EPS = 1e-2


@dataclass(frozen=True)
class SkySharePilot:
    """What the pilot measured and the share it chose."""

    share: float          #: the share used: ``optimal`` clipped to [0, 1], or 0
    optimal: float        #: c* = -Cov(F, T) / Var(T), relative, within a pixel (0 without variance)
    variance_cut: float   #: 1 - Var(F + c T) / Var(F) at c = ``optimal`` clipped to [0, 1]
    pixels: int           #: pixels that went into it


#: Shares measured in this process, by :func:`scene_key` (``make bench`` loads a scene for
#: each measurement): the last ``KEPT_SHARES``.
_SHARES: "OrderedDict[tuple, SkySharePilot]" = OrderedDict()
KEPT_SHARES = 16


def scene_key(scene, spp: int) -> tuple:
    """What a share is kept by: the scene's description (its ``to_string``: shapes, BSDFs,
    emitters, sensor, integrator) without the film's crop (and the sensor's resolution,
    which follows it) or the sampler's state, and ``spp``. A crop renders part
    of the same frame and gets the frame's share (the pilot's pixels span the whole film):
    ``make bench``'s regions are timed as crops of the frame whose noise they measure."""
    text = re.sub(r"(crop_size|crop_offset|resolution) = \[[^\]]*\],?", "", str(scene))
    # (The sampler's state, which a render changes; its count is ``spp``.)
    text = re.sub(r"(base_seed|sample_count|samples_per_wavefront|wavefront_size) = [^\n,]*,?", "", text)
    return text, int(spp)


#: The on-disk store's format and directory in the table cache (:mod:`mscloth.cache`).
FORMAT = "mscloth-sky-share/1"
SUBDIR = "sky_shares"


def share_path(key: tuple, cache_dir=None) -> Path:
    """Where the share of ``key`` is stored: its name hashes the key, the variant, the
    code and the settings that experiments change at run time."""
    from ..bsdf import sky_albedo
    from ..cache import default_cache_dir, source_fingerprint

    settings = (PILOT_PIXELS, PILOT_SEED, MIN_VARIANCE_CUT, RELMSE_EPS, PILOT_MAX_MIB, PILOT_MARGIN,
                sky_albedo.SAMPLES, sky_albedo.OUTER_INSETS, sky_albedo.NODES_PER_BIN,
                sky_albedo.OUTER_BIN_NODES, sky_albedo.SHAPE_STEPS)
    code = source_fingerprint("bsdf", "scattering", "integrators")
    hs = hashlib.sha256(f"{FORMAT}\n{code}\n{mi.variant()}\n{settings}\n{key[1]}\n".encode())
    hs.update(key[0].encode())
    root = default_cache_dir() if cache_dir is None else Path(cache_dir)
    return root / SUBDIR / f"{hs.hexdigest()}.json"


def kept_share(key: tuple) -> SkySharePilot | None:
    """The share measured for ``key`` in this process, or stored on disk by any; None if
    neither (an unreadable file counts as none)."""
    if key in _SHARES:
        return _SHARES[key]
    path = share_path(key)
    if not path.is_file():
        return None
    try:
        pilot = SkySharePilot(**json.loads(path.read_text()))
        if not all(np.isfinite([pilot.share, pilot.optimal, pilot.variance_cut])) or not 0.0 <= pilot.share <= 1.0:
            raise ValueError("share out of range")
    except Exception as exc:  # noqa: BLE001 (any damage: measure again)
        warnings.warn(f"mscloth: ignoring stored sky share {path}: {exc}", RuntimeWarning, stacklevel=2)
        return None
    from ..cache import mark_used

    mark_used(path)
    return _keep(key, pilot)


def _keep(key: tuple, pilot: SkySharePilot) -> SkySharePilot:
    _SHARES[key] = pilot
    while len(_SHARES) > KEPT_SHARES:
        _SHARES.popitem(last=False)
    return pilot


def keep_share(key: tuple, pilot: SkySharePilot, store: bool = True) -> SkySharePilot:
    """Keep ``pilot`` for ``key`` in this process and, with ``store``, on disk (a cache
    that cannot be written only costs a pilot next time); returns it."""
    from ..atomic import atomic_write

    if store:
        path = share_path(key)
        try:
            atomic_write(path, lambda f: f.write(json.dumps(asdict(pilot)).encode()))
        except OSError as exc:
            warnings.warn(f"mscloth: cannot store sky share {path}: {exc}", RuntimeWarning, stacklevel=2)
    return _keep(key, pilot)


def pilot_pixels(sensor) -> tuple[np.ndarray, np.ndarray]:
    """(x, y): PILOT_PIXELS random pixels (seed PILOT_SEED) of ``sensor``'s whole film (not
    only its crop)."""
    w, h = sensor.film().size()
    rng = np.random.default_rng(PILOT_SEED)
    return rng.integers(0, w, PILOT_PIXELS), rng.integers(0, h, PILOT_PIXELS)


def render_sample_count(sensor, spp: int) -> int:
    """The samples per pixel a render asked for ``spp`` takes with ``sensor``'s sampler (a
    stratified sampler rounds up to a square: 128 -> 144), which the pilot renders with
    and keeps its share by. Asked quietly: Mitsuba warns of each rounded count, and the
    render that asked warns once itself."""
    sampler = sensor.sampler().clone()
    with errors_only():
        sampler.set_sample_count(int(spp))
    return int(sampler.sample_count())


def camera_rays(sensor, x: np.ndarray, y: np.ndarray, spp: int, seed: int):
    """(rays, sampler): ``spp`` camera rays (whole-pixel differentials) through each pixel
    (``x``, ``y``), pixel after pixel, placed by a copy of ``sensor``'s sampler seeded with
    ``seed`` (its stratification over each pixel's samples, as in a render), and the
    sampler their paths go on drawing from."""
    film = sensor.film()
    sampler = sensor.sampler().clone()
    sampler.set_sample_count(spp)
    if sampler.sample_count() != spp:
        raise ValueError(f"sky share pilot: {spp} spp is not a count the sensor's sampler takes "
                         f"(it would render {sampler.sample_count()}: see render_sample_count)")
    # (As a render of one pass sets it: a previous render's value would change the strata.)
    sampler.set_samples_per_wavefront(spp)
    sampler.seed(seed, len(x) * spp)
    index = dr.arange(mi.UInt32, len(x) * spp) // spp
    pixel = mi.Point2f(dr.gather(mi.Float, mi.Float(np.asarray(x, np.float32)), index),
                       dr.gather(mi.Float, mi.Float(np.asarray(y, np.float32)), index))
    # The sensor's sample positions span the film's crop (pixels outside it lie beyond [0, 1]).
    offset, size = mi.ScalarVector2f(film.crop_offset()), mi.ScalarVector2f(film.crop_size())
    position = (pixel + sampler.next_2d() - offset) / size
    rays, _ = sensor.sample_ray_differential(mi.Float(0.0), sampler.next_1d(), position, sampler.next_2d())
    return rays, sampler


def choose_share(F, T, M, min_cut: float = MIN_VARIANCE_CUT) -> SkySharePilot:
    """The share from the pilot's pixel estimates (luminance): ``F`` (2, pixels) two
    independent renders without the control variate, ``T`` (2, pixels) its mean term at
    c = 1 in the same renders, ``M`` (pixels) a third render, which weighs each pixel by
    1 / (M^2 + RELMSE_EPS). Pixels that are not finite in any of them are left out, and
    those whose T is 0 in both renders (no sample read a table: the share does not change
    them)."""
    F, T, M = (np.asarray(a, dtype=np.float64) for a in (F, T, M))
    df, dt = F[0] - F[1], T[0] - T[1]
    ok = np.isfinite(df) & np.isfinite(dt) & np.isfinite(M) & ((T[0] != 0.0) | (T[1] != 0.0))
    df, dt, M = df[ok], dt[ok], M[ok]
    if not df.size:
        return SkySharePilot(0.0, 0.0, 0.0, 0)
    weight = 1.0 / (M * M + RELMSE_EPS)
    var_f, var_t, cov = (float(np.sum(weight * a * b)) for a, b in ((df, df), (dt, dt), (df, dt)))
    if not (var_t > 0.0 and var_f > 0.0):
        return SkySharePilot(0.0, 0.0, 0.0, int(df.size))
    optimal = -cov / var_t
    share = float(np.clip(optimal, 0.0, 1.0))
    cut = 1.0 - (var_f + 2.0 * share * cov + share * share * var_t) / var_f
    return SkySharePilot(share if cut >= min_cut else 0.0, float(optimal), float(cut), int(df.size))
