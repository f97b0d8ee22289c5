"""``hwbridge dxl``: talk to Dynamixel servos on a bench (scan, ping, read, write).

The URL is any link (``/dev/ttyUSB0``, ``serial:///dev/ttyUSB0?baud=1000000``, a pty path).
Serial ports default to the factory baud rate of the protocol (57600 for 2.0, 1 Mbaud for 1.0)
unless ``--baud`` or the URL's ``baud=`` says otherwise. Registers are named as in the model's
control table (``present_position``, "Present Position") or given as a raw address.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any

import typer

from hwbridge.cli.common import emit_json, stderr_console
from hwbridge.errors import HwBridgeError

if TYPE_CHECKING:
    from hwbridge.devices.dynamixel import DynamixelBus, Register

__all__ = ["dxl_app", "parse_ids"]

dxl_app = typer.Typer(
    help="Dynamixel servos on a serial bus: scan, ping, read, write.", no_args_is_help=True
)

UrlArg = Annotated[
    str,
    typer.Argument(
        metavar="URL", help="The bus: /dev/ttyUSB0, serial:///dev/ttyUSB0?baud=N, a pty path."
    ),
]
IdArg = Annotated[int, typer.Argument(metavar="ID", min=0, max=253, help="Servo ID.")]
ProtocolOpt = Annotated[
    int, typer.Option("--protocol", "-p", min=1, max=2, help="Dynamixel protocol: 1 or 2.")
]
BaudOpt = Annotated[
    int | None,
    typer.Option(
        "--baud", "-b", min=1, help="Serial baud rate (default 57600 on 2.0, 1000000 on 1.0)."
    ),
]
TimeoutOpt = Annotated[
    float, typer.Option("--timeout", "-t", min=0.001, help="Seconds to wait for a status.")
]
RetriesOpt = Annotated[int, typer.Option("--retries", min=0, help="Resends after a timeout.")]
ModelOpt = Annotated[
    str | None,
    typer.Option("--model", "-m", help="Servo model (XL430-W250, AX-12A...); default: ask it."),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable JSON output.")]

_FACTORY_BAUD = {1: 1_000_000, 2: 57600}


def parse_ids(text: str) -> list[int]:
    """``0-20``, ``1,2,5`` or ``1-3,7`` to a sorted list of IDs."""
    ids: set[int] = set()
    for part in text.replace(" ", "").split(","):
        if not part:
            continue
        low, sep, high = part.partition("-")
        try:
            first = int(low)
            last = int(high) if sep else first
        except ValueError:
            raise typer.BadParameter(
                f"{part!r} is not an ID or a range such as 0-20", param_hint="--ids"
            ) from None
        if first > last or first < 0 or last > 253:
            raise typer.BadParameter(f"bad ID range {part!r} (IDs are 0-253)", param_hint="--ids")
        ids.update(range(first, last + 1))
    if not ids:
        raise typer.BadParameter("no IDs given", param_hint="--ids")
    return sorted(ids)


def _open_bus(
    url: str, protocol: int, baud: int | None, timeout: float, retries: int
) -> DynamixelBus:
    from hwbridge.devices.dynamixel import DynamixelBus
    from hwbridge.links import open_link
    from hwbridge.links.registry import scheme_of

    options: dict[str, Any] = {}
    if scheme_of(url) == "serial":
        if baud is not None:
            options["baud"] = baud
        elif "baud=" not in url:
            options["baud"] = _FACTORY_BAUD[protocol]
    elif baud is not None:
        raise typer.BadParameter("--baud applies to serial ports only", param_hint="--baud")
    link = open_link(url, **options)
    return DynamixelBus(link, protocol, timeout=timeout, retries=retries, owns_link=True)


def _resolve(
    bus: DynamixelBus, id_: int, target: str, size: int | None, model: str | None
) -> tuple[int, int, Register | None]:
    """(address, size, register or None) for a register name or a raw address."""
    if model is not None:
        bus.set_model(id_, model)
    text = target.strip()
    if text.isdigit() or text.lower().startswith("0x"):
        address = int(text, 0)
        register = None
        try:
            register = bus.model(id_).table.at(address)
        except HwBridgeError:
            register = None  # an unknown model: raw access still works
        if size is None:
            size = register.size if register is not None else 1
        if register is not None and register.size != size:
            register = None
        return address, size, register
    register = bus.register(id_, text)
    if size is not None and size != register.size:
        raise typer.BadParameter(
            f"{register.name} is {register.size} bytes, not {size}", param_hint="SIZE"
        )
    return register.address, register.size, register


@dxl_app.command("scan")
def scan(
    url: UrlArg,
    protocol: ProtocolOpt = 2,
    baud: BaudOpt = None,
    ids: Annotated[
        str | None, typer.Option("--ids", help="IDs to look for: 0-20, 1,2,5 (default all).")
    ] = None,
    timeout: TimeoutOpt = 0.05,
    retries: RetriesOpt = 0,
    as_json: JsonOpt = False,
) -> None:
    """Find the servos on a bus (one broadcast PING on 2.0, a PING per ID on 1.0)."""
    wanted = parse_ids(ids) if ids else None
    with _open_bus(url, protocol, baud, timeout, retries) as bus:
        found = bus.scan(wanted)
    if as_json:
        emit_json([r.as_dict() for r in found])
    else:
        for result in found:
            typer.echo(
                _describe(result.id, result.model_name, result.model_number, result.firmware)
            )
    if not found:
        span = f"IDs {ids}" if ids else "any ID"
        stderr_console().print(
            f"no servo answered on {url} (Protocol {protocol}.0, {span}); check power, wiring, "
            "--protocol and --baud",
            highlight=False,
            markup=False,
        )
        raise typer.Exit(1)


def _describe(id_: int, name: str, number: int | None, firmware: int | None) -> str:
    details = []
    if number is not None:
        details.append(f"model {number}")
    if firmware is not None:
        details.append(f"firmware {firmware}")
    extra = f" ({', '.join(details)})" if details and not name.startswith("model ") else ""
    return f"servo {id_}: {name}{extra}"


@dxl_app.command("ping")
def ping(
    url: UrlArg,
    id_: IdArg,
    protocol: ProtocolOpt = 2,
    baud: BaudOpt = None,
    timeout: TimeoutOpt = 0.05,
    retries: RetriesOpt = 0,
    as_json: JsonOpt = False,
) -> None:
    """PING one servo and show its model and firmware."""
    with _open_bus(url, protocol, baud, timeout, retries) as bus:
        result = bus.ping(id_)
    if as_json:
        emit_json(result.as_dict())
    else:
        typer.echo(_describe(result.id, result.model_name, result.model_number, result.firmware))


@dxl_app.command("read")
def read(
    url: UrlArg,
    id_: IdArg,
    target: Annotated[
        str, typer.Argument(metavar="REGISTER|ADDR", help="Register name or address.")
    ],
    size: Annotated[
        int | None, typer.Argument(metavar="[SIZE]", min=1, max=1024, help="Bytes (raw reads).")
    ] = None,
    protocol: ProtocolOpt = 2,
    baud: BaudOpt = None,
    model: ModelOpt = None,
    timeout: TimeoutOpt = 0.05,
    retries: RetriesOpt = 0,
    as_json: JsonOpt = False,
) -> None:
    """Read a register (by name from the model's control table) or raw bytes at an address."""
    with _open_bus(url, protocol, baud, timeout, retries) as bus:
        address, length, register = _resolve(bus, id_, target, size, model)
        data = bus.read(id_, address, length)
        value = register.decode(data) if register is not None else int.from_bytes(data, "little")
        converted = _converted(bus, id_, register, value)
    if as_json:
        emit_json(
            {
                "id": id_,
                "register": register.name if register is not None else None,
                "address": address,
                "size": length,
                "value": value,
                "bytes": data.hex(),
                **converted,
            }
        )
        return
    label = register.name if register is not None else "raw"
    unit = f" [{register.unit}]" if register is not None and register.unit else ""
    extra = "".join(
        f", {v:.4f} {k.split('_', 1)[1].replace('_', '/')}" for k, v in converted.items()
    )
    typer.echo(
        f"servo {id_} {label} ({address}, {length} byte{'s' if length > 1 else ''}): "
        f"{value}{unit}{extra}  [{data.hex(' ')}]"
    )


def _converted(
    bus: DynamixelBus, id_: int, register: Register | None, value: int
) -> dict[str, float]:
    """SI values of position and velocity registers (rad, rad/s)."""
    if register is None:
        return {}
    try:
        model = bus.model(id_)
    except HwBridgeError:
        return {}
    if register.name in ("Present Position", "Goal Position", "Position Trajectory"):
        return {"value_rad": model.ticks_to_radians(value)}
    if register.name in (
        "Present Velocity",
        "Goal Velocity",
        "Velocity Trajectory",
        "Present Speed",
        "Moving Speed",
    ):
        return {"value_rad_s": model.velocity_to_rad_s(value)}
    return {}


def _parse_value(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise typer.BadParameter(
            f"{text!r} is not an integer (decimal, 0x.. hex, negative allowed)", param_hint="VALUE"
        ) from None


@dxl_app.command("write")
def write(
    url: UrlArg,
    id_: IdArg,
    target: Annotated[
        str, typer.Argument(metavar="REGISTER|ADDR", help="Register name or address.")
    ],
    value: Annotated[
        str,
        typer.Argument(
            metavar="VALUE", help="Integer, 0x.. allowed; put -- before a negative one."
        ),
    ],
    size: Annotated[
        int | None, typer.Option("--size", "-s", min=1, max=4, help="Bytes (raw addresses).")
    ] = None,
    protocol: ProtocolOpt = 2,
    baud: BaudOpt = None,
    model: ModelOpt = None,
    timeout: TimeoutOpt = 0.05,
    retries: RetriesOpt = 0,
    as_json: JsonOpt = False,
) -> None:
    """Write a register (by name) or raw bytes at an address (little-endian)."""
    number = _parse_value(value)
    with _open_bus(url, protocol, baud, timeout, retries) as bus:
        address, length, register = _resolve(bus, id_, target, size, model)
        try:
            if register is not None:
                data = register.encode(number)
            else:
                data = number.to_bytes(length, "little", signed=number < 0)
        except (ValueError, OverflowError) as exc:
            raise typer.BadParameter(
                f"{number} does not fit {length} byte(s): {exc}", param_hint="VALUE"
            ) from None
        bus.write(id_, address, data)
    name = register.name if register is not None else "raw"
    if as_json:
        emit_json(
            {
                "id": id_,
                "register": register.name if register else None,
                "address": address,
                "size": length,
                "value": number,
                "ok": True,
            }
        )
    else:
        plural = "s" if length > 1 else ""
        typer.echo(f"servo {id_}: wrote {number} to {name} ({address}, {length} byte{plural})")
