"""The soak bench's per-stage figures: the client's final counts once the boards stop, and a
stage's summary line (losses, latency, growth, the boards' loss account, acceptance)."""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import Any

from _soak_board import board_name, topic_name
from _soak_children import Child

WARM_S = 120.0
"""RSS and descriptor growth are taken from this far into a run (or a fifth of a shorter run)."""

DRAIN_IDLE_S = 5.0
"""After the boards stop: the client's counts are final once none has grown for this long."""
DRAIN_MAX_S = 120.0


def wait_drained(
    client: Child, counts: dict[str, Any], boards: int, reliable: int
) -> tuple[dict[str, Any], float]:
    """The client's final counts once what was in flight has arrived: every reliable message
    the boards published, or nothing more for DRAIN_IDLE_S (a loaded machine may hold seconds of
    backlog in the bridge's reliable windows and queues); and how long that took."""
    wanted = {
        topic_name(index, j): counts[board_name(index)]["published"][j]
        for index in range(boards)
        for j in range(reliable)
    }
    started = last_growth = time.monotonic()
    last_total = -1
    while True:
        final: dict[str, Any] = json.loads(client.ask("final", 30))
        received: dict[str, int] = final["received"]
        now = time.monotonic()
        if all(received.get(topic, 0) >= sent for topic, sent in wanted.items()):
            break
        total = sum(received.values())
        if total != last_total:
            last_total, last_growth = total, now
        if now - last_growth >= DRAIN_IDLE_S or now - started >= DRAIN_MAX_S:
            break
        time.sleep(0.5)
    return final, round(time.monotonic() - started, 1)


def stage_summary(
    args: argparse.Namespace,
    boards: int,
    minutes: float,
    samples: list[dict[str, Any]],
    counts: dict[str, Any],
    final: dict[str, Any],
    bridge_cpu: float,
    late: int,
) -> dict[str, Any]:
    received: dict[str, int] = final["received"]
    first_seq: dict[str, int] = final["first_seq"]
    reliable_lost = best_effort_lost = published = refused = reliable_lost_at_start = 0
    for index in range(boards):
        board = counts[board_name(index)]
        for j in range(args.topics):
            sent: int = board["published"][j]
            lost = sent - received.get(topic_name(index, j), 0)
            published += sent
            refused += board["refused"][j]
            if j < args.reliable:
                reliable_lost += lost
                reliable_lost_at_start += first_seq.get(topic_name(index, j), sent)
            else:
                best_effort_lost += lost
    duration = minutes * 60.0
    warm = min(WARM_S, duration / 5)
    warm_samples = [s for s in samples if s["t_s"] >= warm] or samples
    start, end = warm_samples[0], samples[-1]
    rss_growth = 100.0 * (end["rss_kb"] - start["rss_kb"]) / start["rss_kb"]
    return {
        "bench": "soak",
        "boards": boards,
        "topics": args.topics,
        "reliable_topics": args.reliable,
        "rate_hz": args.rate,
        "minutes": minutes,
        "cpu_cores": round(bridge_cpu, 3),
        "cpu_cores_max_sample": max(s["bridge_cpu_cores"] for s in samples),
        "rss_kb_start": start["rss_kb"],
        "rss_kb_end": end["rss_kb"],
        "rss_growth_pct": round(rss_growth, 2),
        "rss_from_s": start["t_s"],
        "fds_start": start["fds"],
        "fds_growth": end["fds"] - start["fds"],
        "threads_end": end["threads"],
        "p50_ms": final["p50_ms"],
        "p99_ms": final["p99_ms"],
        "max_ms": final["max_ms"],
        "reliable_lost": reliable_lost,
        "reliable_lost_at_start": reliable_lost_at_start,
        "best_effort_lost": best_effort_lost,
        "board_session_ends": {
            key: sum(counts[board_name(index)][key] for index in range(boards))
            for key in ("link_losses", "peer_resets")
        },
        **_loss_account(counts, boards),
        "out_of_order": sum(final["out_of_order"].values()),
        "published": published,
        "refused_by_board": refused,
        "messages_per_s": round(final["messages"] / duration, 1),
        "asked_per_s": boards * args.topics * args.rate,
        "offered_per_s": round(published / duration, 1),
        "late_ticks": late,
        "calls": final["calls"],
        "calls_failed": final["calls_failed"],
        "calls_skipped": final["calls_skipped"],
        "calls_asked_per_s": float(boards) if getattr(args, "calls", True) else 0.0,
        "call_p50_ms": final["call_p50_ms"],
        "call_p99_ms": final["call_p99_ms"],
        "emulator_cpu_cores": round(
            sum(s["emulator_cpu_cores"] for s in samples) / len(samples), 3
        ),
        "client_cpu_cores": round(sum(s["client_cpu_cores"] for s in samples) / len(samples), 3),
        "boards_kind": args.boards_kind,
        "emulators": 0,
        "cpus": os.cpu_count(),
        "loadavg": [round(x, 2) for x in os.getloadavg()],
        "peer": None,
        "acceptance": {
            "below_one_core": bridge_cpu < 1.0,
            "rss_growth_below_5_pct": rss_growth < 5.0,
            "no_reliable_lost": reliable_lost == 0,
        },
    }


def _loss_account(counts: dict[str, Any], boards: int) -> dict[str, Any]:
    """What the firmware boards say of the link losses they declared (the Python emulators say
    nothing of this): each loss's gap since the board last read a byte from the bridge, how long
    the board's own loop had not run just before (starved of the CPU), and the bytes left unread
    in its socket; the boards' own stalls (loop gaps above 200 ms) and the longest gap."""
    notes: list[dict[str, int]] = []
    stalls = longest = 0
    for index in range(boards):
        board = counts[board_name(index)]
        notes += board.get("losses", [])
        stalls += board.get("own_stalls", 0)
        longest = max(longest, board.get("max_loop_gap_ms", 0))
    starved = [n for n in notes if n["loop_gap_ms"] >= 200]
    return {
        "board_own_stalls": stalls,
        "board_max_loop_gap_ms": longest,
        "loss_account": {
            "noted": len(notes),
            "board_starved": len(starved),
            "bridge_silent": len(notes) - len(starved),
            "since_byte_ms": sorted(n["since_byte_ms"] for n in notes)[-10:],
            "loop_gap_ms": sorted(n["loop_gap_ms"] for n in notes)[-10:],
            "pending_bytes": sorted(n["pending"] for n in notes)[-10:],
        },
    }
