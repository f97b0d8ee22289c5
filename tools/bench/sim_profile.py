#!/usr/bin/env python3
"""Where an AVR board's answer to a service call goes, function by function, in simavr.

Runs the ``sim_service_hello`` servers of ``tools/bench/sim.py`` (HwBridge's Trigger server with
ACK_IN_DATA, and with ``--peer`` rosserial's ros_lib answering "hello") on an ATmega328P at
1 Mbaud behind the bridge, makes ``--calls`` calls, and reads the runner's ``--trace-pc`` log:
every instruction from each read of the pty to the next byte the firmware sends. For each call
it keeps the instructions from the request's last byte reaching the firmware (as
``answer_delays`` in sim.py computes it) to the answer's first byte: ``board_answer``, the board's
own part of a call. Each instruction's cycles go to the function its address is in (``avr-nm``
of the ELF; with LTO, inlined code counts in its caller). Prints one JSON line per firmware:
the median cycles of a call's answer (``answer_cycles_p50``), cycles per call by function,
largest first (with ``--timeline N``, call N's answer as the functions it ran through, in order),
and where a call's time goes: ``rtt_us_p50`` (wall clock),
``board_and_line_us_p50`` (simulated: from the request handed to the UART to the answer's last
byte out, the line's time both ways included) and ``host_us_p50``, the difference of the two
medians (the host's part, with the runner's pty pacing of up to 50 us each way). ros_lib's
request arrival is counted with HwBridge's byte time (the line's; ros_lib writes slower).

Not a benchmark with a pass mark: a tool for finding what to make faster (issue 29).
Runs in under a minute.
"""

from __future__ import annotations

import argparse
import bisect
import itertools
import json
import statistics
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _ros_lib import ROSSERIAL_GIT, build_ros_lib_sketch, make_ros_lib
from sim import (
    HWBRIDGE_HELLO_SERVICE,
    REQUEST_X,
    ROSSERIAL_HELLO_SERVICE,
    Running,
    answer_windows,
    build_hwbridge_sketch,
    byte_cycles,
    service_times,
)

from hwbridge.firmware.sim import read_pc_trace, read_uart_trace

BAUD = 1_000_000


def symbols(elf: Path) -> tuple[list[int], list[str]]:
    """Function start addresses (sorted) and their names, from ``avr-nm``."""
    listing = subprocess.run(
        ["avr-nm", "-n", "-C", str(elf)], capture_output=True, text=True, check=True
    ).stdout
    starts: list[int] = []
    names: list[str] = []
    for line in listing.splitlines():
        parts = line.split(" ", 2)
        if len(parts) == 3 and parts[1] in "TtWw" and len(parts[1]) == 1:
            starts.append(int(parts[0], 16))
            names.append(parts[2])
    return starts, names


def profile(
    elf: Path,
    protocol: str,
    service: tuple[str, str, bytes],
    calls: int,
    tmp: Path,
    line_byte: int | None = None,
    timeline: int | None = None,
) -> dict[str, Any]:
    """One firmware's profile (the JSON line); ``line_byte``: the line's byte time in cycles
    (None: from this firmware's own writes, see ``byte_cycles`` in sim.py); ``timeline``: the
    index of a call whose answer is also given as the run of functions it went through."""
    uart, pcs = tmp / f"{elf.stem}.uart", tmp / f"{elf.stem}.pc"
    running = Running(elf, protocol, BAUD, trace=uart, trace_pc=pcs)
    try:
        times = service_times(running, *service, calls)
    finally:
        running.close()
    trace = read_uart_trace(uart)
    byte_time = line_byte if line_byte is not None else byte_cycles(trace)
    if byte_time is None:
        raise RuntimeError(f"{elf.name} sent nothing")
    windows = answer_windows(trace, byte_time)
    # the board's whole part of each call: from the request's first byte handed to the UART
    # to the answer's last byte out (the last byte of the burst, plus its byte time)
    board_parts: list[int] = []
    request = None
    last_out = 0
    for entry in trace:
        if not entry.into_avr:
            last_out = entry.cycle
            continue
        if request is not None and last_out > request.cycle:
            board_parts.append(last_out + byte_time - request.cycle)
        request = entry
    records = read_pc_trace(pcs)
    starts, names = symbols(elf)
    per_function: Counter[str] = Counter()
    totals: list[int] = []
    w = 0
    window_total = 0
    segments: list[list[Any]] = []  # [cycles from the window's start, cycles, function]
    for (cycle, pc), (following, _) in itertools.pairwise(records):
        while w < len(windows) and cycle >= windows[w][1]:
            if window_total:
                totals.append(window_total)
            window_total = 0
            w += 1
        if w == len(windows):
            break
        if cycle < windows[w][0] or following - cycle > 50:  # before the last byte; a gap
            continue
        spent = following - cycle
        window_total += spent
        at = bisect.bisect_right(starts, pc) - 1
        name = names[at] if at >= 0 else f"0x{pc:04x}"
        per_function[name] += spent
        if w == timeline:
            if segments and segments[-1][2] == name:
                segments[-1][1] += spent
            else:
                segments.append([cycle - windows[w][0], spent, name])
    answered = len(totals)
    answer = statistics.median(totals) if totals else None
    rtt_us = statistics.median(times) * 1e6
    board_us = statistics.median(board_parts) / 16
    return {
        "firmware": elf.stem,
        "calls": answered,
        "byte_cycles": byte_time,
        "answer_cycles_p50": answer,
        "answer_us_p50": round(answer / 16, 1) if answer is not None else None,
        "rtt_us_p50": round(rtt_us, 1),
        "board_and_line_us_p50": round(board_us, 1),
        "host_us_p50": round(rtt_us - board_us, 1),
        "per_call_by_function": {
            name: round(count / answered) for name, count in per_function.most_common(25)
        }
        if answered
        else {},
        **({"timeline": segments} if timeline is not None else {}),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--calls", type=int, default=100)
    parser.add_argument("--peer", action="store_true", help="profile ros_lib's server too")
    parser.add_argument(
        "--timeline",
        type=int,
        metavar="N",
        help="also give call N's answer as the run of functions it went through: [cycles from "
        "the request's last byte, cycles, function] for each stretch in one function",
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="hwbridge-sim-profile-") as folder:
        tmp = Path(folder)
        ours = build_hwbridge_sketch("HelloService", HWBRIDGE_HELLO_SERVICE, BAUD, tmp)
        trigger = ("/bench/count", "std_srvs/Trigger", b"")
        found = profile(ours, "native", trigger, args.calls, tmp, timeline=args.timeline)
        print(json.dumps(found), flush=True)
        if args.peer and (ROSSERIAL_GIT / "HEAD").exists():
            ros_lib = make_ros_lib(tmp)
            theirs = build_ros_lib_sketch(
                ros_lib, "RosHelloService", ROSSERIAL_HELLO_SERVICE, BAUD, tmp
            )
            test = ("/bench/test_srv", "rosserial_arduino/Test", REQUEST_X)
            line = int(found["byte_cycles"])
            found = profile(theirs, "rosserial", test, args.calls, tmp, line, args.timeline)
            print(json.dumps(found), flush=True)


if __name__ == "__main__":
    main()
