"""ARM firmware in QEMU: :class:`QemuBoard` runs an ELF built for ``--board stm32f405`` or
``--board microbit`` in Debian's ``qemu-system-arm`` (``-M netduinoplus2`` or ``-M microbit``)
with the board's UART on a pseudo-terminal, as :class:`hwbridge.firmware.sim.SimAvr` runs an AVR.

QEMU is started with ``-display none -monitor none``, the first serial port on a ``pty``
character device, and QMP on a Unix socket in a temporary folder: the pty's path is asked there
(``query-chardev``), and :meth:`QemuBoard.reset` sends
``system_reset`` there (a board reset: the firmware starts again from its reset vector, the pty
stays). :meth:`QemuBoard.close` (also at exit of a ``with`` block, and on Ctrl-C in
``hwbridge firmware sim``) stops QEMU: SIGTERM, then SIGKILL after a grace period.
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
import shutil
import socket
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from types import TracebackType
from typing import Final

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.build import ARM_BOARDS
from hwbridge.firmware.children import follow_parent

__all__ = ["DEBIAN_PACKAGE", "QemuBoard", "QemuError", "QemuMissingError", "run_semihosted"]

log = logging.getLogger("hwbridge.firmware.qemu")

DEBIAN_PACKAGE: Final = "qemu-system-arm"
_PTY_NAME: Final = re.compile(r"pty:(/dev/pts/\d+)")


class QemuError(HwBridgeError):
    """QEMU could not start, or stopped."""


class QemuMissingError(QemuError):
    """qemu-system-arm is not installed."""


def _qemu() -> str:
    found = shutil.which("qemu-system-arm")
    if found is None:
        raise QemuMissingError(
            f"qemu-system-arm is not installed: install the Debian package {DEBIAN_PACKAGE} "
            f"(apt-get install {DEBIAN_PACKAGE})"
        )
    return found


def _machine(board: str) -> str:
    known = ARM_BOARDS.get(board)
    if known is None:
        raise QemuError(f"unknown ARM board {board!r}; use one of {', '.join(ARM_BOARDS)}")
    return known.qemu_machine


class QemuBoard:
    """One ARM board in QEMU; :attr:`link_url` is its UART's ``serial:///dev/pts/N``."""

    def __init__(self, elf: Path, board: str, *, start_timeout: float = 30.0) -> None:
        if not elf.is_file():
            raise QemuError(f"{elf}: no such ELF file")
        self.elf = elf
        self.board = board
        self.machine = _machine(board)
        self.start_timeout = start_timeout
        self.pty: str | None = None
        self._process: subprocess.Popen[str] | None = None
        self._folder: str | None = None
        self._stderr: list[str] = []
        self._reader: threading.Thread | None = None

    @property
    def link_url(self) -> str:
        if self.pty is None:
            raise QemuError("QEMU is not running")
        return f"serial://{self.pty}"

    @property
    def pid(self) -> int | None:
        """The QEMU process's id, None when it is not running (a test stops it with SIGSTOP to
        stand for a busy machine)."""
        process = self._process
        return None if process is None or process.poll() is not None else process.pid

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    @property
    def exit_code(self) -> int | None:
        return None if self._process is None else self._process.poll()

    def start(self) -> QemuBoard:
        """Starts QEMU and waits for the pty's path (at most ``start_timeout`` seconds)."""
        qemu = _qemu()
        self._folder = tempfile.mkdtemp(prefix="hwbridge-qemu-")
        qmp = Path(self._folder) / "qmp.sock"
        command = [
            qemu,
            "-M",
            self.machine,
            "-display",
            "none",
            "-monitor",
            "none",
            "-chardev",
            "pty,id=uart",
            "-serial",
            "chardev:uart",
            "-qmp",
            f"unix:{qmp},server=on,wait=off",
            "-kernel",
            str(self.elf),
        ]
        log.debug("starting %s", " ".join(command))
        self._process = subprocess.Popen(
            follow_parent(command),  # a killed hwbridge leaves no QEMU behind
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,  # Ctrl-C in a terminal reaches us, and we stop QEMU
        )
        self._reader = threading.Thread(
            target=self._read_stderr, args=(self._process,), daemon=True
        )
        self._reader.start()
        deadline = time.monotonic() + self.start_timeout
        while self.pty is None:
            if self._process.poll() is not None or time.monotonic() > deadline:
                self.close()
                why = "".join(self._stderr).strip() or "no pty reported"
                raise QemuError(f"qemu-system-arm -M {self.machine} did not start: {why}")
            if qmp.exists():
                with contextlib.suppress(OSError, ValueError):
                    self.pty = self._pty_path()
            if self.pty is None:
                time.sleep(0.05)
        return self

    def _pty_path(self) -> str | None:
        answer = self.qmp("query-chardev")
        devices = answer.get("return")
        for device in devices if isinstance(devices, list) else []:
            if isinstance(device, dict) and device.get("label") == "uart":
                found = _PTY_NAME.search(str(device.get("filename", "")))
                if found:
                    return found.group(1)
        return None

    def _read_stderr(self, process: subprocess.Popen[str]) -> None:
        assert process.stderr is not None
        with contextlib.suppress(ValueError, OSError):  # closed by close() after a kill
            for line in process.stderr:
                self._stderr.append(line)
                log.info("qemu: %s", line.rstrip())

    def qmp(
        self, command: str, timeout: float = 10.0, arguments: dict[str, object] | None = None
    ) -> dict[str, object]:
        """Runs one QMP command (with ``arguments``); returns its answer (``{"return": ...}``)."""
        if self._folder is None or self._process is None or self._process.poll() is not None:
            raise QemuError("QEMU is not running")
        path = str(Path(self._folder) / "qmp.sock")
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(timeout)
            sock.connect(path)
            reader = sock.makefile("r", encoding="utf-8")
            json.loads(reader.readline())  # the greeting
            call: dict[str, object] = {"execute": command}
            if arguments is not None:
                call["arguments"] = arguments
            for text in ({"execute": "qmp_capabilities"}, call):
                sock.sendall((json.dumps(text) + "\n").encode())
                while True:
                    answer: dict[str, object] = json.loads(reader.readline())
                    if "event" not in answer:
                        break
                if "error" in answer:
                    raise QemuError(f"QMP {text['execute']}: {answer['error']}")
            return answer

    def reset(self) -> None:
        """A board reset (QMP ``system_reset``): the firmware starts again; the pty stays."""
        self.qmp("system_reset")

    def peek(self, address: int, size: int) -> bytes:
        """``size`` bytes of the board's memory from the physical ``address`` (the monitor's
        ``xp``), read while it runs."""
        answer = self.qmp(
            "human-monitor-command", arguments={"command-line": f"xp /{size}xb {address:#x}"}
        )
        text = answer.get("return")
        if not isinstance(text, str):
            raise QemuError(f"xp at {address:#x}: no answer ({answer})")
        # lines such as "0000000020000154: 0x01 0x00 ..."
        values = [int(word, 16) for line in text.splitlines() for word in line.split()[1:]]
        if len(values) != size:
            raise QemuError(f"xp at {address:#x}: {size} bytes asked, got {text!r}")
        return bytes(values)

    def close(self) -> None:
        """Stops QEMU (SIGTERM, then SIGKILL after 5 s) and removes its socket folder."""
        process, self._process = self._process, None
        if process is not None and process.poll() is None:
            process.terminate()
            try:
                process.wait(5)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(5)
        if self._reader is not None:  # it ends at the end of QEMU's stderr
            self._reader.join(5)
        if process is not None and process.stderr is not None:
            with contextlib.suppress(OSError):
                process.stderr.close()
        if self._folder is not None:
            shutil.rmtree(self._folder, ignore_errors=True)
            self._folder = None

    def __enter__(self) -> QemuBoard:
        return self.start() if self._process is None else self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def run_semihosted(
    elf: Path,
    board: str,
    timeout: float = 120.0,
    *,
    serial_file: Path | None = None,
    run_for: float | None = None,
) -> subprocess.CompletedProcess[str]:
    """Runs a test program built with semihosting (``rdimon``) to its end: its stdout and stderr
    are QEMU's, its exit code QEMU's. The UART goes to ``serial_file`` (or nowhere). With
    ``run_for``, a program still running after that many seconds (stopped in a fault handler)
    is stopped, and what it wrote is returned with exit code -15."""
    command = [
        _qemu(),
        "-M",
        _machine(board),
        "-display",
        "none",
        "-monitor",
        "none",
        "-serial",
        f"file:{serial_file}" if serial_file is not None else "null",
        "-semihosting-config",
        "enable=on,target=native",
        "-kernel",
        str(elf),
    ]
    process = subprocess.Popen(
        command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        stdout, stderr = process.communicate(timeout=run_for if run_for is not None else timeout)
    except subprocess.TimeoutExpired:
        process.terminate()
        try:
            stdout, stderr = process.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            stdout, stderr = process.communicate()
        if run_for is None:
            raise QemuError(
                f"{elf.name} did not finish in {timeout:.0f} s:\n{stdout}{stderr}"
            ) from None
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    return subprocess.CompletedProcess(command, process.returncode, stdout, stderr)
