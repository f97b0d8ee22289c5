#!/usr/bin/env python3
"""AVR firmware in simavr: hwbridge's Arduino library against rosserial's ros_lib.

Both libraries' firmware is built for an ATmega328P at 16 MHz and run in simavr
(:class:`hwbridge.firmware.sim.SimAvr`, held to real time), each behind hwbridge's bridge (the
native protocol for the HwBridge library, hwbridge's rosserial host for ros_lib), with a graph
subscriber or service caller in this process. For each library and baud rate (115200 and
1000000):

- ``sim_throughput_*``: a HelloWorld-style publisher of std_msgs/String "hello world!" that
  publishes at every loop() (no delay), messages per second reaching the graph subscriber,
  per second of *simulated* time (the AVR's own clock; ``sim_speed`` says how fast the
  simulation ran against the wall clock). ``wire_bytes_per_msg`` are the bytes the bridge read
  from the UART per message received (framing, headers and the other traffic of the session
  included).
- ``sim_service``: the service of the library's ServiceServer example called from the graph
  one call after the other (HwBridge: ``count``, std_srvs/Trigger, answered "N calls"; ros_lib:
  ``test_srv``, rosserial_arduino/Test, answered "hello" or "world", with its example's
  ``delay(10)`` and its ``chatter`` publish taken out of loop() so that both only serve, as
  fast as they can), ``p50_us`` and ``p99_us`` of the round trip, wall clock. Both firmwares
  run at once, each in its simavr behind its bridge, and the calls alternate between them
  (``alternating``), so that both meet the same moments of the host's load.
  ``board_answer_us`` and ``peer_board_answer_us`` are each board's own part of a call, in
  simulated time (the runner's ``--trace-uart`` log): the median time from the request's last
  byte reaching the firmware to the answer's first byte written to the UART, the same whatever
  the host's load; ``board_answer_ratio`` is ros_lib's over HwBridge's (above 1, HwBridge
  answers sooner). (With the publish left in, ros_lib's answers queued behind a line full of
  its messages: the ratio read 1.3 to 2.5 where it reads 0.7 to 1.2 without, runs of the same
  day on a shared machine.) The two answers differ: "N calls" is 5 bytes longer than "hello"
  and takes the board a number's formatting, so ``wire_bytes_per_call`` reads 32 against 30.
- ``sim_service_hello``: the like-for-like service: both servers answer "hello" (HwBridge:
  Trigger with ACK_IN_DATA, SERVICE_CHANNELS and SHORT_CALLS; ros_lib: Test to the request "x")
  and loop() is ``spinOnce()`` alone. Per call the line carries HwBridge's 9-byte request and
  19-byte answer against ros_lib's 13 and 17 bytes: the answer's native frame (header, request
  id, CRC-16, COBS, the carried ACK and the Trigger's bool) is 2 bytes longer than rosserial's,
  its request 4 shorter, 2 bytes a call fewer: 22 us at 1 Mbaud, 174 us at 115200 (with
  SERVICE_CHANNELS alone, before SHORT_CALLS, PROTOCOL.md 2.8, 1 byte a call more; before both,
  5 bytes more).

``ratio`` is hwbridge / rosserial: above 1, hwbridge delivers more messages per second; for the
service lines the figure compared is calls per second (1 / mean round trip), and ``ratio_p50``
compares the median round trips (peer / hwbridge: above 1, hwbridge answers faster).
A runner keeps a bias of its own for its whole life: two runners of one firmware, their calls
alternating as here, read 0.969 to 1.014 against each other (four pairs, 600 calls each; with
the runner's former pacing quantum of 1 ms, one pair read 1.115: see ``runner.c``, TICK_US). So
the calls of a service line are spread over ``PAIRS`` (4) pairs of runners started one after
the other, each pair's calls alternating, and ``ratio_pairs`` is ``ratio`` for each pair. On
this 2-core machine (two simulators and the bridges share it), five runs of sim_service_hello at
1 Mbaud with one pair of 1000 calls each, on one commit, read 0.942 to 1.082 (the quarters of
their calls 0.842 to 1.113).

At 1 Mbaud, the AVR's own count of the cycles of library work (``sim_cycles_*``; simulated
cycles, deterministic but for the host's traffic, which the wall clock paces):

- ``sim_cycles_publish``: ``*_cycles_per_msg``, the cycles inside ``publish()`` per message.
- ``sim_cycles_service``: ``*_cycles_per_call``, the cycles inside the ``spinOnce()`` calls
  entered with received bytes waiting, per service call over ``--calls`` calls one after
  another (everything the call costs the board: reading and checking its frames, the
  callback, the answer and the ACKs); ``idle_spin_cycles``, one ``spinOnce()`` with nothing to
  read; ``spins_per_call``, the busy ``spinOnce()`` calls a call took.

The sketches (CYCLES_PRELUDE and the ``*_CYCLES_*`` sources below) read Timer1, running at
clk/1, just before and just after each library call, made with interrupts off: the count is the
library's instructions (and the Arduino core's ``HardwareSerial`` code they call), no
interrupt handler falls inside. A publish is made only when the UART's transmit ring is empty,
so it never waits for the line; a service sketch runs every ``spinOnce()`` with interrupts off,
so bytes arrive only between two of them. The bench reads the counters out of the AVR's SRAM
(the runner's ``peek``) and refuses a counter that does not count 1000 cycles for
``__builtin_avr_delay_cycles(1000)``. Here ``ratio`` is hwbridge / rosserial cycles: below 1,
hwbridge spends fewer. ``calls_per_wall_s`` is wall clock (the simulation is held to real time)
and ``p50_us`` the median round trip; ``wall_ratio`` and ``wall_ratio_p50`` are hwbridge / ros_lib
calls per second by the mean and by the median round trip (above 1, hwbridge answers faster).
These sketches run every ``spinOnce()`` with interrupts off, so the UART's interrupts move one
byte in and one byte out per loop(): a call's round trip there grows with its bytes times one
idle loop (392 cycles for HwBridge, 338 for ros_lib), not with the line rate; for wall-clock
calls per second as a sketch sees them, read ``sim_service_hello``.
Both libraries are called the same way: the same runner, baud rate, in-process bridge, graph and
caller (a Zenoh query per call); what differs is the firmware and the bridge's protocol session
(hwbridge's native one, with CRC-16 and ACKs, or its rosserial host).

What simavr's UART model means for the figures: simavr moves a byte through the AVR's UART in
the time the baud rate gives it (UBRR and U2X as the firmware sets them: 10 bit times a byte),
in both directions, with the AVR's 64-byte receive FIFO; the pty side has no rate at all (the
runner moves the bytes between the pty and the UART every 50 us of simulated time). The
line rate is therefore the AVR's real one, and the messages per second depend on the bytes per
message and on the CPU time the firmware spends per message (both simulated cycle by cycle), as
on a real Uno; what is not modelled is a USB-serial converter's latency (an Uno's 16U2 batches
bytes into USB frames: about 1 ms more per direction on hardware) and a real pty's baud limit.
The round trips are wall-clock: they include the simulator's pacing (every 100 us of simulated
time the runner sleeps off what the simulation gained on the wall clock past 100 us; it may fall
behind on a busy machine) and the host's scheduling.

ros_lib comes from rosserial's sources (``ROSSERIAL_GIT``: a git directory of
github.com/ros-drivers/rosserial, default /work/.mirror/ros-drivers+rosserial/repo): its
client library and Arduino hardware files are taken from there at bench time, and the message
headers it needs (std_msgs/String and Time, rosserial_msgs, rosserial_arduino/Test) are
generated here from hwbridge's message definitions, into a temporary folder; nothing of it is
kept. Without the sources the rosserial lines are skipped with a line saying so.

Runs in about two minutes (``--only cycles``: under one); prints one JSON object per line.
"""

from __future__ import annotations

import argparse
import itertools
import json
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import emit
from _ros_lib import ROSSERIAL_GIT, build_ros_lib_sketch, git_file, make_ros_lib

from hwbridge.firmware import build
from hwbridge.firmware.sim import SimAvr, UartBytes, read_uart_trace

BAUDS = (115200, 1000000)
CYCLES_BAUD = 1000000
REQUEST_X = b"\x01\x00\x00\x00x"
"""rosserial_arduino/Test's request with input "x", serialized."""
T = TypeVar("T")
DOMAIN = "bench_sim"
HELLO = "hello world!"

HWBRIDGE_PUBLISHER = """\
#include <HwBridge.h>
#include <std_msgs/String.h>
hwbridge::NodeHandle nh;
std_msgs::String str_msg;
hwbridge::Publisher<std_msgs::String> chatter("chatter");
void setup() {
  nh.initNode(BENCH_BAUD, "hello");
  nh.advertise(chatter);
  str_msg.data.assign("hello world!");
}
void loop() {
  if (nh.connected()) chatter.publish(str_msg);
  nh.spinOnce();
}
"""

ROSSERIAL_PUBLISHER = """\
#include <ros.h>
#include <std_msgs/String.h>
ros::NodeHandle nh;
std_msgs::String str_msg;
ros::Publisher chatter("chatter", &str_msg);
char hello[13] = "hello world!";
void setup() {
  nh.getHardware()->setBaud(BENCH_BAUD);
  nh.initNode();
  nh.advertise(chatter);
}
void loop() {
  str_msg.data = hello;
  if (nh.connected()) chatter.publish(&str_msg);
  nh.spinOnce();
}
"""

# Service servers for sim_service_hello: the same work on both sides, nothing else in loop() (the
# cycles sketches without their counters, interrupts as any sketch has them): each answers
# "hello" (HwBridge: std_srvs/Trigger with ACK_IN_DATA built in; ros_lib: rosserial_arduino/Test
# to the request "x").
_HWBRIDGE_SERVER = """\
#define HWBRIDGE_ACK_IN_DATA 1
#include <HwBridge.h>
#include <std_srvs/Trigger.h>
hwbridge::NodeHandle nh;
void on_count(const std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  res.success = true;
  res.message.assign("hello");
}
hwbridge::ServiceServer<std_srvs::Trigger> count("count", &on_count);
void setup() {
  nh.initNode(BENCH_BAUD, "service_server");
  nh.advertiseService(count);
"""
"""The HwBridge server's sketch up to the end of setup() (the hello and the cycles servers)."""
HWBRIDGE_HELLO_SERVICE = _HWBRIDGE_SERVER + "}\nvoid loop() { nh.spinOnce(); }\n"

_ROSSERIAL_SERVER = """\
#include <ros.h>
#include <rosserial_arduino/Test.h>
ros::NodeHandle nh;
using rosserial_arduino::Test;
void callback(const Test::Request&, Test::Response& res) { res.output = "hello"; }
ros::ServiceServer<Test::Request, Test::Response> server("test_srv", &callback);
void setup() {
  nh.getHardware()->setBaud(BENCH_BAUD);
  nh.initNode();
  nh.advertiseService(server);
"""
"""ros_lib's server up to the end of setup() (the hello and the cycles servers)."""
ROSSERIAL_HELLO_SERVICE = _ROSSERIAL_SERVER + "}\nvoid loop() { nh.spinOnce(); }\n"

# The cycle counter of the cycles_* lines, put before each of their sketches: Timer1 at clk/1
# (16 MHz, 16 bits; the Arduino core only sets it up for analogWrite on pins 9 and 10) read
# just before and just after one library call made with interrupts off, so that the count is
# the library's instructions alone (no UART or millis interrupt falls inside it); the calls are
# made only when they cannot wait on the line (see the sketches), so no waiting is counted
# either. bench.check is a 1000-cycle busy wait measured the same way: the bench refuses a
# counter that does not read 1000 for it.
CYCLES_PRELUDE = """\
#include <Arduino.h>
#include <avr/io.h>
#include <avr/interrupt.h>
struct BenchCounters {
  uint32_t pub_cycles;   // cycles inside publish()
  uint32_t pubs;         // publish() calls counted
  uint32_t spin_cycles;  // cycles inside spinOnce() entered with received bytes waiting
  uint32_t spins;        // such spinOnce() calls
  uint32_t idle_cycles;  // cycles inside spinOnce() entered with nothing received
  uint32_t idles;        // such spinOnce() calls
  uint16_t check;        // cycles counted around __builtin_avr_delay_cycles(1000)
};
volatile BenchCounters bench;
static uint16_t bench_zero;
#define BENCH_BARRIER() __asm__ __volatile__("" ::: "memory")
#define BENCH_COUNT(total, count, call)                                      \\
  do {                                                                       \\
    const uint8_t sreg_ = SREG;                                              \\
    cli();                                                                   \\
    BENCH_BARRIER();                                                         \\
    const uint16_t t0_ = TCNT1;                                              \\
    BENCH_BARRIER();                                                         \\
    call;                                                                    \\
    BENCH_BARRIER();                                                         \\
    const uint16_t t1_ = TCNT1;                                              \\
    BENCH_BARRIER();                                                         \\
    SREG = sreg_;                                                            \\
    bench.total += static_cast<uint16_t>(t1_ - t0_ - bench_zero);            \\
    bench.count += 1;                                                        \\
  } while (0)
static void bench_start() {
  TCCR1A = 0;
  TCCR1B = _BV(CS10);  // normal mode, clk/1
  TIMSK1 = 0;
  const uint8_t sreg = SREG;
  cli();
  const uint16_t a = TCNT1;
  BENCH_BARRIER();
  const uint16_t b = TCNT1;
  SREG = sreg;
  bench_zero = static_cast<uint16_t>(b - a);
  BENCH_COUNT(check, spins, __builtin_avr_delay_cycles(1000));
  bench.spins = 0;
}
static inline bool bench_tx_idle() {
  return Serial.availableForWrite() >= SERIAL_TX_BUFFER_SIZE - 1;
}
"""

# Publishers for cycles_per_msg: publish() only when the UART's transmit ring is empty (so that
# it never waits for the line), the same 16-byte std_msgs/String as sim_throughput_hello.
HWBRIDGE_CYCLES_PUBLISHER = """\
#include <HwBridge.h>
#include <std_msgs/String.h>
hwbridge::NodeHandle nh;
std_msgs::String str_msg;
hwbridge::Publisher<std_msgs::String> chatter("chatter");
void setup() {
  nh.initNode(BENCH_BAUD, "hello");
  nh.advertise(chatter);
  str_msg.data.assign("hello world!");
  bench_start();
}
void loop() {
  if (nh.connected() && bench_tx_idle()) BENCH_COUNT(pub_cycles, pubs, chatter.publish(str_msg));
  nh.spinOnce();
}
"""

ROSSERIAL_CYCLES_PUBLISHER = """\
#include <ros.h>
#include <std_msgs/String.h>
ros::NodeHandle nh;
std_msgs::String str_msg;
ros::Publisher chatter("chatter", &str_msg);
char hello[13] = "hello world!";
void setup() {
  nh.getHardware()->setBaud(BENCH_BAUD);
  nh.initNode();
  nh.advertise(chatter);
  bench_start();
}
void loop() {
  str_msg.data = hello;
  if (nh.connected() && bench_tx_idle()) BENCH_COUNT(pub_cycles, pubs, chatter.publish(&str_msg));
  nh.spinOnce();
}
"""

# Service servers for cycles_per_call: every spinOnce() runs with interrupts off, so that bytes
# arrive only between two of them, and is counted as busy when it is entered with received
# bytes waiting (a call's bytes, an ACK or the bridge's own traffic; an answer is shorter than
# the transmit ring, so it does not wait for the line), idle otherwise. The busy cycles over a
# run of calls are divided by the calls; idle_spin_cycles is what one spinOnce() with nothing
# to read costs (a sketch pays it at every loop()). Each answers "hello" (HwBridge:
# std_srvs/Trigger, ros_lib: rosserial_arduino/Test with the request "x"). The HwBridge server
# builds ACK_IN_DATA in (as the library's ServiceServer example does): a call has no ACK frame.
HWBRIDGE_CYCLES_SERVICE = (
    _HWBRIDGE_SERVER
    + """\
  bench_start();
}
void loop() {
  if (Serial.available() > 0) BENCH_COUNT(spin_cycles, spins, nh.spinOnce());
  else BENCH_COUNT(idle_cycles, idles, nh.spinOnce());
}
"""
)

ROSSERIAL_CYCLES_SERVICE = (
    _ROSSERIAL_SERVER
    + """\
  bench_start();
}
void loop() {
  if (Serial.available() > 0) BENCH_COUNT(spin_cycles, spins, nh.spinOnce());
  else BENCH_COUNT(idle_cycles, idles, nh.spinOnce());
}
"""
)


def build_hwbridge_sketch(name: str, source: str | None, baud: int, tmp: Path) -> Path:
    from hwbridge.firmware.sim.examples import EXAMPLES_DIR

    folder = tmp / f"{name}-{baud}" / name
    folder.mkdir(parents=True, exist_ok=True)
    text = source if source is not None else (EXAMPLES_DIR / name / f"{name}.ino").read_text()
    if source is None:
        text = text.replace("nh.initNode(115200,", "nh.initNode(BENCH_BAUD,")
    (folder / f"{name}.ino").write_text(text)
    return build.build_sketch(folder, "uno", folder / "build", defines=[f"BENCH_BAUD={baud}"])


def rosserial_service_source() -> str:
    """ros_lib's ServiceServer example as the sim_service lines run it: its loop() without the
    ``delay(10)`` and without the ``chatter`` publish, so that, like HwBridge's example, it
    serves as fast as it can and does nothing else (with the publish at every loop, the
    service's answers queued behind a line full of messages: at 115200 baud ros_lib's calls
    took a median 10.6 ms, 3.3 ms without them)."""
    text = git_file(
        "rosserial_arduino/src/ros_lib/examples/ServiceServer/ServiceServer.pde"
    ).decode()
    for line in ("delay(10);", "chatter.publish( &str_msg );"):
        if line not in text:
            raise RuntimeError(f"rosserial's ServiceServer example has no {line!r} any more")
        text = text.replace(line, "")
    return text.replace(
        "nh.initNode();", "nh.getHardware()->setBaud(BENCH_BAUD);\n  nh.initNode();"
    )


# ------------------------------------------------------------------------------ measuring
class Running:
    """A firmware in simavr behind an in-process bridge on an embedded graph."""

    def __init__(
        self,
        elf: Path,
        protocol: str,
        baud: int,
        trace: Path | None = None,
        trace_pc: Path | None = None,
    ) -> None:
        from hwbridge.bridge import BoardSpec, Bridge
        from hwbridge.graph import Graph

        self.sim = SimAvr(elf, trace_uart=trace, trace_pc=trace_pc).start()
        self.graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{_free_port()}"], domain=DOMAIN)
        self.bridge = Bridge(self.graph)
        self.bridge.add_board(
            BoardSpec(
                f"{self.sim.url}?baud={baud}",
                protocol=protocol,
                namespace="/bench",
                start_delay=0.1,
                name="board",
            )
        )
        deadline = time.monotonic() + 30
        while self.bridge.boards["board"].state != "connected":
            if time.monotonic() > deadline:
                raise RuntimeError(f"the {protocol} firmware did not connect")
            time.sleep(0.05)

    def bytes_in(self) -> int:
        info = self.bridge.boards["board"].info()
        link = info.get("link", {})
        for key in ("bytes_in", "rx_bytes", "bytes_read", "read_bytes"):
            if key in link:
                return int(link[key])
        return -1

    def close(self) -> None:
        self.bridge.stop()
        self.graph.close()
        self.sim.close()


def throughput(running: Running, seconds: float) -> dict[str, float]:
    from hwbridge.graph import ANY_TYPE

    count = [0]
    node = running.graph.node("bench_sub")
    node.subscriber(
        "/bench/chatter", ANY_TYPE, lambda _m: count.__setitem__(0, count[0] + 1), raw=True
    )
    time.sleep(1.0)
    n0, b0, s0, w0 = count[0], running.bytes_in(), running.sim.time, time.monotonic()
    time.sleep(seconds)
    n1, b1, s1, w1 = count[0], running.bytes_in(), running.sim.time, time.monotonic()
    messages = n1 - n0
    return {
        "per_sim_s": messages / (s1 - s0) if s1 > s0 else 0.0,
        "wire": (b1 - b0) / messages if messages and b0 >= 0 else -1.0,
        "speed": (s1 - s0) / (w1 - w0),
        "messages": messages,
    }


def service_times(
    running: Running, service: str, type_name: str, payload: bytes, calls: int
) -> list[float]:
    """Round trips (s) of ``calls`` calls with the serialized request ``payload``."""
    node = running.graph.node("bench_caller")
    deadline = time.monotonic() + 20
    while True:  # the service appears on the graph once the board advertised it
        try:
            node.call_raw(service, type_name, payload, timeout=2.0)
            break
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)
    times = []
    for _ in range(calls):
        started = time.perf_counter()
        node.call_raw(service, type_name, payload, timeout=2.0)
        times.append(time.perf_counter() - started)
    return times


_COUNTERS = ("pub_cycles", "pubs", "spin_cycles", "spins", "idle_cycles", "idles")


def bench_counters(running: Running, address: int) -> dict[str, int]:
    """The sketch's ``bench`` counters (see CYCLES_PRELUDE), read out of the AVR's SRAM."""
    data = running.sim.peek(address, 4 * len(_COUNTERS) + 2)
    values = {
        name: int.from_bytes(data[4 * i : 4 * i + 4], "little") for i, name in enumerate(_COUNTERS)
    }
    values["check"] = int.from_bytes(data[-2:], "little")
    return values


def counters_address(elf: Path) -> int:
    """Where the ``bench`` counters are in the AVR's data space (their ELF symbol)."""
    done = subprocess.run(
        [build._tool("avr-nm"), "-C", str(elf)], capture_output=True, text=True, check=True
    )
    for line in done.stdout.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2] == "bench":
            return int(parts[0], 16) - 0x800000
    raise RuntimeError(f"{elf}: no symbol 'bench' (the cycle counters)")


def _checked(counters: dict[str, int], elf: Path) -> None:
    if not 995 <= counters["check"] <= 1005:
        raise RuntimeError(
            f"{elf.name}: Timer1 counted {counters['check']} cycles for a 1000-cycle wait: "
            "the cycle counter cannot be trusted"
        )


def cycles_per_message(running: Running, elf: Path, seconds: float) -> dict[str, float]:
    """Library cycles per publish() over a window of ``seconds`` (wall clock)."""
    address = counters_address(elf)
    deadline = time.monotonic() + 30
    first = bench_counters(running, address)
    while first["pubs"] == 0:  # connected and publishing
        if time.monotonic() > deadline:
            raise RuntimeError(f"{elf.name} published nothing")
        time.sleep(0.2)
        first = bench_counters(running, address)
    _checked(first, elf)
    time.sleep(seconds)
    last = bench_counters(running, address)
    messages = last["pubs"] - first["pubs"]
    if messages <= 0:
        raise RuntimeError(f"{elf.name} stopped publishing")
    return {"cycles": (last["pub_cycles"] - first["pub_cycles"]) / messages, "messages": messages}


def cycles_per_call(
    running: Running, elf: Path, service: str, type_name: str, payload: bytes, calls: int
) -> dict[str, float]:
    """Library cycles in spinOnce() per service call, over ``calls`` calls one after another."""
    address = counters_address(elf)
    service_times(running, service, type_name, payload, 1)  # the service is up
    first = bench_counters(running, address)
    _checked(first, elf)
    times = service_times(running, service, type_name, payload, calls)
    last = bench_counters(running, address)
    return {
        "cycles": (last["spin_cycles"] - first["spin_cycles"]) / calls,
        "spins_per_call": (last["spins"] - first["spins"]) / calls,
        "idle_spin_cycles": (last["idle_cycles"] - first["idle_cycles"])
        / max(1, last["idles"] - first["idles"]),
        "calls_per_wall_s": 1.0 / statistics.mean(times),
        "p50_us": statistics.median(times) * 1e6,
    }


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="throughput window (wall s)")
    parser.add_argument("--calls", type=int, default=200, help="service calls per case")
    parser.add_argument(
        "--only",
        choices=("all", "cycles", "rates"),
        default="all",
        help="cycles: only the sim_cycles_* lines (simulated, deterministic); rates: only the "
        "sim_throughput_* and sim_service lines",
    )
    args = parser.parse_args()
    have_ros = (ROSSERIAL_GIT / "HEAD").exists()
    if not have_ros:
        print(
            json.dumps(
                {
                    "bench": "sim",
                    "skipped": "rosserial",
                    "why": f"no rosserial git directory at {ROSSERIAL_GIT} (set ROSSERIAL_GIT)",
                }
            ),
            flush=True,
        )
    with tempfile.TemporaryDirectory(prefix="hwbridge-bench-sim-") as folder:
        tmp = Path(folder)
        ros_lib = make_ros_lib(tmp) if have_ros else None
        if args.only != "rates":
            measure_cycles(tmp, ros_lib, args.seconds, args.calls)
        for baud in BAUDS if args.only != "cycles" else ():
            ours_elf = build_hwbridge_sketch("BenchHello", HWBRIDGE_PUBLISHER, baud, tmp)
            ours = _measure(ours_elf, "native", baud, lambda r: throughput(r, args.seconds))
            theirs: dict[str, float] | None = None
            if ros_lib is not None:
                elf = build_ros_lib_sketch(ros_lib, "RosHello", ROSSERIAL_PUBLISHER, baud, tmp)
                theirs = _measure(elf, "rosserial", baud, lambda r: throughput(r, args.seconds))
            emit(
                "sim_throughput_hello",
                {"baud": baud, "type": "std_msgs/String"},
                ours["per_sim_s"],
                "rosserial_ros_lib" if theirs else None,
                theirs["per_sim_s"] if theirs else None,
                wire_bytes_per_msg=round(ours["wire"], 1),
                peer_wire_bytes_per_msg=round(theirs["wire"], 1) if theirs else None,
                sim_speed=round(ours["speed"], 3),
                peer_sim_speed=round(theirs["speed"], 3) if theirs else None,
            )

            for line, ours_source, ros_source in (
                ("sim_service", None, rosserial_service_source() if ros_lib else ""),
                ("sim_service_hello", HWBRIDGE_HELLO_SERVICE, ROSSERIAL_HELLO_SERVICE),
            ):
                service_line(line, ours_source, ros_source, ros_lib, baud, tmp, args.calls)


def service_line(
    line: str,
    ours_source: str | None,
    ros_source: str,
    ros_lib: Path | None,
    baud: int,
    tmp: Path,
    calls: int,
) -> None:
    """One sim_service* line: ``calls`` calls of HwBridge's server (``ours_source``, or the
    library's ServiceServer example) and of ros_lib's (``ros_source``) through the bridge.

    With ros_lib, both firmwares run at once (two simavr processes, two bridges) and the calls
    alternate between them, one each in turn: both meet the machine's load of the same moment,
    so the ratio no longer depends on which of two short windows a burst of other work fell in
    (back to back, 200 calls each, the ratio read 0.92 to 1.48 across runs of one commit). The
    calls are spread over PAIRS pairs of runners, one pair after the other."""
    name = "ServiceServer" if ours_source is None else "HelloService"
    ours_elf = build_hwbridge_sketch(name, ours_source, baud, tmp)
    ours_call = ("/bench/count", "std_srvs/Trigger", b"")
    theirs_call = ("/bench/test_srv", "rosserial_arduino/Test", REQUEST_X)
    theirs_t: list[float] | None = None
    by_pair: list[float] = []
    traces = (tmp / f"{line}-{baud}-ours.uart", tmp / f"{line}-{baud}-theirs.uart")
    if ros_lib is None:
        ours_t = _measure(ours_elf, "native", baud, lambda r: service_times(r, *ours_call, calls))
    else:
        elf = build_ros_lib_sketch(ros_lib, f"Ros{name}", ros_source, baud, tmp)
        ours_t, theirs_t = [], []
        for index, share in enumerate(_shares(calls, PAIRS)):
            logged = index == 0  # (the first pair's UART logs give the boards' own part)

            def alternate(
                ours: Running, theirs: Running, share: int = share
            ) -> tuple[list[float], list[float]]:
                return alternating_service_times((ours, *ours_call), (theirs, *theirs_call), share)

            mine, peer = _measure_pair(
                (ours_elf, "native", traces[0] if logged else None),
                (elf, "rosserial", traces[1] if logged else None),
                baud,
                alternate,
            )
            ours_t += mine
            theirs_t += peer
            by_pair.append(_ratio(mine, peer))
    emit(
        line,
        {"baud": baud},
        1.0 / statistics.mean(ours_t),
        "rosserial_ros_lib" if theirs_t else None,
        1.0 / statistics.mean(theirs_t) if theirs_t else None,
        p50_us=round(_percentile(ours_t, 0.5) * 1e6),
        p99_us=round(_percentile(ours_t, 0.99) * 1e6),
        peer_p50_us=round(_percentile(theirs_t, 0.5) * 1e6) if theirs_t else None,
        peer_p99_us=round(_percentile(theirs_t, 0.99) * 1e6) if theirs_t else None,
        ratio_p50=round(_percentile(theirs_t, 0.5) / _percentile(ours_t, 0.5), 3)
        if theirs_t
        else None,
        ratio_pairs=by_pair if theirs_t else None,
        calls=len(ours_t),
        alternating=theirs_t is not None,
        **(_answer_fields(*traces) if theirs_t is not None else {}),
    )


PAIRS = 4
"""Pairs of runners a sim_service* line's calls are spread over, each pair started afresh for its
share: a runner keeps a bias of its own for its whole life (one or two percent either way, see
the module's docstring), which a single pair would put into the ratio whole."""


def _shares(calls: int, parts: int) -> list[int]:
    """``calls`` split into at most ``parts`` shares, none empty, that differ by one at most."""
    return [calls // parts + (i < calls % parts) for i in range(min(parts, calls))]


def _ratio(ours: list[float], theirs: list[float]) -> float:
    """Calls per second of round trips ``ours`` over those of ``theirs`` (hwbridge / ros_lib)."""
    return round(statistics.mean(theirs) / statistics.mean(ours), 3)


def _answer_fields(ours: Path, theirs: Path) -> dict[str, Any]:
    """The boards' own part of a call, from the runners' UART logs (simulated time)."""
    ours_trace = read_uart_trace(ours)
    byte_time = byte_cycles(ours_trace)
    if byte_time is None:
        return {}
    mine = answer_delays(ours_trace, byte_time)
    peer = answer_delays(read_uart_trace(theirs), byte_time)
    if not mine or not peer:
        return {}
    return {
        "board_answer_us": round(statistics.median(mine), 1),
        "peer_board_answer_us": round(statistics.median(peer), 1),
        "board_answer_ratio": round(statistics.median(peer) / statistics.median(mine), 3),
        "wire_bytes_per_call": call_bytes(ours_trace),
        "peer_wire_bytes_per_call": call_bytes(read_uart_trace(theirs)),
    }


def call_bytes(trace: list[UartBytes]) -> float | None:
    """The median bytes a call puts on the line, both ways, from a ``--trace-uart`` log: the
    bytes handed to the firmware since its last answer, plus the answer's bytes up to the next
    input (a request and its answer; the rare heartbeat or time sync among them moves the median
    not at all)."""
    sizes: list[int] = []
    into = out = 0
    for entry in trace:
        if entry.into_avr:
            if out:
                sizes.append(into + out)
                into = out = 0
            into += len(entry.data)
        else:
            out += len(entry.data)
    return statistics.median(sizes) if sizes else None


def byte_cycles(trace: list[UartBytes]) -> int | None:
    """The line's byte time in AVR cycles, from the ``--trace-uart`` log of a firmware that
    writes as fast as the line takes its bytes (HwBridge's): the most common gap between two
    bytes it wrote to the UART, the pace of its bursts. 176 cycles at 1 Mbaud and 1496 at
    115200 in simavr, whose UART takes 11 bit times a byte (UBRR's rounding included); the
    same pace as the received bytes' interrupts. Not the shortest gap: the UART takes a second
    byte as soon as the first moves to its shift register. Not from ros_lib's log: it writes
    slower than the line (some 245 cycles a byte at 1 Mbaud)."""
    sent = [e.cycle for e in trace if not e.into_avr]
    gaps = Counter(b - a for a, b in itertools.pairwise(sent) if b > a)
    return gaps.most_common(1)[0][0] if gaps else None


def answer_delays(trace: list[UartBytes], byte_time: int) -> list[float]:
    """For each request in a ``--trace-uart`` log, microseconds of simulated time from its last
    byte reaching the firmware to the answer's first byte written to the UART: the board's own
    part of a call (reading and checking the request, the callback, and writing the answer up
    to its first byte), whatever the host's load (:func:`answer_windows`; 16 MHz cycles)."""
    return [(answered - arrived) / 16.0 for arrived, answered in answer_windows(trace, byte_time)]


def answer_windows(trace: list[UartBytes], byte_time: int) -> list[tuple[int, int]]:
    """For each request in a ``--trace-uart`` log, the cycle its last byte reached the firmware
    and the cycle the answer's first byte was written to the UART. A request is the bytes
    handed to the UART last before a byte went out (one read of the pty; a request split over
    two reads counts from the second); its last byte reaches the firmware one byte time per
    byte after it was handed over (``byte_time``: the line's, :func:`byte_cycles`)."""
    windows: list[tuple[int, int]] = []
    request: UartBytes | None = None
    for entry in trace:
        if entry.into_avr:
            request = entry
        elif request is not None:
            windows.append((request.cycle + len(request.data) * byte_time, entry.cycle))
            request = None
    return windows


Call = tuple[Running, str, str, bytes]
"""Where a call goes: the running firmware, the service's name, its type, the request."""


def alternating_service_times(
    ours: Call, theirs: Call, calls: int
) -> tuple[list[float], list[float]]:
    """Round trips (s) of ``calls`` calls to each of two services, made one each in turn."""
    for running, name, kind, payload in (ours, theirs):
        service_times(running, name, kind, payload, 0)  # returns once the service has answered
    nodes = [running.graph.node("bench_caller") for running, *_ in (ours, theirs)]
    times: tuple[list[float], list[float]] = ([], [])
    for n in range(2 * calls):
        side = n % 2 if (n // 2) % 2 == 0 else 1 - n % 2  # ABBA: neither side always goes first
        _, name, kind, payload = (ours, theirs)[side]
        started = time.perf_counter()
        nodes[side].call_raw(name, kind, payload, timeout=2.0)
        times[side].append(time.perf_counter() - started)
    return times


def _cycles_line(
    case: str, unit: str, ours: dict[str, float], theirs: dict[str, float] | None
) -> None:
    line: dict[str, Any] = {
        "bench": f"sim_cycles_{case}",
        "baud": CYCLES_BAUD,
        "mcu": "atmega328p",
        f"hwbridge_cycles_per_{unit}": round(ours["cycles"]),
    }
    if theirs is not None:
        line.update(
            peer="rosserial_ros_lib",
            **{f"peer_cycles_per_{unit}": round(theirs["cycles"])},
            ratio=round(ours["cycles"] / theirs["cycles"], 3),
        )
    line.update({k: round(v, 2) for k, v in ours.items() if k != "cycles"})
    if theirs is not None:
        line.update({f"peer_{k}": round(v, 2) for k, v in theirs.items() if k != "cycles"})
        if "calls_per_wall_s" in ours:
            # Wall clock, hwbridge / ros_lib: calls per second by the mean round trip (what a
            # caller gets, a few slow calls of a busy machine included) and by the median one.
            line["wall_ratio"] = round(ours["calls_per_wall_s"] / theirs["calls_per_wall_s"], 3)
            line["wall_ratio_p50"] = round(theirs["p50_us"] / ours["p50_us"], 3)
    sys.stdout.write(json.dumps(line) + "\n")
    sys.stdout.flush()


def measure_cycles(tmp: Path, ros_lib: Path | None, seconds: float, calls: int) -> None:
    """The sim_cycles_publish and sim_cycles_service lines (see the module's docstring)."""
    baud = CYCLES_BAUD
    elf = build_hwbridge_sketch(
        "CyclesHello", CYCLES_PRELUDE + HWBRIDGE_CYCLES_PUBLISHER, baud, tmp
    )
    hello = elf
    ours = _measure(elf, "native", baud, lambda r: cycles_per_message(r, hello, seconds))
    theirs = None
    if ros_lib is not None:
        elf = build_ros_lib_sketch(
            ros_lib, "RosCyclesHello", CYCLES_PRELUDE + ROSSERIAL_CYCLES_PUBLISHER, baud, tmp
        )
        ros_hello = elf
        theirs = _measure(
            elf, "rosserial", baud, lambda r: cycles_per_message(r, ros_hello, seconds)
        )
    _cycles_line("publish", "msg", ours, theirs)

    elf = build_hwbridge_sketch(
        "CyclesService", CYCLES_PRELUDE + HWBRIDGE_CYCLES_SERVICE, baud, tmp
    )
    server = elf
    ours = _measure(
        elf,
        "native",
        baud,
        lambda r: cycles_per_call(r, server, "/bench/count", "std_srvs/Trigger", b"", calls),
    )
    theirs = None
    if ros_lib is not None:
        elf = build_ros_lib_sketch(
            ros_lib, "RosCyclesService", CYCLES_PRELUDE + ROSSERIAL_CYCLES_SERVICE, baud, tmp
        )
        ros_server = elf
        theirs = _measure(
            elf,
            "rosserial",
            baud,
            lambda r: cycles_per_call(
                r, ros_server, "/bench/test_srv", "rosserial_arduino/Test", REQUEST_X, calls
            ),
        )
    _cycles_line("service", "call", ours, theirs)


ATTEMPTS = 3
"""Runs of one case before the bench gives up: on a loaded machine the simulation can fall
behind the wall clock long enough for the bridge to lose the board (its 0.8 s link timeout) or
a call to time out; the case is then run again from a fresh simulation, and said so on stderr."""


def _measure(elf: Path, protocol: str, baud: int, measure: Callable[[Running], T]) -> T:
    """``measure`` on ``elf`` running in simavr behind a bridge, retried ATTEMPTS times."""
    return _measure_all([(elf, protocol, None)], baud, lambda started: measure(started[0]))


def _measure_pair(
    ours: tuple[Path, str, Path | None],
    theirs: tuple[Path, str, Path | None],
    baud: int,
    measure: Callable[[Running, Running], T],
) -> T:
    """``measure`` on two firmwares (ELF, protocol, UART log or None) running at once, retried
    ATTEMPTS times."""
    return _measure_all([ours, theirs], baud, lambda started: measure(*started))


def _measure_all(
    firmwares: list[tuple[Path, str, Path | None]],
    baud: int,
    measure: Callable[[list[Running]], T],
) -> T:
    """``measure`` on the firmwares (ELF, protocol, UART log or None) running at once, each in
    simavr behind its bridge; started again, all of them, when a start or ``measure`` fails
    (ATTEMPTS tries)."""
    names = " and ".join(elf.name for elf, _, _ in firmwares)
    for attempt in range(1, ATTEMPTS + 1):
        started: list[Running] = []
        try:
            for elf, protocol, trace in firmwares:
                started.append(Running(elf, protocol, baud, trace))
            return measure(started)
        except Exception as exc:
            if attempt == ATTEMPTS:
                raise
            print(f"{names}: {exc}; running again", file=sys.stderr, flush=True)
        finally:
            for running in started:
                running.close()
    raise AssertionError("unreachable")


if __name__ == "__main__":
    main()
