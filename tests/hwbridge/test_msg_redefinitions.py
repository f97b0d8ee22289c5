"""A --msg-path package may hold the standard definitions themselves: identical ones are accepted
(std_msgs/Empty included, which rosbags stores with a placeholder member), different ones are
refused with the file."""

from __future__ import annotations

import functools
from pathlib import Path

from tests.cliutil import run_hwbridge

_hwbridge = functools.partial(run_hwbridge, timeout=60)


def test_the_real_std_msgs_definitions_are_accepted(tmp_path: Path) -> None:
    package = tmp_path / "std_msgs" / "msg"
    package.mkdir(parents=True)
    (package / "Empty.msg").write_text("")
    (package / "String.msg").write_text("string data\n")
    for name, md5 in (
        ("std_msgs/Empty", "d41d8cd98f00b204e9800998ecf8427e"),
        ("std_msgs/String", "992ce8a1687cec8c8bd883ec73ca41d1"),
    ):
        done = _hwbridge("--msg-path", str(tmp_path), "msg", "md5", name)
        assert done.returncode == 0, done.stderr
        assert done.stdout.strip() == md5


def test_a_different_definition_is_refused_naming_the_file(tmp_path: Path) -> None:
    package = tmp_path / "std_msgs" / "msg"
    package.mkdir(parents=True)
    (package / "String.msg").write_text("int32 data\n")
    done = _hwbridge("--msg-path", str(tmp_path), "msg", "md5", "std_msgs/String")
    assert done.returncode == 1
    assert f"{package / 'String.msg'}: redefines std_msgs/String differently" in done.stderr
