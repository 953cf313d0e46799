"""The README's examples run as written."""
import re
from pathlib import Path

import mitsuba as mi
import numpy as np

import mscloth

README = (Path(__file__).resolve().parents[1] / "README.md").read_text()


def code_block(language: str, section: str | None = None) -> str:
    """The first ``language`` block of the README, or of its ``## section``."""
    text = README if section is None else README.split(f"## {section}\n", 1)[1].split("\n## ", 1)[0]
    match = re.search(r"```%s\n(.*?)```" % language, text, re.S)
    assert match, f"README has no {language} block"
    return match.group(1)


def test_python_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    source = code_block("python").replace("mi.set_variant(mscloth.default_variant())", "pass")
    namespace = {}
    exec(compile(source, "README.md", "exec"), namespace)
    image = np.array(namespace["image"])
    assert np.all(np.isfinite(image)) and image.mean() > 0.01
    assert (tmp_path / "cloth.png").exists()


def test_xml_example_loads_and_renders():
    mscloth.register()
    scene = mi.load_string(code_block("xml", "Using the plugin from Mitsuba XML"))
    image = np.array(mi.render(scene, spp=4))
    assert image.shape == (64, 64, 3) and np.all(np.isfinite(image)) and image.mean() > 0.01


def test_parameter_table_lists_every_parameter():
    from mscloth.bsdf.parameters import FLOAT_PARAMETERS, SPECTRUM_PARAMETERS

    for name in list(FLOAT_PARAMETERS) + list(SPECTRUM_PARAMETERS) + ["pattern", "resolution"]:
        assert f"| `{name}` |" in README, name


def test_fabric_xml_snippet_loads():
    mscloth.register()
    bsdf = code_block("xml", "Fabrics")
    scene = mi.load_string(f'<scene version="3.0.0"><shape type="rectangle">{bsdf}</shape></scene>')
    cloth = scene.shapes()[0].bsdf()
    assert cloth.maps.meta["fabric"] == "silk-charmeuse"
    width_mm = cloth.maps.meta["tile_size_mm"][0]
    assert abs(cloth.params.uv_scale[0] - 10.0 / width_mm) < 1e-3 * cloth.params.uv_scale[0]  # UVs in cm


def test_parameter_tables_flag_what_traverse_exposes():
    """README.md's `cloth` table and the plugin docstring's list-table give each parameter
    the flags of parameters.EXPOSED, the table that ``traverse`` follows ("—": not exposed)."""
    from mscloth.bsdf.parameters import EXPOSED, exposure_text

    section = README.split("## `cloth` parameters\n", 1)[1].split("\n## ", 1)[0]
    rows = {line.split("`")[1]: line.rstrip(" |").rsplit("| ", 1)[1]
            for line in section.splitlines() if line.startswith("| `")}
    assert set(EXPOSED) <= set(rows)
    assert {name: cell for name, cell in rows.items() if cell != exposure_text(name)} == {}

    mscloth.register()
    doc = type(mi.load_dict({"type": "cloth", "multiscale": False, "visibility": False})).__doc__
    table = doc.split(".. list-table::", 1)[1].split("\n\n", 2)[1]
    cells = {}
    for row in table.split("   * - ")[2:]:  # after the header row
        parts = row.split("\n     - ")
        for name in parts[0].split(", "):
            cells[name.strip()] = parts[-1].strip()
    assert set(rows) <= set(cells) and all(cells[name] == exposure_text(name) for name in cells)
    assert cells["roughness"] == "P, ∂ at fibre level, P multi-scale" and cells["pattern"] == "—"
