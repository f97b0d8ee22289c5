"""Uploading firmware to a board's serial bootloader with avrdude (``hwbridge firmware upload``).

:func:`prepare_image` turns what the user gives (a sketch folder, an ELF, an Intel HEX) into a
checked Intel HEX; :func:`check_port` refuses a port that does not exist or that another
program holds (pyserial's lock, which ``hwbridge connect`` takes); :class:`Upload` runs avrdude,
tells each step as avrdude reaches it, turns its failures into one clear sentence, and can be
stopped from another thread (Ctrl-C: the avrdude process is killed).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import select
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from hwbridge.errors import HwBridgeError
from hwbridge.firmware import build
from hwbridge.firmware.checks import FirmwareTarget, check_elf, check_hex
from hwbridge.firmware.children import follow_parent
from hwbridge.firmware.sim.bootloader import HEX_SUFFIXES, is_intel_hex

__all__ = [
    "AVRDUDE_PACKAGE",
    "PROGRAMMERS",
    "PortBusyError",
    "Programmer",
    "Upload",
    "UploadError",
    "check_port",
    "prepare_image",
]

AVRDUDE_PACKAGE: Final = "avrdude"
"""The Debian package with avrdude."""

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Programmer:
    """How avrdude talks to a board's bootloader."""

    part: str
    programmer: str
    """avrdude's ``-c``: the bootloader's protocol as Arduino's boards.txt names it
    (``upload.protocol``)."""
    baud: int
    """boards.txt's ``upload.speed``."""
    sync_attempts: bool
    """Whether avrdude's programmer takes ``-x attempts=N`` (STK500 v1's does; ``wiring``
    refuses the option, and its stk500v2 sync retries by itself)."""


PROGRAMMERS: Final = {
    "uno": Programmer("atmega328p", "arduino", 115200, True),  # Optiboot (STK500 v1)
    "mega": Programmer("atmega2560", "wiring", 115200, False),  # stk500v2 with the DTR reset
}
_ATTEMPTS: Final = 4
"""avrdude's tries to get in sync (each resets the board again; about 6 s each)."""


class UploadError(HwBridgeError):
    """The upload failed (the message says why, in one sentence)."""


def _no_progress(line: str) -> None:
    del line


def prepare_image(
    target: Path, board: str, workdir: Path, *, progress: Progress = _no_progress
) -> Path:
    """The Intel HEX to upload for ``target``: a sketch folder (or ``.ino``) is built for
    ``board``, an ELF converted (avr-objcopy, into ``workdir``), a HEX used as it is. The HEX
    is checked (record checksums, and that it fits the flash the bootloader leaves)."""
    if board not in PROGRAMMERS:
        raise UploadError(f"unknown board {board!r}: {' or '.join(PROGRAMMERS)}")
    if not target.exists():
        raise UploadError(f"no such sketch, ELF or HEX file: {target}")
    suffix = target.suffix.lower()
    if target.is_dir() or suffix == ".ino":
        elf = build.build_sketch(target, board, progress=progress)
        image = elf.with_suffix(".hex")
        progress(f"built {image}")
    elif suffix == ".elf":
        check_elf(target, _target(board))
        objcopy = shutil.which("avr-objcopy")
        if objcopy is None:
            raise UploadError("avr-objcopy is not installed (apt-get install binutils-avr)")
        image = workdir / (target.stem + ".hex")
        done = subprocess.run(
            [objcopy, "-O", "ihex", "-R", ".eeprom", str(target), str(image)],
            capture_output=True,
            text=True,
            check=False,
        )
        if done.returncode != 0:
            raise UploadError(f"cannot convert {target} to Intel HEX: {done.stderr.strip()}")
    elif is_intel_hex(target):
        image = target
    else:
        raise UploadError(
            f"{target}: give a sketch folder, an .elf or an Intel HEX file "
            f"({', '.join(HEX_SUFFIXES)})"
        )
    check_hex(image, _target(board))
    return image


def _target(board: str) -> FirmwareTarget:
    """The board ``board`` (a key of :data:`PROGRAMMERS`) as the firmware checks see it: an ELF
    built for another MCU would be written and run as garbage, a HEX must fit the flash the
    board's bootloader leaves."""
    part = PROGRAMMERS[board].part
    choices: dict[str, str] = {}
    for name, programmer in PROGRAMMERS.items():
        choices.setdefault(programmer.part, name)
    return FirmwareTarget(
        mcu=part,
        name=f"the {board}'s {part}",
        verb="upload",
        option="--board",
        value=board,
        choices=choices,
        space={name: build.BOARDS[name].flash for name in PROGRAMMERS},
        space_name=f"of flash the {board}'s bootloader leaves",
        error=UploadError,
    )


def _port_path(port: str) -> Path:
    return Path(port.removeprefix("serial://").split("?", 1)[0])


class PortBusyError(UploadError):
    """Another process holds the port; ``pid`` is the lock's holder (None: not known)."""

    def __init__(self, message: str, path: Path, pid: int | None, holder: str = "") -> None:
        super().__init__(message)
        self.path = path
        self.pid = pid
        self.holder = holder
        """``pid N: its command line`` ('' when not known)."""


def _lock_holder(path: Path) -> tuple[int | None, str]:
    """Who holds the flock on ``path``, from /proc/locks: the pid and ``pid N: command``, or
    (None, '')."""
    try:
        inode = path.resolve().stat().st_ino
        rows = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None, ""
    for row in rows:
        words = row.split()
        if len(words) > 5 and words[1] == "FLOCK" and words[5].endswith(f":{inode}"):
            pid = words[4]
            try:
                raw = Path(f"/proc/{pid}/cmdline").read_bytes()
                command = " ".join(raw.decode(errors="replace").split("\0")).strip()
            except OSError:
                command = ""
            number = int(pid) if pid.isdigit() else None
            return number, f"pid {pid}" + (f": {command[:120]}" if command else "")
    return None, ""


def check_port(port: str) -> Path:
    """The serial port's path, once it is known to exist and to be free: raises
    :class:`UploadError` when it does not exist or another program holds it (the lock
    pyserial takes, as ``hwbridge connect`` does)."""
    path = _port_path(port)
    if not path.exists():
        raise UploadError(f"no such port: {path}")
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError as exc:
        if exc.errno == errno.EBUSY:
            raise UploadError(f"port {path} is busy: another program has it open") from exc
        raise UploadError(f"cannot open port {path}: {exc.strerror}") from exc
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
            raise UploadError(f"cannot lock port {path}: {exc.strerror}") from exc
        pid, holder = _lock_holder(path)
        raise PortBusyError(
            f"port {path} is busy: another process has it open"
            + (f" ({holder})" if holder else "")
            + " - a running bridge ('hwbridge connect') or a serial monitor? stop it first",
            path,
            pid,
            holder,
        ) from None
    finally:
        os.close(fd)  # closing drops the lock
    return path


_STEPS: Final = (
    (re.compile(r"device initialized|device signature"), "reset"),
    (re.compile(r"writing (?:\d+ bytes )?flash|writing output file|erasing chip"), "write"),
    (re.compile(r"verifying flash|reading on-chip flash data"), "verify"),
)
_NO_ANSWER: Final = re.compile(
    r"not in sync|not responding|unable to open programmer|stk500v2_getsync|timeout", re.I
)
_OUT_OF_STEP: Final = re.compile(r"protocol expects|programmer is out of sync", re.I)
"""The bootloader answered, then its replies stopped matching avrdude's requests."""
_MISMATCH: Final = re.compile(r"verification (?:error|mismatch)|mismatch", re.I)


SILENCE_LIMIT: Final = 60.0
"""avrdude prints its retries, its progress bars and its errors; a run silent this long is stuck
(seen: avrdude spinning for half an hour on a pty whose simulator had gone)."""


class Upload:
    """avrdude writing ``image`` into ``port``'s board through its bootloader, with verify."""

    silence_limit: float = SILENCE_LIMIT
    """Seconds avrdude may write nothing before it is taken for stuck (ended, an error)."""

    def __init__(
        self, image: Path, port: Path, board: str = "uno", *, progress: Progress = _no_progress
    ) -> None:
        self.image = image
        self.port = port
        self.programmer = PROGRAMMERS[board]
        self.progress = progress
        self.output: list[str] = []
        self._process: subprocess.Popen[bytes] | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()

    @property
    def stopped(self) -> bool:
        """Whether :meth:`stop` was called."""
        return self._stop.is_set()

    def command(self, avrdude: str) -> list[str]:
        p = self.programmer
        return [
            avrdude,
            "-p", p.part,
            "-c", p.programmer,
            "-P", str(self.port),
            "-b", str(p.baud),
            "-D",
            *(["-x", f"attempts={_ATTEMPTS}"] if p.sync_attempts else []),
            "-U", f"flash:w:{self.image}:i",
        ]  # fmt: skip

    def run(self) -> None:
        """Upload and verify; raises :class:`UploadError` (or returns early after :meth:`stop`,
        with :attr:`stopped` set)."""
        avrdude = shutil.which("avrdude")
        if avrdude is None:
            raise UploadError(
                f"avrdude is not installed: install the Debian package {AVRDUDE_PACKAGE} "
                f"(sudo apt-get install {AVRDUDE_PACKAGE})"
            )
        self.progress(f"reset: {self.port} (waiting for the bootloader)")
        with self._lock:
            if self._stop.is_set():
                return
            self._process = subprocess.Popen(
                follow_parent(self.command(avrdude)),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                start_new_session=True,  # its own group: stop() ends it and nothing else
            )
        process = self._process
        assert process.stdout is not None
        seen: set[str] = set()
        pending = b""
        stuck = False
        heard = time.monotonic()
        fd = process.stdout.fileno()
        while True:
            ready, _, _ = select.select([fd], [], [], 1.0)
            if not ready:
                if time.monotonic() - heard > self.silence_limit:
                    stuck = True
                    self._end(process)
                    break
                continue
            chunk = os.read(fd, 4096)
            if not chunk:
                break
            heard = time.monotonic()
            pending += chunk
            *lines, pending = re.split(rb"[\r\n]", pending)
            for raw in lines:
                self._line(raw.decode(errors="replace").strip(), seen)
        self._line(pending.decode(errors="replace").strip(), seen)
        code = process.wait()
        if self._stop.is_set():
            return
        if stuck:
            raise UploadError(
                f"avrdude wrote nothing for {self.silence_limit:g} s and was ended: the board on "
                f"{self.port} stopped answering mid-upload (unplugged, or a simulator that went "
                "away); plug it in again and upload again"
            )
        if code != 0:
            raise UploadError(self.explain_failure(code))
        self.progress(f"done: {self.image.name} written to {self.port} and verified")

    def _line(self, line: str, seen: set[str]) -> None:
        if not line or (line.startswith(("Writing |", "Reading |")) and "100%" not in line):
            return
        self.output.append(line)
        for pattern, step in _STEPS:
            if step not in seen and pattern.search(line):
                seen.add(step)
                if step == "reset":
                    self.progress("reset: the bootloader answered")
                elif step == "write":
                    self.progress(f"write: {self.image.name}")
                else:
                    self.progress("verify: reading the flash back")

    def explain_failure(self, code: int) -> str:
        """One sentence for a failed avrdude run (exit status ``code``), from its output."""
        text = "\n".join(self.output)
        errors = [line for line in self.output if "error" in line.lower()]
        if _MISMATCH.search(text):
            detail = next((line for line in errors if "mismatch" in line.lower()), "")
            return (
                f"verify mismatch: the flash read back from the board on {self.port} differs "
                f"from {self.image}"
                + (f" ({detail.removeprefix('avrdude error: ')})" if detail else "")
            )
        if re.search(r"can't open device|no such file", text, re.I) and not self.port.exists():
            return f"no such port: {self.port}"
        if _OUT_OF_STEP.search(text):
            detail = next((line for line in errors if _OUT_OF_STEP.search(line)), "")
            return (
                f"the board on {self.port} answered out of step with the bootloader protocol "
                f"({detail.removeprefix('avrdude error: ')}): it was reset during the upload, "
                "another program wrote to the port, or an application answered instead of a "
                "bootloader; try again"
            )
        if _NO_ANSWER.search(text):
            return f"no bootloader answered on {self.port}: check the port and the board"
        tail = "\n".join(self.output[-8:])
        return f"avrdude failed (exit status {code}):\n{tail}"

    def stop(self) -> None:
        """End avrdude at once (from any thread); :meth:`run` then returns."""
        with self._lock:
            self._stop.set()
            process = self._process
        if process is not None:
            self._end(process)

    @staticmethod
    def _end(process: subprocess.Popen[bytes]) -> None:
        if process.poll() is None:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(process.pid, signal.SIGKILL)
