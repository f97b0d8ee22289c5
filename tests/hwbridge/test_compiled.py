"""Compiled modules (``hwbridge/compiled``): built with the real Cython and C compiler, used only
for the source they were built from, off with ``HWBRIDGE_COMPILED=0``, and the build's errors.
When the suite itself runs with them (``tools/test`` builds them first), the plain-Python path is
run too, on the protocol tests that pin its behaviour down."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hwbridge.compiled import ENV, MODULES, active, available, cache_root, compiled_path

ROOT = Path(__file__).resolve().parents[2]
COBS = "hwbridge.protocols.native.cobs"

_PROBE = """
import importlib, json, sys
from hwbridge.protocols.native import cobs
from hwbridge.compiled import active
data = bytes(range(256)) * 3 + b"\\0\\0x"
wire = cobs.encode(data)
assert cobs.decode(wire) == data
print(json.dumps({"compiled": active(), "file": cobs.__file__, "wire": wire.hex()}))
"""


def _probe(cache: Path, **env: str) -> dict[str, object]:
    """Import the COBS module in a new interpreter with ``cache`` as XDG_CACHE_HOME."""
    done = subprocess.run(
        [sys.executable, "-c", _PROBE],
        env={**os.environ, "XDG_CACHE_HOME": str(cache), **env},
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    result: dict[str, object] = json.loads(done.stdout.splitlines()[-1])
    return result


def _compiled_cli(cache: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hwbridge.compiled", *args],
        env={**os.environ, "XDG_CACHE_HOME": str(cache)},
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )


def test_a_compiled_module_is_used_for_its_own_source_only(tmp_path: Path) -> None:
    """``build`` compiles the module with the real tools and says so; a new interpreter then
    loads the compiled copy, which gives the bytes the source gives. Not with
    ``HWBRIDGE_COMPILED=0``, and not once the copy is filed under another source's digest (as
    after an edit of the module): then the source runs."""
    pytest.importorskip("Cython")
    pure = _probe(tmp_path)
    assert pure["compiled"] == [] and str(pure["file"]).endswith("cobs.py")

    built = _compiled_cli(tmp_path, "build", COBS)
    assert built.returncode == 0, built.stderr
    assert "compiling 1 of 1 modules" in built.stderr and f"[1/1] {COBS}" in built.stderr
    fast = _probe(tmp_path)
    assert fast["compiled"] == [COBS] and not str(fast["file"]).endswith(".py")
    assert fast["wire"] == pure["wire"]

    status = _compiled_cli(tmp_path, "status")
    assert f"compiled  {COBS}" in status.stdout and "source    hwbridge.pump" in status.stdout
    again = _compiled_cli(tmp_path, "build", COBS)
    assert again.returncode == 0 and "all 1 up to date" in again.stderr

    assert _probe(tmp_path, HWBRIDGE_COMPILED="0")["compiled"] == []

    copy = Path(str(fast["file"]))
    copy.parent.rename(copy.parent.with_name("0" * 24))  # the digest of some other source
    assert _probe(tmp_path)["compiled"] == []


def test_build_errors_say_what_is_missing(tmp_path: Path) -> None:
    """An unknown module, and a machine without Cython: status 1 and the reason, nothing made."""
    unknown = _compiled_cli(tmp_path, "build", "hwbridge.nope")
    assert unknown.returncode == 1
    assert "error: not a module that is compiled: hwbridge.nope" in unknown.stderr
    no_cython = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; sys.modules['Cython'] = None\n"
            "from hwbridge.compiled.__main__ import main\n"
            f"sys.exit(main(['build', '{COBS}']))",
        ],
        env={**os.environ, "XDG_CACHE_HOME": str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert no_cython.returncode == 1
    assert "error: Cython is not installed (pip install 'hwbridge[fast]'" in no_cython.stderr
    assert not (tmp_path / "hwbridge").exists()


def test_compiled_paths_follow_the_source() -> None:
    """The file a compiled copy has depends on the source's bytes and on nothing else given."""
    a = compiled_path(COBS, b"x = 1\n", Path("/r"))
    assert a == compiled_path(COBS, b"x = 1\n", Path("/r"))
    assert a != compiled_path(COBS, b"x = 2\n", Path("/r"))
    assert a.parent.parent == Path("/r") and a.name.startswith("cobs.")


@pytest.mark.skipif(
    os.environ.get("HWBRIDGE_EXPECT_COMPILED") != "1",
    reason="tools/test sets HWBRIDGE_EXPECT_COMPILED=1 when it built the compiled modules",
)
def test_the_suite_runs_the_modules_it_built() -> None:
    """Where ``tools/test`` built them, this suite's processes load every compiled module (a
    build that the finder then never used would leave the suite, and the benches, on the plain
    path without a word)."""
    for name in MODULES:
        __import__(name)
    missing = sorted(set(MODULES) - set(active()))
    assert not missing, f"built but not loaded: {missing} (cache {cache_root()})"


@pytest.mark.skipif(
    os.environ.get(ENV) == "0" or not available(),
    reason="this run has no compiled module: it is the plain path",
)
def test_the_plain_path_passes_the_protocol_tests_too() -> None:
    """This run's processes use compiled modules: the protocol tests that pin framing and
    sessions down (golden vectors, fast paths, session rules) run again without them."""
    files = [
        "tests/protocols/test_native_fastpaths.py",
        "tests/protocols/test_native_framing.py",
        "tests/protocols/test_native_session.py",
        "tests/protocols/test_rosserial_vectors.py",
        "tests/protocols/test_rosserial_host.py",
    ]
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist", *files],
        cwd=ROOT,
        env={**os.environ, "HWBRIDGE_COMPILED": "0"},
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert " passed" in done.stdout
