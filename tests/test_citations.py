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


# A place in the two seed papers cited without its key ("Doerr Eq. 30", "ReSWARM §4.2"): one citation form only.
BARE = re.compile(r"(?:^|[^\[A-Za-z/])(?:Doerr|ReSWARM)(?: et al\.)?(?: 2021)?,? (?:Eqs?\.|§|Table|Fig\.)")


def test_places_in_the_seed_papers_are_cited_with_their_key():
    bare = []
    for path in scanned_files():
        if path == REFERENCES:
            continue
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if BARE.search(line):
                bare.append(f"{path.relative_to(REPO)}:{n}: {line.strip()[:100]}")
    assert not bare, "cite as [Doerr2021] Eq. N / [ReSWARM2023] §N:\n" + "\n".join(bare[:20])
    assert BARE.search("the LQR cost (Doerr Eq. 10)") and BARE.search("ReSWARM §4.2.1 says")
    assert not BARE.search("([Doerr2021] Eq. 10)") and not BARE.search("Doerr et al. 2021 plan")

