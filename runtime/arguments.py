"""The public API's argument checks, in one place: a wrong type is a TypeError and a wrong
value a ValueError, each naming the argument, raised where it enters the API rather than from
deep inside numpy or onnxruntime. (Sampling options check themselves: mogo.sampling.)"""

from __future__ import annotations

import itertools
import reprlib
import string
import unicodedata
import warnings
from collections.abc import Iterable, Sequence
from numbers import Integral, Real
from typing import TYPE_CHECKING

from mogo.align_words import spoken_numbers

if TYPE_CHECKING:  # the `mogo` command imports this module for PromptWarning alone
    from tokenizers import Tokenizer

UNKNOWN, SPECIAL_TOKENS = "[UNK]", ("[PAD]", "[UNK]", "[CLS]")  # a bundle tokenizer's
MAX_SCHEDULE_ENTRIES = 100  # prompts in one play(): each switch costs about a token step's work


class ScheduleError(ValueError):
    """An entry of a schedule that cannot be played (`index`; None: the schedule as a whole)
    and the `problem`, for a caller that names entries its own way (the `mogo` command: by
    FILE:LINE)."""

    def __init__(self, index: int | None, problem: str):
        super().__init__(problem if index is None else f"schedule[{index}]: {problem}")
        self.index, self.problem = index, problem


class PromptWarning(UserWarning):
    """A prompt the model reads only in part: words it does not know, or tokens beyond its text
    encoder's length. The motion follows the rest; the `mogo` command prints a `note:` line."""


class UnfamiliarPromptWarning(PromptWarning):
    """A prompt far from everything the model was trained on (a bundle with a sentence
    encoder reads any words, but knows only its training actions): the message gives the
    score and the nearest captions it knows; MotionGenerator.known(prompt) gives them as
    values. The `mogo` command prints it as a note, and refuses it with --strict."""


class UnknownPromptWarning(PromptWarning):
    """A prompt with no word the model knows: it makes one generic motion for it. A warning,
    not an error, in the API (measurements feed such prompts on purpose; make it one with
    warnings.simplefilter("error", UnknownPromptWarning)); the `mogo` command refuses it."""


class CutWarning(PromptWarning):
    """A motion the model did not end within the bundle's longest clip (a prompt of several
    actions, "walks, then sits down"): cut there, maybe mid-action. The `mogo` command prints
    it as a note; ask for `seconds`, or use a stream, for longer motion."""


def checked_prompt(text: object, name: str = "text") -> str:
    """A prompt as the model, the files and the terminal get it: valid Unicode (a lone
    surrogate is what a terminal in another encoding than UTF-8 leaves), each run of
    whitespace one space, control and invisible format characters (zero-width spaces, bidi
    overrides, terminal escapes' ESC) removed; empty once cleaned is refused."""
    if not isinstance(text, str):
        raise TypeError(f"{name} must be a string (the prompt), got {type(text).__name__}")
    try:  # JSON's "\ud800" or a Latin-1 terminal's bytes: a lone surrogate is no text
        text.encode("utf-8")
    except UnicodeEncodeError as error:
        raise ValueError(
            f"{name} is not valid Unicode: a lone surrogate "
            f"{text[error.start]!r} at character {error.start}"
        ) from None
    cleaned = " ".join(
        "".join(" " if c.isspace() else c for c in text if c.isspace() or not _invisible(c)).split()
    )
    if not cleaned:
        raise ValueError(
            "the prompt is empty" + (" (only invisible characters)" if text.strip() else "")
        )
    return cleaned


def _invisible(character: str) -> bool:
    """A control or format character (C0/C1 controls, zero-width spaces and joiners, bidi
    marks and overrides): nothing a prompt or a file name shows."""
    return unicodedata.category(character) in ("Cc", "Cf", "Zl", "Zp")


def shown(text: object, keep: str = "") -> str:
    """`text` (a path, a message) for a terminal: control and invisible characters but those
    in `keep` written as escapes (\\n, \\x1b, \\u202e), lone surrogates too, so that what
    the user reads is what it is, on the lines it says."""
    return "".join(
        c.encode("unicode_escape", "backslashreplace").decode("ascii")
        if c not in keep and (_invisible(c) or unicodedata.category(c) == "Cs")
        else c
        for c in str(text)
    )


def read_prompt(
    text: object,
    tokenizer: Tokenizer,
    max_length: int,
    vocabulary_size: int | None,
    name: str = "text",
    stacklevel: int = 2,
) -> str:
    """A prompt checked: text and not empty; a prompt with no word the model knows, words it
    does not know and tokens past the text encoder's `max_length` (counted by the untruncated
    `tokenizer`) are told by a PromptWarning, for the line `stacklevel` frames up from here
    (as warnings.warn counts: 2 is the caller of read_prompt). A word is known when it is
    one token of the vocabulary: others become [UNK] or are spelled out in single letters
    (w ##a ##l ##k ##e ##d), and their meaning is lost. vocabulary_size None: a pretrained
    encoder, whose word pieces carry meaning, so only the length is told."""
    text = checked_prompt(text, name)
    spoken = spoken_numbers(text)  # what the text encoders read (mogo.text_side)
    encoding = tokenizer.encode(spoken)
    if vocabulary_size is not None:
        _tell_unknown_words(spoken, encoding, vocabulary_size, stacklevel + 1)
    if len(encoding.ids) > max_length:
        read = spoken[: encoding.offsets[max_length - 1][1]].split()[-5:]  # its last words
        warnings.warn(
            f"the prompt is {len(encoding.ids)} tokens long and the model reads only "
            f"{max_length}: everything after {short(' '.join(read))} is ignored "
            "(play the parts one after another instead)",
            PromptWarning,
            stacklevel=stacklevel,
        )
    return text


def word_reading(text: str, encoding) -> tuple[bool, list[str]]:
    """(whether a word of `text` is one token of the vocabulary, the words that are not: [UNK]
    or spelled out in pieces), from its `encoding` by a bundle's own WordPiece tokenizer."""
    words: dict[int, list[int]] = {}  # word -> its tokens' indices ([CLS] has no word)
    for index, word in enumerate(encoding.word_ids):
        if word is not None:
            words.setdefault(word, []).append(index)
    known, unknown = False, []
    for indices in words.values():
        token = encoding.tokens[indices[0]]
        if len(indices) == 1 and token not in SPECIAL_TOKENS:
            known = known or any(c.isalpha() for c in token)
        elif spelled := text[
            encoding.offsets[indices[0]][0] : encoding.offsets[indices[-1]][1]
        ].strip(string.punctuation):
            unknown.append(spelled)
    return known, list(dict.fromkeys(unknown))


def _tell_unknown_words(text: str, encoding, vocabulary_size: int, stacklevel: int) -> None:
    """A trained-with-the-model encoder's words: none known, or some unknown (see read_prompt)."""
    known, unknown = word_reading(text, encoding)
    if not known:
        warnings.warn(
            f"the model knows no word of the prompt {short(text)}, so its motion "
            f"would be a generic one: it knows the {vocabulary_size} words of its "
            "training captions, such as 'a person walks forward' (align=True, or "
            "--align rules, maps some other words onto them)",
            UnknownPromptWarning,
            stacklevel=stacklevel,
        )
    elif unknown:
        listed = ", ".join(map(repr, unknown[:8])) + (
            f" and {len(unknown) - 8} more" if len(unknown) > 8 else ""
        )
        warnings.warn(
            f"the model does not know {listed}: their meaning is lost",
            PromptWarning,
            stacklevel=stacklevel,
        )


def checked_seconds(seconds: object, minimum: float, fps: float, maximum: float) -> float:
    """A length: a number from `minimum` (one token step) up to `maximum`."""
    if isinstance(seconds, bool) or not isinstance(seconds, Real):
        raise TypeError(f"seconds must be a number, got {type(seconds).__name__}")
    if not seconds > 0:
        raise ValueError(f"seconds must be a positive number, got {number_text(seconds)}")
    if seconds > maximum:
        raise ValueError(
            f"seconds must be at most {maximum:.0f} in one call, got "
            f"{number_text(seconds)}; "
            "use a stream for longer motion"
        )
    if float(seconds) < minimum:
        raise ValueError(
            f"seconds must be at least {minimum:g} (one token step, "
            f"{plural(round(minimum * fps), 'frame')} at {fps:g} fps), got "
            f"{float(seconds):g}"
        )
    return float(seconds)


def checked_int(value: object, name: str, minimum: int, maximum: int | None = None) -> int:
    """An integer argument (numpy's too; not a bool) from `minimum` up to `maximum`."""
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {number_text(value)}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be at most {maximum}, got {number_text(value)}")
    return int(value)


def checked_bool(value: object, name: str) -> bool:
    """A True/False argument (numpy's bool too); 0, 1 or "no" are not taken for one."""
    if isinstance(value, bool) or (
        getattr(value, "shape", None) == () and getattr(value, "dtype", None) == "bool"
    ):
        return bool(value)
    raise TypeError(f"{name} must be True or False, got {type(value).__name__}")


def checked_schedule(schedule: object) -> list:
    """A schedule's shape: a non-empty list of at most MAX_SCHEDULE_ENTRIES (prompt, seconds)
    pairs (their values are the generator's to check)."""
    if isinstance(schedule, (str, bytes)) or not isinstance(schedule, Iterable):
        raise TypeError(
            f"schedule must be a list of (prompt, seconds) pairs, got {type(schedule).__name__}"
        )
    entries = list(itertools.islice(schedule, MAX_SCHEDULE_ENTRIES + 1))
    if not entries:
        raise ValueError("the schedule is empty")
    if len(entries) > MAX_SCHEDULE_ENTRIES:
        raise ScheduleError(
            MAX_SCHEDULE_ENTRIES,
            f"more than {MAX_SCHEDULE_ENTRIES} prompts in "
            "one schedule; use a stream (MotionStream) for more",
        )
    for k, entry in enumerate(entries):
        if isinstance(entry, (str, bytes)) or not isinstance(entry, Sequence) or len(entry) != 2:
            raise TypeError(
                f"schedule[{k}] must be a (prompt, seconds) pair, got {reprlib.repr(entry)}"
            )
    return entries


def number_text(value: object) -> str:
    """A number for a message: an integer too long for Python to print (past 4300 digits) by
    its size instead of an error about the error."""
    try:
        return repr(value)
    except ValueError:
        return f"an integer of {value.bit_length()} bits"


def short(text: str, limit: int = 60) -> str:
    """Quoted on one line, cut to about `limit` characters, for messages."""
    return repr(text if len(text) <= limit else text[: limit - 3] + "...")


def plural(count: int, noun: str) -> str:
    """'1 frame', '2 frames': counts as messages print them."""
    return f"{count} {noun}{'' if count == 1 else 's'}"
