"""How a ``hwbridge`` process ends when its command returns (``hwbridge.cli.entry``).

It does what the interpreter's exit does first (``threading``'s exit hooks, which close open
graphs, the join of non-daemon threads, the ``atexit`` handlers, the streams flushed), and
then leaves with ``os._exit``: the finalization after that stops the threads Zenoh and rclpy
started, and one caught calling into Python aborted the process ("FATAL: exception not
rethrown", seen at the end of a successful ``hwbridge demo --firmware``). That crash is a race
no test can bring about at will; what is checked is that the process takes the way around it.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import atexit, os, sys, threading

    class Marker:
        def __del__(self):
            os.write(1, b"finalized\\n")

    marker = Marker()  # a global of __main__: collected only by the finalization
    atexit.register(lambda: os.write(1, b"atexit\\n"))

    def late():
        threading.main_thread().join()  # returns once the exit has begun
        os.write(1, b"joined\\n")

    threading.Thread(target=late).start()  # not a daemon: the exit waits for it
    sys.argv = ["hwbridge", *sys.argv[1:]]
    from hwbridge.cli import entry
    entry()
    """
)


def _hwbridge(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", SCRIPT, *argv],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_a_finished_command_runs_the_exit_hooks_and_skips_the_finalization() -> None:
    done = _hwbridge("msg", "list")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert "std_msgs/String" in lines  # the command's whole output, flushed
    assert lines[-2:] == ["joined", "atexit"], lines[-5:]
    assert "finalized" not in lines


def test_a_failed_command_keeps_its_status() -> None:
    done = _hwbridge("msg", "show", "no_such/Type")
    assert done.returncode == 1, (done.stdout, done.stderr)
    assert "no_such/Type" in done.stderr
    assert done.stdout.splitlines()[-2:] == ["joined", "atexit"]
