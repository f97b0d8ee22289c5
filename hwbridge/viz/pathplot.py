"""A path plot as a small hand-written SVG: what odometry says the robot drove against where it
really went (``hwbridge demo`` writes one next to its summary).

No plotting library: the picture is a room outline, its obstacles, two polylines, a start and an
end mark, a scale bar and a legend, in world metres mapped to pixels with y pointing up.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import escape

__all__ = ["PathPlot", "Point", "render_svg", "write_svg"]

Point = tuple[float, float]

_WIDTH = 720
_MARGIN = 40
_LEGEND = 56
_ODOM_COLOUR = "#d62728"
_TRUTH_COLOUR = "#1f77b4"


@dataclass
class PathPlot:
    """What to draw: the two paths (metres), the room's size centred on the origin, walls
    inside it as segments, a title and lines of text under the legend."""

    odometry: list[Point] = field(default_factory=list)
    truth: list[Point] = field(default_factory=list)
    room: tuple[float, float] | None = None
    obstacles: Sequence[tuple[float, float, float, float]] = ()
    title: str = "driven path"
    notes: list[str] = field(default_factory=list)

    def add(self, odometry: Point | None, truth: Point) -> None:
        """Add one sample (odometry may be missing before the first message)."""
        if odometry is not None and all(math.isfinite(v) for v in odometry):
            self.odometry.append(odometry)
        self.truth.append(truth)


def _bounds(plot: PathPlot) -> tuple[float, float, float, float]:
    xs = [p[0] for p in plot.odometry + plot.truth]
    ys = [p[1] for p in plot.odometry + plot.truth]
    if plot.room is not None:
        w, d = plot.room
        xs += [-w / 2, w / 2]
        ys += [-d / 2, d / 2]
    for x1, y1, x2, y2 in plot.obstacles:
        xs += [x1, x2]
        ys += [y1, y2]
    if not xs:
        return -1.0, -1.0, 1.0, 1.0
    x0, x1_, y0, y1_ = min(xs), max(xs), min(ys), max(ys)
    pad = 0.05 * max(x1_ - x0, y1_ - y0, 0.2)
    return x0 - pad, y0 - pad, x1_ + pad, y1_ + pad


def render_svg(plot: PathPlot) -> str:
    """The plot as an SVG document (a string)."""
    x0, y0, x1, y1 = _bounds(plot)
    scale = (_WIDTH - 2 * _MARGIN) / (x1 - x0)
    height = round((y1 - y0) * scale) + 2 * _MARGIN + _LEGEND + 16 * len(plot.notes)

    def px(point: Point) -> str:
        x = _MARGIN + (point[0] - x0) * scale
        y = _MARGIN + (y1 - point[1]) * scale
        return f"{x:.1f},{y:.1f}"

    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{_WIDTH}" height="{height}" '
        f'viewBox="0 0 {_WIDTH} {height}" font-family="sans-serif" font-size="13">',
        f"<title>{escape(plot.title)}</title>",
        f'<rect width="{_WIDTH}" height="{height}" fill="white"/>',
        f'<text x="{_MARGIN}" y="24" font-size="16" font-weight="bold">{escape(plot.title)}</text>',
    ]
    if plot.room is not None:
        w, d = plot.room
        corners = [(-w / 2, -d / 2), (w / 2, -d / 2), (w / 2, d / 2), (-w / 2, d / 2)]
        out.append(
            f'<polygon id="room" points="{" ".join(px(c) for c in corners)}" fill="#f7f7f7" '
            'stroke="#444" stroke-width="2"/>'
        )
    for index, (ax, ay, bx, by) in enumerate(plot.obstacles):
        out.append(
            f'<polyline id="obstacle{index}" points="{px((ax, ay))} {px((bx, by))}" '
            'stroke="#444" stroke-width="4" fill="none"/>'
        )
    for name, points, colour, dash in (
        ("truth", plot.truth, _TRUTH_COLOUR, ""),
        ("odometry", plot.odometry, _ODOM_COLOUR, ' stroke-dasharray="6 4"'),
    ):
        if points:
            out.append(
                f'<polyline id="{name}" points="{" ".join(px(p) for p in points)}" '
                f'fill="none" stroke="{colour}" stroke-width="2"{dash}/>'
            )
            sx, sy = px(points[-1]).split(",")
            out.append(f'<circle id="{name}-end" cx="{sx}" cy="{sy}" r="4" fill="{colour}"/>')
    if plot.truth:
        sx, sy = px(plot.truth[0]).split(",")
        out.append(
            f'<circle id="start" cx="{sx}" cy="{sy}" r="5" fill="none" stroke="black" '
            'stroke-width="2"/>'
        )
    # Scale bar: the largest of 0.1/0.2/0.5/1/2/5 m that fits a fifth of the width.
    span = (x1 - x0) / 5
    bar = max((s for s in (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0) if s <= span), default=0.1)
    base_y = height - _LEGEND - 16 * len(plot.notes) - _MARGIN / 2
    bx0 = _MARGIN
    bx1 = _MARGIN + bar * scale
    out.append(
        f'<line id="scale" x1="{bx0:.1f}" y1="{base_y + 14:.1f}" x2="{bx1:.1f}" '
        f'y2="{base_y + 14:.1f}" stroke="black" stroke-width="3"/>'
    )
    out.append(f'<text x="{bx1 + 6:.1f}" y="{base_y + 18:.1f}">{bar:g} m</text>')
    legend_y = base_y + 40
    out.append(
        f'<line x1="{_MARGIN}" y1="{legend_y - 4}" x2="{_MARGIN + 30}" y2="{legend_y - 4}" '
        f'stroke="{_TRUTH_COLOUR}" stroke-width="2"/>'
        f'<text x="{_MARGIN + 36}" y="{legend_y}">ground truth ({len(plot.truth)} points)</text>'
    )
    second = _MARGIN + 260
    out.append(
        f'<line x1="{second}" y1="{legend_y - 4}" x2="{second + 30}" y2="{legend_y - 4}" '
        f'stroke="{_ODOM_COLOUR}" stroke-width="2" stroke-dasharray="6 4"/>'
        f'<text x="{second + 36}" y="{legend_y}">odometry ({len(plot.odometry)} points)</text>'
    )
    for index, note in enumerate(plot.notes):
        out.append(
            f'<text class="note" x="{_MARGIN}" y="{legend_y + 20 + 16 * index}">'
            f"{escape(note)}</text>"
        )
    out.append("</svg>")
    return "\n".join(out) + "\n"


def write_svg(plot: PathPlot, path: Path) -> Path:
    """Write the plot to ``path`` (its folder must exist); returns the path."""
    path.write_text(render_svg(plot), encoding="utf-8")
    return path
