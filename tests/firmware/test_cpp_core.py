"""The C++ library's framing and stream layers (``firmware/HwBridge``), built and run host-native.

Every program is built into pytest's temporary directory with ``g++ -std=c++11 -Wall -Wextra
-Werror -O1``, once plain and once under ASan and UBSan (``-fsanitize=address,undefined
-fno-sanitize-recover=all -O0``; the warnings that need the optimizer are the plain build's):
``test_vectors`` (every vector of ``protocols/vectors/native_frames.json``, fed on stdin, plus
unit checks and a pty/TCP loopback of the POSIX ``Hardware``), ``test_streams`` (the reliable
stream over a seeded lossy, duplicating, reordering link) and ``fuzz_decoder`` (a seeded,
time-bounded fuzz run; also as a libFuzzer target when clang++ with its fuzzer runtime is
installed). The headers are also compiled one by one, and for the ATmega328P with ``avr-g++``
when it is on PATH.
"""

from __future__ import annotations

import importlib.util
import json
import re
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LIBRARY = ROOT / "firmware" / "HwBridge"
INCLUDE = LIBRARY / "src"
TESTS = ROOT / "firmware" / "tests"
HEADERS = sorted(p.relative_to(INCLUDE).as_posix() for p in INCLUDE.rglob("*.h"))
HOST_SHIM = {h for h in HEADERS if h.startswith("hwbridge/host/")}
"""The Arduino stand-in of host builds (--board host), built by test_session_e2e.py."""
HOST_ONLY = {"hwbridge/hardware_posix.h"} | HOST_SHIM
ARDUINO_ONLY = {"hwbridge/hardware_arduino.h", "hwbridge/hardware_udp.h", "hwbridge/arduino_seed.h"}
"""Needs the Arduino core: built by the sketch builds (tests/firmware/test_session_build.py;
hardware_udp.h by the host build of examples/UdpNode, tests/firmware/test_udp_board.py)."""
ARM_ONLY = {"hwbridge/hardware_stm32f4.h", "hwbridge/hardware_nrf51.h"}
"""32-bit register maps: built for their boards by the ARM sketch builds (tests/arm/)."""
NODE_PARTS = {h for h in HEADERS if h.startswith("hwbridge/node/")}
"""Parts of node_impl.h, included by it only (each says so when included alone)."""

CXXFLAGS = ["-std=c++11", "-Wall", "-Wextra", "-Werror", "-O1"]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-O0"]
"""Sanitized builds at -O0 (the last -O wins): they compile in half the CPU time of -O1 (4 s
against 8 s for test_session.cpp; these builds were the suite's largest CPU cost after the
firmware examples), and every program they run is bounded in time or small. The plain build at
-O1 keeps the warnings that only the optimizer finds (-Wmaybe-uninitialized)."""
AVRFLAGS = [
    "-mmcu=atmega328p",
    "-std=gnu++11",
    "-Os",
    "-Wall",
    "-Wextra",
    "-Werror",
    "-fno-exceptions",
    "-fno-rtti",
]
FUZZ_SECONDS = 3

needs_gxx = pytest.mark.skipif(
    shutil.which("g++") is None, reason="g++ is not installed (Debian package g++)"
)
needs_avr = pytest.mark.skipif(
    shutil.which("avr-g++") is None,
    reason="avr-g++ is not installed (Debian packages gcc-avr avr-libc binutils-avr)",
)

Builder = Callable[[str], Path]


def _vector_lines() -> str:
    spec = importlib.util.spec_from_file_location("firmware_vectors", TESTS / "vectors.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    lines: list[str] = module.lines(ROOT)
    return "".join(line + "\n" for line in lines)


def _compile(command: list[str]) -> None:
    result = subprocess.run(command, check=False, capture_output=True, text=True, timeout=300)
    if result.returncode != 0:
        pytest.fail(f"{' '.join(command)} failed:\n{result.stderr}", pytrace=False)


def _run(command: list[str], stdin: str = "", timeout: float = 120) -> str:
    result = subprocess.run(
        command, check=False, input=stdin, capture_output=True, text=True, timeout=timeout
    )
    if result.returncode != 0:
        pytest.fail(
            f"{' '.join(command)} exited with {result.returncode}:\n{result.stderr}{result.stdout}",
            pytrace=False,
        )
    assert "runtime error" not in result.stderr, result.stderr  # UBSan, in case it recovered
    return result.stdout


@pytest.fixture(scope="module", params=["plain", "sanitized"])
def build(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Builder:
    """Builds ``firmware/tests/NAME.cpp`` once per variant into a temporary directory."""
    if shutil.which("g++") is None:
        pytest.skip("g++ is not installed (Debian package g++)")
    out = tmp_path_factory.mktemp(f"cpp_{request.param}")
    flags = CXXFLAGS + (SANITIZE if request.param == "sanitized" else [])
    built: dict[str, Path] = {}

    def make(name: str) -> Path:
        if name not in built:
            exe = out / name
            _compile(["g++", *flags, f"-I{INCLUDE}", str(TESTS / f"{name}.cpp"), "-o", str(exe)])
            built[name] = exe
        return built[name]

    return make


def test_every_golden_vector(build: Builder) -> None:
    out = _run([str(build("test_vectors"))], stdin=_vector_lines())
    match = re.search(r"ok: (\d+) vectors", out)
    assert match, out
    assert int(match.group(1)) == len(_vector_lines().splitlines())


def test_a_wrong_vector_fails_with_its_name(build: Builder, tmp_path: Path) -> None:
    lines = _vector_lines().splitlines()
    first = lines[0].split(" ")
    first[2] = first[2][:-4] + ("ff" if first[2][-4:-2] != "ff" else "fe") + "00"
    result = subprocess.run(
        [str(build("test_vectors")), "--no-posix"],
        check=False,
        input=" ".join(first) + "\n",
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 1
    assert f"FAIL: {first[1]}: encoded" in result.stderr


def test_reliable_stream_over_a_lossy_link(build: Builder) -> None:
    out = _run([str(build("test_streams")), "1"])
    assert "ok:" in out
    assert "retransmits 0 " not in out.split("window 1:")[1].splitlines()[0]


def test_fuzz_decoder_bounded(build: Builder) -> None:
    out = _run([str(build("fuzz_decoder")), "1", str(FUZZ_SECONDS)], timeout=FUZZ_SECONDS + 60)
    match = re.search(r"ok: seed 1, (\d+) inputs", out)
    assert match and int(match.group(1)) > 1000, out


def _clang() -> str | None:
    return next((c for c in ("clang++", "clang++-14") if shutil.which(c)), None)


def test_libfuzzer_bounded(tmp_path: Path) -> None:
    """The same fuzz target under libFuzzer, from a corpus of the golden vectors' wire bytes."""
    clang = _clang()
    if clang is None:
        pytest.skip("clang++ is not installed (Debian packages clang-14 libclang-rt-14-dev)")
    exe = tmp_path / "fuzz_libfuzzer"
    flags = [*CXXFLAGS, "-DHWBRIDGE_LIBFUZZER", "-fsanitize=fuzzer,address,undefined"]
    source = TESTS / "fuzz_decoder.cpp"
    probe = subprocess.run(
        [clang, *flags, "-fno-sanitize-recover=all", f"-I{INCLUDE}", str(source), "-o", str(exe)],
        check=False,
        capture_output=True,
        text=True,
        timeout=300,
    )
    if probe.returncode != 0 and "fuzzer" in probe.stderr and "cannot find" in probe.stderr:
        pytest.skip(f"{clang} has no libFuzzer runtime (Debian package libclang-rt-14-dev)")
    assert probe.returncode == 0, probe.stderr
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    frames = json.loads((ROOT / "protocols/vectors/native_frames.json").read_text())
    runs = [v["hex"] for key in ("vectors", "decode_only", "bad") for v in frames[key]]
    runs += ["".join(v["frames_hex"]) for v in frames["fragmentation"]]
    for index, wire in enumerate(runs):
        (corpus / f"v{index}").write_bytes(bytes.fromhex(wire))
    result = subprocess.run(
        [str(exe), f"-max_total_time={FUZZ_SECONDS}", "-seed=1", str(corpus)],
        check=False,
        capture_output=True,
        text=True,
        timeout=FUZZ_SECONDS + 120,
        cwd=tmp_path,  # crash files, if any, land here
    )
    assert result.returncode == 0, result.stderr[-4000:]
    assert re.search(r"Done \d+ runs", result.stderr), result.stderr[-2000:]


@needs_gxx
@pytest.mark.parametrize(
    "header", [h for h in HEADERS if h not in ARDUINO_ONLY | HOST_SHIM | NODE_PARTS]
)
def test_each_header_compiles_alone(header: str, tmp_path: Path) -> None:
    source = tmp_path / "one.cpp"
    source.write_text(f'#include "{header}"\n#include "{header}"\nint main() {{ return 0; }}\n')
    # -Wshadow for the library's own headers; the generated message headers (gen_msgs.py) name
    # their writer `w`, which a field `w` (geometry_msgs/Quaternion) shadows.
    shadow = ["-Wshadow"] if header.startswith("hwbridge/") else []
    _compile(["g++", *CXXFLAGS, *shadow, "-fsyntax-only", f"-I{INCLUDE}", str(source)])


@needs_avr
@pytest.mark.parametrize(
    "header", [h for h in HEADERS if h not in HOST_ONLY | ARDUINO_ONLY | ARM_ONLY | NODE_PARTS]
)
def test_each_header_compiles_for_avr(header: str, tmp_path: Path) -> None:
    source = tmp_path / "one.cpp"
    source.write_text(f'#include "{header}"\nint main() {{ return 0; }}\n')
    _compile(["avr-g++", *AVRFLAGS, "-fsyntax-only", f"-I{INCLUDE}", str(source)])


def _syntax_check(source: Path) -> subprocess.CompletedProcess[str]:
    """g++ -fsyntax-only on source with the library and the test harness on the include path;
    the result, whether it compiles or not."""
    return subprocess.run(
        ["g++", *CXXFLAGS, "-fsyntax-only", f"-I{INCLUDE}", f"-I{TESTS}", str(source)],
        check=False,
        capture_output=True,
        text=True,
    )


@needs_gxx
@pytest.mark.parametrize("header", sorted(NODE_PARTS))
def test_node_parts_refuse_to_be_included_alone(header: str, tmp_path: Path) -> None:
    source = tmp_path / "one.cpp"
    source.write_text(f'#include "{header}"\nint main() {{ return 0; }}\n')
    result = _syntax_check(source)
    assert result.returncode != 0 and "include HwBridge.h" in result.stderr, result.stderr


@needs_gxx
def test_a_hardware_trait_declared_false_is_off(tmp_path: Path) -> None:
    """A Hardware that declares kSharesCpu, kDatagram or kNoAckInData as false gets what one that
    leaves the member out gets: the feature off (only true turns it on)."""
    source = tmp_path / "traits.cpp"
    checks = []
    for trait, member in (
        ("SharesCpu", "kSharesCpu"),
        ("IsDatagramSink", "kDatagram"),
        ("NoAckInData", "kNoAckInData"),
    ):
        checks.append(
            f"struct Yes{member} {{ static const bool {member} = true; }};\n"
            f"struct No{member} {{ static const bool {member} = false; }};\n"
            f'static_assert(hwbridge::detail::{trait}<Yes{member}>::value, "{trait} true");\n'
            f'static_assert(!hwbridge::detail::{trait}<No{member}>::value, "{trait} false");\n'
            f'static_assert(!hwbridge::detail::{trait}<Empty>::value, "{trait} absent");\n'
        )
    source.write_text(
        '#include "hwbridge/encoder.h"\nstruct Empty {};\n'
        + "".join(checks)
        + "int main() { return 0; }\n"
    )
    result = _syntax_check(source)
    assert result.returncode == 0, result.stderr


@needs_gxx
@pytest.mark.parametrize("timeout_ms", [30000, 40000])
def test_profile_timeouts_above_30_s_do_not_compile(timeout_ms: int, tmp_path: Path) -> None:
    """The session's 16-bit ticks compare within 32.7 s: a profile asking more is an error."""
    source = tmp_path / "profile.cpp"
    source.write_text(
        '#include "session_harness.h"\n'
        "struct P : harness::GoldenProfile {\n"
        f"  static const uint16_t kParamTimeoutMs = {timeout_ms};\n"
        "};\n"
        "hwbridge::NodeHandle_<harness::FakeHardware, P> node;\n"
        "int main() { return node.connected(); }\n"
    )
    result = _syntax_check(source)
    if timeout_ms <= 30000:
        assert result.returncode == 0, result.stderr
    else:
        assert result.returncode != 0 and "kParamTimeoutMs: at most 30000 ms" in result.stderr


@needs_avr
@pytest.mark.parametrize("profile", ["hello", "comfortable"])
def test_avr_build_uses_no_heap(profile: str, tmp_path: Path) -> None:
    """Every template instantiated for the ATmega328P; no malloc/new in the image; RAM as set."""
    elf = tmp_path / "avr_core.elf"
    define = ["-DPROFILE_COMFORTABLE"] if profile == "comfortable" else []
    source = TESTS / "avr_core.cpp"
    _compile(["avr-g++", *AVRFLAGS, "-flto", *define, f"-I{INCLUDE}", str(source), "-o", str(elf)])
    symbols = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True)
    assert not re.search(r"\b(malloc|free|_Znw\w*|_Zdl\w*|realloc)\b", symbols.stdout)
    size = subprocess.run(["avr-size", str(elf)], capture_output=True, text=True, check=True)
    text, data, bss = (int(v) for v in size.stdout.splitlines()[1].split()[:3])
    # Receive run buffer 70 + retransmission slots (window x (MTU + 9)) + reassembly buffer +
    # state: within PROTOCOL.md 2.13's protocol budget (307 B hello world, 570 B comfortable)
    # plus the 20-30 bytes of counters and state this layer keeps beyond it.
    assert data + bss <= (340 if profile == "hello" else 620), size.stdout
    assert text < 8192, size.stdout


needs_simavr = pytest.mark.skipif(
    shutil.which("simavr") is None, reason="simavr is not installed (Debian)"
)


def _run_on_avr(source: str, tmp_path: Path, defines: list[str]) -> str:
    """Builds ``firmware/tests/<source>`` for the ATmega328P and runs it in simavr; returns what
    it printed on UART 0 (with simavr's own lines)."""
    elf = tmp_path / Path(source).with_suffix(".elf").name
    flags = [*AVRFLAGS, "-flto", *defines, f"-I{INCLUDE}"]
    _compile(["avr-g++", *flags, str(TESTS / source), "-o", str(elf)])
    run = subprocess.run(
        ["simavr", "-m", "atmega328p", "-f", "16000000", str(elf)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    return run.stdout + run.stderr


@needs_avr
@needs_simavr
@pytest.mark.parametrize("variant", ["default", "small"])
def test_crc_on_the_avr(variant: str, tmp_path: Path) -> None:
    """crc16 as the ATmega328P runs it (simavr): the library's 18-instruction step by default,
    the bit loop of HWBRIDGE_SMALL_CRC, each against avr-libc's _crc_xmodem_update on random runs
    and on the check value."""
    define = ["-DHWBRIDGE_SMALL_CRC"] if variant == "small" else []
    output = _run_on_avr("avr_crc.cpp", tmp_path, define)
    assert "CRC OK" in output and "CRC BAD" not in output, output


@needs_avr
@needs_simavr
def test_frame_encoder_on_the_avr(tmp_path: Path) -> None:
    """write_frame as the ATmega328P runs it (simavr): its fused CRC and COBS pass in assembly
    against the frame's definition (crc16 and the look-ahead COBS), on 400 random frames, some
    of them ending with a full 254-byte group."""
    output = _run_on_avr("avr_encode.cpp", tmp_path, ["-DHWBRIDGE_ACK_IN_DATA=1"])
    found = re.search(r"ENCODE OK (\d+)", output)
    assert found is not None and "ENCODE BAD" not in output, output
    assert int(found.group(1)) > 0, f"no frame ended with a full group: {output}"


def test_library_sources_allocate_nothing() -> None:
    """No heap, no exceptions, no RTTI, no STL in the library (the tests may use them)."""
    forbidden = re.compile(
        r"\bnew\b|\bdelete\b|\bmalloc\b|\bcalloc\b|\brealloc\b|\bfree\s*\(|\bthrow\b|\btry\b"
        r"|\bcatch\b|dynamic_cast|typeid|std::|#include\s*<(?!(stddef|stdint|string|stdlib"
        r"|stdio|errno|fcntl|netdb|termios|time|unistd|util/crc16|avr/pgmspace|Arduino)\.h>"
        r"|(netinet|sys)/)"
    )
    for path in sorted(INCLUDE.rglob("*.h")):
        if path.relative_to(INCLUDE).as_posix() in HOST_SHIM:
            continue  # the host build's Arduino stand-in: a native program's code
        code = re.sub(r"//[^\n]*|/\*.*?\*/", "", path.read_text(), flags=re.S)
        hits = [m.group(0) for m in forbidden.finditer(code)]
        assert not hits, f"{path.relative_to(ROOT)}: {hits}"


def test_library_properties() -> None:
    fields = dict(
        line.split("=", 1)
        for line in (LIBRARY / "library.properties").read_text().splitlines()
        if "=" in line
    )
    assert fields["name"] == "HwBridge"
    assert fields["category"] == "Communication"
    assert fields["architectures"] == "*"
    for key in ("version", "author", "sentence", "paragraph", "url"):
        assert fields.get(key), key
    assert re.fullmatch(r"\d+\.\d+\.\d+", fields["version"])
