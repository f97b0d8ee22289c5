"""Drive ``tests/viz/js/client.mjs``: a Foxglove viewer's connection made with the npm package
``@foxglove/ws-protocol`` (``FoxgloveClient`` over ``ws``) under Node.js, which decodes and
encodes ROS 1 messages with Foxglove's own ``@foxglove/rosmsg-serialization``.

Commands go to its stdin and its events come back as JSON lines; :meth:`NodeClient.wait_for`
waits for an event with a deadline and fails with the last events seen."""

from __future__ import annotations

import contextlib
import json
import shutil
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

JS_DIR = Path(__file__).resolve().parent / "js"
CLIENT = JS_DIR / "client.mjs"

Event = dict[str, Any]

_install_lock = threading.Lock()


def node_or_skip() -> str:
    """The ``node`` executable, with the npm packages installed (``npm ci``) if missing."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("Node.js is not installed (tools/test installs Debian's nodejs and npm)")
    with _install_lock:
        if not (JS_DIR / "node_modules" / "@foxglove" / "ws-protocol").is_dir():
            npm = shutil.which("npm")
            if npm is None:
                pytest.fail("node is here but npm is not: install npm to fetch the test client")
            done = subprocess.run(
                [npm, "ci", "--no-audit", "--no-fund"],
                cwd=JS_DIR,
                capture_output=True,
                text=True,
                timeout=600,
                check=False,
            )
            if done.returncode != 0:
                pytest.fail(f"npm ci in {JS_DIR} failed:\n{done.stdout}\n{done.stderr}")
    return node


class NodeClient:
    """One ``client.mjs`` process connected to ``url`` offering ``subprotocol``."""

    def __init__(self, url: str, subprotocol: str, log: Path) -> None:
        node = node_or_skip()
        self.log = log
        self.process = subprocess.Popen(
            [node, str(CLIENT), url, subprotocol],
            cwd=JS_DIR,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=log.open("w"),
            text=True,
        )
        self.events: list[Event] = []
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                event = {"event": "unparsed", "line": line}
            with self._changed:
                self.events.append(event)
                self._changed.notify_all()
        with self._changed:
            self.events.append({"event": "exited"})
            self._changed.notify_all()

    def send(self, **command: Any) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write(json.dumps(command) + "\n")
        self.process.stdin.flush()

    def find(self, predicate: Callable[[Event], bool], start: int = 0) -> Event | None:
        with self._changed:
            return next((e for e in self.events[start:] if predicate(e)), None)

    def wait_for(
        self, predicate: Callable[[Event], bool], what: str, timeout: float = 30.0, start: int = 0
    ) -> Event:
        """The first event from index ``start`` on that satisfies ``predicate``."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                found = next((e for e in self.events[start:] if predicate(e)), None)
                if found is not None:
                    return found
                left = deadline - time.monotonic()
                if left <= 0 or (self.events and self.events[-1]["event"] == "exited"):
                    break
                self._changed.wait(left)
            recent = [e for e in self.events if e["event"] not in ("message", "time")][-15:]
        pytest.fail(
            f"the Foxglove client saw no {what}; its last events: {recent}\n"
            f"its stderr: {self.log.read_text()}"
        )

    def event(self, kind: str, timeout: float = 30.0, **fields: Any) -> Event:
        """The first event of ``kind`` whose fields include ``fields``."""
        return self.wait_for(
            lambda e: e["event"] == kind and all(e.get(k) == v for k, v in fields.items()),
            f"{kind} event with {fields}",
            timeout,
        )

    def close(self) -> None:
        if self.process.poll() is None:
            with contextlib.suppress(BrokenPipeError, OSError):
                self.send(cmd="close")
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        if self.process.stdin is not None:
            self.process.stdin.close()

    def __enter__(self) -> NodeClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
