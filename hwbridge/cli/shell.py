"""How every ``hwbridge`` command looks to a user: help pages and unknown commands.

* Help is plain text written here, not Typer's rich panels: docstrings lose their reST markup
  (``code``, :func:`x`, directives) and every line is wrapped at the terminal's width
  (``COLUMNS`` or the real width), with an option's ``[default: ...]`` and a choice list kept
  whole on one line.
* An unknown command, at any level, is a usage error that names the closest commands; the root
  finds them in the lazy command table without importing any command module.

:class:`Command` and :class:`Group` carry both; :func:`adopt` makes a command module's Typer
app build its commands and groups with them.
"""

from __future__ import annotations

import difflib
import inspect
import re
import shutil
import textwrap
from typing import TYPE_CHECKING, Any, Literal

import typer
from typer.core import TyperCommand, TyperGroup

try:  # Typer vendors Click from 0.26 on
    from typer._click.exceptions import ClickException, UsageError
except ImportError:  # pragma: no cover - an older Typer, on Click itself
    from click.exceptions import ClickException, UsageError  # type: ignore[no-redef,import-not-found,unused-ignore]  # pyright: ignore[reportMissingImports]

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

__all__ = [
    "ClickException",
    "Command",
    "Group",
    "UsageError",
    "adopt",
    "help_width",
    "no_command",
    "plain_text",
    "render_help",
    "summary",
]

_MIN_WIDTH = 40
_COLUMN_MAX = 30
"""Widest first column (option names) of a definition list before its help goes below it."""


def help_width() -> int:
    """Columns to wrap help at: ``COLUMNS``, else the terminal's, else 80."""
    return max(_MIN_WIDTH, shutil.get_terminal_size().columns)


# ---------------------------------------------------------------------- reST to plain text
_ROLE = re.compile(r":[\w.+-]+(?::[\w.+-]+)?:`(?P<body>[^`]+)`")
_LITERAL = re.compile(r"``(?P<body>.+?)``")
_DEFAULT_ROLE = re.compile(r"(?<![`\w])`(?P<body>[^`\s][^`]*)`(?![`\w])")
_START = r"(?:(?<=[\s(\[{'\"])|^)"
_END = r"(?=[\s)\]}'\".,;:!?]|$)"
_STRONG = re.compile(_START + r"\*\*(?P<body>[^*\s](?:[^*\n]*[^*\s])?)\*\*" + _END, re.M)
_EMPHASIS = re.compile(_START + r"\*(?P<body>[^*\s](?:[^*\n]*[^*\s])?)\*" + _END, re.M)
_DIRECTIVE = re.compile(r"^(?P<indent>\s*)\.\.\s+(?P<name>[\w-]+)::\s*(?P<rest>.*)$")
_COMMENT = re.compile(r"^\s*\.\.(\s.*)?$")
_ADMONITIONS = {"note", "warning", "tip", "important", "caution", "hint", "attention", "danger"}


def _role(match: re.Match[str]) -> str:
    body = match.group("body")
    titled = re.fullmatch(r"(?P<title>.+?)\s*<[^>]+>", body)
    if titled:
        return titled.group("title")
    if body.startswith("~"):
        return body[1:].rsplit(".", 1)[-1]
    return body.lstrip("!")


def _literal(match: re.Match[str]) -> str:
    body = match.group("body")
    return f"'{body}'" if " " in body else body


def _inline(text: str) -> str:
    text = _ROLE.sub(_role, text)
    text = _LITERAL.sub(_literal, text)
    text = _DEFAULT_ROLE.sub(lambda m: m.group("body"), text)
    text = _STRONG.sub(lambda m: m.group("body"), text)
    return _EMPHASIS.sub(lambda m: m.group("body"), text)


def plain_text(text: str) -> str:
    """``text`` (a docstring or an option's help, reST) as plain text, paragraphs kept.

    Inline markup gives its text (````x```` gives ``x``, quoted when it holds a space;
    ``:func:`~a.b``` gives ``b``); admonitions (``.. note::``) become ``Note:``; other
    directives and comments go, their indented content stays; ``::`` ending a paragraph
    becomes ``:``. Click's ``\\f`` (end of help) is honoured.
    """
    text = inspect.cleandoc(text.split("\f", 1)[0])
    lines: list[str] = []
    for line in text.splitlines():
        directive = _DIRECTIVE.match(line)
        if directive:
            name = directive.group("name").lower()
            if name in _ADMONITIONS:
                rest = directive.group("rest")
                lines.append(f"{directive.group('indent')}{name.capitalize()}: {rest}".rstrip())
            continue
        if _COMMENT.match(line):
            continue
        stripped = line.rstrip()
        if stripped.strip() == "::":
            continue
        if stripped.endswith("::"):
            stripped = stripped[:-1]
        lines.append(_inline(stripped))
    return "\n".join(lines).strip("\n")


def summary(text: str | None) -> str:
    """The first paragraph of a help text, plain, on one line."""
    if not text:
        return ""
    first = plain_text(text).split("\n\n", 1)[0]
    return " ".join(first.split()).replace("\b", "").strip()


# ---------------------------------------------------------------------- wrapping
_BRACKETS = re.compile(r"\[[^\[\]]*\]")
_HOLD = "\x00"
"""Stands for a space that must not break a line (inside ``[default: ...]``)."""


def _hold_extras(text: str) -> str:
    """Keep each item of a ``[default: x; env var: Y; required]`` group, and a choice list
    such as ``[zstd|lz4|none]``, on one line (lines may break between items)."""

    def hold(match: re.Match[str]) -> str:
        items = match.group(0)[1:-1].split("; ")
        return "[" + "; ".join(item.replace(" ", _HOLD) for item in items) + "]"

    return _BRACKETS.sub(hold, text)


def _wrap(text: str, width: int, indent: int, hanging: int | None = None) -> list[str]:
    """One paragraph wrapped to ``width`` columns, words and held units never cut; a unit
    longer than the space left is cut only when nothing else can fit it."""
    rest = indent if hanging is None else hanging
    wrapper = textwrap.TextWrapper(
        width=width,
        initial_indent=" " * indent,
        subsequent_indent=" " * rest,
        break_long_words=False,
        break_on_hyphens=False,
    )
    lines = wrapper.wrap(_hold_extras(text))
    if any(len(line) > width for line in lines):
        wrapper.break_long_words = True
        lines = wrapper.wrap(_hold_extras(text))
    return [line.replace(_HOLD, " ") for line in lines]


def _paragraphs(text: str, width: int, indent: int) -> list[str]:
    """Plain ``text`` wrapped: prose re-flowed, bullets with a hanging indent, indented blocks
    (examples, literal blocks) kept as written unless wider than the page."""
    out: list[str] = []
    for block in re.split(r"\n\s*\n", text):
        if not block.strip():
            continue
        if out:
            out.append("")
        raw = block.splitlines()
        keep = block.startswith("\b") or all(line.startswith((" ", "\t")) for line in raw)
        if keep:
            for written in raw:
                line = written.replace("\b", "").rstrip()
                lead = len(line) - len(line.lstrip())
                if line:
                    out += _wrap(line.strip(), width, indent + lead, indent + lead + 2)
            continue
        items: list[list[str]] = []
        for line in raw:
            if re.match(r"\s*([-*+]|\d+[.)])\s", line) or not items:
                items.append([line.strip()])
            else:
                items[-1].append(line.strip())
        for item in items:
            bullet = re.match(r"([-*+]|\d+[.)])\s+", item[0])
            hanging = indent + (len(bullet.group(0)) if bullet else 0)
            out += _wrap(" ".join(item), width, indent, hanging)
    return out


def _definitions(rows: Sequence[tuple[str, str]], width: int, indent: int = 2) -> list[str]:
    """Rows of (term, help): help to the right of the terms, or below a term too wide."""
    if not rows:
        return []
    column = min(max(len(term) for term, _ in rows), _COLUMN_MAX, width // 3)
    help_at = indent + column + 2
    out: list[str] = []
    for term, given in rows:
        text = " ".join(plain_text(given).split()) if given else ""
        first = " " * indent + term
        if len(first) > width:
            out += _wrap(term, width, indent, indent + 4)
            first = ""
        if not text:
            if first:
                out.append(first)
            continue
        if first and len(term) <= column:
            lines = _wrap(text, width, help_at)
            if all(len(line) <= width for line in lines) and (
                len(lines) == 1 or lines[0][:help_at].strip() == ""
            ):
                out.append(first + lines[0][len(first) :])
                out += lines[1:]
                continue
        if first:
            out.append(first)
        below = help_at if help_at <= width // 2 else indent + 8
        out += _wrap(text, width, below)
    return out


def _section(title: str, lines: list[str]) -> list[str]:
    return ["", f"{title}:", *lines] if lines else []


def render_help(command: Any, ctx: typer.Context, width: int | None = None) -> str:
    """The help page of ``command`` in ``ctx``: usage, description, arguments, options and, for
    a group, its commands, every line at most ``width`` columns."""
    width = width or help_width()
    pieces = command.collect_usage_pieces(ctx)
    prefix = f"Usage: {ctx.command_path} "
    usage = " ".join(pieces)
    if len(prefix) + 20 <= width:
        lines = _wrap(usage, width - len(prefix), 0)
        page = [prefix + lines[0], *(" " * len(prefix) + line for line in lines[1:])]
    else:
        page = [prefix.rstrip(), *_wrap(usage, width, 4)]
    description = plain_text(command.help or "")
    if description:
        page += ["", *_paragraphs(description, width, 2)]
    arguments: list[tuple[str, str]] = []
    options: list[tuple[str, str]] = []
    for param in command.get_params(ctx):
        record = param.get_help_record(ctx)
        if record is None:
            continue
        (arguments if param.param_type_name == "argument" else options).append(record)
    page += _section("Arguments", _definitions(arguments, width))
    page += _section("Options", _definitions(options, width))
    if isinstance(command, TyperGroup):
        rows = []
        for name in command.list_commands(ctx):
            sub = command.get_command(ctx, name)
            if sub is not None and not sub.hidden:
                rows.append((name, summary(sub.short_help or sub.help)))
        page += _section("Commands", _definitions(rows, width))
    if command.epilog:
        page += ["", *_paragraphs(plain_text(command.epilog), width, 2)]
    return "\n".join(page) + "\n"


# ---------------------------------------------------------------------- commands and groups
def no_command(name: str, known: Iterable[str]) -> str:
    """The message for an unknown command ``name``, naming the closest of ``known``."""
    names = list(known)
    close = difflib.get_close_matches(name, names, n=3, cutoff=0.6)
    close += [n for n in names if n.startswith(name) and n not in close][: 3 - len(close)]
    if not close:
        return f"no command {name!r}"
    quoted = [repr(n) for n in close]
    choices = quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " or " + quoted[-1]
    return f"no command {name!r}; did you mean {choices}?"


class _PlainHelp:
    """Help written by :func:`render_help` (not Typer's rich panels), and the one-line summary a
    group lists for it."""

    short_help: str | None
    help: str | None
    rich_markup_mode: Literal["markdown", "rich", None]

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.rich_markup_mode = None

    def format_help(self, ctx: Any, formatter: Any) -> None:
        formatter.write(render_help(self, ctx))

    def get_short_help_str(self, limit: int = 45) -> str:
        return summary(self.short_help or self.help)


class Command(_PlainHelp, TyperCommand):
    """A command whose help is :func:`render_help`'s."""


class Group(_PlainHelp, TyperGroup):
    """A group whose help is :func:`render_help`'s and whose unknown commands are usage errors
    naming the closest ones."""

    def resolve_command(self, ctx: Any, args: list[str]) -> Any:
        name = args[0] if args else ""
        if (
            name
            and not name.startswith("-")
            and not ctx.resilient_parsing
            and self.get_command(ctx, name) is None
        ):
            raise UsageError(no_command(name, self.list_commands(ctx)), ctx)
        return super().resolve_command(ctx, args)


def adopt(app: typer.Typer) -> typer.Typer:
    """Make ``app`` (and the apps added to it) build :class:`Group` and :class:`Command`
    unless they ask for classes of their own; returns ``app``."""
    if not isinstance(app.info.cls, type) or app.info.cls is TyperGroup:
        app.info.cls = Group
    for command in app.registered_commands:
        if command.cls in (None, TyperCommand):
            command.cls = Command
    for group in app.registered_groups:
        if not isinstance(group.cls, type) or group.cls is TyperGroup:
            group.cls = Group
        if group.typer_instance is not None:
            adopt(group.typer_instance)
    return app
