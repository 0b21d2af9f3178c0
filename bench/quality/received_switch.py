"""How late a prompt switch shows in the frames a caller receives (issue 40: within 0.5 s,
median, with the low-latency decoder).

A stream switches at the next token step, but the frames it hands out lag the tokens by the
decoder's lookahead and the feet's (and a decode burst): frames already drawn under the old
prompt still come out. So the measure starts where the caller is, at the frames it had
received when it called `set_prompt`, and ends at the frame where the judge
(stream_checks.reaction_frames) finds the new action under way.
"""

from __future__ import annotations

import numpy as np

from mogo.bench.quality.stream_checks import FPS

VISIBLE_SECONDS = 0.5  # issue 40's goal for the median, with the low-latency decoder


def visible(starts: list[int], reactions: list[int | None], received: list[int]) -> list:
    """Frames from what the caller had received at each set_prompt to the new action under
    way: the switch's first frame `start` plus the judge's reaction, less `received`; None
    where the action never shows. The three lists are per switch."""
    return [
        None if reaction is None else start + reaction - got
        for start, reaction, got in zip(starts, reactions, received, strict=True)
    ]


def received_table(result: dict) -> str:
    """One row per stream path with such figures (a decoder each, `mogo bench long-streams
    --low-latency`): the switch, as received, in seconds."""
    columns: dict[str, list[int | None]] = {}
    for row in result["rows"]:
        if row["kind"] == "switches" and row.get("visible"):
            columns.setdefault(row["column"], []).extend(row["visible"])
    if not columns:
        return ""
    lines = [
        "| switch visible in the received frames | switches | median (s) | 90th percentile (s) "
        f"| within {VISIBLE_SECONDS:g} s | never under way |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for column, frames in columns.items():
        seconds = np.array([np.inf if f is None else f / FPS for f in frames])
        median, p90 = (np.percentile(seconds, q, method="lower") for q in (50, 90))
        lines.append(
            f"| {column} | {len(seconds)} | {median:.2f} | {p90:.2f} | "
            f"{np.mean(seconds <= VISIBLE_SECONDS):.0%} | {np.sum(~np.isfinite(seconds))} |"
        )
    return "\n".join(lines)
