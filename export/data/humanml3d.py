"""The HumanML3D caption file format: one caption a line, `caption#word/POS ...#start#end`.

Torch-free, so data tools that need no training (`mogo data show`) can read captions too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


class DatasetError(ValueError):
    """A dataset folder that breaks the HumanML3D layout; the message names the file."""


@dataclass(frozen=True)
class Caption:
    text: str
    tokens: tuple[tuple[str, str], ...]  # (word, part of speech) pairs; may be empty
    start_frame: int
    end_frame: int | None  # exclusive; None: to the end of the clip


def parse_caption_line(line: str, fps: float, where: str) -> Caption:
    """Parse `caption#word/POS word/POS ...#start#end` (start/end in seconds).

    As in the standard loaders, a NaN time counts as 0.0 and 0.0#0.0 means the whole clip;
    otherwise the caption covers feature rows [int(start * fps), int(end * fps)).
    `where` ("path:line") prefixes every error.
    """
    fields = line.rstrip("\r\n").rsplit("#", 3)
    if len(fields) != 4 or not fields[0].strip():
        raise DatasetError(f"{where}: expected 'caption#word/POS ...#start#end', got {line!r}")
    text, tokens_field, start_field, end_field = fields
    tokens = []
    for token in tokens_field.split():
        word, slash, pos = token.rpartition("/")
        if not slash or not word or not pos:
            raise DatasetError(f"{where}: token {token!r} is not word/POS")
        tokens.append((word, pos))
    times = []
    for name, field in (("start", start_field), ("end", end_field)):
        try:
            seconds = float(field)
        except ValueError:
            raise DatasetError(f"{where}: {name} time {field!r} is not a number") from None
        if math.isnan(seconds):
            seconds = 0.0
        if not math.isfinite(seconds) or seconds < 0:
            raise DatasetError(f"{where}: {name} time {field!r} is not a time in seconds")
        times.append(seconds)
    start, end = times
    if start == 0.0 and end == 0.0:
        return Caption(text.strip(), tuple(tokens), 0, None)
    return Caption(text.strip(), tuple(tokens), int(start * fps), int(end * fps))


def format_caption_line(text: str, start_seconds: float = 0.0, end_seconds: float = 0.0,
                        tokens: tuple[tuple[str, str], ...] = ()) -> str:
    """One text-file line; 0.0#0.0 marks a caption of the whole clip."""
    if "#" in text or "\n" in text:
        raise ValueError(f"a caption may not contain '#' or a newline: {text!r}")
    token_field = " ".join(f"{word}/{pos}" for word, pos in tokens)
    return f"{text}#{token_field}#{float(round(start_seconds, 3))!r}#{float(round(end_seconds, 3))!r}"
