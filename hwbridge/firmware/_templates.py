"""The fixed C++ text of the generated headers: real ``.h`` files under ``templates/``.

``hwbridge_wire.h`` (the byte helpers: little-endian loads and stores, the bounded Reader and
Writer, the frame CRC) and ``hwbridge_msg.h`` (ROS 1 strings, arrays, time, float64 on top of
them) are copied as they are; ``control_prelude.h`` is the fixed start of
``hwbridge_control_base.h``, the part of ``hwbridge_control.h`` the other parts include.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Final

__all__ = ["TEMPLATE_DIR", "WIRE_NAME", "template"]

TEMPLATE_DIR: Final = Path(__file__).resolve().parent / "templates"
WIRE_NAME: Final = "hwbridge_wire.h"


@cache
def template(name: str) -> str:
    """The text of ``templates/NAME``."""
    return (TEMPLATE_DIR / name).read_text(encoding="utf-8")
