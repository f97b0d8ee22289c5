#!/usr/bin/env python3
"""Many boards: what one more board costs the bridge (issue 29, item 3). Not a test: it prints
figures and checks nothing.

Brings up ``--boards`` (1, 8, 32, 64) firmware boards, out of process, each with ``--topics``
topics (10) at ``--rate`` Hz (50), the first ``--reliable`` (2) of them reliable, for ``--minutes``
(1) each, with the machinery of ``tools/bench/soak.py`` (imported, not copied): one host build
of the HwBridge library a board (``tools/bench/SoakBoard``, TCP to the bridge), ``hwbridge
connect`` bridging them, and a measuring client on Zenoh subscribed to every topic (no service
calls here). Where a count is in ``--shard-at`` (32, 64), it runs a second time with the boards
shared out over several bridge processes, ``--per-bridge`` (16) boards each, all on one Zenoh
graph (the client connects to every bridge's endpoint): the two shapes side by side. Where a
count is in ``--up-at`` (64), it runs once more through ``hwbridge up`` as a user runs it: a
robot file of the same boards, sharded as the product shards it (``--boards-per-process``, 16 as
``up``'s default; the parent keeps the graph and the parameters, each shard its boards), the
parent and its shards measured together (``shape``: ``up``; ``bridges``: processes, the parent
included).

One JSON line per run (``bench: boards``): ``bridges`` (processes), ``bridge_cpu_cores`` (all
bridge processes, utime + stime over the run), ``cpu_cores_per_board``, ``cpu_us_per_message``
(bridge CPU time over the messages the boards published), ``rss_kb`` (all bridges, at the end),
``rss_kb_per_board`` and ``rss_kb_per_extra_board`` (RSS above the 1-board run's, per board
beyond the first), ``p50_ms``/``p99_ms`` board-to-subscriber latency (the message's
CLOCK_MONOTONIC stamp at publishing to its arrival at the client; one clock on one machine),
``messages_per_s`` received against ``offered_per_s`` (published by the boards) and
``asked_per_s``, messages lost (``reliable_lost``, ``best_effort_lost``: exact, every message is
numbered), the boards' session ends, the client's and the boards' CPU, and the load average.

Every figure is also a ratio against the baseline measured first in the same run, 1 board on 1
bridge: ``cost_per_message_ratio`` (``cpu_us_per_message`` / the baseline's),
``rss_per_board_ratio``, ``p50_ratio``, ``p99_ratio``; ``acceptance.cost_per_message_within_20_pct``
is ``cost_per_message_ratio <= 1.2`` (issue 29: the cost per message must not grow with the
number of boards, within 20 % from 1 to 64). A last line (``bench: boards_summary``) gives, per
shape, the ratio at the largest count and that acceptance flag.

On a 2-core machine that also runs the boards and the client, 64 boards (32,000 messages/s
asked) are more than the machine has: ``offered_per_s`` below ``asked_per_s`` (the boards' own
``late_ticks``) and ``client_cpu_cores`` near a core say when the bench, not the bridge, is the
limit; the cost per message stays comparable because it is the bridge's CPU over what it
carried.

What it found (2-core machine shared with other work, load average 19-30): the cost per message
falls with the boards on one bridge process up to 32 (101, 76, 53 µs at 1, 8, 32 boards), but
at 64 one process is overwhelmed (213 µs a message, 936 link losses declared by boards that
were running: the bridge silent past the 0.8 s link timeout, 3,300 of 32,000 messages/s
carried), while 4 processes of 16 boards carried 14,000/s at 63 µs (ratio 0.63) with 28 link
losses. So ``hwbridge up`` now shards: more boards than ``--boards-per-process`` (16) run in
child bridge processes. Through ``up`` itself (30 s a run, load average 10-58): 64 boards in one
process 142.5 µs a message (ratio 1.41, 2,468 of 32,000 messages/s carried, 469 link losses),
through ``up``'s default (parent + 4 shards) 55.4 µs (ratio 0.55, 14,620/s carried, 331 link
losses at a load average of 58); the parent's router, which every message leaving a shard
passes, is in that figure.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import soak  # tools/bench is not a package: found through sys.path above

from hwbridge.robot.shards import plan_shards

# ------------------------------------------------------------------- the product's shape: up
_CONNECT_COMMAND = soak.hwbridge_command
_CPU_SECONDS = soak.cpu_seconds
_PROC_SAMPLE = soak.proc_sample
_TREES: dict[int, bool] = {}
"""Per measured pid: whether it is an ``hwbridge up`` (measured with its child processes)."""


def _is_up(pid: int) -> bool:
    if pid not in _TREES:
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            return False
        _TREES[pid] = b"up" in argv and b"--boards-per-process" in argv
    return _TREES[pid]


def _tree(pid: int) -> list[int]:
    """``pid`` and, for an ``hwbridge up``, its live child processes (its shards)."""
    if not _is_up(pid):
        return [pid]
    found = [pid]
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text(encoding="ascii")
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            found.append(int(entry.name))
    return found


def _tree_cpu_seconds(pid: int) -> float:
    total = 0.0
    for member in _tree(pid):
        with contextlib.suppress(OSError):  # a child that just ended
            total += _CPU_SECONDS(member)
    return total


def _tree_sample(pid: int) -> dict[str, int]:
    total = {"rss_kb": 0, "threads": 0, "fds": 0}
    for member in _tree(pid):
        try:
            sample = _PROC_SAMPLE(member)
        except OSError:
            continue
        for key, value in sample.items():
            total[key] += value
    return total


def use_up(per_process: int | None, folder: Path) -> None:
    """Make soak's bridge ``hwbridge up`` (a robot file of the same boards, ``per_process``
    boards a bridge process; None: ``connect`` as soak runs it), measured with its shards."""
    if per_process is None:
        soak.hwbridge_command = _CONNECT_COMMAND
        return
    soak.hwbridge_command = lambda: [
        sys.executable,
        str(Path(__file__).resolve()),
        "--as-up",
        str(per_process),
        str(folder),
    ]
    soak.cpu_seconds = _tree_cpu_seconds
    soak.proc_sample = _tree_sample


def as_up(per_process: str, folder: str, argv: list[str]) -> None:
    """Become ``hwbridge up`` for soak's ``connect`` command line ``argv`` (``connect --listen
    EP --quiet --protocol native --name NAME... URL...``): the same boards in a robot file."""
    names = [argv[i + 1] for i, arg in enumerate(argv) if arg == "--name"]
    urls = [arg for arg in argv if arg.startswith("socket://")]
    listen = argv[argv.index("--listen") + 1]
    boards = [
        {"name": name, "link": url, "protocol": "native"}
        for name, url in zip(names, urls, strict=True)
    ]
    robot = Path(folder) / f"robot-{len(boards)}-{os.getpid()}.yaml"
    robot.write_text(json.dumps({"robot": "bench", "boards": boards}))  # JSON is YAML
    command = [*_CONNECT_COMMAND(), "up", str(robot), "--listen", listen, "--quiet"]
    command += ["--boards-per-process", per_process]
    os.execv(command[0], command)  # the same pid: soak measures and stops it


def _figures(summary: dict[str, Any], minutes: float) -> dict[str, Any]:
    """The per-run figures of a soak stage summary."""
    boards: int = summary["boards"]
    duration = minutes * 60.0
    cores: float = summary["cpu_cores"]
    published: int = summary["published"]
    return {
        "bench": "boards",
        "boards": boards,
        "bridges": summary["bridges"],
        "topics": summary["topics"],
        "reliable_topics": summary["reliable_topics"],
        "rate_hz": summary["rate_hz"],
        "minutes": minutes,
        "bridge_cpu_cores": cores,
        "cpu_cores_per_board": round(cores / boards, 4),
        "cpu_us_per_message": round(cores * duration * 1e6 / published, 2) if published else None,
        "rss_kb": summary["rss_kb_end"],
        "rss_kb_per_board": round(summary["rss_kb_end"] / boards, 1),
        "p50_ms": summary["p50_ms"],
        "p99_ms": summary["p99_ms"],
        "max_ms": summary["max_ms"],
        "messages_per_s": summary["messages_per_s"],
        "offered_per_s": summary["offered_per_s"],
        "asked_per_s": summary["asked_per_s"],
        "published": published,
        "reliable_lost": summary["reliable_lost"],
        "best_effort_lost": summary["best_effort_lost"],
        "refused_by_board": summary["refused_by_board"],
        "board_session_ends": summary["board_session_ends"],
        "board_stalls": summary["board_own_stalls"],
        "loss_account": summary["loss_account"],
        "late_ticks": summary["late_ticks"],
        "client_cpu_cores": summary["client_cpu_cores"],
        "boards_cpu_cores": summary["emulator_cpu_cores"],
        "threads": summary["threads_end"],
        "fds": summary["fds_start"] + summary["fds_growth"],
        "bridge_warnings": summary["bridge_warnings"],
        "bridge_warnings_first": summary["bridge_warnings_first"][:2],
        "cpus": summary["cpus"],
        "loadavg": summary["loadavg"],
    }


def _ratio(value: float | None, base: float | None) -> float | None:
    if value is None or not base:
        return None
    return round(value / base, 3)


def with_ratios(line: dict[str, Any], base: dict[str, Any]) -> dict[str, Any]:
    """``line`` with its ratios against ``base`` (the 1-board, 1-bridge run)."""
    extra = line["boards"] - base["boards"]
    line["baseline"] = {"boards": base["boards"], "bridges": base["bridges"]}
    line["rss_kb_per_extra_board"] = (
        round((line["rss_kb"] - base["rss_kb"]) / extra, 1) if extra > 0 else None
    )
    line["cost_per_message_ratio"] = _ratio(line["cpu_us_per_message"], base["cpu_us_per_message"])
    line["rss_per_board_ratio"] = _ratio(line["rss_kb_per_board"], base["rss_kb_per_board"])
    line["p50_ratio"] = _ratio(line["p50_ms"], base["p50_ms"])
    line["p99_ratio"] = _ratio(line["p99_ms"], base["p99_ms"])
    ratio = line["cost_per_message_ratio"]
    line["acceptance"] = {"cost_per_message_within_20_pct": ratio is not None and ratio <= 1.2}
    return line


def _emit(line: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(line) + "\n")
    sys.stdout.flush()


def _numbers(text: str, what: str, parser: argparse.ArgumentParser) -> list[float]:
    try:
        return [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        parser.error(f"{what}: expected numbers separated by commas, got {text!r}")


def main() -> None:
    if sys.argv[1:2] == ["--as-up"]:  # soak's bridge, as hwbridge up (see use_up)
        as_up(sys.argv[2], sys.argv[3], sys.argv[4:])
        return
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--boards", default="1,8,32,64", help="board counts, one run each")
    parser.add_argument(
        "--minutes", default="1", help="minutes per run (one value, or one per --boards entry)"
    )
    parser.add_argument("--rate", type=float, default=50.0, help="messages/s per topic")
    parser.add_argument("--topics", type=int, default=10, help="topics per board")
    parser.add_argument("--reliable", type=int, default=2, help="reliable topics per board")
    parser.add_argument("--sample", type=float, default=10.0, help="seconds between samples")
    parser.add_argument(
        "--shard-at",
        default="32,64",
        help="board counts also run sharded over several bridge processes ('' for none)",
    )
    parser.add_argument(
        "--per-bridge", type=int, default=16, help="boards per bridge process when sharded"
    )
    parser.add_argument(
        "--up-at",
        default="64",
        help="board counts also run through 'hwbridge up' (a robot file of the same boards) as "
        "the product shards them ('' for none)",
    )
    parser.add_argument(
        "--boards-per-process",
        type=int,
        default=16,
        help="'hwbridge up --boards-per-process' in the --up-at runs (its default: 16)",
    )
    parser.add_argument("--log-dir", help="keep the bridges' logs in this folder")
    args = parser.parse_args()
    counts = [int(n) for n in _numbers(args.boards, "--boards", parser)]
    if not counts or min(counts) < 1:
        parser.error("--boards: counts of at least 1")
    minutes = _numbers(args.minutes, "--minutes", parser)
    if len(minutes) == 1:
        minutes *= len(counts)
    if len(minutes) != len(counts) or min(minutes) <= 0:
        parser.error("--minutes: one positive value, or one per --boards entry")
    shard_at = {int(n) for n in _numbers(args.shard_at, "--shard-at", parser)}
    up_at = {int(n) for n in _numbers(args.up_at, "--up-at", parser)}
    if args.per_bridge < 1:
        parser.error("--per-bridge: at least 1")
    # what soak.run_stage reads of its arguments
    args.boards_kind = "firmware"
    args.per_emulator = 1
    args.calls = False
    args.quiet_samples = True
    baseline_minutes = minutes[counts.index(1)] if 1 in counts else minutes[0]
    runs: list[tuple[int, float, int, str]] = (
        [] if 1 in counts else [(1, baseline_minutes, 1, "connect")]
    )
    for count, stage_minutes in zip(counts, minutes, strict=True):
        runs.append((count, stage_minutes, 1, "connect"))
        sharded = -(-count // args.per_bridge)
        if count in shard_at and sharded > 1:
            runs.append((count, stage_minutes, sharded, "connect"))
        if count in up_at:
            runs.append((count, stage_minutes, 1, "up"))
    lines: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="hwbridge-boards-") as tmp:
        args.board_program = soak.build_board(Path(tmp) / "board")
        logs = Path(args.log_dir) if args.log_dir else Path(tmp)
        logs.mkdir(parents=True, exist_ok=True)
        base: dict[str, Any] | None = None
        for count, stage_minutes, bridges, shape in runs:
            up = shape == "up"
            shards = len(plan_shards([str(n) for n in range(count)], args.boards_per_process))
            print(
                f"boards: {count} boards on "
                + (
                    f"'hwbridge up' ({1 + shards if shards else 1} processes)"
                    if up
                    else f"{bridges} bridge process(es)"
                )
                + f" for {stage_minutes} min",
                file=sys.stderr,
                flush=True,
            )
            args.bridges = bridges
            use_up(args.boards_per_process if up else None, Path(tmp))
            line = _figures(soak.run_stage(args, count, stage_minutes, logs), stage_minutes)
            line["shape"] = shape
            if up:  # the parent (graph, parameters) and its shards, measured together
                line["bridges"] = 1 + shards if shards else 1
            if base is None:
                base = dict(line)
            lines.append(with_ratios(line, base))
            _emit(line)
    assert base is not None
    shapes: dict[str, Any] = {}
    kinds = {
        "one_bridge": lambda ln: ln["shape"] == "connect" and ln["bridges"] == 1,
        "sharded": lambda ln: ln["shape"] == "connect" and ln["bridges"] > 1,
        "up_default": lambda ln: ln["shape"] == "up",
    }
    for shape, test in kinds.items():
        chosen = [ln for ln in lines if test(ln)]
        if not chosen:
            continue
        top = max(chosen, key=lambda ln: ln["boards"])
        shapes[shape] = {
            "boards": top["boards"],
            "bridges": top["bridges"],
            "cost_per_message_ratio": top["cost_per_message_ratio"],
            "p99_ratio": top["p99_ratio"],
            "reliable_lost": top["reliable_lost"],
            "cost_per_message_within_20_pct": top["acceptance"]["cost_per_message_within_20_pct"],
        }
    _emit(
        {
            "bench": "boards_summary",
            "baseline": {
                "boards": base["boards"],
                "cpu_us_per_message": base["cpu_us_per_message"],
            },
            "shapes": shapes,
            "peer": None,
        }
    )


if __name__ == "__main__":
    main()
