"""The shape of the code: no import cycles, no huge modules, protocols/ free of the runtime.

The import graph is read statically (``ast``) from every module of the installed ``hwbridge``
package, ``hwbridge.protocols`` and ``hwbridge.devices`` included (through the symlinks
``hwbridge/protocols`` and ``hwbridge/devices``). Edges:

* module-level imports (also those inside a module-level ``if``/``try``/``with`` or a class body)
  and function-level imports: both are dependencies at run time (a function-level import only
  defers one), so a cycle through them is a failure; the message marks function-level edges;
* ``if TYPE_CHECKING:`` imports are collected apart: they do not count for cycles (nothing runs
  them), but they do count for the protocols/ rule.

``from a.b import c`` is an edge to ``a.b.c`` when that is a module, else to ``a.b``. The parent
packages that Python initialises on the way (``a``, ``a.b``) are not edges, as in import-linter
and pydeps: a package ``__init__`` that re-exports its submodules is not a cycle.

The same edges, taken between folders (``hwbridge.emulator``, ``hwbridge.devices``, and each
module directly in ``hwbridge/`` on its own), must make no cycle either: the layers of
docs/design.md. A ``__main__`` module is a program that ``python -m`` runs and nothing imports,
so its imports are left out of that graph (``hwbridge.firmware.sim``'s runs the CLI's command).

A device is one folder: each built-in device type's plugin lives in a folder of its own under
``devices/``, and no module outside that folder names the type in a string (the registry's list
of built-ins aside).
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import itertools
import os
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "hwbridge"
MAX_LINES = 800
SIZE_CHECKED = ("hwbridge", "protocols", "devices")
SYMLINKS = {"protocols": "../protocols", "devices": "../devices"}
MYPY_SINGLE_FILE = "protocols/native/cobs.py"


@dataclass
class Module:
    name: str
    path: Path
    is_package: bool
    runtime: set[str] = field(default_factory=set)
    """Modules imported when this one is imported (module level, not TYPE_CHECKING)."""
    lazy: set[str] = field(default_factory=set)
    """Modules imported inside functions (when they run)."""
    typing: set[str] = field(default_factory=set)
    """Modules imported under TYPE_CHECKING only (never at run time)."""
    imported: set[str] = field(default_factory=set)
    """Every dotted name this module imports, resolved (for the protocols/ rule)."""


def _walk_package(root: Path, name: str) -> Iterator[tuple[str, Path, bool]]:
    """(module name, path, is a package) below ``root``, following symlinked folders."""
    for folder, dirs, files in os.walk(root, followlinks=True):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__" and d.isidentifier())
        rel = Path(folder).relative_to(root)
        prefix = ".".join((name, *rel.parts))
        for file in sorted(files):
            if not file.endswith(".py"):
                continue
            path = Path(folder) / file
            if file == "__init__.py":
                yield prefix, path, True
            elif file[:-3].isidentifier():
                yield f"{prefix}.{file[:-3]}", path, False


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


Kind = Literal["runtime", "lazy", "typing"]


def _imports(tree: ast.Module) -> Iterator[tuple[ast.Import | ast.ImportFrom, Kind]]:
    """Every import statement with its kind: module level, in a function, or TYPE_CHECKING."""

    def visit(node: ast.AST, kind: Kind) -> Iterator[tuple[ast.Import | ast.ImportFrom, Kind]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Import | ast.ImportFrom):
                yield child, kind
            elif isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                yield from visit(child, "typing" if kind == "typing" else "lazy")
            elif isinstance(child, ast.If) and _is_type_checking(child.test):
                for stmt in child.body:
                    yield from visit(ast.Module(body=[stmt], type_ignores=[]), "typing")
                for stmt in child.orelse:
                    yield from visit(ast.Module(body=[stmt], type_ignores=[]), kind)
            else:
                yield from visit(child, kind)

    yield from visit(tree, "runtime")


def _targets(node: ast.Import | ast.ImportFrom, module: Module, known: set[str]) -> set[str]:
    """Dotted names ``node`` imports: ``a.b.c`` for ``from a.b import c`` if it is a module."""
    if isinstance(node, ast.Import):
        return {alias.name for alias in node.names}
    if node.level:
        package = module.name if module.is_package else module.name.rpartition(".")[0]
        parts = package.split(".")
        base_parts = parts[: len(parts) - (node.level - 1)]
        base = ".".join([*base_parts, *([node.module] if node.module else [])])
    else:
        base = node.module or ""
    out = set()
    for alias in node.names:
        candidate = f"{base}.{alias.name}"
        out.add(candidate if candidate in known else base)
    return out


def _internal(name: str, known: set[str]) -> str | None:
    """The known module ``name`` refers to (itself or its longest known prefix)."""
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


def _graph() -> dict[str, Module]:
    modules = {
        name: Module(name, path, is_package)
        for name, path, is_package in _walk_package(ROOT / PACKAGE, PACKAGE)
    }
    known = set(modules)
    for module in modules.values():
        tree = ast.parse(module.path.read_text(encoding="utf-8"), str(module.path))
        for node, kind in _imports(tree):
            for target in _targets(node, module, known):
                module.imported.add(target)
                internal = _internal(target, known)
                if internal is not None and internal != module.name:
                    getattr(module, kind).add(internal)
    return modules


def _edges(module: Module) -> set[str]:
    """What ``module`` needs at run time: the edges that make cycles."""
    return module.runtime | module.lazy


def _cycles(modules: dict[str, Module]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each as a cycle path."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(modules) + 100))

    def connect(name: str) -> None:
        index[name] = low[name] = len(index)
        stack.append(name)
        on_stack.add(name)
        for target in sorted(_edges(modules[name])):
            if target not in index:
                connect(target)
                low[name] = min(low[name], low[target])
            elif target in on_stack:
                low[name] = min(low[name], index[target])
        if low[name] == index[name]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == name:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for name in sorted(modules):
        if name not in index:
            connect(name)
    return [_cycle_path(modules, set(component)) for component in sorted(components)]


def _cycle_path(modules: dict[str, Module], component: set[str]) -> list[str]:
    """One concrete cycle through the component's first module (breadth-first, shortest)."""
    start = min(component)
    previous: dict[str, str] = {}
    queue = [start]
    while queue:
        current = queue.pop(0)
        for target in sorted(_edges(modules[current]) & component):
            if target == start:
                path = [current]
                while path[-1] != start:
                    path.append(previous[path[-1]])
                return [*reversed(path), start]
            if target not in previous:
                previous[target] = current
                queue.append(target)
    return sorted(component)  # not reached: a component of several modules has a cycle


def test_package_symlinks() -> None:
    for name, target in SYMLINKS.items():
        link = ROOT / PACKAGE / name
        assert link.is_symlink(), f"{link} must be a symlink to {target}"
        assert str(link.readlink()) == target, f"{link} points at {link.readlink()}, not {target}"
        assert (link / "__init__.py").is_file()


def test_import_graph_covers_the_package() -> None:
    modules = _graph()
    for expected in (
        "hwbridge",
        "hwbridge.msg",
        "hwbridge.protocols",
        "hwbridge.protocols.native.cobs",
        "hwbridge.devices",
        "hwbridge.devices.dynamixel.packets",
    ):
        assert expected in modules, expected
    framing = modules["hwbridge.protocols.native.framing"]
    assert "hwbridge.protocols.native.cobs" in framing.runtime


def test_cycle_finder_finds_cycles() -> None:
    modules = {name: Module(name, Path(name), is_package=False) for name in "abcde"}
    modules["a"].runtime = {"b"}
    modules["b"].runtime = {"c"}
    modules["c"].runtime = {"a", "d"}
    modules["c"].lazy = {"e"}
    modules["d"].typing = {"a"}  # TYPE_CHECKING only: no cycle
    modules["e"].lazy = {"c"}  # function level: a cycle
    assert _cycles(modules) == [["a", "b", "c", "a"]]  # one component: a b c e
    lazy = "-(in a function)->"
    assert _describe_cycle(modules, ["c", "e", "c"]) == f"c {lazy} e {lazy} c"


def _describe_cycle(modules: dict[str, Module], cycle: list[str]) -> str:
    text = cycle[0]
    for source, target in itertools.pairwise(cycle):
        lazy = target not in modules[source].runtime
        text += f" {'-(in a function)->' if lazy else '->'} {target}"
    return text


def test_no_import_cycles() -> None:
    modules = _graph()
    cycles = _cycles(modules)
    assert not cycles, "import cycles (TYPE_CHECKING imports aside):\n" + "\n".join(
        "  " + _describe_cycle(modules, cycle) for cycle in cycles
    )


BRIDGE = f"{PACKAGE}.bridge"
BRIDGE_OWNERS = {BRIDGE, f"{BRIDGE}.core", f"{BRIDGE}.board"}
"""The bridge modules that may see the board connection: the package (it re-exports it), the
bridge that creates the connections, and the connection's own module."""


def test_bridge_parts_never_see_their_owner() -> None:
    """The session adapter and the endpoints get a port from the board's connection and never
    import it, not even for types (``TYPE_CHECKING``), nor through the package that re-exports
    it: the bridge's parts have no import circle to hide."""
    modules = _graph()
    owner = {f"{BRIDGE}.board", BRIDGE}
    offending = [
        f"  {module.name} imports {target}"
        for module in modules.values()
        if module.name.startswith(f"{BRIDGE}.") and module.name not in BRIDGE_OWNERS
        for target in sorted((module.runtime | module.lazy | module.typing) & owner)
    ]
    assert {f"{BRIDGE}.adapter", f"{BRIDGE}.endpoints"} <= set(modules)
    assert not offending, "only hwbridge.bridge.core may use the board's connection:\n" + (
        "\n".join(offending)
    )


def _folder(module: str) -> str:
    """The folder a module belongs to: ``hwbridge.emulator.world`` -> ``hwbridge.emulator``."""
    return ".".join(module.split(".")[:2])


def _folder_graph(modules: dict[str, Module]) -> dict[str, Module]:
    """The import graph between folders; each folder's edges keep one module edge per target
    (in ``imported``, as ``"source -> target"``) to show in a failure."""
    folders: dict[str, Module] = {}
    for module in modules.values():
        source = _folder(module.name)
        folder = folders.setdefault(source, Module(source, module.path, is_package=True))
        if module.name.rpartition(".")[2] == "__main__":
            continue
        for target in sorted(_edges(module)):
            into = _folder(target)
            if into == source:
                continue
            if target in module.runtime:
                folder.runtime.add(into)
                folder.lazy.discard(into)
            elif into not in folder.runtime:
                folder.lazy.add(into)
            folder.imported.add(f"{module.name} -> {target}")
    return folders


def _folder_edge(folders: dict[str, Module], source: str, target: str) -> str:
    for edge in sorted(folders[source].imported):
        if _folder(edge.rpartition(" -> ")[2]) == target:
            return edge
    return f"{source} -> {target}"  # not reached for an edge of the graph


def test_folder_graph_finds_a_cycle_through_a_function_level_import() -> None:
    modules = {
        name: Module(name, Path(name), is_package=False)
        for name in ("hwbridge.a.x", "hwbridge.b.y", "hwbridge.b.__main__", "hwbridge.c")
    }
    modules["hwbridge.a.x"].runtime = {"hwbridge.b.y"}
    modules["hwbridge.b.y"].lazy = {"hwbridge.a.x"}
    modules["hwbridge.b.__main__"].runtime = {"hwbridge.c"}  # a program: no edge
    modules["hwbridge.c"].runtime = {"hwbridge.b.y"}
    folders = _folder_graph(modules)
    assert _cycles(folders) == [["hwbridge.a", "hwbridge.b", "hwbridge.a"]]
    assert _folder_edge(folders, "hwbridge.b", "hwbridge.a") == "hwbridge.b.y -> hwbridge.a.x"


def test_no_import_cycles_between_folders() -> None:
    folders = _folder_graph(_graph())
    cycles = _cycles(folders)
    assert not cycles, "import cycles between folders (TYPE_CHECKING imports aside):\n" + "\n".join(
        "  "
        + _describe_cycle(folders, cycle)
        + "\n"
        + "".join(
            f"    {_folder_edge(folders, source, target)}\n"
            for source, target in itertools.pairwise(cycle)
        )
        for cycle in cycles
    )


DEVICES = ROOT / PACKAGE / "devices"
"""Where built-in devices live (through the symlink, as the import graph names them)."""
REGISTRY = ROOT / PACKAGE / "robot" / "registry.py"
BUILTIN_LIST = "BUILTIN_DEVICES"
"""The registry's one list of the built-in device types, the one place besides their folders
that names them."""


def _builtin_devices() -> dict[str, str]:
    registry = importlib.import_module(f"{PACKAGE}.robot.registry")
    builtin: dict[str, str] = getattr(registry, BUILTIN_LIST)
    return builtin


def _device_folders(modules: dict[str, Module]) -> dict[str, Path]:
    """Each built-in device type's folder: the one its plugin's module is in (``devices/``
    itself, for a plugin not in a folder of its own)."""
    folders = {}
    for name, target in sorted(_builtin_devices().items()):
        module = modules[target.partition(":")[0]]
        folders[name] = module.path.parent
    return folders


def test_each_builtin_device_has_a_folder_of_its_own() -> None:
    outside = [
        f"  {name}: {folder.relative_to(ROOT)}"
        for name, folder in _device_folders(_graph()).items()
        if folder.parent != DEVICES
    ]
    assert not outside, "device plugins outside a folder devices/<device>/:\n" + "\n".join(outside)


def _string_literals(tree: ast.Module) -> Iterator[tuple[ast.Constant, bool]]:
    """Every string constant, with whether it is in the registry's list of built-ins."""

    def visit(node: ast.AST, in_list: bool) -> Iterator[tuple[ast.Constant, bool]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Constant) and isinstance(child.value, str):
                yield child, in_list
            listing = isinstance(child, ast.Assign | ast.AnnAssign) and any(
                isinstance(target, ast.Name) and target.id == BUILTIN_LIST
                for target in (child.targets if isinstance(child, ast.Assign) else [child.target])
            )
            yield from visit(child, in_list or listing)

    yield from visit(tree, in_list=False)


def test_no_module_names_a_device_type_outside_its_folder() -> None:
    """Modules of hwbridge (protocols/ and devices/ through the symlinks) and tools/; tests and
    docs may name device types."""
    folders = _device_folders(_graph())
    paths = [path for _, path, _ in _walk_package(ROOT / PACKAGE, PACKAGE)]
    paths += sorted((ROOT / "tools").rglob("*.py"))
    named = []
    for path in paths:
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for node, in_list in _string_literals(tree):
            if node.value not in folders:
                continue
            folder = folders[node.value]
            if folder.parent == DEVICES and path.is_relative_to(folder):
                continue
            if in_list and path == REGISTRY:
                continue
            named.append(f"  {path.relative_to(ROOT)}:{node.lineno}: {node.value!r}")
    assert not named, (
        "device types named outside their folders (a device is one folder: what names it "
        "belongs in devices/<device>/):\n" + "\n".join(named)
    )


def _line_count(path: Path) -> int:
    with path.open("rb") as file:
        return sum(1 for _ in file)


def test_no_module_over_800_lines() -> None:
    too_big = []
    for folder in SIZE_CHECKED:
        for dirpath, dirs, files in os.walk(ROOT / folder):  # symlinks not followed: once each
            dirs[:] = sorted(d for d in dirs if d != "__pycache__")
            for file in sorted(files):
                if file.endswith(".py"):
                    path = Path(dirpath) / file
                    lines = _line_count(path)
                    if lines > MAX_LINES:
                        too_big.append(f"  {path.relative_to(ROOT)}: {lines} lines")
    assert not too_big, f"modules over {MAX_LINES} lines:\n" + "\n".join(too_big)


def test_protocols_import_nothing_from_the_runtime() -> None:
    offending = []
    for module in _graph().values():
        if not module.name.startswith(f"{PACKAGE}.protocols"):
            continue
        for target in sorted(module.imported):
            inside = target == f"{PACKAGE}.protocols" or target.startswith(f"{PACKAGE}.protocols.")
            if (target == PACKAGE or target.startswith(f"{PACKAGE}.")) and not inside:
                offending.append(f"  {module.name} imports {target}")
    assert not offending, "protocols/ must not import the hwbridge runtime:\n" + "\n".join(
        offending
    )


def test_mypy_on_one_protocols_file(tmp_path: Path) -> None:
    """Plain ``mypy FILE`` (strict, per pyproject) understands the package through the symlinks."""
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed")
    done = subprocess.run(
        [sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path), MYPY_SINGLE_FILE],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    output = done.stdout + done.stderr
    assert done.returncode == 0, output
    assert "Success" in output, output
