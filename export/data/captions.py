"""HumanML3D-style captions for animator programs: the templates of
mogo.export.data.caption_templates rendered with a segment's params, and segments joined into
one sentence."""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from mogo.align import conjugate  # shared with prompt alignment
from mogo.align_words import spoken_number
from mogo.export.data.animator import Segment
from mogo.export.data.caption_templates import (
    JOINERS,
    POOLS,
    SUBJECTS,
    TEMPLATES,
    Sentence,
    Template,
)

_VERB = re.compile(r"<(\w+)>")
_REPETITION_NOUNS = {
    "jump": "jump",
    "squat": "squat",
    "clap": "clap",
    "punch": "punch",
    "jumping_jacks": "jumping jack",
    "hop": "hop",
    "shrug": "shrug",
    "uppercut": "uppercut",
}
_GAITS = {"walk": ("walk", "steps"), "jog": ("jog", "strides"), "run": ("run", "strides")}


def number_word(n: int) -> str:
    """Counts up to twenty in words, larger ones in digits."""
    return spoken_number(n) if 0 <= n <= 20 else str(n)


def times_word(n: int) -> str:
    return {1: "once", 2: "twice"}.get(n, f"{number_word(n)} times")


def count_noun(n: int, noun: str) -> str:
    """ "a squat", "three punches"."""
    if n == 1:
        return f"an {noun}" if noun[0] in "aeiou" else f"a {noun}"
    plural = noun + "es" if noun.endswith(("s", "sh", "ch", "x", "z")) else noun + "s"
    return f"{number_word(n)} {plural}"


def _reference(subject: str) -> tuple[str, str]:
    """(pronoun or definite noun, possessive) that refer back to the subject."""
    return {
        "a man": ("he", "his"),
        "a woman": ("she", "her"),
        "a figure": ("the figure", "its"),
    }.get(subject, ("the person", "their"))


def _side(signed_degrees: float) -> str:
    return "left" if signed_degrees > 0 else "right"


def _turn_size(degrees: float) -> tuple[list[str], list[str]]:
    """Amount phrases ("ninety degrees") and fraction phrases ("a quarter") of a turn,
    rounded to the nearest eighth of a circle ("about" when that rounding is coarse)."""
    eighths = max(1, round(abs(degrees) / 45))
    about = "about " if abs(abs(degrees) - 45 * eighths) > 10 else ""
    fractions = {
        1: ["a slight", "an eighth of a"],
        2: ["a quarter", "a ninety-degree"],
        3: ["a three-eighths"],
        4: ["a half", "a half-circle"],
        5: ["a five-eighths"],
        6: ["a three-quarter"],
        7: ["an almost full"],
        8: ["a full"],
    }
    amount = spoken_number(45 * eighths) if eighths <= 8 else str(45 * eighths)
    amounts = [f"{about}{amount} degrees"]
    if eighths == 2:
        amounts.append(f"{about}a quarter of a circle")
    if eighths == 4:
        amounts.append("halfway around")
    if about:
        return amounts, ["a partial"]
    return amounts, fractions.get(eighths, ["a full"])


def _path(turn: float) -> list[str]:
    """How a locomotion path bends (turn in signed degrees, + = left)."""
    size, side = abs(turn), _side(turn)
    if size < 10:
        return ["", "in a straight line", "straight"]
    if size < 60:
        return [
            f"veering slightly to the {side}",
            f"in a gentle curve to the {side}",
            f"bearing slightly {side}",
        ]
    if size < 135:
        return [
            f"in a curve to the {side}",
            f"curving to the {side}",
            f"while turning {side}",
            f"along a path that bends to the {side}",
        ]
    if size < 225:
        return [
            f"in a half circle to the {side}",
            f"in a u-turn to the {side}",
            f"turning around to the {side}",
        ]
    return [f"in a circle to the {side}", f"in a full circle to the {side}"]


def _slots(primitive: str, params: dict, possessive: str) -> dict[str, list[str]]:
    """Synonym lists for every slot the primitive's templates may use."""
    slots: dict[str, list[str]] = {"pos": [possessive]}
    if primitive in _GAITS:
        gait, stride = _GAITS[primitive]
        slots["gait"] = [gait]
        slots["stride"] = [stride]
    if "steps" in params:
        slots["steps"] = [number_word(params["steps"])]
    if "turn" in params:
        slots["path"] = _path(params["turn"])
    if "speed" in params:
        slots.update(_speed_slots(params["speed"]))
    if "direction" in params and primitive != "spin":
        direction = params["direction"]
        slots["dir"] = {
            "forward": ["forward", "forwards", "ahead"],
            "backward": ["backward", "backwards"],
            "left": ["to the left", "sideways to the left", "leftward"],
            "right": ["to the right", "sideways to the right", "rightward"],
        }[direction]
        if direction in ("left", "right"):
            slots["lateral"] = [f"to the {direction}", direction]
    if "angle" in params:
        slots.update(_angle_slots(params["angle"]))
    if primitive == "spin":
        slots["side"] = [params["direction"]]
        slots["rot"] = ["counterclockwise" if params["direction"] == "left" else "clockwise"]
    if "count" in params:
        slots["times"] = [times_word(params["count"])]
        if primitive in _REPETITION_NOUNS:
            slots["reps"] = [count_noun(params["count"], _REPETITION_NOUNS[primitive])]
    if primitive == "jumping_jacks":
        slots["star_reps"] = [count_noun(params["count"], "star jump")]
    if primitive == "jump":
        slots["jump_dir"] = (
            ["forward", "forwards", "ahead"] if params["forward"] else ["in place", "on the spot"]
        )
    if "hand" in params:
        slots.update(_hand_slots(params, possessive))
    if "at" in params:
        slots["point_at"] = {
            "forward": ["forward", "ahead", "straight ahead"],
            "up": ["up", "upward", "at the sky"],
            "sideways": [f"to the {params['hand']}", f"out to the {params['hand']} side"],
        }[params["at"]]
    if "foot" in params:
        foot = params["foot"]
        slots["leg"] = [f"the {foot} leg", f"{possessive} {foot} leg", f"the {foot} foot"]
        slots["side"] = [foot]
    if "seconds" in params:
        seconds = round(params["seconds"])
        words = number_word(seconds)
        slots["secs"] = (
            ["a moment", "a second"]
            if seconds <= 1
            else [f"{words} seconds", f"about {words} seconds"]
        )
    return slots


def _angle_slots(angle: float) -> dict[str, list[str]]:
    """The slots a turn's angle fills: how far, to which side, which way round."""
    amounts, fractions = _turn_size(angle)
    return dict(
        turn_amount=amounts,
        turn_fraction=fractions,
        side=[_side(angle)],
        rot=["counterclockwise" if angle > 0 else "clockwise"],
    )


def _speed_slots(speed: str) -> dict[str, list[str]]:
    """The slots a pace fills: as an adverb, an adjective, a step's size."""
    return dict(
        speed={
            "slow": ["slowly", "at a slow pace", "leisurely"],
            "normal": ["", "at a normal pace", "at a steady pace"],
            "fast": ["quickly", "at a fast pace", "briskly"],
        }[speed],
        speed_adv={
            "slow": ["slowly"],
            "normal": ["", "steadily"],
            "fast": ["quickly", "rapidly"],
        }[speed],
        speed_adj={
            "slow": ["slow", "gentle"],
            "normal": ["steady", "normal"],
            "fast": ["fast", "quick"],
        }[speed],
        step_adj={"slow": ["small", "slow"], "normal": [""], "fast": ["quick", "big"]}[speed],
    )


def _hand_slots(params: dict, possessive: str) -> dict[str, list[str]]:
    """The slots a hand fills (both, or one: its arm, fist, side and counted punches)."""
    hand = params["hand"]
    if hand == "both":
        return dict(
            hand=["both hands", f"both of {possessive} hands"],
            arm=["both arms", f"both of {possessive} arms", f"{possessive} arms"],
        )
    slots = dict(
        hand=[f"the {hand} hand", f"{possessive} {hand} hand"],
        arm=[f"the {hand} arm", f"{possessive} {hand} arm"],
        fist=[f"the {hand} fist", f"{possessive} {hand} fist", f"the {hand} hand"],
        side=[hand],
    )
    if "count" in params:
        slots["side_reps"] = [count_noun(params["count"], f"{hand} punch")]
    return slots


class _Choices(dict):
    """A format mapping that picks one synonym per slot, the first time the slot is used."""

    def __init__(self, slots: dict[str, list[str]], rng: np.random.Generator):
        super().__init__()
        self.slots = slots
        self.rng = rng

    def __missing__(self, key: str) -> str:
        options = self.slots[key]
        value = options[int(self.rng.integers(len(options)))]
        self[key] = value
        return value


def _tidy(text: str) -> str:
    text = re.sub(r"\s+", " ", text).strip()
    return re.sub(r" ([,.])", r"\1", text)


def templates(primitive: str, pool: str) -> tuple[Template, ...]:
    """The primitive's templates in one pool ("train" or "heldout")."""
    if pool not in POOLS:
        raise ValueError(f"unknown caption pool {pool!r}; expected one of {', '.join(POOLS)}")
    return tuple(t for t in TEMPLATES[primitive] if t.heldout == (pool == "heldout"))


def _choose(options: Sequence[Template], rng: np.random.Generator) -> Template:
    return options[int(rng.integers(len(options)))]


def render(
    template: Template, primitive: str, params: dict, rng: np.random.Generator, subject: str
) -> tuple[str, str]:
    """A template as a finite verb phrase ("walks forward") and a gerund ("walking forward")."""
    slots = _slots(primitive, params, _reference(subject)[1])
    filled = template.text.format_map(_Choices(slots, rng))
    finite = _VERB.sub(lambda m: conjugate(m.group(1), "s"), filled)
    gerund = _VERB.sub(lambda m: conjugate(m.group(1), "ing"), filled)
    return _tidy(finite), _tidy(gerund)


def _phrase(
    segment: Segment, rng: np.random.Generator, pool: str, subject: str
) -> tuple[str, str, str]:
    fitting = [t for t in templates(segment.primitive, pool) if t.fits(segment.params)]
    if not fitting:
        raise ValueError(f"no {pool} caption template fits {segment.primitive} {segment.params}")
    template = _choose(fitting, rng)
    return (template.id,) + render(template, segment.primitive, segment.params, rng, subject)


def caption_segment(segment: Segment, rng: np.random.Generator, pool: str = "train") -> Sentence:
    """One segment as a sentence: "a person waves with the right hand."."""
    subject = SUBJECTS[int(rng.integers(len(SUBJECTS)))]
    template_id, finite, _ = _phrase(segment, rng, pool, subject)
    return Sentence(f"{subject} {finite}.", (template_id,))


def caption_program(
    segments: Sequence[Segment], rng: np.random.Generator, pool: str = "train"
) -> Sentence:
    """A whole program as one sentence, its segments in order, joined by joiner templates
    from the same pool (joiners are pooled too, so held-out captions also join unseen)."""
    if not segments:
        raise ValueError("a program needs at least one segment")
    subject = SUBJECTS[int(rng.integers(len(SUBJECTS)))]
    reference = _reference(subject)[0]
    first_id, a, A = _phrase(segments[0], rng, pool, subject)
    ids = [first_id]
    text = f"{subject} {a}"
    joiners = [j for j in JOINERS if j.heldout == (pool == "heldout")]
    for k, segment in enumerate(segments[1:]):
        template_id, b, B = _phrase(segment, rng, pool, subject)
        usable = joiners if k == 0 else [j for j in joiners if "{prev}" in j.text]
        joiner = _choose(usable, rng)
        text = joiner.text.format(prev=text, a=a, A=A, b=b, B=B, s=subject, ref=reference)
        ids += [joiner.id, template_id]
    return Sentence(_tidy(text) + ".", tuple(ids))
