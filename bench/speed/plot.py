"""Small charts as PNGs with pillow alone (no plotting library to install): a line chart on
log-log axes (or linear ones), one coloured line per series, a legend (enough to see how step
time grows with the cache); grouped bars (the same measures side by side per path)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

WIDTH, HEIGHT = 760, 460
LEFT, RIGHT, TOP, BOTTOM = 70, 250, 40, 50  # margins around the plot area
FONT = ImageFont.load_default(size=12)  # pillow's own; at its default size spaces vanish
COLOURS = [
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
]


def log_line_chart(
    path: Path,
    title: str,
    x_label: str,
    y_label: str,
    series: dict[str, list[tuple[float, float]]],
    log: bool = True,
) -> None:
    """series: name -> [(x, y), ...], all values > 0; drawn on log10 axes (log=False: linear
    axes from 0, any values >= 0)."""
    points = [p for values in series.values() for p in values]
    if not points:
        raise ValueError("nothing to plot")
    ranges = _decades if log else _linear
    scale = math.log10 if log else float
    x_range = ranges(min(x for x, _ in points), max(x for x, _ in points))
    y_range = ranges(min(y for _, y in points), max(y for _, y in points))
    image = Image.new("RGB", (WIDTH, HEIGHT), "white")
    draw = ImageDraw.Draw(image)
    plot_w, plot_h = WIDTH - LEFT - RIGHT, HEIGHT - TOP - BOTTOM

    def to_pixel(x: float, y: float) -> tuple[float, float]:
        fx = (scale(x) - x_range[0]) / (x_range[1] - x_range[0])
        fy = (scale(y) - y_range[0]) / (y_range[1] - y_range[0])
        return LEFT + fx * plot_w, TOP + (1 - fy) * plot_h

    ticks = (
        (lambda r: [10**d for d in range(r[0], r[1] + 1)])
        if log
        else (lambda r: list(np.arange(r[0], r[1] + r[2] / 2, r[2])))
    )
    x_low, y_low = (10 ** x_range[0], 10 ** y_range[0]) if log else (x_range[0], y_range[0])
    for tick in ticks(x_range):
        px, _ = to_pixel(tick, y_low)
        draw.line([(px, TOP), (px, TOP + plot_h)], fill="#dddddd")
        draw.text((px - 10, TOP + plot_h + 6), _label(tick), fill="black", font=FONT)
    for tick in ticks(y_range):
        _, py = to_pixel(x_low, tick)
        draw.line([(LEFT, py), (LEFT + plot_w, py)], fill="#dddddd")
        draw.text((8, py - 7), _label(tick), fill="black", font=FONT)
    draw.rectangle([LEFT, TOP, LEFT + plot_w, TOP + plot_h], outline="black")
    draw.text((LEFT, 2), title, fill="black", font=FONT)  # the y label below it, not over it
    draw.text((LEFT + plot_w // 2 - 40, HEIGHT - 22), x_label, fill="black", font=FONT)
    draw.text((8, TOP - 19), y_label, fill="black", font=FONT)
    for k, (name, values) in enumerate(series.items()):
        colour = COLOURS[k % len(COLOURS)]
        pixels = [to_pixel(x, y) for x, y in sorted(values)]
        if len(pixels) > 1:
            draw.line(pixels, fill=colour, width=2)
        for px, py in pixels:
            draw.ellipse([px - 3, py - 3, px + 3, py + 3], fill=colour)
        legend_y = TOP + 16 * k
        draw.line(
            [(WIDTH - RIGHT + 15, legend_y + 6), (WIDTH - RIGHT + 35, legend_y + 6)],
            fill=colour,
            width=3,
        )
        draw.text((WIDTH - RIGHT + 40, legend_y - 1), name, fill="black", font=FONT)
    image.save(path, optimize=True)


def bar_chart(path: Path, title: str, y_label: str, groups: dict[str, dict[str, float]]) -> None:
    """Grouped bars on a linear axis from 0: groups[group][series] = value (>= 0), one colour
    per series (the legend), each value written above its bar."""
    names = list(dict.fromkeys(name for bars in groups.values() for name in bars))
    values = [v for bars in groups.values() for v in bars.values()]
    if not values:
        raise ValueError("nothing to plot")
    low, high, unit = _linear(0.0, 1.08 * max(values))  # room for the values over the bars
    image = Image.new("RGB", (WIDTH, HEIGHT), "white")
    draw = ImageDraw.Draw(image)
    plot_w, plot_h = WIDTH - LEFT - RIGHT, HEIGHT - TOP - BOTTOM
    for tick in np.arange(low, high + unit / 2, unit):
        py = TOP + (1 - tick / high) * plot_h
        draw.line([(LEFT, py), (LEFT + plot_w, py)], fill="#dddddd")
        draw.text((8, py - 7), _label(tick), fill="black", font=FONT)
    group_w = plot_w / len(groups)
    bar_w = 0.8 * group_w / len(names)
    for g, (group, bars) in enumerate(groups.items()):
        left = LEFT + g * group_w + 0.1 * group_w
        for k, name in enumerate(names):
            if name not in bars:
                continue
            x0, py = left + k * bar_w, TOP + (1 - bars[name] / high) * plot_h
            draw.rectangle([x0, py, x0 + bar_w - 2, TOP + plot_h], fill=COLOURS[k % len(COLOURS)])
            text = f"{bars[name]:.0f}"
            draw.text((x0 + (bar_w - FONT.getlength(text)) / 2, py - 13), text, "black", FONT)
        for row, line in enumerate(group.split(", ")):  # a long name on lines of its own
            draw.text((left, TOP + plot_h + 6 + 13 * row), line, fill="black", font=FONT)
    draw.rectangle([LEFT, TOP, LEFT + plot_w, TOP + plot_h], outline="black")
    draw.text((LEFT, 2), title, fill="black", font=FONT)
    draw.text((8, TOP - 19), y_label, fill="black", font=FONT)
    for k, name in enumerate(names):
        legend_y = TOP + 16 * k
        colour = COLOURS[k % len(COLOURS)]
        draw.rectangle(
            [WIDTH - RIGHT + 15, legend_y + 1, WIDTH - RIGHT + 35, legend_y + 11], fill=colour
        )
        draw.text((WIDTH - RIGHT + 40, legend_y - 1), name, fill="black", font=FONT)
    image.save(path, optimize=True)


def _decades(low: float, high: float) -> tuple[int, int]:
    """Whole powers of ten around [low, high], at least one decade apart."""
    if low <= 0:
        raise ValueError(f"log axes need values > 0, got {low}")
    first, last = math.floor(math.log10(low)), math.ceil(math.log10(high))
    return first, max(last, first + 1)


def _linear(low: float, high: float) -> tuple[float, float, float]:
    """From 0 (or below, for negative values) to the highest value rounded up to a tick, and
    the tick spacing: a power of ten, or a fifth of one where that gives too few ticks."""
    low = min(0.0, low)
    span = max(high - low, 1e-9)
    unit = 10 ** math.floor(math.log10(span))
    if span / unit < 3:
        unit /= 5
    return math.floor(low / unit) * unit, math.ceil(high / unit) * unit, unit


def _label(value: float) -> str:
    if value == 0 or 1e-3 <= abs(value) < 1e5:
        return f"{value:g}"
    return f"1e{round(math.log10(abs(value)))}"
