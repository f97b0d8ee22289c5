"""Seeded, bounded fuzzing of what users type and write (issue 19): robot files, .msg files and
link URLs. Whatever the input, hwbridge answers with an exit status of 0, 1 or 2 and, on failure,
only ``error: ...`` lines; never a traceback (an exception escaping ``main``)."""

from __future__ import annotations

import contextlib
import random
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hwbridge.bridge import BoardSpec
from hwbridge.cli import main
from hwbridge.errors import HwBridgeError

ROOT = Path(__file__).resolve().parents[2]
DIFFBOT = (ROOT / "examples" / "robots" / "diffbot.yaml").read_text().splitlines()
FUZZ = settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
TOKENS = [
    "",
    " ",
    "-",
    ":",
    "[",
    "]",
    "{",
    "}",
    "'",
    '"',
    "#",
    "&a",
    "*a",
    "!!python/object",
    "~",
    "null",
    "true",
    "0",
    "-1",
    "1e400",
    "nan",
    "0x1F",
    "3.5",
    "fast",
    "ü",
    "\t",
    "robot",
    "boards",
    "devices",
    "type",
    "name",
    "link",
    "hcsr04",
    "diffdrive",
    "dynamixel_bus",
    "pty://",
    "foo://bar",
    "socket://h:notaport",
    "serial:///dev/x?baud=abc",
    "/diffbot",
    "bad name",
]


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # typer's usage errors
        code = int(exc.code or 0)
    return code, capsys.readouterr().err


def _check_answer(code: int, err: str) -> None:
    assert code in (0, 1, 2), (code, err)
    assert "Traceback" not in err
    if code == 1:
        lines = [line for line in err.splitlines() if line.strip()]
        assert lines and all(line.startswith("error: ") for line in lines), err


@FUZZ
@given(seed=st.integers(0, 2**32 - 1), edits=st.integers(1, 6))
def test_mangled_robot_files(
    seed: int, edits: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = random.Random(seed)
    lines = list(DIFFBOT)
    for _ in range(edits):
        at = rng.randrange(len(lines))
        action = rng.randrange(4)
        if action == 0:
            del lines[at]
        elif action == 1:
            lines.insert(at, lines[rng.randrange(len(lines))])
        elif action == 2:  # a value replaced by a token
            head, sep, _ = lines[at].partition(":")
            lines[at] = f"{head}{sep or ':'} {rng.choice(TOKENS)}"
        else:  # indentation broken
            lines[at] = " " * rng.randrange(0, 9) + lines[at].lstrip()
        if not lines:
            lines = [""]
    robot = tmp_path / "robot.yaml"
    robot.write_text("\n".join(lines) + "\n")
    code, err = _run(["robot", "check", str(robot)], capsys)
    assert code in (0, 1), err
    _check_answer(code, err)
    if code == 1:
        assert all(line.startswith(f"error: {robot}") for line in err.splitlines() if line)


@FUZZ
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(1, 6))
def test_random_message_definitions(
    seed: int, count: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = random.Random(seed)
    words = [
        "int32",
        "float64",
        "string",
        "uint8[]",
        "time",
        "Header",
        "fuzz_msgs/A",
        "fuzz_msgs/B[]",
        "std_msgs/Nope",
        "x",
        "y",
        "X=1",
        "a=",
        "#",
        "---",
        "int8[3]",
        "bool",
        "\xff",
        "=",
        "[]",
    ]
    root = Path(tempfile.mkdtemp(dir=tmp_path))  # tmp_path is shared by the examples
    package = root / "fuzz_msgs" / "msg"
    package.mkdir(parents=True)
    for name in ("A", "B"):
        text = "\n".join(
            " ".join(rng.choice(words) for _ in range(rng.randrange(1, 4))) for _ in range(count)
        )
        data = text.encode("utf-8", "surrogateescape")
        if rng.random() < 0.2:
            data += bytes([rng.randrange(0x80, 0x100)])  # a stray non-UTF-8 byte
        (package / f"{name}.msg").write_bytes(data)
    code, err = _run(["--msg-path", str(root), "msg", "show", "fuzz_msgs/A"], capsys)
    _check_answer(code, err)


@FUZZ
@given(
    url=st.one_of(
        st.sampled_from(TOKENS),
        st.builds(
            lambda scheme, rest, query: f"{scheme}://{rest}{query}",
            st.sampled_from(
                [
                    "serial",
                    "socket",
                    "tcp-listen",
                    "udp",
                    "udp-listen",
                    "pty",
                    "memory",
                    "spy+socket",
                    "foo",
                    "SOCKET",
                    "",
                ]
            ),
            st.text(alphabet="ab.:0123456789/[]@%", max_size=20),
            st.sampled_from(
                [
                    "",
                    "?baud=abc",
                    "?baud=9600",
                    "?allow=1.2.3.0/33",
                    "?takeover=2",
                    "?x=1",
                    "?baud=",
                    "?&&",
                ]
            ),
        ),
        st.text(max_size=30),
    )
)
def test_link_urls_are_accepted_or_refused_with_an_error(url: str) -> None:
    with contextlib.suppress(HwBridgeError):  # refused with a message: fine
        BoardSpec(url)
