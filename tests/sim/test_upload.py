"""``hwbridge firmware upload`` for real: ``hwbridge firmware sim --bootloader`` runs Optiboot on a
simulated Uno, avrdude uploads the HelloWorld example through the pty, and the sketch then
reaches the graph behind a bridge. A port held by the bridge, a corrupted HEX file (refused; the
firmware in flash keeps running) and a port that does not exist give their clear errors."""

from __future__ import annotations

import functools
import json
import os
import shutil
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Final

import pytest

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.build import LIBRARY_DIR
from hwbridge.firmware.sim.bootloader import bootloader_hex
from hwbridge.firmware.upload import Upload
from tests.bridgeproc import BridgeProcess
from tests.cliutil import run_hwbridge
from tests.netutil import wait_until

HELLO = LIBRARY_DIR / "examples" / "HelloWorld"


_hwbridge = functools.partial(run_hwbridge, timeout=300)


class SimProcess:
    """``hwbridge firmware sim --bootloader`` in a subprocess; :attr:`path` is its pty."""

    def __init__(self, *extra: str) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "hwbridge", "firmware", "sim", "--bootloader", *extra],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.lines: list[str] = []
        self.errors: list[str] = []
        for stream, into in ((self.process.stdout, self.lines), (self.process.stderr, self.errors)):
            threading.Thread(target=self._collect, args=(stream, into), daemon=True).start()

    @staticmethod
    def _collect(stream: object, into: list[str]) -> None:
        for line in stream:  # type: ignore[attr-defined]
            into.append(line.rstrip())

    @property
    def path(self) -> str:
        assert wait_until(lambda: bool(self.lines) or self.process.poll() is not None, 120), (
            "the simulator printed no URL"
        )
        assert self.lines, f"the simulator stopped: {self.errors}"
        return self.lines[0].removeprefix("serial://")

    def stop(self) -> None:
        self.process.send_signal(2)  # SIGINT, as Ctrl-C
        try:
            self.process.wait(15)
        finally:
            if self.process.poll() is None:
                self.process.kill()
                self.process.wait(5)


def _needs(mcu: str) -> None:
    if shutil.which("avrdude") is None:
        pytest.skip("avrdude is not installed (apt-get install avrdude)")
    try:
        bootloader_hex(mcu)
    except HwBridgeError as exc:
        pytest.skip(f"no bootloader for {mcu} here: {exc}")


@pytest.fixture
def simulator(runner: Path) -> Iterator[SimProcess]:
    del runner  # built (or skipped) first
    _needs("atmega328p")
    sim = SimProcess()
    yield sim
    sim.stop()


def _upload_on_a_busy_machine(
    sim: SimProcess, upload: Callable[[], subprocess.CompletedProcess[str]]
) -> subprocess.CompletedProcess[str]:
    """``upload()``, once more if it failed in a way a lagging simulator explains, while the
    simulator said it ran behind real time: avrdude's timeouts are wall-clock ones, and a machine
    too busy to run the AVR in real time looks like a silent board to it ("no bootloader
    answered"); and when the simulator catches up on AVR time while avrdude waits for the CPU,
    Optiboot's 1 s watchdog runs out between two of avrdude's commands and the sketch answers
    the next one ("out of step", seen in CI with the simulator 2.5 s behind). The retry is an
    upload from the start, pause included; any other failure is not retried."""
    done = upload()
    lagged = any("behind real time" in line for line in sim.errors)
    explained = "no bootloader answered" in done.stderr or "out of step" in done.stderr
    if done.returncode != 0 and lagged and explained:
        sys.stderr.write(f"the simulator lagged; upload again:\n{done.stderr}\n")
        done = upload()
    return done


def _chatter(bridge: BridgeProcess) -> str:
    done = bridge.cli("topic", "echo", "/chatter", "-n", "1", "--timeout", "30")
    assert done.returncode == 0, done.stderr + bridge.output()
    return done.stdout


def test_upload_then_the_sketch_reaches_the_graph(simulator: SimProcess, tmp_path: Path) -> None:
    sketch = tmp_path / "HelloWorld"
    shutil.copytree(HELLO, sketch, ignore=shutil.ignore_patterns("build"))
    port = simulator.path

    done = _hwbridge("firmware", "upload", str(sketch), "--port", port)
    assert done.returncode == 0, done.stderr + "\nsimulator: " + "\n".join(simulator.errors)
    for step in ("built ", "reset: the bootloader answered", "write: ", "verify: ", "verified"):
        assert step in done.stderr, done.stderr
    hex_file = sketch / "build" / "uno" / "HelloWorld.hex"
    assert str(hex_file) in done.stderr

    bridge = BridgeProcess(port, tmp_path, "upload_test")
    try:
        bridge.wait_ready()
        assert "data: hello world!" in _chatter(bridge)
        # the bridge holds the port: an upload is refused, saying who has it
        busy = _hwbridge("firmware", "upload", str(hex_file), "--port", port)
        assert busy.returncode == 1
        assert "busy" in busy.stderr and "hwbridge connect" in busy.stderr, busy.stderr
        # (this upload runs on another graph than the bridge's: it cannot offer to pause it)
        assert "no bridge on the graph this command reaches" in busy.stderr, busy.stderr
    finally:
        bridge.stop()

    # a corrupted image (one data byte changed, its record's checksum no longer matches) is
    # refused before the board is touched
    lines = hex_file.read_text().splitlines()
    record = lines[10]
    lines[10] = record[:9] + ("0" if record[9] != "0" else "1") + record[10:]
    corrupted = tmp_path / "corrupted.hex"
    corrupted.write_text("\n".join(lines) + "\n")
    refused = _hwbridge("firmware", "upload", str(corrupted), "--port", port)
    assert refused.returncode == 1
    assert "error: refusing to upload" in refused.stderr, refused.stderr
    assert "bad checksum" in refused.stderr and "line 11" in refused.stderr, refused.stderr

    # the firmware uploaded first still runs (opening the port resets it through Optiboot)
    again = BridgeProcess(port, tmp_path, "upload_test_again")
    try:
        again.wait_ready()
        assert "data: hello world!" in _chatter(again)
    finally:
        again.stop()
    assert simulator.process.poll() is None, simulator.errors


def test_upload_to_a_missing_port(tmp_path: Path) -> None:
    image = tmp_path / "empty.hex"
    image.write_text(":0400000000000000FC\n:00000001FF\n")
    done = _hwbridge("firmware", "upload", str(image), "--port", str(tmp_path / "ttyNONE"))
    assert done.returncode == 1
    assert f"error: no such port: {tmp_path / 'ttyNONE'}" in done.stderr, done.stderr


def test_replies_out_of_step_are_told_apart_from_silence(tmp_path: Path) -> None:
    """avrdude's words when the bootloader's replies stop matching its requests (seen when the
    board was reset in the middle of an upload) give their own sentence, not "no bootloader"."""
    upload = Upload(tmp_path / "x.hex", tmp_path / "port")
    upload.output = [
        "avrdude error: protocol expects OK byte 0x10 but got 0x04",
        "avrdude error: initialization failed, rc=-1",
        "avrdude done.  Thank you.",
    ]
    text = upload.explain_failure(1)
    assert "out of step" in text and "expects OK byte 0x10 but got 0x04" in text, text
    upload.output = ["avrdude error: stk500_getsync() attempt 4 of 4: not in sync: resp=0x00"]
    assert upload.explain_failure(1).startswith("no bootloader answered"), upload.explain_failure(1)


def _stuck_avrdude(tmp_path: Path) -> tuple[dict[str, str], Path]:
    """An environment whose ``avrdude`` is a stand-in that writes one line and its pid, then
    nothing (as a real one spinning on a pty whose simulator had gone did for half an hour)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    pid_file = tmp_path / "avrdude.pid"
    script = bin_dir / "avrdude"
    script.write_text(f"#!/bin/sh\necho $$ > {pid_file}\necho 'avrdude: stuck'\nexec sleep 600\n")
    script.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}
    return env, pid_file


def _alive(pid_file: Path) -> bool:
    try:
        os.kill(int(pid_file.read_text()), 0)
    except ProcessLookupError:
        return False
    return True


def test_a_silent_avrdude_is_ended_with_an_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    env, pid_file = _stuck_avrdude(tmp_path)
    monkeypatch.setenv("PATH", env["PATH"])
    upload = Upload(tmp_path / "x.hex", tmp_path / "port")
    upload.silence_limit = 1.0
    with pytest.raises(HwBridgeError, match="avrdude wrote nothing for 1 s and was ended"):
        upload.run()
    assert upload.output == ["avrdude: stuck"]
    assert wait_until(lambda: not _alive(pid_file), 10)


def test_a_killed_upload_leaves_no_avrdude_behind(tmp_path: Path) -> None:
    """The avrdude of a ``hwbridge firmware upload`` that is killed (SIGKILL: no clean-up runs)
    goes with it instead of holding the port."""
    env, pid_file = _stuck_avrdude(tmp_path)
    image = tmp_path / "empty.hex"
    image.write_text(":0400000000000000FC\n:00000001FF\n")
    master, slave = os.openpty()
    try:
        upload = subprocess.Popen(
            [sys.executable, "-m", "hwbridge", "firmware", "upload", str(image), "--port",
             os.ttyname(slave)],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert wait_until(lambda: pid_file.exists() and bool(pid_file.read_text().strip()), 60)
            assert _alive(pid_file)
        finally:
            upload.kill()
            _, err = upload.communicate(timeout=30)
        assert wait_until(lambda: not _alive(pid_file), 10), err
    finally:
        if pid_file.exists() and _alive(pid_file):
            os.kill(int(pid_file.read_text()), 9)
        os.close(master)
        os.close(slave)


def _sketch(tmp_path: Path, name: str, topic: str, text: str) -> Path:
    """HelloWorld copied to ``tmp_path/name``, publishing ``text`` on ``topic``."""
    sketch = tmp_path / name
    sketch.mkdir()
    source = (HELLO / "HelloWorld.ino").read_text()
    source = source.replace('chatter("chatter")', f'chatter("{topic}")')
    source = source.replace('"hello world!"', f'"{text}"')
    assert f'"{topic}"' in source and f'"{text}"' in source
    (sketch / f"{name}.ino").write_text(source)
    return sketch


def _echo(bridge: BridgeProcess, topic: str) -> str:
    done = bridge.cli("topic", "echo", topic, "-n", "1", "--timeout", "60", timeout=120)
    assert done.returncode == 0, done.stderr + bridge.output()
    return done.stdout


def test_upload_pauses_the_bridge_that_holds_the_port(runner: Path, tmp_path: Path) -> None:
    """A bridge runs sketch A from the simulated Uno's pty; an upload of sketch B through the same
    pty pauses the bridge (asked on a terminal, or --pause-bridge), and the same bridge then
    shows sketch B's topic."""
    del runner
    _needs("atmega328p")
    sketch_a = _sketch(tmp_path, "SketchA", "chatter_a", "from sketch A")
    sketch_b = _sketch(tmp_path, "SketchB", "chatter_b", "from sketch B")
    sim = SimProcess(str(sketch_a))  # flashed with A, Optiboot in front
    bridge: BridgeProcess | None = None
    try:
        port = sim.path
        bridge = BridgeProcess(port, tmp_path, "upload_pause")
        bridge.wait_ready()
        assert "data: from sketch A" in _echo(bridge, "/chatter_a")

        # not on a terminal, and no --pause-bridge: refused, naming the bridge and the flag
        refused = subprocess.run(
            [sys.executable, "-m", "hwbridge", "firmware", "upload", str(sketch_b),
             "--port", port],
            stdin=subprocess.DEVNULL,
            env=bridge.env,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )  # fmt: skip
        assert refused.returncode == 1, refused.stderr
        assert "busy: board " in refused.stderr and "--pause-bridge" in refused.stderr
        assert "hwbridge -v connect" in refused.stderr, refused.stderr

        # on a terminal the user is asked; "n" leaves the bridge alone
        master, slave = os.openpty()
        try:
            os.write(master, b"n\n")
            declined = subprocess.run(
                [sys.executable, "-m", "hwbridge", "firmware", "upload", str(sketch_b),
                 "--port", port],
                stdin=slave,
                env=bridge.env,
                capture_output=True,
                text=True,
                timeout=300,
                check=False,
            )  # fmt: skip
        finally:
            os.close(slave)
            os.close(master)
        assert declined.returncode == 1, declined.stderr
        assert "pause it for the upload? [y/N]" in declined.stderr, declined.stderr
        assert "busy" in declined.stderr and "pause:" not in declined.stderr
        assert "released" not in bridge.output()

        done = _upload_on_a_busy_machine(
            sim,
            lambda: bridge.cli(
                "firmware", "upload", str(sketch_b), "--port", port, "--pause-bridge", timeout=600
            ),
        )
        assert done.returncode == 0, (
            done.stderr + "\nbridge:\n" + bridge.output() + "\nsimulator:\n" + "\n".join(sim.errors)
        )
        for step in ("pause: asking board", "pause: the bridge released", "write: ", "verified",
                     "resume: board"):  # fmt: skip
            assert step in done.stderr, done.stderr
        log = bridge.output()
        assert "released " in log and "for an upload; holding off" in log, log
        assert "resuming: reopening" in log, log
        # the same bridge, the new firmware
        assert "data: from sketch B" in _echo(bridge, "/chatter_b")
        info = json.loads(bridge.cli("board", "info", "--json").stdout)
        assert info["topics"]["publishes"] == ["/chatter_b"], info
        assert bridge.process.poll() is None
    finally:
        if bridge is not None:
            bridge.stop()
        sim.stop()


BOARDS_TXT = Path("/usr/share/arduino/hardware/arduino/avr/boards.txt")


def _boards_txt() -> dict[str, str]:
    if not BOARDS_TXT.is_file():
        pytest.skip(f"no {BOARDS_TXT} (apt-get install arduino-core-avr)")
    pairs = (line.split("=", 1) for line in BOARDS_TXT.read_text().splitlines() if "=" in line)
    return {key.strip(): value.strip() for key, value in pairs if not key.startswith("#")}


@pytest.mark.parametrize(
    ("board", "prefix"), [("uno", "uno."), ("mega", "mega.menu.cpu.atmega2560.")]
)
def test_avrdude_arguments_match_arduinos_boards_txt(
    board: str, prefix: str, tmp_path: Path
) -> None:
    """The programmer (-c), baud (-b) and part avrdude gets for each board are what Arduino's
    boards.txt gives its upload (the Mega 2560: stk500v2 through avrdude's "wiring"); the flash
    room checked before an upload is its maximum_size. avrdude's wiring programmer refuses
    -x attempts=N (it exits at once), so only STK500 v1 gets it."""
    from hwbridge.firmware import build

    facts = _boards_txt()
    build_mcu = facts.get(f"{prefix}build.mcu") or facts[f"{board}.build.mcu"]
    command = Upload(tmp_path / "x.hex", tmp_path / "port", board).command("avrdude")
    options = dict(zip(command[1::2], command[2::2], strict=False))
    assert options["-c"] == facts[f"{prefix}upload.protocol"]
    assert options["-b"] == facts[f"{prefix}upload.speed"]
    assert options["-p"] == build_mcu
    assert build.BOARDS[board].flash == int(facts[f"{prefix}upload.maximum_size"])
    assert ("-x" in command) == (options["-c"] == "arduino")


_SMALLEST_BOOT_SECTION: Final = {"atmega328p": 512, "atmega2560": 1024}
"""Bytes of each AVR's smallest boot section (BOOTSZ 11: 256 and 512 words); each step of BOOTSZ
down doubles it (the datasheets' boot size configuration tables)."""


@pytest.mark.parametrize(
    ("board", "prefix"),
    [("uno", "uno."), ("nano", "nano.menu.cpu.atmega328."), ("mega", "mega.menu.cpu.atmega2560.")],
)
def test_a_boards_room_is_its_mcus_flash_less_its_bootloaders_section(
    board: str, prefix: str
) -> None:
    """The flash a sketch may use is the MCU's flash less the boot section that boards.txt's
    high fuse gives the bootloader (BOOTSZ, bits 2..1); on the boards the simulator has a
    bootloader for, that bootloader begins where the sketch's room ends."""
    from hwbridge.firmware import build
    from hwbridge.firmware.sim.bootloader import flash_layout, read_hex

    facts = _boards_txt()
    spec = build.BOARDS[board]
    bootsz = (int(facts[f"{prefix}bootloader.high_fuses"], 16) >> 1) & 3
    section = _SMALLEST_BOOT_SECTION[spec.mcu] << (3 - bootsz)
    assert spec.boot_section == section
    assert spec.flash == build.MCU_FLASH[spec.mcu] - section
    if board in ("uno", "mega"):
        assert flash_layout(spec.mcu) == (spec.flash, build.MCU_FLASH[spec.mcu])
        assert min(read_hex(bootloader_hex(spec.mcu))) == spec.flash


def test_mega_upload_through_the_stk500v2_bootloader(runner: Path, tmp_path: Path) -> None:
    """The Mega path for real: the Mega 2560's stk500v2 bootloader (Debian's build) runs in the
    simulated ATmega2560, avrdude's wiring programmer writes and verifies HelloWorld built for
    the Mega through it, and the sketch then reaches the graph."""
    del runner
    _needs("atmega2560")
    sim = SimProcess("--mcu", "atmega2560")
    try:
        port = sim.path
        sketch = tmp_path / "HelloWorld"
        shutil.copytree(HELLO, sketch, ignore=shutil.ignore_patterns("build"))
        done = _upload_on_a_busy_machine(
            sim,
            lambda: _hwbridge("firmware", "upload", str(sketch), "--port", port, "--board", "mega"),
        )
        assert done.returncode == 0, done.stderr + "\nsimulator: " + "\n".join(sim.errors)
        for step in ("built ", "reset: the bootloader answered", "write: ", "verify: ", "verified"):
            assert step in done.stderr, done.stderr
        assert str(sketch / "build" / "mega" / "HelloWorld.hex") in done.stderr
        # The stk500v2 bootloader takes any byte within its first moments after a reset as the
        # start of an upload, and each further byte keeps it waiting: the bridge lets the board
        # speak first (--start-delay) rather than probe it at once.
        bridge = BridgeProcess(port, tmp_path, "upload_mega", "--start-delay", "3")
        try:
            bridge.wait_ready()
            assert "data: hello world!" in _chatter(bridge)
        finally:
            bridge.stop()
        assert sim.process.poll() is None, sim.errors
    finally:
        sim.stop()


@pytest.mark.parametrize(
    ("board", "mcu", "start_delay"),
    [("uno", "atmega328p", "0"), ("mega", "atmega2560", "2"), ("mega", "atmega2560", "0")],
)
def test_a_board_reset_under_the_bridge_comes_back(
    runner: Path, tmp_path: Path, board: str, mcu: str, start_delay: str
) -> None:
    """Pressing the reset button while the bridge is connected. The Uno's Optiboot gives up on
    the first byte that is no upload (its watchdog starts the sketch). A Mega's stk500v2 takes
    the bridge's next bytes as an upload and waits 5 s after each one: a bridge that kept
    calling the silent board (HELLOs every 0.25 s) held it there for good. With a start delay
    (a Mega's default in a robot file) the bridge listens first; without one (``hwbridge
    connect`` as a user first types it) it calls in bursts with pauses, its first probes at the
    open's reset included. Either way the bootloader gives up, and HelloWorld is back."""
    del runner
    _needs(mcu)
    from hwbridge.firmware.build import build_sketch
    from hwbridge.firmware.sim import SimAvr

    sketch = tmp_path / "HelloWorld"
    shutil.copytree(HELLO, sketch, ignore=shutil.ignore_patterns("build"))
    elf = build_sketch(sketch, board, tmp_path / "out")
    sim = SimAvr(elf.with_suffix(".hex"), bootloader=bootloader_hex(mcu), mcu=mcu).start()
    try:
        sim.go()
        port = sim.url.removeprefix("serial://")
        bridge = BridgeProcess(port, tmp_path, f"{board}_reset", "--start-delay", start_delay)
        try:
            bridge.wait_ready()
            # (a Mega without a start delay is recognised after a pause of the bridge's calls,
            # the first of 6 s, or a later longer one if the simulator runs behind real time)
            before = bridge.wait_session(90)
            assert "data: hello world!" in _chatter(bridge)
            resets, since = sim.resets, len(bridge.output())
            sim.reset()
            assert wait_until(lambda: sim.resets > resets, 30), "the simulator did not reset"
            # Back means connected to the board's next boot, not taken for the old session
            # resumed: the simulated AVR reads the same clock and A0 at every boot, and the
            # count of boots it keeps in SRAM through the reset gives the new boot a new session
            # id (PROTOCOL.md 2.10). So the board's session id is compared, not log lines
            # counted: on a busy machine the simulator can go unscheduled for longer than the
            # bridge's 0.8 s link timeout, before the reset as after it, and the board, which in
            # its own time never missed a heartbeat, comes back with its session resumed
            # ("session ended", "connected (native, session resumed)": lines that met the old
            # counts before the reset did anything, and failed the old "no session resumed"
            # check after it).
            bridge.wait_session(90, other_than=before, since=since)
            assert "data: hello world!" in _chatter(bridge)
        finally:
            bridge.stop()
    finally:
        sim.close()
