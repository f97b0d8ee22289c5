"""``examples/README.md`` names files that exist: every path it names in backquotes or links."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "examples" / "README.md"

# a `quoted` path (with a / or a file suffix) or a markdown link's target
_QUOTED = re.compile(r"`([A-Za-z0-9_.\-/]+)`")
_LINK = re.compile(r"\]\(([^)#\s]+)\)")


def _named_paths(text: str) -> list[str]:
    found = [m for m in _QUOTED.findall(text) if "/" in m or re.search(r"\.[a-z]{2,4}$", m)]
    return found + [m for m in _LINK.findall(text) if "://" not in m]


def test_every_path_the_examples_readme_names_exists() -> None:
    text = README.read_text(encoding="utf-8")
    named = _named_paths(text)
    assert len(named) >= 5, named  # the robot files, the layout, the sketch...
    missing = [
        path for path in named if not (ROOT / path).exists() and not (README.parent / path).exists()
    ]
    assert not missing, f"examples/README.md names missing files: {missing}"
