"""The board's end of a native session: emulated boards, and the firmware's specification."""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Sequence

from hwbridge.protocols.native._control.common import Role
from hwbridge.protocols.native._framing.links import NativeFraming
from hwbridge.protocols.native._session.config import (
    _MAX_TIME_SAMPLES,
    BoardInfo,
    DeviceConfig,
    TopicEntry,
)
from hwbridge.protocols.native._session.core import SessionCore
from hwbridge.protocols.native._session.events import Event
from hwbridge.protocols.native._session.handshake import Handshake
from hwbridge.protocols.native._session.params import DeviceParams
from hwbridge.protocols.native._session.receive import Receiver
from hwbridge.protocols.native._session.services import Services
from hwbridge.protocols.native._session.timesync import DeviceTime
from hwbridge.protocols.native._session.topics import DeviceTable
from hwbridge.protocols.native.control import (
    ControlMessage,
    EntryKind,
    HostTimeRequestMsg,
    ParamValueMsg,
    ReadyMsg,
    TimeResponseMsg,
    TopicAckMsg,
)


class DeviceSession(
    DeviceTable,
    DeviceParams,
    DeviceTime,
    Services,
    Handshake,
    Receiver,
    SessionCore[Event],
):
    """A board's end of the link: announces its table, publishes, serves, asks for params.

    It honours its configured limits: the host never gets a reason to send it a frame larger
    than ``config.mtu`` or a message larger than ``config.max_message``, and its own decoder
    rejects anything larger. A real board picks a new random session id at every boot; create a
    new DeviceSession to emulate a reset. With ``now`` it announces itself at once (its first
    HELLO waits in :meth:`chunks_to_send`), as a board does at boot; otherwise on the first
    ``tick``.
    """

    _ROLE = Role.DEVICE
    _PUBLISH_KIND = EntryKind.PUBLISHER
    _RECEIVE_KIND = EntryKind.SUBSCRIBER
    _CALL_KIND = EntryKind.SERVICE_CLIENT
    _SERVE_KIND = EntryKind.SERVICE_SERVER

    def __init__(
        self,
        board: BoardInfo,
        topics: Sequence[TopicEntry] = (),
        config: DeviceConfig | None = None,
        *,
        framing: NativeFraming | None = None,
        session_id: int | None = None,
        rng: random.Random | None = None,
        now: float | None = None,
    ) -> None:
        super().__init__(
            config if config is not None else DeviceConfig(),
            framing=framing,
            session_id=session_id,
            rng=rng,
        )
        self._board = board
        table: dict[int, TopicEntry] = {}
        for entry in topics:
            if entry.channel in table:
                raise ValueError(
                    f"channel {entry.channel} used twice ({table[entry.channel].name}, "
                    f"{entry.name})"
                )
            table[entry.channel] = entry
        if len(table) > 255:
            raise ValueError(f"{len(table)} entries; a board announces at most 255")
        self._table = table
        self._accepted = set()
        self._params = {}
        self._time_offset_samples = deque(maxlen=_MAX_TIME_SAMPLES)
        self._start(now)

    def _on_teardown(self) -> None:
        self._accepted.clear()
        self._time_offset_samples.clear()

    def _on_role_control(self, msg: ControlMessage) -> bool:
        if isinstance(msg, HostTimeRequestMsg):
            self._answer_time_request(msg)
        elif isinstance(msg, TimeResponseMsg):
            self._on_time_response(msg)
        elif isinstance(msg, TopicAckMsg):
            self._on_topic_ack(msg)
        elif isinstance(msg, ReadyMsg):
            self._on_ready(msg)
        elif isinstance(msg, ParamValueMsg):
            self._on_param_value(msg)
        else:
            return False
        return True
