"""Record graph topics to MCAP files and play them back, bytes unchanged.

Files follow MCAP's ``ros1`` profile, so Foxglove, the ``mcap`` CLI and ``rosbags`` read them:
one schema per message type (encoding ``ros1msg``, name the ROS 1 type name, data the full
definition text with its dependencies, as rosbag stores it), one channel per topic and type
(message encoding ``ros1``, metadata ``md5sum`` and ``type`` as in a rosbag connection header),
and the ROS 1 serialized bytes exactly as they travelled on the graph::

    from hwbridge.graph import Graph
    from hwbridge.recorder import Player, Recorder

    with Graph.attached() as graph:
        with Recorder(graph, "run.mcap", ["/odom", "/imu"], limit=1000) as recorder:
            recorder.wait()                       # until 1000 messages (or stop() elsewhere)
        print(recorder.stats.messages)
        Player(graph, "run.mcap", rate=2.0).run()

A message's log and publish times are both the time it was received (the graph carries no send
time). A message whose type is not in the registry (or whose md5 differs from the registry's) is
still recorded, on a channel without a schema that keeps the type and md5 in its metadata.
"""

from __future__ import annotations

from hwbridge.recorder.common import (
    ChannelStats,
    PlayerStats,
    RecorderStats,
    RecordingError,
)
from hwbridge.recorder.play import Player
from hwbridge.recorder.record import COMPRESSIONS, Compression, Recorder

__all__ = [
    "COMPRESSIONS",
    "ChannelStats",
    "Compression",
    "Player",
    "PlayerStats",
    "Recorder",
    "RecorderStats",
    "RecordingError",
]
