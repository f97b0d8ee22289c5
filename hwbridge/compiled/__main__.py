"""``python -m hwbridge.compiled build|status``: see :mod:`hwbridge.compiled`."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from hwbridge.compiled import MODULES, available
from hwbridge.compiled.build import BuildError, build


def _say(line: str) -> None:
    sys.stderr.write(line + "\n")
    sys.stderr.flush()


def main(argv: Sequence[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m hwbridge.compiled",
        description="Compile the modules on a message's path with Cython (see the module's doc).",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    make = sub.add_parser("build", help="compile the modules whose source has no compiled copy")
    make.add_argument("modules", nargs="*", help="only these (default: all)")
    make.add_argument(
        "-j", "--jobs", type=int, default=0, help="compilers at once (0: a core each)"
    )
    sub.add_parser("status", help="which modules have a compiled copy of their current source")
    args = parser.parse_args(argv)
    if args.command == "status":
        built = set(available())
        for name in MODULES:
            state = "compiled" if name in built else "source"
            sys.stdout.write(f"{state:9} {name}\n")
        return 0
    try:
        build(args.modules or MODULES, jobs=args.jobs, progress=_say)
    except BuildError as exc:
        _say(f"error: {exc}")
        return 1
    except KeyboardInterrupt:
        _say("interrupted")
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
