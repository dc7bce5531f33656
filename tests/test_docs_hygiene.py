"""What a reader meets first is true (issue 22 item 10): the method is cited where it is
(docs/method.md, no SPEC the repository does not have), no path of a development machine,
a LICENSE as pyproject says."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEXTS = [ROOT / "README.md", ROOT / "configs" / "default.toml",
         *sorted((ROOT / "docs").glob("*.md"))]


def test_no_citation_of_a_spec_the_repository_does_not_have() -> None:
    assert not (ROOT / "SPEC.md").exists()
    for path in [*TEXTS, *sorted((ROOT / "evperc").rglob("*.py"))]:
        found = re.findall(r"\bSPEC\b", path.read_text())
        assert not found, f"{path.relative_to(ROOT)} cites SPEC {len(found)} times"


def test_method_sections_cited_exist() -> None:
    method = (ROOT / "docs" / "method.md").read_text()
    sections = {int(n) for n in re.findall(r"^## (\d+)\. ", method, flags=re.M)}
    assert sections == set(range(1, max(sections) + 1)) and max(sections) >= 7  # §1–§7, no gap
    for path in [*TEXTS, *sorted((ROOT / "evperc").rglob("*.py"))]:
        for n in re.findall(r"method(?:\.md)? §(\d+)", path.read_text()):
            assert int(n) in sections, (path, n)


def test_no_development_machine_paths() -> None:
    for path in TEXTS:
        assert "/work/" not in path.read_text(), path


def test_licence_file_matches_pyproject() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "evperc developers" in text
