"""Ctrl-C while a command is still importing what it needs stops it there, not later.

A command imports most of its code lazily, after ``main`` has taken the signals over
(``hwbridge emulate`` imports the emulator and the device plugins; its URL comes about a second
after the start on a 2-core machine without .pyc files). An import spends most of its time in
C (compiling, reading, stat) called from the import system's own frames, where the signal
handler does not raise (an exception there may be dropped or leave an import lock taken). It
used to wait for a later interruption (every 50 ms) that happened to land elsewhere: 0.2-1.1 s
after the signal, and meanwhile the command went on starting (``emulate dxl-bus`` printed its
URL after the Ctrl-C). Now the handler has the KeyboardInterrupt raised as the next Python
function outside the import system starts (``hwbridge.cli.stopping._raise_on_next_call``).

The test makes the moment deterministic instead of timing it: the robot file's device plugin
(an entry point on a folder of this test) waits in the import system for a module that
another thread is importing, the test signals it there, and once the signal has come the other
thread lets the import finish; the plugin then calls a function that sleeps for a minute in C,
where no later interruption lands. Before the fix the KeyboardInterrupt was never raised: the
command ended only through the forced exit 1.5 s after the signal ("exiting now"). Now it ends
with 130 through the KeyboardInterrupt, without the forced exit. The only time involved is that
forced exit's own 1.5 s deadline, which the fixed command misses only if it gets no CPU for
over a second right after the signal; the wait for the exit is 60 s, generous for any machine.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SYNC = """\
import threading

inside = threading.Event()
"""

HELD = """\
# Imported by a thread of slowdev_plugin: holds this module's import lock until the command got
# its signal (and a moment more, for the main thread to run its handler in the import system).
import time

import slowdev_sync
from hwbridge.cli import stopping

slowdev_sync.inside.set()
stopping.STOP.wait()
time.sleep(0.2)
"""

PLUGIN = """\
import threading
import time

import slowdev_sync


def _hold() -> None:
    import slowdev_held  # noqa: F401


def _work() -> None:
    time.sleep(60)  # in C: a later interruption does not land in Python code here


threading.Thread(target=_hold, daemon=True).start()
slowdev_sync.inside.wait()
print("importing", flush=True)
import slowdev_held  # noqa: E402,F401  # waits in the import system for the thread's import
_work()
"""

ROBOT = """\
robot: slowbot
boards:
  - name: base
    link: /dev/null
    protocol: native
    devices:
      - type: slowdev
"""


def _plugin_folder(tmp: Path, plugin: str = PLUGIN) -> Path:
    site = tmp / "site"
    info = site / "slowdev-0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: slowdev\nVersion: 0\n")
    (info / "entry_points.txt").write_text("[hwbridge.devices]\nslowdev = slowdev_plugin:Plugin\n")
    (site / "slowdev_sync.py").write_text(SYNC)
    (site / "slowdev_held.py").write_text(HELD)
    (site / "slowdev_plugin.py").write_text(plugin)
    return site


def test_sigint_while_emulate_imports_stops_it_without_the_forced_exit(tmp_path: Path) -> None:
    _interrupt_emulate(_plugin_folder(tmp_path), tmp_path)


NAMING = """\
import time

from hwbridge.cli import stopping


class Named:
    def __set_name__(self, owner: type, name: str) -> None:
        print("importing", flush=True)
        while not stopping.STOP.is_set():  # the signal comes while the class is being made
            time.sleep(0.01)


class Holder:
    value = Named()


def _work() -> None:
    time.sleep(60)  # in C: a later interruption does not land in Python code here


_work()
"""


def test_sigint_while_a_class_is_made_in_an_import_is_no_runtime_error(tmp_path: Path) -> None:
    """A class made during an import calls its attributes' ``__set_name__`` (numpy's ``finfo``
    and its ``cached_property``, as ``record`` first loads the message types); Python 3.11 turns
    an exception leaving one into "RuntimeError: Error calling __set_name__". A Ctrl-C that
    came there was raised there: a traceback and exit status 1 (seen in CI's
    test_every_long_running_command_stops_within_2_s_of_sigint). Now it is raised as the next
    function after the class starts, as in the import system."""
    _interrupt_emulate(_plugin_folder(tmp_path, NAMING), tmp_path)


def _interrupt_emulate(site: Path, tmp_path: Path) -> None:
    """``hwbridge emulate`` of a robot whose device plugin is in ``site``: SIGINT once the
    plugin's import prints "importing"; the command must end with 130 through the
    KeyboardInterrupt (not the forced exit, not a traceback), before printing its URL."""
    robot = tmp_path / "slowbot.yaml"
    robot.write_text(ROBOT)
    path = os.pathsep.join(p for p in (str(site), str(ROOT), os.environ.get("PYTHONPATH")) if p)
    process = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "emulate", str(robot), "--tcp", "0"],
        env={**os.environ, "PYTHONPATH": path},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        assert process.stdout is not None
        first = process.stdout.readline()
        assert first == b"importing\n", (first, process.stderr.read() if process.stderr else b"")
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    errors = err.decode(errors="replace")
    assert "exiting now" not in errors, errors  # the forced exit: the interrupt never landed
    assert "Traceback" not in errors, errors
    assert out == b"", out  # no URL: the command did not go on starting
    assert process.returncode == 130, (process.returncode, errors)
    assert "interrupted" in errors.splitlines(), errors  # as design.md's Stopping says
