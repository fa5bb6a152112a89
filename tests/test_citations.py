"""Everything the project cites exists in the project: every ``docs/NAME.rst`` (and the
section it names) that code, configs, tests and the README point to, and no path outside
the repository."""

from __future__ import annotations

import itertools
import re

from .conftest import ROOT

SOURCES = [*ROOT.glob("src/scanqa/**/*.py"), *ROOT.glob("calib/*.toml"),
           *ROOT.glob("sample_data/*.toml"), *ROOT.glob("sample_data/*.sh"),
           *ROOT.glob("benchmarks/*.py"), *ROOT.glob("docs/studies/*.py"),
           ROOT / "README.md", ROOT / "Makefile",
           ROOT / "pyproject.toml", *ROOT.glob("docs/*.rst")]
CITE = re.compile(r"docs/([A-Za-z_]+)\.rst(?:,? ?\(?[\"']([^\"']+)[\"']\)?)?")


def _sections(rst: str) -> set[str]:
    """Section titles of a reStructuredText page (a line underlined by = - ~ ^)."""
    lines = rst.splitlines()
    return {a.strip() for a, b in itertools.pairwise(lines)
            if a.strip() and re.fullmatch(r"([=\-~^\"'])\1{2,}", b.strip())}


def test_every_cited_docs_page_and_section_exists():
    missing = []
    for path in SOURCES:
        for page, section in CITE.findall(path.read_text(encoding="utf-8")):
            target = ROOT / "docs" / f"{page}.rst"
            if not target.exists():
                missing.append(f"{path.relative_to(ROOT)} cites docs/{page}.rst")
            elif section and not any(section.lower() in s.lower()
                                     for s in _sections(target.read_text(encoding="utf-8"))):
                missing.append(f"{path.relative_to(ROOT)} cites section {section!r} of "
                               f"docs/{page}.rst")
    assert not missing, "\n".join(missing)


def test_nothing_outside_the_repository_is_cited():
    outside = re.compile(r"DESIGN\.md|shared/seed|\.\./shared|infer_paper_scanner")
    bad = [str(p.relative_to(ROOT)) for p in SOURCES
           if outside.search(p.read_text(encoding="utf-8"))]
    assert not bad, bad
