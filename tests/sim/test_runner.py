"""The simavr runner with a test program of our own (tests/sim/avr/probe.c): the UART on a pty,
pins driven and watched, an HC-SR04 echo, an I2C register file, watchdog and external resets."""

from __future__ import annotations

import itertools
import shutil
import subprocess
import threading
from collections import Counter
from pathlib import Path

import pytest

from hwbridge.firmware.sim import (
    SimAvr,
    SimError,
    Tick,
    arduino_pin,
    read_pc_trace,
    read_uart_trace,
    runner_binary,
)
from hwbridge.firmware.sim.bootloader import HEX_SUFFIXES
from tests.netutil import wait_until
from tests.sim.conftest import Terminal


def test_runner_is_cached(runner: Path) -> None:
    assert runner_binary() == runner
    assert runner.stat().st_mode & 0o111


def test_arduino_pins() -> None:
    assert [arduino_pin(n) for n in (0, 2, 7, 8, 13, 14, "A5")] == [
        "D0", "D2", "D7", "B0", "B5", "C0", "C5",
    ]  # fmt: skip
    assert arduino_pin(2, "atmega2560") == "E4"
    assert arduino_pin(20, "atmega2560") == "D1"
    assert arduino_pin("PD3") == "D3"
    with pytest.raises(SimError):
        arduino_pin(20)
    with pytest.raises(SimError):
        arduino_pin("X9")


def test_missing_elf(tmp_path: Path) -> None:
    with pytest.raises(SimError, match="no firmware"):
        SimAvr(tmp_path / "nothing.elf")
    with pytest.raises(SimError, match="unknown MCU"):
        SimAvr(tmp_path, mcu="atmega8")


def test_uart_pins_twi_and_resets(probe_elf: Path, terminal_factory: type[Terminal]) -> None:
    ticks: list[Tick] = []
    writes: list[tuple[int, int, bytes]] = []
    resets = threading.Event()
    with SimAvr(probe_elf) as sim:
        sim.on_tick.append(ticks.append)
        sim.on_i2c_write.append(lambda a, r, d: writes.append((a, r, d)))
        sim.on_reset.append(resets.set)
        sim.start(hold=True)
        assert sim.url.startswith("serial:///dev/pts/")
        for line in (
            "enc 0 D2 D4",
            "out D5",
            "out D7",
            "sonar 0 B1 B2",
            "echo 0 1740",
            "i2c 68",
            "reg 68 75 68",
            "reg 68 3b 0102030405",
        ):
            sim.command(line)
        uart = terminal_factory(sim.path)
        sim.go()
        assert uart.read_until(b"boot\n") == b"boot\n"
        # UART echo, both ways
        uart.write(b"HELLO 0123 #")
        assert uart.read_until(b"#") == b"HELLO 0123 #"
        # quadrature: 100 steps forward are 50 edges of A (x2 decoding), then back to -31; the
        # runner plays the edges out over AVR time from when it reads the command, so the count
        # is asked until it arrives (the clock the ticks report may lag the command)
        counts: list[bytes] = []

        def count_is(expected: bytes) -> bool:
            uart.write(b"c")
            counts.append(uart.read_until(b"\n"))
            return counts[-1] == expected

        sim.command("pos 0 100")
        assert wait_until(lambda: count_is(b"C50\n"), 10, step=0.02), counts[-5:]
        sim.command("pos 0 -31")
        assert wait_until(lambda: count_is(b"C-15\n"), 10, step=0.02), counts[-5:]
        # PWM on OC0B and a direction pin: duty measured over a report period
        uart.write(b"p\x40")
        uart.read_until(b"P\n")
        # The AVR set the PWM before it answered, but the time the ticks report may lag behind
        # the AVR's (by more than 10 ms on a busy machine, where a window from sim.time saw a
        # period before the PWM): the periods after the first that shows it are whole ones.
        assert wait_until(lambda: any(t.duty.get("D5", 0.0) > 0 for t in ticks), 10, step=0.01)
        start = next(t for t in ticks if t.duty.get("D5", 0.0) > 0).time
        sim.wait_time(start + 0.03)
        late = [t for t in ticks if t.time > start]
        assert late
        for tick in late:
            assert tick.duty["D5"] == pytest.approx(65 / 256, abs=0.01)
            assert tick.duty["D7"] == 1.0
        # the sonar: the echo is as wide as set
        # (the program's polling loop adds a few microseconds)
        uart.write(b"s")
        assert int(uart.read_until(b"\n")[1:]) == pytest.approx(1740, abs=4)
        # Commands are taken at the runner's next tick, and the UART's bytes move every 50 us
        # of AVR time: the width is asked until the new one arrives (the old one until then).
        sim.command("echo 0 250")
        widths: list[int] = []

        def echo_is_250() -> bool:
            uart.write(b"s")
            widths.append(int(uart.read_until(b"\n")[1:]))
            return abs(widths[-1] - 250) <= 4

        assert wait_until(echo_is_250, 10, step=0.02), widths[-5:]
        assert all(abs(w - 1740) <= 4 or abs(w - 250) <= 4 for w in widths), widths
        # I2C: the firmware's write reported, burst reads from the register file
        uart.write(b"i")
        assert uart.read_until(b"\n") == b"I68 010203040500\n"
        # the runner reports bus writes at its next tick, on another pipe than the UART's reply
        assert wait_until(lambda: writes == [(0x68, 0x6B, b"\x00")], 10, step=0.02), writes
        # the watchdog resets the chip; the runner says so and the encoder is still there
        uart.write(b"w")
        assert uart.read_until(b"boot\n").endswith(b"boot\n")
        assert resets.wait(5)
        uart.write(b"c")
        assert uart.read_until(b"\n") == b"C0\n"
        sim.command("pos 0 -35")
        assert wait_until(lambda: count_is(b"C-2\n"), 10, step=0.02), counts[-5:]
        # a reset from outside, as the reset pin gives
        sim.reset()
        assert uart.read_until(b"boot\n").endswith(b"boot\n")
        uart.write(b"AGAIN")
        assert uart.read_until(b"AGAIN") == b"AGAIN"
        # the runner's "reset" line comes on its own pipe, read by another thread: it may
        # arrive after the UART's bytes (seen with both cores loaded)
        assert wait_until(lambda: sim.resets == 2, 10, step=0.02), sim.resets
        assert sim.callback_errors == 0
    assert not sim.running


def test_uart_carries_a_burst_whole(probe_elf: Path, terminal_factory: type[Terminal]) -> None:
    """The runner's pty hands the host's bytes to the UART only while its 64-byte receive FIFO
    has room (simavr's XOFF/XON): a burst far longer than the FIFO, written at once, comes back
    from the echoing program whole and in order (a byte pushed into a full FIFO is lost)."""
    # bytes the probe echoes (no command letters), long enough to fill the FIFO many times
    letters = bytes(sorted(set(range(0x20, 0x7F)) - set(b"cpsirwa#")))
    burst = (letters * 40)[:3000] + b"#"
    with SimAvr(probe_elf) as sim:
        sim.start(hold=True)
        uart = terminal_factory(sim.path)
        sim.go()
        assert uart.read_until(b"boot\n") == b"boot\n"
        uart.write(burst)
        assert uart.read_until(b"#", timeout=60) == burst


@pytest.mark.parametrize("suffix", HEX_SUFFIXES)
def test_an_intel_hex_runs_without_a_bootloader(
    probe_elf: Path, terminal_factory: type[Terminal], tmp_path: Path, suffix: str
) -> None:
    """The probe as an Intel HEX, by each name of one, runs as its ELF does (libsimavr reads no
    HEX: the runner, told by SimAvr, loads it; the AVR ran blank flash and crashed)."""
    objcopy = shutil.which("avr-objcopy")
    if objcopy is None:
        pytest.skip("avr-objcopy is not installed (apt-get install binutils-avr)")
    image = tmp_path / f"probe{suffix}"
    subprocess.run([objcopy, "-O", "ihex", "-R", ".eeprom", str(probe_elf), str(image)], check=True)
    _echo_hello(image, terminal_factory)


def _echo_hello(
    probe_elf: Path,
    terminal_factory: type[Terminal],
    *,
    trace_uart: Path | None = None,
    trace_pc: Path | None = None,
) -> None:
    """The probe (an ELF or an Intel HEX) boots and echoes "hello#", still running after it;
    the runner's logs asked for if given."""
    with SimAvr(probe_elf, trace_uart=trace_uart, trace_pc=trace_pc) as sim:
        sim.start(hold=True)
        uart = terminal_factory(sim.path)
        sim.go()
        assert uart.read_until(b"boot\n") == b"boot\n"
        uart.write(b"hello#")
        assert uart.read_until(b"#") == b"hello#"
        assert sim.exited is None


def test_uart_trace_stamps_every_byte_both_ways(
    probe_elf: Path, terminal_factory: type[Terminal], tmp_path: Path
) -> None:
    """``trace_uart`` (the runner's --trace-uart) logs every byte the host handed to the UART
    and every byte the firmware wrote to it, with the AVR's cycle count: the probe's "boot" and
    echo appear in order, no two written bytes closer than a byte time at 115200 baud (10 bits:
    1389 cycles at 16 MHz, less UBRR's rounding), and each echoed byte after it arrived."""
    trace = tmp_path / "uart.log"
    _echo_hello(probe_elf, terminal_factory, trace_uart=trace)
    entries = read_uart_trace(trace)
    into = b"".join(e.data for e in entries if e.into_avr)
    out = [e for e in entries if not e.into_avr]
    assert into == b"hello#"
    assert b"".join(e.data for e in out) == b"boot\nhello#"
    cycles = [e.cycle for e in out]
    assert all(b - a >= 1300 for a, b in itertools.pairwise(cycles))
    handed = next(e.cycle for e in entries if e.into_avr)
    assert all(e.cycle > handed for e in out[len(b"boot\n") :])


def test_pc_trace_records_the_instructions_from_a_read_to_the_next_byte_out(
    probe_elf: Path, terminal_factory: type[Terminal], tmp_path: Path
) -> None:
    """``trace_pc`` (the runner's --trace-pc) logs every instruction from each read of the pty
    that brought bytes to the next byte the firmware writes: the probe's echo of "hello#" is
    such a window, its records one instruction apart in cycles (1 to 5 each, an interrupt's
    entry a few more), at flash addresses, starting at the read the UART log shows and ending
    before the first echoed byte; each address inside a function of the ELF (``avr-nm``), and
    the probe's UART polling loop among them, run many times while the bytes trickle in."""
    uart_log, pc_log = tmp_path / "uart.log", tmp_path / "pc.bin"
    _echo_hello(probe_elf, terminal_factory, trace_uart=uart_log, trace_pc=pc_log)
    entries = read_uart_trace(uart_log)
    handed = next(e for e in entries if e.into_avr)
    echoed = next(e for e in entries if not e.into_avr and e.cycle > handed.cycle)
    records = read_pc_trace(pc_log)
    window = [(cycle, pc) for cycle, pc in records if handed.cycle <= cycle < echoed.cycle]
    assert len(window) > 50
    assert window[0][0] - handed.cycle < 10
    assert echoed.cycle - window[-1][0] < 10
    assert all(1 <= b[0] - a[0] <= 12 for a, b in itertools.pairwise(window))
    listing = subprocess.run(
        ["avr-nm", "-S", str(probe_elf)], capture_output=True, text=True, check=True
    ).stdout
    functions = [
        (int(start, 16), int(start, 16) + int(size, 16))
        for start, size, kind, _ in (
            fields for fields in map(str.split, listing.splitlines()) if len(fields) == 4
        )
        if kind in "tTwW"
    ]
    assert all(any(a <= pc < b for a, b in functions) for _, pc in window)
    assert max(Counter(pc for _, pc in window).values()) > 20  # the polling loop
    assert not [r for r in records if r[0] < handed.cycle]  # nothing before the first read


def test_reset_drops_what_the_host_sent_before(
    probe_elf: Path, terminal_factory: type[Terminal]
) -> None:
    """Bytes the host wrote that the AVR had not taken when it is reset are gone after the
    reset, as with a board held in reset: the program that boots sees only what comes after."""
    with SimAvr(probe_elf, speed=0.02) as sim:  # slow: the burst is still unread at the reset
        sim.start(hold=True)
        uart = terminal_factory(sim.path)
        sim.go()
        assert uart.read_until(b"boot\n", timeout=60) == b"boot\n"
        uart.write(b"X" * 2000)
        sim.reset()
        assert uart.read_until(b"boot\n", timeout=60).endswith(b"boot\n")
        uart.write(b"#")
        assert uart.read_until(b"#", timeout=60) == b"#"  # no X left over from before


def test_peek_reads_the_data_space(probe_elf: Path, terminal_factory: type[Terminal]) -> None:
    """``peek`` reads the AVR's data space between instructions (the benches read counters a
    sketch keeps in SRAM with it): here the UART and TWI registers probe.c set at boot."""
    with SimAvr(probe_elf) as sim:
        sim.start(hold=True)
        uart = terminal_factory(sim.path)
        sim.go()
        assert uart.read_until(b"boot\n") == b"boot\n"
        assert sim.peek(0xC4, 2) == bytes([16, 0])  # UBRR0: 115200 with U2X at 16 MHz
        assert sim.peek(0xC1, 1)[0] & 0x18 == 0x18  # UCSR0B: RXEN0 | TXEN0
        assert sim.peek(0xB8, 1) == bytes([72])  # TWBR: 100 kHz
        with pytest.raises(SimError, match="outside"):
            sim.peek(0x8FF, 2)  # past RAMEND
        with pytest.raises(SimError, match=r"1\.\.64"):
            sim.peek(0x100, 65)


def test_missing_toolchain_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import hwbridge.firmware.sim as sim_module

    monkeypatch.setattr(sim_module, "_HEADERS", tmp_path / "no-simavr-headers")
    with pytest.raises(sim_module.SimToolchainMissingError) as caught:
        runner_binary(cache=tmp_path / "cache")
    message = str(caught.value)
    assert "\n" not in message
    for package in ("simavr", "libsimavr-dev", "libsimavrparts1", "libelf-dev"):
        assert package in message
