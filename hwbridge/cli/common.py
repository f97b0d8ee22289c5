"""Helpers shared by the command modules: the per-invocation context and consoles."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import typer
from rich.console import Console

from hwbridge.msg import TypeRegistry, registry

__all__ = ["Context", "console_err", "get_registry"]

console_err = Console(stderr=True, soft_wrap=True)


@dataclass(frozen=True)
class Context:
    """Options given before the subcommand (``hwbridge --msg-path DIR msg show ...``)."""

    msg_path: tuple[Path, ...] = ()


def get_registry(ctx: typer.Context) -> TypeRegistry:
    """The type registry for this invocation's --msg-path and HWBRIDGE_MSG_PATH."""
    obj = ctx.find_root().obj
    paths = obj.msg_path if isinstance(obj, Context) else ()
    return registry(paths)
