"""The host's end of a native session: one per board link."""

from __future__ import annotations

import random
from typing import Any

from hwbridge.protocols.native._control.common import Features, Role
from hwbridge.protocols.native._framing.links import NativeFraming
from hwbridge.protocols.native._session.config import BoardInfo, HostConfig, TypeCheck
from hwbridge.protocols.native._session.core import SessionCore
from hwbridge.protocols.native._session.events import HostEvent
from hwbridge.protocols.native._session.handshake import Handshake
from hwbridge.protocols.native._session.params import HostParams
from hwbridge.protocols.native._session.receive import Receiver
from hwbridge.protocols.native._session.services import Services
from hwbridge.protocols.native._session.timesync import HostTime
from hwbridge.protocols.native._session.topics import HostTable
from hwbridge.protocols.native.control import (
    BoardInfoMsg,
    ControlMessage,
    EntryKind,
    HostTimeResponseMsg,
    ParamGetMsg,
    TableEndMsg,
    TimeRequestMsg,
    TopicMsg,
)


class HostSession(
    HostTable,
    HostParams,
    HostTime,
    Services,
    Handshake,
    Receiver,
    SessionCore[HostEvent],
):
    """The host's end of one board link; a :class:`hwbridge.protocols.base.BoardSession`.

    ``type_check`` is called for every entry the board announces and returns the type the host
    expects for it (for example from its type registry or from the topic already on the graph),
    or None to accept the entry as announced. A different type name or md5 refuses the entry:
    an :class:`Error` event carries a :class:`TopicMismatchError` and the board is told too.

    ``framing`` is how frames travel on the link: :class:`NativeStreamFraming` (the default:
    serial, TCP) or :class:`NativeDatagramFraming` (one frame per datagram). With ``now`` the
    session starts at once: its first HELLO waits in :meth:`chunks_to_send`; otherwise it goes
    out on the first ``tick`` (or answers the board's HELLO, if that comes first).
    """

    _ROLE = Role.HOST
    _PUBLISH_KIND = EntryKind.SUBSCRIBER
    _RECEIVE_KIND = EntryKind.PUBLISHER
    _CALL_KIND = EntryKind.SERVICE_SERVER
    _SERVE_KIND = EntryKind.SERVICE_CLIENT

    def __init__(
        self,
        config: HostConfig | None = None,
        *,
        type_check: TypeCheck | None = None,
        framing: NativeFraming | None = None,
        session_id: int | None = None,
        rng: random.Random | None = None,
        now: float | None = None,
    ) -> None:
        self._host_cfg = config if config is not None else HostConfig()
        super().__init__(self._host_cfg, framing=framing, session_id=session_id, rng=rng)
        self._type_check = type_check
        self._board: BoardInfo | None = None
        self._announced = {}
        self._topics = {}
        self._init_params()
        self._start(now)

    def describe(self) -> dict[str, Any]:
        """The board and the session, for ``hwbridge board info`` (JSON-able)."""
        board = self._board
        link = self._link
        return {
            "protocol": "native",
            "state": self._state.value,
            "board": board.name if board is not None else None,
            "unique_id": board.unique_id.hex() if board is not None else None,
            "firmware_version": board.identity.version if board is not None else None,
            "mtu": link.mtu if link is not None else None,
            "window": link.window if link is not None else None,
            "features": _feature_names(link.features) if link is not None else None,
            "host_session": self._id,
            "device_session": self.peer_session_id or None,
            "rtt": self._rtt.srtt,
            "datagram": self._framing.datagram,
        }

    def _may_log(self) -> bool:
        return self._link is not None and bool(self._link.features & Features.HOST_LOG)

    def _on_teardown(self) -> None:
        self._board = None
        self._announced.clear()
        self._topics.clear()
        self._clear_params()

    def _on_role_control(self, msg: ControlMessage) -> bool:
        if isinstance(msg, TimeRequestMsg):
            self._answer_time_request(msg)
        elif isinstance(msg, HostTimeResponseMsg):
            self._on_time_response(msg)
        elif isinstance(msg, BoardInfoMsg):
            self._board = BoardInfo(msg.name, msg.unique_id, msg.firmware_version)
        elif isinstance(msg, TopicMsg):
            self._on_topic(msg)
        elif isinstance(msg, TableEndMsg):
            self._on_table_end(msg)
        elif isinstance(msg, ParamGetMsg):
            self._on_param_get(msg)
        else:
            return False
        return True

    def _hello_context(self) -> str:
        return (
            " (is the board connected, powered, flashed with hwbridge firmware, and is the baud "
            "rate right?)"
        )


def _feature_names(features: Features) -> list[str]:
    """The names of the features a session negotiated (PROTOCOL.md 2.14), lowest bit first."""
    return [f.name for f in Features if f and f & features and f.name is not None]
