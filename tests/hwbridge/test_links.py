"""Byte links with real parts: ptys, loopback sockets, threads (no mocks).

Every scheme runs the same contract (round trips, peer loss, close() waking blocked I/O, writes
that do not interleave); scheme-specific tests follow.
"""

from __future__ import annotations

import itertools
import logging
import os
import random
import re
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hwbridge.errors import HwBridgeError, LinkError
from hwbridge.links import (
    Link,
    LinkClosedError,
    MemoryLink,
    create_link,
    memory_pair,
    open_link,
    register_scheme,
    schemes,
)
from hwbridge.links.pseudoterminal import PtyLink
from hwbridge.links.serialport import SerialLink
from hwbridge.links.spy import hexdump
from hwbridge.links.tcp import TcpListenLink
from tests.netutil import free_port, wait_until

termios = pytest.importorskip("termios", reason="ptys and termios are POSIX only")

pytestmark = [
    pytest.mark.timeout(30),
    # An unclosed socket or file shows up as a ResourceWarning when collected: make it fail.
    pytest.mark.filterwarnings("error::ResourceWarning"),
    pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning"),
]

JOIN = 10.0  # generous bound for a thread to finish; never a speed assertion
_names = itertools.count()


def open_fds() -> set[str]:
    """This process's open file descriptors (Linux; empty elsewhere)."""
    folder = Path("/proc/self/fd")
    return {entry.name for entry in folder.iterdir()} if folder.exists() else set()


@pytest.fixture(autouse=True)
def no_leaked_descriptors() -> Iterator[None]:
    """Each test closes what it opens: sockets, ptys, wakers and selectors go with close()."""
    before = open_fds()
    yield
    assert wait_until(lambda: open_fds() <= before, timeout=2), open_fds() - before


# ---------------------------------------------------------------------------------- helpers


def connect_listener(listener: TcpListenLink, client_url: str, **options: Any) -> Link:
    """Open a socket:// client to ``listener`` and let the listener accept it."""
    client = open_link(client_url, **options)
    assert wait_until(lambda: listener.read(timeout=0.05) == b"" and listener.connected)
    return client


def listen() -> TcpListenLink:
    link = open_link("tcp-listen://127.0.0.1:0")
    assert isinstance(link, TcpListenLink)
    return link


def client_url(listener: TcpListenLink) -> str:
    assert listener.bound_address is not None
    return f"socket://127.0.0.1:{listener.bound_address[1]}"


def make_memory(_: Path) -> tuple[Link, Link]:
    return memory_pair()


def make_pty(_: Path) -> tuple[Link, Link]:
    master = open_link("pty://")
    assert isinstance(master, PtyLink)
    assert master.slave_path is not None
    slave = open_link(f"serial://{master.slave_path}?baud=115200")
    return master, slave


def make_tcp(_: Path) -> tuple[Link, Link]:
    listener = listen()
    return listener, connect_listener(listener, client_url(listener))


def make_spy(tmp: Path) -> tuple[Link, Link]:
    name = f"spy-{next(_names)}"
    spied = open_link(f"spy+memory://{name}?end=0", spy_file=str(tmp / "spy.txt"))
    return spied, open_link(f"memory://{name}")


PAIRS: dict[str, Callable[[Path], tuple[Link, Link]]] = {
    "memory": make_memory,
    "pty-vs-serial": make_pty,
    "tcp-listen-vs-socket": make_tcp,
    "spy+memory": make_spy,
}


@pytest.fixture(params=sorted(PAIRS))
def pair(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[Link, Link]]:
    first, second = PAIRS[request.param](tmp_path)
    try:
        yield first, second
    finally:
        first.close()
        second.close()


def transfer(src: Link, dst: Link, chunks: list[bytes]) -> bytes:
    """Write ``chunks`` from a thread while reading them on ``dst``; returns what arrived."""
    expected = sum(len(c) for c in chunks)
    errors: list[LinkError] = []

    def writer() -> None:
        try:
            for chunk in chunks:
                src.write(chunk)
        except LinkError as exc:  # reported by the assertion below
            errors.append(exc)

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    got = bytearray()
    deadline = time.monotonic() + JOIN
    while len(got) < expected and time.monotonic() < deadline:
        got += dst.read(4096, timeout=0.2)
    thread.join(JOIN)
    assert not thread.is_alive()
    assert errors == []
    return bytes(got)


def read_in_thread(link: Link, timeout: float | None = None) -> tuple[threading.Thread, list[Any]]:
    """Start a thread blocked in ``link.read``; the list gets its result or exception."""
    outcome: list[Any] = []

    def reader() -> None:
        try:
            outcome.append(link.read(timeout=timeout))
        except LinkError as exc:
            outcome.append(exc)

    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    return thread, outcome


# -------------------------------------------------------------------------- contract: every link

chunk_lists = st.lists(st.binary(min_size=1, max_size=700), min_size=1, max_size=6)


@settings(
    max_examples=25,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(forth=chunk_lists, back=chunk_lists)
def test_round_trip_random_bytes(
    pair: tuple[Link, Link], forth: list[bytes], back: list[bytes]
) -> None:
    first, second = pair
    assert transfer(first, second, forth) == b"".join(forth)
    assert transfer(second, first, back) == b"".join(back)


def test_all_byte_values_pass_unchanged(pair: tuple[Link, Link]) -> None:
    every = bytes(range(256)) * 4
    first, second = pair
    assert transfer(first, second, [every]) == every
    assert transfer(second, first, [every]) == every


def test_read_times_out_with_empty_bytes(pair: tuple[Link, Link]) -> None:
    first, second = pair
    assert first.read(timeout=0.05) == b""
    assert second.read(timeout=0) == b""
    assert first.is_open
    assert second.is_open


@pytest.mark.parametrize("side", [0, 1])
def test_close_from_another_thread_unblocks_a_blocked_read(
    pair: tuple[Link, Link], side: int
) -> None:
    link = pair[side]
    thread, outcome = read_in_thread(link, timeout=None)
    wait_until(lambda: False, timeout=0.1)  # give the reader time to block (not required)
    link.close()
    thread.join(JOIN)
    assert not thread.is_alive()
    assert len(outcome) == 1
    assert isinstance(outcome[0], LinkClosedError)
    assert outcome[0].local
    assert not link.is_open


def test_concurrent_writes_do_not_interleave(pair: tuple[Link, Link]) -> None:
    first, second = pair
    writers, records, size = 4, 6, 20_000  # records larger than the buffers: partial sends

    def write_records(index: int) -> None:
        for seq in range(records):
            first.write(bytes([index]) * (size - 1) + bytes([seq]))

    threads = [
        threading.Thread(target=write_records, args=(i,), daemon=True) for i in range(writers)
    ]
    for thread in threads:
        thread.start()
    got = bytearray()
    deadline = time.monotonic() + JOIN
    while len(got) < writers * records * size and time.monotonic() < deadline:
        got += second.read(65536, timeout=0.2)
    for thread in threads:
        thread.join(JOIN)
    assert len(got) == writers * records * size
    seen: dict[int, list[int]] = {i: [] for i in range(writers)}
    for start in range(0, len(got), size):
        record = got[start : start + size]
        assert len(set(record[:-1])) == 1, f"interleaved record at offset {start}"
        seen[record[0]].append(record[-1])
    assert all(seqs == list(range(records)) for seqs in seen.values())


def test_io_on_a_closed_link_raises_local_link_closed_error(pair: tuple[Link, Link]) -> None:
    first, _ = pair
    first.close()
    first.close()  # idempotent
    with pytest.raises(LinkClosedError) as read_error:
        first.read()
    with pytest.raises(LinkClosedError) as write_error:
        first.write(b"x")
    assert read_error.value.local
    assert write_error.value.local
    assert "open()" in str(read_error.value)
    assert isinstance(read_error.value, HwBridgeError)


def test_stats_count_bytes_and_calls(pair: tuple[Link, Link]) -> None:
    first, second = pair
    first.open()  # a no-op on an open link
    assert transfer(first, second, [b"abc", b"defg"]) == b"abcdefg"
    assert first.stats.writes == 2
    assert first.stats.bytes_out == 7
    assert second.stats.bytes_in == 7
    assert 1 <= second.stats.reads <= 7
    assert first.stats.opens == 1
    assert first.stats.as_dict()["errors"] == 0


# ---------------------------------------------------------------------------------- memory://


def test_memory_peer_close_ends_the_other_side_after_draining() -> None:
    first, second = memory_pair()
    first.write(b"last words")
    first.close()
    assert second.read(timeout=1) == b"last words"
    with pytest.raises(LinkClosedError) as info:
        second.read(timeout=1)
    assert not info.value.local
    assert "other end" in str(info.value)
    assert not second.is_open
    with pytest.raises(LinkClosedError, match="reconnect"):
        second.write(b"x")
    assert second.stats.errors == 1
    # Both ends reopen and talk again.
    first.open()
    second.open()
    assert transfer(first, second, [b"again"]) == b"again"
    assert second.stats.opens == 2
    first.close()
    second.close()


def test_memory_two_urls_get_both_ends_and_a_third_is_refused() -> None:
    with open_link("memory://shared") as first, open_link("memory://shared") as second:
        assert first.connected
        assert second.connected
        with pytest.raises(LinkError, match="both ends open"):
            open_link("memory://shared")
        assert transfer(second, first, [b"hi"]) == b"hi"
    third = open_link("memory://shared")  # the name was forgotten when both ends closed
    assert not third.connected
    third.close()


def test_memory_buffer_is_bounded_and_writes_wait_or_time_out() -> None:
    first, second = memory_pair(buffer_size=16, write_timeout=0.05)
    first.write(b"y" * 16)
    with pytest.raises(LinkError, match=r"timed out .* 0 of 1 bytes"):
        first.write(b"z")
    assert second.read(max_bytes=100, timeout=1) == b"y" * 16
    first.write(b"z")
    assert second.read(timeout=1) == b"z"
    first.close()
    second.close()


def test_close_unblocks_a_writer_waiting_for_room() -> None:
    first, second = memory_pair(buffer_size=8)
    errors: list[LinkError] = []

    def writer() -> None:
        try:
            first.write(b"w" * 64)
        except LinkError as exc:
            errors.append(exc)

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    wait_until(lambda: False, timeout=0.1)  # let it fill the 8 bytes and wait
    assert thread.is_alive()
    first.close()
    thread.join(JOIN)
    assert not thread.is_alive()
    assert isinstance(errors[0], LinkClosedError)
    assert errors[0].local
    second.close()


# -------------------------------------------------------------------------- pty:// and serial


def test_pty_slave_is_raw_for_a_plain_open() -> None:
    with open_link("pty://") as master:
        assert isinstance(master, PtyLink)
        assert master.slave_path is not None
        fd = os.open(master.slave_path, os.O_RDWR | os.O_NOCTTY)
        try:
            attrs = termios.tcgetattr(fd)
            assert not attrs[3] & (termios.ECHO | termios.ICANON | termios.ISIG)
            assert not attrs[1] & termios.OPOST
            assert not attrs[0] & (termios.ICRNL | termios.INLCR | termios.IGNCR | termios.IXON)
            tricky = b"\r\n\x03\x04\x11\x13\x1a\x7f\xff\x00line\n"
            master.write(tricky)
            got = b""
            while len(got) < len(tricky):
                got += os.read(fd, 100)
            assert got == tricky
            os.write(fd, tricky)
            assert transfer_in(master, len(tricky)) == tricky
            assert master.read(timeout=0.05) == b""  # nothing echoed back
        finally:
            os.close(fd)


def transfer_in(link: Link, size: int) -> bytes:
    got = b""
    deadline = time.monotonic() + JOIN
    while len(got) < size and time.monotonic() < deadline:
        got += link.read(timeout=0.2)
    return got


def test_pty_peer_leaving_ends_the_session_and_the_next_peer_is_served() -> None:
    with open_link("pty://") as master:
        assert isinstance(master, PtyLink)
        assert master.read(timeout=0.05) == b""  # nobody has the slave open yet
        assert not master.connected
        with pytest.raises(LinkClosedError, match="no program has"):
            master.write(b"nobody listens")
        assert master.is_open
        for round_ in range(2):
            board = open_link(f"serial://{master.slave_path}")
            assert wait_until(lambda: master.connected)
            board.write(b"hello %d" % round_)
            assert transfer_in(master, 7) == b"hello %d" % round_
            board.write(b"bye")
            board.close()
            assert transfer_in(master, 3) == b"bye"  # bytes written before leaving arrive first
            with pytest.raises(LinkClosedError, match="closed it") as info:
                master.read(timeout=JOIN)
            assert not info.value.local
            assert master.is_open
            assert master.read(timeout=0.05) == b""


def test_pty_symlink_points_at_the_slave_while_open(tmp_path: Path) -> None:
    path = tmp_path / "board0"
    with open_link(f"pty://?symlink={path}") as master:
        assert isinstance(master, PtyLink)
        assert path.is_symlink()
        assert str(path.readlink()) == master.slave_path
        with open_link(str(path)) as board:
            board.write(b"via symlink")
            assert transfer_in(master, 11) == b"via symlink"
    assert not path.exists()


def test_serial_link_sees_the_pty_master_close_as_link_closed() -> None:
    master_fd, slave_fd = os.openpty()
    slave_path = os.ttyname(slave_fd)
    os.close(slave_fd)
    link = open_link(slave_path, baud=9600)
    try:
        os.write(master_fd, b"ping")
        assert transfer_in(link, 4) == b"ping"
        thread, outcome = read_in_thread(link, timeout=None)
        os.close(master_fd)
        thread.join(JOIN)
        assert not thread.is_alive()
        assert isinstance(outcome[0], LinkClosedError)
        assert not outcome[0].local
        assert slave_path in str(outcome[0])
        assert not link.is_open
        with pytest.raises(LinkClosedError, match="reconnect"):
            link.read()
        with pytest.raises(LinkError, match="does not exist"):
            link.open()  # the pty is gone for good
    finally:
        link.close()


def test_serial_reads_after_a_full_and_a_draining_read() -> None:
    """A read that filled its size leaves the rest to the next read; one that drained the port
    makes the next wait for data first (poll before read): both see every byte, in order, and
    a timeout still returns nothing."""
    with open_link("pty://") as master:
        assert isinstance(master, PtyLink)
        with open_link(f"serial://{master.slave_path}") as board:
            assert wait_until(lambda: master.connected)
            master.write(b"0123456789")
            got = b""
            while len(got) < 10:
                chunk = board.read(4, timeout=JOIN)
                assert 1 <= len(chunk) <= 4
                got += chunk
            assert got == b"0123456789"
            assert board.read(4, timeout=0.05) == b""  # drained: waits, then times out
            assert board.read(4, timeout=0) == b""
            master.write(b"ab")
            assert transfer_in(board, 2) == b"ab"
            master.write(b"xyz")  # taken by reads that do not wait
            seen = bytearray()
            assert wait_until(lambda: seen.extend(board.read(3, timeout=0)) or seen == b"xyz")


@settings(max_examples=25, deadline=None, derandomize=True)
@given(chunks=chunk_lists, sizes=st.lists(st.integers(1, 64), min_size=1, max_size=8))
def test_serial_reads_of_any_size_take_every_byte_in_order(
    chunks: list[bytes], sizes: list[int]
) -> None:
    """Reads of sizes that fill (the next read reads at once) or drain (the next waits in poll
    first) in any order: the bytes written come out whole and in order."""
    expected = b"".join(chunks)
    with open_link("pty://") as master:
        assert isinstance(master, PtyLink)
        with open_link(f"serial://{master.slave_path}") as board:
            assert wait_until(lambda: master.connected)
            writer = threading.Thread(target=lambda: [master.write(c) for c in chunks])
            writer.start()
            got = bytearray()
            deadline = time.monotonic() + JOIN
            for size in itertools.cycle(sizes):
                if len(got) >= len(expected) or time.monotonic() > deadline:
                    break
                chunk = board.read(size, timeout=0.2)
                assert len(chunk) <= size
                got += chunk
            writer.join(JOIN)
            assert bytes(got) == expected


def test_serial_write_blocked_by_a_board_that_does_not_read_is_unblocked_by_close() -> None:
    with open_link("pty://") as master:
        assert isinstance(master, PtyLink)
        board = open_link(f"serial://{master.slave_path}")
        errors: list[LinkError] = []

        def writer() -> None:
            try:
                board.write(b"z" * 1_000_000)  # far more than the pty buffers
            except LinkError as exc:
                errors.append(exc)

        thread = threading.Thread(target=writer, daemon=True)
        thread.start()
        wait_until(lambda: False, timeout=0.1)
        assert thread.is_alive()
        board.close()
        thread.join(JOIN)
        assert not thread.is_alive()
        assert isinstance(errors[0], LinkClosedError)
        assert errors[0].local


def test_serial_options_and_errors(tmp_path: Path) -> None:
    with open_link("pty://") as master:
        assert isinstance(master, PtyLink)
        assert master.slave_path is not None
        url = f"serial://{master.slave_path}?baud=57600&parity=even&stopbits=2&reset=1"
        with open_link(url, bytesize=7, rtscts=False) as board:
            assert isinstance(board, SerialLink)
            assert (board.baud, board.parity, board.stopbits, board.bytesize) == (57600, "E", 2, 7)
            with pytest.raises(LinkError, match="busy"):
                open_link(master.slave_path)  # exclusive by default
    with pytest.raises(LinkError, match="does not exist") as info:
        open_link("serial:///dev/hwbridge-no-such-port")
    assert "/dev/hwbridge-no-such-port" in str(info.value)
    with pytest.raises(LinkError, match="absolute path"):
        open_link("serial://dev/hwbridge-no-such-port")
    with pytest.raises(LinkError, match="socket://localhost:5760"):
        open_link("localhost:5760")


@pytest.mark.skipif(os.getuid() == 0, reason="root opens any device")
def test_serial_permission_denied_says_which_group() -> None:
    with open_link("pty://") as master:
        assert isinstance(master, PtyLink)
        assert master.slave_path is not None
        Path(master.slave_path).chmod(0)
        with pytest.raises(LinkError, match=r"permission denied.*group"):
            open_link(master.slave_path)


# ----------------------------------------------------------------------- socket:// tcp-listen://


def test_tcp_listen_serves_one_client_then_the_next() -> None:
    listener = listen()
    try:
        assert listener.read(timeout=0.05) == b""
        assert not listener.connected
        with pytest.raises(LinkClosedError, match="no client"):
            listener.write(b"x")
        for round_ in range(2):
            client = connect_listener(listener, client_url(listener))
            assert listener.client_address is not None
            assert transfer(client, listener, [b"hello %d" % round_]) == b"hello %d" % round_
            assert transfer(listener, client, [b"ack"]) == b"ack"
            client.close()
            with pytest.raises(LinkClosedError, match="disconnected") as info:
                transfer_in(listener, 1)
            assert not info.value.local
            assert listener.is_open
            assert not listener.connected
            assert listener.client_address is None
    finally:
        listener.close()


def test_tcp_listen_with_takeover_a_new_client_replaces_a_stale_one() -> None:
    listener = open_link("tcp-listen://127.0.0.1:0?takeover=1")
    assert isinstance(listener, TcpListenLink)
    old = connect_listener(listener, client_url(listener))
    new = open_link(client_url(listener))
    try:
        new.write(b"I rebooted")
        with pytest.raises(LinkClosedError, match="replaced"):
            transfer_in(listener, 10)
        assert transfer_in(listener, 10) == b"I rebooted"
        with pytest.raises(LinkClosedError):
            transfer_in(old, 1)  # the host dropped the stale connection
        assert transfer(listener, new, [b"welcome"]) == b"welcome"
    finally:
        for link in (old, new, listener):
            link.close()


def test_tcp_listen_refuses_a_second_client_by_default(caplog: pytest.LogCaptureFixture) -> None:
    """Nobody on the network replaces a connected board (issue 19 item 6)."""
    listener = listen()
    first = connect_listener(listener, client_url(listener))
    second = open_link(client_url(listener))
    try:
        second.write(b"let me in")
        first.write(b"first")
        assert transfer_in(listener, 5) == b"first"  # still serving the first client
        assert listener.read(timeout=0.3) == b""  # the waiting connection is accepted, refused
        with pytest.raises(LinkClosedError):
            transfer_in(second, 1)  # closed by the listener
        assert any("refused a second connection" in r.getMessage() for r in caplog.records)
        assert transfer(listener, first, [b"still you"]) == b"still you"
        first.close()
        with pytest.raises(LinkClosedError, match="disconnected"):
            transfer_in(listener, 1)
        third = connect_listener(listener, client_url(listener))  # once it went, the next one
        assert transfer(third, listener, [b"next"]) == b"next"
        third.close()
    finally:
        for link in (first, second, listener):
            link.close()


def test_tcp_listen_allow_list(caplog: pytest.LogCaptureFixture) -> None:
    refused = open_link("tcp-listen://127.0.0.1:0?allow=192.168.4.0/24")
    allowed = open_link("tcp-listen://127.0.0.1:0?allow=10.0.0.0/8,127.0.0.1")
    assert isinstance(refused, TcpListenLink) and isinstance(allowed, TcpListenLink)
    try:
        outsider = open_link(client_url(refused))
        refused.read(timeout=0.3)  # accepts, and refuses it
        assert not refused.connected
        assert any("not in allow=192.168.4.0/24" in r.getMessage() for r in caplog.records)
        with pytest.raises(LinkClosedError):
            transfer_in(outsider, 1)
        outsider.close()
        insider = connect_listener(allowed, client_url(allowed))
        assert transfer(insider, allowed, [b"hi"]) == b"hi"
        insider.close()
    finally:
        refused.close()
        allowed.close()
    with pytest.raises(LinkError, match="not an address or network"):
        create_link("tcp-listen://:0?allow=192.168.4.0/33")


def test_tcp_listener_gone_then_back_on_the_same_port() -> None:
    listener = listen()
    port = listener.bound_address
    client = connect_listener(listener, client_url(listener))
    listener.close()
    assert listener.bound_address is None
    with pytest.raises(LinkClosedError) as info:
        transfer_in(client, 1)
    assert not info.value.local
    assert not client.is_open
    listener.open()  # port=0 binds the port it had before
    assert listener.bound_address == port
    client.open()  # reconnects
    assert wait_until(lambda: listener.read(timeout=0.05) == b"" and listener.connected)
    assert transfer(client, listener, [b"back"]) == b"back"
    client.close()
    listener.close()


def test_socket_to_a_closed_port_says_connection_refused() -> None:
    port = free_port()
    link = create_link(f"socket://127.0.0.1:{port}")
    with pytest.raises(LinkError) as info:
        link.open()
    assert not isinstance(info.value, LinkClosedError)
    assert f"127.0.0.1:{port}" in str(info.value)
    assert "refused" in str(info.value)
    assert "nothing is listening" in str(info.value)
    assert not link.is_open
    assert link.stats.errors == 1


def test_tcp_listen_on_a_busy_port_says_so() -> None:
    listener = listen()
    try:
        assert listener.bound_address is not None
        with pytest.raises(LinkError, match=r"already in use|another program"):
            open_link(f"tcp-listen://127.0.0.1:{listener.bound_address[1]}")
    finally:
        listener.close()


def test_close_unblocks_an_idle_listener_and_a_blocked_socket_writer() -> None:
    listener = listen()
    thread, outcome = read_in_thread(listener, timeout=None)
    listener.close()
    thread.join(JOIN)
    assert isinstance(outcome[0], LinkClosedError)

    listener = listen()
    client = connect_listener(listener, client_url(listener))
    errors: list[LinkError] = []

    def writer() -> None:  # nobody reads: the socket buffers fill and send waits
        try:
            client.write(b"q" * 64_000_000)
        except LinkError as exc:
            errors.append(exc)

    writing = threading.Thread(target=writer, daemon=True)
    writing.start()
    wait_until(lambda: False, timeout=0.2)
    client.close()
    writing.join(JOIN)
    assert not writing.is_alive()
    assert isinstance(errors[0], LinkClosedError)
    assert errors[0].local
    listener.close()


# ------------------------------------------------------------------------------------ spy+URL


HEX_LINE = re.compile(r"^\s*\d+\.\d+ (TX|RX) ([0-9a-f]{8})  ((?:[0-9a-f]{2} {1,2})*[0-9a-f]{2})")


def parse_dump(lines: list[str]) -> dict[str, bytes]:
    """Rebuild the bytes of each direction from hex-dump lines, checking the offsets."""
    streams = {"TX": bytearray(), "RX": bytearray()}
    for line in lines:
        match = HEX_LINE.match(line)
        if match:
            direction, offset, hex_text = match.groups()
            assert int(offset, 16) == len(streams[direction])
            streams[direction] += bytes.fromhex(hex_text)
    return {k: bytes(v) for k, v in streams.items()}


def test_spy_file_has_the_hex_of_what_was_written_and_read(tmp_path: Path) -> None:
    out = tmp_path / "dump.txt"
    sent = b"hello, board!\r\n" + random.Random(7).randbytes(100)
    received = b"\x00\x01 board says hi\xff" * 3
    spied = open_link(f"spy+memory://spy-file?end=0&spy_file={out}")
    board = open_link("memory://spy-file")
    assert transfer(spied, board, [sent[:40], sent[40:]]) == sent
    assert transfer(board, spied, [received]) == received
    spied.close()
    board.close()
    text = out.read_text()
    assert parse_dump(text.splitlines()) == {"TX": sent, "RX": received}
    assert "|hello, board!.." in text
    assert "open memory://spy-file" in text
    assert "close" in text.splitlines()[-1]


def test_spy_logs_to_its_logger_and_reports_errors(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="hwbridge.links.spy")
    spied = open_link("spy+memory://spy-log?end=0")
    board = open_link("memory://spy-log")
    assert spied.connected
    assert transfer(spied, board, [b"ping"]) == b"ping"
    assert transfer(board, spied, [b"pong"]) == b"pong"
    board.close()
    with pytest.raises(LinkClosedError):
        spied.read(timeout=JOIN)
    assert not spied.is_open  # lost with the memory link it wraps
    spied.close()
    lines = [r.getMessage().split(" ", 1)[1] for r in caplog.records if r.name.endswith("spy")]
    assert parse_dump(lines) == {"TX": b"ping", "RX": b"pong"}
    assert any("LinkClosedError" in line for line in lines)


def test_spy_over_a_listener_survives_a_client_leaving(tmp_path: Path) -> None:
    spied = open_link("spy+tcp-listen://127.0.0.1:0", spy_file=str(tmp_path / "x.txt"))
    inner = spied.inner  # type: ignore[attr-defined]
    assert isinstance(inner, TcpListenLink)
    client = open_link(client_url(inner))
    assert transfer(client, spied, [b"hi"]) == b"hi"
    client.close()
    with pytest.raises(LinkClosedError):
        transfer_in(spied, 1)
    assert spied.is_open
    spied.close()


def test_hexdump_layout() -> None:
    lines = list(hexdump(bytes(range(0x41, 0x41 + 18)), offset=32))
    assert lines[0] == (
        "00000020  41 42 43 44 45 46 47 48  49 4a 4b 4c 4d 4e 4f 50 |ABCDEFGHIJKLMNOP|"
    )
    assert lines[1].startswith("00000030  51 52 ")
    assert lines[1].endswith("|QR|")


# ------------------------------------------------------------------------ URLs and the registry


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("seral:///dev/ttyACM0", "did you mean serial://"),
        ("tcp-lisen://:0", "did you mean tcp-listen://"),
        ("sokcet://127.0.0.1:1", "did you mean socket://"),
        ("spy+seral:///dev/ttyACM0", "did you mean serial://"),
        ("memroy://x", "did you mean memory://"),
        ("tcp://10.0.0.2:11411", "socket://HOST:PORT"),
        ("", "empty link URL"),
        ("spy+", "wraps nothing"),
        ("socket://127.0.0.1", "no port"),
        ("socket://:1234", "no host"),
        ("socket://127.0.0.1:99999", "bad port"),
        ("tcp-listen://", "no port"),
        ("memory://", "no name"),
        ("pty:///dev/pts/3", "takes no path"),
        ("serial://", "names no serial port"),
        ("serial:///dev/x?baud=fast", "bad value 'fast' for option 'baud'"),
        ("serial:///dev/x?bau=9600", "did you mean 'baud'"),
        ("serial:///dev/x?baud=1&baud=2", "given twice"),
        ("serial:///dev/x?parity=maybe", "expected N, E, O"),
        ("memory://x?buffer_size=0", "positive"),
        ("spy+memory://x?spy_fil=a.txt", "did you mean 'spy_file'"),
    ],
)
def test_bad_urls_raise_link_error_with_a_hint(url: str, expected: str) -> None:
    with pytest.raises(LinkError) as info:
        create_link(url)
    assert expected in str(info.value)


def test_unknown_scheme_lists_the_known_ones() -> None:
    with pytest.raises(LinkError) as info:
        create_link("zzz://x")
    message = str(info.value)
    for scheme in ("serial", "socket", "tcp-listen", "pty", "memory", "spy"):
        assert scheme in message


def test_schemes_and_bare_paths() -> None:
    table = schemes()
    assert table["serial"] == "hwbridge.links.serialport:SerialLink"
    assert {"socket", "tcp-listen", "pty", "memory", "spy"} <= table.keys()
    for path in ("/dev/ttyUSB0", "COM3", "/dev/pts/5?baud=9600", "SERIAL:///dev/ttyACM0"):
        assert type(create_link(path)).__name__ == "SerialLink"
    assert type(create_link("spy+/dev/ttyUSB0")).__name__ == "SpyLink"
    assert create_link("/dev/pts/5?baud=9600", baud=230400).baud == 230400  # type: ignore[attr-defined]


def test_register_scheme_and_plugin_errors() -> None:
    def factory(url: str, **options: Any) -> Link:
        return MemoryLink("memory://" + url.split("://", 1)[1], **options)

    register_scheme("loopback-test", factory)
    assert schemes()["loopback-test"].endswith("factory")
    first = open_link("loopback-test://reg")
    second = open_link("LOOPBACK-TEST://reg")
    assert transfer(first, second, [b"registered"]) == b"registered"
    first.close()
    second.close()

    register_scheme("broken-test", "hwbridge_no_such_module:Link")
    with pytest.raises(LinkError, match="failed to load"):
        create_link("broken-test://x")
    register_scheme("not-a-link-test", lambda url, **_: object())  # type: ignore[arg-type]
    with pytest.raises(LinkError, match="not a Link"):
        create_link("not-a-link-test://x")
    with pytest.raises(ValueError, match="invalid scheme"):
        register_scheme("9bad scheme", factory)


def test_entry_point_plugins_are_found(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "hwbridge_ep_plugin.py").write_text(
        textwrap.dedent(
            """
            from hwbridge.links import MemoryLink

            def make(url, **options):
                return MemoryLink("memory://ep-" + url.split("://", 1)[1], **options)
            """
        )
    )
    dist = tmp_path / "hwbridge_ep_plugin-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: hwbridge-ep-plugin\nVersion: 1.0\n"
    )
    (dist / "entry_points.txt").write_text("[hwbridge.links]\nep-test = hwbridge_ep_plugin:make\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    link = open_link("ep-test://x")  # an unknown scheme makes the registry look again
    assert isinstance(link, MemoryLink)
    assert link.name == "ep-x"
    assert schemes()["ep-test"] == "hwbridge_ep_plugin:make"
    link.close()


def test_builtins_are_declared_once_in_their_tables_not_as_entry_points() -> None:
    """hwbridge's own schemes, protocols and device types live in the registries' built-in
    tables; its pyproject.toml declares no entry point naming one (entry points are how other
    packages add theirs)."""
    if sys.version_info < (3, 11):
        pytest.skip("tomllib is Python 3.11+")
    import tomllib

    from hwbridge.links.registry import BUILTIN_SCHEMES
    from hwbridge.links.registry import ENTRY_POINT_GROUP as LINKS
    from hwbridge.protocols.registry import BUILTIN_PROTOCOLS
    from hwbridge.protocols.registry import ENTRY_POINT_GROUP as PROTOCOLS
    from hwbridge.robot.registry import BUILTIN_DEVICES
    from hwbridge.robot.registry import ENTRY_POINT_GROUP as DEVICES

    project = tomllib.loads((Path(__file__).parents[2] / "pyproject.toml").read_text())["project"]
    declared = project.get("entry-points", {})
    for group, table in (
        (LINKS, BUILTIN_SCHEMES),
        (PROTOCOLS, BUILTIN_PROTOCOLS),
        (DEVICES, BUILTIN_DEVICES),
    ):
        entries: dict[str, str] = declared.get(group, {})
        assert not entries.keys() & table.keys(), group
        assert not set(entries.values()) & set(table.values()), group


def test_an_entry_point_cannot_replace_a_builtin_scheme(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    dist = tmp_path / "hwbridge_ep_override-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: hwbridge-ep-override\nVersion: 1.0\n"
    )
    (dist / "entry_points.txt").write_text("[hwbridge.links]\nMEMORY = elsewhere:Link\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(LinkError, match="unknown link scheme 'zzz-reread'"):
        create_link("zzz-reread://x")  # an unknown scheme makes the registry read them again
    assert any("cannot replace the built-in" in r.getMessage() for r in caplog.records)
    assert schemes()["memory"] == "hwbridge.links.memory:MemoryLink"


def test_importing_links_loads_no_io_library() -> None:
    code = (
        "import sys, hwbridge.links\n"
        "loaded = [m for m in sys.modules if m == 'serial' or m.startswith('serial.')\n"
        "          or m in ('hwbridge.links.tcp', 'hwbridge.links.serialport',\n"
        "                   'hwbridge.links.pseudoterminal', 'hwbridge.links.spy')]\n"
        "assert not loaded, loaded\n"
        "from hwbridge.links import SerialLink, create_link\n"
        "assert 'hwbridge.links.serialport' in sys.modules\n"
        "create_link('/dev/ttyUSB0')\n"
        "assert 'serial' not in sys.modules  # pyserial comes with the first open()\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert result.returncode == 0, result.stderr


def test_create_link_does_not_open_and_context_manager_closes() -> None:
    link = create_link("memory://ctx")
    assert not link.is_open
    assert "closed" in repr(link)
    with pytest.raises(LinkClosedError) as info:
        link.read()
    assert info.value.local
    with link as opened:
        assert opened is link
        assert opened.is_open
    assert not link.is_open
