"""The ``clothpath`` integrator: same estimator as Mitsuba's ``path``, plus pixel footprints.

Images are small (24x24 or 32x32) and use the LLVM variant set in conftest.py.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mscloth.bsdf.footprint_estimator import FootprintEstimator
from mscloth.integrators import clothpath_class, register_integrators
from mscloth.integrators import footprint as fp

register_integrators()


# ----------------------------------------------------------------------------------------
# Scenes
# ----------------------------------------------------------------------------------------

def cornell_dict(integrator: dict) -> dict:
    """Cornell box (diffuse walls, area light), a rough-metal box, open front to a constant sky."""
    s = mi.cornell_box()
    s["sensor"]["film"]["width"] = 24
    s["sensor"]["film"]["height"] = 24
    s["sensor"]["film"]["pixel_format"] = "rgba"
    s["sensor"]["film"]["rfilter"] = {"type": "box"}
    s["small-box"]["bsdf"] = {"type": "roughconductor", "material": "Au", "alpha": 0.2}
    s["env"] = {"type": "constant", "radiance": {"type": "rgb", "value": [0.3, 0.3, 0.4]}}
    s["integrator"] = integrator
    return s


def envmap_dict(integrator: dict) -> dict:
    """Only an environment map (sky gradient + a small bright sun) lights a floor and spheres
    (rough metal, glass: delta paths and a relative IOR in Russian roulette)."""
    h, w = 32, 64
    theta = (np.arange(h) + 0.5) / h * np.pi
    phi = (np.arange(w) + 0.5) / w * 2 * np.pi
    sky = np.zeros((h, w, 3), dtype=np.float32)
    sky[...] = (0.2 + 0.8 * np.cos(theta)[:, None, None].clip(0, 1)) * np.array([0.4, 0.6, 1.0])
    sun = np.exp(-((theta[:, None] - 0.6) ** 2 + (phi[None, :] - 2.0) ** 2) / 0.01)
    sky += (20.0 * sun)[..., None] * np.array([1.0, 0.9, 0.7], dtype=np.float32)
    return {
        "type": "scene",
        "integrator": integrator,
        "sensor": {
            "type": "perspective", "fov": 40,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, -4, 2.5], target=[0, 0, 0.3],
                                                       up=[0, 0, 1]),
            "film": {"type": "hdrfilm", "width": 24, "height": 24, "pixel_format": "rgba",
                     "rfilter": {"type": "box"}},
        },
        "sky": {"type": "envmap", "bitmap": mi.Bitmap(sky.astype(np.float32)),
                "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90)},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(3),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.5, 0.4]}}},
        "metal": {"type": "sphere", "center": [-0.8, 0, 0.6], "radius": 0.6,
                  "bsdf": {"type": "roughconductor", "material": "Cu", "alpha": 0.3}},
        "glass": {"type": "sphere", "center": [0.8, 0.2, 0.6], "radius": 0.6,
                  "bsdf": {"type": "dielectric"}},
    }


SCENES = {"cornell": cornell_dict, "envmap": envmap_dict}
CONFIGS = [{}, {"max_depth": 1}, {"max_depth": 2}, {"max_depth": 3},
           {"hide_emitters": True}, {"rr_depth": 1}]


def render(scene, spp, seed):
    return np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)


def load(name, integrator_type, config, emitter_sampling="one"):
    """`path` or `clothpath` (by default picking one emitter per vertex, as `path` does)."""
    if integrator_type == "clothpath":
        config = dict({"footprint_aovs": True, "emitter_sampling": emitter_sampling}, **config)
    else:  # `path` has one emitter sample per vertex
        config = {k: v for k, v in config.items() if k != "emitter_samples"}
    return mi.load_dict(SCENES[name](dict(type=integrator_type, **config)))


# ----------------------------------------------------------------------------------------
# 1. Same estimator as `path`
# ----------------------------------------------------------------------------------------

def test_aovs_are_opt_in():
    plain = mi.load_dict(SCENES["cornell"](dict(type="clothpath")))
    assert plain.integrator().aov_names() == []
    assert render(plain, 1, 0).shape == (24, 24, 4)


def test_aov_names_and_channels():
    scene = load("cornell", "clothpath", {})
    assert scene.integrator().aov_names() == ["footprint_u", "footprint_v", "footprint_texels_u",
                                              "footprint_texels_v"]
    img = render(scene, 1, 0)
    assert img.shape == (24, 24, 8)  # R, G, B, A, the four footprint AOVs
    assert np.all(img[..., 6:] == 0.0)  # no footprint-shading BSDF in the Cornell box


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: ",".join(f"{k}={v}" for k, v in c.items()) or "default")
def test_same_seed_same_image_as_path(name, config):
    """Same random numbers in the same order: the image (colour and alpha) equals `path`'s
    up to float rounding."""
    ref = render(load(name, "path", config), 16, seed=7)
    ours = render(load(name, "clothpath", config), 16, seed=7)[..., :4]
    assert np.all(np.isfinite(ours))
    assert ref[..., :3].max() > 0.05  # the scene is not black
    diff = np.abs(ours - ref)
    assert diff.max() <= 1e-4 * max(1.0, ref.max()), diff.max()


def _region_means(imgs: np.ndarray, block: int) -> np.ndarray:
    """Per-pass means over the whole image and over block x block tiles: (passes, regions, 3)."""
    p, h, w, c = imgs.shape
    tiles = imgs.reshape(p, h // block, block, w // block, block, c).mean(axis=(2, 4))
    return np.concatenate([imgs.mean(axis=(1, 2))[:, None, :],
                           tiles.reshape(p, -1, c)], axis=1)


@pytest.mark.parametrize("emitter_sampling", ["one", "all"])
@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("config", [{}, {"max_depth": 2}, {"hide_emitters": True}, {"emitter_samples": 3}],
                         ids=["default", "max_depth=2", "hide_emitters", "emitter_samples=3"])
def test_agrees_with_path_in_expectation(name, config, emitter_sampling):
    """Independent seeds, 16 passes x 64 spp each: the image mean and 4x4 tile means agree
    with `path` within 5 standard errors, the errors estimated from the pass-to-pass spread.
    With ``emitter_sampling=all`` (every emitter sampled at each vertex, except the cornell
    box's constant sky, left to BSDF sampling) or several emitter samples per vertex (MIS
    weighted by their count) the estimator differs from `path`'s but must converge to the
    same image."""
    passes, spp = 16, 64
    ref_scene = load(name, "path", config)
    our_scene = load(name, "clothpath", config, emitter_sampling)
    ref = np.stack([render(ref_scene, spp, seed=i)[..., :3] for i in range(passes)])
    ours = np.stack([render(our_scene, spp, seed=1000 + i)[..., :3] for i in range(passes)])
    r, o = _region_means(ref, 6), _region_means(ours, 6)
    diff = o.mean(axis=0) - r.mean(axis=0)
    se = np.sqrt(o.var(axis=0, ddof=1) / passes + r.var(axis=0, ddof=1) / passes)
    scale = np.abs(r.mean(axis=0)) + 1e-3
    # A region without noise (e.g. only the light or only the sky) must match to rounding.
    tol = 5.0 * se + 1e-5 * scale
    worst = np.max(np.abs(diff) / tol)
    assert worst <= 1.0, (worst, diff, se)


#: The square's reflectance and the sky's radiance of :func:`square_under_sky`.
SQUARE_REFLECTANCE = np.array([0.5, 0.4, 0.3])
SKY_RADIANCE = np.array([1.0, 2.0, 3.0])


def square_under_sky(mode="all", square_bsdf=None, **shapes):
    """A square (diffuse SQUARE_REFLECTANCE unless ``square_bsdf``) that fills a 16 x 16
    view, under a constant sky of SKY_RADIANCE, with ``emitter_sampling`` ``mode`` and the
    extra ``shapes``, loaded."""
    if square_bsdf is None:
        square_bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": SQUARE_REFLECTANCE.tolist()}}
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "clothpath", "emitter_sampling": mode},
        "sensor": {"type": "perspective", "fov": 20,  # every pixel on the square
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16}},
        "square": {"type": "rectangle", "bsdf": square_bsdf},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": SKY_RADIANCE.tolist()}},
        **shapes})


def test_uniform_environment_is_left_to_bsdf_sampling():
    """A diffuse square under a constant sky only: with ``all`` the sky is reached by
    cosine-weighted BSDF samples alone, whose weight is the albedo, so every pixel on the
    square is albedo x radiance at 1 spp without noise; ``one`` (Mitsuba's MIS with uniform
    sphere samples of the sky) is noisy."""
    expected = SKY_RADIANCE * SQUARE_REFLECTANCE
    every = render(square_under_sky("all"), 1, 0)[..., :3].reshape(-1, 3)
    one = render(square_under_sky("one"), 1, 0)[..., :3].reshape(-1, 3)
    np.testing.assert_allclose(every, np.broadcast_to(expected, every.shape), rtol=1e-5)
    assert np.abs(one - expected).max() > 0.05


def test_same_seed_same_image_whatever_order_the_loader_lists_emitters():
    """Mitsuba lists emitters in the order its parallel loader finished them; with ``all``
    each emitter draws its own sample numbers, so clothpath puts them in an order of the
    scene's own (ids) first. Loaded serially, the loader lists them in reverse insertion
    order: two insertion orders give two emitter orders and must give one image. A box
    pixel filter: a wider one splats each sample into neighbouring pixels with atomic adds,
    whose order between threads moves the last bit of a sum from run to run."""
    def light(x, colour):
        return {"type": "rectangle", "emitter": {"type": "area", "radiance": {"type": "rgb", "value": colour}},
                "to_world": mi.ScalarTransform4f().translate([x, 0, 2]).rotate([1, 0, 0], 180).scale(0.4)}
    lights = {"red": light(-1, [5, 1, 1]), "green": light(0, [1, 5, 1]), "blue": light(1, [1, 1, 5])}
    images, orders = [], []
    for names in (("red", "green", "blue"), ("blue", "green", "red")):
        scene = {"type": "scene", "integrator": {"type": "clothpath"},
                 "sensor": {"type": "perspective", "fov": 60,
                            "to_world": mi.ScalarTransform4f().look_at(origin=[0, -3, 3], target=[0, 0, 0], up=[0, 0, 1]),
                            "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}}},
                 "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(3)}}
        scene.update((name, lights[name]) for name in names)
        loaded = mi.load_dict(scene, parallel=False)
        orders.append([e.get_shape().id() for e in loaded.emitters()])
        images.append(render(loaded, 4, 7))
    assert orders[0] != orders[1]  # else this test shows nothing
    np.testing.assert_array_equal(images[0], images[1])


#: A fresh process: loads a floor under a sky and a sun, the emitters constructed in the
#: order argv[1] names, renders, and prints the hash of its largest kernel.
_KERNEL_HASH_SCRIPT = """
import sys
import drjit as dr
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
import mscloth
mscloth.register()
emitters = {"sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.5, 0.6, 0.7]}},
            "sun": {"type": "directional", "direction": [0.3, -0.4, -1.0]}}
scene = {"type": "scene", "integrator": {"type": "clothpath"},
         "sensor": {"type": "perspective", "fov": 60,
                    "to_world": mi.ScalarTransform4f().look_at(origin=[0, -3, 3], target=[0, 0, 0], up=[0, 0, 1]),
                    "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}}},
         "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(3)}}
scene.update((name, emitters[name]) for name in sys.argv[1].split(","))
loaded = mi.load_dict(scene, parallel=False)
dr.set_flag(dr.JitFlag.KernelHistory, True)
mi.render(loaded, spp=2, seed=0)
kernels = [k for k in dr.kernel_history() if "operation_count" in k]
print(max(kernels, key=lambda k: k["operation_count"])["hash"])
"""


def test_one_kernel_whichever_emitter_the_loader_constructed_first():
    """Mitsuba's parallel loader constructs emitters in an order that varies from run to run,
    and an escaped ray's environment emitter entered the kernel as a literal (its index in
    that order): two kernels, so a warm render missed Dr.Jit's kernel cache now and then.
    clothpath reads the environment through an opaque pointer: two fresh processes that
    construct the emitters in either order trace the same kernel. (In one process the
    second scene's emitters get new indices, so fresh processes it is.)"""
    import subprocess
    import sys

    hashes = [subprocess.run([sys.executable, "-c", _KERNEL_HASH_SCRIPT, order], capture_output=True, text=True,
                             check=True, timeout=300).stdout.split()[-1]
              for order in ("sky,sun", "sun,sky")]
    assert hashes[0] == hashes[1]


def test_max_depth_one_is_emitters_only():
    """max_depth=1: only directly visible emitters (the light, the sky); walls black until
    max_depth=2; max_depth=0: black and transparent."""
    one = render(load("cornell", "clothpath", {"max_depth": 1}), 4, 0)
    two = render(load("cornell", "clothpath", {"max_depth": 2}), 4, 0)
    light = one[..., :3].max(axis=2) > 1.0
    assert light.any()
    rest = one[~light][:, :3]
    # Elsewhere only the sky (0.3, 0.3, 0.4) times the fraction of the pixel that sees it.
    assert np.allclose(rest[:, 1], rest[:, 0]) and np.allclose(rest[:, 2], rest[:, 0] * 4 / 3)
    walls = ~light & (one[..., :3].max(axis=2) == 0)
    assert walls.sum() > 100 and two[walls][:, :3].mean() > 0.02
    zero = render(load("cornell", "clothpath", {"max_depth": 0}), 4, 0)
    assert np.all(zero[..., :4] == 0)


def test_hide_emitters_hides_light_and_sky():
    shown = render(load("cornell", "clothpath", {"max_depth": 1}), 4, 0)
    hidden = render(load("cornell", "clothpath", {"max_depth": 1, "hide_emitters": True}), 4, 0)
    assert shown[..., :3].max() > 1.0
    assert np.all(hidden[..., :3] == 0)
    # Pixels seeing some sky become (partly) transparent; pixels on walls stay opaque.
    some_sky = (shown[..., 0] > 0) & (shown[..., :3].max(axis=2) < 1.0)
    walls = shown[..., :3].max(axis=2) == 0
    assert some_sky.any() and np.all(hidden[some_sky][:, 3] < 1)
    assert np.all(shown[..., 3] == 1) and np.all(hidden[walls][:, 3] == 1)


def test_invalid_parameters():
    """Bad properties raise mscloth's ParameterError (Mitsuba's loader names it in the
    RuntimeError it raises in its place)."""
    error = "ParameterError: clothpath: "
    with pytest.raises(Exception, match=error + '"max_depth"'):
        mi.load_dict({"type": "clothpath", "max_depth": -2})
    with pytest.raises(Exception, match=error + '"rr_depth"'):
        mi.load_dict({"type": "clothpath", "rr_depth": 0})
    with pytest.raises(Exception, match=error + '"emitter_sampling" must be "all" or "one"'):
        mi.load_dict({"type": "clothpath", "emitter_sampling": "some"})
    for bad in (0, 257, 2.5):
        with pytest.raises(Exception, match=error + '"emitter_samples" must be an integer in'):
            mi.load_dict({"type": "clothpath", "emitter_samples": bad})
    for name in ("gap_shadows", "scattered_footprints", "footprint_aovs"):
        with pytest.raises(Exception, match=error + f'"{name}" must be a boolean'):
            mi.load_dict({"type": "clothpath", name: "yes"})
    with pytest.raises(Exception, match=error + '"uv_filter" must be "box" or "tent"'):
        mi.load_dict({"type": "clothpath", "uv_filter": "gaussian"})


def test_registration_is_idempotent():
    cls = clothpath_class()
    register_integrators()
    assert clothpath_class() is cls
    assert isinstance(mi.load_dict({"type": "clothpath"}), cls)


# ----------------------------------------------------------------------------------------
# 2. Footprint at the first hit: the whole pixel, whatever the sample count
# ----------------------------------------------------------------------------------------

def square_view(n_across: int, res: int = 32, tilt_deg: float = 0.0, sensor: str = "perspective",
                bsdf: dict | None = None, spp: int | None = None) -> dict:
    """Camera on the z axis looking at the unit-UV rectangle [-1, 1]^2 (optionally tilted
    about the y axis, i.e. along u), which spans exactly ``n_across`` of ``res`` pixels."""
    dist = 4.0
    film = {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}
    to_world = mi.ScalarTransform4f().look_at(origin=[0, 0, dist], target=[0, 0, 0], up=[0, 1, 0])
    if sensor == "perspective":
        half = math.atan(res / n_across / dist)  # half the field of view
        cam = {"type": "perspective", "fov": 2 * math.degrees(half), "near_clip": 1e-4,
               "to_world": to_world, "film": film}
    else:  # orthographic: the view spans 2 res / n_across units
        cam = {"type": "orthographic", "near_clip": 1e-4, "film": film,
               "to_world": to_world @ mi.ScalarTransform4f().scale([res / n_across, res / n_across, 1])}
    if spp is not None:
        cam["sampler"] = {"type": "independent", "sample_count": spp}
    return {
        "type": "scene",
        "integrator": {"type": "clothpath", "footprint_aovs": True},
        "sensor": cam,
        "square": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], tilt_deg),
                   "bsdf": bsdf or {"type": "diffuse"}},
        "sky": {"type": "constant"},
    }


@pytest.mark.parametrize("spp", [1, 16])
def test_first_hit_footprint_is_one_pixel(spp):
    n = 16
    img = render(mi.load_dict(square_view(n)), spp, 0)
    fu, fv = img[..., 3], img[..., 4]
    c = slice(13, 19)  # pixels well inside the square
    assert np.allclose(fu[c, c], 1 / (2 * n), rtol=5e-3), fu[c, c]
    assert np.allclose(fv[c, c], 1 / (2 * n), rtol=5e-3), fv[c, c]
    assert np.all(fu[:4, :4] == 0)  # sky: no footprint


def test_footprint_uses_the_sample_count_from_the_scene_sampler():
    """The scale to undo is the one Mitsuba applied: spp from the sensor's sampler too."""
    img = render(mi.load_dict(square_view(16, spp=64)), 0, 0)
    assert np.allclose(img[14:18, 14:18, 3], 1 / 32, rtol=5e-3)


def test_first_hit_footprint_oblique_orthographic():
    """Orthographic camera: the footprint is exactly one pixel wide; tilting the square by
    60 degrees about v stretches it along u by 1/cos(60) = 2 and leaves v alone."""
    n = 16
    head_on = render(mi.load_dict(square_view(n, sensor="orthographic")), 4, 0)
    tilted = render(mi.load_dict(square_view(n, sensor="orthographic", tilt_deg=60)), 4, 0)
    c = slice(14, 18)
    assert np.allclose(head_on[c, c, 3], 1 / (2 * n), rtol=1e-3)
    assert np.allclose(tilted[c, c, 3], 2 / (2 * n), rtol=1e-3)
    assert np.allclose(tilted[c, c, 4], 1 / (2 * n), rtol=1e-3)


# ----------------------------------------------------------------------------------------
# What the BSDF sees: a probe BSDF turns si.duv_dx / si.duv_dy into radiance
# ----------------------------------------------------------------------------------------

class ZeroEval(mi.BSDF):
    """A test BSDF whose eval and pdf are zero everywhere (delta lobes only, or none)."""

    def eval(self, ctx, si, wo, active=True):
        return mi.Color3f(0.0)

    def pdf(self, ctx, si, wo, active=True):
        return mi.Float(0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return mi.Color3f(0.0), mi.Float(0.0)


class FootprintProbe(ZeroEval):
    """Delta transmission (light passes straight through) with weight ``scale * h_u``, h_u the
    u half-width of the footprint the BSDF receives: seen against a sky of radiance 1, a
    pixel's value is ``scale * h_u`` at the probe, without noise."""

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.scale = props.get("scale", 1.0)
        flags = mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        self.m_components = [flags]
        self.m_flags = flags

    def sample(self, ctx, si, sample1, sample2, active):
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = -si.wi
        bs.pdf = 1.0
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DeltaTransmission)
        bs.sampled_component = 0
        h_u = 0.5 * (dr.abs(si.duv_dx.x) + dr.abs(si.duv_dy.x))
        return bs, mi.Spectrum(self.scale * h_u) & active

    def to_string(self):
        return "FootprintProbe[]"


mi.register_bsdf("footprint_probe", lambda props: FootprintProbe(props))


class NormalTurnProbe(ZeroEval):
    """A mirror whose weight is how far the normal turns across the footprint it receives
    (``FootprintEstimator.normal_tilt``) over the footprint's size on the surface
    (|dp/duv si.duv_dx|, |dp/duv si.duv_dy|, the larger): 1 / radius on a sphere, whose
    normal is p / radius, and 0 on a flat shape."""

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        flags = mi.BSDFFlags.DeltaReflection | mi.BSDFFlags.FrontSide
        self.m_components = [flags]
        self.m_flags = flags

    def sample(self, ctx, si, sample1, sample2, active):
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = mi.reflect(si.wi)
        bs.pdf = 1.0
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DeltaReflection)
        bs.sampled_component = 0
        size = dr.maximum(dr.norm(si.dp_du * si.duv_dx.x + si.dp_dv * si.duv_dx.y),
                          dr.norm(si.dp_du * si.duv_dy.x + si.dp_dv * si.duv_dy.y))
        turn = FootprintEstimator.normal_tilt(si) * dr.rcp(dr.maximum(size, 1e-12))
        return bs, mi.Spectrum(turn) & active

    def to_string(self):
        return "NormalTurnProbe[]"


mi.register_bsdf("normal_turn_probe", lambda props: NormalTurnProbe(props))


def uv_sphere_mesh(radius: float, bsdf: dict, nu: int = 96, nv: int = 48):
    """A triangle mesh of a sphere with vertex normals and texcoords (u along the
    longitude, v along the latitude, as Mitsuba's sphere)."""
    theta, phi = np.meshgrid(np.linspace(0.0, np.pi, nv + 1), np.linspace(0.0, 2.0 * np.pi, nu + 1), indexing="ij")
    # The poles on the y axis: a camera on the z axis sees the equator.
    n = np.stack([np.sin(theta) * np.cos(phi), np.cos(theta), np.sin(theta) * np.sin(phi)], -1).reshape(-1, 3)
    uv = np.stack([phi / (2.0 * np.pi), theta / np.pi], -1).reshape(-1, 2)
    a = (np.arange(nv)[:, None] * (nu + 1) + np.arange(nu)[None, :]).ravel()
    faces = np.concatenate([np.stack([a, a + nu + 1, a + 1], 1), np.stack([a + 1, a + nu + 1, a + nu + 2], 1)])
    mesh = mi.Mesh("ball", len(n), len(faces), has_vertex_normals=True, has_vertex_texcoords=True,
                   props=mi.Properties())
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f(*(radius * n).T.astype(np.float32)))
    params["faces"] = dr.ravel(mi.Vector3u(*faces.astype(np.uint32).T))
    params["vertex_texcoords"] = dr.ravel(mi.Point2f(*uv.T.astype(np.float32)))
    params.update()
    mesh.recompute_vertex_normals()
    mesh.set_bsdf(mi.load_dict(bsdf))
    return mesh


def test_normal_derivatives_are_converted_only_where_a_mesh_needs_it():
    """Rectangles, disks and spheres give dn/duv per UV or zero (their scenes trace no
    conversion); a triangle mesh with vertex normals and texcoords needs it, one without
    normals does not."""
    probe = {"type": "normal_turn_probe"}
    flat = {"type": "scene", "a": {"type": "rectangle"}, "b": {"type": "sphere"}, "c": {"type": "disk"}}
    assert not fp.needs_uv_normal_derivatives(mi.load_dict(flat))
    assert fp.needs_uv_normal_derivatives(mi.load_dict(dict(flat, d=uv_sphere_mesh(1.0, probe))))
    faceted = mi.Mesh("faceted", 3, 1, has_vertex_normals=False, has_vertex_texcoords=True)
    assert not fp.needs_uv_normal_derivatives(mi.load_dict(dict(flat, d=faceted)))


def test_bsdf_sees_how_far_the_normal_turns_across_the_footprint():
    """``clothpath`` hands the BSDF the normal's derivatives per UV (RayFlags.dNSdUV, which
    RayFlags.All leaves out; Mitsuba's meshes give them per barycentric unit, which
    ``uv_normal_derivatives`` converts): the footprint estimator gives curved cloth's probes
    cells by them. A sphere of radius 2 reads 1/2 wherever it is seen, analytic or a mesh
    (within its facets' 2%); a flat square 0."""
    probe = {"type": "normal_turn_probe"}
    sensor = {"type": "perspective", "fov": 30,
              "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 10], target=[0, 0, 0], up=[0, 1, 0]),
              "film": {"type": "hdrfilm", "width": 32, "height": 32, "rfilter": {"type": "box"}}}
    for ball, rtol in (({"type": "sphere", "radius": 2.0, "bsdf": probe}, 1e-3), (uv_sphere_mesh(2.0, probe), 0.02)):
        scene = {"type": "scene", "integrator": {"type": "clothpath"}, "sensor": sensor, "ball": ball,
                 "sky": {"type": "constant"}}
        img = render(mi.load_dict(scene), 4, 0)
        np.testing.assert_allclose(img[10:22, 10:22, 0], 0.5, rtol=rtol)
    flat = render(mi.load_dict(square_view(16, bsdf=probe)), 4, 0)
    assert np.all(flat[13:19, 13:19, 0] == 0.0) and np.all(flat[:4, :4, 0] == 1.0)


def test_bsdf_receives_the_first_hit_footprint():
    n = 16
    img = render(mi.load_dict(square_view(n, bsdf={"type": "footprint_probe", "scale": 10.0})), 4, 0)
    c = slice(13, 19)
    assert np.allclose(img[c, c, 0], 10.0 / (2 * n), rtol=5e-3)
    assert np.allclose(img[c, c, 0], 10.0 * img[c, c, 3], rtol=1e-4)  # = 10 x the AOV


def mirror_scene(mirror_bsdf: dict | None, d1: float = 2.0, d2: float = 2.0, **integrator) -> dict:
    """A probe square (half-size 5, so dp_du = 10) seen head-on at total distance d1 + d2:
    directly (``mirror_bsdf`` None) or via a mirror at distance d1 (45 degrees incidence).
    ``integrator``: further clothpath properties."""
    res, fov = 8, 4.0
    film = {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}
    probe = {"type": "rectangle", "bsdf": {"type": "footprint_probe", "scale": 100.0}}
    s = {"type": "scene", "integrator": {"type": "clothpath", "footprint_aovs": True, **integrator},
         "sky": {"type": "constant"}}
    if mirror_bsdf is None:
        s["sensor"] = {"type": "perspective", "fov": fov, "near_clip": 1e-4, "film": film,
                       "to_world": mi.ScalarTransform4f().look_at(
                           origin=[0, 0, d1 + d2], target=[0, 0, 0], up=[0, 1, 0])}
        probe["to_world"] = mi.ScalarTransform4f().scale(5)
    else:
        r = 1 / math.sqrt(2)
        s["sensor"] = {"type": "perspective", "fov": fov, "near_clip": 1e-4, "film": film,
                       "to_world": mi.ScalarTransform4f().look_at(
                           origin=[0, -d1 * r, d1 * r], target=[0, 0, 0], up=[0, 0, 1])}
        s["mirror"] = {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(0.5),
                       "bsdf": mirror_bsdf}
        # Facing back along the reflected ray, centred on it at distance d2.
        probe["to_world"] = mi.ScalarTransform4f().look_at(
            origin=[0, d2 * r, d2 * r], target=[0, 0, 0], up=[1, 0, 0]) @ mi.ScalarTransform4f().scale(5)
    s["probe"] = probe
    return s


def test_footprint_after_a_mirror_equals_the_direct_one_at_equal_distance():
    """A flat mirror keeps the camera's spread: the probe sees the footprint of the total
    distance, as if looked at directly from that distance."""
    direct = render(mi.load_dict(mirror_scene(None)), 4, 0)[3:5, 3:5, 0]
    mirror = render(mi.load_dict(mirror_scene({"type": "conductor", "material": "none"})), 4, 0)[3:5, 3:5, 0]
    pixel_angle = 2 * math.tan(math.radians(2.0)) / 8
    expected = 100.0 * pixel_angle * 4.0 / 10.0 / 2  # scale * (width / |dp_du|) / 2
    assert np.allclose(direct, expected, rtol=1e-2), (direct, expected)
    assert np.allclose(mirror, direct, rtol=2e-2), (mirror, direct)


def test_footprint_after_a_rough_bounce_is_larger():
    """A rough bounce widens the cone: the probe behind a rough mirror sees a footprint many
    times the direct one at the same distance (with the spread rule: pixel spread ~0.009 rad,
    lobe of GGX alpha 0.2 adds ~0.5 rad). Without widening it would be about equal."""
    direct = render(mi.load_dict(mirror_scene(None)), 16, 0)[3:5, 3:5, 0].mean()
    rough = render(mi.load_dict(mirror_scene({"type": "roughconductor", "material": "none",
                                              "alpha": 0.2}, scattered_footprints=True)), 16, 0)[3:5, 3:5, 0].mean()
    assert rough > 10 * direct, (rough, direct)
    # ... yet bounded: the widest possible cone (MAX_SPREAD over d2 = 2) projected head-on.
    assert rough < 100.0 * (fp.MAX_SPREAD * 2.0 + 0.1) / 10.0 / 2 * 1.5


def test_no_footprint_after_a_rough_bounce_by_default():
    """By default only camera rays and their delta chains carry footprints: behind a rough
    mirror the probe sees a zero footprint, behind a smooth one the cone's."""
    rough = render(mi.load_dict(mirror_scene({"type": "roughconductor", "material": "none",
                                              "alpha": 0.2})), 16, 0)[3:5, 3:5, 0]
    assert np.all(rough == 0.0), rough
    smooth = render(mi.load_dict(mirror_scene({"type": "conductor", "material": "none"})), 4, 0)[3:5, 3:5, 0]
    assert np.all(smooth > 0.0), smooth
    with pytest.raises(Exception, match="\"scattered_footprints\" must be a boolean"):
        mi.load_dict({"type": "clothpath", "scattered_footprints": 1})


# ----------------------------------------------------------------------------------------
# 3. footprint.py, pure functions
# ----------------------------------------------------------------------------------------

def _np(x):
    return np.array(x, dtype=np.float64)


def test_cone_width_grows_linearly_with_distance():
    t = mi.Float(np.linspace(0.0, 10.0, 11))
    w = _np(fp.cone_width(mi.Float(0.05), mi.Float(0.01), t))
    assert np.allclose(w, 0.05 + 0.01 * np.linspace(0, 10, 11), rtol=1e-6)
    assert np.allclose(np.diff(w, 2), 0.0, atol=1e-6)


def test_camera_cone_of_a_pinhole_and_an_orthographic_camera():
    o = mi.Point3f(0, 0, 0)
    d = mi.Vector3f(0, 0, 1)
    ang = 0.01
    w, s = fp.camera_cone(o, d, o, mi.Vector3f(math.sin(ang), 0, math.cos(ang)),
                          o, mi.Vector3f(0, math.sin(ang), math.cos(ang)))
    assert _np(w)[0] == 0 and abs(_np(s)[0] - ang) < 1e-6
    w, s = fp.camera_cone(o, d, mi.Point3f(0.2, 0, 0), d, mi.Point3f(0, 0.2, 0), d)
    assert abs(_np(w)[0] - 0.2) < 1e-7 and _np(s)[0] == 0


def test_bounce_spread_rule():
    spread = mi.Float(0.01, 0.01, 0.01, 0.01, 0.01)
    pdf = mi.Float(1.0, 100.0, 10.0, 1 / math.pi, 0.0)
    delta = mi.Bool(True, False, False, False, False)
    out = _np(fp.bounce_spread(spread, pdf, delta))
    assert out[0] == pytest.approx(0.01)  # delta: unchanged
    assert out[1] == pytest.approx(0.01 + 2 / math.sqrt(math.pi * 100), rel=1e-5)
    assert out[2] == pytest.approx(0.01 + 2 / math.sqrt(math.pi * 10), rel=1e-5)
    assert out[1] < out[2] < out[3]  # rougher lobes (lower density) spread more
    assert out[3] == pytest.approx(fp.MAX_SPREAD)  # diffuse: capped
    assert out[4] == pytest.approx(0.01)  # no sample (pdf 0): unchanged
    assert np.all(np.isfinite(out))


def test_mis_weight_is_zero_where_a_density_is_undefined():
    """The power heuristic, and 0 (not pdf_a^2) where the other density is NaN: a footprint
    BSDF's NaN pdf once turned emitter samples' weights into their squared density
    (the cotton-jersey close view: fireflies and +11% brightness)."""
    from mscloth.integrators.clothpath import mis_weight

    a = mi.Float(2.0, 2.0, 2.0, 0.0, 2.0, math.inf)
    b = mi.Float(1.0, 0.0, math.nan, 0.0, math.inf, 1.0)
    out = _np(mis_weight(a, b))
    assert out[0] == pytest.approx(0.8)
    assert out[1] == pytest.approx(1.0)
    np.testing.assert_array_equal(out[2:], 0.0)


def test_differential_footprint_matches_mitsuba_uv_partials():
    """On a well-parameterised surface the robust solve equals compute_uv_partials."""
    scene = mi.load_dict({"type": "scene", "s": {"type": "sphere", "radius": 1.5}})
    rng = np.random.default_rng(1)
    n = 64
    o = mi.Point3f(*(rng.normal(size=(3, n)) * 0.15 + np.array([[0.2], [0.1], [5.0]])))
    d = dr.normalize(mi.Vector3f(*(rng.normal(size=(3, n)) * 0.05 + np.array([[0], [0], [-1.0]]))))
    ray = mi.RayDifferential3f(o, d)
    ray.o_x = o + mi.Vector3f(0.001, 0, 0)
    ray.o_y = o + mi.Vector3f(0, 0.002, 0)
    ray.d_x = dr.normalize(d + mi.Vector3f(0.003, 0.001, 0))
    ray.d_y = dr.normalize(d + mi.Vector3f(-0.001, 0.004, 0))
    ray.has_differentials = True
    si = scene.ray_intersect(mi.Ray3f(ray))
    assert dr.all(si.is_valid())
    dx, dy = fp.differential_footprint(si.p, si.n, si.dp_du, si.dp_dv,
                                       ray.o_x, ray.d_x, ray.o_y, ray.d_y)
    si.compute_uv_partials(ray)
    assert np.allclose(_np(dx), _np(si.duv_dx), rtol=1e-3, atol=1e-6)
    assert np.allclose(_np(dy), _np(si.duv_dy), rtol=1e-3, atol=1e-6)


def test_cone_footprint_head_on_and_oblique():
    dp_du, dp_dv = mi.Vector3f(2, 0, 0), mi.Vector3f(0, 3, 0)
    n = mi.Vector3f(0, 0, 1)
    w = mi.Float(0.06)
    dx, dy = fp.cone_footprint(w, mi.Vector3f(0, 0, -1), n, dp_du, dp_dv)
    hu, hv = (float(_np(h)[0]) for h in fp.half_widths(dx, dy))
    assert hu == pytest.approx(0.03 / 2, rel=1e-5) and hv == pytest.approx(0.03 / 3, rel=1e-5)
    assert _np(dx)[1, 0] == 0 and _np(dy)[0, 0] == 0  # axis-aligned box
    # 60 degrees from the normal, in the x-z plane: stretched by 2 along u only.
    th = math.radians(60)
    dx, dy = fp.cone_footprint(w, mi.Vector3f(math.sin(th), 0, -math.cos(th)), n, dp_du, dp_dv)
    hu, hv = (float(_np(h)[0]) for h in fp.half_widths(dx, dy))
    assert hu == pytest.approx(2 * 0.03 / 2, rel=1e-4) and hv == pytest.approx(0.03 / 3, rel=1e-4)
    # Rotation-free: at 45 degrees azimuth the box covers the rotated ellipse.
    d = mi.Vector3f(math.sin(th) / math.sqrt(2), math.sin(th) / math.sqrt(2), -math.cos(th))
    dx, dy = fp.cone_footprint(w, d, n, mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0))
    hu, hv = (float(_np(h)[0]) for h in fp.half_widths(dx, dy))
    r_major, r_minor = 0.03 * 2, 0.03
    expect = math.sqrt((r_major ** 2 + r_minor ** 2) / 2)
    assert hu == pytest.approx(expect, rel=1e-4) and hv == pytest.approx(expect, rel=1e-4)


# ----------------------------------------------------------------------------------------
# 4. Degenerate parameterisations and grazing angles
# ----------------------------------------------------------------------------------------

def _assert_capped(duv_dx, duv_dy):
    for v in (duv_dx, duv_dy):
        assert np.all(np.isfinite(_np(v)))
    for h in fp.half_widths(duv_dx, duv_dy):
        assert np.all(_np(h) <= fp.MAX_HALF_WIDTH * (1 + 1e-6))


def test_degenerate_and_grazing_footprints_are_finite():
    n = mi.Vector3f(0, 0, 1)
    zero = mi.Vector3f(0, 0, 0)
    # dp_du = 0 (a pole): the u extent is the whole range, v is regular.
    dx, dy = fp.cone_footprint(mi.Float(0.04), mi.Vector3f(0, 0, -1), n, zero, mi.Vector3f(math.pi, 0, 0))
    hu, hv = (float(_np(h)[0]) for h in fp.half_widths(dx, dy))
    assert hu == pytest.approx(fp.MAX_HALF_WIDTH) and hv == pytest.approx(0.02 / math.pi, rel=1e-5)
    # Both zero, parallel, grazing, zero width: all finite and within the cap.
    cases = [
        (mi.Float(0.04), mi.Vector3f(0, 0, -1), zero, zero),
        (mi.Float(0.04), mi.Vector3f(0, 0, -1), mi.Vector3f(1, 0, 0), mi.Vector3f(2, 0, 0)),
        (mi.Float(0.04), mi.Vector3f(1, 0, 0), mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0)),
        (mi.Float(0.0), mi.Vector3f(0, 0, -1), mi.Vector3f(1e-30, 0, 0), mi.Vector3f(0, 1, 0)),
        (mi.Float(1e30), mi.Vector3f(0, 0, -1), mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0)),
    ]
    for w, d, du, dv in cases:
        _assert_capped(*fp.cone_footprint(w, d, n, du, dv))
    # An offset ray parallel to the tangent plane.
    p = mi.Point3f(0, 0, 0)
    o = mi.Point3f(0, 0, 1)
    _assert_capped(*fp.differential_footprint(p, n, mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0),
                                              o, mi.Vector3f(1, 0, 0), o, mi.Vector3f(0, 0, -1)))


def test_sphere_pole_gives_finite_footprints():
    """Camera rays hitting a sphere at its pole, where dp_du = 0: finite AOVs and colours,
    u extent capped at the whole range, through the render loop and through sample()."""
    res = 33  # odd: the centre pixel holds the pole
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "clothpath", "footprint_aovs": True}, "sky": {"type": "constant"},
        "sensor": {"type": "perspective", "fov": 30, "film": {"type": "hdrfilm", "width": res, "height": res,
                                                               "rfilter": {"type": "box"}},
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])},
        "ball": {"type": "sphere", "bsdf": {"type": "footprint_probe", "scale": 1.0}},
    })
    img = render(scene, 16, 0)
    assert np.all(np.isfinite(img))
    assert np.all(img[..., 3:] <= fp.MAX_HALF_WIDTH)
    c = res // 2
    assert img[c, c, 3] > 10 * img[c, c, 4]  # many azimuths meet in the pole's pixel

    # Exactly at the pole, through sample() with a hand-made differential (not scaled: spp 1).
    sampler = mi.load_dict({"type": "independent", "sample_count": 1})
    sampler.seed(0, 1)
    ray = mi.RayDifferential3f(mi.Point3f(0, 0, 5), mi.Vector3f(0, 0, -1))
    ray.o_x = ray.o
    ray.o_y = ray.o
    ray.d_x = dr.normalize(mi.Vector3f(0.01, 0, -1))
    ray.d_y = dr.normalize(mi.Vector3f(0, 0.01, -1))
    ray.has_differentials = True
    si = scene.ray_intersect(mi.Ray3f(ray))
    assert dr.all(si.dp_du == 0)  # really the degenerate point
    spec, valid, aovs = scene.integrator().sample(scene, sampler, ray, None, True)
    fu, fv = float(_np(aovs[0])[0]), float(_np(aovs[1])[0])
    assert bool(_np(valid)[0]) and math.isfinite(fu) and math.isfinite(fv)
    assert fu == pytest.approx(fp.MAX_HALF_WIDTH)
    assert fv == pytest.approx(0.5 * 4 * 0.01 / math.pi, rel=1e-2)  # dv/dx = |dp|/|dp_dv|, pi
    assert np.all(np.isfinite(_np(spec)))


# ----------------------------------------------------------------------------------------
# Scalar variant (Python bools, no symbolic loop): same image as `path` there too
# ----------------------------------------------------------------------------------------

_SCALAR_SCRIPT = r"""
import mscloth, mitsuba as mi, numpy as np
mi.set_variant("scalar_rgb")
mi.set_log_level(mi.LogLevel.Error)
from mscloth.integrators import register_integrators
register_integrators()
def scene(kind, **kw):
    s = mi.cornell_box()
    s["sensor"]["film"].update(width=6, height=6, pixel_format="rgba")
    s["small-box"]["bsdf"] = {"type": "roughconductor", "alpha": 0.2}
    s["env"] = {"type": "constant", "radiance": 0.2}
    s["integrator"] = dict(type=kind, **kw)
    return mi.load_dict(s)
worst = 0.0
for kw in [{}, {"max_depth": 1, "hide_emitters": True}, {"max_depth": 2, "rr_depth": 1}]:
    a = np.array(mi.render(scene("path", **kw), spp=16, seed=3))
    b = np.array(mi.render(scene("clothpath", emitter_sampling="one", **kw), spp=16, seed=3))
    assert np.all(np.isfinite(b))
    assert a[..., :3].max() > 0 or kw.get("hide_emitters")
    worst = max(worst, float(np.abs(a - b[..., :4]).max()))
print("WORST", worst)
# Every emitter sampled (area light and sky): the same image in expectation. Image means
# of 8 passes each; the difference within 5 standard errors of the pass-to-pass spread.
ref = [np.array(mi.render(scene("path"), spp=16, seed=100 + i))[..., :3].mean() for i in range(8)]
ours = [np.array(mi.render(scene("clothpath"), spp=16, seed=200 + i))[..., :3].mean() for i in range(8)]
assert np.all(np.isfinite(ours))
se = np.sqrt(np.var(ref, ddof=1) / 8 + np.var(ours, ddof=1) / 8)
print("ALL", abs(np.mean(ref) - np.mean(ours)) / se)
"""


def test_scalar_variant_matches_path():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _SCALAR_SCRIPT], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    worst = float(out.stdout.split("WORST")[1].split()[0])
    assert worst <= 1e-4, worst
    assert float(out.stdout.split("ALL")[1]) <= 5.0


_SCALAR_AOV_SCRIPT = r"""
import sys, mscloth, mitsuba as mi, numpy as np
mi.set_variant("scalar_rgb")
mi.set_log_level(mi.LogLevel.Error)
mscloth.register()
T = mi.ScalarTransform4f
scene = mi.load_dict({
    "type": "scene", "integrator": {"type": "clothpath", "footprint_aovs": True},
    "sensor": {"type": "perspective", "fov": 40, "to_world": T().look_at([0, 0, 3], [0, 0, 0], [0, 1, 0]),
               "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}}},
    "sky": {"type": "constant", "radiance": 0.5},
    "cloth": {"type": "rectangle", "to_world": T().scale(0.5), "bsdf": {"type": "cloth", "resolution": 16}}})
np.save(sys.argv[1], np.array(mi.render(scene, spp=1, seed=0)))
"""


def test_scalar_variant_records_footprint_aovs(tmp_path):
    """footprint_aovs in scalar_rgb, where camera rays miss (a miss has no BSDF to ask for its
    texels: scalar clothpath dereferenced a null shape there): a unit UV square seen head-on
    across N = 8 / (2 * 3 tan 20 deg) pixels gets half-widths 1/(2N) and 16 * 2/(2N) texels
    where the cloth is seen, 0 around it."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _SCALAR_AOV_SCRIPT, str(tmp_path / "aov.npy")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    aov = np.load(tmp_path / "aov.npy")[..., -4:]
    on_cloth = aov[..., 0] > 0.0
    assert 0 < on_cloth.sum() < on_cloth.size
    half = 1.0 / (2.0 * 8.0 / (2.0 * 3.0 * math.tan(math.radians(20.0))))
    np.testing.assert_allclose(aov[on_cloth][:, :2], half, rtol=0.05)
    np.testing.assert_allclose(aov[on_cloth][:, 2:], 16 * 2 * half, rtol=0.05)
    assert np.all(aov[~on_cloth] == 0.0)


# ----------------------------------------------------------------------------------------
# Pixel-centred footprints at the first hit
# ----------------------------------------------------------------------------------------

def test_pixel_centre_offset_recovers_the_film_position():
    """The offset of a camera sample from its pixel centre, from the point it sees."""
    sensor = mi.load_dict({"type": "perspective", "fov": 50,
                           "to_world": mi.ScalarTransform4f().look_at(origin=[0.3, 1, 4], target=[0, 0.5, 0],
                                                                      up=[0, 1, 0]),
                           "film": {"type": "hdrfilm", "width": 16, "height": 9, "rfilter": {"type": "box"}}})
    rng = np.random.default_rng(4)
    n = 1000
    px, py = rng.integers(0, 16, n), rng.integers(0, 9, n)
    fx, fy = rng.uniform(0.02, 0.98, n), rng.uniform(0.02, 0.98, n)
    pos = mi.Point2f((px + fx) / 16.0, (py + fy) / 9.0)
    ray, _ = sensor.sample_ray_differential(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    p = ray.o + ray.d * mi.Float(rng.uniform(0.5, 20.0, n))
    ox, oy, ok = fp.pixel_centre_offset(sensor, p)
    assert np.all(np.array(ok))
    np.testing.assert_allclose(np.array(ox), fx - 0.5, atol=2e-4)
    np.testing.assert_allclose(np.array(oy), fy - 0.5, atol=2e-4)
    # Behind the camera: not valid.
    _, _, ok = fp.pixel_centre_offset(sensor, ray.o - ray.d)
    assert not np.any(np.array(ok))
    # A crop window's camera centres points of the frame outside its window as the whole
    # frame's does (the sky-share pilot renders pixels of the whole frame in a crop).
    cropped = mi.load_dict({"type": "perspective", "fov": 50,
                            "to_world": mi.ScalarTransform4f().look_at(origin=[0.3, 1, 4], target=[0, 0.5, 0],
                                                                       up=[0, 1, 0]),
                            "film": {"type": "hdrfilm", "width": 16, "height": 9, "rfilter": {"type": "box"},
                                     "crop_offset_x": 5, "crop_offset_y": 3, "crop_width": 4, "crop_height": 2}})
    cx, cy, ok = fp.pixel_centre_offset(cropped, p)
    assert np.all(np.array(ok))
    np.testing.assert_allclose(np.array(cx), fx - 0.5, atol=2e-4)
    np.testing.assert_allclose(np.array(cy), fy - 0.5, atol=2e-4)


def test_orthographic_centre_offset_recovers_the_film_position():
    """The same for an orthographic camera (rotated, scaled, a crop window): from the ray
    origin, the corner ray's origin and the whole-pixel differentials."""
    sensor = mi.load_dict({"type": "orthographic",
                           "to_world": mi.ScalarTransform4f().look_at(origin=[0.3, 1, 4], target=[0, 0.5, 0],
                                                                      up=[0, 1, 0]) @ mi.ScalarTransform4f().scale([2, 2, 1]),
                           "film": {"type": "hdrfilm", "width": 16, "height": 9, "crop_offset_x": 3,
                                    "crop_offset_y": 2, "crop_width": 10, "crop_height": 6,
                                    "rfilter": {"type": "box"}}})
    rng = np.random.default_rng(5)
    n = 1000
    px, py = rng.integers(0, 10, n), rng.integers(0, 6, n)
    fx, fy = rng.uniform(0.02, 0.98, n), rng.uniform(0.02, 0.98, n)
    ray, _ = sensor.sample_ray_differential(0.0, 0.5, mi.Point2f((px + fx) / 10.0, (py + fy) / 6.0),
                                            mi.Point2f(0.5, 0.5))
    corner, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(0.0, 0.0), mi.Point2f(0.5, 0.5))
    ox, oy, ok = fp.orthographic_centre_offset(ray.o, corner.o, ray.o_x - ray.o, ray.o_y - ray.o)
    assert np.all(np.array(ok))
    np.testing.assert_allclose(np.array(ox), fx - 0.5, atol=2e-4)
    np.testing.assert_allclose(np.array(oy), fy - 0.5, atol=2e-4)


class UvProbe(ZeroEval):
    """A footprint-shading BSDF that ends the path and reports what it was handed: its
    eval at every direction is (si.uv, pixel_offset.x)."""

    footprint_shading = True

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.m_flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        self.m_components = [self.m_flags]

    def eval_pdf_sample_n(self, ctx, si, wos, s1, s2, active=True, pixel_offset=None):
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = mi.Vector3f(0, 0, 1)
        bs.pdf = 0.0  # end the path here
        colour = mi.Color3f(si.uv.x, si.uv.y, pixel_offset.x)
        return [colour for _ in wos], [mi.Float(0.0) for _ in wos], bs, mi.Color3f(0.0)

    def sample(self, ctx, si, s1, s2, active=True):
        return dr.zeros(mi.BSDFSample3f), mi.Color3f(0.0)


mi.register_bsdf("uv_probe", lambda props: UvProbe(props))


class OpenSheet(FootprintProbe):
    """A sheet of cloth that is all gap: light crosses it straight (a delta transmission of
    weight 1) and shadow rays cross it whole (``gap_transmission`` 1)."""

    def sample(self, ctx, si, sample1, sample2, active=True):
        bs, _ = FootprintProbe.sample(self, ctx, si, sample1, sample2, active)
        return bs, mi.Color3f(1.0) & active

    def gap_transmission(self, si, active=True):
        return mi.Float(1.0)


mi.register_bsdf("open_sheet", lambda props: OpenSheet(props))


def _uv_probe_view(camera: str, sheets: int = 0) -> tuple[dict, float]:
    """(scene, half-width of the view at the probe plane z = 0): the probe plane seen
    head-on from z = 3 (8x8 pixels, 30 degrees), behind ``sheets`` open sheets at
    z = 1, 1.5, ... (uv_probe: each pixel's value is the uv its samples were shaded at)."""
    look = mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0])
    t = np.tan(np.radians(15.0)) * 3.0  # half-width of the view at the plane
    sensor = {"type": "perspective", "fov": 30, "to_world": look}
    if camera == "orthographic":
        sensor = {"type": "orthographic", "to_world": look @ mi.ScalarTransform4f().scale([t, t, 1])}
    sensor.update({"film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}})
    scene = {"type": "scene", "integrator": {"type": "clothpath", "max_depth": 2 + sheets},
             "sensor": sensor,
             "plane": {"type": "rectangle", "bsdf": {"type": "uv_probe"}},
             # Radiance 1 from the camera's side: the emitter sample returns the probe's value.
             "light": {"type": "directional", "direction": [0, 0, -1], "irradiance": 1.0}}
    for i in range(sheets):
        scene[f"sheet{i}"] = {"type": "rectangle", "bsdf": {"type": "open_sheet"},
                              "to_world": mi.ScalarTransform4f().translate([0, 0, 1.0 + 0.5 * i]).scale(4.0)}
    return scene, t


def _assert_pixel_centres_seen(scene: dict, t: float, atol: float = 2e-4):
    """Every sample of a pixel reports the uv of the pixel centre (within ``atol``; a pixel
    is 0.05 wide in uv), and its own offset from that centre (uniform in [-1/2, 1/2) along
    x)."""
    # The probe's eval (= uv) weighted by the emitter sample: each pixel's mean is its uv.
    ours = render(mi.load_dict(scene), 64, seed=1)
    centres = (np.arange(8) + 0.5) / 8.0
    u = 0.5 + (centres - 0.5) * t  # rectangle: uv = (x + 1) / 2 over [-1, 1]
    v = 0.5 + (0.5 - centres) * t
    np.testing.assert_allclose(ours[..., 0], np.broadcast_to(u[None, :], (8, 8)), atol=atol)
    np.testing.assert_allclose(ours[..., 1], np.broadcast_to(v[:, None], (8, 8)), atol=atol)
    # No spread between the samples of a pixel: the variance across seeds vanishes.
    other = render(mi.load_dict(scene), 1, seed=5)
    np.testing.assert_allclose(other[..., :2], ours[..., :2], atol=atol)
    # The offsets: within the pixel, uniform (mean 0, standard deviation 12^-1/2).
    offsets = other[..., 2].ravel()
    assert np.all(np.abs(offsets) <= 0.5), offsets
    assert abs(offsets.mean()) < 4.0 * 0.29 / 8.0 and abs(offsets.std() - 0.289) < 0.08, offsets
    assert np.all(np.abs(ours[..., 2]) < 4.0 * 0.29 / 8.0), ours[..., 2]


@pytest.mark.parametrize("camera", ["perspective", "orthographic"])
def test_footprint_bsdfs_see_the_pixel_centre_at_the_first_hit(camera):
    """A BSDF with eval_pdf_sample_n and footprint_shading gets the uv of the pixel centre at
    the first hit: every sample of a pixel reports the same uv, the centre's; and each
    sample's own offset from that centre (uniform in [-1/2, 1/2) along x)."""
    _assert_pixel_centres_seen(*_uv_probe_view(camera))


@pytest.mark.parametrize("camera", ["perspective", "orthographic"])
@pytest.mark.parametrize("sheets", [1, 2])
def test_footprint_bsdfs_seen_through_gaps_see_the_pixel_centre(camera, sheets):
    """Through the gaps of cloth the camera ray goes on straight, so what it hits behind is
    still seen through the pixel: it gets the pixel centre's uv and the sample's offset as
    a first hit does. Shaded at the sample's own uv with a footprint centred there, the
    pixel averaged its footprint over twice its width (the sphere scene's near region:
    squared bias 4.6e-5 -> 1.9e-5, performance log L55)."""
    # Each crossing spawns the ray again a little off the line: float error of ~2e-4.
    _assert_pixel_centres_seen(*_uv_probe_view(camera, sheets), atol=5e-4)


# ----------------------------------------------------------------------------------------
# Shadow rays through the gaps of cloth (delta emitters)
# ----------------------------------------------------------------------------------------

def _floor_under_cloth(cloth_bsdf, spp=64, seed=0, **integrator):
    """A diffuse floor seen from the side, lit by a sun straight above through a cloth
    sheet (or nothing) one unit higher; max_depth 2: the floor's direct light only."""
    import mscloth

    mscloth.register()
    scene = {"type": "scene", "integrator": {"type": "clothpath", "max_depth": 2, **integrator},
             "sensor": {"type": "perspective", "fov": 20,
                        "to_world": mi.ScalarTransform4f().look_at(origin=[0, -8, 0.5], target=[0, 0, 0], up=[0, 0, 1]),
                        "film": {"type": "hdrfilm", "width": 32, "height": 32, "rfilter": {"type": "box"}}},
             "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(3),
                       "bsdf": {"type": "diffuse", "reflectance": 0.5}},
             "sun": {"type": "directional", "direction": [0, 0, -1], "irradiance": 1.0}}
    if cloth_bsdf is not None:
        scene["cloth"] = {"type": "rectangle", "bsdf": cloth_bsdf,
                          "to_world": mi.ScalarTransform4f().translate([0, 0, 1]).scale(10)}
    img = render(mi.load_dict(scene), spp, seed)[8:24, 4:28, :3].mean(axis=-1)
    return img.mean(), img.std(ddof=1) / np.sqrt(img.size)


@pytest.mark.parametrize("multiscale", [True, False])
def test_sun_shines_through_the_gaps_of_cloth(multiscale):
    """The floor under a cloth sheet receives the sun times the cloth's mean gap
    transmittance T_sheen(n)^2 (1 - mean I), within 5 standard errors (pixel spread) plus
    5% (the floor region sees a finite part of the weave)."""
    from mscloth.maps.builtin import resolve_pattern
    from mscloth.scattering import sheen

    open_sky, _ = _floor_under_cloth(None, spp=4)
    under, err = _floor_under_cloth({"type": "cloth", "pattern": "plain", "uv_scale": 40.0,
                                     "multiscale": multiscale})
    gap_fraction = 1.0 - resolve_pattern("plain", None).gap.mean()
    t_sheen = float(np.array(sheen.sheen_transmittance(mi.Vector3f(0, 0, 1), 0.5, 0.2))[0])
    expected = open_sky * t_sheen ** 2 * gap_fraction
    assert gap_fraction > 0.01 and under > 0.0
    assert abs(under - expected) <= 5.0 * err + 0.05 * expected, (under, expected, err)


def _floor_under_opaque_sheet(max_depth, spp=16):
    """Seen from under a cloth sheet that transmits only through its gaps (no transmission
    lobes): a floor lit by a sun above the sheet. Light reaches the image only by shadow
    rays crossing the sheet: from the floor at the first hit, or from floors reached again
    after bouncing off the sheet's underside."""
    import mscloth

    mscloth.register()
    cloth = {"type": "cloth", "pattern": "plain", "uv_scale": 400.0, "specular_transmittance": 0.0,
             "diffuse_transmittance": 0.0, "diffuse_albedo": 0.5}
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "clothpath", "max_depth": max_depth, "rr_depth": 100},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0.9], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}}},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(30),
                  "bsdf": {"type": "diffuse", "reflectance": 0.8}},
        "cloth": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 1]).scale(30),
                  "bsdf": cloth},
        "sun": {"type": "directional", "direction": [0, 0, -1], "irradiance": 1.0}})
    return render(scene, spp, 1)[..., :3].mean()


def test_shadow_rays_from_point_shaded_vertices_cross_cloth_at_a_point(monkeypatch):
    """Only vertices that carry a footprint (the first hit and delta chains) hand their ray
    cone to shadow rays crossing cloth; after a rough bounce the vertex is shaded at a point,
    and so are its shadow rays' crossings (a zero cone: one texel's gap, no table reads).
    With crossings made to pass light only when they have a cone, the floors reached after
    the first bounce add nothing; with real crossings they do (so such crossings happen)."""
    from mscloth.integrators import gap_shadows

    real_direct, real_all = _floor_under_opaque_sheet(2), _floor_under_opaque_sheet(6)
    assert real_all > 1.05 * real_direct > 0.0, (real_direct, real_all)

    def only_with_a_cone(scene, si, target, cone_width, cone_spread, active, max_crossings=None):
        return dr.select((cone_width > 0.0) | (cone_spread > 0.0), 1.0, 0.0)

    monkeypatch.setattr(gap_shadows, "shadow_transmittance", only_with_a_cone)
    direct, everything = _floor_under_opaque_sheet(2), _floor_under_opaque_sheet(6)
    assert direct > 0.0
    assert everything == pytest.approx(direct, rel=1e-5)


@pytest.mark.parametrize("multiscale", [True, False])
def test_gap_shadows_off_makes_cloth_block_the_sun(multiscale):
    """``gap_shadows`` false: the sheet that lets the sun through its gaps (the test above)
    blocks it like any surface, and the floor under it gets nothing."""
    cloth = {"type": "cloth", "pattern": "plain", "uv_scale": 40.0, "multiscale": multiscale}
    through, _ = _floor_under_cloth(cloth, spp=4)
    blocked, _ = _floor_under_cloth(cloth, spp=4, gap_shadows=False)
    assert through > 0.0
    assert blocked == 0.0


def test_opaque_surfaces_still_block_the_sun():
    """A diffuse sheet instead of cloth: no light reaches the floor (only the first
    crossing is tested for gaps, and a diffuse BSDF has none)."""
    under, _ = _floor_under_cloth({"type": "diffuse"}, spp=4)
    assert under == 0.0


# ----------------------------------------------------------------------------------------
# Emitter sampling through the gaps of cloth (area lights, skies): MIS with BSDF paths
# ----------------------------------------------------------------------------------------

#: Camera and area light positions: a camera between a sheer sheet (z = 1) and the floor,
#: under a light above the sheet; or above both, seeing the floor through the sheet.
_GAP_VIEWS = {"under": ([0, 0, 0.8], [0, 0, 2.0]), "above": ([0, -1.0, 3.0], [0.8, 0.3, 2.0])}


def _gap_sky():
    """An environment map: a sky gradient and a small bright sun (not a delta emitter)."""
    h, w = 16, 32
    theta = (np.arange(h) + 0.5) / h * np.pi
    phi = (np.arange(w) + 0.5) / w * 2 * np.pi
    sky = np.zeros((h, w, 3), dtype=np.float32)
    sky[...] = (0.2 + 0.8 * np.cos(theta)[:, None, None].clip(0, 1)) * np.array([0.4, 0.6, 1.0])
    sky += (20.0 * np.exp(-((theta[:, None] - 0.5) ** 2 + (phi[None, :] - 2.0) ** 2) / 0.02))[..., None]
    return {"type": "envmap", "bitmap": mi.Bitmap(sky.astype(np.float32)),
            "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90)}


def _sheer_cloth_scene(integrator: dict, view: str = "under", layers: int = 1, sky: bool = False):
    """A diffuse floor under ``layers`` sheets of silk organza (fibre level: 36% gaps,
    yarns that also transmit), 16x16 pixels, lit by a 1 m square area light 2 m up (and an
    environment map if ``sky``)."""
    import mscloth

    mscloth.register()
    t = mi.ScalarTransform4f
    cam, light = _GAP_VIEWS[view]
    scene = {"type": "scene", "integrator": integrator,
             "sensor": {"type": "perspective", "fov": 40,
                        "to_world": t().look_at(origin=cam, target=[0, 0, 0], up=[0, 1, 0]),
                        "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}}},
             "floor": {"type": "rectangle", "to_world": t().scale(3),
                       "bsdf": {"type": "diffuse", "reflectance": 0.8}},
             "light": {"type": "rectangle", "to_world": t().translate(light).rotate([1, 0, 0], 180).scale(0.5),
                       "emitter": {"type": "area", "radiance": 10.0}}}
    if sky:
        scene["sky"] = _gap_sky()
    cloth = {"type": "cloth", "fabric": "silk-organza", "multiscale": False}
    for i in range(layers):
        scene[f"cloth{i}"] = {"type": "rectangle", "bsdf": cloth,
                              "to_world": t().translate([0, 0, 1.0 + 0.2 * i]).scale(3)}
    return mi.load_dict(scene)


_GAP_CASES = {"under": ("under", False), "above": ("above", False), "under-sky": ("under", True)}
_gap_pass_cache: dict = {}


def _gap_passes(case: str, integrator_type: str):
    """16 passes x 16 spp (independent seeds) of a case: (per-pixel mean, per-pixel
    variance of a pass) of the luminance-like channel mean, cached for the module."""
    key = (case, integrator_type)
    if key not in _gap_pass_cache:
        view, sky = _GAP_CASES[case]
        scene = _sheer_cloth_scene({"type": integrator_type}, view, sky=sky)
        seed0 = 0 if integrator_type == "path" else 1000
        imgs = np.stack([render(scene, 16, seed0 + i)[..., :3].mean(axis=-1) for i in range(16)])
        _gap_pass_cache[key] = (imgs.mean(axis=0), imgs.var(axis=0, ddof=1), len(imgs))
    return _gap_pass_cache[key]


@pytest.mark.parametrize("case", list(_GAP_CASES))
def test_light_through_cloth_gaps_agrees_with_path(case):
    """Shadow rays towards area lights and skies cross cloth through its gaps, weighed by
    MIS against BSDF paths that cross the gaps (whose gap crossings keep the MIS state of
    the vertex before them): the image must converge to Mitsuba's ``path``, which reaches
    such light by BSDF sampling alone (the gap is a delta lobe there, weight 1). The image
    mean and its four 8x8 tiles agree within 5 standard errors, from per-pixel pass-to-pass
    variances. (A gap crossing that resets MIS to 'delta, weight 1', as before, counts the
    light twice: about +80% under the sheet.)"""
    ref_mean, ref_var, n = _gap_passes(case, "path")
    our_mean, our_var, _ = _gap_passes(case, "clothpath")
    assert np.all(np.isfinite(our_mean)) and ref_mean.mean() > 0.1

    def regions(a):  # the image and its 8x8 tiles: sums over pixels
        tiles = a.reshape(2, 8, 2, 8).sum(axis=(1, 3)).ravel()
        return np.concatenate([[a.sum()], tiles]), np.concatenate([[a.size], np.full(4, 64)])

    (ref_sum, count), (our_sum, _) = regions(ref_mean), regions(our_mean)
    (ref_v, _), (our_v, _) = regions(ref_var), regions(our_var)
    diff = (our_sum - ref_sum) / count
    se = np.sqrt((ref_v + our_v) / n) / count
    assert np.all(np.abs(diff) <= 5.0 * se), (diff, se)


@pytest.mark.parametrize("case", list(_GAP_CASES))
def test_shadow_rays_through_cloth_gaps_cut_the_noise(case):
    """Where the light comes through sheer cloth, per-pixel variance at equal spp falls by
    a large factor against BSDF sampling alone (``path``, and clothpath before emitter
    samples crossed gaps): measured 20x under the sheet, 13x seen through it from above,
    15x with an environment map too. Asserted: at least 5x."""
    _, ref_var, _ = _gap_passes(case, "path")
    _, our_var, _ = _gap_passes(case, "clothpath")
    ratio = ref_var.mean() / our_var.mean()
    assert ratio >= 5.0, ratio


@pytest.mark.parametrize("emitter_sampling", ["all", "one"])
def test_shadow_rays_cross_no_more_cloth_than_bsdf_paths_can(emitter_sampling):
    """A shadow ray crosses only as many sheets as a BSDF path from the same vertex can
    cross (each crossing is a vertex) before ``max_depth``; otherwise MIS would weigh it
    against paths that never reach the light. Two sheets over the floor: at max_depth 3
    neither the floor's shadow rays nor its BSDF paths reach the light (black, as with
    ``path``), at max_depth 4 both do."""
    def image(max_depth):
        scene = _sheer_cloth_scene({"type": "clothpath", "max_depth": max_depth,
                                    "emitter_sampling": emitter_sampling}, layers=2)
        return render(scene, 4, 0)[..., :3]

    assert np.all(image(3) == 0.0)
    assert image(4).mean() > 0.02


def test_footprint_texels_aov_counts_the_cloth_texels():
    """A cloth square seen head-on across N pixels, uv_scale s, tile of W texels: each pixel
    spans s W / N texels (the AOV the README suggests for checking a scene's scale)."""
    import mscloth

    mscloth.register()
    n, s_uv = 16, 3.0
    cloth = {"type": "cloth", "pattern": "plain", "uv_scale": s_uv, "uv_scale_v": s_uv}
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "clothpath", "footprint_aovs": True, "max_depth": 1},
        "sensor": {"type": "orthographic",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 2], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": n, "height": n, "rfilter": {"type": "box"}}},
        "square": {"type": "rectangle", "bsdf": cloth}})
    tile = mi.load_dict(cloth).fibre.tile.tile_w
    img = render(scene, 4, 0)  # R, G, B, footprint_u, footprint_v, texels_u, texels_v
    np.testing.assert_allclose(img[2:-2, 2:-2, 5], s_uv * tile / n, rtol=1e-3)
    np.testing.assert_allclose(img[2:-2, 2:-2, 6], s_uv * tile / n, rtol=1e-3)


def _render_kernel_operations(scene_dict) -> int:
    """Operations in the largest kernel a 1-spp render of ``scene_dict`` launches (counted
    when traced, whether or not Dr.Jit's kernel cache holds the kernel)."""
    scene = mi.load_dict(scene_dict)
    had = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history_clear()
        dr.eval(mi.render(scene, spp=1, seed=0))
        history = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, had)
    return max(k["operation_count"] for k in history if k["type"] == dr.KernelType.JIT)


def test_cloths_of_different_tiles_trace_one_callable():
    """A cloth's tile size reaches traced code as opaque values, not literals: two
    multi-scale cloths whose tiles differ in size (and pattern) trace the same code, one
    callable in the render's kernel as for two cloths of the same tile, not one each (the
    sphere scene's kernel: 29k operations with literals, 11k without; performance log L23)."""
    import mscloth

    mscloth.register()

    def scene(first, second):
        s = {"type": "scene", "integrator": {"type": "clothpath", "max_depth": 2},
             "sensor": {"type": "perspective", "fov": 40,
                        "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                        "film": {"type": "hdrfilm", "width": 4, "height": 4, "rfilter": {"type": "box"}}},
             "sky": {"type": "constant", "radiance": 1.0}}
        for name, x, (pattern, resolution) in (("left", -1.1, first), ("right", 1.1, second)):
            s[name] = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([x, 0, 0]),
                       "bsdf": {"type": "cloth", "pattern": pattern, "resolution": resolution, "uv_scale": 20.0}}
        return s

    same = _render_kernel_operations(scene(("plain", 32), ("plain", 32)))
    different = _render_kernel_operations(scene(("plain", 32), ("twill-2-2", 48)))
    assert different < 1.1 * same, (different, same)


# ----------------------------------------------------------------------------------------
# uv_filter: the filter over the first hit's uv
# ----------------------------------------------------------------------------------------

def _stripes_scene(uv_filter: str, cycles_per_pixel: float, width: int = 64, height: int = 16) -> dict:
    """Black and white stripes across a diffuse rectangle that fills an orthographic view,
    ``cycles_per_pixel`` stripe periods per pixel, under a white sky: each pixel is the
    filtered mean of the stripes (albedo x 1)."""
    periods = int(round(cycles_per_pixel * width))
    stripes = np.zeros((2, 2 * periods, 3), dtype=np.float32)
    stripes[:, 1::2] = 1.0
    T = mi.ScalarTransform4f
    return {"type": "scene",
            "integrator": {"type": "clothpath", "max_depth": 2, "uv_filter": uv_filter},
            "sensor": {"type": "orthographic",
                       "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": width, "height": height,
                                "rfilter": {"type": "box"}},
                       "sampler": {"type": "multijitter", "sample_count": 64}},
            "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
            "card": {"type": "rectangle", "to_world": T().scale([1.0, 1.0, 1.0]),
                     "bsdf": {"type": "diffuse", "reflectance": {
                         "type": "bitmap", "bitmap": mi.Bitmap(stripes), "raw": True,
                         "filter_type": "nearest", "wrap_mode": "repeat"}}}}


def _beat_amplitude(uv_filter: str, cycles_per_pixel: float):
    """(mean, amplitude of the strongest low-frequency beat) of the stripes' columns."""
    image = np.array(mi.render(mi.load_dict(_stripes_scene(uv_filter, cycles_per_pixel)), seed=3))
    columns = image[..., 0].mean(axis=0)
    spectrum = np.abs(np.fft.rfft(columns - columns.mean())) * 2.0 / columns.size
    return columns.mean(), spectrum[1:].max()


def test_tent_uv_filter_removes_the_moire_of_stripes_near_the_pixel_period():
    """Stripes at 1.3 cycles per pixel: the box beats them into a moire of 0.3 cycles per
    pixel with sinc(1.3) = 19% of the stripes' fundamental (2/pi): amplitude ~0.12; box x
    tent (a quadratic B-spline) keeps sinc^3 = 0.7%: ~0.004. Noise per column mean (64 spp x
    16 rows, stratified) is under 0.01, its spectrum's bins under ~0.005. Both keep the mean."""
    box_mean, box_beat = _beat_amplitude("box", 1.3)
    tent_mean, tent_beat = _beat_amplitude("tent", 1.3)
    assert box_beat > 0.06, box_beat
    assert tent_beat < 0.02, tent_beat
    assert abs(box_mean - 0.5) < 0.02 and abs(tent_mean - 0.5) < 0.02, (box_mean, tent_mean)


def test_tent_uv_filter_keeps_detail_at_a_few_pixels_per_period():
    """Stripes of 8 pixels' period, their edges on pixel edges: the box gives the discrete
    square wave 1,1,1,1,0,0,0,0 (fundamental 0.653); box x tent keeps the stripes'
    fundamental 2/pi times sinc^3(1/8) = 0.589 (its harmonics' aliases are gone): a soft
    filter, as Mitsuba's default gaussian, not a blur."""
    _, box_beat = _beat_amplitude("box", 0.125)
    _, tent_beat = _beat_amplitude("tent", 0.125)
    square = np.abs(np.fft.rfft(np.tile([1.0, 1, 1, 1, 0, 0, 0, 0], 8)))[8] * 2.0 / 64
    assert box_beat == pytest.approx(square, rel=0.03)
    assert tent_beat == pytest.approx(2.0 / np.pi * np.sinc(0.125) ** 3, rel=0.03)


def test_the_sample_density_is_needed_where_mis_or_ray_cones_read_it():
    """clothpath tells BSDFs (``eval_pdf_sample_n``'s ``mis``) whether it reads a sample's
    density beyond its sign: with an emitter it samples that a path can also hit (area
    lights, environments it samples), or ray cones after rough bounces; not with delta
    emitters alone (a sun, a point light), whatever lights the scene by BSDF sampling alone."""
    from mscloth.integrators.clothpath import sample_density_needed
    sun = mi.load_dict({"type": "directional", "direction": [0, 0, -1]})
    point = mi.load_dict({"type": "point", "position": [0, 0, 1]})
    sky = mi.load_dict({"type": "constant"})
    area = mi.load_dict({"type": "rectangle", "emitter": {"type": "area"}}).emitter()
    assert not sample_density_needed([], False)
    assert not sample_density_needed([sun, point], False)
    assert sample_density_needed([sun, sky], False)
    assert sample_density_needed([area], False)
    assert sample_density_needed([sun], True)


def test_bsdfs_without_the_mis_argument_still_shade():
    """``mis`` came later to the footprint protocol: a footprint-shading BSDF whose
    eval_pdf_sample_n does not take it is called without it."""
    calls = []

    class Old:
        footprint_shading = True

        def eval_pdf_sample_n(self, ctx, si, wos, sample1, sample2, active=True, pixel_offset=None):
            calls.append(pixel_offset)
            return [1.0], [1.0], None, 1.0

    class New(Old):
        def eval_pdf_sample_n(self, ctx, si, wos, sample1, sample2, active=True, pixel_offset=None,
                              pixel_filter="box", mis=True):
            calls.append(mis)
            return [1.0], [1.0], None, 1.0

    class Newer(Old):
        def eval_pdf_sample_n(self, ctx, si, wos, sample1, sample2, active=True, pixel_offset=None,
                              pixel_filter="box", mis=True, exact_wos=None):
            calls.append((mis, exact_wos))
            return [1.0], [1.0], None, 1.0

    from mscloth.integrators import bsdf_contract as contract
    contract.eval_pdf_sample_n(Old(), None, None, None, [None], 0.5, None, True, "offset", "box", mis=False)
    contract.eval_pdf_sample_n(New(), None, None, None, [None], 0.5, None, True, "offset", "box", mis=False)
    contract.eval_pdf_sample_n(New(), None, None, None, [None], 0.5, None, True, "offset", "box", mis=True)
    # exact_wos (a Float from clothpath: 1 where exact) reaches only BSDFs that take it, as a mask.
    contract.eval_pdf_sample_n(Old(), None, None, None, [None], 0.5, None, True, "offset", "box", 1.0)
    contract.eval_pdf_sample_n(New(), None, None, None, [None], 0.5, None, True, "offset", "box", 1.0, mis=False)
    contract.eval_pdf_sample_n(Newer(), None, None, None, [None], 0.5, None, True, "offset", "box", 1.0, mis=False)
    contract.eval_pdf_sample_n(Newer(), None, None, None, [None], 0.5, None, True, "offset", "box", 0.0)
    assert calls == ["offset", False, True, "offset", False, (False, True), (True, False)]


class ExactProbe(ZeroEval):
    """A footprint-shading BSDF that ends the path and reports whether clothpath marked its
    emitter directions exact: its eval there is (exact_wos, whether exact_wos came, 0)."""

    footprint_shading = True

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.m_flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        self.m_components = [self.m_flags]

    def eval_pdf_sample_n(self, ctx, si, wos, s1, s2, active=True, pixel_offset=None, pixel_filter="box",
                          mis=True, exact_wos=None):
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = mi.Vector3f(0, 0, 1)
        bs.pdf = 0.0  # end the path here
        given = exact_wos is not None
        colour = mi.Color3f(dr.select(exact_wos, 1.0, 0.0) if given else 0.0, 1.0 if given else 0.0, 0.0)
        return [colour for _ in wos], [mi.Float(0.0) for _ in wos], bs, mi.Color3f(0.0)

    def sample(self, ctx, si, s1, s2, active=True):
        return dr.zeros(mi.BSDFSample3f), mi.Color3f(0.0)


mi.register_bsdf("exact_probe", lambda props: ExactProbe(props))


@pytest.mark.parametrize("sun_cos,sky,exact,given", [
    (1.0, 0.01, 1.0, 1.0),   # a sun over a dim sky: its direction carries the light
    (1.0, 0.1, 0.0, 0.0),    # 1 < 4 pi 0.1: no lane can be exact, nothing is handed over
    (0.5, 0.05, 0.0, 1.0),   # the sun could (1 > 4 pi 0.05), but at 60 degrees it does not
    (0.5, 0.0, 1.0, 1.0),    # no sky at all
])
def test_emitter_directions_are_exact_where_a_sun_outshines_the_sky(sun_cos, sky, exact, given):
    """clothpath marks a first hit's emitter directions exact (``exact_wos``) where the delta
    emitters' irradiance there exceeds EXACT_EMITTER_RATIO x pi x the environment's mean
    radiance, and hands footprint BSDFs no mark where no lane can be."""
    from mscloth.integrators.clothpath import EXACT_EMITTER_RATIO, environment_radiance
    assert EXACT_EMITTER_RATIO == 4.0  # the cases above are set for it
    env = mi.load_dict({"type": "constant", "radiance": {"type": "rgb", "value": [0.5, 0.58, 0.72]}})
    assert environment_radiance(env) == pytest.approx(float(mi.luminance(mi.Color3f(0.5, 0.58, 0.72))[0]), rel=1e-5)
    assert environment_radiance(None) == 0.0
    look = mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0])
    sine = float(np.sqrt(1.0 - sun_cos ** 2))
    scene = {"type": "scene", "integrator": {"type": "clothpath", "max_depth": 2},
             "sensor": {"type": "perspective", "fov": 20, "to_world": look,
                        "film": {"type": "hdrfilm", "width": 4, "height": 4, "rfilter": {"type": "box"}},
                        "sampler": {"type": "independent"}},
             "plane": {"type": "rectangle", "bsdf": {"type": "exact_probe"}},
             "sun": {"type": "directional", "direction": [sine, 0.0, -sun_cos], "irradiance": 1.0}}
    if sky > 0.0:
        scene["sky"] = {"type": "constant", "radiance": sky}
    image = np.array(mi.render(mi.load_dict(scene), spp=4))
    np.testing.assert_allclose(image[..., 0], exact, atol=1e-6)  # the probe's value times irradiance 1
    np.testing.assert_allclose(image[..., 1], given, atol=1e-6)


@pytest.mark.parametrize("enclosed", [False, True])
def test_sky_control_variate_share_leaves_what_a_sky_control_variate_would(enclosed, monkeypatch):
    """``SKY_CONTROL_VARIATE_SHARE`` c (bench/sky_control_variate.py) renders the image minus
    c L_env A(wi) at the first hit. A diffuse square under a constant sky: in the open every cosine sample
    escapes with weight = albedo, so the image is albedo x radiance and the residual 0;
    inside a black sphere every sample hits it, so the image is 0 and the residual
    -albedo x radiance (the sky it would have brought, subtracted); c = 1/2, half of either.
    With ``SKY_ALBEDO_SAMPLES`` the estimator is whole again: the plain image."""
    from mscloth.integrators import clothpath

    black = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
    shapes = {"shell": {"type": "sphere", "radius": 10.0, "bsdf": black}} if enclosed else {}
    scene = lambda: square_under_sky(**shapes)  # noqa: E731
    lit = SKY_RADIANCE * SQUARE_REFLECTANCE
    plain = render(scene(), 1, 0)[..., :3].reshape(-1, 3)
    expected_plain = np.zeros(3) if enclosed else lit
    np.testing.assert_allclose(plain, np.broadcast_to(expected_plain, plain.shape), rtol=1e-5, atol=1e-6)
    for share in (1.0, 0.5):
        monkeypatch.setattr(clothpath, "SKY_CONTROL_VARIATE_SHARE", share)
        residual = render(scene(), 1, 0)[..., :3].reshape(-1, 3)
        expected = expected_plain - share * lit
        np.testing.assert_allclose(residual, np.broadcast_to(expected, residual.shape), rtol=1e-5, atol=1e-6)
        # The whole estimator (share x radiance x the albedo's estimate added back; a diffuse
        # sample's weight is the albedo): the plain image, open or enclosed.
        monkeypatch.setattr(clothpath, "SKY_ALBEDO_SAMPLES", 3)
        whole = render(scene(), 1, 0)[..., :3].reshape(-1, 3)
        monkeypatch.setattr(clothpath, "SKY_ALBEDO_SAMPLES", 0)
        np.testing.assert_allclose(whole, plain, rtol=1e-5, atol=1e-6)


def test_sky_control_variate_is_unbiased_through_delta_lobes_and_bounces(monkeypatch):
    """The whole estimator (``SKY_ALBEDO_SAMPLES``) against the plain one, on a square that
    lets 40% of the light straight through (a Null lobe: ``mask``) over a grey floor, under
    a grey ceiling that hides part of the sky: paths reflect into the sky or the ceiling,
    or cross the square and bounce on the floor. The means agree within 4 standard errors
    over the square's pixels, and the residual's mean is the plain one's minus c L_env times
    the square's non-delta albedo (0.6 x its reflectance). Subtracting after a delta sample
    or past the first bounce, or counting delta samples in A, shifts them by 0.1-1."""
    from mscloth.integrators import clothpath

    grey = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}
    sheer = {"type": "mask", "opacity": 0.6, "bsdf": {"type": "twosided", "bsdf": {
        "type": "diffuse", "reflectance": {"type": "rgb", "value": SQUARE_REFLECTANCE.tolist()}}}}
    scene = lambda: square_under_sky(  # noqa: E731
        square_bsdf=sheer,
        floor={"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, -1]).scale(10), "bsdf": grey},
        ceiling={"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 6]).scale(3), "bsdf": grey})

    def pixels(seed, share=0.0, samples=0):
        monkeypatch.setattr(clothpath, "SKY_CONTROL_VARIATE_SHARE", share)
        monkeypatch.setattr(clothpath, "SKY_ALBEDO_SAMPLES", samples)
        try:
            return render(scene(), 64, seed)[..., :3].reshape(-1, 3)
        finally:
            monkeypatch.setattr(clothpath, "SKY_CONTROL_VARIATE_SHARE", 0.0)
            monkeypatch.setattr(clothpath, "SKY_ALBEDO_SAMPLES", 0)

    plain = pixels(1)
    for share in (1.0, 0.5):
        for image, shift in ((pixels(2, share, 2), 0.0),
                             (pixels(3, share), share * SKY_RADIANCE * 0.6 * SQUARE_REFLECTANCE)):
            diff = plain - image
            se = np.sqrt((plain.var(axis=0, ddof=1) + image.var(axis=0, ddof=1)) / len(plain))
            assert np.all(np.abs(diff.mean(axis=0) - shift) <= 4 * se + 1e-4), (share, shift, diff.mean(axis=0), se)
