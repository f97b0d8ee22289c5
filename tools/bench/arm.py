#!/usr/bin/env python3
"""The HwBridge library on the ARM boards in QEMU, next to the ATmega328P in simavr.

The publisher and the service server of ``tools/bench/sim.py`` (a std_msgs/String "hello
world!" published at every loop(), and the ServiceServer example's ``count``, std_srvs/Trigger,
called one call after the other) are built for the STM32F405 (QEMU ``netduinoplus2``) and the
micro:bit's nRF51822 (QEMU ``microbit``) and for the Uno, each run behind an in-process bridge
on an embedded graph, at 115200 baud:

- ``arm_throughput_hello``: messages per second reaching the graph subscriber. For the ARM
  boards per wall-clock second (QEMU's clocks follow the host's); for the peer, the Uno in
  simavr, per second of simulated time, as ``sim.py`` measures it.
- ``arm_service``: calls per second (1 / mean round trip), with ``p50_us`` and ``p99_us``,
  wall clock, for both.

``ratio`` is ARM board / Uno. What the figures mean: QEMU's UART models have no baud rate (a
byte is passed to the pty as soon as the firmware writes it: the STM32's USART and the nRF51's
UART hold one received byte, or six, until the firmware reads them), so the ARM figures are the
firmware's and the host's speed, not a 115200-baud line's; simavr paces the Uno's UART at its
baud rate. Both run on the same host in the same run. Prints one JSON object per line.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import emit, free_port
from sim import HWBRIDGE_PUBLISHER, Running, service_times, throughput

from hwbridge.firmware import build
from hwbridge.firmware.qemu import QemuBoard
from hwbridge.firmware.sim.examples import EXAMPLES_DIR

BAUD = 115200
DOMAIN = "bench_arm"


class QemuRunning:
    """A firmware in QEMU behind an in-process bridge on an embedded graph (``sim.Running``'s
    interface: ``graph``, ``bridge``, ``close``)."""

    def __init__(self, elf: Path, board: str) -> None:
        from hwbridge.bridge import BoardSpec, Bridge
        from hwbridge.graph import Graph

        self.board = QemuBoard(elf, board).start()
        self.graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain=DOMAIN)
        self.bridge = Bridge(self.graph)
        self.bridge.add_board(
            BoardSpec(self.board.link_url, protocol="native", namespace="/bench", name="board")
        )
        deadline = time.monotonic() + 60
        while self.bridge.boards["board"].state != "connected":
            if time.monotonic() > deadline:
                raise RuntimeError(f"the {board} firmware did not connect")
            time.sleep(0.05)

    def close(self) -> None:
        self.bridge.stop()
        self.graph.close()
        self.board.close()


def _wall_throughput(running: QemuRunning, seconds: float) -> float:
    from hwbridge.graph import ANY_TYPE

    count = [0]
    node = running.graph.node("bench_sub")
    node.subscriber(
        "/bench/chatter", ANY_TYPE, lambda _m: count.__setitem__(0, count[0] + 1), raw=True
    )
    time.sleep(1.0)
    n0, w0 = count[0], time.monotonic()
    time.sleep(seconds)
    return (count[0] - n0) / (time.monotonic() - w0)


def _sketch(tmp: Path, name: str, source: str) -> Path:
    folder = tmp / name
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.ino").write_text(source)
    return folder


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="throughput window (wall s)")
    parser.add_argument("--calls", type=int, default=200, help="service calls per case")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="hwbridge-bench-arm-") as folder:
        tmp = Path(folder)
        hello = _sketch(tmp, "BenchHello", HWBRIDGE_PUBLISHER)
        service = EXAMPLES_DIR / "ServiceServer"
        defines = [f"BENCH_BAUD={BAUD}"]
        uno_hello = build.build_sketch(hello, "uno", tmp / "uno-hello", defines=defines)
        running: Any = Running(uno_hello, "native", BAUD)
        try:
            uno_rate = throughput(running, args.seconds)["per_sim_s"]
        finally:
            running.close()
        uno_service_elf = build.build_sketch(service, "uno", tmp / "uno-service")
        running = Running(uno_service_elf, "native", BAUD)
        try:
            uno_times = service_times(running, "/bench/count", "std_srvs/Trigger", b"", args.calls)
        finally:
            running.close()
        for board in build.ARM_BOARDS:
            elf = build.build_sketch(hello, board, tmp / f"{board}-hello", defines=defines)
            running = QemuRunning(elf, board)
            try:
                rate = _wall_throughput(running, args.seconds)
            finally:
                running.close()
            emit(
                "arm_throughput_hello", {"board": board, "baud": BAUD}, rate, "uno_simavr", uno_rate
            )
            elf = build.build_sketch(service, board, tmp / f"{board}-service")
            running = QemuRunning(elf, board)
            try:
                times = service_times(running, "/bench/count", "std_srvs/Trigger", b"", args.calls)
            finally:
                running.close()
            emit(
                "arm_service",
                {"board": board, "baud": BAUD},
                1.0 / statistics.mean(times),
                "uno_simavr",
                1.0 / statistics.mean(uno_times),
                p50_us=round(statistics.median(times) * 1e6),
                p99_us=round(sorted(times)[int(0.99 * (len(times) - 1))] * 1e6),
                peer_p50_us=round(statistics.median(uno_times) * 1e6),
                peer_p99_us=round(sorted(uno_times)[int(0.99 * (len(uno_times) - 1))] * 1e6),
            )


if __name__ == "__main__":
    main()
