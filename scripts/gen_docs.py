"""README.md's `cloth` parameter table, generated from mscloth.bsdf.parameter_docs (the
table the plugin docstring is generated from too).

    python scripts/gen_docs.py           # exit 1 and say so if README.md is out of date
    python scripts/gen_docs.py --write   # rewrite the table between the markers

The table lies between the lines ``<!-- parameters:begin -->`` and ``<!-- parameters:end -->``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"
BEGIN, END = "<!-- parameters:begin -->", "<!-- parameters:end -->"


def generated(readme: str) -> str:
    """``readme`` with what lies between the markers replaced by the generated section."""
    from mscloth.bsdf.parameter_docs import markdown_section

    head, rest = readme.split(BEGIN + "\n", 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{markdown_section()}\n{END}{tail}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="rewrite README.md's table")
    args = parser.parse_args(argv)
    text = README.read_text()
    new = generated(text)
    if args.write:
        if new != text:
            README.write_text(new)
        return 0
    if new != text:
        print(f"{README}: the parameter table is out of date; run scripts/gen_docs.py --write",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
