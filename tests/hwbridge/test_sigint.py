"""Ctrl-C always works: every long-running command exits within 2 s of SIGINT, at any moment of
its life (issue 25).

Each command runs as a real ``python -m hwbridge`` subprocess against what it needs (a graph
started here with ``hwbridge graph``, emulated boards, an MCAP file recorded here, a roscore, an
AVR ELF in simavr) and gets one SIGINT after a delay drawn from a seeded RNG, uniform over
0 .. (its typical start-up + 1 s); the first trial of each command sends at 0 ms. It must be
gone within 2 s of the signal, with status 0 or 130, and print no traceback and no ``FATAL``;
``record`` leaves either no file or a finished MCAP (never a half-written one).

The 2 s is the product's promise (issue 25), so this is one timing assertion the test makes
on purpose. The only slack is the harness's own latency, measured during the run: control
trials SIGINT a ``sleep`` (which dies at once) among the others, and the largest delay seen
between sending and reaping one is added to the deadline.

A signal that lands while the interpreter itself is still starting, before any hwbridge code
has run, is counted apart ("early") and not failed: it dies by SIGINT's default action with no
output, or Python reports that its initialization (``site``, the standard streams) or its
import of ``runpy`` for ``-m`` was interrupted, or prints a KeyboardInterrupt traceback with
no frame of ours (runpy, an import hook of site-packages), or drops the KeyboardInterrupt
that it raised in a callback of its import system ("Exception ignored in: <function
_get_module_lock...>"), or ``site`` reports the interrupted import line of a ``.pth`` file as
"Error processing line" (CPython 3.11 turns a KeyboardInterrupt in ``__set_name__`` into a
RuntimeError, which ``site`` catches), and starts the command as if nothing had come (the trial
then runs until it is killed). Nothing of ours runs by then; Python's own handling is what a
user gets, and the next Ctrl-C stops the command.

``HWBRIDGE_SIGINT_TRIALS`` trials per command (default 8; the issue's figure is 50),
``HWBRIDGE_SIGINT_JOBS`` at once (default 4), ``HWBRIDGE_SIGINT_SEED`` (default 25),
``HWBRIDGE_SIGINT_ONLY`` a comma-separated list of the commands to try (default all). The
summary (trials, early, failures, largest exit latency, forced exits per command) is printed;
run with ``-s`` to see it.
"""

from __future__ import annotations

import importlib.util
import os
import random
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml

from tests.netutil import free_port, ros_domain_id, wait_until

PROMISE = 2.0
"""Seconds from SIGINT to exit: the requirement under test."""

TRIALS = int(os.environ.get("HWBRIDGE_SIGINT_TRIALS", "8"))
JOBS = int(os.environ.get("HWBRIDGE_SIGINT_JOBS", "4"))
SEED = int(os.environ.get("HWBRIDGE_SIGINT_SEED", "25"))
ONLY = {
    name.strip() for name in os.environ.get("HWBRIDGE_SIGINT_ONLY", "").split(",") if name.strip()
}
HUNG = 20.0
"""A trial still running this long after its signal is killed and counted as hung."""

ROOT = Path(__file__).resolve().parents[2]
DIFFBOT = ROOT / "examples" / "robots" / "diffbot.yaml"


@dataclass
class Command:
    """A long-running command: its argv after ``hwbridge`` for trial ``index``, its extra
    environment, and its typical start-up time on an idle machine (seconds)."""

    name: str
    argv: list[str]
    startup: float
    env: dict[str, str] = field(default_factory=dict)
    per_trial_listen: bool = False  # owns a router: a fresh endpoint and domain per trial


@dataclass
class Outcome:
    command: str
    delay: float
    returncode: int
    latency: float
    output: str
    problem: str | None = None
    """What the trial found wrong besides timing, status and output (a half-written file)."""

    @property
    def early(self) -> bool:
        """The signal came while the interpreter was still starting (no hwbridge code ran)."""
        if "Fatal Python error: init_" in self.output:  # interrupted in interpreter init
            return True
        if self.output.startswith("Could not import runpy module") and (
            f'File "{ROOT / "hwbridge"}' not in self.output
        ):  # 'python -m' interrupted while importing runpy itself (status 1)
            return True
        if self._swallowed_by_the_import_system() or self._swallowed_by_site():
            return True
        if self.returncode != -signal.SIGINT:
            return False
        ours = f'File "{ROOT / "hwbridge"}'
        return not self.output.strip() or (
            self.output.rstrip().endswith("KeyboardInterrupt") and ours not in self.output
        )

    def _swallowed_by_the_import_system(self) -> bool:
        """Python's own KeyboardInterrupt, raised in a weakref callback of the import system
        (a module lock collected while the interpreter imports ``runpy``, ``site`` or the
        ``hwbridge`` package itself) and printed as "Exception ignored": the interpreter drops
        it and carries on, so the command starts as if no signal had come. That can only happen
        before ``hwbridge/__init__.py`` takes the signal over: its handler exits without
        raising, and from ``main`` on a watcher thread ends the process whatever the main
        thread does with the exception."""
        head, marker, rest = self.output.partition(
            "Exception ignored in: <function _get_module_lock"
        )
        traceback = rest.split("KeyboardInterrupt", 1)[0]
        return (
            bool(marker)
            and "hwbridge" not in head
            and "KeyboardInterrupt" in rest
            and f'File "{ROOT / "hwbridge"}' not in traceback
        )

    def _swallowed_by_site(self) -> bool:
        """Python's own KeyboardInterrupt, raised while ``site`` ran a ``.pth`` file's import
        line (pip's editable-install finder, setuptools' distutils hack) and turned into an
        Exception on the way: CPython 3.11 wraps whatever ``__set_name__`` raises in a
        RuntimeError ("Error calling __set_name__", seen in ``ipaddress`` under ``pathlib``),
        and ``site`` prints an Exception from a ``.pth`` line as "Error processing line" and
        goes on starting the interpreter. The command then starts as if no signal had come, and
        no hwbridge code had run when it came."""
        if not self.output.startswith("Error processing line"):
            return False
        report = self.output.split("Remainder of file ignored", 1)[0]
        return "KeyboardInterrupt" in report and f'File "{ROOT / "hwbridge"}' not in report

    @property
    def forced(self) -> bool:
        return "exiting now" in self.output


class Processes:
    """Helper processes of the run (graph, publisher, emulators, roscore), stopped at the end."""

    def __init__(self, tmp: Path, env: dict[str, str]) -> None:
        self.tmp = tmp
        self.env = env
        self.running: list[tuple[subprocess.Popen[bytes], Path]] = []

    def start(self, name: str, argv: list[str], env: dict[str, str] | None = None) -> Path:
        log = self.tmp / f"{name}.log"
        with log.open("wb") as out:
            process = subprocess.Popen(
                argv, env={**self.env, **(env or {})}, stdout=out, stderr=subprocess.STDOUT
            )
        self.running.append((process, log))
        return log

    def hwbridge(self, name: str, *argv: str, env: dict[str, str] | None = None) -> Path:
        return self.start(name, [sys.executable, "-m", "hwbridge", *argv], env)

    def stop(self) -> None:
        for process, _log in reversed(self.running):
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process, _log in reversed(self.running):
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def _first_line(log: Path, timeout: float = 60) -> str:
    assert wait_until(lambda: log.read_text().strip() != "", timeout), log.name
    return log.read_text().splitlines()[0].strip()


def _probe_elf(tmp: Path) -> Path | None:
    """tests/sim/avr/probe.c built for an ATmega328P, when avr-gcc and the runner are here."""
    from hwbridge.firmware.sim import SimToolchainMissingError, runner_binary

    compiler = shutil.which("avr-gcc")
    if compiler is None:
        return None
    try:
        runner_binary()
    except SimToolchainMissingError:
        return None
    elf = tmp / "probe.elf"
    source = ROOT / "tests" / "sim" / "avr" / "probe.c"
    cmd = [compiler, "-mmcu=atmega328p", "-DF_CPU=16000000UL", "-Os", "-o", str(elf), str(source)]
    subprocess.run(cmd, check=True)
    return elf


def _has_rclpy() -> bool:
    """rclpy is installed (``hwbridge ros2`` starts itself again with its library paths)."""
    return importlib.util.find_spec("rclpy") is not None


@pytest.fixture(scope="module")
def commands(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[list[Command], str, dict[str, str]]]:
    """The commands under test, against helper processes started here; what was left out; and
    the environment that points the attached tools at the graph."""
    tmp = tmp_path_factory.mktemp("sigint")
    domain = f"sigint{os.getpid()}"
    graph_endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {**os.environ, "HWBRIDGE_DOMAIN": domain, "HWBRIDGE_ENDPOINT": graph_endpoint}
    env.pop("HWBRIDGE_ZENOH_CONFIG", None)
    helpers = Processes(tmp, env)
    missing: list[str] = []
    try:
        graph_log = helpers.hwbridge("graph", "graph", "--listen", graph_endpoint)
        assert _first_line(graph_log) == graph_endpoint
        helpers.hwbridge(
            "chatter",
            "topic",
            "pub",
            "/sigint/chatter",
            "std_msgs/String",
            "{data: hi}",
            "-r",
            "20",
        )
        mcap = tmp / "play.mcap"
        recorded = subprocess.run(
            [
                sys.executable,
                "-m",
                "hwbridge",
                "record",
                "-q",
                "-o",
                str(mcap),
                "/sigint/chatter",
                "--duration",
                "3",
            ],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        assert recorded.returncode == 0 and mcap.exists(), recorded.stderr
        board_urls = {}
        for user in ("connect", "up"):
            log = helpers.hwbridge(f"board-{user}", "emulate", "diffbot", "--tcp", "0")
            board_urls[user] = _first_line(log)
        pair = tmp / "diffbot_pair.yaml"  # two boards, for up in two bridge processes
        robot = yaml.safe_load(DIFFBOT.read_text())
        robot["boards"].append(dict(robot["boards"][0], name="base2", namespace="/diffbot2"))
        pair.write_text(yaml.safe_dump(robot))
        pair_links: list[str] = []
        for name in ("base", "base2"):
            log = helpers.hwbridge(
                f"pair-{name}", "emulate", str(pair), "--board", name, "--tcp", "0"
            )
            pair_links += ["--link", f"{name}={_first_line(log)}"]
        listen = ["--listen", "tcp/127.0.0.1:0"]  # replaced per trial
        found = [
            Command(
                "connect", ["connect", board_urls["connect"], "--quiet", *listen], 1.5, {}, True
            ),
            Command(
                "up",
                ["up", str(DIFFBOT), "--link", f"base={board_urls['up']}", "--quiet", *listen],
                2.0,
                {},
                True,
            ),
            Command(
                "up sharded",
                ["up", str(pair), *pair_links, "--boards-per-process", "1", "--quiet", *listen],
                3.0,
                {},
                True,
            ),
            Command(
                "topic pub -r",
                ["topic", "pub", "/sigint/cmd", "std_msgs/String", "{data: x}", "-r", "10"],
                1.5,
            ),
            Command("topic echo", ["topic", "echo", "/sigint/chatter"], 1.5),
            Command("record", ["record", "-o", str(tmp / "record.mcap"), "/sigint/chatter"], 1.5),
            Command("play", ["play", str(mcap), "--loop"], 1.5),
            Command("viz", ["viz", "--port", "0"], 1.5),
            Command("monitor", ["monitor", "--json"], 1.5),
            Command("emulate", ["emulate", "diffbot", "--tcp", "0"], 1.0),
        ]
        if shutil.which("roscore") is not None:
            master_port = free_port()
            helpers.start("roscore", ["roscore", "-p", str(master_port)])
            master = f"http://127.0.0.1:{master_port}"
            found.append(Command("ros1", ["ros1", "--master", master], 1.5))
        else:
            missing.append("ros1 (no roscore)")
        if _has_rclpy():
            ros_domain = ros_domain_id(2)
            found.append(Command("ros2", ["ros2"], 4.0, {"ROS_DOMAIN_ID": ros_domain}))
        else:
            missing.append("ros2 (no rclpy)")
        elf = _probe_elf(tmp)
        if elf is not None:
            found.append(Command("firmware sim", ["firmware", "sim", str(elf)], 1.0))
        else:
            missing.append("firmware sim (no avr-gcc or simavr)")
        if ONLY:
            unknown = ONLY - {command.name for command in found}
            assert not unknown, f"HWBRIDGE_SIGINT_ONLY names no command here: {sorted(unknown)}"
            found = [command for command in found if command.name in ONLY]
        yield found, ", ".join(missing), env
    finally:
        helpers.stop()


def _trial(command: Command, index: int, delay: float, tmp: Path, base: dict[str, str]) -> Outcome:
    argv = list(command.argv)
    env = {**base, **command.env}
    if command.per_trial_listen:
        argv[-1] = f"tcp/127.0.0.1:{free_port()}"
        env["HWBRIDGE_DOMAIN"] = f"{base['HWBRIDGE_DOMAIN']}-{command.name}-{index}"
    if command.name != "record":
        return _signal_after(
            command.name, [sys.executable, "-m", "hwbridge", *argv], env, delay, tmp
        )
    mcap = tmp / f"record-{index}.mcap"
    argv[2] = str(mcap)
    outcome = _signal_after(
        command.name, [sys.executable, "-m", "hwbridge", *argv], env, delay, tmp
    )
    if mcap.exists() and not _complete_mcap(mcap):
        outcome.problem = f"left a half-written {mcap.name} ({mcap.stat().st_size} bytes)"
    return outcome


MCAP_MAGIC = b"\x89MCAP0\r\n"


def _complete_mcap(path: Path) -> bool:
    """Starts and ends with the MCAP magic: the recorder finished the file (footer written)."""
    data = path.read_bytes()
    return (
        len(data) >= 2 * len(MCAP_MAGIC)
        and data.startswith(MCAP_MAGIC)
        and data.endswith(MCAP_MAGIC)
    )


def _signal_after(
    name: str, argv: list[str], env: dict[str, str], delay: float, tmp: Path
) -> Outcome:
    """Start ``argv``, SIGINT it after ``delay`` s, and time its exit from the send."""
    log = tmp / f"{name.replace(' ', '_')}-{threading.get_ident()}-{time.monotonic_ns()}.log"
    with log.open("wb") as out:
        process = subprocess.Popen(argv, env=env, stdout=out, stderr=subprocess.STDOUT)
    time.sleep(delay)
    sent = time.monotonic()
    process.send_signal(signal.SIGINT)
    killer = threading.Timer(HUNG, process.kill)
    killer.start()
    returncode = process.wait()  # a blocking waitpid: no polling interval in the latency
    latency = time.monotonic() - sent
    killer.cancel()
    return Outcome(name, delay, returncode, latency, log.read_text(errors="replace"))


@pytest.mark.timeout(max(300, TRIALS * 60))  # the 50 trials a command take minutes
def test_every_long_running_command_stops_within_2_s_of_sigint(
    commands: tuple[list[Command], str, dict[str, str]], tmp_path: Path
) -> None:
    found, missing, env = commands
    rng = random.Random(SEED)
    base = {**env, "HWBRIDGE_STOP_TRACE": "1"}  # a forced exit shows what hung
    jobs: list[tuple[Command, int, float]] = []
    for command in found:
        for index in range(TRIALS):
            delay = 0.0 if index == 0 else rng.uniform(0.0, command.startup + 1.0)
            jobs.append((command, index, delay))
    rng.shuffle(jobs)  # the commands' trials side by side, as a loaded machine would run them
    control = Command("control", [], 0.0)
    controls = [(control, index, rng.uniform(0.2, 1.0)) for index in range(max(4, TRIALS // 2))]
    jobs += controls
    rng.shuffle(jobs)

    def run(job: tuple[Command, int, float]) -> Outcome:
        command, index, delay = job
        if command is control:
            return _signal_after("control", ["sleep", "60"], base, delay, tmp_path)
        return _trial(command, index, delay, tmp_path, base)

    with ThreadPoolExecutor(JOBS) as pool:
        outcomes = list(pool.map(run, jobs))

    harness = max(o.latency for o in outcomes if o.command == "control")
    deadline = PROMISE + harness
    failures: list[str] = []
    lines = [
        f"SIGINT trials (seed {SEED}, {JOBS} at once); harness latency {harness * 1000:.0f} ms; "
        f"deadline {deadline:.3f} s",
        f"{'command':<14} {'trials':>6} {'early':>5} {'failed':>6} {'max exit s':>10} "
        f"{'forced':>6}",
    ]
    for command in found:
        mine = [o for o in outcomes if o.command == command.name]
        bad = [o for o in mine if not o.early and _problem(o, deadline)]
        measured = [o.latency for o in mine if not o.early]
        lines.append(
            f"{command.name:<14} {len(mine):>6} {sum(o.early for o in mine):>5} {len(bad):>6} "
            f"{max(measured, default=0.0):>10.3f} {sum(o.forced for o in mine):>6}"
        )
        failures += [
            f"{o.command} (signal after {o.delay:.3f} s): {_problem(o, deadline)}\n"
            + _ends(o.output)
            for o in bad
        ]
    if missing:
        lines.append(f"not run: {missing}")
    print("\n" + "\n".join(lines))
    assert not failures, "\n\n".join(failures[:10])


def _ends(output: str, each: int = 1500) -> str:
    """The start and the end of a trial's output (how it began is what explains a hang)."""
    if len(output) <= 2 * each:
        return output
    return f"{output[:each]}\n[... {len(output) - 2 * each} characters ...]\n{output[-each:]}"


def _problem(outcome: Outcome, deadline: float) -> str | None:
    if outcome.latency > deadline:
        return f"exited {outcome.latency:.3f} s after SIGINT (status {outcome.returncode})"
    if outcome.returncode not in (0, 130):
        return f"exit status {outcome.returncode}"
    if "Traceback" in outcome.output:
        return "a traceback"
    if "FATAL" in outcome.output:
        return "FATAL in its output"
    return outcome.problem


def test_what_the_suite_starts_handles_sigint_when_the_suite_was_started_ignoring_it() -> None:
    """The SIGINT tests need the commands they start to handle SIGINT as when started from a
    terminal. A suite started in the background of a script (``./tools/test &`` in a CI
    runner's shell) inherits SIGINT ignored, and so would everything it starts; tests/conftest.py
    gives the suite's processes a handler instead, which exec does not pass on. Here a process
    started with SIGINT ignored (``trap '' INT``) loads the conftest and starts a Python: that one
    has its KeyboardInterrupt handler."""
    report = "import signal; print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)"
    code = (
        "import subprocess, sys\n"
        "import tests.conftest\n"
        f"print(subprocess.run([sys.executable, '-c', {report!r}], capture_output=True,"
        " text=True, check=True).stdout.strip())\n"
    )
    done = subprocess.run(
        ["/bin/sh", "-c", 'trap "" INT; exec "$0" -c "$1"', sys.executable, code],
        cwd=Path(__file__).parents[2],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    assert done.stdout.strip() == "True", done.stderr
