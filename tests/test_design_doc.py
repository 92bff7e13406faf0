"""Every citation of the design document ("design 2.4", "design sections 9.1 and 14.1", "docs/design.md 10.5") in
the code, the tests, the scripts and the docs names a section that docs/design.md has."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "docs" / "design.md"
TOKEN = r"\d+(?:\.\d+)*"
SEP = r"(?:, | and |/| / |-)"
CITATION = re.compile(rf"\b[Dd]esign(?:\.md)?(?: sections?)?\s+({TOKEN}(?:{SEP}{TOKEN})*)")
SUFFIXES = (".py", ".md", ".yaml", ".yml", ".sh", ".toml", ".txt")


def sections() -> set[str]:
    heads = re.findall(r"^#{2,4} (\d+(?:\.\d+)*)\.? ", DESIGN.read_text(encoding="utf-8"), flags=re.M)
    return set(heads)


def cited() -> dict[str, list[str]]:
    """section -> the places citing it."""
    files = [ROOT / "README.md"] + [
        p
        for d in ("src", "tests", "benchmarks", "scripts", "docs")
        for p in sorted((ROOT / d).rglob("*"))
        if p.suffix in SUFFIXES and p.is_file()
    ]
    out: dict[str, list[str]] = {}
    for f in files:
        for m in CITATION.finditer(f.read_text(encoding="utf-8")):
            for ref in re.split(SEP, m.group(1)):
                out.setdefault(ref, []).append(f.relative_to(ROOT).as_posix())
    return out


def test_the_design_document_has_numbered_sections():
    have = sections()
    assert {"1", "2.4", "5.5.2", "13.2", "15"} <= have
    assert len(have) > 60


def test_every_cited_design_section_exists():
    have = sections()
    missing = {ref: where for ref, where in cited().items() if ref not in have}
    assert not missing, f"citations of sections docs/design.md does not have: {missing}"
