"""The board session of the C++ library (``firmware/HwBridge/src/hwbridge/node.h``), host-native.

``firmware/tests/test_session.cpp`` replays the golden transcript of PROTOCOL.md 2.12
(``protocols/vectors/native_session.json``) into a C++ board and compares every byte it writes,
then checks bad input (counted, dropped, session kept), heartbeats, the link timeout and HELLO
backoff, host restarts and pending requests failing; ``fuzz_session.cpp`` is a seeded,
time-bounded fuzz run of the session's receive path with guard words around the node. Each is
built with ``g++ -std=c++11 -Wall -Wextra -Werror``, plain and under ASan/UBSan, again with
the fixed-RTO reliable sender, and again in the hello-world profile's shape (no fragmentation,
the one-slot reliable sender).
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.firmware.test_cpp_core import CXXFLAGS, INCLUDE, SANITIZE, TESTS

Builder = Callable[[str], Path]
FUZZ_SECONDS = 3


def _transcript() -> str:
    spec = importlib.util.spec_from_file_location("session_vectors", TESTS / "session_vectors.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    lines: list[str] = module.lines()
    return "".join(line + "\n" for line in lines)


def _run(command: list[str], stdin: str, timeout: float = 120) -> str:
    result = subprocess.run(
        command, check=False, input=stdin, capture_output=True, text=True, timeout=timeout
    )
    output = result.stderr + result.stdout
    assert result.returncode == 0, f"{' '.join(command)} exited with {result.returncode}:\n{output}"
    assert "runtime error" not in result.stderr, result.stderr
    return result.stdout


@pytest.fixture(scope="module", params=["plain", "sanitized", "fixed_rto", "hello"])
def build(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Builder:
    if shutil.which("g++") is None:
        pytest.skip("g++ is not installed (Debian package g++)")
    out = tmp_path_factory.mktemp(f"session_{request.param}")
    flags = CXXFLAGS + (SANITIZE if request.param == "sanitized" else [])
    if request.param == "fixed_rto":  # the board's fixed RTO (HelloWorldProfile), sanitized
        flags += [*SANITIZE, "-DHWBRIDGE_TEST_FIXED_RTO"]
    if request.param == "hello":  # HelloWorldProfile's shape: no fragmentation, one-slot sender
        flags += [*SANITIZE, "-DHWBRIDGE_TEST_HELLO"]

    def make(name: str) -> Path:
        exe = out / name
        if not exe.exists():
            command = ["g++", *flags, f"-I{INCLUDE}", str(TESTS / f"{name}.cpp"), "-o", str(exe)]
            result = subprocess.run(command, check=False, capture_output=True, text=True)
            assert result.returncode == 0, result.stderr
        return exe

    return make


def test_golden_transcript_and_session_rules(build: Builder) -> None:
    out = _run([str(build("test_session"))], _transcript())
    assert "golden transcript: 42 frames" in out
    assert "checks passed" in out


def test_a_wrong_transcript_byte_fails(build: Builder) -> None:
    """The replay can fail: one byte of the board's BOARD_INFO changed in the transcript."""
    good = "T board_info d 0250013f10020375"
    text = _transcript().replace(good, good[:-1] + "6")
    result = subprocess.run(
        [str(build("test_session"))], input=text, capture_output=True, text=True, check=False
    )
    assert result.returncode == 1
    assert "board_info: the board wrote" in result.stderr


def test_fuzz_session_bounded(build: Builder) -> None:
    out = _run([str(build("fuzz_session")), "11", str(FUZZ_SECONDS)], _transcript(), timeout=60)
    assert "fuzz_session: seed 11" in out
