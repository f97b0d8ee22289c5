"""Loopback emulator: virtual boards with physics, reachable like real ones (pty, TCP, memory).

``hwbridge emulate diffbot`` starts one and prints the URL to connect to; ``hwbridge demo`` runs
a board, the bridge and the device nodes together.
"""

from hwbridge.emulator.board import ROBOTS_DIR, BoardConfig, VirtualBoard, load_board
from hwbridge.emulator.world import World, WorldConfig

__all__ = ["ROBOTS_DIR", "BoardConfig", "VirtualBoard", "World", "WorldConfig", "load_board"]
