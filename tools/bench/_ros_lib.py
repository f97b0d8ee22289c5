"""rosserial's ros_lib for the simavr benches: its client and Arduino files from rosserial's
sources (``ROSSERIAL_GIT``), message headers generated from hwbridge's definitions, and sketches
built against them the way ``hwbridge firmware build`` builds (see ``sim.py``)."""

from __future__ import annotations

import hashlib
import os
import subprocess
from pathlib import Path
from typing import Any

from hwbridge import msg
from hwbridge.firmware import build

ROSSERIAL_GIT = Path(os.environ.get("ROSSERIAL_GIT", "/work/.mirror/ros-drivers+rosserial/repo"))


def git_file(path: str) -> bytes:
    return subprocess.run(
        ["git", "--git-dir", str(ROSSERIAL_GIT), "show", f"HEAD:{path}"],
        capture_output=True,
        check=True,
    ).stdout


def git_ls(prefix: str) -> list[str]:
    done = subprocess.run(
        ["git", "--git-dir", str(ROSSERIAL_GIT), "ls-tree", "-r", "--name-only", "HEAD", prefix],
        capture_output=True,
        text=True,
        check=True,
    )
    return done.stdout.split()


_CTYPES = {
    "bool": ("bool", 1),
    "uint8": ("uint8_t", 1),
    "int8": ("int8_t", 1),
    "uint16": ("uint16_t", 2),
    "int16": ("int16_t", 2),
    "uint32": ("uint32_t", 4),
    "int32": ("int32_t", 4),
    "float32": ("float", 4),
}


def _put(expr: str, size: int) -> list[str]:
    lines = [f"      {{ uint32_t v = 0; memcpy(&v, &({expr}), {size});"]
    lines += [f"        out[n++] = (unsigned char)(v >> {8 * i});" for i in range(size)]
    return [*lines, "      }"]


def _get(expr: str, ctype: str, size: int) -> list[str]:
    parts = " | ".join(f"((uint32_t)in[n + {i}] << {8 * i})" for i in range(size))
    return [
        f"      {{ uint32_t v = {parts}; {ctype} t; memcpy(&t, &v, {size});",
        f"        {expr} = t; n += {size}; }}",
    ]


def _string_get(expr: str) -> list[str]:
    # The string's bytes move one place back over its length's last byte, which becomes room
    # for the terminating zero at their end (as ros_lib does, no copy elsewhere).
    return [
        "      { uint32_t len = (uint32_t)in[n] | ((uint32_t)in[n+1] << 8) | "
        "((uint32_t)in[n+2] << 16) | ((uint32_t)in[n+3] << 24); n += 4;",
        "        for (uint32_t k = 0; k < len; ++k) in[n + k - 1] = in[n + k];",
        f"        in[n + len - 1] = 0; {expr} = (char *)(in + n - 1); n += len; }}",
    ]


def _string_put(expr: str) -> list[str]:
    return [
        f"      {{ uint32_t len = strlen({expr}); memcpy(out + n, &len, 4); n += 4;",
        f"        memcpy(out + n, {expr}, len); n += len; }}",
    ]


def _message_class(registry: Any, type_name: str, class_name: str, type_text: str) -> str:
    """A ros::Msg subclass for ``type_name`` (the field kinds ros_lib's own messages use)."""
    members: list[str] = []
    put: list[str] = []
    get: list[str] = []
    for name, (kind, detail) in registry.fields(type_name):
        if kind.name == "BASE" and detail[0] == "string":
            members.append(f'  const char *{name} = "";')
            put += _string_put(name)
            get += _string_get(name)
        elif kind.name == "BASE":
            ctype, size = _CTYPES[detail[0]]
            members.append(f"  {ctype} {name} = 0;")
            put += _put(name, size)
            get += _get(name, ctype, size)
        elif kind.name == "NAME" and "Time" in detail:
            members.append(f"  ros::Time {name};")
            put += _put(f"{name}.sec", 4) + _put(f"{name}.nsec", 4)
            get += _get(f"{name}.sec", "uint32_t", 4) + _get(f"{name}.nsec", "uint32_t", 4)
        elif kind.name == "SEQUENCE":
            element = detail[0][1][0]
            ctype = "char *" if element == "string" else _CTYPES[element][0]
            members += [f"  uint32_t {name}_length = 0;", f"  {ctype} *{name} = nullptr;"]
            put += [
                f"      memcpy(out + n, &{name}_length, 4); n += 4;",
                f"      for (uint32_t i = 0; i < {name}_length; i++) {{",
            ]
            put += (
                _string_put(f"{name}[i]")
                if element == "string"
                else _put(f"{name}[i]", _CTYPES[element][1])
            )
            put += ["      }"]
            get += [
                "      { uint32_t count = (uint32_t)in[n] | ((uint32_t)in[n+1] << 8) | "
                "((uint32_t)in[n+2] << 16) | ((uint32_t)in[n+3] << 24); n += 4;",
                f"        if (count > {name}_length) {name} = ({ctype} *)realloc({name}, "
                f"count * sizeof({ctype}));",
                f"        {name}_length = count;",
                "        for (uint32_t i = 0; i < count; i++) {",
            ]
            get += (
                _string_get(f"{name}[i]")
                if element == "string"
                else _get(f"{name}[i]", ctype, _CTYPES[element][1])
            )
            get += ["        }", "      }"]
        else:
            raise ValueError(f"{type_name}.{name}: a field kind this generator does not make")
    constants = [
        f"  enum {{ {name} = {value} }};" for name, _type, value in registry.constants(type_name)
    ]
    md5 = registry.md5(type_name)
    return "\n".join(
        [
            f"class {class_name} : public ros::Msg {{",
            " public:",
            *members,
            *constants,
            "  int serialize(unsigned char *out) const override {",
            "    int n = 0;",
            *put,
            "    return n;",
            "  }",
            "  int deserialize(unsigned char *in) override {",
            "    int n = 0;",
            *get,
            "    return n;",
            "  }",
            f'  const char *getType() override {{ return "{type_text}"; }}',
            f'  const char *getMD5() override {{ return "{md5}"; }}',
            "};",
        ]
    )


def _header(package: str, body: str) -> str:
    guard = f"BENCH_ROS_LIB_{package.upper()}_{hashlib.md5(body.encode()).hexdigest()[:8]}"
    return "\n".join(
        [
            f"#ifndef {guard}",
            f"#define {guard}",
            "#include <stdint.h>",
            "#include <stdlib.h>",
            "#include <string.h>",
            '#include "ros/msg.h"',
            '#include "ros/time.h"',
            f"namespace {package} {{",
            body,
            "}",
            "#endif",
            "",
        ]
    )


def make_ros_lib(folder: Path) -> Path:
    """An Arduino library folder (``ros_lib/src``) with rosserial's client and Arduino files
    and generated message headers."""
    registry = msg.registry()
    src = folder / "ros_lib" / "src"
    for prefix, strip in (
        ("rosserial_client/src/ros_lib/", "rosserial_client/src/ros_lib/"),
        ("rosserial_arduino/src/ros_lib/", "rosserial_arduino/src/ros_lib/"),
    ):
        for path in git_ls(prefix):
            relative = path[len(strip) :]
            if relative.startswith(("examples/", "tests/")) or not relative.endswith(
                (".h", ".cpp")
            ):
                continue
            if "Tcp" in relative:
                continue
            target = src / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(git_file(path))
    messages = {
        "std_msgs/String": ("std_msgs", "String"),
        "std_msgs/Time": ("std_msgs", "Time"),
        "rosserial_msgs/TopicInfo": ("rosserial_msgs", "TopicInfo"),
        "rosserial_msgs/Log": ("rosserial_msgs", "Log"),
    }
    for type_name, (package, name) in messages.items():
        body = _message_class(registry, type_name, name, type_name)
        (src / package).mkdir(parents=True, exist_ok=True)
        (src / package / f"{name}.h").write_text(_header(package, body))
    for service, (package, name) in {
        "rosserial_msgs/RequestParam": ("rosserial_msgs", "RequestParam"),
        "rosserial_arduino/Test": ("rosserial_arduino", "Test"),
    }.items():
        parts = [
            _message_class(registry, f"{service}Request", f"{name}Request", service),
            _message_class(registry, f"{service}Response", f"{name}Response", service),
            f"class {name} {{ public: typedef {name}Request Request; "
            f"typedef {name}Response Response; }};",
        ]
        (src / package).mkdir(parents=True, exist_ok=True)
        (src / package / f"{name}.h").write_text(_header(package, "\n".join(parts)))
    return folder / "ros_lib"


def build_ros_lib_sketch(ros_lib: Path, name: str, source: str, baud: int, tmp: Path) -> Path:
    """Compile a ros_lib sketch as build_sketch does, without -Werror for rosserial's code."""
    board = build.BOARDS["uno"]
    out = tmp / f"{name}-{baud}"
    out.mkdir(parents=True, exist_ok=True)
    gpp, gcc = build._tool("avr-g++"), build._tool("avr-gcc")
    flags = [
        *build._CPP_FLAGS,
        *build._flags(board),
        f"-I{ros_lib / 'src'}",
        f"-DBENCH_BAUD={baud}",
    ]
    cpp = out / f"{name}.ino.cpp"
    cpp.write_text("#include <Arduino.h>\n" + source)
    objects = [out / f"{name}.o"]
    _run([gpp, *flags, "-w", str(cpp), "-o", str(objects[0])])
    for unit in sorted((ros_lib / "src").rglob("*.cpp")):
        objects.append(out / f"{unit.stem}.o")
        _run([gpp, *flags, "-w", str(unit), "-o", str(objects[-1])])
    elf = out / f"{name}.elf"
    core = build._core_archive(board)
    _run(
        [
            *(gcc, "-Os", "-flto", "-fuse-linker-plugin", "-Wl,--gc-sections"),
            *(f"-mmcu={board.mcu}", "-o", str(elf), *map(str, objects), str(core), "-lm"),
        ]
    )
    return elf


def _run(command: list[str]) -> None:
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command[:2])}...: {done.stderr.strip()[:2000]}")
