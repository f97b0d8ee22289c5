"""Helpers shared by the benchmarks: timing loops and the JSON line format.

Every benchmark prints one JSON object per line with at least ``bench``, the case (``payload``
or ``type``) and ``hwbridge_per_s``; where a peer is measured also ``peer``, ``peer_per_s`` and
``ratio`` (hwbridge / peer).
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections.abc import Callable
from typing import Any


def rate(
    work: Callable[[], object], count: int, *, repeats: int = 5, budget_s: float = 1.0
) -> float:
    """Best operations per second of ``work`` (which performs ``count`` operations per call)."""
    best = 0.0
    deadline = time.perf_counter() + budget_s
    for _ in range(repeats):
        start = time.perf_counter()
        work()
        elapsed = time.perf_counter() - start
        best = max(best, count / elapsed if elapsed > 0 else float("inf"))
        if time.perf_counter() > deadline:
            break
    return best


def emit(
    bench: str,
    case: dict[str, Any],
    ours: float,
    peer: str | None = None,
    theirs: float | None = None,
    **extra: Any,
) -> None:
    """Print one benchmark line."""
    line: dict[str, Any] = {"bench": bench, **case, "hwbridge_per_s": round(ours, 1)}
    if peer is not None and theirs is not None:
        line.update(peer=peer, peer_per_s=round(theirs, 1), ratio=round(ours / theirs, 3))
    line.update(extra)
    sys.stdout.write(json.dumps(line) + "\n")
    sys.stdout.flush()


def free_port() -> int:
    """A TCP port nobody listens on now (on 127.0.0.1)."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def hwbridge_command() -> list[str]:
    """The installed console script next to this interpreter, else ``python -m hwbridge``."""
    import sys
    from pathlib import Path

    script = Path(sys.executable).with_name("hwbridge")
    return [str(script)] if script.exists() else [sys.executable, "-m", "hwbridge"]


def proc_sample(pid: int) -> dict[str, int]:
    """RSS (kB), threads and open descriptors of process ``pid``, from /proc."""
    from pathlib import Path

    rss = 0
    with Path(f"/proc/{pid}/status").open(encoding="ascii") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                rss = int(line.split()[1])
                break
    return {
        "rss_kb": rss,
        "threads": sum(1 for _ in Path(f"/proc/{pid}/task").iterdir()),
        "fds": sum(1 for _ in Path(f"/proc/{pid}/fd").iterdir()),
    }


def stop_process(process: Any, sig: int | None = None) -> None:
    """Send ``sig`` (default SIGTERM) to a child still running; kill it after 10 s."""
    import signal
    import subprocess

    if process.poll() is None:
        process.send_signal(signal.SIGTERM if sig is None else sig)
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def child_line(process: Any, what: str, timeout: float = 60.0) -> str:
    """The next line of a child's stdout, stripped (RuntimeError naming ``what`` if the child
    ends or says nothing for ``timeout`` seconds)."""
    out = process.stdout
    assert out is not None
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(out.readline()), daemon=True)
    reader.start()
    reader.join(timeout)
    if not got or not got[0]:
        raise RuntimeError(f"{what}: no answer (status {process.poll()})")
    return str(got[0]).strip()
