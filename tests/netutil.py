"""Test helpers: free loopback ports and bounded waiting."""

from __future__ import annotations

import hashlib
import os
import random
import signal
import socket
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def _ephemeral_low() -> int:
    """The first port of the kernel's ephemeral range (32768 if it cannot be read)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


_EPHEMERAL_LOW = _ephemeral_low()
_PORTS = random.Random()
"""Seeded from the OS: the xdist workers draw apart."""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now, drawn below the kernel's
    ephemeral range: a port the kernel hands out (to ``bind(("", 0))``, or as the local port of
    a connection the many Zenoh clients of a parallel run open) could be taken again before the
    test binds it, and a process of the suite then failed with "already in use"."""
    draws = 100 if _EPHEMERAL_LOW > 11_000 else 0  # (else the kernel's choice, below)
    for _ in range(draws):
        port = _PORTS.randrange(10_000, _EPHEMERAL_LOW)
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(sock.getsockname()[1])
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


ROS_DOMAIN_SLOTS = 3
"""Modules that start ROS 2 nodes, each with its own slot: test_ros2, test_ros2_tf, test_sigint."""


def ros_domain_id(slot: int) -> str:
    """A ROS_DOMAIN_ID (10..99) for the module with ``slot`` that no other module of this run
    uses, on any pytest-xdist worker: the run's id picks a base, the worker an offset from it
    (two runs at once on one machine may still meet, 1 in 30)."""
    assert 0 <= slot < ROS_DOMAIN_SLOTS
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID") or str(os.getpid())
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0)
    base = int(hashlib.sha256(run.encode()).hexdigest(), 16)
    return str(10 + ((base + worker) % 30) * ROS_DOMAIN_SLOTS + slot)


def wait_until(condition: Callable[[], bool], timeout: float = 10.0, step: float = 0.01) -> bool:
    """Poll ``condition`` until it holds or ``timeout`` passes; returns whether it held."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(step)
    return condition()


def call_when_ready(node: Any, name: str, srv: str, request: Any, timeout: float = 10.0) -> Any:
    """Call a service, retrying while its server's declaration has not reached us yet."""
    from hwbridge.errors import HwBridgeTimeoutError

    box: list[Any] = []

    def attempt() -> bool:
        try:
            box.append(node.call(name, srv, request, timeout=0.5))
        except HwBridgeTimeoutError:
            return False
        return True

    assert wait_until(attempt, timeout=timeout)
    return box[0]


def reap(process: Any) -> bool:
    """Wait up to 15 s for a child to end, then kill it; whether it ended by itself."""
    try:
        process.wait(15)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(5)
        return False
    return True


def stop_child(process: Any, sig: int = signal.SIGINT) -> bool:
    """Send ``sig`` to a child that still runs and :func:`reap` it."""
    if process.poll() is None:
        process.send_signal(sig)
    return reap(process)
