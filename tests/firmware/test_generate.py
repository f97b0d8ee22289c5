"""``hwbridge firmware generate``: the C++ headers, compiled and run against the Python codecs.

Each test program is written here, compiled with the host g++ (C++11, warnings are errors,
AddressSanitizer and UBSan) and fed hex lines on stdin; heap buffers of the exact size make any
read or write past a bound an ASan report. The headers are compiled for the ATmega328P too when
avr-g++ is installed.
"""

from __future__ import annotations

import json
import random
import shutil
import struct
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from rosbags.interfaces import Nodetype

from hwbridge import msg
from hwbridge.cli import main
from hwbridge.errors import HwBridgeError
from hwbridge.firmware.gen_control import (
    BASE_NAME,
    BOARD_NAME,
    CONTROL_NAMES,
    HEADER_NAME,
    MSGS_NAME,
    PART_NAMES,
    generate_control_files,
    generate_control_header,
)
from hwbridge.firmware.gen_msgs import Capacities, MessageHeaders, parse_capacity
from hwbridge.protocols.errors import ProtocolError
from hwbridge.protocols.msgtypes import INT_RANGES, ros1_name
from hwbridge.protocols.native import control as ctl
from hwbridge.protocols.native import framing
from hwbridge.protocols.native._control import schema as sc
from tests.firmware.examples import VECTORS, control_vectors, examples, truncated_vectors

GXX = shutil.which("g++")
AVR_GXX = shutil.which("avr-g++")
needs_gxx = pytest.mark.skipif(GXX is None, reason="no host g++ (Debian package g++)")
CXXFLAGS = ["-std=c++11", "-Wall", "-Wextra", "-Werror", "-pedantic", "-g", "-O1"]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"]

MSG_TYPES = [
    "hwbridge_msgs/ImuRaw",
    "hwbridge_msgs/SonarEcho",
    "hwbridge_msgs/WheelTargets",
    "hwbridge_msgs/WheelTicks",
    "std_msgs/String",
    "std_msgs/Bool",
    "std_msgs/Float64",
    "sensor_msgs/JointState",
    "std_srvs/SetBool",  # a service: request and response
    "rosserial_msgs/Log",  # constants
    "geometry_msgs/PoseWithCovarianceStamped",  # fixed-size float64[36], nested messages
    "std_msgs/Duration",
    "std_msgs/Empty",
    "std_msgs/Int64",
    "std_msgs/UInt64",
    "std_msgs/Char",
    "std_msgs/Byte",
    "std_msgs/Int8MultiArray",
]
CAPACITIES = ["sensor_msgs/JointState.name=3", "sensor_msgs/JointState.name[]=6"]


def compile_and_run(
    tmp: Path, source: str, stdin: str, *, flags: tuple[str, ...] = (), name: str = "t"
) -> list[str]:
    """Build ``source`` with the headers in ``tmp`` and run it; its stdout lines."""
    assert GXX is not None
    cpp = tmp / f"{name}.cpp"
    cpp.write_text(source)
    exe = tmp / name
    built = subprocess.run(
        [GXX, *CXXFLAGS, *SANITIZE, *flags, f"-I{tmp}", str(cpp), "-o", str(exe)],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
    )
    assert built.returncode == 0, built.stderr[-4000:]
    ran = subprocess.run(
        [str(exe)], input=stdin, capture_output=True, text=True, timeout=60, check=False
    )
    assert ran.returncode == 0, ran.stderr[-4000:]
    return ran.stdout.splitlines()


HEX_IO = r"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <stdint.h>

static size_t unhex(const char* s, uint8_t* out) {
  size_t n = 0;
  for (; s[0] && s[1] && s[0] != '\n'; s += 2) {
    unsigned v;
    sscanf(s, "%2x", &v);
    out[n++] = static_cast<uint8_t>(v);
  }
  return n;
}
static void hex(const uint8_t* p, size_t n) {
  for (size_t i = 0; i < n; ++i) printf("%02x", p[i]);
  printf("\n");
}
/** A heap copy of exactly n bytes: reading past it is an ASan report. */
static uint8_t* exact(const uint8_t* p, size_t n) {
  uint8_t* copy = static_cast<uint8_t*>(malloc(n ? n : 1));
  if (n) memcpy(copy, p, n);
  return copy;
}
"""

# -- the control codec -----------------------------------------------------------------------

CONTROL_MAIN = r"""
#include "hwbridge_control.h"
using namespace hwbridge::control;

/** Decode; if that works, every too-small buffer must be refused, then re-encode. */
template <class M>
static void roundtrip(const uint8_t* in, size_t n) {
  M m;
  uint8_t* copy = exact(in, n);
  bool ok = decode(copy, n, &m);
  if (!ok) {
    printf("refused\n");
    free(copy);
    return;
  }
  size_t len = 0;
  uint8_t big[1024];
  if (!encode(m, big, sizeof big, &len)) {
    printf("encode failed\n");
    free(copy);
    return;
  }
  for (size_t cap = 0; cap < len; ++cap) {
    uint8_t* small = static_cast<uint8_t*>(malloc(cap ? cap : 1));
    size_t got = 12345;
    if (encode(m, small, cap, &got) || got != 12345) printf("cap %zu not refused\n", cap);
    free(small);
  }
  free(copy);
  hex(big, len);
}

static void header(const uint8_t* body, size_t n) {
  FrameHeader h;
  uint8_t* copy = exact(body, n);
  if (n < FRAME_HEADER_SIZE + FRAME_CRC_SIZE || !decode(copy, n, &h)) {
    printf("refused\n");
    free(copy);
    return;
  }
  uint16_t crc = crc16(copy, n - 2);
  uint8_t out[FRAME_HEADER_SIZE];
  size_t len = 0;
  if (crc != (copy[n - 2] | copy[n - 1] << 8) || !encode(h, out, sizeof out, &len)) {
    printf("bad crc or encode\n");
  } else {
    printf("%u %u %u %u ", h.type, h.frag, h.channel, h.seq);
    hex(out, len);
  }
  free(copy);
}

int main() {
  static char line[70000];
  static uint8_t data[35000];
  while (fgets(line, sizeof line, stdin)) {
    size_t n = unhex(line + 2, data);
    if (line[0] == 'H') {
      header(data, n);
      continue;
    }
    switch (n ? data[0] : 0) {
%CASES%
      default:
        printf("unknown\n");
    }
  }
  return 0;
}
"""


def control_program() -> str:
    cases = "\n".join(
        f"      case {m.class_name}::OPCODE: roundtrip<{m.class_name}>(data, n); break;"
        for m in sc.load_schema().messages
    )
    return HEX_IO + CONTROL_MAIN.replace("%CASES%", cases)


def python_roundtrip(payload: bytes) -> bytes | None:
    try:
        return ctl.decode_control(payload).encode()
    except ProtocolError:
        return None


def control_inputs() -> Iterator[tuple[str, bytes, bool]]:
    """(what, payload, exact): exact when a re-encoding must give the payload back."""
    schema = sc.load_schema()
    for name, payload in control_vectors():
        yield f"vector {name}", payload, True
    for name, payload in truncated_vectors():
        yield f"vector {name}", payload, True
    for spec in schema.messages:
        for i, attrs in enumerate(examples(schema, spec)):
            payload = sc.codec(spec.name).encode(attrs)
            yield f"{spec.name} example {i}", payload, True
            for cut in range(1, len(payload)):
                yield f"{spec.name} example {i} cut to {cut}", payload[:cut], False
    bad = {
        "HELLO version 2": bytes([1, 2]) + bytes(19),
        "HELLO role 2": bytes([1, 1, 2]) + bytes(18),
        "TOPIC kind 4": bytes([0x11, 1, 4, 0]) + bytes(16) + b"\x01a",
        "TOPIC name not UTF-8": bytes([0x11, 1, 0, 0]) + bytes(16) + b"\x01\xff",
        "BOARD_INFO version not UTF-8": b"\x10\x01\x00\x00\xc3",
        "LOG level 5": b"\x40\x05hi",
        "LOG text not UTF-8 (lenient)": b"\x40\x01\xff\xfe",
        "PARAM_GET type 5": b"\x30\x01\x00\x05\x00\x00\x00",
        "PARAM_VALUE type ANY": b"\x31\x01\x00\x00\x01a\x00",
        "PARAM_VALUE list short": b"\x31\x01\x00\x00\x01a\x82\x02\x00\x01\x00\x00\x00",
        "PARAM_VALUE string element short": b"\x31\x01\x00\x00\x01a\x04\x05\x00abc",
        "SERVICE_RESPONSE status 3": b"\x21\x01\x01\x00\x03",
        "TIME_RESPONSE nsec 1e9": b"\x04" + bytes(4) + struct.pack("<II", 1, 10**9) + bytes(8),
        "TOPIC_ACK status 3": b"\x13\x01\x03",
        "trailing bytes after READY": b"\x14\x02\x00\x00",
    }
    for name, payload in bad.items():
        yield name, payload, False


@needs_gxx
def test_the_control_header_against_the_python_codec(tmp_path: Path) -> None:
    for name, text in generate_control_files().items():
        (tmp_path / name).write_text(text)
    inputs = list(control_inputs())
    frames = json_frames()
    stdin = "".join(f"C {p.hex()}\n" for _, p, _ in inputs)
    stdin += "".join(f"H {body.hex()}\n" for _, body, _ in frames)
    out = compile_and_run(tmp_path, control_program(), stdin)
    assert len(out) == len(inputs) + len(frames)
    for (what, payload, exact), got in zip(inputs, out, strict=False):
        want = python_roundtrip(payload)
        if want is None:
            assert got == "refused", f"{what}: C++ accepts {payload.hex()}, Python refuses it"
        elif exact:
            assert got == want.hex() == payload.hex(), what
        else:  # lenient text cut mid-character: Python replaces it, C++ keeps the bytes
            assert got in (want.hex(), payload.hex()), f"{what}: {got} != {want.hex()}"
    for (name, body, frame), got in zip(frames, out[len(inputs) :], strict=False):
        if frame is None:
            assert got == "refused", name
        else:
            kind, frag, channel, seq, head = got.split()
            assert (int(kind), int(frag), int(channel), int(seq)) == (
                frame.type,
                frame.frag,
                frame.channel,
                frame.seq,
            ), name
            # The schema's header codec leaves flag bits 1-0 out (bit 1 reserved, bit 0 the
            # ACK_IN_DATA flag that the framing layer reads): it writes them as zero.
            assert head == bytes([body[0] & 0xFC]).hex() + body[1:3].hex(), name


def json_frames() -> list[tuple[str, bytes, framing.Frame | None]]:
    """(name, body, frame or None if a decoder must refuse it) of ``native_frames.json``."""
    data = json.loads((VECTORS / "native_frames.json").read_text())
    found: list[tuple[str, bytes, framing.Frame | None]] = []
    for v in data["vectors"] + data["decode_only"]:
        wire = bytes.fromhex(v["hex"]).strip(b"\x00")
        found.append((v["name"], framing.cobs_decode(wire), framing.decode_frame(wire)))
    for v in data["bad"]:
        if v["expect"] in ("version", "reserved_type"):
            body = framing.cobs_decode(bytes.fromhex(v["hex"]).rstrip(b"\x00"))
            found.append((v["name"], body, None))
    return found


# -- message headers -------------------------------------------------------------------------

FLOATS = [0.0, 1.5, -2.25, 1e10, 6.103515625e-05, -3.0517578125e-05, 2.0**-149]
"""float32-exact values, so that the float-as-double (AVR) build gives the same bytes."""


def syntax_check(tmp: Path, source: str, name: str) -> None:
    """Compile ``source`` with the headers in ``tmp`` (syntax and warnings only)."""
    assert GXX is not None
    cpp = tmp / f"{name}.cpp"
    cpp.write_text(source)
    built = subprocess.run(
        [GXX, *CXXFLAGS, "-fsyntax-only", f"-I{tmp}", str(cpp)],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
    )
    assert built.returncode == 0, f"{name}: {built.stderr[-4000:]}"


def test_the_control_header_is_split_in_parts() -> None:
    """hwbridge_control.h holds the identity macros and includes its parts in order: the base
    (enums, constants, the frame header), then the messages and the board's view, each of which
    includes the base only (no cycle). Each declaration is in one part."""
    files = generate_control_files()
    assert set(files) == {*CONTROL_NAMES, "hwbridge_wire.h"}
    assert PART_NAMES == (BASE_NAME, MSGS_NAME, BOARD_NAME)
    top = files[HEADER_NAME]
    assert top == generate_control_header()
    includes = [line for line in top.splitlines() if line.startswith("#include")]
    assert includes == [f'#include "{name}"' for name in PART_NAMES]
    for name in CONTROL_NAMES:
        guard = name.removesuffix(".h").upper() + "_H"
        assert f"#ifndef {guard}\n#define {guard}\n" in files[name], name
        assert files[name].endswith("#endif\n"), name
    base_includes = [line for line in files[BASE_NAME].splitlines() if line.startswith("#include")]
    assert base_includes[-1] == '#include "hwbridge_wire.h"'
    for name in (MSGS_NAME, BOARD_NAME):
        own = [line for line in files[name].splitlines() if line.startswith("#include")]
        assert own == [f'#include "{BASE_NAME}"'], name
    where = {
        "#define HWBRIDGE_SCHEMA_HASH": HEADER_NAME,
        "struct Opcode {": BASE_NAME,
        "struct FrameHeader {": BASE_NAME,
        "inline size_t param_value_size(": BASE_NAME,
        "struct HelloMsg {": MSGS_NAME,
        "inline bool decode(const uint8_t* buf, size_t len, LogMsg* m)": MSGS_NAME,
        "namespace board {": BOARD_NAME,
        "struct Hello {": BOARD_NAME,
    }
    for text, name in where.items():
        assert [n for n in CONTROL_NAMES if text in files[n]] == [name], text


@needs_gxx
def test_each_control_header_compiles_alone(tmp_path: Path) -> None:
    """Each control header compiles as the only include, the parts in any order and twice."""
    for name, text in generate_control_files().items():
        (tmp_path / name).write_text(text)
    for i, name in enumerate(CONTROL_NAMES):
        syntax_check(tmp_path, f'#include "{name}"\n', f"alone{i}")
    order = [*reversed(CONTROL_NAMES), *CONTROL_NAMES]
    uses = (
        "using namespace hwbridge::control;\n"
        "uint8_t f(uint8_t* p) {\n"
        "  LogMsg m;\n"
        "  size_t n = 0;\n"
        "  if (!encode(m, p, 8, &n)) return 0;\n"
        "  uint8_t* end = board::Log::put(p, LogLevel::INFO);\n"
        "  return static_cast<uint8_t>(end - p + n);\n"
        "}\n"
    )
    syntax_check(tmp_path, "".join(f'#include "{n}"\n' for n in order) + uses, "all")


@dataclass
class Sample:
    """Python values of one message and the C++ statements that set the same ones."""

    values: dict[str, Any] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)


def _scalar(base: str, rng: random.Random) -> tuple[Any, str]:
    if base == "bool":
        value = rng.random() < 0.5
        return value, "true" if value else "false"
    if base in ("float32", "float64"):
        value = rng.choice(FLOATS)
        return value, repr(value) + ("f" if base == "float32" else "")
    if base == "string":
        text = "".join(rng.choice("abc XYZ/_09") for _ in range(rng.randint(0, 5)))
        return text, f'"{text}"'
    low, high = INT_RANGES[base]
    value = rng.choice([low, high, rng.randint(low, high), 0])
    suffix = "ULL" if base == "uint64" else "LL" if base == "int64" else ""
    literal = f"{value}{suffix}"
    if value == low and low < 0:
        literal = f"({value + 1}{suffix} - 1)"
    return value, literal


def _assign(ref: str, base: str, literal: str) -> str:
    if base == "string":
        return f"{ref}.assign({literal});"
    return f"{ref} = {literal};"


def sample(
    reg: Any, type_name: str, rng: random.Random, ref: str, lengths: dict[str, int]
) -> Sample:
    """Random values for every field; ``lengths`` overrides the length of some arrays."""
    out = Sample()
    for name, (kind, arg) in reg.fields(type_name):
        cref = f"{ref}.{name}"
        if kind == Nodetype.BASE:
            value, literal = _scalar(arg[0], rng)
            out.values[name] = value
            out.lines.append(_assign(cref, arg[0], literal))
        elif kind == Nodetype.NAME:
            nested = _nested(reg, arg, rng, cref, lengths)
            out.values[name] = nested.values
            out.lines += nested.lines
        else:
            (sub_kind, sub_arg), size = arg
            n = size if kind == Nodetype.ARRAY else lengths.get(name, rng.randint(0, 3))
            if kind == Nodetype.SEQUENCE:
                out.lines.append(f"{cref}.size = {n};")
            items = []
            for i in range(n):
                if sub_kind == Nodetype.BASE:
                    value, literal = _scalar(sub_arg[0], rng)
                    out.lines.append(_assign(f"{cref}[{i}]", sub_arg[0], literal))
                    items.append(value)
                else:
                    nested = _nested(reg, sub_arg, rng, f"{cref}[{i}]", lengths)
                    out.lines += nested.lines
                    items.append(nested.values)
            out.values[name] = items
    return out


def _nested(
    reg: Any, store_name: str, rng: random.Random, ref: str, lengths: dict[str, int]
) -> Sample:
    if store_name.startswith("builtin_interfaces/"):
        signed = store_name.endswith("Duration")
        sec = rng.choice([-(2**31), 7, 2**31 - 1] if signed else [0, 7, 2**31 - 1])
        nsec = rng.choice([0, 999_999_999, 12345])
        sec_literal = f"({sec + 1} - 1)" if sec == -(2**31) else str(sec)
        return Sample(
            {"secs": sec, "nsecs": nsec}, [f"{ref}.sec = {sec_literal};", f"{ref}.nsec = {nsec};"]
        )
    return sample(reg, ros1_name(store_name), rng, ref, lengths)


def cpp_type(type_name: str) -> str:
    pkg, base = type_name.split("/")
    return f"{pkg}::{base}"


def message_types(reg: Any) -> list[str]:
    """The message types to test: MSG_TYPES, services as their request and response."""
    found = []
    for name in MSG_TYPES:
        if name in reg.service_names() and name not in reg.message_names():
            srv = reg.service(name)
            found += [srv.request.name, srv.response.name]
        else:
            found.append(name)
    return found


MSG_MAIN = r"""
template <class M>
static void check(const M& m, const char* name, const char* md5) {
  static uint8_t big[8192];
  size_t len = m.serialize(big, sizeof big);
  hex(big, len);
  for (size_t cap = 0; cap < len; ++cap) {  // too small: refused, never overrun
    uint8_t* small = static_cast<uint8_t*>(malloc(cap ? cap : 1));
    if (m.serialize(small, cap) != 0) printf("cap %zu not refused\n", cap);
    free(small);
  }
  M back;
  uint8_t* copy = exact(big, len);
  if (!back.deserialize(copy, len)) printf("deserialize failed\n");
  for (size_t cut = 0; cut < len; ++cut) {  // short input: refused, never overread
    M part;
    uint8_t* shorter = exact(big, cut);
    if (part.deserialize(shorter, cut)) printf("cut %zu not refused\n", cut);
    free(shorter);
  }
  static uint8_t again[8192];
  size_t len2 = back.serialize(again, sizeof again);
  if (len2 != len || memcmp(again, big, len)) printf("re-serialized differently\n");
  uint8_t* longer = exact(big, len + 1);
  longer[len] = 0;
  if (back.deserialize(longer, len + 1)) printf("trailing byte not refused\n");
  free(longer);
  free(copy);
  if (strcmp(M::type_name(), name) || strcmp(M::md5sum(), md5)) printf("bad names\n");
}

/** Deserialize stdin's hex as M and serialize it again; "refused" if it does not fit. */
template <class M>
static void echo(const char* line) {
  static uint8_t data[35000];
  size_t n = unhex(line, data);
  uint8_t* copy = exact(data, n);
  M m;
  if (!m.deserialize(copy, n)) {
    printf("refused\n");
  } else {
    static uint8_t out[8192];
    hex(out, m.serialize(out, sizeof out));
  }
  free(copy);
}

int main() {
  static char line[70000];
%BODY%
  return 0;
}
"""


def message_program(reg: Any, seed: int) -> tuple[str, list[str], list[tuple[str, bytes, bool]]]:
    """(C++ source, hex that each check prints first, (type, input bytes, fits) to echo)."""
    rng = random.Random(seed)
    includes = [f'#include "{name}.h"' for name in MSG_TYPES]
    body: list[str] = []
    expected: list[str] = []
    for name in message_types(reg):
        for _ in range(3):
            s = sample(reg, name, rng, "m", {})
            encoded = msg.encode(msg.from_dict(name, s.values, reg), name, reg)
            expected.append(encoded.hex())
            body.append("  {")
            body.append(f"    {cpp_type(name)} m;")
            body += ["    " + line for line in s.lines]
            md5 = reg.message(name).md5
            body.append(f'    check(m, "{name}", "{md5}");')
            body.append("  }")
    echoes: list[tuple[str, bytes, bool]] = []
    # Arrays and strings longer than their capacities (JointState: 3 names of 6 bytes).
    for names, fits in ((["a", "bb", "cccccc"], True), (["a", "b", "c", "d"], False)):
        value = {"name": names, "position": [1.5] * 8}
        echoes.append(
            ("sensor_msgs/JointState", encode(reg, "sensor_msgs/JointState", value), fits)
        )
    value = {"name": ["toolong"]}
    echoes.append(("sensor_msgs/JointState", encode(reg, "sensor_msgs/JointState", value), False))
    value = {"position": [0.0] * 9}
    echoes.append(("sensor_msgs/JointState", encode(reg, "sensor_msgs/JointState", value), False))
    echoes.append(("std_msgs/String", encode(reg, "std_msgs/String", {"data": "x" * 32}), True))
    echoes.append(("std_msgs/String", encode(reg, "std_msgs/String", {"data": "x" * 33}), False))
    echoes.append(("std_msgs/String", b"\xff\xff\xff\xff", False))  # length 4 GiB, 0 bytes
    for type_name, _, _ in echoes:
        body.append("  if (!fgets(line, sizeof line, stdin)) return 1;")
        body.append(f"  echo<{cpp_type(type_name)}>(line);")
    source = "\n".join(includes) + HEX_IO + MSG_MAIN.replace("%BODY%", "\n".join(body))
    return source, expected, echoes


def encode(reg: Any, name: str, values: dict[str, Any]) -> bytes:
    return msg.encode(msg.from_dict(name, values, reg), name, reg)


def write_headers(tmp: Path, reg: Any) -> None:
    limits = Capacities()
    for text in CAPACITIES:
        type_name, name, n = parse_capacity(text)
        limits.fields[(type_name, name)] = n
    for rel, text in MessageHeaders(reg, limits).headers(MSG_TYPES).items():
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp / rel).write_text(text)


@needs_gxx
@pytest.mark.parametrize("soft_float64", [False, True], ids=["double", "float64-as-float"])
def test_message_headers_serialize_as_hwbridge_msg(tmp_path: Path, soft_float64: bool) -> None:
    reg = msg.registry()
    write_headers(tmp_path, reg)
    source, expected, echoes = message_program(reg, seed=14)
    flags = ("-DHWBRIDGE_FLOAT64_AS_FLOAT",) if soft_float64 else ()
    stdin = "".join(data.hex() + "\n" for _, data, _ in echoes)
    out = compile_and_run(tmp_path, source, stdin, flags=flags)
    assert len(out) == len(expected) + len(echoes), out[-5:]
    assert out[: len(expected)] == expected
    for (name, data, fits), got in zip(echoes, out[len(expected) :], strict=True):
        assert got == (data.hex() if fits else "refused"), name


F64_CHECK = r"""
#include "hwbridge_msg.h"
#include <stdio.h>
#include <inttypes.h>
using namespace hwbridge::msg::detail;
int main() {
  uint64_t d;
  uint32_t f;
  while (scanf("%" SCNx64 " %" SCNx32, &d, &f) == 2) {
    printf("%08" PRIx32 " %016" PRIx64 "\n", f64_to_f32(d), f32_to_f64(f));
  }
  return 0;
}
"""


@needs_gxx
def test_float64_conversions_for_4_byte_double(tmp_path: Path) -> None:
    """binary64 <-> binary32 by hand (AVR): as the host's own conversion, subnormals, infinities,
    NaN and ties to even included."""
    for name, text in MessageHeaders(msg.registry()).headers([]).items():
        (tmp_path / name).write_text(text)
    rng = random.Random(3)
    doubles = [0.0, -0.0, 1.0, 1.5, -2.25, 1e-40, 1e-45, 7e-46, 3.4028235e38, 3.5e38, 1e300, 1e-300]
    doubles += [float("inf"), -float("inf"), 1 + 2**-24, 1 + 3 * 2**-24, 1 + 2**-24 + 2**-50]
    doubles += [struct.unpack("<d", rng.randbytes(8))[0] for _ in range(300)]
    doubles += [rng.uniform(-1e6, 1e6) for _ in range(300)]
    floats = [struct.unpack("<I", struct.pack("<f", x))[0] for x in (1.0, 1e-40, 1e-45, -3.0)]
    floats += [0x7F800000, 0xFF800000, 0x7FC00000, 0x00000001, 0x007FFFFF, 0x80000000]
    floats += [rng.getrandbits(32) for _ in range(300)]
    pairs = list(zip(doubles, floats * 3, strict=False))
    stdin = "".join(f"{struct.unpack('<Q', struct.pack('<d', d))[0]:x} {f:x}\n" for d, f in pairs)
    out = compile_and_run(tmp_path, F64_CHECK, stdin, name="f64")
    assert len(out) == len(pairs)
    for (d, f), line in zip(pairs, out, strict=True):
        to_f32, to_f64 = line.split()
        if d != d:  # NaN stays a NaN (its payload need not)
            assert (int(to_f32, 16) & 0x7FC00000) == 0x7FC00000
        else:
            try:
                want = struct.unpack("<I", struct.pack("<f", d))[0]
            except OverflowError:  # above the float range: Python refuses, C++ gives infinity
                want = 0x7F800000 | (0x80000000 if d < 0 else 0)
            assert int(to_f32, 16) == want, (d, to_f32)
        single = struct.unpack("<f", struct.pack("<I", f))[0]
        if single == single:
            assert int(to_f64, 16) == struct.unpack("<Q", struct.pack("<d", single))[0], hex(f)


@pytest.mark.skipif(AVR_GXX is None, reason="no avr-g++ (Debian package gcc-avr)")
def test_the_headers_compile_for_the_atmega328p(tmp_path: Path) -> None:
    assert AVR_GXX is not None
    reg = msg.registry()
    write_headers(tmp_path, reg)
    for name, text in generate_control_files().items():
        (tmp_path / name).write_text(text)
    includes = "".join(f'#include "{name}.h"\n' for name in MSG_TYPES)
    source = f'#include "{HEADER_NAME}"\n{includes}' + (
        "#include <avr/pgmspace.h>\n"
        "uint8_t buf[64];\n"
        "size_t f() {\n"
        "  std_msgs::String s;\n"
        '  s.data.assign("hi");\n'
        "  hwbridge::control::LogMsg log;\n"
        "  size_t n = 0;\n"
        "  if (!hwbridge::control::encode(log, buf, sizeof buf, &n)) return 0;\n"
        "  sensor_msgs::JointState j;\n"
        "  j.position.push_back(1.5);\n"
        "  return s.serialize(buf, sizeof buf) + j.serialize(buf, sizeof buf) + n +\n"
        "         pgm_read_byte(std_msgs::String::md5sum());\n"
        "}\n"
    )
    (tmp_path / "avr.cpp").write_text(source)
    built = subprocess.run(
        [
            AVR_GXX,
            "-mmcu=atmega328p",
            "-std=gnu++11",
            "-Os",
            "-Wall",
            "-Wextra",
            "-Werror",
            f"-I{tmp_path}",
            "-c",
            str(tmp_path / "avr.cpp"),
            "-o",
            str(tmp_path / "avr.o"),
        ],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
    )
    assert built.returncode == 0, built.stderr[-4000:]
    symbols = subprocess.run(
        ["avr-objdump", "-t", str(tmp_path / "avr.o")], capture_output=True, text=True, check=True
    ).stdout
    md5_symbols = [
        line for line in symbols.splitlines() if "StringNames_" in line and "md5" in line
    ]
    assert md5_symbols and all(".progmem" in line for line in md5_symbols), md5_symbols


# -- the command -----------------------------------------------------------------------------


def test_headers_and_generate_with_a_folder_write_the_same(tmp_path: Path) -> None:
    """``firmware headers DIR`` is the header generator; ``firmware generate DIR`` (not a robot
    file) still is, for existing callers."""
    assert main(["firmware", "headers", str(tmp_path / "h"), "std_msgs/String"]) == 0
    assert main(["firmware", "generate", str(tmp_path / "g"), "std_msgs/String"]) == 0
    headers = {p.relative_to(tmp_path / "h"): p.read_text() for p in (tmp_path / "h").rglob("*.h")}
    generated = {
        p.relative_to(tmp_path / "g"): p.read_text() for p in (tmp_path / "g").rglob("*.h")
    }
    assert headers == generated and Path("std_msgs/String.h") in headers


def test_the_command_writes_the_headers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["firmware", "generate", str(tmp_path / "a")]) == 0
    written = sorted(
        p.relative_to(tmp_path / "a").as_posix() for p in (tmp_path / "a").rglob("*.h")
    )
    assert written == [
        "hwbridge_control.h",
        "hwbridge_control_base.h",
        "hwbridge_control_board.h",
        "hwbridge_control_msgs.h",
        "hwbridge_msg.h",
        "hwbridge_msgdefs.h",
        "hwbridge_msgs/Bme280.h",
        "hwbridge_msgs/ImuRaw.h",
        "hwbridge_msgs/SonarEcho.h",
        "hwbridge_msgs/WheelTargets.h",
        "hwbridge_msgs/WheelTicks.h",
        "hwbridge_wire.h",
        "sensor_msgs/JointState.h",
        "std_msgs/Bool.h",
        "std_msgs/Float64.h",
        "std_msgs/Header.h",
        "std_msgs/String.h",
    ]
    assert "17 headers written" in capsys.readouterr().out
    assert (tmp_path / "a" / HEADER_NAME).read_text() == generate_control_header()
    for name, text in generate_control_files().items():
        assert (tmp_path / "a" / name).read_text() == text, name
    pkg = tmp_path / "msgs" / "my_pkg" / "msg"
    pkg.mkdir(parents=True)
    (pkg / "Thing.msg").write_text("string label\nint32[] values\n")
    args = ["firmware", "generate", str(tmp_path / "b"), "--msg-path", str(tmp_path / "msgs")]
    assert main([*args, "--capacity", "my_pkg/Thing.values=3", "my_pkg/Thing"]) == 0
    text = (tmp_path / "b" / "my_pkg" / "Thing.h").read_text()
    assert "hwbridge::msg::Array<int32_t, 3> values;" in text
    assert "hwbridge::msg::String<32> label;" in text


def test_bad_capacities_and_types_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(HwBridgeError, match=r"expected pkg/Type\.field=N"):
        parse_capacity("std_msgs/String=3")
    with pytest.raises(HwBridgeError, match="N from 1 to 65535"):
        parse_capacity("std_msgs/String.data=0")
    limits = Capacities(fields={("std_msgs/String", "nope"): 3})
    with pytest.raises(HwBridgeError, match=r"std_msgs/String\.nope: not a variable-length"):
        MessageHeaders(msg.registry(), limits).headers(["std_msgs/String"])
    assert main(["firmware", "generate", str(tmp_path), "std_msgs/Strin"]) == 1
    assert not any(tmp_path.iterdir())  # nothing written
    assert "unknown message type 'std_msgs/Strin'" in capsys.readouterr().err
