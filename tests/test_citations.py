"""Citations resolve: sources are cited by the keys of docs/references.md, never by files a clone does not have.

The project's notes cite the papers as "seed 000"/"seed 001" and the reference numbers as "REFERENCE.md"; neither
exists in a user's clone. Every ``[Key]`` used must be defined in docs/references.md.
"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REFERENCES = REPO / "docs" / "references.md"
SCANNED = ("oacli", "tests", "benchmarks", "docs", "configs", "README.md")
SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".txt"}

# A citation key: a capitalised name ending in a year or in FSW/Code/Data ("[Doerr2021]", "[RattleCode]").
KEY = re.compile(r"\[([A-Z][A-Za-z]*(?:\d{4}|FSW|Code|Data))\]")
# Pieces of text only the project's workspace resolves ("seed 000" and "seed 001" spelled with a space).
UNRESOLVABLE = re.compile(r"seed 00[01]\b|seeds/|REFERENCE\.md", re.IGNORECASE)


def scanned_files() -> list[Path]:
    """The text files whose citations must resolve (this test itself excluded)."""
    out = []
    for name in SCANNED:
        path = REPO / name
        files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.suffix in SUFFIXES)
        out += [p for p in files if p.resolve() != Path(__file__).resolve()]
    return out


def defined_keys() -> set[str]:
    """The keys docs/references.md defines (``**[Key]**`` in its tables)."""
    return set(re.findall(r"\*\*\[([^\]]+)\]\*\*", REFERENCES.read_text(encoding="utf-8")))


def test_references_define_the_core_keys():
    keys = defined_keys()
    assert {"Doerr2021", "ReSWARM2023", "RATTLE2022", "Rakovic2005", "Mayne2005", "AstrobeeFSW", "RattleCode"} <= keys


def test_every_cited_key_is_defined():
    keys = defined_keys()
    missing = []
    for path in scanned_files():
        for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            missing += [f"{path.relative_to(REPO)}:{lineno} [{k}]" for k in KEY.findall(line) if k not in keys]
    assert not missing, "citation keys not defined in docs/references.md:\n" + "\n".join(missing)


def test_no_citation_of_workspace_only_files():
    found = []
    for path in scanned_files():
        for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if UNRESOLVABLE.search(line):
                found.append(f"{path.relative_to(REPO)}:{lineno}: {line.strip()[:100]}")
    assert not found, "cite by key (docs/references.md) instead of:\n" + "\n".join(found)
