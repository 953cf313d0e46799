"""The package's layout, read from its sources' import statements (top-level and inside
functions alike): no import cycles between mscloth's modules, the renderer never reaches the
evaluation, and only the evaluation imports its optional extra (matplotlib, FLIP). And the
tests use mscloth through public names only (no ``obj._private``)."""
import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

#: The renderer: none of its modules may import mscloth.evaluation, directly or through others.
RENDERER = ("bsdf", "maps", "precompute", "patterns", "scattering", "integrators")
#: The floors of the pipeline, in order (docs/architecture.md): each reaches only those before it.
FLOORS = ("patterns", "maps", "precompute", "bsdf", "integrators")
#: The floors below the renderer (NumPy only): none of their modules reaches Mitsuba or Dr.Jit.
NO_RENDERER = ("patterns", "maps", "precompute")
#: Third-party modules of the ``evaluation`` extra (pyproject.toml).
EVALUATION_EXTRA = ("matplotlib", "flip_evaluator")
#: Cycles tolerated for now (none): a new one fails the test.
KNOWN_CYCLES = []


def module_files() -> dict:
    """{dotted module name: its file} for every module of src/mscloth (a package by its __init__)."""
    modules = {}
    for path in sorted((SRC / "mscloth").rglob("*.py")):
        parts = path.relative_to(SRC).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def imported(name: str, path: Path, modules) -> tuple[set, set]:
    """(mscloth modules, other top-level modules) that ``path`` imports anywhere in its code.

    ``from X import a, b`` depends on X's own code when it reads an attribute of X, and on
    X.a when that is a submodule; ``from . import sub`` alone leaves the package's __init__ out
    (it only looks the submodule up)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    inside, outside = set(), set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                # `import a.b.c` runs a, a.b and a.b.c
                inside.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))
                outside.add(parts[0])
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                base = ".".join(base + ([node.module] if node.module else []))
            else:
                base = node.module
            submodules = {f"{base}.{alias.name}" for alias in node.names} & set(modules)
            inside |= submodules
            if len(submodules) < len(node.names):
                inside.add(base)
            outside.add(base.split(".")[0])
    return {m for m in inside if m in modules and m != name}, outside - {"mscloth"}


def import_graph() -> tuple[dict, dict]:
    modules = module_files()
    graph, third_party = {}, {}
    for name, path in modules.items():
        graph[name], third_party[name] = imported(name, path, modules)
    return graph, third_party


def cycles(graph: dict) -> list[set]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(component)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def reachable(graph: dict, start: str) -> set:
    seen, todo = set(), [start]
    while todo:
        for w in graph[todo.pop()] - seen:
            seen.add(w)
            todo.append(w)
    return seen


def test_the_graph_sees_imports_at_every_level_and_cycles_through_them():
    """The reader itself: a function-level import counts, and a two-module cycle is found."""
    graph, _ = import_graph()
    assert "mscloth.evaluation.report" in graph["mscloth.evaluation.compare"]  # imported inside run_compare
    assert "mscloth.scenes.builtin" in graph["mscloth.evaluation.renders"]  # inside scene_dict
    assert "mscloth.integrators.footprint" in graph["mscloth.integrators.clothpath"]  # `from . import footprint`
    assert "mscloth.integrators" not in graph["mscloth.integrators.clothpath"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]


def test_no_import_cycles_but_the_known_ones():
    found = cycles(import_graph()[0])
    assert [c for c in found if c not in KNOWN_CYCLES] == []


def test_the_renderer_never_reaches_the_evaluation():
    graph, _ = import_graph()
    assert "mscloth.evaluation.compare" in graph
    for name in graph:
        if (name.split(".") + [""])[1] in RENDERER or name in ("mscloth", "mscloth.render", "mscloth.loading"):
            reached = {m for m in reachable(graph, name) if m.startswith("mscloth.evaluation")}
            assert not reached, f"{name} imports {sorted(reached)}"


def test_each_floor_reaches_only_the_floors_before_it():
    graph, _ = import_graph()

    def floor(module):
        package = (module.split(".") + [""])[1]
        return FLOORS.index(package) if package in FLOORS else None

    for name in graph:
        if floor(name) is not None:
            above = sorted(m for m in reachable(graph, name) if (floor(m) or 0) > floor(name))
            assert not above, f"{name} ({FLOORS[floor(name)]}) reaches {above}"


def test_the_lower_floors_need_no_renderer():
    """patterns, maps and precompute (and the fibre NDF precompute shares with shading) run
    on NumPy alone: nothing they import, directly or through others, imports Mitsuba or Dr.Jit."""
    graph, third_party = import_graph()
    for name in graph:
        if (name.split(".") + [""])[1] in NO_RENDERER or name == "mscloth.scattering.fibre_ndf":
            renderer = {m for m in reachable(graph, name) | {name} if third_party[m] & {"mitsuba", "drjit"}}
            assert not renderer, f"{name} reaches Mitsuba or Dr.Jit through {sorted(renderer)}"


def test_only_the_evaluation_imports_its_optional_extra():
    graph, third_party = import_graph()
    users = {name for name, modules in third_party.items() if modules & set(EVALUATION_EXTRA)}
    assert users and all(name.startswith("mscloth.evaluation.") for name in users), users


def private_uses(path: Path) -> list[str]:
    """``line: name`` for each underscored attribute read (``x._name``) and each underscored
    name imported (``from m import _name``) in ``path``; dunders and the package's private
    modules (``mscloth.precompute._march``, whose public functions tests may import) aside."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names = []
        if isinstance(node, ast.Attribute):
            names = [node.attr]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = [a.name for a in node.names
                     if not (SRC / Path(*node.module.split("."), a.name + ".py")).is_file()]
        found += [f"{node.lineno}: {n}" for n in names if n.startswith("_") and not n.startswith("__")]
    return found


def test_tests_use_public_names_only(tmp_path):
    """No test calls an underscored method of the BSDF, or any other private name: what a
    test needs is public (fault injection through ``monkeypatch.setattr(module, "_name", ...)``
    aside, which names it in a string)."""
    sample = tmp_path / "test_sample.py"
    sample.write_text("from mscloth.precompute import _march\nfrom mscloth.precompute._march import _x, y\n"
                      "bsdf.__class__\nbsdf._calibrate()\n")
    assert private_uses(sample) == ["2: _x", "4: _calibrate"]
    tests = Path(__file__).resolve().parent
    bad = {path.name: uses for path in sorted(tests.glob("*.py")) if (uses := private_uses(path))}
    assert not bad, bad
