"""Tools whose output is piped into a reader that stops early (``hwbridge topic echo T | head -1``)
end quietly, as ``topic hz`` and the other commands writing from the main thread do."""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Iterator

import pytest

from hwbridge.graph import Graph


@pytest.fixture(scope="module")
def chatter(router: Graph) -> Iterator[None]:
    """``/pipes/chatter`` published at 100 Hz for the module."""
    publisher = router.node("talker", namespace="/pipes").publisher("chatter", "std_msgs/String")
    stop = threading.Event()

    def run() -> None:
        count = 0
        while not stop.is_set():
            publisher.publish({"data": f"hello {count}"})
            count += 1
            stop.wait(0.01)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    yield
    stop.set()
    thread.join()


@pytest.mark.parametrize("options", [[], ["--json"]])
def test_topic_echo_into_a_reader_that_stops(
    chatter: None, endpoint: str, graph_domain: str, options: list[str]
) -> None:
    argv = ["--endpoint", endpoint, "--domain", graph_domain, "topic", "echo", "/pipes/chatter"]
    echo = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", *argv, *options],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert echo.stdout is not None
        first = echo.stdout.readline()
        assert "hello" in first, echo.stderr.read() if echo.stderr else ""
        echo.stdout.close()  # what `head -1` does after its line
        _, err = echo.communicate(timeout=30)
    finally:
        if echo.poll() is None:
            echo.kill()
            echo.wait()
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert err == ""
    assert echo.returncode == 1
