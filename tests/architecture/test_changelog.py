"""The changelog's fragments (changelog.d/, one per user-visible change) are ones towncrier can build into
CHANGELOG.md: each named `<issue>.<type>.md` with a type of [tool.towncrier], and the draft holds them all."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CONFIG = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["towncrier"]
FRAGMENTS = sorted((REPO / CONFIG["directory"]).glob("*.md"))


def test_every_fragment_is_named_for_its_issue_and_a_known_type():
    types = {t["directory"] for t in CONFIG["type"]}
    assert FRAGMENTS, "changelog.d/ holds the unreleased changes"
    for fragment in FRAGMENTS:
        m = re.fullmatch(r"(\d+)\.(\w+)(\.\d+)?\.md", fragment.name)
        assert m and m.group(2) in types, f"{fragment.name}: name it <issue>.<type>.md, type one of {sorted(types)}"
        assert fragment.read_text(encoding="utf-8").strip(), f"{fragment.name} is empty"


def test_the_changelog_has_the_place_towncrier_writes_to():
    assert CONFIG["start_string"] in (REPO / CONFIG["filename"]).read_text(encoding="utf-8")


@pytest.mark.skipif(importlib.util.find_spec("towncrier") is None,
                    reason="towncrier is not installed (pip install -e '.[docs]')")
def test_towncrier_drafts_the_next_entry_from_every_fragment():
    done = subprocess.run([sys.executable, "-m", "towncrier", "build", "--draft", "--version", "9.9.9"], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    for fragment in FRAGMENTS:
        first_words = " ".join(fragment.read_text(encoding="utf-8").split()[:6])
        assert first_words in " ".join(done.stdout.split()), f"{fragment.name} is not in the draft"
