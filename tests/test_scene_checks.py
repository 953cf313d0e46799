"""Scenes that would render worse than they should warn once (mscloth.scene_checks), and
only those."""
import warnings

import mitsuba as mi
import pytest

import mscloth
from mscloth.loading import load_dict, load_file
from mscloth.scene_checks import SceneWarning

mscloth.register()

#: Cheap cloth: no tables to build.
FIBRE = {"type": "cloth", "resolution": 16, "multiscale": False, "visibility": False}
MULTISCALE = {"type": "cloth", "resolution": 16}


def _ply(path, uvs: bool, first_uv=(0.0, 0.0)) -> str:
    """A one-triangle PLY file, with or without texture coordinates (the first vertex's:
    ``first_uv``)."""
    mesh = mi.Mesh("triangle", 3, 1, has_vertex_texcoords=uvs)
    params = mi.traverse(mesh)
    params["vertex_positions"] = [0, 0, 0, 1, 0, 0, 0, 1, 0]
    params["faces"] = [0, 1, 2]
    if uvs:
        params["vertex_texcoords"] = [*first_uv, 1, 0, 0, 1]
    params.update()
    mesh.write_ply(str(path))
    return str(path)


def _scene(integrator="path", **shapes) -> dict:
    scene = {"type": "scene", **shapes}
    if integrator is not None:
        scene["integrator"] = integrator if isinstance(integrator, dict) else {"type": integrator}
    return scene


def _scene_warnings(load, *args) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load(*args)
    return [str(w.message) for w in caught if issubclass(w.category, SceneWarning)]


def test_mesh_without_uvs_under_cloth_warns_once_naming_it(tmp_path):
    flat = _ply(tmp_path / "flat.ply", uvs=False)
    scene = _scene(sheet={"type": "ply", "filename": flat, "bsdf": FIBRE},
                   ball={"type": "sphere", "bsdf": FIBRE})
    messages = _scene_warnings(load_dict, scene)
    assert len(messages) == 1, messages
    assert "'sheet'" in messages[0] and "without UV" in messages[0] and "'ball'" not in messages[0]


def test_mesh_without_uvs_in_a_scene_file_is_named_by_its_file(tmp_path):
    _ply(tmp_path / "flat.ply", uvs=False)
    xml = tmp_path / "scene.xml"
    xml.write_text('<scene version="3.0.0"><shape type="ply"><string name="filename" value="flat.ply"/>'
                   '<bsdf type="cloth"><integer name="resolution" value="16"/>'
                   '<boolean name="multiscale" value="false"/><boolean name="visibility" value="false"/>'
                   '</bsdf></shape></scene>')
    messages = _scene_warnings(load_file, xml)
    assert len(messages) == 1 and "'flat.ply'" in messages[0], messages


@pytest.mark.parametrize("shape", ["mesh with UVs", "sphere", "rectangle", "disk", "cylinder",
                                   "mesh without UVs, not cloth"])
def test_shapes_with_uvs_or_without_cloth_do_not_warn(tmp_path, shape):
    if shape.startswith("mesh"):
        with_uvs = shape == "mesh with UVs"
        node = {"type": "ply", "filename": _ply(tmp_path / "m.ply", uvs=with_uvs),
                "bsdf": FIBRE if with_uvs else {"type": "diffuse"}}
    else:
        node = {"type": shape, "bsdf": FIBRE}
    assert _scene_warnings(load_dict, _scene(s=node)) == []


def test_multiscale_cloth_under_path_warns_once_to_use_clothpath():
    scene = _scene(a={"type": "rectangle", "bsdf": MULTISCALE}, b={"type": "sphere", "bsdf": MULTISCALE})
    messages = _scene_warnings(load_dict, scene)
    assert len(messages) == 1, messages
    assert "clothpath" in messages[0] and "PathIntegrator" in messages[0] and "'a'" in messages[0]


@pytest.mark.parametrize("wrap", [
    lambda cloth: {"type": "blendbsdf", "weight": 0.2, "a": {"type": "diffuse"}, "b": cloth},
    lambda cloth: {"type": "mask", "opacity": 0.9, "bsdf": cloth},
    lambda cloth: {"type": "blendbsdf", "weight": 0.5, "a": {"type": "diffuse"},
                   "b": {"type": "mask", "opacity": 0.9, "bsdf": cloth}},
], ids=["blendbsdf", "mask", "mask in blendbsdf"])
def test_cloth_nested_in_another_bsdf_is_checked_as_cloth(tmp_path, wrap):
    """Before the fix only a shape's own BSDF was looked at: a cloth inside ``blendbsdf``
    or ``mask`` on a mesh without UVs, under ``path``, gave no warning at all."""
    flat = _ply(tmp_path / "flat.ply", uvs=False)
    messages = _scene_warnings(load_dict, _scene(sheet={"type": "ply", "filename": flat, "bsdf": wrap(MULTISCALE)}))
    assert len(messages) == 2, messages
    assert "'sheet'" in messages[0] and "without UV" in messages[0]
    assert "'sheet'" in messages[1] and "PathIntegrator" in messages[1]
    # Fibre-level cloth under clothpath on a mesh with UVs: nothing to say.
    good = _ply(tmp_path / "uv.ply", uvs=True)
    assert _scene_warnings(load_dict, _scene("clothpath", sheet={"type": "ply", "filename": good,
                                                                 "bsdf": wrap(FIBRE)})) == []


@pytest.mark.parametrize("bsdf,integrator", [
    (FIBRE, "path"),                    # fibre-level cloth needs no footprints
    (MULTISCALE, "clothpath"),
    (MULTISCALE, {"type": "aov", "aovs": "dd:depth", "inner": {"type": "clothpath"}}),
    (MULTISCALE, None),                 # the integrator comes with mi.render: unknown here
])
def test_cloth_that_gets_the_footprints_it_needs_does_not_warn(bsdf, integrator):
    assert _scene_warnings(load_dict, _scene(integrator, s={"type": "rectangle", "bsdf": bsdf})) == []


def test_cli_render_warns_in_one_line(tmp_path, capsys):
    # `mscloth render x.xml --res` loads through its own path (the film size rewritten).
    from mscloth.cli import main

    _ply(tmp_path / "flat.ply", uvs=False)
    xml = tmp_path / "scene.xml"
    xml.write_text('<scene version="3.0.0"><integrator type="path"/>'
                   '<sensor type="perspective"><film type="hdrfilm"/></sensor>'
                   '<shape type="ply" id="sheet"><string name="filename" value="flat.ply"/><bsdf type="cloth">'
                   '<integer name="resolution" value="16"/><boolean name="multiscale" value="false"/>'
                   '<boolean name="visibility" value="false"/></bsdf></shape></scene>')
    assert main(["render", str(xml), "--spp", "1", "--res", "8x8", "--out", str(tmp_path / "x.exr")]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "warning" in line.lower()]
    assert len(lines) == 1 and lines[0].startswith("mscloth: warning: cloth on 'sheet'"), lines


@pytest.mark.parametrize("bad", ["nan", "inf"])
def test_mesh_with_non_finite_uvs_warns_and_renders_finite(tmp_path, bad):
    # A non-finite uv with finite uv edges (as Mitsuba's OBJ loader gives them) once placed
    # multi-scale cloth's table reads anywhere in memory: the render crashed (segmentation
    # fault) under clothpath. Now: a warning, and a finite image.
    import numpy as np

    obj = tmp_path / "bad.obj"
    obj.write_text("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
                   f"vt 0 0\nvt {bad} 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    cloth = dict(MULTISCALE, uv_scale=24.0)  # footprints of many texels: the multi-scale branch
    scene = _scene({"type": "clothpath"}, sheet={"type": "obj", "filename": str(obj), "bsdf": cloth},
                   light={"type": "constant"},
                   sensor={"type": "perspective",
                           "to_world": mi.ScalarTransform4f().look_at([0, 0, 3], [0, 0, 0], [0, 1, 0]),
                           "film": {"type": "hdrfilm", "width": 16, "height": 16}})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded = load_dict(scene)
    messages = [str(w.message) for w in caught if issubclass(w.category, SceneWarning)]
    assert len(messages) == 1 and "'sheet' (1 non-finite)" in messages[0], messages
    image = np.asarray(mi.render(loaded, spp=4))
    assert np.isfinite(image).all() and image.mean() > 0.0
