"""An emulated MAVLink vehicle: pymavlink on the far end of a UDP socket or a serial port
(a pty), speaking as a small ArduPilot-like rover would.

It sends HEARTBEAT, ATTITUDE, GLOBAL_POSITION_INT, BATTERY_STATUS and SYS_STATUS at their
rates; it obeys COMMAND_LONG ``MAV_CMD_COMPONENT_ARM_DISARM`` (answering COMMAND_ACK), SET_MODE
and ``MAV_CMD_DO_SET_MODE``, and velocity setpoints (SET_POSITION_TARGET_LOCAL_NED in the body
frame), which move it while it is armed. :meth:`MavlinkVehicle.pause` makes it fall silent (a
radio out of range) until :meth:`MavlinkVehicle.resume`.

Run it alone with ``python -m hwbridge.emulator.mavlink_vehicle udpout:127.0.0.1:14550``.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Final

__all__ = ["MavlinkVehicle", "VehicleState"]


def _dialect() -> Any:
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


_RATES: Final[dict[str, float]] = {
    "HEARTBEAT": 5.0,
    "ATTITUDE": 20.0,
    "GLOBAL_POSITION_INT": 5.0,
    "BATTERY_STATUS": 2.0,
    "SYS_STATUS": 1.0,
}
_EARTH_RADIUS: Final = 6_378_137.0


@dataclass
class VehicleState:
    """What the vehicle is doing (read it under :attr:`MavlinkVehicle.lock`)."""

    armed: bool = False
    custom_mode: int = 0
    """ArduPilot Rover's mode number (0 MANUAL, 4 HOLD, 10 AUTO, 15 GUIDED...)."""
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """The last body-frame velocity setpoint (forward, right, down; m/s)."""
    yaw_rate: float = 0.0
    lat: float = 47.397742
    lon: float = 8.545594
    alt: float = 488.0
    yaw: float = 0.0
    commands: list[int] = field(default_factory=list)
    """Every COMMAND_LONG command number received, in order."""
    gcs_heartbeats: int = 0
    """HEARTBEATs received from the ground station (the bridge)."""
    setpoints: int = 0


class MavlinkVehicle:
    """The vehicle on pymavlink connection ``device`` (``udpout:HOST:PORT``, a serial path...).

    ``start()`` runs it on a thread; ``close()`` stops it and closes the connection.
    """

    def __init__(
        self,
        device: str,
        *,
        system: int = 1,
        component: int = 1,
        rates: dict[str, float] | None = None,
        baud: int = 115200,
    ) -> None:
        from pymavlink import mavutil

        self.device = device
        self.state = VehicleState()
        self.lock = threading.Lock()
        self.rates = {**_RATES, **(rates or {})}
        self.sent: dict[str, int] = dict.fromkeys(self.rates, 0)
        self._conn: Any = mavutil.mavlink_connection(
            device,
            baud=baud,
            source_system=system,
            source_component=component,
            dialect="ardupilotmega",
        )
        self._mav: Any = self._conn.mav
        self._silent = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = time.monotonic()

    # ------------------------------------------------------------------ control
    def start(self) -> MavlinkVehicle:
        self._thread = threading.Thread(target=self._run, name="mavlink-vehicle", daemon=True)
        self._thread.start()
        return self

    def pause(self) -> None:
        """Stop sending anything (commands received are still obeyed)."""
        self._silent.set()

    def resume(self) -> None:
        self._silent.clear()

    def send_corrupted(self) -> None:
        """Send one HEARTBEAT with a payload byte flipped after its checksum was computed (the
        receiver must count a CRC error and drop it)."""
        mavlink = _dialect()
        message = self._mav.heartbeat_encode(
            mavlink.MAV_TYPE_GROUND_ROVER, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0
        )
        packet = bytearray(message.pack(self._mav))
        packet[12] ^= 0xFF  # a payload byte (MAVLink 2: 10 header bytes before the payload)
        self._conn.write(bytes(packet))

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self._conn.close()

    def __enter__(self) -> MavlinkVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ the loop
    def _run(self) -> None:
        due = dict.fromkeys(self.rates, 0.0)
        last = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            self._move(now - last)
            last = now
            for name, rate in self.rates.items():
                if rate > 0 and now >= due[name]:
                    due[name] = now + 1.0 / rate
                    if not self._silent.is_set():
                        self._send(name, now)
            self._receive()
            time.sleep(0.005)

    def _receive(self) -> None:
        while True:
            try:
                message = self._conn.recv_msg()
            except (OSError, ValueError):
                return
            if message is None:
                return
            self._handle(message)

    def _handle(self, message: Any) -> None:
        mavlink = _dialect()
        kind = message.get_type()
        if kind == "HEARTBEAT":
            with self.lock:
                self.state.gcs_heartbeats += 1
        elif kind == "COMMAND_LONG":
            result = mavlink.MAV_RESULT_ACCEPTED
            with self.lock:
                self.state.commands.append(int(message.command))
                if message.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                    self.state.armed = message.param1 > 0.5
                elif message.command == mavlink.MAV_CMD_DO_SET_MODE:
                    self.state.custom_mode = int(message.param2)
                else:
                    result = mavlink.MAV_RESULT_UNSUPPORTED
            self._mav.command_ack_send(message.command, result)
        elif kind == "SET_MODE":
            with self.lock:
                self.state.custom_mode = int(message.custom_mode)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            with self.lock:
                self.state.velocity = (float(message.vx), float(message.vy), float(message.vz))
                self.state.yaw_rate = float(message.yaw_rate)
                self.state.setpoints += 1

    def _move(self, dt: float) -> None:
        with self.lock:
            s = self.state
            if not s.armed:
                return
            s.yaw = (s.yaw + s.yaw_rate * dt + math.pi) % (2 * math.pi) - math.pi
            north = (s.velocity[0] * math.cos(s.yaw) - s.velocity[1] * math.sin(s.yaw)) * dt
            east = (s.velocity[0] * math.sin(s.yaw) + s.velocity[1] * math.cos(s.yaw)) * dt
            s.lat += math.degrees(north / _EARTH_RADIUS)
            s.lon += math.degrees(east / (_EARTH_RADIUS * math.cos(math.radians(s.lat))))

    def _send(self, name: str, now: float) -> None:
        mavlink = _dialect()
        mav = self._mav
        boot_ms = int((now - self._started) * 1000) & 0xFFFFFFFF
        with self.lock:
            s = VehicleState(**vars(self.state))
        if name == "HEARTBEAT":
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            if s.armed:
                base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            mav.heartbeat_send(
                mavlink.MAV_TYPE_GROUND_ROVER,
                mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                base,
                s.custom_mode,
                mavlink.MAV_STATE_ACTIVE if s.armed else mavlink.MAV_STATE_STANDBY,
            )
        elif name == "ATTITUDE":
            t = now - self._started
            mav.attitude_send(boot_ms, 0.05 * math.sin(t), -0.02, s.yaw, 0.05, 0.0, s.yaw_rate)
        elif name == "GLOBAL_POSITION_INT":
            v = s.velocity if s.armed else (0.0, 0.0, 0.0)
            mav.global_position_int_send(
                boot_ms,
                round(s.lat * 1e7),
                round(s.lon * 1e7),
                round(s.alt * 1000),
                0,
                round(v[0] * math.cos(s.yaw) * 100),
                round(v[0] * math.sin(s.yaw) * 100),
                0,
                round(math.degrees(s.yaw) % 360 * 100),
            )
        elif name == "BATTERY_STATUS":
            cells = [3950, 3950, 3950] + [65535] * 7
            mav.battery_status_send(
                0,
                mavlink.MAV_BATTERY_FUNCTION_ALL,
                mavlink.MAV_BATTERY_TYPE_LIPO,
                2500,
                cells,
                1200 if s.armed else 150,
                -1,
                -1,
                76,
            )
        elif name == "SYS_STATUS":
            mav.sys_status_send(0, 0, 0, 250, 11850, 150, 76, 0, 0, 0, 0, 0, 0)
        self.sent[name] += 1


def main(argv: list[str] | None = None) -> int:
    """``python -m hwbridge.emulator.mavlink_vehicle DEVICE``: run until Ctrl-C."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        sys.stderr.write("usage: python -m hwbridge.emulator.mavlink_vehicle udpout:HOST:PORT\n")
        return 2
    vehicle = MavlinkVehicle(args[0]).start()
    sys.stderr.write(f"MAVLink vehicle on {args[0]}; Ctrl-C stops\n")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        vehicle.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
