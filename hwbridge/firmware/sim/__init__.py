"""AVR firmware in simavr: the runner (a small C program against Debian's libsimavr), built on
first use and cached, and :class:`SimAvr`, the Python side that starts it and talks to it.

The runner loads an ELF (or an Intel HEX: a file named as one, ``.hex``, ``.ihex`` or ``.ihx``
as :data:`~hwbridge.firmware.sim.bootloader.HEX_SUFFIXES` says, which :class:`SimAvr` tells the
runner with ``--hex``) for an ATmega328P or ATmega2560, puts UART0 on a pseudo-terminal (its URL,
``serial:///dev/pts/N``, is its first line of output), holds the simulation to the wall clock (or
a stated speed-up), and carries the devices on the MCU's pins through a line protocol on its
stdin and stdout (see ``runner.c``): watched output
pins report their duty every report period together with the simulated time, input pins are
driven, quadrature encoders are moved to a position (the edges spread over the next period),
HC-SR04 triggers are answered with an echo of a set width, and I2C register files answer on
the TWI bus (the firmware's writes are reported). :mod:`hwbridge.emulator.pins` puts the
emulator's world on these pins.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import shutil
import struct
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Final

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.sim.bootloader import is_intel_hex

__all__ = [
    "DEBIAN_PACKAGES",
    "MCUS",
    "SimAvr",
    "SimError",
    "SimToolchainMissingError",
    "Tick",
    "UartBytes",
    "arduino_pin",
    "read_pc_trace",
    "read_uart_trace",
    "runner_binary",
]

log = logging.getLogger("hwbridge.firmware.sim")

SOURCE: Final = Path(__file__).with_name("runner.c")
DEBIAN_PACKAGES: Final = "simavr libsimavr-dev libsimavrparts1 libelf-dev gcc"
"""What building the runner needs (apt-get install ...)."""
MCUS: Final = ("atmega328p", "atmega2560")
_HEADERS: Final = Path("/usr/include/simavr")
_LIBS: Final = ("-lsimavr", "-lsimavrparts", "-lelf", "-lpthread", "-lutil")


class SimError(HwBridgeError):
    """The simulation could not start, or stopped."""


class SimToolchainMissingError(SimError):
    """simavr's development files or a C compiler are missing."""


def _cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hwbridge" / "simavr-runner"


def runner_binary(*, cache: Path | None = None) -> Path:
    """The runner's executable: built from ``runner.c`` on first use, cached under
    ``~/.cache/hwbridge/simavr-runner/<hash of the source>/``."""
    source = SOURCE.read_bytes()
    key = hashlib.sha256(source + b"\0" + " ".join(_LIBS).encode()).hexdigest()[:16]
    folder = (cache or _cache_root()) / key
    binary = folder / "hwbridge-simavr"
    if binary.exists():
        return binary
    compiler = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
    if compiler is None or not (_HEADERS / "sim_avr.h").exists():
        raise SimToolchainMissingError(
            "the simavr runner cannot be built: install the Debian packages "
            f"{DEBIAN_PACKAGES} (apt-get install {DEBIAN_PACKAGES})"
        )
    folder.mkdir(parents=True, exist_ok=True)
    partial = folder / f"hwbridge-simavr.{os.getpid()}.tmp"
    command = [
        compiler,
        "-std=gnu11",
        "-O2",
        "-Wall",
        "-Wextra",
        "-Werror",
        "-isystem",
        str(_HEADERS),
        "-o",
        str(partial),
        str(SOURCE),
        *_LIBS,
    ]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        missing = "cannot find -l" in done.stderr or "No such file" in done.stderr
        if missing:
            raise SimToolchainMissingError(
                "the simavr runner cannot be built: install the Debian packages "
                f"{DEBIAN_PACKAGES} (apt-get install {DEBIAN_PACKAGES})"
            )
        raise SimError(f"building the simavr runner failed:\n{done.stderr.strip()}")
    partial.replace(binary)  # atomic: concurrent first uses each build, one wins
    log.info("built the simavr runner: %s", binary)
    return binary


# ---------------------------------------------------------------------- pins
_MEGA_PINS: Final[dict[int, str]] = {
    0: "E0", 1: "E1", 2: "E4", 3: "E5", 4: "G5", 5: "E3", 6: "H3", 7: "H4", 8: "H5", 9: "H6",
    10: "B4", 11: "B5", 12: "B6", 13: "B7", 14: "J1", 15: "J0", 16: "H1", 17: "H0", 18: "D3",
    19: "D2", 20: "D1", 21: "D0", 38: "D7", 39: "G2", 40: "G1", 41: "G0", 50: "B3", 51: "B2",
    52: "B1", 53: "B0",
    **{22 + i: f"A{i}" for i in range(8)},
    **{30 + i: f"C{7 - i}" for i in range(8)},
    **{42 + i: f"L{7 - i}" for i in range(8)},
    **{54 + i: f"F{i}" for i in range(8)},
    **{62 + i: f"K{i}" for i in range(8)},
}  # fmt: skip


def arduino_pin(pin: int | str, mcu: str = "atmega328p") -> str:
    """An Arduino pin number (or ``"A0"``) as the runner names it: port letter and bit (``D2``).

    A name already in that form (``"PD2"`` or ``"D2"`` for the port) is given back without
    ``P``; plain numbers follow the Uno's or the Mega's pin map."""
    if isinstance(pin, str):
        text = pin.strip().upper()
        if text.startswith("P") and len(text) == 3:
            return text[1:]
        if text.startswith("A") and text[1:].isdigit():
            number = int(text[1:]) + (14 if mcu == "atmega328p" else 54)
        elif text.isdigit():
            number = int(text)
        else:
            raise SimError(f"not a pin: {pin!r} (an Arduino number, A0.., or a port bit like PD2)")
    else:
        number = pin
    if mcu == "atmega328p":
        if 0 <= number <= 7:
            return f"D{number}"
        if 8 <= number <= 13:
            return f"B{number - 8}"
        if 14 <= number <= 19:
            return f"C{number - 14}"
    elif number in _MEGA_PINS:
        return _MEGA_PINS[number]
    raise SimError(f"{mcu} has no Arduino pin {pin!r}")


# ---------------------------------------------------------------------- the process
@dataclass(frozen=True)
class Tick:
    """One report of the runner: simulated time (s since power-on) and each watched output
    pin's duty (share of the period it was high) by port-bit name."""

    time: float
    duty: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class UartBytes:
    """One line of a ``--trace-uart`` log (see ``runner.c``)."""

    into_avr: bool
    """True: bytes the runner read from the pty and handed to the UART at ``cycle`` (the UART
    delivers them to the firmware one per byte time from then on); False: one byte the
    firmware wrote to the UART's data register at ``cycle`` (the next write waits a byte
    time)."""
    cycle: int
    """The AVR's cycle count (cycles since power-on)."""
    data: bytes


def read_uart_trace(path: Path | str) -> list[UartBytes]:
    """The lines of a ``--trace-uart`` log (a last line still being written is left out)."""
    entries: list[UartBytes] = []
    for line in Path(path).read_text().splitlines():
        parts = line.split()
        if len(parts) != 3 or parts[0] not in ("i", "o"):
            continue
        try:
            entries.append(UartBytes(parts[0] == "i", int(parts[1]), bytes.fromhex(parts[2])))
        except ValueError:
            continue
    return entries


def read_pc_trace(path: Path | str) -> list[tuple[int, int]]:
    """The records of a ``--trace-pc`` log: (cycle count before the instruction, its byte
    address in flash), in order (a record still being written is left out)."""
    data = Path(path).read_bytes()
    whole = len(data) - len(data) % 12
    return [(cycle, pc) for cycle, pc in struct.iter_unpack("<QI", data[:whole])]


class SimAvr:
    """The runner with one ``firmware``: an ELF, or an Intel HEX (a file named as one:
    ``.hex``, ``.ihex``, ``.ihx``). ``start()`` returns once the UART's pty exists (:attr:`url`);
    with ``hold`` the AVR waits until :meth:`go` so that devices are in place before it boots.

    With ``bootloader`` (an Intel HEX, see :func:`~hwbridge.firmware.sim.bootloader.optiboot_hex`)
    the CPU starts at the bootloader, each open of the pty resets the AVR into it (an Uno's
    auto-reset), and ``firmware`` (an ELF or an Intel HEX, or None) is the application already
    in flash: upload another one through the pty with avrdude.

    Callbacks run on the reader thread, in the order the runner reported: ``on_tick(tick)``,
    ``on_i2c_write(address, register, data)``, ``on_uart(name, packet)``, ``on_reset()`` and
    ``on_exit(state)``."""

    def __init__(
        self,
        firmware: Path | str | None,
        *,
        bootloader: Path | str | None = None,
        mcu: str = "atmega328p",
        frequency: int = 16_000_000,
        speed: float = 1.0,
        report_us: int = 5000,
        symlink: Path | str | None = None,
        trace_uart: Path | str | None = None,
        trace_pc: Path | str | None = None,
    ) -> None:
        if mcu not in MCUS:
            raise SimError(f"unknown MCU {mcu!r}: choose {' or '.join(MCUS)}")
        self.firmware = Path(firmware) if firmware is not None else None
        """The application: an ELF, or an Intel HEX (the runner is told ``--hex``)."""
        if self.firmware is not None and not self.firmware.is_file():
            raise SimError(f"no firmware at {self.firmware}")
        self.bootloader = Path(bootloader) if bootloader is not None else None
        if self.bootloader is None and self.firmware is None:
            raise SimError("no firmware to run")
        if self.bootloader is not None and not self.bootloader.is_file():
            raise SimError(f"no bootloader at {self.bootloader}")
        self.mcu = mcu
        self.frequency = frequency
        self.speed = speed
        self.report_us = report_us
        self.symlink = Path(symlink) if symlink is not None else None
        """A path kept pointing at the current pty, across :meth:`restart` (which makes a new
        pty): give the bridge ``serial://SYMLINK`` and it finds the board again."""
        self.trace_uart = Path(trace_uart) if trace_uart is not None else None
        """Where the runner logs every UART0 byte with the AVR's cycle count (``--trace-uart``
        in ``runner.c``; :func:`read_uart_trace` reads it)."""
        self.trace_pc = Path(trace_pc) if trace_pc is not None else None
        """Where the runner logs every instruction from each read of the pty to the next byte
        the firmware sends (``--trace-pc``; :func:`read_pc_trace` reads it)."""
        self.url = ""
        self.time = 0.0
        """Simulated seconds since power-on, as of the last report."""
        self.resets = 0
        self.exited: str | None = None
        self.on_tick: list[Callable[[Tick], None]] = []
        self.on_i2c_write: list[Callable[[int, int, bytes], None]] = []
        self.on_uart: list[Callable[[str, bytes], bytes | None]] = []
        """A packet on a bus UART (``bus N``): return the reply, or None; the AVR waits for
        it. The first callback that answers (not None) gives the reply."""
        self.on_reset: list[Callable[[], None]] = []
        self.on_exit: list[Callable[[str], None]] = []
        self.on_start: list[Callable[[], None]] = []
        """Run after each start (and restart) while the AVR is held: set devices up here."""
        self.restarts = 0
        self.callback_errors = 0
        self._process: subprocess.Popen[str] | None = None
        self._reader: threading.Thread | None = None
        self._write_lock = threading.Lock()
        self._stopping = False
        """Set when :meth:`close` begins: the runner may still report ticks it ran before."""
        self._ticked = threading.Condition()
        self._peeked: dict[int, bytes | None] = {}
        """Answers of the runner to ``peek``, by address, until :meth:`peek` takes them."""

    # ------------------------------------------------------------------ life
    def start(self, *, hold: bool = False) -> SimAvr:
        binary = runner_binary()
        command = [
            str(binary),
            "--mcu",
            self.mcu,
            "--freq",
            str(self.frequency),
            "--speed",
            repr(float(self.speed)),
            "--report-us",
            str(self.report_us),
            "--hold",
            *(["--bootloader", str(self.bootloader)] if self.bootloader is not None else []),
            *(["--trace-uart", str(self.trace_uart)] if self.trace_uart is not None else []),
            *(["--trace-pc", str(self.trace_pc)] if self.trace_pc is not None else []),
            *(["--hex"] if self.firmware is not None and is_intel_hex(self.firmware) else []),
            *([str(self.firmware)] if self.firmware is not None else []),
        ]
        self._process = subprocess.Popen(
            command,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        stdout = self._process.stdout
        assert stdout is not None
        first = stdout.readline().strip()
        if not first.startswith("serial://"):
            error = self._stderr_text()
            self.close()
            raise SimError(f"the simavr runner did not start: {error or first or 'no output'}")
        self.url = first
        self.time = 0.0
        self.exited = None
        if self.symlink is not None:
            fresh = self.symlink.with_name(f".{self.symlink.name}.{os.getpid()}")
            fresh.unlink(missing_ok=True)
            fresh.symlink_to(self.path)
            fresh.replace(self.symlink)  # atomic: the old pty's path is never missing
        self._reader = threading.Thread(target=self._read, args=(stdout,), daemon=True)
        self._reader.name = "simavr-reader"
        self._reader.start()
        threading.Thread(target=self._drain_stderr, daemon=True, name="simavr-stderr").start()
        for setup in list(self.on_start):
            setup()
        if not hold:
            self.go()
        return self

    @property
    def link_url(self) -> str:
        """The URL to give the bridge: the symlink's when there is one, else the pty's."""
        return f"serial://{self.symlink}" if self.symlink is not None else self.url

    def restart(self) -> None:
        """Stop the simulation and start it again from power-on: a new process and a new pty
        (the symlink follows), devices set up again by the ``on_start`` callbacks."""
        self._stop()
        self.restarts += 1
        self.start()

    def _stderr_text(self) -> str:
        process = self._process
        if process is None or process.stderr is None:
            return ""
        try:
            process.wait(1)
        except subprocess.TimeoutExpired:
            return ""
        return " ".join(process.stderr.read().split())[:500]

    def _drain_stderr(self) -> None:
        process = self._process
        if process is None or process.stderr is None:
            return
        try:
            for line in process.stderr:
                text = line.rstrip()
                if text:
                    # The runner's lag behind real time matters to whoever talks to the board.
                    level = logging.WARNING if "behind real time" in text else logging.DEBUG
                    log.log(level, "simavr: %s", text.removeprefix("hwbridge-simavr: "))
        except (ValueError, OSError):  # close() closed the pipe while this thread read it
            return

    @property
    def path(self) -> str:
        """The UART's pseudo-terminal (``/dev/pts/N``)."""
        return self.url.removeprefix("serial://")

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    @property
    def exit_code(self) -> int | None:
        """The runner's exit status once it has ended (negative: the signal that ended it), else
        None."""
        return self._process.poll() if self._process is not None else None

    def command(self, line: str) -> None:
        """Send one command line to the runner (see ``runner.c``)."""
        process = self._process
        if process is None or process.stdin is None:
            raise SimError("the simulation is not running")
        with self._write_lock:
            try:
                process.stdin.write(line + "\n")
                process.stdin.flush()
            except (BrokenPipeError, ValueError, OSError) as exc:
                raise SimError(f"the simulation has stopped ({exc})") from exc

    def go(self) -> None:
        """Let a held AVR start running."""
        self.command("go")

    def reset(self) -> None:
        """Reset the AVR, as its reset pin does (the pty stays)."""
        self.command("reset")

    def peek(self, address: int, size: int, timeout: float = 10.0) -> bytes:
        """``size`` (1..64) bytes of the AVR's data space from ``address`` (an ELF symbol's
        address less 0x800000), read by the runner between two instructions."""
        if not 1 <= size <= 64:
            raise SimError(f"peek: {size} bytes (1..64 at a time)")
        with self._ticked:
            self._peeked.pop(address, None)
        self.command(f"peek {address:x} {size}")
        deadline = time.monotonic() + timeout
        with self._ticked:
            while address not in self._peeked:
                left = deadline - time.monotonic()
                if left <= 0 or not self.running:
                    raise SimError(f"the runner did not answer peek {address:#x}")
                self._ticked.wait(min(left, 0.5))
            data = self._peeked.pop(address)
        if data is None:
            raise SimError(f"peek {address:#x} {size}: outside the AVR's data space")
        return data

    def wait_time(self, seconds: float, timeout: float = 30.0) -> float:
        """Block until the simulated clock reaches ``seconds``; returns it."""
        deadline = time.monotonic() + timeout
        with self._ticked:
            while self.time < seconds:
                left = deadline - time.monotonic()
                if left <= 0 or not self.running:
                    raise SimError(
                        f"the simulation did not reach {seconds:.3f} s (at {self.time:.3f} s)"
                    )
                self._ticked.wait(min(left, 0.5))
        return self.time

    def close(self) -> None:
        """Stop the simulation (and remove the symlink, if it points at our pty)."""
        self._stop()
        link = self.symlink
        if link is not None and link.is_symlink() and str(link.readlink()) == self.path:
            link.unlink(missing_ok=True)

    def _stop(self) -> None:
        process = self._process
        if process is None:
            return
        self._stopping = True
        with contextlib.suppress(SimError):
            self.command("quit")
        try:
            process.wait(3)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(3)
        # The runner has exited: its stdout ends, so the reader finishes before we close it.
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(3)
        for stream in (process.stdin, process.stdout, process.stderr):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()

    def __enter__(self) -> SimAvr:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ events
    def _read(self, stdout: IO[str]) -> None:
        try:
            for line in stdout:
                self._handle(line)
        except (ValueError, OSError):  # closed under us (a stop from another thread)
            return

    def _handle(self, line: str) -> None:
        try:
            self._event(line.split())
        except SimError:
            if self._stopping:  # a model answering a last tick after "quit": nothing to tell
                return
            self._callback_failed(line)
        except Exception:  # noqa: BLE001 - a model's bug must not stop the reader
            self._callback_failed(line)

    def _callback_failed(self, line: str) -> None:
        """Count a failed event callback; the first is logged with its traceback (call it from
        an ``except`` block)."""
        self.callback_errors += 1
        if self.callback_errors == 1:
            log.exception("simavr: handling %r failed", line.strip())

    def _event(self, words: list[str]) -> None:
        if not words:
            return
        kind = words[0]
        if kind == "t":
            duty = {}
            for word in words[2:]:
                name, _, value = word.partition("=")
                duty[name] = float(value)
            tick = Tick(int(words[1]) / 1e6, duty)
            for handle in list(self.on_tick):
                handle(tick)
            with self._ticked:
                self.time = tick.time
                self._ticked.notify_all()
        elif kind == "i2cw" and len(words) == 4:
            address, register, data = int(words[1], 16), int(words[2], 16), bytes.fromhex(words[3])
            for handle_write in list(self.on_i2c_write):
                handle_write(address, register, data)
        elif kind == "uart" and len(words) == 3:
            name, data = words[1], bytes.fromhex(words[2])
            reply: bytes | None = None
            try:
                for handle_uart in list(self.on_uart):
                    reply = handle_uart(name, data)
                    if reply is not None:
                        break
            finally:  # the AVR is held until it has an answer
                self.command(f"tx {name} {reply.hex() if reply else '-'}")
        elif kind == "mem" and len(words) == 3:
            memory = None if words[2] == "-" else bytes.fromhex(words[2])
            with self._ticked:
                self._peeked[int(words[1], 16)] = memory
                self._ticked.notify_all()
        elif kind == "reset":
            self.resets += 1
            log.info("simavr: the AVR was reset")
            for handle_reset in list(self.on_reset):
                handle_reset()
        elif kind == "exit":
            self.exited = words[1] if len(words) > 1 else "done"
            log.warning("simavr: the AVR stopped (%s)", self.exited)
            for handle_exit in list(self.on_exit):
                handle_exit(self.exited)
