"""Built-in scenes, their XML export, and `mscloth render` / `mscloth scene`."""
import re
import subprocess
import sys
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

import mscloth
from mscloth.loading import load_dict
from mscloth.maps.generate import generate_maps
from mscloth.maps.cloth_maps import ClothMaps
from mscloth.scenes.builtin import SCENES, builtin_scene, set_cloth_parameters
from mscloth.scenes.xml_export import scene_to_xml

mscloth.register()


def run(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "mscloth", *args], capture_output=True, text=True, timeout=timeout)


#: The rough, sky-lit scenes with woven and knitted cloth; the shiny ones (issue 20) follow.
ROUGH_SCENES = ("plane", "sphere", "drape")
SHINY_SCENES = ("satin", "satin-plane", "denim")
LOOKDEV_SCENES = ("swatch",)  # fabric presets: tests/test_fabrics.py


def test_every_scene_is_listed_here():
    assert sorted(SCENES) == sorted(ROUGH_SCENES + SHINY_SCENES + LOOKDEV_SCENES)


@pytest.mark.parametrize("name", ROUGH_SCENES)
def test_scene_has_woven_and_knitted_cloth_sky_and_sun(name):
    scene = builtin_scene(name, 32, 18)
    patterns = [node["bsdf"]["pattern"] for node in scene.values()
                if isinstance(node, dict) and node.get("bsdf", {}).get("type") == "cloth"]
    knits = {"jersey", "rib-1-1", "rib-2-2"}
    assert any(p in knits for p in patterns) and any(p not in knits for p in patterns), patterns
    assert scene["sky"]["type"] == "constant" and scene["sun"]["type"] == "directional"
    assert scene["integrator"]["type"] == "clothpath"


@pytest.mark.parametrize("name", sorted(SCENES))
def test_xml_export_renders_the_same_image(name, tmp_path):
    scene = builtin_scene(name, 24, 16)
    xml = tmp_path / f"{name}.xml"
    xml.write_text(scene_to_xml(scene))
    a = np.array(mi.render(load_dict(scene), spp=8, seed=3))
    b = np.array(mi.render(mi.load_file(str(xml)), spp=8, seed=3))
    assert np.all(np.isfinite(a)) and a.mean() > 0.01
    # Same seed, same scene: the pixels without cloth (sky, most of the floor: 37-59% of
    # these frames) agree to float precision. Transforms read back from XML differ in the
    # last bits, which moves hits' uv on cloth tiled hundreds of times and so the
    # control-variate residual texel: those pixels differ by noise, with zero mean.
    diff = (a - b).ravel()
    assert np.mean(np.abs(diff) < 1e-4) > 0.3
    assert abs(diff.mean()) <= 5 * diff.std() / np.sqrt(diff.size) + 1e-6


def test_render_builtin_scene_writes_exr_and_png(tmp_path):
    out = tmp_path / "img" / "plane.exr"
    result = run("render", "plane", "--spp", "2", "--res", "32x18", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert out.stat().st_size > 0 and out.with_suffix(".png").stat().st_size > 0
    assert "M samples/s" in result.stdout
    # the rate is over the render alone; kernel compilation is reported beside it
    samples, render_s, compile_s = (float(v) for v in re.search(
        r"([0-9.]+) M samples/s \(render ([0-9.]+) s, plus ([0-9.]+) s kernel compilation\)", result.stdout).groups())
    assert compile_s >= 0 and samples == pytest.approx(32 * 18 * 2 / render_s / 1e6, rel=0.05, abs=0.01)


def test_scene_command_writes_xml_and_meshes_then_refuses_to_overwrite(tmp_path):
    out = tmp_path / "drape.xml"
    first = run("scene", "drape", "--out", str(out), "--res", "24x16")
    assert first.returncode == 0, first.stderr
    assert any((tmp_path / "meshes").glob("*.ply"))
    before = out.read_text()
    second = run("scene", "drape", "--out", str(out))
    assert second.returncode != 0 and "--force" in second.stderr
    assert out.read_text() == before
    rendered = run("render", str(out), "--spp", "1", "--res", "20x12", "--out", str(tmp_path / "d.exr"))
    assert rendered.returncode == 0, rendered.stderr


def test_exported_scene_folder_can_be_moved(tmp_path, monkeypatch):
    """Meshes and cloth maps directories are written relative to the XML: the exported
    folder loads from where it was moved to, from another working directory (the maps were
    named by absolute path: "maps directory '.../x/maps/denim_maps-...' does not exist")."""
    from mscloth.loading import load_file

    out = tmp_path / "x" / "denim.xml"
    result = run("scene", "denim", "--out", str(out), "--res", "16x9")
    assert result.returncode == 0, result.stderr
    assert 'name="pattern" value="maps/denim_maps-' in out.read_text()
    moved = tmp_path / "moved"
    (tmp_path / "x").rename(moved)
    monkeypatch.chdir(tmp_path)
    scene = load_file(str(moved / "denim.xml"))
    assert tuple(scene.sensors()[0].film().size()) == (16, 9)


def test_exported_fabric_file_is_named_relative_to_the_xml(tmp_path, monkeypatch):
    """`scene swatch --fabric black.json --out fb/sub/a.xml` wrote "black.json", relative to
    the working directory, which the BSDF does not look in: the XML names it from its folder
    and loads from anywhere."""
    import json

    from mscloth.cli import main
    from mscloth.loading import load_file

    (tmp_path / "black.json").write_text(json.dumps({"base": "denim", "warp_color": [0.05, 0.05, 0.05]}))
    monkeypatch.chdir(tmp_path)
    assert main(["scene", "swatch", "--fabric", "black.json", "--out", "fb/sub/a.xml", "--res", "16x12"]) == 0
    xml = tmp_path / "fb" / "sub" / "a.xml"
    assert 'name="fabric" value="../../black.json"' in xml.read_text()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert tuple(load_file(str(xml)).sensors()[0].film().size()) == (16, 12)


def test_scene_exports_the_resolution_render_renders(tmp_path, capsys):
    """`scene swatch` wrote 512x288 while `render swatch` renders 480x360: the fov is
    horizontal, so the framing differed. Both take the scene builder's own default."""
    import inspect

    from mscloth.cli import main
    from mscloth.scenes.swatch import swatch_scene

    out = tmp_path / "s.xml"
    assert main(["scene", "swatch", "--out", str(out)]) == 0
    text = out.read_text()
    defaults = inspect.signature(swatch_scene).parameters
    for key in ("width", "height"):
        assert f'<integer name="{key}" value="{defaults[key].default}"/>' in text
    assert (defaults["width"].default, defaults["height"].default) == (480, 360)


def _cloths(scene):
    return [node["bsdf"] for node in scene.values() if isinstance(node, dict) and node.get("bsdf", {}).get("type") == "cloth"]


#: Largest fraction of a shiny scene's tile that may be holes between yarns: real satin and
#: denim are dense (the default generated maps of satin-8-3 and twill-3-1 have 3.5%).
MAX_GAP_FRACTION = 0.005


@pytest.mark.parametrize("name", SHINY_SCENES)
def test_shiny_scene_low_sun_dim_sky_dense_maps(name):
    """A strong sun 10-20 degrees above the horizon, a sky at most a tenth of the rough scenes',
    cloth maps (generated once, keyed by their parameters) with nearly no gaps, and the
    parameters of shiny satin or rough denim."""
    scene = builtin_scene(name, 32, 18)
    assert scene["integrator"]["type"] == "clothpath"
    sun = np.array(scene["sun"]["direction"], dtype=float)
    elevation = np.degrees(np.arcsin(-sun[1] / np.linalg.norm(sun)))
    assert 10.0 <= elevation <= 20.0 and min(scene["sun"]["irradiance"]["value"]) >= 5.0
    sky = np.array(scene["sky"]["radiance"]["value"])
    rough_sky = np.array(builtin_scene("plane", 32, 18)["sky"]["radiance"]["value"])
    assert np.all(sky <= 0.1 * rough_sky + 1e-9) and np.all(sky >= 0.05 * rough_sky - 1e-9)
    cloths = _cloths(scene)
    assert cloths
    for bsdf in cloths:
        maps = ClothMaps.load(bsdf["pattern"])
        gaps = 1.0 - float(maps.gap.mean())
        assert gaps < MAX_GAP_FRACTION, gaps
        if name == "denim":
            assert maps.meta["name"] == "twill-3-1" and 0.3 <= bsdf["roughness"] <= 0.35
            warp, weft = np.array(maps.meta["warp_colors"][0]), np.array(maps.meta["weft_colors"][0])
            assert warp[2] > 2 * warp[0] and weft.min() > 0.3  # indigo warp, ecru weft
        else:
            assert maps.meta["name"] == "satin-8-3" and bsdf["roughness"] == 0.12
            assert bsdf["specular_albedo"] == 0.8 and max(bsdf["diffuse_albedo"]["value"]) <= 0.15
            assert bsdf["specular_transmittance"] <= 0.1 and bsdf["sheen_thickness"] <= 0.15
    # The default maps of the same pattern have gaps: the dense maps are the scene's choice.
    default = generate_maps(maps.meta["name"], maps.resolution)
    assert 1.0 - float(default.gap.mean()) > 5 * MAX_GAP_FRACTION
    # Generated once: a second call names the same directory and does not write it again
    # (it only marks it used).
    inode = (Path(cloths[0]["pattern"]) / "maps.npz").stat().st_ino
    assert _cloths(builtin_scene(name, 32, 18))[0]["pattern"] == cloths[0]["pattern"]
    assert (Path(cloths[0]["pattern"]) / "maps.npz").stat().st_ino == inode


@pytest.mark.parametrize("name", SHINY_SCENES)
def test_shiny_scene_renders_finite_and_writes_as_xml_with_its_maps(name, tmp_path):
    """``mscloth scene`` writes the XML and the maps beside it; the XML loads and renders
    (32x18, 2 spp) a finite, non-black image (the dictionary's render: the XML export test)."""
    out = tmp_path / f"{name}.xml"
    result = run("scene", name, "--out", str(out), "--res", "32x18")
    assert result.returncode == 0, result.stderr
    patterns = {bsdf["pattern"] for bsdf in _cloths(SCENES[name](32, 18, maps_dir=tmp_path / "maps"))}
    text = out.read_text()
    for pattern in patterns:  # relative to the XML, as its meshes
        assert Path(pattern).parent == (tmp_path / "maps").resolve() and f'value="maps/{Path(pattern).name}"' in text
    img = np.array(mi.render(mi.load_file(str(out)), spp=2, seed=1))
    assert img.shape == (18, 32, 3) and np.all(np.isfinite(img)) and img.mean() > 0.01


@pytest.mark.parametrize("args,message", [
    (["render", "nosuch"], "unknown scene 'nosuch'"),
    (["render", "missing.xml"], "does not exist"),
    (["render", "plane", "--spp", "0"], "[1, 65536]"),
    (["render", "plane", "--res", "wide"], "WIDTHxHEIGHT"),
    (["render", "plane", "--res", "4x4"], "[8, 16384]"),
    (["render", "plane", "--out", "image.png"], ".exr"),
    (["scene", "nosuch", "--out", "x.xml"], "unknown scene"),
    (["maps", "jersey", "--plies", "3", "--out", "m"], "--plies does not apply to jersey"),
    (["maps", "plain", "--ply-twist", "30", "--out", "m"], "--ply-twist needs --plies 2 or more"),
    (["maps", "denim", "--fabric", "--twist", "20", "--out", "m"], "--twist does not apply to a fabric preset"),
    # the flag given, not --fabric NAME
    (["render", "plane", "--view", "close"], "--view applies to the swatch scene only (mscloth render swatch "
                                             "--view close), not to 'plane'"),
    (["scene", "plane", "--out", "p.xml", "--light", "sunsky"], "(mscloth scene swatch --light sunsky)"),
])
def test_bad_input_is_one_clear_line(args, message, tmp_path):
    result = subprocess.run([sys.executable, "-m", "mscloth", *args], capture_output=True, text=True,
                            timeout=120, cwd=tmp_path)
    assert result.returncode != 0
    assert message in result.stderr
    assert "Traceback" not in result.stderr
    assert not any(tmp_path.rglob("*.exr")) and not any(tmp_path.rglob("*.png"))


def test_malformed_scene_file(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'><shape type='nosuchshape'/></scene>")
    result = run("render", str(bad), "--out", str(tmp_path / "x.exr"))
    assert result.returncode != 0 and "cannot load" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "x.exr").exists()


SWITCHES = [dict(), dict(visibility=False), dict(unbiased_ccv=True), dict(parallax=True),
            dict(direction_rank=24), dict(direction_rank=24, unbiased_ccv=True), dict(sheen_thickness=0.0),
            dict(specular_albedo=0.0, specular_transmittance=0.0), dict(multiscale=False)]


@pytest.mark.parametrize("switches", SWITCHES, ids=lambda d: ",".join(f"{k}={v}" for k, v in d.items()) or "default")
def test_every_switch_renders_a_finite_image(switches):
    """The plane scene (woven and knitted cloth, sky and sun, footprints from close-up to
    the horizon) with each of cloth's switches: compiles (Dr.Jit traces a different kernel
    for each) and gives a finite, non-black image. Small tiles (64 texels) and two visibility clusters: the switches change the
    kernels and the tables' form, not with the tile's size or the clusters' count (which
    unrolls loops: 8 made the unbiased_ccv kernel take 80 s to compile)."""
    mscloth.register()
    scene = builtin_scene("plane", 24, 14)
    assert set_cloth_parameters(scene, resolution=64, clusters=2, **switches) == 2
    img = np.array(mi.render(load_dict(scene), spp=2))
    assert np.all(np.isfinite(img)) and img[..., :3].mean() > 0.05



def _under_cloth_ceiling(scattered_footprints: bool, multiscale: bool = True) -> dict:
    """A diffuse floor under a cloth ceiling, sky and sun above it: the floor's light comes
    through the cloth, shaded where floor paths meet it after a rough (diffuse) bounce."""
    T = mi.ScalarTransform4f
    return {"type": "scene",
            "integrator": {"type": "clothpath", "scattered_footprints": scattered_footprints},
            "sensor": {"type": "perspective", "fov": 60,
                       "to_world": T().look_at(origin=[0, 0, 0.5], target=[0, 0.3, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 24, "height": 24, "rfilter": {"type": "box"}}},
            "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.5, 0.6, 0.7]}},
            "sun": {"type": "directional", "direction": [0.3, 0.2, -1.0], "irradiance": {"type": "rgb", "value": [3, 3, 3]}},
            "floor": {"type": "rectangle", "to_world": T().scale(20.0), "bsdf": {"type": "diffuse"}},
            "ceiling": {"type": "rectangle", "to_world": T().translate([0, 0, 1.0]) @ T().scale(20.0),
                        "bsdf": {"type": "cloth", "pattern": "twill-2-1", "uv_scale": 400.0, "multiscale": multiscale}}}


def test_point_shading_after_rough_bounces_keeps_the_image():
    """clothpath shades cloth at the hit point after a non-delta bounce by default, whole
    ray-cone footprints with ``scattered_footprints``, and brute force shades every hit
    fibre-level: the three estimate the same image. Tolerance: 4 sigma of the difference of
    the per-seed means, plus 1% of the mean for the footprint form's stated approximations
    (binning, mean SGGX)."""
    def means(*args):
        loaded = load_dict(_under_cloth_ceiling(*args))
        return np.array([np.array(mi.render(loaded, spp=16, seed=s))[..., :3].mean() for s in range(8)])

    point, cone, brute = means(False), means(True), means(False, False)
    assert np.all(np.isfinite(point)) and point.mean() > 0.01
    for other in (cone, brute):
        sigma = np.sqrt(point.var(ddof=1) / len(point) + other.var(ddof=1) / len(other))
        assert abs(point.mean() - other.mean()) < 4.0 * sigma + 0.01 * other.mean(), (point.mean(), other.mean(), sigma)


def test_render_refuses_to_overwrite_without_force(tmp_path, capsys):
    """As `mscloth scene` and `mscloth maps`: an existing EXR, or the PNG beside it, is only
    replaced with --force (and the refusal comes before the render)."""
    from mscloth.cli import main

    out = tmp_path / "plane.exr"
    args = ["render", "plane", "--spp", "1", "--res", "16x9", "--out", str(out)]
    assert main(args) == 0
    png = out.with_suffix(".png")
    before = png.read_bytes()
    capsys.readouterr()
    for existing in (out, png):
        assert main(args) == 2
        captured = capsys.readouterr()
        assert captured.err.strip() == f"mscloth: error: {existing} exists; pass --force to overwrite"
        assert "mscloth render:" not in captured.out and png.read_bytes() == before
        if existing == out:
            out.unlink()  # the PNG alone still blocks
    assert main(args + ["--force"]) == 0
    assert out.is_file() and out.with_suffix(".png").read_bytes() != b""


@pytest.mark.parametrize("command", ["render", "demo", "scene"])
@pytest.mark.parametrize("why", ["a file in the way", "permission denied"])
def test_unwritable_out_fails_before_rendering_and_names_it(tmp_path, capsys, monkeypatch, command, why):
    import errno

    import mscloth.atomic
    from mscloth.cli import main

    if why == "a file in the way":
        blocker = tmp_path / "a_file"
        blocker.write_text("x")
        folder = blocker / "sub"
    else:
        folder = tmp_path / "read-only"

        def refuse(path):
            raise PermissionError(errno.EACCES, "Permission denied", str(path))

        monkeypatch.setattr(mscloth.atomic, "_create_file", refuse)  # root ignores chmod 0500
    if command == "render":
        out = folder / "x.exr"
        args = ["render", "plane", "--spp", "1", "--res", "16x9", "--out", str(out)]
    elif command == "scene":
        out = folder / "x.xml"
        args = ["scene", "plane", "--out", str(out)]
    else:
        out = folder / "demo.exr"
        args = ["demo", "--spp", "1", "--res", "16", "--out", str(folder)]
    assert main(args) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith(f"mscloth: error: cannot write {out}: ") and captured.err.count("\n") == 1
    assert "samples/s" not in captured.out and "render [" not in captured.err


def test_render_names_its_output_after_the_scene_and_renders_the_count_the_sampler_takes(
        tmp_path, capsys, monkeypatch):
    # multijitter takes 12 samples for --spp 10: said once, in mscloth's words, and the
    # header and the rate say 12. The default --out is out/SCENE.exr.
    from mscloth.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["render", "plane", "--spp", "10", "--res", "16x9"]) == 0
    captured = capsys.readouterr()
    assert (tmp_path / "out" / "plane.exr").is_file() and (tmp_path / "out" / "plane.png").is_file()
    assert "plane, 16x9, 12 spp" in captured.out
    warned = [line for line in captured.err.splitlines() if "warning" in line.lower() or "WARN" in line]
    assert warned == ["mscloth: warning: the scene's sampler (MultijitterSampler) takes 12 samples per pixel, "
                      "not --spp 10: rendering 12"], captured.err


def test_an_output_whose_png_is_a_directory_fails_before_rendering(tmp_path, capsys):
    from mscloth.cli import main

    (tmp_path / "d.png").mkdir()
    assert main(["render", "plane", "--spp", "1", "--res", "16x9", "--out", str(tmp_path / "d.exr"), "--force"]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"mscloth: error: cannot write {tmp_path / 'd.png'}: it is a directory\n"
    assert not (tmp_path / "d.exr").exists() and "mscloth render:" not in captured.out
