"""A graph node for a Dynamixel bus: what ROS users expect from one (DEVICES.md).

* ``joint_states`` (sensor_msgs/JointState): positions in rad, velocities in rad/s and efforts
  at ``rate_hz``; read with one SYNC_READ of Present Load/Current, Velocity and Position
  (Protocol 2.0) or a READ per servo (1.0, whose servos have no SYNC_READ). The effort is what
  the servo measures, not a torque (no torque constant is published for these servos): the
  Present Load as a signed fraction of the maximum torque (-1..1) on servos that report load
  (XL430, AX-12A), the Present Current in amperes on those that measure current (XM430).
* ``joint_command`` (sensor_msgs/JointState): goals for several joints in one message, by name:
  ``position`` (rad) and/or ``velocity`` (rad/s), each list empty or as long as ``name``; a
  name that is not a joint of the bus is reported once (WARNING) and its entries skipped.
* ``<joint>/goal_position`` (std_msgs/Float64, rad) and ``<joint>/goal_velocity``
  (std_msgs/Float64, rad/s): the latest command per joint goes out with the next cycle, in one
  SYNC_WRITE per register. A goal velocity is the Goal Velocity of an X servo in velocity mode
  (Operating Mode 1), otherwise the speed of its moves (Profile Velocity on X, Moving Speed on
  AX-12A, which in wheel mode is the signed wheel speed).
* ``torque_enable`` (std_srvs/SetBool): torque on or off for every joint, each write
  acknowledged.
* ``/diagnostics`` (diagnostic_msgs/DiagnosticArray), about once a second: one status per
  servo, named ``dynamixel/<joint>``, with the servo id and model as ``hardware_id``: OK, or
  the hardware error bits it reports (Hardware Error Status on X series, the status packet's
  error bits on Protocol 1.0: overload, overheating, input voltage, electrical shock, motor
  encoder) as ERROR when they meet the servo's Shutdown register (its torque went off) and
  WARN when they do not (an AX-12A's input voltage alarm, by default), or ERROR "no status"
  while it does not answer. A new hardware error, a servo that stops answering and one that
  recovers are also logged (WARNING, then INFO).

A servo that stops answering is left out of ``joint_states`` (the others keep being published,
with fewer names) and asked again once a second, until it answers and is read again.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from hwbridge.devices.dynamixel.bus import DynamixelBus
from hwbridge.devices.dynamixel.tables import ServoModel
from hwbridge.errors import HwBridgeError, HwBridgeTimeoutError
from hwbridge.graph import Graph, Node, Publisher, ServiceServer, Subscriber

__all__ = ["DynamixelNode"]

log = logging.getLogger("hwbridge.devices.dynamixel")

X_HARDWARE_ERRORS = {
    0x01: "input voltage",
    0x04: "overheating",
    0x08: "motor encoder",
    0x10: "electrical shock",
    0x20: "overload",
}
"""Bits of the X series' Hardware Error Status register (e-manual)."""
P1_HARDWARE_ERRORS = {0x01: "input voltage", 0x04: "overheating", 0x20: "overload"}
"""The hardware bits of a Protocol 1.0 status packet's error byte (DEVICES.md)."""
_OK, _WARN, _ERROR = 0, 1, 2
"""diagnostic_msgs/DiagnosticStatus levels."""
DIAGNOSTICS_PERIOD = 1.0


class DynamixelNode:
    """Publishes joint states and takes joint commands for the servos ``joints`` names.

    ``joints`` maps joint names to servo IDs. The node runs a thread from construction until
    :meth:`close`; the bus stays open (it belongs to the caller). ``stamp`` gives the
    JointState header time (default: wall clock). ``node`` is the graph node to use (a device
    plugin's, in its namespace); without one the node is ``graph.node(name, namespace)``.
    """

    def __init__(
        self,
        graph: Graph,
        bus: DynamixelBus,
        joints: Mapping[str, int],
        *,
        rate_hz: float = 100.0,
        name: str = "dynamixel",
        namespace: str = "/",
        frame_id: str = "",
        stamp: Callable[[], float] = time.time,
        node: Node | None = None,
    ) -> None:
        if not joints:
            raise ValueError("give at least one joint: joints={'name': servo_id}")
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be positive, not {rate_hz}")
        self.bus = bus
        self.joints = dict(joints)
        self.rate_hz = rate_hz
        self.frame_id = frame_id
        self._stamp = stamp
        self._names = list(self.joints)
        self.models: dict[str, ServoModel] = {n: bus.model(i) for n, i in self.joints.items()}
        if bus.protocol == 2 and any(m.series != "X" for m in self.models.values()):
            raise HwBridgeError("on Protocol 2.0 the node drives X series servos only")
        self._velocity_mode = {
            n: m.series == "X" and bus.read_register(self.joints[n], "Operating Mode") == 1
            for n, m in self.models.items()
        }
        self._wheel_mode = {
            n: m.series == "AX"
            and bus.read_register(self.joints[n], "CW Angle Limit") == 0
            and bus.read_register(self.joints[n], "CCW Angle Limit") == 0
            for n, m in self.models.items()
        }
        self._current = {
            n: "Present Current" in [r.name for r in m.table.registers]
            for n, m in self.models.items()
        }
        """Joints whose servo measures current (2.69 mA units) rather than load (0.1 %)."""
        self._shutdown = {n: bus.read_register(self.joints[n], "Shutdown") for n in self.models}
        """Per joint, the hardware errors that turn its torque off (the Shutdown register)."""
        self.published = 0
        self.read_errors = 0
        self.write_errors = 0
        self.last_error: HwBridgeError | None = None
        self._goals: dict[tuple[str, str], int] = {}
        self._goals_lock = threading.Lock()
        self._stop = threading.Event()
        self.node = node if node is not None else graph.node(name, namespace)
        self._publisher: Publisher = self.node.publisher("joint_states", "sensor_msgs/JointState")
        self._subscribers: list[Subscriber] = []
        for joint in self._names:
            self._subscribers.append(
                self.node.subscriber(
                    f"{joint}/goal_position", "std_msgs/Float64", self._on_position(joint)
                )
            )
            self._subscribers.append(
                self.node.subscriber(
                    f"{joint}/goal_velocity", "std_msgs/Float64", self._on_velocity(joint)
                )
            )
        self._subscribers.append(
            self.node.subscriber("joint_command", "sensor_msgs/JointState", self._on_command)
        )
        self._service: ServiceServer = self.node.service(
            "torque_enable", "std_srvs/SetBool", self._torque_service
        )
        self._diagnostics: Publisher = self.node.publisher(
            "/diagnostics", "diagnostic_msgs/DiagnosticArray"
        )
        self._next_diagnostics = 0.0
        self.health: dict[str, str] = dict.fromkeys(self._names, "")
        """Per joint: "" when fine, else what is wrong ("no status", hardware errors)."""
        self.silent: set[str] = set()
        """Joints whose servo did not answer: left out of joint_states until it answers."""
        self._unknown_names: set[str] = set()
        self._thread = threading.Thread(target=self._run, name=f"dxl-node-{name}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ commands
    def _on_position(self, joint: str) -> Callable[[Any], None]:
        model = self.models[joint]

        def take(message: Any) -> None:
            value = float(message.data)
            if math.isfinite(value):
                self._set_goal(joint, "Goal Position", model.radians_to_ticks(value))

        return take

    def _on_velocity(self, joint: str) -> Callable[[Any], None]:
        model = self.models[joint]
        if model.series == "AX":
            register = "Moving Speed"
        elif self._velocity_mode[joint]:
            register = "Goal Velocity"
        else:
            register = "Profile Velocity"
        ax_joint_mode = model.series == "AX" and not self._wheel_mode[joint]

        def take(message: Any) -> None:
            value = float(message.data)
            if not math.isfinite(value):
                return
            raw = model.rad_s_to_velocity(value if register != "Profile Velocity" else abs(value))
            if ax_joint_mode:
                raw &= 0x3FF  # joint mode: a speed, no direction
            self._set_goal(joint, register, raw)

        return take

    def _on_command(self, message: Any) -> None:
        names = list(message.name)
        positions, velocities = list(message.position), list(message.velocity)
        for what, values in (("position", positions), ("velocity", velocities)):
            if values and len(values) != len(names):
                log.warning(
                    "%s: joint_command has %d names but %d %ss: ignored",
                    self.node.name,
                    len(names),
                    len(values),
                    what,
                )
                return
        for index, joint in enumerate(names):
            if joint not in self.joints:
                if joint not in self._unknown_names:
                    self._unknown_names.add(joint)
                    log.warning(
                        "%s: joint_command names %r, which is not a joint of this bus (%s)",
                        self.node.name,
                        joint,
                        ", ".join(self._names),
                    )
                continue
            if positions:
                self._on_position(joint)(_Value(float(positions[index])))
            if velocities:
                self._on_velocity(joint)(_Value(float(velocities[index])))

    def _set_goal(self, joint: str, register: str, value: int) -> None:
        with self._goals_lock:
            self._goals[(joint, register)] = value

    def _torque_service(self, request: Any) -> dict[str, Any]:
        enable = bool(request.data)
        failed = []
        for joint, id_ in self.joints.items():
            try:
                self.bus.set_torque(id_, enable)
            except HwBridgeError as exc:
                failed.append(f"{joint}: {exc}")
        state = "on" if enable else "off"
        if failed:
            return {"success": False, "message": f"torque {state} failed for " + "; ".join(failed)}
        return {"success": True, "message": f"torque {state} for {len(self.joints)} joints"}

    # ------------------------------------------------------------------ loop
    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_time = time.monotonic()
        while not self._stop.is_set():
            self._write_goals()
            self._publish_state()
            if time.monotonic() >= self._next_diagnostics:
                self._next_diagnostics = time.monotonic() + DIAGNOSTICS_PERIOD
                self._publish_diagnostics()
            next_time += period
            delay = next_time - time.monotonic()
            if delay < -period:  # fell behind (slow bus): do not try to catch up
                next_time = time.monotonic()
                delay = 0.0
            self._stop.wait(max(delay, 0.0))

    def _write_goals(self) -> None:
        with self._goals_lock:
            goals, self._goals = self._goals, {}
        by_register: dict[str, dict[int, int]] = {}
        for (joint, register), value in goals.items():
            by_register.setdefault(register, {})[self.joints[joint]] = value
        for register, values in by_register.items():
            try:
                self.bus.sync_write_register(register, values)
            except (HwBridgeError, ValueError) as exc:
                self._failed("write", exc)

    def _publish_state(self) -> None:
        try:
            names, positions, velocities, efforts = self._read_state()
        except HwBridgeError as exc:
            self._failed("read", exc)
            return
        if not names:
            return
        self._publisher.publish(
            {
                "header": {"stamp": self._stamp(), "frame_id": self.frame_id},
                "name": names,
                "position": positions,
                "velocity": velocities,
                "effort": efforts,
            }
        )
        self.published += 1

    def _read_state(self) -> tuple[list[str], list[float], list[float], list[float]]:
        """The answering joints and their readings; a joint whose servo times out joins
        :attr:`silent` (counted as a read error), the others are still read."""
        answering = [n for n in self._names if n not in self.silent]
        raw: dict[str, bytes] = {}
        if self.bus.protocol == 2 and answering:
            # Present Load/Current 126 (2), Present Velocity 128 (4), Present Position 132 (4)
            try:
                by_id = self.bus.sync_read(126, 10, [self.joints[n] for n in answering])
                raw = {n: by_id[self.joints[n]] for n in answering if self.joints[n] in by_id}
            except HwBridgeTimeoutError as exc:
                self._failed("read", exc)  # someone is silent: find out who, servo by servo
        if len(raw) < len(answering):
            # AX-12A: Present Position 36, Present Speed 38, Present Load 40
            address, length = (126, 10) if self.bus.protocol == 2 else (36, 6)
            for name in answering:
                try:
                    raw[name] = self.bus.read(self.joints[name], address, length)
                except HwBridgeTimeoutError as exc:
                    self.silent.add(name)
                    self._failed("read", exc)
        names = [n for n in answering if n in raw]
        positions: list[float] = []
        velocities: list[float] = []
        efforts: list[float] = []
        for name in names:
            model, data = self.models[name], raw[name]
            if self.bus.protocol == 2:
                effort = int.from_bytes(data[:2], "little", signed=True)
                efforts.append(effort * 2.69e-3 if self._current[name] else effort / 1000.0)
                velocities.append(
                    model.velocity_to_rad_s(int.from_bytes(data[2:6], "little", signed=True))
                )
                positions.append(
                    model.ticks_to_radians(int.from_bytes(data[6:], "little", signed=True))
                )
            else:  # bit 10 of Present Speed/Load: direction
                positions.append(model.ticks_to_radians(int.from_bytes(data[:2], "little")))
                velocities.append(model.velocity_to_rad_s(int.from_bytes(data[2:4], "little")))
                load = int.from_bytes(data[4:], "little")
                efforts.append((-1 if load & 0x400 else 1) * (load & 0x3FF) / 1023.0)
        return names, positions, velocities, efforts

    def _servo_health(self, joint: str) -> tuple[int, str]:
        """The diagnostic level and "" if the servo answers and reports no hardware error,
        else what is wrong."""
        id_ = self.joints[joint]
        try:
            if self.models[joint].series == "X":
                bits = self.bus.read_register(id_, "Hardware Error Status")
                names = X_HARDWARE_ERRORS
            else:
                self.bus.ping(id_, identify=False)
                bits = self.bus.alerts.get(id_, 0)
                names = P1_HARDWARE_ERRORS
        except HwBridgeTimeoutError as exc:
            self.silent.add(joint)  # a servo found silent here is a read error too: the state
            self._failed("read", exc)  # reads skip silent joints, so they never count it
            return _ERROR, "no status"
        except HwBridgeError as exc:
            return _ERROR, f"status not read: {exc}"
        self.silent.discard(joint)
        if self.models[joint].series != "X":
            bits &= sum(names)  # the other bits are instruction errors, not hardware
        found = [name for bit, name in names.items() if bits & bit]
        unknown = bits & ~sum(names)
        if unknown:
            found.append(f"bits 0x{unknown:02X}")
        if not found:
            return _OK, ""
        return (_ERROR if bits & self._shutdown[joint] else _WARN), ", ".join(found)

    def _publish_diagnostics(self) -> None:
        statuses = []
        for joint in self._names:
            level, problem = self._servo_health(joint)
            before = self.health[joint]
            if problem != before:
                if problem:
                    log.warning(
                        "%s: servo %d (%s): %s", self.node.name, self.joints[joint], joint, problem
                    )
                else:
                    log.info(
                        "%s: servo %d (%s) is fine again", self.node.name, self.joints[joint], joint
                    )
                self.health[joint] = problem
            statuses.append(
                {
                    "level": level,
                    "name": f"dynamixel/{joint}",
                    "message": problem or "OK",
                    "hardware_id": f"id {self.joints[joint]} {self.models[joint].name}",
                    "values": [
                        {"key": "id", "value": str(self.joints[joint])},
                        {"key": "model", "value": self.models[joint].name},
                    ],
                }
            )
        self._diagnostics.publish({"header": {"stamp": self._stamp()}, "status": statuses})

    def _failed(self, what: str, exc: Exception) -> None:
        first = (self.read_errors if what == "read" else self.write_errors) == 0
        if what == "read":
            self.read_errors += 1
        else:
            self.write_errors += 1
        if isinstance(exc, HwBridgeError):
            self.last_error = exc
        log_at = log.warning if first else log.debug
        log_at("dynamixel node: %s failed: %s", what, exc)

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        """Stop the thread and leave the graph (the bus stays open)."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(2.0)
        for sub in self._subscribers:
            sub.close()
        self._service.close()
        self._publisher.close()
        self._diagnostics.close()

    def __enter__(self) -> DynamixelNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Value:
    """A std_msgs/Float64-shaped value (``data``), to share the per-joint goal handlers."""

    def __init__(self, data: float) -> None:
        self.data = data
