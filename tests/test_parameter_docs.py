"""One table documents the ``cloth`` parameters (mscloth.bsdf.parameter_docs): it lists
every parameter the plugin reads, once, with the code's defaults, and README.md and the
plugin docstring hold what is generated from it."""
import importlib.util
from pathlib import Path

import pytest

from mscloth.bsdf import parameter_docs
from mscloth.bsdf.parameter_docs import PARAMETER_DOCS, ParameterDoc, markdown_section
from mscloth.bsdf.parameters import (BOOL_PARAMETERS, FLOAT_PARAMETERS, INT_PARAMETERS, PARAMETER_NAMES,
                                     SPECTRUM_PARAMETERS, exposure_text)

ROOT = Path(__file__).resolve().parents[1]
_SPEC = importlib.util.spec_from_file_location("gen_docs", ROOT / "scripts" / "gen_docs.py")
gen_docs = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(gen_docs)


def test_every_parameter_read_has_exactly_one_row():
    names = [p.name for p in PARAMETER_DOCS]
    assert sorted(names) == sorted(PARAMETER_NAMES)
    assert len(names) == len(set(names))


def code_default(name):
    """The default ``read_parameters`` uses, as the docs write it."""
    if name in FLOAT_PARAMETERS:
        return FLOAT_PARAMETERS[name][0]
    if name in SPECTRUM_PARAMETERS:
        return SPECTRUM_PARAMETERS[name][0]
    if name in INT_PARAMETERS:
        return INT_PARAMETERS[name][0]
    if name in BOOL_PARAMETERS:
        return "true" if BOOL_PARAMETERS[name][0] else "false"
    return None  # fabric, pattern, resolution: read_parameters' own literals


@pytest.mark.parametrize("doc", PARAMETER_DOCS, ids=lambda d: d.name)
def test_documented_defaults_are_the_codes(doc):
    expected = code_default(doc.name)
    if expected is None:
        assert doc.default == {"fabric": "none", "pattern": "`plain`", "resolution": "0"}[doc.name]
    elif isinstance(expected, str):
        assert doc.default == expected
    else:  # the number first; what follows says how a fabric changes it
        assert float(doc.default.split()[0]) == expected


def test_readme_holds_the_generated_table():
    readme = (ROOT / "README.md").read_text()
    assert gen_docs.generated(readme) == readme, "README.md is out of date: run scripts/gen_docs.py --write"
    assert markdown_section() in readme
    for doc in PARAMETER_DOCS:
        assert f"| `{doc.name}` | {doc.type} | {doc.default} | {doc.meaning} | {exposure_text(doc.name)} |" in readme


def test_generation_follows_the_table(monkeypatch):
    """The generators read PARAMETER_DOCS: a changed row shows in README's section and the
    docstring's list-table, and an out-of-date README is reported."""
    changed = (ParameterDoc("roughness", "float", "0.3", "A `changed` meaning."),) + PARAMETER_DOCS[1:]
    monkeypatch.setattr(parameter_docs, "PARAMETER_DOCS", changed)
    assert "| `roughness` | float | 0.3 | A `changed` meaning. |" in markdown_section()
    rst_row = "   * - roughness\n     - float\n     - 0.3\n     - A ``changed`` meaning."
    assert rst_row in parameter_docs.rst_list_table()
    readme = (ROOT / "README.md").read_text()
    assert gen_docs.generated(readme) != readme


def test_plugin_docstring_is_generated_with_flags():
    from mscloth.bsdf.registry import cloth_class

    doc = cloth_class().__doc__
    table = doc.split(".. list-table::", 1)[1].split("\n\n", 2)[1]
    rows = table.split("   * - ")[1:]
    assert rows[0].split("\n     - ") == ["Parameter", "Type", "Default", "Meaning", "Flags\n"]
    assert [row.split("\n", 1)[0] for row in rows[1:]] == [p.name for p in PARAMETER_DOCS]
    for row, p in zip(rows[1:], PARAMETER_DOCS):
        cells = [c.strip() for c in row.split("\n     - ")]
        assert cells[1:3] == [p.type, parameter_docs.to_rst(p.default)]
        assert " ".join(cells[3].split()) == parameter_docs.to_rst(p.meaning)
        assert cells[4] == exposure_text(p.name)
