"""Every fact the package cites is in the repository (issue 40): ``docs/reference.md#section``
citations name a section that exists, and nothing points to a file outside the repository."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _cited() -> list[tuple[Path, str]]:
    out = []
    for p in sorted((ROOT / "gprace").rglob("*")):
        if p.suffix in (".py", ".toml") and p.is_file():
            text = p.read_text(encoding="utf-8")
            assert "REFERENCE.md" not in text, f"{p}: cites REFERENCE.md, which is not in the repository"
            out += [(p, m) for m in re.findall(r"docs/reference\.md#([a-z0-9-]+)", text)]
    return out


def test_reference_citations_name_existing_sections():
    sections = set(re.findall(r"^## ([a-z0-9-]+)\s*$", (ROOT / "docs" / "reference.md").read_text(), flags=re.M))
    cited = _cited()
    assert len(cited) >= 15  # the docstrings and configs that cite the reference facts
    missing = [(str(p.relative_to(ROOT)), s) for p, s in cited if s not in sections]
    assert not missing, missing
    assert {s for _, s in cited} == sections  # and every section is cited somewhere
