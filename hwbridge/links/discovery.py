"""Which serial ports there are, what is behind them, and the ``usb:`` and ``auto`` links.

``hwbridge board scan`` lists the ports that pyserial finds (``serial.tools.list_ports``), names
the board or USB-serial chip behind each by its USB vendor and product ID (:data:`KNOWN_USB_IDS`),
gives its stable ``/dev/serial/by-id/...`` name where udev made one, and with ``--probe`` asks
whether a hwbridge (native) or rosserial board answers there (:func:`probe_port`).

A robot file (or ``hwbridge up --link NAME=...``) may name a board by what it is rather than where
it is plugged in; :func:`resolve_link` turns these into a port when ``hwbridge up`` starts:

- ``usb:VID:PID`` or ``usb:VID:PID:SERIAL`` (hexadecimal IDs, as ``lsusb`` prints them): the one
  port with that USB ID (and serial number);
- ``auto``: the one port whose USB ID is in :data:`KNOWN_USB_IDS`.

Either may end with the serial link's options (``usb:2341:0043?baud=57600``). No match, or more
than one, is an error naming what was found. The port is given by its ``/dev/serial/by-id`` name
when it has one, so that the bridge finds the board again after it is unplugged and comes back
under another ``ttyACM`` number.

Listing is injectable (``comports``: any callable returning records with pyserial's
``ListPortInfo`` attributes, :class:`PortRecord`) so that it can be tested without USB devices.
"""

from __future__ import annotations

import os
import re
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Protocol

from hwbridge.errors import HwBridgeError, LinkError

__all__ = [
    "AUTO",
    "BY_ID_DIR",
    "KNOWN_USB_IDS",
    "PortRecord",
    "ProbeResult",
    "Resolved",
    "SerialPort",
    "UsbSelector",
    "by_id_names",
    "describe_usb_id",
    "is_usb_link",
    "list_serial_ports",
    "parse_usb_link",
    "probe_port",
    "resolve_link",
    "resolve_links",
]

AUTO: Final = "auto"
"""The link that means "the one port with a known board behind it"."""
BY_ID_DIR: Final = Path("/dev/serial/by-id")
"""Where udev (Linux) puts stable names of USB serial ports, as symlinks to the tty devices."""

KNOWN_USB_IDS: Final[dict[tuple[int, int], str]] = {
    # Arduino's own USB IDs, from the AVR core's boards.txt (the 2A03 ones are arduino.org's).
    (0x2341, 0x0043): "Arduino Uno (ATmega16U2 USB-serial)",
    (0x2A03, 0x0043): "Arduino Uno (ATmega16U2 USB-serial)",
    (0x2341, 0x0001): "Arduino Uno (ATmega8U2 USB-serial)",
    (0x2341, 0x0243): "Arduino Uno R3 (ATmega16U2 USB-serial)",
    (0x2341, 0x006A): "Arduino Uno",
    (0x2341, 0x0010): "Arduino Mega 2560 (ATmega8U2 USB-serial)",
    (0x2341, 0x0042): "Arduino Mega 2560 R3 (ATmega16U2 USB-serial)",
    (0x2A03, 0x0010): "Arduino Mega 2560",
    (0x2A03, 0x0042): "Arduino Mega 2560 R3",
    (0x2341, 0x0036): "Arduino Leonardo (bootloader)",
    (0x2341, 0x8036): "Arduino Leonardo",
    (0x2A03, 0x0036): "Arduino Leonardo (bootloader)",
    (0x2A03, 0x8036): "Arduino Leonardo",
    (0x2341, 0x0037): "Arduino Micro (bootloader)",
    (0x2341, 0x8037): "Arduino Micro",
    (0x2341, 0x0058): "Arduino Nano Every",
    # USB-serial chips on clones and other boards (a Nano is usually one of these).
    (0x1A86, 0x7523): "CH340 USB-serial (Nano or Uno clone, ESP board)",
    (0x1A86, 0x55D4): "CH9102 USB-serial (ESP32 board)",
    (0x0403, 0x6001): "FTDI FT232R USB-serial (Nano, Duemilanove, FTDI cable)",
    (0x0403, 0x6015): "FTDI FT231X USB-serial",
    (0x10C4, 0xEA60): "Silicon Labs CP210x USB-serial (ESP32 board)",
    (0x16C0, 0x0483): "Teensy (USB serial)",
    (0x303A, 0x1001): "ESP32-C3/S3 built-in USB-Serial/JTAG",
    (0x2E8A, 0x000A): "Raspberry Pi Pico (RP2040 USB serial)",
}
"""USB vendor and product IDs of boards and USB-serial chips, and what they usually are."""

_USB_RE: Final = re.compile(
    r"^(?i:usb):(?P<vid>[0-9A-Fa-f]{1,4}):(?P<pid>[0-9A-Fa-f]{1,4})(?::(?P<serial>[^?]+))?$"
)


class PortRecord(Protocol):
    """What :func:`list_serial_ports` reads of a port: pyserial's ``ListPortInfo`` attributes."""

    @property
    def device(self) -> str: ...
    @property
    def description(self) -> str: ...
    @property
    def vid(self) -> int | None: ...
    @property
    def pid(self) -> int | None: ...
    @property
    def serial_number(self) -> str | None: ...


@dataclass(frozen=True)
class SerialPort:
    """One serial port: its device, USB identity (None for a port that is not USB), what is
    usually behind that USB ID, and its stable ``/dev/serial/by-id`` name."""

    device: str
    description: str = ""
    vid: int | None = None
    pid: int | None = None
    serial_number: str | None = None
    board: str | None = None
    by_id: str | None = None

    @property
    def usb_id(self) -> str | None:
        """``VID:PID`` in hexadecimal (as lsusb writes it), None if not a USB port."""
        if self.vid is None or self.pid is None:
            return None
        return f"{self.vid:04x}:{self.pid:04x}"

    @property
    def path(self) -> str:
        """The name to open: the by-id one when there is one (it survives a replug)."""
        return self.by_id or self.device

    def describe(self) -> str:
        """``/dev/ttyACM0 (2341:0043 Arduino Uno..., serial N)``, for messages."""
        facts = [f for f in (self.usb_id, self.board or self.description) if f and f != "n/a"]
        if self.serial_number:
            facts.append(f"serial {self.serial_number}")
        return f"{self.device} ({' '.join(facts)})" if facts else self.device

    def as_dict(self) -> dict[str, Any]:
        return {
            "device": self.device,
            "by_id": self.by_id,
            "usb_id": self.usb_id,
            "vid": self.vid,
            "pid": self.pid,
            "serial_number": self.serial_number,
            "board": self.board,
            "description": self.description,
        }


@dataclass(frozen=True)
class UsbSelector:
    """A ``usb:VID:PID[:SERIAL]`` or ``auto`` link, parsed; ``query`` is the serial options."""

    vid: int | None
    pid: int | None
    serial_number: str | None = None
    query: str = ""

    @property
    def auto(self) -> bool:
        return self.vid is None

    def matches(self, port: SerialPort) -> bool:
        if self.auto:
            return port.board is not None
        if (port.vid, port.pid) != (self.vid, self.pid):
            return False
        return self.serial_number is None or port.serial_number == self.serial_number

    def __str__(self) -> str:
        if self.auto:
            return AUTO
        serial = f":{self.serial_number}" if self.serial_number else ""
        return f"usb:{self.vid:04x}:{self.pid:04x}{serial}"


def describe_usb_id(vid: int | None, pid: int | None) -> str | None:
    """What is usually behind a USB ID (:data:`KNOWN_USB_IDS`), None if unknown or not USB."""
    if vid is None or pid is None:
        return None
    return KNOWN_USB_IDS.get((vid, pid))


def by_id_names(folder: Path = BY_ID_DIR) -> dict[str, str]:
    """The stable names in ``folder`` by the device each points to (symlinks resolved); the first
    in sorted order when several point to one device. Empty if the folder does not exist."""
    try:
        entries = sorted(folder.iterdir())
    except OSError:
        return {}
    names: dict[str, str] = {}
    for entry in entries:
        try:
            target = os.path.realpath(entry)
        except OSError:
            continue
        names.setdefault(target, str(entry))
    return names


def _pyserial_comports() -> list[Any]:
    from serial.tools.list_ports import comports

    return list(comports())


def list_serial_ports(
    comports: Callable[[], Iterable[PortRecord]] | None = None, by_id_dir: Path = BY_ID_DIR
) -> list[SerialPort]:
    """The serial ports ``comports`` lists (default pyserial's), sorted by device, each with its
    USB identity, what is behind it and its by-id name."""
    records = list((comports or _pyserial_comports)())
    stable = by_id_names(by_id_dir)
    ports = []
    for record in records:
        device = str(record.device)
        vid, pid = record.vid, record.pid
        ports.append(
            SerialPort(
                device=device,
                description=str(record.description or ""),
                vid=vid,
                pid=pid,
                serial_number=record.serial_number or None,
                board=describe_usb_id(vid, pid),
                by_id=stable.get(os.path.realpath(device)),
            )
        )
    return sorted(ports, key=lambda p: p.device)


def is_usb_link(url: str) -> bool:
    """Whether ``url`` is a ``usb:`` or ``auto`` link (checked or not)."""
    base = url.strip().split("?", 1)[0]
    return base == AUTO or base.lower().startswith("usb:")


def parse_usb_link(url: str) -> UsbSelector | None:
    """The selector of a ``usb:VID:PID[:SERIAL]`` or ``auto`` link, None for any other URL;
    LinkError saying how to write it for a malformed ``usb:`` one."""
    if not is_usb_link(url):
        return None
    base, _, query = url.strip().partition("?")
    if base == AUTO:
        return UsbSelector(None, None, None, query)
    match = _USB_RE.match(base)
    if match is None:
        raise LinkError(
            f"{url!r} is not a USB link: write usb:VID:PID or usb:VID:PID:SERIAL with the IDs "
            "in hexadecimal, e.g. usb:2341:0043 ('hwbridge board scan' lists them)"
        )
    return UsbSelector(
        int(match.group("vid"), 16), int(match.group("pid"), 16), match.group("serial"), query
    )


def resolve_link(
    url: str, ports: Sequence[SerialPort] | None = None
) -> tuple[str, SerialPort | None]:
    """The link URL to open for ``url`` and the port it names: a ``usb:`` or ``auto`` link
    becomes the path of its one matching port among ``ports`` (default: those there are now,
    :func:`list_serial_ports`), with the link's options; any other URL is returned as it is,
    with None. LinkError naming the ports found when none or several match."""
    selector = parse_usb_link(url)
    if selector is None:
        return url, None
    if ports is None:
        ports = list_serial_ports()
    found = [port for port in ports if selector.matches(port)]
    if len(found) == 1:
        port = found[0]
        return port.path + (f"?{selector.query}" if selector.query else ""), port
    what = "a known board" if selector.auto else f"USB ID {selector}"
    if found:
        hint = (
            "usb:VID:PID:SERIAL with its serial number, or its path"
            if any(p.serial_number for p in found)
            else "its path"
        )
        raise LinkError(
            f"{url}: {len(found)} serial ports have {what}: "
            f"{'; '.join(p.describe() for p in found)}; give {hint}"
        )
    seen = "; ".join(p.describe() for p in ports) if ports else "none"
    raise LinkError(
        f"{url}: no serial port has {what} (ports found: {seen}); is the board plugged in? "
        "'hwbridge board scan' lists the ports"
    )


@dataclass(frozen=True)
class Resolved:
    """One link of :func:`resolve_links`: the URL to open and its port, or the problem."""

    url: str
    resolved: str | None
    port: SerialPort | None
    problem: str | None = None
    """Why it did not resolve: ``link URL: ...`` (None: it did)."""
    shared: bool = False
    """The problem is that another link names the same port."""


def resolve_links(
    links: Sequence[tuple[str, str]],
    list_ports: Callable[[], Sequence[SerialPort]] | None = None,
) -> dict[str, Resolved]:
    """The ``usb:`` and ``auto`` links among ``links`` (pairs of what the link is for, e.g.
    ``board base``, and its URL) resolved against the ports there are now (listed once, by
    ``list_ports``, default :func:`list_serial_ports`), by what they are for. A link that names
    no port or several, or a port that an earlier link already names, gets its ``problem``
    instead. ``hwbridge up`` and ``hwbridge connect`` resolve their links with this."""
    wanted = [(what, url) for what, url in links if is_usb_link(url)]
    if not wanted:
        return {}
    ports = (list_ports or list_serial_ports)()
    taken: dict[str, str] = {}
    results: dict[str, Resolved] = {}
    for what, url in wanted:
        try:
            resolved, port = resolve_link(url, ports)
        except HwBridgeError as exc:
            results[what] = Resolved(url, None, None, f"link {exc}")
            continue
        device = port.device if port is not None else resolved
        if device in taken:
            results[what] = Resolved(
                url,
                None,
                port,
                f"link {url} is {device}, which {taken[device]} uses too; name the port of each "
                "(usb:VID:PID:SERIAL or its path)",
                shared=True,
            )
            continue
        taken[device] = what
        results[what] = Resolved(url, resolved, port)
    return results


# ----------------------------------------------------------------------------------- probing


@dataclass(frozen=True)
class ProbeResult:
    """What answered on a port: a protocol's name, or None with ``problem`` saying why not."""

    protocol: str | None
    problem: str | None = None
    received: int = 0

    def describe(self) -> str:
        if self.protocol is not None:
            return self.protocol
        return self.problem or "no answer"


_PROBE_GAPS: Final = (0.1, 0.2, 0.4, 0.8, 1.0)


def probe_port(
    url: str,
    timeout: float = 3.0,
    baud: int | None = None,
    open_link: Callable[..., Any] | None = None,
) -> ProbeResult:
    """Open ``url``, listen for a board and send the protocols' probes (as the bridge does when
    it detects a board) for at most ``timeout`` seconds, then close it. Opening an Arduino's port
    usually resets it, so give ``timeout`` its boot time (about 2 s on an Uno)."""
    from hwbridge.protocols.detect import ProtocolDetector, detectable_protocols

    if open_link is None:
        from hwbridge.links import open_link as default_open

        open_link = default_open
    specs: Sequence[Any] = detectable_protocols()
    detector = ProtocolDetector(specs)
    probes = [spec.probe for spec in specs if spec.probe]
    try:
        link = open_link(url, **({"baud": baud} if baud is not None else {}))
    except HwBridgeError as exc:
        return ProbeResult(None, f"cannot open: {exc}")
    received = 0
    try:
        started = time.monotonic()
        deadline = started + timeout
        next_probe, gaps = started, list(_PROBE_GAPS)
        while True:
            now = time.monotonic()
            if now >= deadline:
                break
            if probes and now >= next_probe:
                for probe in probes:
                    link.write(probe)
                next_probe = now + (gaps.pop(0) if len(gaps) > 1 else gaps[0])
            data = link.read(4096, timeout=min(0.05, max(deadline - now, 0.0)))
            if data:
                received += len(data)
                found = detector.feed(data)
                if found is not None:
                    return ProbeResult(found, None, received)
    except HwBridgeError as exc:
        return ProbeResult(None, f"link failed: {exc}", received)
    finally:
        link.close()
    if received:
        return ProbeResult(None, f"{received} bytes, no known protocol (wrong baud?)", received)
    return ProbeResult(None, "silent", 0)
