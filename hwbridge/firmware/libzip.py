"""The HwBridge Arduino library as a zip for the Arduino IDE's "Add .ZIP Library".

The IDE (Sketch > Include Library > Add .ZIP Library...) unpacks a zip whose one top folder is
the library into the sketchbook's ``libraries/`` folder. :func:`write_library_zip` writes
``HwBridge/`` with ``library.properties`` (checked against the fields the Arduino library
specification 1.5 asks for), ``library.json``, the READMEs, ``src/`` and ``examples/NAME/NAME.ino``
(with each example's other files), leaving out build folders, caches, hidden files and build
products. Entries are sorted and dated 1980-01-01, so the same library gives the same bytes.
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Final

from hwbridge.errors import HwBridgeError

__all__ = [
    "REQUIRED_PROPERTIES",
    "TOP_FOLDER",
    "library_files",
    "read_properties",
    "write_library_zip",
]

TOP_FOLDER: Final = "HwBridge"
"""The zip's one top folder: the library's name, as the IDE installs it."""
REQUIRED_PROPERTIES: Final = (
    "name",
    "version",
    "author",
    "maintainer",
    "sentence",
    "paragraph",
    "category",
    "url",
    "architectures",
)
"""The library.properties fields of the 1.5 library format that must be there (``includes``,
``depends``, ``dot_a_linkage``... are optional)."""
CATEGORIES: Final = (
    "Display",
    "Communication",
    "Signal Input/Output",
    "Sensors",
    "Device Control",
    "Timing",
    "Data Storage",
    "Data Processing",
    "Other",
)
"""The categories the specification allows."""
_TOP_FILES: Final = ("library.properties", "library.json", "README.md", "LICENSE", "keywords.txt")
_SKIPPED_DIRS: Final = frozenset({"build", "__pycache__", ".pio", ".vscode", "CMakeFiles"})
_SKIPPED_SUFFIXES: Final = frozenset(
    {".o", ".a", ".d", ".elf", ".hex", ".eep", ".map", ".lst", ".pyc", ".bin", ".zip"}
)
_DATE: Final = (1980, 1, 1, 0, 0, 0)


def read_properties(path: Path) -> dict[str, str]:
    """The ``key=value`` lines of a properties file (``#`` comments and blank lines skipped);
    HwBridgeError naming the file for one that cannot be read."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise HwBridgeError(f"{path}: cannot read: {exc}") from exc
    found: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        key, equals, value = stripped.partition("=")
        if not equals:
            raise HwBridgeError(f"{path}:{number}: expected key=value, got {stripped!r}")
        found[key.strip()] = value.strip()
    return found


def _check_properties(path: Path) -> None:
    props = read_properties(path)
    missing = [key for key in REQUIRED_PROPERTIES if not props.get(key)]
    if missing:
        raise HwBridgeError(f"{path}: missing {', '.join(missing)} (Arduino library format 1.5)")
    if props["name"] != TOP_FOLDER:
        raise HwBridgeError(f"{path}: name is {props['name']!r}, expected {TOP_FOLDER!r}")
    if props["category"] not in CATEGORIES:
        raise HwBridgeError(
            f"{path}: category {props['category']!r} is not one of {', '.join(CATEGORIES)}"
        )


def _kept(path: Path) -> bool:
    return not path.name.startswith(".") and path.suffix.lower() not in _SKIPPED_SUFFIXES


def _tree(folder: Path) -> Iterator[Path]:
    """The files under ``folder`` that belong in the library, sorted, skipped folders pruned."""
    for entry in sorted(folder.iterdir()):
        if entry.is_dir():
            if entry.name not in _SKIPPED_DIRS and not entry.name.startswith("."):
                yield from _tree(entry)
        elif entry.is_file() and _kept(entry):
            yield entry


def library_files(library: Path) -> list[Path]:
    """The files of the library at ``library`` that go into the zip, relative to it; a
    HwBridgeError for a folder that is not the library or an example without its NAME.ino."""
    if not (library / "src").is_dir():
        raise HwBridgeError(f"{library}: no src/ folder: not the HwBridge library")
    _check_properties(library / "library.properties")
    files = [Path(name) for name in _TOP_FILES if (library / name).is_file()]
    files += [p.relative_to(library) for p in _tree(library / "src")]
    examples = library / "examples"
    if examples.is_dir():
        for entry in sorted(examples.iterdir()):
            if entry.is_file() and _kept(entry):
                files.append(entry.relative_to(library))  # examples/README.md
            elif entry.is_dir() and not entry.name.startswith("."):
                if not (entry / f"{entry.name}.ino").is_file():
                    raise HwBridgeError(f"{entry}: an example needs {entry.name}.ino in it")
                files += [p.relative_to(library) for p in _tree(entry)]
    return files


def write_library_zip(out: Path, library: Path | None = None) -> list[str]:
    """Write the library (default the one ``hwbridge firmware build`` uses) to the zip ``out``
    (its folder is made); returns the names of the files written into it."""
    if library is None:
        from hwbridge.firmware.build import LIBRARY_DIR

        library = LIBRARY_DIR
    files = library_files(library)
    folders = sorted({str(parent) for f in files for parent in f.parents if str(parent) != "."})
    names: list[str] = []
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        partial = out.with_name(out.name + ".part")
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(_entry(f"{TOP_FOLDER}/", 0o40755), b"")
            for folder in folders:
                archive.writestr(_entry(f"{TOP_FOLDER}/{folder}/", 0o40755), b"")
            for rel in files:
                name = f"{TOP_FOLDER}/{rel.as_posix()}"
                info = _entry(name, 0o100644)
                info.compress_type = zipfile.ZIP_DEFLATED
                archive.writestr(info, (library / rel).read_bytes())
                names.append(name)
        partial.replace(out)
    except OSError as exc:
        raise HwBridgeError(f"{out}: cannot write the library zip: {exc}") from exc
    return names


def _entry(name: str, mode: int) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name, date_time=_DATE)
    info.external_attr = mode << 16
    if name.endswith("/"):
        info.external_attr |= 0x10  # MS-DOS directory flag
    return info
