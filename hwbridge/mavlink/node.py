"""The host node of a MAVLink vehicle (a flight controller, a rover's autopilot): MAVLink in,
graph topics and services out, in the device's namespace.

Published (from the vehicle chosen by ``system``, or the first one heard):

* ``imu`` (sensor_msgs/Imu) from ATTITUDE: orientation and angular velocity turned from
  MAVLink's NED/FRD frames into ROS's ENU/FLU (REP 103); no linear acceleration (its covariance's
  first element is -1, as REP 145 says for a missing part);
* ``gps/fix`` (sensor_msgs/NavSatFix) from GLOBAL_POSITION_INT (altitude above MSL);
* ``battery`` (sensor_msgs/BatteryState) from BATTERY_STATUS;
* ``armed`` (std_msgs/Bool) and ``mode`` (std_msgs/String) from each HEARTBEAT;
* ``connected`` (std_msgs/Bool): on every change of the link's state and with each heartbeat;
  False once no heartbeat came for ``link_timeout`` seconds (logged as a warning, and logged
  again when the vehicle is back);
* ``mavlink/NAME`` (``mavlink/CamelName``, see :mod:`hwbridge.mavlink.msgdefs`): every message
  received, raw, as a type of its own (the ``raw`` setting chooses which);
* ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) once a second: link state and counters.

Commands: ``arm`` (std_srvs/SetBool: true arms, false disarms; success when the vehicle's
COMMAND_ACK accepts), ``set_mode`` (std_msgs/String topic: a mode name such as GUIDED, or a
number), ``cmd_vel`` (geometry_msgs/Twist topic, body frame FLU: sent as a velocity setpoint,
SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_BODY_OFFSET_NED). The node sends its own HEARTBEAT
(as a ground station) at ``heartbeat_rate``, which vehicles use to notice a lost ground link.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, Final

from hwbridge.errors import HwBridgeError, LinkError
from hwbridge.mavlink.msgdefs import load_dialect, raw_type

__all__ = ["MavlinkNode"]

log = logging.getLogger("hwbridge.mavlink")

_DIAGNOSTICS_PERIOD: Final = 1.0
_ACK_TIMEOUT: Final = 3.0
_GCS_SYSTEM: Final = 255
_GCS_COMPONENT: Final = 190
_UINT16_MAX: Final = 65535
# SET_POSITION_TARGET_LOCAL_NED type_mask: use vx, vy, vz and yaw_rate only.
_VELOCITY_ONLY: Final = 0b0000_0101_1100_0111
_MAV_FRAME_BODY_OFFSET_NED: Final = 9


class _LinkWriter:
    """What pymavlink's ``MAVLink.send`` writes to: the node's link (errors counted)."""

    def __init__(self, node: MavlinkNode) -> None:
        self._node = node

    def write(self, data: bytes) -> None:
        self._node._write(data)


class MavlinkNode:
    """Bridge one MAVLink vehicle to the graph (see the module's description)."""

    def __init__(
        self,
        graph: Any,
        link: Any,
        *,
        node: Any,
        system: int = 0,
        heartbeat_rate: float = 1.0,
        link_timeout: float = 3.0,
        raw: tuple[str, ...] = ("*",),
        frame_id: str = "base_link",
        dialect: str = "ardupilotmega",
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.graph = graph
        self.link = link
        self.node = node
        self.system = system
        self.heartbeat_period = 1.0 / heartbeat_rate if heartbeat_rate > 0 else math.inf
        self.link_timeout = link_timeout
        self.raw = frozenset(name.upper() for name in raw)
        self.frame_id = frame_id
        self.dialect = dialect
        self._clock = clock
        self._module = load_dialect(dialect)
        self._mav: Any = self._module.MAVLink(
            _LinkWriter(self), srcSystem=_GCS_SYSTEM, srcComponent=_GCS_COMPONENT
        )
        self._mav.robust_parsing = True
        self._lock = threading.Lock()  # guards the counters and the state below
        self._send_lock = threading.Lock()
        self.connected = False
        self.armed = False
        self.mode = ""
        self.vehicle_type: int | None = None
        self.counters: dict[str, int] = {
            "received": 0,
            "sent": 0,
            "crc_errors": 0,
            "write_errors": 0,
            "link_losses": 0,
            "link_errors": 0,
        }
        self.received: dict[str, int] = {}
        self.last_error = ""
        self._last_heartbeat = -math.inf
        self._acks: dict[int, tuple[threading.Event, list[int]]] = {}
        self._raw_publishers: dict[str, Any] = {}
        pub = node.publisher
        self._imu = pub("imu", "sensor_msgs/Imu")
        self._fix = pub("gps/fix", "sensor_msgs/NavSatFix")
        self._battery = pub("battery", "sensor_msgs/BatteryState")
        self._armed = pub("armed", "std_msgs/Bool")
        self._mode = pub("mode", "std_msgs/String")
        self._connected = pub("connected", "std_msgs/Bool")
        self._diagnostics = pub("/diagnostics", "diagnostic_msgs/DiagnosticArray")
        self._closeables: list[Any] = [
            self._imu,
            self._fix,
            self._battery,
            self._armed,
            self._mode,
            self._connected,
            self._diagnostics,
            node.service("arm", "std_srvs/SetBool", self._arm_service),
            node.subscriber("set_mode", "std_msgs/String", self._on_set_mode),
            node.subscriber("cmd_vel", "geometry_msgs/Twist", self._on_cmd_vel),
        ]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mavlink-node", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ link and loop
    def _write(self, data: bytes) -> None:
        try:
            self.link.write(data)
        except LinkError as exc:
            with self._lock:
                self.counters["write_errors"] += 1
            log.debug("MAVLink write on %s failed: %s", self.link.url, exc)
            return
        with self._lock:
            self.counters["sent"] += 1

    def _send(self, build: Callable[[Any], None]) -> None:
        """Run ``build(mav)`` (a ``*_send`` call) with the send lock (pymavlink's sequence)."""
        with self._send_lock:
            build(self._mav)

    def _send_heartbeat(self) -> None:
        gcs, invalid = self._module.MAV_TYPE_GCS, self._module.MAV_AUTOPILOT_INVALID
        self._send(lambda mav: mav.heartbeat_send(gcs, invalid, 0, 0, 0))

    def _run(self) -> None:
        next_heartbeat = 0.0
        next_diagnostics = 0.0
        backoff = 0.1
        while not self._stop.is_set():
            now = time.monotonic()
            if not self.link.is_open:
                try:
                    self.link.open()
                    backoff = 0.1
                except LinkError as exc:
                    self._link_error(exc)
                    self._stop.wait(backoff)
                    backoff = min(2.0, backoff * 2)
                    self._check_timeout(time.monotonic())
                    continue
            if now >= next_heartbeat:
                next_heartbeat = now + self.heartbeat_period
                self._send_heartbeat()
            if now >= next_diagnostics:
                next_diagnostics = now + _DIAGNOSTICS_PERIOD
                self._publish_diagnostics()
            try:
                data = self.link.read(4096, 0.05)
            except LinkError as exc:
                self._link_error(exc)
                self._stop.wait(0.05)
                data = b""
            if data:
                for message in self._mav.parse_buffer(data) or ():
                    self._handle(message)
            self._check_timeout(time.monotonic())

    def _link_error(self, exc: LinkError) -> None:
        with self._lock:
            self.counters["link_errors"] += 1
            first = self.last_error != str(exc)
            self.last_error = str(exc)
        if first:
            log.warning("MAVLink link %s: %s", self.link.url, exc)

    def _check_timeout(self, now: float) -> None:
        if self.connected and now - self._last_heartbeat > self.link_timeout:
            with self._lock:
                self.connected = False
                self.counters["link_losses"] += 1
            log.warning(
                "%s: MAVLink vehicle %d lost: no heartbeat for %.1f s",
                self.node.name,
                self.system,
                self.link_timeout,
            )
            self._connected.publish({"data": False})
            self._publish_diagnostics()

    # ------------------------------------------------------------------ messages in
    def _handle(self, message: Any) -> None:
        kind = message.get_type()
        if kind == "BAD_DATA":
            reason = str(getattr(message, "reason", ""))
            if "invalid MAVLink prefix" not in reason:  # noise between packets is not a CRC error
                with self._lock:
                    self.counters["crc_errors"] += 1
            return
        with self._lock:
            self.counters["received"] += 1
            self.received[kind] = self.received.get(kind, 0) + 1
        source = message.get_srcSystem()
        if (
            kind == "HEARTBEAT"
            and self.system == 0
            and source != _GCS_SYSTEM
            and message.type != self._module.MAV_TYPE_GCS
        ):
            self.system = source
            log.info("%s: following MAVLink system %d", self.node.name, source)
        if "*" in self.raw or kind in self.raw:
            self._publish_raw(kind, message)
        if source != self.system:
            return
        if kind == "HEARTBEAT":
            self._on_heartbeat(message)
        elif kind == "ATTITUDE":
            self._imu.publish(_imu(message, self._header()))
        elif kind == "GLOBAL_POSITION_INT":
            self._fix.publish(_fix(message, self._header()))
        elif kind == "BATTERY_STATUS":
            self._battery.publish(_battery(message, self._header()))
        elif kind == "COMMAND_ACK":
            waiter = self._acks.get(int(message.command))
            if waiter is not None:
                waiter[1].append(int(message.result))
                waiter[0].set()

    def _publish_raw(self, kind: str, message: Any) -> None:
        publisher = self._raw_publishers.get(kind)
        if publisher is None:
            try:
                info = raw_type(kind, self.dialect)
            except HwBridgeError as exc:
                log.debug("no ROS type for %s: %s", kind, exc)
                return
            publisher = self.node.raw_publisher(f"mavlink/{kind}", info.name, info.md5)
            self._raw_publishers[kind] = publisher
            self._closeables.append(publisher)
        publisher.publish_raw(raw_type(kind, self.dialect).serialize(message))

    def _on_heartbeat(self, message: Any) -> None:
        from pymavlink import mavutil

        self._last_heartbeat = time.monotonic()
        armed = bool(message.base_mode & self._module.MAV_MODE_FLAG_SAFETY_ARMED)
        mode = mavutil.mode_string_v10(message)
        was = self.connected
        with self._lock:
            self.connected = True
            self.armed = armed
            self.mode = mode
            self.vehicle_type = int(message.type)
            self.last_error = ""
        if not was:
            log.warning(
                "%s: MAVLink vehicle %d connected (mode %s, %s)",
                self.node.name,
                self.system,
                mode,
                "armed" if armed else "disarmed",
            )
        self._connected.publish({"data": True})
        self._armed.publish({"data": armed})
        self._mode.publish({"data": mode})

    def _header(self) -> dict[str, Any]:
        return {"stamp": self._clock(), "frame_id": self.frame_id}

    # ------------------------------------------------------------------ commands out
    def command(
        self, command: int, params: tuple[float, ...], timeout: float = _ACK_TIMEOUT
    ) -> int:
        """Send COMMAND_LONG and wait for its COMMAND_ACK; returns MAV_RESULT (raises
        HwBridgeError when no answer comes in time). Sent again (confirmation 1, then 2)
        while no answer comes, as ground stations do."""
        event, results = threading.Event(), list[int]()
        self._acks[command] = (event, results)
        values = (list(params) + [0.0] * 7)[:7]

        def send(confirmation: int) -> Callable[[Any], None]:
            return lambda mav: mav.command_long_send(self.system, 1, command, confirmation, *values)

        try:
            for confirmation in range(3):
                self._send(send(confirmation))
                if event.wait(timeout / 3):
                    return results[0]
        finally:
            self._acks.pop(command, None)
        raise HwBridgeError(
            f"vehicle {self.system} did not acknowledge command {command} within {timeout:g} s"
        )

    def _arm_service(self, request: Any) -> dict[str, Any]:
        mavlink = self._module
        arm = bool(request.data)
        if not self.connected:
            return {"success": False, "message": "no vehicle connected"}
        result = self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0 if arm else 0.0,))
        accepted = result == mavlink.MAV_RESULT_ACCEPTED
        name = (
            mavlink.enums["MAV_RESULT"][result].name
            if result in mavlink.enums["MAV_RESULT"]
            else str(result)
        )
        return {"success": accepted, "message": f"{'arm' if arm else 'disarm'}: {name}"}

    def mode_number(self, name: str) -> int:
        """The custom mode number of mode ``name`` for this vehicle (or a number as text)."""
        from pymavlink import mavutil

        text = name.strip().upper()
        if text.isdigit():
            return int(text)
        vehicle = self.vehicle_type
        mapping: Mapping[str, int] | None = (
            mavutil.mode_mapping_byname(vehicle) if vehicle is not None else None
        )
        if not mapping or text not in mapping:
            known = ", ".join(sorted(mapping)) if mapping else "none known yet"
            raise HwBridgeError(f"unknown mode {name!r} (modes: {known})")
        return int(mapping[text])

    def _on_set_mode(self, message: Any) -> None:
        try:
            number = self.mode_number(str(message.data))
        except HwBridgeError as exc:
            log.warning("%s: set_mode: %s", self.node.name, exc)
            return
        flag = self._module.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        self._send(lambda mav: mav.set_mode_send(self.system, flag, number))

    def _on_cmd_vel(self, message: Any) -> None:
        lin, ang = message.linear, message.angular
        self._send(
            lambda mav: mav.set_position_target_local_ned_send(
                0,
                self.system,
                1,
                _MAV_FRAME_BODY_OFFSET_NED,
                _VELOCITY_ONLY,
                0.0,
                0.0,
                0.0,
                float(lin.x),
                -float(lin.y),
                -float(lin.z),
                0.0,
                0.0,
                0.0,
                0.0,
                -float(ang.z),
            )
        )

    # ------------------------------------------------------------------ state
    def stats(self) -> dict[str, Any]:
        """Counters and state (a consistent snapshot)."""
        with self._lock:
            return {
                "connected": self.connected,
                "system": self.system,
                "armed": self.armed,
                "mode": self.mode,
                **self.counters,
                "messages": dict(sorted(self.received.items())),
                "last_error": self.last_error,
            }

    def _publish_diagnostics(self) -> None:
        stats = self.stats()
        level = 0 if stats["connected"] else 2
        text = "connected" if stats["connected"] else (stats["last_error"] or "no heartbeat")
        values = [
            {"key": key, "value": str(stats[key])}
            for key in ("system", "mode", "armed", *self.counters)
        ]
        self._diagnostics.publish(
            {
                "header": {"stamp": self._clock()},
                "status": [
                    {
                        "level": level,
                        "name": f"mavlink{self.node.namespace.rstrip('/')}",
                        "message": text,
                        "hardware_id": self.link.url,
                        "values": values,
                    }
                ],
            }
        )

    def close(self) -> None:
        """Stop the thread, leave the graph and close the link."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(2.0)
        for item in self._closeables:
            item.close()
        self.link.close()


# ---------------------------------------------------------------------- conversions
def _quaternion(roll: float, pitch: float, yaw: float) -> dict[str, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return {
        "x": sr * cp * cy - cr * sp * sy,
        "y": cr * sp * cy + sr * cp * sy,
        "z": cr * cp * sy - sr * sp * cy,
        "w": cr * cp * cy + sr * sp * sy,
    }


def _imu(message: Any, header: dict[str, Any]) -> dict[str, Any]:
    """ATTITUDE (NED world, FRD body) as an Imu in ENU/FLU: roll stays, pitch and the body
    rates about y and z change sign, and the heading turns from north-clockwise to
    east-counterclockwise (yaw_enu = pi/2 - yaw_ned)."""
    yaw = math.atan2(math.sin(math.pi / 2 - message.yaw), math.cos(math.pi / 2 - message.yaw))
    return {
        "header": header,
        "orientation": _quaternion(float(message.roll), -float(message.pitch), yaw),
        "orientation_covariance": [0.0] * 9,
        "angular_velocity": {
            "x": float(message.rollspeed),
            "y": -float(message.pitchspeed),
            "z": -float(message.yawspeed),
        },
        "angular_velocity_covariance": [0.0] * 9,
        "linear_acceleration": {"x": 0.0, "y": 0.0, "z": 0.0},
        "linear_acceleration_covariance": [-1.0] + [0.0] * 8,
    }


def _fix(message: Any, header: dict[str, Any]) -> dict[str, Any]:
    no_fix = message.lat == 0 and message.lon == 0
    return {
        "header": header,
        "status": {"status": -1 if no_fix else 0, "service": 1},
        "latitude": message.lat / 1e7,
        "longitude": message.lon / 1e7,
        "altitude": message.alt / 1000.0,
        "position_covariance": [0.0] * 9,
        "position_covariance_type": 0,
    }


def _battery(message: Any, header: dict[str, Any]) -> dict[str, Any]:
    cells = [v / 1000.0 for v in message.voltages if v not in (_UINT16_MAX, _UINT16_MAX - 1)]
    current = message.current_battery
    remaining = message.battery_remaining
    temperature = message.temperature
    return {
        "header": header,
        "voltage": sum(cells) if cells else math.nan,
        "temperature": temperature / 100.0 if temperature != 32767 else math.nan,
        # MAVLink counts current out of the battery as positive; ROS counts discharge negative.
        "current": -current / 100.0 if current != -1 else math.nan,
        "charge": math.nan,
        "capacity": math.nan,
        "design_capacity": math.nan,
        "percentage": remaining / 100.0 if remaining != -1 else math.nan,
        "power_supply_status": 2 if current > 0 else 0,  # DISCHARGING or UNKNOWN
        "power_supply_health": 0,
        "power_supply_technology": 3 if message.type == 1 else 0,  # LIPO
        "present": True,
        "cell_voltage": cells,
        "cell_temperature": [],
        "location": str(message.id),
        "serial_number": "",
    }
