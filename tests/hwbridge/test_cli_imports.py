"""What the command line imports: each command only what it needs (start-up time), and no
import cycles or borrowed private names in ``hwbridge.cli`` and ``hwbridge.graph``."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

from hwbridge.cli import COMMANDS, build_app

HEAVY = ("zenoh", "numpy", "rosbags", "yaml", "mcap", "serial", "rich", "hwbridge.msg")
ROOT = Path(__file__).parents[2]


def imported_after(code: str) -> set[str]:
    """Which of HEAVY a fresh interpreter has imported after running ``code``."""
    probe = (
        f"import sys\n{code}\n"
        "import json\n"
        f"print(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.splitlines()[-1]))


def run_cli(*argv: str) -> str:
    return (
        "from hwbridge.cli import main\n"
        "import contextlib, io\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    code = main({list(argv)!r})\n"
        "assert code == 0, code\n"
    )


def test_importing_the_cli_imports_nothing_heavy() -> None:
    assert imported_after("import hwbridge.cli") == set()


@pytest.mark.parametrize(
    ("argv", "allowed"),
    [
        (["--help"], {"rich"}),  # typer writes help with rich
        (["connect", "--help"], {"rich"}),
        (["topic", "--help"], {"rich"}),
        (["msg", "md5", "std_msgs/String"], {"numpy", "rosbags", "yaml", "hwbridge.msg"}),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else "",
)
def test_commands_import_only_what_they_need(argv: list[str], allowed: set[str]) -> None:
    assert imported_after(run_cli(*argv)) <= allowed


def test_the_lazy_table_says_what_the_commands_say() -> None:
    """``hwbridge --help`` lists COMMANDS without importing them: the one-line help there must
    be the command's own (its docstring's or group's first line)."""
    import typer

    group = typer.main.get_group(build_app())
    ctx = group.make_context("hwbridge", ["msg"], resilient_parsing=True)
    for name, lazy in COMMANDS.items():
        command = group.get_command(ctx, name)
        assert command is not None
        own = (command.help or "").strip().splitlines()[0]
        assert lazy.help == own, name


def _module_imports() -> dict[str, tuple[set[str], list[str]]]:
    """Module -> (modules of the same packages it imports at module level, TYPE_CHECKING
    blocks included; private names it imports from other modules)."""
    files = {}
    for folder in ("hwbridge/graph", "hwbridge/cli"):
        for path in (ROOT / folder).glob("*.py"):
            name = folder.replace("/", ".") + ("" if path.stem == "__init__" else "." + path.stem)
            files[name] = path
    out: dict[str, tuple[set[str], list[str]]] = {}
    for name, path in files.items():
        body = ast.parse(path.read_text()).body
        statements = [*body, *(s for n in body if isinstance(n, ast.If) for s in n.body)]
        edges: set[str] = set()
        private: list[str] = []
        for statement in statements:
            if isinstance(statement, ast.ImportFrom) and statement.module:
                if statement.module in files and statement.module != name:
                    edges.add(statement.module)
                private += [
                    f"{statement.module}.{alias.name}"
                    for alias in statement.names
                    if alias.name.startswith("_") and not alias.name.startswith("__")
                ]
            elif isinstance(statement, ast.Import):
                edges |= {a.name for a in statement.names if a.name in files} - {name}
        out[name] = (edges, private)
    return out


def test_no_import_cycles_and_no_borrowed_private_names() -> None:
    modules = _module_imports()
    for name, (_, private) in modules.items():
        assert not private, f"{name} imports private names {private}"

    def visit(name: str, path: list[str]) -> None:
        for target in modules[name][0]:
            assert target not in path, " -> ".join([*path, target])
            visit(target, [*path, target])

    for name in modules:
        visit(name, [name])
