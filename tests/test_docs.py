"""The documents' cross-references resolve: every performance-log entry (``performance-log.md
L<n>``, ``log L<n>``) and design section (``design.md §<n>``) the code and the documents cite
exists, so a moved or missing entry shows."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def sources():
    """Every file that cites the documents: the package, tests, benchmarks, scripts, docs."""
    for folder in ("src", "tests", "bench", "scripts", "docs"):
        yield from (p for p in sorted((ROOT / folder).rglob("*")) if p.suffix in (".py", ".md"))
    yield ROOT / "README.md"


def citations(pattern: str, text: str) -> set:
    """The numbers cited in ``text`` by ``pattern`` (a regex whose group 1 is a list such as
    ``L3, L12`` or ``L1-L19``)."""
    found = set()
    for match in re.finditer(pattern, text):
        numbers = [int(n) for n in re.findall(r"\d+", match.group(1))]
        if re.search(r"L?\d+\s*[-–]\s*L\d+", match.group(1)):
            found.update(range(numbers[0], numbers[-1] + 1))
        else:
            found.update(numbers)
    return found


def test_cited_performance_log_entries_exist():
    entries = {int(n) for n in re.findall(r"^## L(\d+)\.", (DOCS / "performance-log.md").read_text(), re.M)}
    assert entries == set(range(1, max(entries) + 1))
    pattern = r"(?:performance-log(?:\.md)?|\blog),? (?:entr(?:y|ies) )?(L\d+(?:\s*(?:,|and|[-–])\s*L\d+)*)"
    missing = {}
    for path in sources():
        cited = citations(pattern, path.read_text(errors="replace"))
        if cited - entries:
            missing[str(path.relative_to(ROOT))] = sorted(cited - entries)
    assert not missing, missing


def test_cited_design_sections_exist():
    text = (DOCS / "design.md").read_text()
    sections = {m for m in re.findall(r"^## (\d+)\.", text, re.M)}
    sections |= set(re.findall(r"^\*\*(\d+\.\d+)[ .]", text, re.M))
    missing = {}
    for path in sources():
        cited = set(re.findall(r"design\.md §(\d+(?:\.\d+)?)", path.read_text(errors="replace")))
        if cited - sections:
            missing[str(path.relative_to(ROOT))] = sorted(cited - sections)
    assert not missing, missing
