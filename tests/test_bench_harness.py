"""The benchmark harness's fast board publisher sends what the session itself would."""

from __future__ import annotations

import importlib.util
import itertools
import platform
import random
import shutil
import statistics
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from hwbridge.protocols.native.session import DeviceSession, HostSession, Message
from tests.protocols.lossy import SimLink
from tests.protocols.test_native_session import BOARD, CH_CHATTER, TOPICS, connect

BENCH = Path(__file__).parents[1] / "tools" / "bench" / "bridge.py"


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_bridge", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("bench_bridge", module)
    spec.loader.exec_module(module)
    return module


def _connected(device_class: Any) -> SimLink:
    host = HostSession(rng=random.Random(0))
    device = device_class(BOARD, TOPICS, rng=random.Random(1))
    link = SimLink(host, device, seed=0)
    connect(link)
    link.run(0.5)
    return link


def test_publish_repeated_sends_the_frames_publish_would() -> None:
    plain = _connected(DeviceSession)
    fast = _connected(_bench()._fast_publisher_class())
    fast_device: Any = fast.device  # a FastPublisher
    payload = b"\x0c\x00\x00\x000123456789ab"
    for count in (1, 255, 300, 1000):  # across sequence number wrap-arounds
        for _ in range(count):
            plain.device.publish(CH_CHATTER, payload)
        fast_device.publish_repeated(CH_CHATTER, payload, count)
        expected = plain.device.data_to_send()
        sent = fast.device.data_to_send()
        assert sent == expected.lstrip(b"\x00")  # publish() may lead with 0x00 after idling
        events = fast.host.receive_data(sent, fast.now)
        assert [e.payload for e in events if isinstance(e, Message)] == [payload] * count
    # The replayed cycles skip the board's session (its counters), not the host's.
    host_fast, _host_plain = fast.host.stats.as_dict(), plain.host.stats.as_dict()
    assert host_fast["be_frames_lost"] == 0
    assert host_fast["be_messages_received"] >= sum((1, 255, 300, 1000))


def test_bridge_bench_runs_small_and_prints_the_documented_fields() -> None:
    """A short run of tools/bench/bridge.py (both protocols, pty): each JSON line carries what
    the docstring promises, and every message sent is counted as received. No timing checks."""
    import json
    import subprocess

    done = subprocess.run(
        [sys.executable, str(BENCH), "--transport", "pty", "--messages", "3000", "--calls", "40"],
        capture_output=True,
        text=True,
        timeout=240,
        check=True,
    )
    lines = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    names = [line["bench"] for line in lines]
    assert names == [
        "bridge_throughput_native_pty",
        "bridge_latency_native_pty",
        "bridge_throughput_rosserial_pty",
        "bridge_latency_rosserial_pty",
    ]
    for line in lines:
        if "throughput" in line["bench"]:
            assert line["received"] == line["sent"] == 3000
            assert line["bridge_drop_counters"] == {}
            assert line["hwbridge_per_s"] > 0 and line["peer"] == "zenoh_raw"
            assert line["bridge_cpu_fraction"] > 0
        else:
            assert line["calls"] == 40 and line["peer"] == "pty_echo"
            for field in (
                "p50_us",
                "p99_us",
                "rtt_p50_us",
                "board_us",
                "graph_rtt_p50_us",
                "zenoh_rtt_p50_us",
                "pty_echo_idle_us",
                "p50_idle_echo_us",
            ):
                assert isinstance(line[field], float), field
            assert line["rtt_p50_us"] > line["board_us"] > 0
            # The floor is the sum of its named parts, the ratio is the round trip over it.
            parts = line["floor_parts_us"]
            assert set(parts) == {"zenoh_rtt", "pty_rtt_idle", "board"}
            assert parts["zenoh_rtt"] == line["zenoh_rtt_p50_us"]
            assert parts["board"] == line["board_us"]
            assert line["floor_p50_us"] == pytest.approx(sum(parts.values()), abs=0.2)
            # The ratio is the median of the rounds', each a round's round trip over its floor.
            rounds = line["rtt_over_floor_rounds"]
            assert len(rounds) == 4 and all(ratio > 0 for ratio in rounds)
            assert line["rtt_over_floor"] == pytest.approx(statistics.median(rounds), abs=1e-3)
            # The bridge's own steps, stamped on more calls: both seen, inside the round trip.
            path = line["bridge_path_us"]
            assert set(path) == {"request", "answer"}
            assert 0 < path["request"] + path["answer"] < line["rtt_p50_us"]
            # A call's request and answer are whole frames: a few bytes each, never zero.
            assert line["frame_bytes"]["request"] > 4 and line["frame_bytes"]["reply"] > 4


def test_hotpath_bench_prints_each_trick_against_its_plain_code() -> None:
    """``tools/bench/framing.py --hotpath`` (the figures _hotpath's docstring cites): one line
    per trick with both rates and their ratio. Fields only, no timing checks."""
    import json
    import subprocess

    script = BENCH.with_name("framing.py")
    done = subprocess.run(
        [sys.executable, str(script), "--hotpath", "--number", "50", "--repeats", "1"],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    assert [(line["bench"], line["peer"]) for line in lines] == [
        ("hotpath_make_frame", "Frame_constructor"),
        ("hotpath_message_event", "Message_constructor"),
        ("hotpath_enum_global", "enum_class_attribute"),
    ]
    for line in lines:
        for field in ("hwbridge_per_s", "peer_per_s"):
            assert isinstance(line[field], int) and line[field] > 0, field
        for field in ("hwbridge_ns", "peer_ns", "ratio"):
            assert isinstance(line[field], float) and line[field] > 0, field
        assert line["number"] == 50 and line["repeats"] == 1
        assert line["python"] == platform.python_version()


def _run_json(script: str, *args: str, timeout: float) -> list[dict[str, Any]]:
    import json
    import subprocess

    done = subprocess.run(
        [sys.executable, str(BENCH.with_name(script)), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=True,
    )
    return [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]


def test_resets_bench_samples_the_bridge_and_sums_up_each_case() -> None:
    """``tools/bench/resets.py`` with a few resets per case: a sample line every ``--every``
    resets and a summary per case with the growth of each figure. Fields only."""
    lines = _run_json(
        "resets.py", "--resets", "4", "--pty-resets", "2", "--every", "2", timeout=240
    )
    figures = ("rss_kb", "threads", "fds")
    summaries = [line for line in lines if "sample" not in line]
    assert [line["bench"] for line in summaries] == [
        "resets_native_pty",
        "resets_rosserial_tcp",
        "resets_rosserial_pty",
    ]
    for summary in summaries:
        samples = [s for s in lines if s.get("sample") and s["bench"] == summary["bench"]]
        assert [s["resets"] for s in samples] == list(range(0, summary["resets"] + 1, 2))
        for sample in samples:
            assert all(isinstance(sample[key], int) and sample[key] > 0 for key in figures)
        assert set(summary["growth"]) == set(figures) == set(summary["peer_growth"])
        assert summary["peer"] == "idle" and summary["bridge_errors"] == []
        assert isinstance(summary["rss_growth_pct"], float) and summary["reset_ms"] > 0


@pytest.mark.parametrize("kind", ["firmware", "python"])
def test_soak_bench_counts_every_message_and_prints_samples_and_a_summary(kind: str) -> None:
    """``tools/bench/soak.py`` with two boards of three topics for six seconds, boards built
    from the HwBridge library (``firmware``: the SoakBoard sketch compiled for the host) or
    Python emulators: sample lines, then a summary in which nothing published went missing
    while every session held (a board may refuse a message while its reliable window is full:
    counted, not lost). Fields only, no timing checks."""
    lines = _run_json(
        "soak.py",
        *("--boards", "2", "--minutes", "0.1", "--sample", "2", "--topics", "3"),
        *("--rate", "20", "--per-emulator", "1", "--boards-kind", kind),
        timeout=240,
    )
    *samples, summary = lines
    assert samples and all(s["bench"] == "soak_sample" and s["boards"] == 2 for s in samples)
    for sample in samples:
        for key in ("bridge_cpu_cores", "emulator_cpu_cores", "client_cpu_cores"):
            assert isinstance(sample[key], float), key
        assert sample["rss_kb"] > 0 and sample["fds"] > 0 and len(sample["loadavg"]) == 3
    assert summary["bench"] == "soak" and summary["boards"] == 2 and summary["emulators"] == 2
    assert summary["boards_kind"] == kind
    assert isinstance(summary["bridge_warnings"], int) and summary["late_ticks"] >= 0
    assert summary["published"] > 0 and summary["refused_by_board"] >= 0
    assert 0 <= summary["reliable_lost_at_start"] <= max(summary["reliable_lost"], 0)
    ends = summary["board_session_ends"]
    assert set(ends) == {"link_losses", "peer_resets"} and all(
        isinstance(count, int) for count in ends.values()
    )
    # Every message is numbered: nothing published goes missing, and no call fails, unless a
    # board's session ended (a machine so busy that a board or the bridge went silent for the
    # 0.8 s link timeout: the bench reports that, it is no counting error).
    if not any(ends.values()):
        assert summary["reliable_lost"] == 0 and summary["best_effort_lost"] == 0
        assert summary["calls_failed"] == 0
    assert summary["calls"] > 0
    for key in ("p50_ms", "p99_ms", "cpu_cores", "rss_growth_pct", "messages_per_s", "drain_s"):
        assert isinstance(summary[key], float), key
    assert set(summary["acceptance"]) == {
        "below_one_core",
        "rss_growth_below_5_pct",
        "no_reliable_lost",
    }


def test_boards_bench_prints_one_line_a_run_with_ratios_to_its_one_board_baseline() -> None:
    """``tools/bench/boards.py`` small: 1 and 2 firmware boards of three topics, the 2-board
    count also sharded over 2 bridge processes (one Zenoh graph), and through ``hwbridge up``
    with one board a process (its parent and 2 shards, measured together). Each run's line has the
    documented fields; its counts are real (every message the boards published reached the
    client when no session ended, whichever bridge carried it) and its ratios are against the
    1-board run of the same invocation. No timing checks."""
    lines = _run_json(
        "boards.py",
        *("--boards", "1,2", "--minutes", "0.1", "--sample", "2", "--topics", "3"),
        *("--rate", "20", "--shard-at", "2", "--per-bridge", "1"),
        *("--up-at", "2", "--boards-per-process", "1"),
        timeout=400,
    )
    *runs, summary = lines
    assert [(r["bench"], r["boards"], r["bridges"], r["shape"]) for r in runs] == [
        ("boards", 1, 1, "connect"),
        ("boards", 2, 1, "connect"),
        ("boards", 2, 2, "connect"),
        ("boards", 2, 3, "up"),
    ]
    base = runs[0]
    for run in runs:
        assert run["published"] > 0 and run["topics"] == 3
        assert run["asked_per_s"] == run["boards"] * 3 * 20.0
        for key in ("bridge_cpu_cores", "cpu_cores_per_board", "cpu_us_per_message"):
            assert isinstance(run[key], float) and run[key] > 0, key
        assert run["rss_kb"] > 0 and run["rss_kb_per_board"] == round(
            run["rss_kb"] / run["boards"], 1
        )
        assert run["cpu_us_per_message"] == pytest.approx(
            run["bridge_cpu_cores"] * 6e7 * 0.1 / run["published"], rel=0.01
        )
        assert isinstance(run["p50_ms"], float) and isinstance(run["p99_ms"], float)
        assert run["baseline"] == {"boards": 1, "bridges": 1}
        assert run["cost_per_message_ratio"] == round(
            run["cpu_us_per_message"] / base["cpu_us_per_message"], 3
        )
        assert run["acceptance"]["cost_per_message_within_20_pct"] == (
            run["cost_per_message_ratio"] <= 1.2
        )
        if not any(run["board_session_ends"].values()):
            assert run["reliable_lost"] == 0 and run["best_effort_lost"] == 0
            # what the client received is what the boards published (exact counts)
            assert run["messages_per_s"] == pytest.approx(run["offered_per_s"], abs=0.11)
    assert base["cost_per_message_ratio"] == 1.0 and base["rss_kb_per_extra_board"] is None
    sharded = runs[2]
    assert sharded["rss_kb_per_extra_board"] is not None
    assert summary["bench"] == "boards_summary"
    assert set(summary["shapes"]) == {"one_bridge", "sharded", "up_default"}
    assert summary["shapes"]["sharded"]["bridges"] == 2
    assert summary["shapes"]["up_default"]["bridges"] == 3
    assert runs[3]["threads"] > runs[1]["threads"]  # three processes' threads, not one's


def _one_line(script: str, *args: str) -> dict[str, Any]:
    """Runs ``tools/bench/<script>`` with ``args``; the one JSON line it prints."""
    import json
    import subprocess

    done = subprocess.run(
        [sys.executable, str(BENCH.with_name(script)), *args],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    (line,) = [json.loads(text) for text in done.stdout.splitlines() if text.startswith("{")]
    assert isinstance(line, dict)
    return line


def test_session_call_bench_times_both_host_sessions() -> None:
    """``tools/bench/session_call.py``: each protocol's host session against its device session
    in one process; a line with both per-call figures and their ratio, every call answered (the
    bench raises otherwise). No timing checks."""
    line = _one_line("session_call.py", "--calls", "50", "--rounds", "3")
    assert line["bench"] == "session_call" and line["peer"] == "rosserial_host"
    assert line["calls"] == 50 and len(line["native_rounds_us"]) == 3
    assert line["native_us"] > 0 and line["rosserial_us"] > 0
    assert line["ratio"] == round(line["rosserial_us"] / line["native_us"], 3)


def test_sim_bench_times_a_board_answer_from_the_line_pace() -> None:
    """``tools/bench/sim.py``'s ``board_answer_us``: the line's byte time is the pace of the
    answers' bursts (not the shortest gap: the UART takes a second byte at once), and each
    request's last byte arrives that many cycles a byte after the request was handed over."""
    from hwbridge.firmware.sim import UartBytes

    path = BENCH.with_name("sim.py")
    spec = importlib.util.spec_from_file_location("bench_sim", path)
    assert spec is not None and spec.loader is not None
    sim = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sim)
    trace: list[UartBytes] = []
    for start in (10_000, 50_000):  # two calls: 12 bytes in, 5 bytes out
        trace.append(UartBytes(True, start, bytes(12)))
        answer = start + 12 * 176 + 1600  # the first byte 100 us after the last one arrived
        for k, cycle in enumerate(
            [answer, answer + 30, *(answer + 30 + 176 * j for j in range(1, 4))]
        ):
            trace.append(UartBytes(False, cycle, bytes([k])))
    assert sim.byte_cycles(trace) == 176
    assert sim.answer_delays(trace, 176) == [100.0, 100.0]
    assert sim.byte_cycles([UartBytes(True, 5, b"x")]) is None
    # bytes a call puts on the line: 12 in and 5 out, whatever the reads and writes they took;
    # a third request split over two reads (7 + 3) with a 4-byte answer
    trace += [UartBytes(True, 90_000, bytes(7)), UartBytes(True, 90_100, bytes(3))]
    trace += [UartBytes(False, 95_000, bytes(4)), UartBytes(True, 99_000, bytes(1))]
    assert sim.call_bytes(trace) == 17
    assert sim.call_bytes(trace[:6]) is None  # no answer ended by a next request yet
    # the calls of a service line spread over the pairs of runners: every call in one share,
    # shares one apart at most, none empty; a pair's ratio is calls per second, hwbridge / ros_lib
    assert sim._shares(1000, 4) == [250] * 4
    assert sim._shares(10, 4) == [3, 3, 2, 2]
    assert sim._shares(2, 4) == [1, 1]
    assert sim._ratio([1.0, 3.0], [4.0, 4.0]) == 2.0


@pytest.mark.skipif(
    shutil.which("avr-g++") is None
    or shutil.which("simavr") is None
    or not Path("/usr/share/arduino/hardware/arduino/avr/cores/arduino").is_dir(),
    reason="needs gcc-avr, avr-libc, arduino-core-avr and simavr (Debian packages)",
)
def test_sim_profile_gives_a_call_as_the_functions_it_ran_through() -> None:
    """``tools/bench/sim_profile.py --timeline N``: call N's answer as stretches of one function
    each, in order from the request's last byte, among them the frame writer and the copy into
    the UART's ring; the per-function sums are there too. No timing checks (cycles differ with
    the firmware)."""
    line = _one_line("sim_profile.py", "--calls", "6", "--timeline", "3")
    assert line["firmware"] == "HelloService" and line["calls"] >= 6
    timeline = line["timeline"]
    starts = [start for start, _cycles, _name in timeline]
    assert starts == sorted(starts) and all(cycles > 0 for _start, cycles, _name in timeline)
    assert all(a[2] != b[2] for a, b in itertools.pairwise(timeline))  # one stretch a function
    names = " ".join(name for _start, _cycles, name in timeline)
    assert "write_frame" in names and "put_block" in names, names
    assert sum(cycles for _start, cycles, _name in timeline) > 1000
    assert "write_frame" in " ".join(line["per_call_by_function"])


def test_zenoh_reply_bench_times_each_way_of_replying() -> None:
    """``tools/bench/zenoh_reply.py`` with a few calls: one line with the p50 of each way of
    replying (inline, from another thread, from a woken one) and the extras over inline. Fields
    only, no timing checks."""
    (line,) = _run_json("zenoh_reply.py", "--calls", "60", timeout=120)
    assert line["bench"] == "zenoh_reply" and line["peer"] == "inline_reply"
    assert line["calls"] == 60
    for kind in ("inline", "other_thread", "other_thread_woken"):
        assert line[f"{kind}_p50_us"] > 0
    assert line["other_thread_extra_us"] == pytest.approx(
        line["other_thread_p50_us"] - line["inline_p50_us"], abs=0.2
    )
    assert line["woken_extra_us"] == pytest.approx(
        line["other_thread_woken_p50_us"] - line["inline_p50_us"], abs=0.2
    )
