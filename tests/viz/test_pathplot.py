"""The demo's path plot: a hand-written SVG of odometry against ground truth."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from hwbridge.viz.pathplot import PathPlot, render_svg
from tests.netutil import free_port

SVG = "{http://www.w3.org/2000/svg}"


def _points(root: ET.Element, name: str) -> list[tuple[float, float]]:
    line = root.find(f".//{SVG}polyline[@id='{name}']")
    assert line is not None, name
    return [
        (float(x), float(y)) for x, y in (pair.split(",") for pair in line.attrib["points"].split())
    ]


def test_paths_are_drawn_in_the_room_with_y_up() -> None:
    plot = PathPlot(room=(4.0, 2.0), obstacles=[(1.0, 0.0, 1.0, 0.5)], title="a <test>")
    plot.add(None, (0.0, 0.0))  # no odometry yet: only the truth gets the point
    plot.add((0.5, 0.0), (0.5, 0.0))
    plot.add((1.0, 0.6), (1.0, 0.5))
    plot.add((float("nan"), 0.0), (1.0, 0.9))  # a non-finite odometry point is left out
    root = ET.fromstring(render_svg(plot))
    assert root.find(f"{SVG}title") is not None and root.find(f"{SVG}title").text == "a <test>"  # type: ignore[union-attr]
    truth, odom = _points(root, "truth"), _points(root, "odometry")
    assert len(truth) == 4 and len(odom) == 2
    # x grows to the right, y grows upwards (smaller pixel y)
    assert truth[1][0] > truth[0][0]
    assert truth[2][1] < truth[1][1]
    # odometry drifted above the truth at the same x
    assert odom[1][0] == truth[2][0] and odom[1][1] < truth[2][1]
    room = root.find(f".//{SVG}polygon[@id='room']")
    assert room is not None
    xs = [float(p.split(",")[0]) for p in room.attrib["points"].split()]
    ys = [float(p.split(",")[1]) for p in room.attrib["points"].split()]
    # every path point lies inside the room's outline
    for x, y in truth + odom:
        assert min(xs) <= x <= max(xs) and min(ys) <= y <= max(ys)
    assert root.find(f".//{SVG}polyline[@id='obstacle0']") is not None
    assert root.find(f".//{SVG}circle[@id='start']") is not None


def test_an_empty_plot_is_still_a_valid_svg() -> None:
    root = ET.fromstring(render_svg(PathPlot()))
    assert root.tag == f"{SVG}svg"
    assert root.find(f".//{SVG}polyline[@id='truth']") is None


def test_demo_writes_the_driven_path_next_to_its_summary(tmp_path: Path) -> None:
    out = tmp_path / "path.svg"
    env = {
        **os.environ,
        "HWBRIDGE_ENDPOINT": f"tcp/127.0.0.1:{free_port()}",
        "HWBRIDGE_DOMAIN": "vizdemo",
    }
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "demo", "--duration", "4", "--plot", str(out)],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr + done.stdout
    lines = done.stdout.strip().splitlines()
    assert lines[-2] == f"path plot: {out}", lines[-3:]
    assert re.fullmatch(r"odometry error: [0-9.]+% of [0-9.]+ m", lines[-1])
    root = ET.parse(out).getroot()
    truth, odom = _points(root, "truth"), _points(root, "odometry")
    assert len(truth) > 20 and len(odom) > 10
    # it moved, and odometry ends near the truth (within 10 px: a few cm in a 6 m room)
    assert abs(truth[-1][0] - truth[0][0]) + abs(truth[-1][1] - truth[0][1]) > 20
    assert abs(odom[-1][0] - truth[-1][0]) < 10 and abs(odom[-1][1] - truth[-1][1]) < 10
    notes = [n.text or "" for n in root.iter(f"{SVG}text") if n.attrib.get("class") == "note"]
    assert any("final odometry error" in n for n in notes)
