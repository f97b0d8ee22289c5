"""The firmware identity in BOARD_INFO (PROTOCOL.md 2.6.1): its text form, the hashes, the build
tag, and what the bridge says about it.

Property tests (seeded, bounded): an identity's text decodes to the identity, through
BOARD_INFO's codec too; any prefix of that text (a board's send buffer cut it) decodes to the
identity with its last items missing, never with a value shortened; any text, garbage included,
decodes without raising.
"""

from __future__ import annotations

import dataclasses
import json
import logging

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.bridge.identity import FirmwareCheck, host_hashes, host_identity
from hwbridge.firmware.gen_msgs import LIBRARY_TYPES, MessageHeaders, messages_hash
from hwbridge.msg import registry
from hwbridge.protocols.base import FirmwareIdentity
from hwbridge.protocols.errors import ProtocolError
from hwbridge.protocols.native import control as ctl
from hwbridge.protocols.native._control.schema import SCHEMA_PATH, load_schema, schema_hash
from hwbridge.protocols.native.identity import (
    ITEM_KEYS,
    format_identity,
    parse_identity,
)
from hwbridge.protocols.native.identity import (
    schema_hash as host_schema_hash,
)
from hwbridge.robot.identity import BuildTag, build_tag, parse_build_tag

SETTINGS = settings(max_examples=200, deadline=None, derandomize=True)

_value = st.text(st.characters(blacklist_characters="\n", blacklist_categories=["Cs"]), max_size=24)
identities = st.builds(
    FirmwareIdentity,
    version=_value,
    name=_value,
    library_version=_value,
    schema_hash=_value,
    messages_hash=_value,
    build_tag=_value,
)


@SETTINGS
@given(identities)
def test_an_identity_round_trips_through_its_text_and_board_info(
    identity: FirmwareIdentity,
) -> None:
    text = format_identity(identity)
    assert parse_identity(text) == identity
    msg = ctl.BoardInfoMsg(3, "uno", b"\x01\x02", text)
    decoded = ctl.decode_control(msg.encode())
    assert isinstance(decoded, ctl.BoardInfoMsg)
    assert parse_identity(decoded.firmware_version) == identity


@SETTINGS
@given(identities, st.integers(min_value=0, max_value=400))
def test_a_cut_text_loses_its_last_items_and_never_shortens_one(
    identity: FirmwareIdentity, cut: int
) -> None:
    text = format_identity(identity)
    got = parse_identity(text[:cut])
    assert identity.version.startswith(got.version)
    sent = [attr for attr in ITEM_KEYS if getattr(identity, attr)]
    kept = [attr for attr in sent if getattr(got, attr)]
    assert kept == sent[: len(kept)]  # a prefix of the items, in order
    for attr in ITEM_KEYS:
        assert getattr(got, attr) in ("", getattr(identity, attr))


@SETTINGS
@given(st.text(max_size=200))
def test_any_text_parses_without_raising(text: str) -> None:
    got = parse_identity(text)
    assert got.version == text.split("\n", maxsplit=1)[0]
    if "\n" not in text:
        assert not got.known


@SETTINGS
@given(st.binary(max_size=80))
def test_board_info_garbage_is_a_protocol_error_or_an_identity(tail: bytes) -> None:
    """BOARD_INFO whose text is any bytes: refused as malformed UTF-8, or decoded to some
    identity; nothing else is raised."""
    payload = bytes([ctl.Opcode.BOARD_INFO, 1, 3]) + b"uno" + b"\x00" + tail
    try:
        msg = ctl.decode_control(payload)
    except ProtocolError:
        return
    assert isinstance(msg, ctl.BoardInfoMsg)
    parse_identity(msg.firmware_version)


def test_the_text_form_is_the_documented_one() -> None:
    identity = FirmwareIdentity(
        version="0.1.0",
        name="diffbot/base",
        library_version="0.1.0",
        schema_hash="1fdd80cd",
        messages_hash="fd79458c",
        build_tag="diffbot/base@0123456789ab",
    )
    assert format_identity(identity) == (
        "0.1.0\ns=1fdd80cd\nm=fd79458c\nb=diffbot/base@0123456789ab\nv=0.1.0\nn=diffbot/base\n"
    )
    assert format_identity(FirmwareIdentity(version="0.1.0")) == "0.1.0"  # the old form
    with pytest.raises(ValueError, match="line break"):
        format_identity(FirmwareIdentity(name="a\nb"))
    # unknown keys, lines without '=', repeated keys: ignored, the first value kept
    assert parse_identity("x\nq=1\nnonsense\ns=aa\ns=bb\n") == FirmwareIdentity(
        "x", schema_hash="aa"
    )


def test_the_firmware_name_falls_back_to_the_build_tag() -> None:
    assert FirmwareIdentity(build_tag="demo/base@0123456789ab").firmware_name == "demo/base"
    assert FirmwareIdentity(name="x", build_tag="demo/base@0123456789ab").firmware_name == "x"
    assert FirmwareIdentity(version="1.0").firmware_name == ""


def test_the_schema_hash_ignores_prose_and_sees_the_wire() -> None:
    raw = json.loads(SCHEMA_PATH.read_text(encoding="utf-8"))
    assert schema_hash(raw, 8) == load_schema().hash == host_schema_hash()
    assert len(load_schema().hash) == 8
    raw["doc"] = "other words"
    raw["messages"][0]["doc"] = "more other words"
    assert schema_hash(raw, 8) == load_schema().hash
    raw["constants"]["MIN_MTU"]["value"] = 25
    assert schema_hash(raw, 8) != load_schema().hash


def test_the_messages_hash_is_over_sorted_name_md5_lines() -> None:
    import hashlib

    md5s = {"std_msgs/String": "992ce8a1687cec8c8bd883ec73ca41d1", "a/B": "0" * 32}
    text = "a/B " + "0" * 32 + "\nstd_msgs/String 992ce8a1687cec8c8bd883ec73ca41d1\n"
    assert messages_hash(md5s) == hashlib.sha256(text.encode()).hexdigest()[:8]
    reg = registry()
    headers = MessageHeaders(reg)
    closure = headers.closure(LIBRARY_TYPES)
    assert sorted(closure) == sorted(LIBRARY_TYPES)  # the list is closed under dependencies
    assert host_hashes(reg)[1] == messages_hash({n: headers.md5(n) for n in closure})
    changed = {n: headers.md5(n) for n in closure} | {"std_msgs/String": "f" * 32}
    assert messages_hash(changed) != host_hashes(reg)[1]


def test_build_tags() -> None:
    tag = build_tag("diffbot", "base", b"robot: diffbot\n")
    assert tag.startswith("diffbot/base@") and len(tag) == len("diffbot/base@") + 12
    assert tag != build_tag("diffbot", "base", b"robot: diffbot\n\n")
    assert parse_build_tag(tag) == BuildTag("diffbot", "base", tag[-12:])
    for bad in ("", "diffbot/base", "diffbot@0123456789ab", "a/b@0123456789a", "a/b@0123456789AB"):
        assert parse_build_tag(bad) is None, bad


def test_firmware_check_warns_once_per_identity(caplog: pytest.LogCaptureFixture) -> None:
    reg = registry()
    check = FirmwareCheck("base", logging.getLogger("hwbridge.board.base"), reg)
    good = host_identity(reg, "1.0", "demo/base")
    stale = FirmwareIdentity("1.0", "demo/base", "0.1.0", "0badf00d", good.messages_hash)
    older = FirmwareIdentity("1.0", "demo/base", "0.1.0", good.schema_hash, "12345678")
    with caplog.at_level(logging.INFO):
        for identity in (None, FirmwareIdentity("0.1.0"), good, good, stale, stale, good, stale):
            check.check(identity)
        assert check.problems and "0badf00d" in check.problems[0]
        check.check(older)
        check.check(older)
        check.check(FirmwareIdentity("0.1.0"))
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 2, warnings
    assert "(control schema hash 0badf00d, this host's " in warnings[0]
    assert "(message definitions hash 12345678, this host's " in warnings[1]
    assert check.info() is None  # the last session told nothing
    check.check(good)
    info = check.info()
    assert info is not None and info["problems"] == [] and info["name"] == "demo/base"


def test_firmware_check_compares_build_tags(caplog: pytest.LogCaptureFixture) -> None:
    reg = registry()
    expected = build_tag("demo", "base", b"robot: demo\n")
    check = FirmwareCheck(
        "base", logging.getLogger("t"), reg, expected_build=expected, robot_file="demo.yaml"
    )
    own = host_identity(reg, "")
    with caplog.at_level(logging.INFO):
        check.check(dataclasses.replace(own, build_tag="not a tag"))
        check.check(dataclasses.replace(own, build_tag=expected))
        check.check(dataclasses.replace(own, build_tag="demo/base@" + "0" * 12))
    said = [(r.levelno, r.getMessage()) for r in caplog.records]
    assert len(said) == 2, said
    assert said[0][0] == logging.INFO and expected in said[0][1] and "demo.yaml" in said[0][1]
    assert said[1][0] == logging.WARNING
    assert expected in said[1][1] and "demo/base@000000000000" in said[1][1]
