"""The documentation: the site builds without warnings, the README's results table is current."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tensegrity_sr.results_tables import main as results_tables

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(shutil.which("mkdocs") is None and not (Path(sys.executable).parent / "mkdocs").exists(),
                    reason="mkdocs not installed (pip install -e .[dev])")  # fmt: skip
def test_site_builds_strict(tmp_path: Path) -> None:
    mkdocs = Path(sys.executable).parent / "mkdocs"
    exe = str(mkdocs) if mkdocs.exists() else "mkdocs"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(ROOT)}
    r = subprocess.run([exe, "build", "--strict", "-d", str(tmp_path / "site")], cwd=ROOT,
                       capture_output=True, text=True, env=env, check=False)  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    assert (tmp_path / "site" / "api" / "identification" / "index.html").is_file()


def test_readme_results_table_matches_the_committed_json() -> None:
    assert results_tables(["--check"]) == 0


def test_readme_is_short_and_has_the_two_commands() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    assert "make demo" in text and "make test" in text


HISTORY = re.compile(
    r"\bsessions? \d|\bcommit [0-9a-f]{7}|\bissue #?\d|\bthe issue\b|\bissue's|\btargets? (?:is |are )?met",
    re.IGNORECASE,
)


def test_user_docs_tell_no_development_history() -> None:
    """README, docs, docstrings and tests describe the software as it is: no session
    numbers, commit hashes or issue references (history belongs in CHANGELOG.md)."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    for package in (
        "tensegrity_env",
        "identification",
        "policies",
        "tensegrity_sr",
        "tests",
        "benchmarks",
    ):
        pages += sorted((ROOT / package).rglob("*.py"))
    pages += sorted((ROOT / "policies").rglob("*.md"))
    for page in pages:
        if page.resolve() == Path(__file__).resolve():
            continue
        hits = HISTORY.findall(page.read_text())
        assert not hits, f"{page.relative_to(ROOT)}: {hits}"
