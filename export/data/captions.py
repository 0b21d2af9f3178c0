"""HumanML3D-style captions for animator programs.

Each primitive has paraphrase templates with stable IDs, split into a train pool and a
held-out pool, so a test split can measure how a model copes with phrasings it never saw.
A template is a verb phrase: `<verb>` marks a verb to conjugate ("walks" / "walking"),
`{slot}` a phrase chosen at random from the synonyms that say the segment's params.
IDs are never renumbered; new templates get new IDs.
"""
from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from mogo.align import conjugate  # shared with prompt alignment
from mogo.export.data.animator import Segment

POOLS = ("train", "heldout")
SUBJECTS = ("a person", "someone", "a man", "a woman", "the person", "a figure")


@dataclass(frozen=True)
class Template:
    id: str
    text: str
    heldout: bool = False
    when: Callable[[dict], bool] | None = None  # the params this phrasing fits; None: all

    def fits(self, params: dict) -> bool:
        return self.when is None or self.when(params)


@dataclass(frozen=True)
class Sentence:
    text: str
    template_ids: tuple[str, ...]


def T(id: str, text: str, when: Callable[[dict], bool] | None = None) -> Template:
    return Template(id, text, False, when)


def H(id: str, text: str, when: Callable[[dict], bool] | None = None) -> Template:
    return Template(id, text, True, when)


def _is(name: str, *values) -> Callable[[dict], bool]:
    return lambda params: params[name] in values


def _angle_near(degrees: float) -> Callable[[dict], bool]:
    return lambda params: abs(abs(params["angle"]) - degrees) <= 22.5


_LOCOMOTION = (
    T("loco.1", "<{gait}> {dir} {speed} {path}"),
    T("loco.2", "<{gait}> {speed_adv} {dir} {path}"),
    T("loco.3", "<take> {steps} {step_adj} {stride} {dir} {path}"),
    T("loco.4", "<{gait}> {dir} for {steps} {stride} {speed} {path}"),
    T("loco.5", "<{gait}> {dir} {path} {speed}"),
    H("loco.6", "<cover> a short distance {dir} {speed} {path}"),
    H("loco.7", "<make> {pos} way {dir} {speed_adv} {path}"),
)

TEMPLATES: dict[str, tuple[Template, ...]] = {
    "walk": _LOCOMOTION + (
        T("walk.1", "<stroll> {dir} {path}", _is("speed", "slow")),
        T("walk.2", "<sidestep> {lateral} {speed} {path}", _is("direction", "left", "right")),
        T("walk.3", "<back> up {speed} {path}", _is("direction", "backward")),
        T("walk.4", "<stride> {dir} {path}", _is("speed", "fast")),
        H("walk.5", "<shuffle> {dir} {path}", _is("speed", "slow")),
    ),
    "jog": _LOCOMOTION + (
        T("jog.1", "<trot> {dir} {speed} {path}"),
        T("jog.2", "<go> for a {speed_adj} jog {dir} {path}"),
        H("jog.3", "<run> {dir} at an easy jog {path}", _is("speed", "slow", "normal")),
    ),
    "run": _LOCOMOTION + (
        T("run.1", "<sprint> {dir} {path}", _is("speed", "fast")),
        T("run.2", "<dash> {dir} {path}", _is("speed", "fast")),
        T("run.3", "<race> {dir} {speed} {path}"),
        H("run.4", "<rush> {dir} {speed} {path}"),
    ),
    "turn": (
        T("turn.1", "<turn> {turn_amount} to the {side}"),
        T("turn.2", "<make> {turn_fraction} turn to the {side}"),
        T("turn.3", "<rotate> {turn_amount} {rot}"),
        T("turn.4", "<turn> around", _angle_near(180)),
        T("turn.5", "<turn> {side}", _angle_near(90)),
        T("turn.6", "<pivot> {turn_amount} to the {side}"),
        H("turn.7", "<swivel> {rot} by {turn_amount}"),
        H("turn.8", "<spin> {pos} body {turn_amount} to the {side}"),
    ),
    "jump": (
        T("jump.1", "<jump> {jump_dir} {times}"),
        T("jump.2", "<do> {reps} {jump_dir}"),
        T("jump.3", "<hop> {jump_dir} {times}"),
        T("jump.4", "<leap> forward {times}", _is("forward", True)),
        T("jump.5", "<jump> up and down {times}", _is("forward", False)),
        H("jump.6", "<bound> {jump_dir} {times}"),
        H("jump.7", "<spring> {jump_dir} with both feet {times}"),
    ),
    "squat": (
        T("squat.1", "<squat> {times}"),
        T("squat.2", "<do> {reps}"),
        T("squat.3", "<squat> down and <stand> back up {times}"),
        T("squat.4", "<bend> {pos} knees into a squat {times}"),
        T("squat.5", "<crouch> down and <rise> {times}"),
        H("squat.6", "<perform> {reps}"),
        H("squat.7", "<lower> {pos} hips toward the floor and <come> back up {times}"),
    ),
    "sit": (
        T("sit.1", "<sit> down"),
        T("sit.2", "<take> a seat"),
        T("sit.3", "<lower> {pos} body into a sitting position"),
        T("sit.4", "<sit> down as if on a chair"),
        H("sit.5", "<settle> down onto an invisible seat"),
    ),
    "bow": (
        T("bow.1", "<bow>"),
        T("bow.2", "<take> a bow"),
        T("bow.3", "<bend> forward at the waist in a bow"),
        T("bow.4", "<bow> politely"),
        H("bow.5", "<lean> {pos} upper body forward in a bow"),
    ),
    "wave": (
        T("wave.1", "<wave> with {hand}"),
        T("wave.2", "<wave> {hand} {times}"),
        T("wave.3", "<raise> {hand} and <wave>"),
        T("wave.4", "<wave> hello with {hand}"),
        T("wave.5", "<wave> {hand} back and forth {times}"),
        H("wave.6", "<greet> someone by waving {hand}"),
        H("wave.7", "<give> a wave with {hand}"),
    ),
    "raise_arms": (
        T("raise_arms.1", "<raise> {arm}"),
        T("raise_arms.2", "<lift> {arm} up"),
        T("raise_arms.3", "<raise> {arm} above {pos} head"),
        T("raise_arms.4", "<put> {arm} up in the air"),
        H("raise_arms.5", "<reach> up with {arm}"),
    ),
    "clap": (
        T("clap.1", "<clap> {times}"),
        T("clap.2", "<clap> {pos} hands {times}"),
        T("clap.3", "<clap> {pos} hands together {times}"),
        T("clap.4", "<give> {reps}"),
        H("clap.5", "<bring> {pos} palms together {times}"),
    ),
    "punch": (
        T("punch.1", "<punch> with {fist} {times}"),
        T("punch.2", "<throw> {reps} with {fist}"),
        T("punch.3", "<throw> {side_reps}"),
        T("punch.4", "<punch> forward with {fist} {times}"),
        H("punch.5", "<jab> with {fist} {times}"),
        H("punch.6", "<strike> forward {times} with {fist}"),
    ),
    "kick": (
        T("kick.1", "<kick> with {leg}"),
        T("kick.2", "<kick> {leg} forward"),
        T("kick.3", "<do> a {side} kick"),
        T("kick.4", "<kick> out with {leg}"),
        H("kick.5", "<swing> {leg} forward in a kick"),
    ),
    "spin": (
        T("spin.1", "<spin> around to the {side}"),
        T("spin.2", "<spin> {rot}"),
        T("spin.3", "<turn> a full circle to the {side}"),
        T("spin.4", "<do> a full spin to the {side}"),
        H("spin.5", "<twirl> around {rot}"),
    ),
    "stretch": (
        T("stretch.1", "<stretch>"),
        T("stretch.2", "<stretch> {pos} arms"),
        T("stretch.3", "<do> a stretch"),
        T("stretch.4", "<stretch> out {pos} body"),
        H("stretch.5", "<limber> up with a stretch"),
    ),
    "jumping_jacks": (
        T("jumping_jacks.1", "<do> {reps}"),
        T("jumping_jacks.2", "<perform> {reps}"),
        T("jumping_jacks.3", "<do> jumping jacks {times}"),
        T("jumping_jacks.4", "<jump> while spreading and closing {pos} arms and legs {times}"),
        H("jumping_jacks.5", "<do> {star_reps}"),
    ),
    "idle": (
        T("idle.1", "<stand> still"),
        T("idle.2", "<stand> still for {secs}"),
        T("idle.3", "<wait> for {secs}"),
        T("idle.4", "<stay> in place for {secs}"),
        T("idle.5", "<stand> in place"),
        H("idle.6", "<pause> for {secs}"),
        H("idle.7", "<remain> standing for {secs}"),
    ),
}

# {prev}: the sentence so far (subject included); {a}/{A}: the first segment as a finite
# verb phrase / gerund, {b}/{B} the next; {s}: the subject; {ref}: he / she / the person.
# Joiners without {prev} can only join the first two segments.
JOINERS = (
    T("join.1", "{prev}, then {b}"),
    T("join.2", "{prev} and then {b}"),
    T("join.3", "{prev}. after that, {ref} {b}"),
    T("join.4", "{prev} before {B}"),
    T("join.5", "{prev}, followed by {B}"),
    T("join.6", "{prev} then {b}"),
    T("join.7", "after {A}, {s} {b}"),
    T("join.8", "{s} first {a}, then {b}"),
    H("join.9", "{prev}, and afterwards {ref} {b}"),
    H("join.10", "{s} starts by {A} and then {b}"),
    H("join.11", "{prev}, and when done, {ref} {b}"),
)

_NUMBERS = ("zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine",
            "ten", "eleven", "twelve", "thirteen", "fourteen", "fifteen", "sixteen",
            "seventeen", "eighteen", "nineteen", "twenty")
_VERB = re.compile(r"<(\w+)>")
_REPETITION_NOUNS = {"jump": "jump", "squat": "squat", "clap": "clap", "punch": "punch",
                     "jumping_jacks": "jumping jack"}
_GAITS = {"walk": ("walk", "steps"), "jog": ("jog", "strides"), "run": ("run", "strides")}


def number_word(n: int) -> str:
    return _NUMBERS[n] if 0 <= n < len(_NUMBERS) else str(n)


def times_word(n: int) -> str:
    return {1: "once", 2: "twice"}.get(n, f"{number_word(n)} times")


def count_noun(n: int, noun: str) -> str:
    """"a squat", "three punches"."""
    if n == 1:
        return f"an {noun}" if noun[0] in "aeiou" else f"a {noun}"
    plural = noun + "es" if noun.endswith(("s", "sh", "ch", "x", "z")) else noun + "s"
    return f"{number_word(n)} {plural}"


def _reference(subject: str) -> tuple[str, str]:
    """(pronoun or definite noun, possessive) that refer back to the subject."""
    return {"a man": ("he", "his"), "a woman": ("she", "her"),
            "a figure": ("the figure", "its")}.get(subject, ("the person", "their"))


def _side(signed_degrees: float) -> str:
    return "left" if signed_degrees > 0 else "right"


def _turn_size(degrees: float) -> tuple[list[str], list[str]]:
    """Amount phrases ("ninety degrees") and fraction phrases ("a quarter") of a turn,
    rounded to the nearest eighth of a circle ("about" when that rounding is coarse)."""
    eighths = max(1, round(abs(degrees) / 45))
    about = "about " if abs(abs(degrees) - 45 * eighths) > 10 else ""
    words = {1: "forty-five", 2: "ninety", 3: "a hundred and thirty-five",
             4: "a hundred and eighty", 5: "two hundred and twenty-five",
             6: "two hundred and seventy", 7: "three hundred and fifteen",
             8: "three hundred and sixty"}
    fractions = {1: ["a slight", "an eighth of a"], 2: ["a quarter", "a ninety-degree"],
                 3: ["a three-eighths"], 4: ["a half", "a half-circle"], 5: ["a five-eighths"],
                 6: ["a three-quarter"], 7: ["an almost full"], 8: ["a full"]}
    amounts = [f"{about}{words.get(eighths, str(45 * eighths))} degrees"]
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
        return [f"veering slightly to the {side}", f"in a gentle curve to the {side}",
                f"bearing slightly {side}"]
    if size < 135:
        return [f"in a curve to the {side}", f"curving to the {side}",
                f"while turning {side}", f"along a path that bends to the {side}"]
    if size < 225:
        return [f"in a half circle to the {side}", f"in a u-turn to the {side}",
                f"turning around to the {side}"]
    return [f"in a circle to the {side}", f"in a full circle to the {side}"]


def _slots(primitive: str, params: dict, possessive: str) -> dict[str, list[str]]:
    """Synonym lists for every slot the primitive's templates may use."""
    slots: dict[str, list[str]] = {"pos": [possessive]}
    if primitive in _GAITS:
        gait, stride = _GAITS[primitive]
        direction, speed = params["direction"], params["speed"]
        slots["gait"] = [gait]
        slots["stride"] = [stride]
        slots["dir"] = {"forward": ["forward", "forwards", "ahead"],
                        "backward": ["backward", "backwards"],
                        "left": ["to the left", "sideways to the left", "leftward"],
                        "right": ["to the right", "sideways to the right", "rightward"],
                        }[direction]
        if direction in ("left", "right"):
            slots["lateral"] = [f"to the {direction}", direction]
        slots["speed"] = {"slow": ["slowly", "at a slow pace", "leisurely"],
                          "normal": ["", "at a normal pace", "at a steady pace"],
                          "fast": ["quickly", "at a fast pace", "briskly"]}[speed]
        slots["speed_adv"] = {"slow": ["slowly"], "normal": ["", "steadily"],
                              "fast": ["quickly", "rapidly"]}[speed]
        slots["speed_adj"] = {"slow": ["slow", "gentle"], "normal": ["steady", "normal"],
                              "fast": ["fast", "quick"]}[speed]
        slots["step_adj"] = {"slow": ["small", "slow"], "normal": [""],
                             "fast": ["quick", "big"]}[speed]
        slots["steps"] = [number_word(params["steps"])]
        slots["path"] = _path(params["turn"])
    if "angle" in params:
        amounts, fractions = _turn_size(params["angle"])
        slots["turn_amount"] = amounts
        slots["turn_fraction"] = fractions
        slots["side"] = [_side(params["angle"])]
        slots["rot"] = ["counterclockwise" if params["angle"] > 0 else "clockwise"]
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
        slots["jump_dir"] = (["forward", "forwards", "ahead"] if params["forward"]
                             else ["in place", "on the spot"])
    if "hand" in params:
        hand = params["hand"]
        if hand == "both":
            slots["hand"] = ["both hands", f"both of {possessive} hands"]
            slots["arm"] = ["both arms", f"both of {possessive} arms", f"{possessive} arms"]
        else:
            slots["hand"] = [f"the {hand} hand", f"{possessive} {hand} hand"]
            slots["arm"] = [f"the {hand} arm", f"{possessive} {hand} arm"]
            slots["fist"] = [f"the {hand} fist", f"{possessive} {hand} fist",
                             f"the {hand} hand"]
            slots["side"] = [hand]
            if "count" in params:
                slots["side_reps"] = [count_noun(params["count"], f"{hand} punch")]
    if "foot" in params:
        foot = params["foot"]
        slots["leg"] = [f"the {foot} leg", f"{possessive} {foot} leg", f"the {foot} foot"]
        slots["side"] = [foot]
    if "seconds" in params:
        seconds = round(params["seconds"])
        words = number_word(seconds)
        slots["secs"] = (["a moment", "a second"] if seconds <= 1
                         else [f"{words} seconds", f"about {words} seconds"])
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


def render(template: Template, primitive: str, params: dict, rng: np.random.Generator,
           subject: str) -> tuple[str, str]:
    """A template as a finite verb phrase ("walks forward") and a gerund ("walking forward")."""
    slots = _slots(primitive, params, _reference(subject)[1])
    filled = template.text.format_map(_Choices(slots, rng))
    finite = _VERB.sub(lambda m: conjugate(m.group(1), "s"), filled)
    gerund = _VERB.sub(lambda m: conjugate(m.group(1), "ing"), filled)
    return _tidy(finite), _tidy(gerund)


def _phrase(segment: Segment, rng: np.random.Generator, pool: str,
            subject: str) -> tuple[str, str, str]:
    fitting = [t for t in templates(segment.primitive, pool) if t.fits(segment.params)]
    if not fitting:
        raise ValueError(f"no {pool} caption template fits {segment.primitive} {segment.params}")
    template = _choose(fitting, rng)
    return (template.id,) + render(template, segment.primitive, segment.params, rng, subject)


def caption_segment(segment: Segment, rng: np.random.Generator,
                    pool: str = "train") -> Sentence:
    """One segment as a sentence: "a person waves with the right hand."."""
    subject = SUBJECTS[int(rng.integers(len(SUBJECTS)))]
    template_id, finite, _ = _phrase(segment, rng, pool, subject)
    return Sentence(f"{subject} {finite}.", (template_id,))


def caption_program(segments: Sequence[Segment], rng: np.random.Generator,
                    pool: str = "train") -> Sentence:
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
