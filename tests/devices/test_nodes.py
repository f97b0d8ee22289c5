"""Host device nodes (each device's ``node`` module) on a real Zenoh graph (a router on a
free port)."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

import numpy as np
import pytest

from hwbridge import msg
from hwbridge.devices.diffdrive.encoders import DiffDriveOdometry, DiffDriveParams
from hwbridge.devices.diffdrive.node import DiffDriveNode
from hwbridge.devices.imu import ChipErrors, ImuTruth, Mpu6050, Mpu9250, MpuChip
from hwbridge.devices.imu.host import decode_burst
from hwbridge.devices.imu.mpu import ACCEL_CONFIG, ACCEL_XOUT_H, GYRO_CONFIG, PWR_MGMT_1
from hwbridge.devices.imu.node import ImuNode
from hwbridge.devices.world import STANDARD_GRAVITY
from hwbridge.graph import Graph
from tests.netutil import wait_until

PARAMS = DiffDriveParams.from_dict(
    {"wheel_radius": 0.033, "wheel_separation": 0.16, "counts_per_rev": 1320}
)
Targets = tuple[float, float]


class ManualClock:
    """A monotonic clock that only moves when the test says so."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def _twist(x: float, z: float = 0.0) -> Any:
    return msg.from_dict("geometry_msgs/Twist", {"linear": {"x": x}, "angular": {"z": z}})


def _wire(targets: Targets) -> Targets:
    """Targets as the board receives them (WheelTargets carries float32)."""
    return (float(np.float32(targets[0])), float(np.float32(targets[1])))


class _Teleop:
    """Publishes cmd_vel on the graph, as a teleop node would: the drive node gets it on the
    graph's own thread. :attr:`sent` counts what it published, so that a test can wait until
    the node has taken every command (its watchdog counts them) before moving its clock."""

    def __init__(self, client: Graph, namespace: str) -> None:
        self._publisher = client.node("teleop").publisher(
            f"{namespace}/cmd_vel", "geometry_msgs/Twist"
        )
        self.sent = 0

    def __call__(self, x: float, z: float = 0.0) -> None:
        self.sent += 1
        self._publisher.publish(_twist(x, z))


def _listen(client: Graph, namespace: str) -> list[Targets]:
    """Every wheel_targets message the board would receive, in order."""
    received: list[Targets] = []
    client.node("board").subscriber(
        f"{namespace}/wheel_targets",
        "hwbridge_msgs/WheelTargets",
        lambda m: received.append((float(m.left), float(m.right))),
    )
    return received


class DriveSendPause:
    """Holds a DiffDriveNode's drive thread still at the start of one ``_send(targets)`` call.

    Installed (as the interpreter's profiling hook for threads started meanwhile) around the
    node's construction, so that only its drive thread carries it. Once :attr:`armed` is set,
    the thread's next ``_send`` call whose targets satisfy ``wanted`` sets :attr:`paused` and
    waits for :meth:`release`. Nothing of the node is replaced: the thread is only held at the
    point where it has decided what to publish and has not yet published it.
    """

    def __init__(self, wanted: Callable[[Targets], bool]) -> None:
        self.wanted = wanted
        self.armed = threading.Event()
        self.paused = threading.Event()
        self._go = threading.Event()

    def _hook(self, frame: FrameType, event: str, _arg: object) -> None:
        if (
            event == "call"
            and self.armed.is_set()
            and frame.f_code.co_name == "_send"
            and threading.current_thread().name == "diffdrive"
            and self.wanted(tuple(frame.f_locals["targets"]))
        ):
            self.armed.clear()
            self.paused.set()
            self._go.wait(10)

    @contextmanager
    def installed(self) -> Iterator[None]:
        threading.setprofile(self._hook)
        try:
            yield
        finally:
            threading.setprofile(None)

    def release(self) -> None:
        self._go.set()


@pytest.mark.parametrize("case", ["stale targets", "watchdog stop"])
def test_a_command_is_never_overtaken_by_what_the_drive_loop_decided_before_it(
    case: str, router: Graph, client: Graph
) -> None:
    """The drive loop has decided what to send (the previous targets, or the watchdog's stop)
    and is about to publish it when a new cmd_vel arrives. The board must end up with the new
    command: nothing the loop decided before it may be published after it."""
    namespace = "/race_" + case.split()[1]
    received = _listen(client, namespace)
    odometry = DiffDriveOdometry.from_params(PARAMS)
    first, newer = odometry.wheel_targets(0.1, 0.0), odometry.wheel_targets(0.3, 0.0)
    pause = DriveSendPause(lambda t: t == ((0.0, 0.0) if case == "watchdog stop" else first))
    clock = ManualClock(100.0)
    with pause.installed():
        node = router.node("devices", namespace=namespace)
        if case == "watchdog stop":  # the loop stops the wheels when the test moves the clock
            drive = DiffDriveNode(node, PARAMS, clock=clock)
        else:  # real time: the loop repeats the targets for 0.5 s after a command
            drive = DiffDriveNode(node, PARAMS)
    command = _Teleop(client, namespace)
    try:

        def first_arrived() -> bool:  # also: the board's and the node's subscriptions match
            command(0.1)
            return _wire(first) in received

        assert wait_until(first_arrived, 10, step=0.05)
        # warm-up commands still on their way would restart the watchdog after the clock moves
        assert wait_until(lambda: drive.watchdog.commands == command.sent, 10)
        pause.armed.set()
        if case == "watchdog stop":
            clock.now += 10.0  # cmd_vel went quiet: the next cycle sends the stop
        assert pause.paused.wait(5), "the drive loop never came to send the expected targets"
        command(0.3)  # cmd_vel arrives, on the graph's thread
        # Without a lock its targets go out now, before the loop's; with one they wait for
        # the loop. Give them the time to go out before letting the loop publish.
        wait_until(lambda: _wire(newer) in received, 1.0)
        pause.release()
        assert wait_until(lambda: received.count(_wire(newer)) >= 2, 5), received
    finally:
        pause.release()
        drive.close()
    after = received[received.index(_wire(newer)) :]
    assert all(targets == _wire(newer) for targets in after), received


def test_the_watchdog_stops_the_wheels_once_and_a_later_command_restarts_them(
    router: Graph, client: Graph
) -> None:
    clock = ManualClock(0.0)
    received = _listen(client, "/watchdog")
    drive = DiffDriveNode(router.node("devices", namespace="/watchdog"), PARAMS, clock=clock)
    drive.stop()  # the test runs the control cycles itself, at the times it chooses
    marker = _wire(drive.odometry.wheel_targets(0.05, 0.0))
    go = _wire(drive.odometry.wheel_targets(0.2, 0.0))
    turn = _wire(drive.odometry.wheel_targets(0.0, 1.0))

    command = _Teleop(client, "/watchdog")

    def subscribed() -> bool:
        command(0.05)
        return marker in received

    def handled(targets: Targets) -> Callable[[], bool]:  # the command went out to the board
        return lambda: bool(received) and received[-1] == targets

    assert wait_until(subscribed, 10, step=0.05)
    assert wait_until(lambda: drive.watchdog.commands == command.sent, 10)
    clock.now = 10.0
    command(0.2)
    assert wait_until(handled(go), 10)
    clock.now = 10.49
    drive.tick()  # within the timeout: the targets repeat
    clock.now = 10.5  # 0.5 s without cmd_vel: one stop
    drive.tick()
    clock.now = 10.6
    drive.tick()  # already stopped: nothing
    command(0.0, 1.0)
    assert wait_until(handled(turn), 10)
    clock.now = 10.7
    drive.tick()
    expected = [go, go, (0.0, 0.0), turn, turn]

    def scenario() -> list[Targets]:  # what followed the last warm-up message (all in order)
        last = len(received) - received[::-1].index(marker)
        return received[last:]

    assert wait_until(lambda: len(scenario()) >= len(expected), 5), received
    assert scenario() == expected
    assert drive.watchdog.timeouts == 1


def _ticks_at(stamp: float, count: int) -> dict[str, Any]:
    """Both wheels at ``count`` at board time ``stamp`` (a straight line)."""
    sec, nanosec = divmod(round(stamp * 1e9), 1_000_000_000)
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}},
        "left": count,
        "right": count,
        "counter_bits": 32,
    }


def test_a_board_clock_set_back_by_a_time_sync_is_not_a_restart_and_loses_no_travel(
    router: Graph, client: Graph
) -> None:
    """A board that runs slow (simavr on a busy machine) falls behind host time between two
    time syncs, and each sync sets its stamps back by what it lost. Its counters go on: the
    node keeps every count (no re-referencing). A restart (counters from 0) still re-references.
    """
    drive = DiffDriveNode(router.node("devices", namespace="/resync"), PARAMS)
    drive.stop()
    publisher = client.node("board").publisher("/resync/wheel_ticks", "hwbridge_msgs/WheelTicks")
    seen: list[float] = []
    client.node("viewer").subscriber(
        "/resync/odom",
        "nav_msgs/Odometry",
        lambda m: seen.append(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9),
    )

    def send(stamp: float, count: int) -> None:
        publisher.publish(msg.from_dict("hwbridge_msgs/WheelTicks", _ticks_at(stamp, count)))

    def reached(stamp: float) -> Callable[[], bool]:
        return lambda: bool(seen) and abs(seen[-1] - stamp) < 1e-6

    def subscribed() -> bool:  # the first reading, again until the node has taken it
        send(100.0, 0)
        return bool(seen)

    try:
        assert wait_until(subscribed, 10, step=0.05)
        stamp, count = 100.0, 0
        for step in range(150):  # 50 Hz, 10 counts a reading; the clock set back 0.35 s twice
            stamp += 0.02 - (0.35 if step in (50, 100) else 0.0)
            count += 10
            send(stamp, count)
            assert wait_until(reached(stamp), 10), (step, seen[-3:])
        assert drive.rereferences == 0
        travelled = drive.odometry.state.distance
        assert travelled == pytest.approx(count * 2 * math.pi * 0.033 / 1320, rel=1e-9)

        send(stamp - 0.35, 10)  # the board restarted: its counters begin again
        assert wait_until(reached(stamp - 0.35), 10)
        assert drive.rereferences == 1
        assert drive.odometry.state.x == pytest.approx(travelled, rel=1e-9)  # the pose is kept
        assert drive.odometry.state.distance == pytest.approx(travelled, rel=1e-9)  # and distance
        send(stamp - 0.33, 20)  # and counting goes on from the new reference
        assert wait_until(reached(stamp - 0.33), 10)
        step_m = 10 * 2 * math.pi * 0.033 / 1320
        assert drive.odometry.state.distance == pytest.approx(travelled + step_m, rel=1e-9)
    finally:
        drive.close()


# ---------------------------------------------------------------------- IMU
def _raw_imu(chip: MpuChip, code: int) -> dict[str, Any]:
    chip.write(PWR_MGMT_1, b"\x00")  # awake (the MPU-6050 starts asleep)
    chip.sample()
    raw = decode_burst(chip.read(ACCEL_XOUT_H, 14))
    return {
        "header": {"frame_id": "imu_link"},
        "chip": code,
        "accel_config": chip.read(ACCEL_CONFIG, 1)[0],
        "gyro_config": chip.read(GYRO_CONFIG, 1)[0],
        "burst": [*raw.accel, raw.temperature, *raw.gyro],
    }


@pytest.mark.parametrize(
    ("chip_class", "constant", "accel_density", "gyro_density", "lsb_per_c", "offset_c"),
    [
        # MPU-6050 product specification; DEVICES.md
        (Mpu6050, "MPU6050", 400e-6, 0.005, 340.0, 36.53),
        # MPU-9250 product specification: noise densities, Temp_Sensitivity, RoomTemp 21 C
        (Mpu9250, "MPU9250", 300e-6, 0.01, 333.87, 21.0),
    ],
)
def test_imu_node_converts_with_the_figures_of_the_chip_the_board_names(
    chip_class: type[MpuChip],
    constant: str,
    accel_density: float,
    gyro_density: float,
    lsb_per_c: float,
    offset_c: float,
    router: Graph,
    client: Graph,
) -> None:
    namespace = f"/imu_{constant.lower()}"
    imu = ImuNode(router.node("devices", namespace=namespace))
    chip = chip_class(errors=ChipErrors(), noise=False, truth=ImuTruth(temperature_c=30.0))
    code = int(getattr(msg.from_dict("hwbridge_msgs/ImuRaw", {}), constant))
    raw = _raw_imu(chip, code)
    pub = client.node("board").publisher(f"{namespace}/imu_raw", "hwbridge_msgs/ImuRaw")

    def converted() -> bool:
        pub.publish(raw)
        return imu.latest is not None

    assert wait_until(converted, 10, step=0.05)
    # The node does not know the board's DLPF setting: it assumes DLPF_CFG 3 (44 / 42 Hz).
    accel_variance = (accel_density * math.sqrt(44.0) * STANDARD_GRAVITY) ** 2
    gyro_variance = math.radians(gyro_density * math.sqrt(42.0)) ** 2
    assert imu.latest.linear_acceleration_covariance[0] == pytest.approx(accel_variance)
    assert imu.latest.angular_velocity_covariance[4] == pytest.approx(gyro_variance)
    word = raw["burst"][3]
    assert imu.temperature_c == pytest.approx(word / lsb_per_c + offset_c)
    assert imu.temperature_c == pytest.approx(30.0, abs=1 / lsb_per_c)
    assert imu.latest.linear_acceleration.z == pytest.approx(STANDARD_GRAVITY, abs=1e-3)


def test_imu_node_drops_an_unknown_chip_and_counts_it(router: Graph, client: Graph) -> None:
    imu = ImuNode(router.node("devices", namespace="/imu_unknown"))
    raw = _raw_imu(Mpu6050(errors=ChipErrors(), noise=False), 7)
    pub = client.node("board").publisher("/imu_unknown/imu_raw", "hwbridge_msgs/ImuRaw")

    def counted() -> bool:
        pub.publish(raw)
        return imu.dropped > 0

    assert wait_until(counted, 10, step=0.05)
    assert imu.latest is None
