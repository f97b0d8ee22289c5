"""A link URL that cannot be used is refused before the bridge starts (one error line, exit 1),
not left to a board thread that fails while the bridge runs on doing nothing."""

from __future__ import annotations

import subprocess
import sys

import pytest

from hwbridge.bridge import BoardSpec
from hwbridge.errors import LinkError


@pytest.mark.parametrize(
    ("url", "said"),
    [
        ("foo://bar", "unknown link scheme 'foo'"),
        ("serial:///dev/ttyS0?baud=abc", "bad value 'abc' for option 'baud'"),
        ("socket://h:notaport", "bad port"),
    ],
)
def test_connect_refuses_a_bad_url_at_once(url: str, said: str) -> None:
    with pytest.raises(LinkError, match=said):
        BoardSpec(url)
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "connect", url],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and said in lines[0], done.stderr
