"""The caption templates of the procedural corpus (mogo.export.data.captions renders them).

Each primitive has paraphrase templates with stable IDs, split into a train pool (T) and a
held-out pool (H), so a test split can measure how a model copes with phrasings it never saw.
A template is a verb phrase: `<verb>` marks a verb to conjugate ("walks" / "walking"),
`{slot}` a phrase chosen at random from the synonyms that say the segment's params.
IDs are never renumbered; new templates get new IDs.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

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
