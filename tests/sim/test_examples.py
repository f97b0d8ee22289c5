"""The HwBridge library's example sketches, built for an ATmega328P, run in simavr behind a real
bridge process, and used from the CLI: topics, services, parameters, a button on a pin, the LED
watched on its pin, and resets (from outside and by the watchdog) recovered by the bridge."""

from __future__ import annotations

import itertools
import json
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.sim import SimAvr, Tick
from hwbridge.firmware.sim.examples import build_example, build_sketch_for_sim
from tests.bridgeproc import BridgeProcess
from tests.netutil import wait_until

SKETCHES = Path(__file__).with_name("sketches")
LED = "B5"  # LED_BUILTIN, pin 13
BUTTON = "D7"  # Button.ino's pin 7


@dataclass
class Running:
    sim: SimAvr
    bridge: BridgeProcess
    led: list[tuple[float, float]]
    """(simulated time, LED duty) of each report."""

    def led_at_least(self, since: float, value: float) -> bool:
        return any(t > since and duty >= value for t, duty in self.led)

    def led_at_most(self, since: float, value: float) -> bool:
        return any(t > since and duty <= value for t, duty in self.led)


@pytest.fixture
def run_example(
    runner: Path, tmp_path: Path, request: pytest.FixtureRequest
) -> Iterator[Callable[..., Running]]:
    started: list[Running] = []

    def start(name: str, *commands: str) -> Running:
        try:
            sketch = SKETCHES / name
            elf = build_sketch_for_sim(sketch) if sketch.is_dir() else build_example(name, "uno")
        except HwBridgeError as exc:
            pytest.skip(f"{name} does not build here: {str(exc).splitlines()[0]}")
        sim = SimAvr(elf)
        led: list[tuple[float, float]] = []
        lock = threading.Lock()

        def on_tick(tick: Tick) -> None:
            with lock:
                led.append((tick.time, tick.duty.get(LED, 0.0)))

        sim.on_tick.append(on_tick)
        sim.start(hold=True)
        sim.command(f"out {LED}")
        for command in commands:
            sim.command(command)
        sim.go()
        bridge = BridgeProcess(sim.url, tmp_path, request.node.name)
        running = Running(sim, bridge, led)
        started.append(running)
        bridge.wait_ready()
        return running

    yield start
    for running in started:
        running.bridge.stop()
        running.sim.close()


def _echo(bridge: BridgeProcess, topic: str) -> str:
    done = bridge.cli("topic", "echo", topic, "-n", "1", "--timeout", "30")
    assert done.returncode == 0, done.stderr + bridge.output()
    return done.stdout


def test_hello_world(run_example: Callable[..., Running]) -> None:
    running = run_example("HelloWorld")
    bridge, sim = running.bridge, running.sim
    assert "data: hello world!" in _echo(bridge, "/chatter")
    topics = bridge.cli("topic", "list")
    assert "/chatter" in topics.stdout
    assert sim.resets == 0


def test_simulation_restarted(runner: Path, tmp_path: Path) -> None:
    """The simulator stops and starts again (a new process, a new pty): the bridge, given the
    symlink that follows the pty, finds the board again on its own."""
    try:
        elf = build_example("HelloWorld", "uno")
    except HwBridgeError as exc:
        pytest.skip(f"HelloWorld does not build here: {str(exc).splitlines()[0]}")
    sim = SimAvr(elf, symlink=tmp_path / "board")
    bridge: BridgeProcess | None = None
    try:
        sim.start()
        assert sim.link_url == f"serial://{tmp_path / 'board'}"
        first = sim.path
        bridge = BridgeProcess(sim.link_url, tmp_path, "sim_restart")
        bridge.wait_ready()
        assert "data: hello world!" in _echo(bridge, "/chatter")
        sim.restart()
        assert sim.restarts == 1
        assert (tmp_path / "board").resolve() == Path(sim.path)
        assert sim.path != first or (tmp_path / "board").exists()
        assert "data: hello world!" in _echo(bridge, "/chatter")
    finally:
        if bridge is not None:
            bridge.stop()
        sim.close()


def test_watchdog_reset_recovered(run_example: Callable[..., Running]) -> None:
    running = run_example("WatchdogHello")
    bridge, sim = running.bridge, running.sim
    assert "data: hello world!" in _echo(bridge, "/chatter")
    done = bridge.cli("topic", "pub", "-1", "/hang", "std_msgs/Empty", "{}")
    assert done.returncode == 0, done.stderr
    assert wait_until(lambda: sim.resets == 1, 20), bridge.output()  # the watchdog's
    assert "data: hello world!" in _echo(bridge, "/chatter")


def test_blink_subscribers_drive_the_led(run_example: Callable[..., Running]) -> None:
    running = run_example("Blink")
    bridge, sim = running.bridge, running.sim
    assert wait_until(lambda: "/led" in bridge.cli("topic", "list").stdout, 30)
    since = sim.time
    done = bridge.cli("topic", "pub", "-1", "/led", "std_msgs/Bool", "{data: true}")
    assert done.returncode == 0, done.stderr
    assert wait_until(lambda: running.led_at_least(since, 1.0), 20), bridge.output()
    since = sim.time
    done = bridge.cli("topic", "pub", "-1", "/toggle_led", "std_msgs/Empty", "{}")
    assert done.returncode == 0, done.stderr
    assert wait_until(lambda: running.led_at_most(since, 0.0), 20), bridge.output()


def test_button_on_its_pin(run_example: Callable[..., Running]) -> None:
    running = run_example("Button", f"in {BUTTON} 1")  # released: the pull-up holds it high
    bridge, sim = running.bridge, running.sim
    assert "data: false" in _echo(bridge, "/pushed")
    since = sim.time
    sim.command(f"in {BUTTON} 0")  # pressed
    assert wait_until(lambda: running.led_at_least(since, 1.0), 20)
    assert "data: true" in _echo(bridge, "/pushed")


def test_service_server(run_example: Callable[..., Running]) -> None:
    running = run_example("ServiceServer")
    bridge, sim = running.bridge, running.sim
    assert wait_until(lambda: "/set_led" in bridge.cli("service", "list").stdout, 30)
    since = sim.time
    done = bridge.cli("service", "call", "/set_led", "{data: true}", "--timeout", "20")
    assert done.returncode == 0, done.stderr + bridge.output()
    assert "LED on" in done.stdout
    assert wait_until(lambda: running.led_at_least(since, 1.0), 20)
    # the library and the host negotiated one-byte call heads (PROTOCOL.md 2.8)
    info = bridge.cli("board", "info", "--json")
    assert info.returncode == 0, info.stderr
    features = json.loads(info.stdout)["session"]["features"]
    assert {"SERVICE_CHANNELS", "SHORT_CALLS"} <= set(features), info.stdout
    done = bridge.cli("service", "call", "/count", "{}", "--timeout", "20")
    assert done.returncode == 0, done.stderr
    assert "2 calls" in done.stdout
    # a reset from outside (the reset pin): the board starts a new session, from 0 calls,
    # and the bridge takes it on its own
    sim.reset()
    assert wait_until(lambda: sim.resets == 1, 10)
    assert wait_until(
        lambda: "1 calls" in bridge.cli("service", "call", "/count", "{}", "--timeout", "5").stdout,
        60,
    ), bridge.output()


def _half_periods(led: list[tuple[float, float]], since: float) -> list[float]:
    """Simulated seconds between the LED's changes after ``since``."""
    changes = []
    level: bool | None = None
    for t, duty in led:
        if t <= since or 0.0 < duty < 1.0:
            continue
        if level is not None and (duty >= 1.0) != level:
            changes.append(t)
        level = duty >= 1.0
    return [b - a for a, b in itertools.pairwise(changes)]


def test_parameters_followed(run_example: Callable[..., Running]) -> None:
    running = run_example("Parameters")
    bridge, sim = running.bridge, running.sim
    done = bridge.cli("param", "set", "/gains", json.dumps([1.0, 0.5, 0.01]))
    assert done.returncode == 0, done.stderr
    done = bridge.cli("param", "set", "/blink_period_ms", "100")
    assert done.returncode == 0, done.stderr
    assert wait_until(lambda: "blink_period_ms = 100" in bridge.output(), 60), bridge.output()
    # the board asks at each connection and follows changes; a reset makes it ask again
    sim.reset()
    assert wait_until(lambda: bridge.output().count("blink_period_ms = 100") == 2, 60), (
        bridge.output()
    )
    assert "gains (x1000) = 1000 500 10" in bridge.output()
    since = sim.time
    sim.wait_time(since + 1.0)
    halves = _half_periods(running.led, since)
    assert halves
    assert sum(halves) / len(halves) == pytest.approx(0.1, abs=0.01)
    done = bridge.cli("param", "set", "/blink_period_ms", "250")
    assert done.returncode == 0, done.stderr
    assert wait_until(lambda: "blink_period_ms = 250" in bridge.output(), 30), bridge.output()
    since = sim.time
    sim.wait_time(since + 2.0)
    halves = _half_periods(running.led, since)
    assert sum(halves) / len(halves) == pytest.approx(0.25, abs=0.01)
