"""The package's layout, read from its sources' import statements (top-level and inside
functions alike): no import cycles between mscloth's modules, the renderer never reaches the
evaluation, and only the evaluation imports its optional extra (matplotlib, FLIP)."""
import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

#: The renderer: none of its modules may import mscloth.evaluation, directly or through others.
RENDERER = ("bsdf", "maps", "precompute", "patterns", "scattering", "integrators")
#: Third-party modules of the ``evaluation`` extra (pyproject.toml).
EVALUATION_EXTRA = ("matplotlib", "flip_evaluator")
#: Cycles there already are, in code this change leaves alone; a new one fails the test.
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


def test_only_the_evaluation_imports_its_optional_extra():
    graph, third_party = import_graph()
    users = {name for name, modules in third_party.items() if modules & set(EVALUATION_EXTRA)}
    assert users and all(name.startswith("mscloth.evaluation.") for name in users), users
