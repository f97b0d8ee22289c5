"""Building the compiled modules of :mod:`hwbridge.compiled` (Cython, setuptools, a C compiler)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from hwbridge.compiled import DIRECTIVES, MODULES, cache_root, compiled_path, source_of

__all__ = ["BuildError", "build"]


class BuildError(Exception):
    """What is missing to build (Cython, a compiler, Python's headers), or what failed."""


def _check_tools() -> None:
    import shutil
    import sysconfig

    try:
        import Cython  # noqa: F401
    except ImportError:
        raise BuildError(
            "Cython is not installed (pip install 'hwbridge[fast]' or pip install cython)"
        ) from None
    include = sysconfig.get_paths().get("include")
    if not include or not (Path(include) / "Python.h").is_file():
        raise BuildError(
            f"Python's C headers are missing ({include}/Python.h; on Debian: apt-get install "
            "python3-dev)"
        )
    compiler = (sysconfig.get_config_var("CC") or "cc").split()[0]
    if shutil.which(compiler) is None:
        raise BuildError(f"no C compiler ({compiler!r} is not on PATH)")


def build(
    names: Sequence[str] = MODULES,
    *,
    root: Path | None = None,
    jobs: int = 0,
    progress: Callable[[str], None] | None = None,
) -> list[Path]:
    """Compile the modules ``names`` whose source has no compiled copy yet into ``root`` (the
    cache by default); returns the files made. ``jobs``: compilers run at once (0: one a core);
    ``progress`` gets a line at the start, one per module made and one at the end.

    Raises:
        BuildError: a tool is missing, or a module did not compile.
    """
    import shutil
    import tempfile
    import time

    root = root or cache_root()
    unknown = sorted(set(names) - set(MODULES))
    if unknown:
        raise BuildError(f"not a module that is compiled: {', '.join(unknown)}")
    todo: list[tuple[str, Path, Path]] = []
    for name in names:
        source = source_of(name)
        target = compiled_path(name, source.read_bytes(), root)
        if not target.is_file():
            todo.append((name, source, target))
    if not todo:
        if progress is not None:
            progress(f"compiled modules: all {len(names)} up to date in {root}")
        return []
    _check_tools()
    jobs = jobs or os.cpu_count() or 1
    started = time.monotonic()
    if progress is not None:
        progress(
            f"compiling {len(todo)} of {len(names)} modules with Cython into {root} "
            f"({jobs} at once; a few minutes)"
        )
    made: list[Path] = []
    with tempfile.TemporaryDirectory(prefix="hwbridge-compile-") as tmp:
        for name, product in _compile(todo, Path(tmp), jobs):
            target = next(target for each, _, target in todo if each == name)
            target.parent.mkdir(parents=True, exist_ok=True)
            partial = target.with_name(target.name + ".part")
            shutil.copyfile(product, partial)
            partial.replace(target)  # whole or not at all: another process may import meanwhile
            made.append(target)
            if progress is not None:
                progress(f"  [{len(made)}/{len(todo)}] {name}")
    if progress is not None:
        progress(f"compiled {len(made)} modules in {time.monotonic() - started:.0f} s")
    return made


def _compile(
    todo: Sequence[tuple[str, Path, Path]], tmp: Path, jobs: int
) -> Iterator[tuple[str, Path]]:
    """Cython and the C compiler over ``todo`` in ``tmp``, ``jobs`` modules at once, each in a
    process of its own: each module's name and extension file, as they are made."""
    from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, as_completed, wait

    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = {
            pool.submit(_compile_one, name, str(source), str(tmp / name)): name
            for name, source, _ in todo
        }
        try:
            for future in as_completed(futures):
                yield futures[future], Path(future.result())
        except BaseException:
            for future in futures:
                future.cancel()
            wait(futures, return_when=FIRST_EXCEPTION)
            raise


def _compile_one(name: str, source: str, tmp: str) -> str:
    """Module ``name`` (from ``source``) compiled in folder ``tmp``: its extension file.
    Runs in a worker process."""
    from Cython.Build import cythonize
    from setuptools import Distribution, Extension  # type: ignore[import-untyped]
    from setuptools.command.build_ext import build_ext  # type: ignore[import-untyped]

    try:
        modules = cythonize(  # type: ignore[no-untyped-call]
            # (after Python's own -O3 -g: less to compile, and no debugging data in the files)
            [Extension(name, [source], extra_compile_args=["-O2", "-g0"])],
            build_dir=f"{tmp}/c",
            compiler_directives=DIRECTIVES,
            quiet=True,
            force=True,
        )
        command = build_ext(Distribution({"ext_modules": modules}))
        command.build_lib = f"{tmp}/lib"
        command.build_temp = f"{tmp}/obj"
        command.ensure_finalized()
        command.run()
    # (any failure of the tools is the build's; setuptools ends a failed compile with SystemExit)
    except (Exception, SystemExit) as exc:  # noqa: BLE001
        raise BuildError(f"{name}: compiling failed: {exc}") from None
    return str(command.get_ext_fullpath(name))
