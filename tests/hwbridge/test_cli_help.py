"""``hwbridge ... --help`` for every command and subcommand (found by walking the help pages
themselves), at 80 and 200 columns, and what an unknown command says, at every level. Every
page comes from a real ``python -m hwbridge`` process."""

from __future__ import annotations

import concurrent.futures
import json
import os
import re
import subprocess
import sys

import pytest

WIDTHS = (80, 200)
MARKUP = re.compile(
    r"``"  # inline literal
    r"|:[a-z]+:`"  # a role (:func:`x`, :data:`Y`)
    r"|(?<![\w`])`[^`\s][^`]*`(?![\w`])"  # `default role`
    r"|^\s*\.\. "  # a directive or comment
    r"|::\s*$",  # a literal block's colons
    re.M,
)


def hwbridge(*argv: str, columns: int = 80) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": str(columns)}
    env.pop("LINES", None)
    return subprocess.run(
        [sys.executable, "-m", "hwbridge", *argv],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def subcommands(page: str) -> list[str]:
    """The names a help page lists under "Commands:"."""
    _, found, rest = page.partition("\nCommands:\n")
    if not found:
        return []
    names = []
    for line in rest.splitlines():
        if not line.startswith("  "):
            break
        if line[2] != " ":
            names.append(line.split()[0])
    return names


def help_pages(columns: int) -> dict[tuple[str, ...], str]:
    """Every command path's help page at ``columns``, found by walking the pages."""
    pages: dict[tuple[str, ...], str] = {}
    level: list[tuple[str, ...]] = [()]
    with concurrent.futures.ThreadPoolExecutor(4) as pool:
        while level:
            done = list(pool.map(lambda p: hwbridge(*p, "--help", columns=columns), level))
            following: list[tuple[str, ...]] = []
            for path, result in zip(level, done, strict=True):
                assert result.returncode == 0, (path, result.stderr)
                assert result.stderr == "", (path, result.stderr)
                pages[path] = result.stdout
                following += [(*path, name) for name in subcommands(result.stdout)]
            level = following
    return pages


def declared_extras() -> dict[tuple[str, ...], list[str]]:
    """Per command path, the bracketed notes each option declares (``default: auto``,
    ``env var: X``...), as Click states them."""
    probe = r"""
import json, typer
from typer.core import TyperGroup
from hwbridge.cli import build_app
out = {}
def walk(command, ctx, path):
    notes = []
    for param in command.get_params(ctx):
        record = param.get_help_record(ctx)
        if record and record[1].endswith("]") and "[" in record[1]:
            notes += record[1][record[1].rindex("[") + 1 : -1].split("; ")
    out[" ".join(path)] = notes
    if isinstance(command, TyperGroup):
        for name in command.list_commands(ctx):
            sub = command.get_command(ctx, name)
            walk(sub, sub.make_context(name, [], parent=ctx, resilient_parsing=True), [*path, name])
group = typer.main.get_group(build_app())
walk(group, group.make_context("hwbridge", [], resilient_parsing=True), [])
print(json.dumps(out))
"""
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr
    return {tuple(k.split()): v for k, v in json.loads(done.stdout).items()}


@pytest.fixture(scope="module")
def extras() -> dict[tuple[str, ...], list[str]]:
    return declared_extras()


@pytest.mark.parametrize("columns", WIDTHS)
def test_every_help_page_is_plain_and_fits(
    columns: int, extras: dict[tuple[str, ...], list[str]]
) -> None:
    pages = help_pages(columns)
    assert len(pages) > 40  # the walk reached the subcommands
    for name in ("topic", "graph", "monitor", "record", "play"):
        assert (name,) in pages
    assert ("topic", "echo") in pages and ("firmware", "build") in pages
    for path, page in pages.items():
        where = "hwbridge " + " ".join(path)
        assert page.startswith(f"Usage: {where.strip()} "), where
        long = [line for line in page.splitlines() if len(line) > columns]
        assert not long, (where, long)
        markup = MARKUP.search(page)
        assert markup is None, (where, markup.group(0) if markup else "")
        lines = page.splitlines()
        for note in extras.get(path, []):  # each default, env var, range: whole on one line
            assert any(note in line for line in lines), (where, note, page)
        for line in lines:  # a default ends on its own line (at "]" or "; " before more notes)
            assert not re.search(r"\[default: [^\];]*$", line), (where, line)


def test_help_that_was_restructured_text() -> None:
    """``topic echo`` says ``---`` in its docstring; ``msg show``-like pages too."""
    page = hwbridge("topic", "echo", "--help", columns=80).stdout
    assert "(--- between them)" in page
    assert "'{type, md5, raw}'" in page or "{type, md5, raw}" in page


@pytest.mark.parametrize(
    ("argv", "message", "group"),
    [
        (["topics", "list"], "no command 'topics'; did you mean 'topic'?", "hwbridge"),
        (["topic", "lst"], "no command 'lst'; did you mean 'list'?", "hwbridge topic"),
        (["board", "stat", "base"], "no command 'stat'; did you mean 'stats'?", "hwbridge board"),
        (["firmware", "biuld"], "no command 'biuld'; did you mean 'build'?", "hwbridge firmware"),
        (["frobnicate"], "no command 'frobnicate'", "hwbridge"),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else "",
)
def test_unknown_commands_name_the_closest(argv: list[str], message: str, group: str) -> None:
    done = hwbridge(*argv)
    assert done.returncode == 2, done.stderr
    assert done.stdout == ""
    lines = done.stderr.splitlines()
    assert lines[0] == f"error: {message}"
    assert lines[-1] == f"Try '{group} -h' for help."


def test_a_misspelt_command_imports_no_command_module() -> None:
    """The root suggests from its lazy table: no command module is imported to do it."""
    probe = (
        "import sys, contextlib, io\n"
        "from hwbridge.cli import main\n"
        "with contextlib.redirect_stderr(io.StringIO()) as err:\n"
        "    code = main(['topics', 'list'])\n"
        "assert code == 2, code\n"
        "assert 'did you mean' in err.getvalue(), err.getvalue()\n"
        "print(sorted(m for m in sys.modules if m.startswith('hwbridge.cli.') "
        "and m.endswith('cmd')))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
