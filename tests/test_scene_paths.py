"""Relative paths in a scene file (a ``cloth``'s ``pattern``) resolve against its directory,
as Mitsuba resolves its own; a missing one says so."""
import os
import shutil
from pathlib import Path

import mitsuba as mi
import pytest

import mscloth
from mscloth.errors import PatternError
from mscloth.loading import load_file
from mscloth.maps.builtin import resolve_pattern

mscloth.register()

# The project's shared data sits beside the checkout (../shared), as in test_wif.py.
WIF_DIR = Path(os.environ.get("MSCLOTH_WIF_DIR") or Path(__file__).resolve().parents[2] / "shared" / "data" / "wif")


def _scene_dir_with_patterns(tmp_path) -> Path:
    """tmp_path/sub/scene.xml naming a WIF file and a maps directory beside it, relatively."""
    sub = tmp_path / "sub"
    (sub / "maps").mkdir(parents=True)
    shutil.copy(WIF_DIR / "54235plain.wif", sub / "draft.wif")
    resolve_pattern("jersey", 16).save(sub / "maps" / "knit")
    cloth = ('<bsdf type="cloth"><string name="pattern" value="{}"/>{}'
             '<boolean name="multiscale" value="false"/><boolean name="visibility" value="false"/></bsdf>')
    woven = cloth.format("draft.wif", '<integer name="resolution" value="24"/>')
    knit = cloth.format("maps/knit", "")
    (sub / "scene.xml").write_text(f'<scene version="3.0.0"><shape type="rectangle" id="woven">{woven}</shape>'
                                   f'<shape type="sphere" id="knit">{knit}</shape></scene>')
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    return sub


@pytest.mark.parametrize("loader", ["mscloth", "mitsuba"])
def test_relative_patterns_resolve_against_the_scene_file(tmp_path, monkeypatch, loader):
    sub = _scene_dir_with_patterns(tmp_path)
    monkeypatch.chdir(tmp_path / "elsewhere")
    xml = str(sub / "scene.xml")
    scene = load_file(xml) if loader == "mscloth" else mi.load_file(xml)
    bsdfs = {shape.id(): shape.bsdf() for shape in scene.shapes()}
    assert bsdfs["woven"].maps.meta["generator"] == "woven" and bsdfs["woven"].maps.resolution[1] == 24
    assert bsdfs["knit"].maps.meta["generator"] == "knit" and bsdfs["knit"].maps.resolution == resolve_pattern("jersey", 16).resolution


def test_relative_patterns_resolve_against_the_scene_file_from_the_cli_loader(tmp_path, monkeypatch):
    from mscloth.cli import load_scene_file

    sub = _scene_dir_with_patterns(tmp_path)
    monkeypatch.chdir(tmp_path / "elsewhere")
    before = str(mi.file_resolver())
    xml = sub / "scene.xml"
    text = xml.read_text().replace("<shape", '<sensor type="perspective"><film type="hdrfilm"/></sensor><shape', 1)
    xml.write_text(text)
    scene = load_scene_file(Path("..") / "sub" / "scene.xml", (8, 8))
    assert {shape.id() for shape in scene.shapes()} == {"woven", "knit"}
    assert str(mi.file_resolver()) == before  # the scene's directory is not left behind


def test_a_pattern_name_wins_over_a_directory_of_that_name_beside_the_scene(tmp_path):
    resolve_pattern("jersey", 16).save(tmp_path / "plain")
    xml = tmp_path / "scene.xml"
    xml.write_text('<scene version="3.0.0"><shape type="sphere" id="s"><bsdf type="cloth">'
                   '<string name="pattern" value="plain"/><integer name="resolution" value="24"/>'
                   '<boolean name="multiscale" value="false"/><boolean name="visibility" value="false"/>'
                   '</bsdf></shape></scene>')
    bsdf = load_file(xml).shapes()[0].bsdf()
    assert bsdf.maps.meta["generator"] == "woven" and bsdf.maps.resolution == (24, 24)


def test_missing_relative_maps_directory_in_a_scene_file_says_it_does_not_exist(tmp_path):
    xml = tmp_path / "scene.xml"
    xml.write_text('<scene version="3.0.0"><shape type="sphere"><bsdf type="cloth">'
                   '<string name="pattern" value="maps/missing"/></bsdf></shape></scene>')
    with pytest.raises(PatternError, match="maps directory 'maps/missing' does not exist"):
        load_file(xml)
