"""docs/equations.md is the index from an equation of the seed papers to the code that implements it.

Every equation a docstring cites by key ([Doerr2021] / [ReSWARM2023], or the older bare "Doerr" / "ReSWARM") must
have a row there, and every dotted name the index gives must exist (a module, or an attribute path inside one).
"""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
INDEX = REPO / "docs" / "equations.md"
CITATION = re.compile(
    r"(\[Doerr2021\]|\bDoerr|\[ReSWARM2023\]|\bReSWARM)(?: et al\.)?(?: 2021)?,? Eqs?\. ?"
    r"((?:\d+[a-z]?)(?:(?: ?[-–,] ?| and )\d+[a-z]?)*)")
ROW = re.compile(r"^\|\s*\[(Doerr2021|ReSWARM2023)\] Eqs?\. (\d+)\s*\|")
NAME = re.compile(r"`(oacli(?:\.[A-Za-z_][A-Za-z0-9_]*)+)`")


def _source(key: str) -> str:
    return "Doerr2021" if "Doerr" in key else "ReSWARM2023"


def expand(numbers: str) -> list[str]:
    """``"31-32, 35b"`` → ``["31", "32", "35b"]`` (ranges of whole equations expanded)."""
    out: list[str] = []
    for part in re.split(r",| and ", numbers):
        part = part.strip()
        span = re.fullmatch(r"(\d+)[a-z]?\s*[-–]\s*(\d+)[a-z]?", part)
        if span:
            out += [str(i) for i in range(int(span.group(1)), int(span.group(2)) + 1)]
        elif part:
            out.append(part)
    return out


def cited_equations() -> dict[tuple[str, str], set[str]]:
    """(source, equation number without its letter) → the docstrings' owners that cite it."""
    cited: dict[tuple[str, str], set[str]] = {}
    for path in sorted((REPO / "oacli").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        where = str(path.relative_to(REPO))
        nodes = [tree, *(n for n in ast.walk(tree)
                         if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef))]
        for node in nodes:
            doc = ast.get_docstring(node) or ""
            for m in CITATION.finditer(doc):
                for eq in expand(m.group(2)):
                    number = re.match(r"\d+", eq)
                    assert number is not None
                    cited.setdefault((_source(m.group(1)), number.group(0)), set()).add(
                        f"{where}:{getattr(node, 'name', '<module>')}")
    return cited


def index_rows() -> dict[tuple[str, str], list[str]]:
    rows: dict[tuple[str, str], list[str]] = {}
    for line in INDEX.read_text(encoding="utf-8").splitlines():
        m = ROW.match(line)
        if m:
            rows[(m.group(1), m.group(2))] = NAME.findall(line)
    return rows


def resolve(dotted: str) -> object:
    """Import the longest module prefix of ``dotted`` and walk the rest as attributes."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj: object = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(dotted)


def test_expand_ranges_and_letters():
    assert expand("31-32, 35b") == ["31", "32", "35b"]
    assert expand("15-28") == [str(i) for i in range(15, 29)]
    assert expand("34b, 35b") == ["34b", "35b"]
    assert expand("12 and 14") == ["12", "14"]


def test_the_citation_pattern_reads_both_forms():
    found = [(_source(m.group(1)), m.group(2)) for m in CITATION.finditer(
        "[Doerr2021] Eq. 28 and [Doerr2021] Eqs. 34-35; [ReSWARM2023] Eq. 27, [ReSWARM2023] Eqs. 38–39")]
    assert found == [("Doerr2021", "28"), ("Doerr2021", "34-35"), ("ReSWARM2023", "27"), ("ReSWARM2023", "38–39")]


def test_every_cited_equation_has_a_row():
    rows = index_rows()
    cited = cited_equations()
    assert len(cited) >= 30  # the docstrings cite most of [Doerr2021]'s 36 equations
    missing = {f"[{src}] Eq. {eq}": sorted(owners)[:3] for (src, eq), owners in cited.items() if (src, eq) not in rows}
    assert not missing, f"equations cited in docstrings but missing from docs/equations.md: {missing}"


def test_every_row_names_existing_code():
    rows = index_rows()
    assert len(rows) >= 36
    for (src, eq), names in rows.items():
        assert names, f"[{src}] Eq. {eq}: the row names no function"
        for dotted in names:
            try:
                resolve(dotted)
            except (ImportError, AttributeError) as exc:
                pytest.fail(f"[{src}] Eq. {eq}: {dotted} does not exist ({exc})")
