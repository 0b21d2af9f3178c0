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
    "walk": _LOCOMOTION
    + (
        T("walk.1", "<stroll> {dir} {path}", _is("speed", "slow")),
        T("walk.2", "<sidestep> {lateral} {speed} {path}", _is("direction", "left", "right")),
        T("walk.3", "<back> up {speed} {path}", _is("direction", "backward")),
        T("walk.4", "<stride> {dir} {path}", _is("speed", "fast")),
        H("walk.5", "<shuffle> {dir} {path}", _is("speed", "slow")),
    ),
    "jog": _LOCOMOTION
    + (
        T("jog.1", "<trot> {dir} {speed} {path}"),
        T("jog.2", "<go> for a {speed_adj} jog {dir} {path}"),
        H("jog.3", "<run> {dir} at an easy jog {path}", _is("speed", "slow", "normal")),
    ),
    "run": _LOCOMOTION
    + (
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
    # corpus v2
    "crouch_walk": (
        T("crouch_walk.1", "<walk> {dir} in a crouch {speed} {path}"),
        T("crouch_walk.2", "<sneak> {dir} crouched low {path}"),
        T("crouch_walk.3", "<crouch> and <walk> {dir} {speed} {path}"),
        T("crouch_walk.4", "<take> {steps} crouching steps {dir} {path}"),
        H("crouch_walk.5", "<creep> {dir} bent low at the knees {speed} {path}"),
    ),
    "tiptoe": (
        T("tiptoe.1", "<walk> {dir} on tiptoe {speed} {path}"),
        T("tiptoe.2", "<walk> {dir} on {pos} toes {path}"),
        T("tiptoe.3", "<sneak> {dir} on tiptoes {path}"),
        T("tiptoe.4", "<take> {steps} steps {dir} on {pos} toes {path}"),
        H("tiptoe.5", "<creep> {dir} quietly on the balls of {pos} feet {path}"),
    ),
    "march": (
        T("march.1", "<march> forward {speed} {path}"),
        T("march.2", "<march> {steps} steps forward {path}"),
        T("march.3", "<march> like a soldier {path}"),
        T("march.4", "<walk> forward lifting {pos} knees high in a march {path}"),
        H("march.5", "<parade> forward with high knees {path}"),
    ),
    "limp": (
        T("limp.1", "<limp> forward {speed} {path}"),
        T("limp.2", "<limp> on {leg} {path}"),
        T("limp.3", "<walk> forward with a limp {path}"),
        T("limp.4", "<walk> with a limp, {pos} {side} leg hurt {path}"),
        H("limp.5", "<hobble> forward on a sore {side} leg {path}"),
    ),
    "skip": (
        T("skip.1", "<skip> forward {speed} {path}"),
        T("skip.2", "<skip> along {path}"),
        T("skip.3", "<skip> {steps} times forward {path}"),
        H("skip.4", "<bounce> forward skipping {path}"),
    ),
    "carry": (
        T("carry.1", "<carry> a box {dir} {path}"),
        T("carry.2", "<walk> {dir} carrying something heavy {speed} {path}"),
        T("carry.3", "<carry> something in both arms {dir} {path}"),
        T("carry.4", "<walk> {dir} holding a box in front of {pos} chest {path}"),
        H("carry.5", "<haul> a load {dir} in both arms {path}"),
    ),
    "stumble": (
        T("stumble.1", "<stumble> and <recover>"),
        T("stumble.2", "<walk> forward, <stumble> and <catch> {pos} balance"),
        T("stumble.3", "<lose> {pos} footing while walking and <recover>"),
        T("stumble.4", "<stumble> forward but <stay> on {pos} feet"),
        H("stumble.5", "<stagger> forward and <regain> {pos} balance"),
    ),
    "hop": (
        T("hop.1", "<hop> on {leg} {times}"),
        T("hop.2", "<hop> on one foot {times}"),
        T("hop.3", "<do> {reps} on {leg}"),
        T("hop.4", "<balance> on {leg} and <hop> {times}"),
        H("hop.5", "<bounce> up and down on {leg} {times}"),
    ),
    "step_up": (
        T("step_up.1", "<step> up onto a box and back down"),
        T("step_up.2", "<climb> up a step {leg} first and <step> back down"),
        T("step_up.3", "<step> up onto a platform and then back down"),
        T("step_up.4", "<climb> onto a step and <climb> back off"),
        H("step_up.5", "<mount> a stair and <descend> again"),
    ),
    "crawl": (
        T("crawl.1", "<crawl> forward on hands and knees"),
        T("crawl.2", "<get> down on all fours and <crawl> forward"),
        T("crawl.3", "<drop> to {pos} hands and knees and <crawl> ahead"),
        T("crawl.4", "<crawl> along the floor"),
        H("crawl.5", "<creep> forward on all fours"),
    ),
    "lie_down": (
        T("lie_down.1", "<get> down to lie on the floor and <get> back up"),
        T("lie_down.2", "<sit> down, <roll> back onto {pos} back and <get> up again"),
        T("lie_down.3", "<go> to lie down on {pos} back, then <stand> up"),
        T("lie_down.4", "<lower> {pos} body to the ground, <rest> on {pos} back and <get> up"),
        H("lie_down.5", "<recline> on the floor and <rise> again"),
    ),
    "pick_up": (
        T("pick_up.1", "<pick> something up from the floor with {hand}"),
        T("pick_up.2", "<bend> down and <pick> up an object with {hand}"),
        T("pick_up.3", "<reach> down with {hand} and <pick> something up"),
        T("pick_up.4", "<pick> up a box off the ground with {hand}"),
        H("pick_up.5", "<lift> an item off the floor with {hand}"),
    ),
    "push": (
        T("push.1", "<push> something forward {times}"),
        T("push.2", "<push> a heavy object with both hands {times}"),
        T("push.3", "<push> forward with both arms {times}"),
        T("push.4", "<shove> something away {times}"),
        H("push.5", "<press> hard against a heavy door {times}"),
    ),
    "pull": (
        T("pull.1", "<pull> something toward {pos} chest {times}"),
        T("pull.2", "<pull> a rope with both hands {times}"),
        T("pull.3", "<reach> forward and <pull> back {times}"),
        T("pull.4", "<pull> on something heavy {times}"),
        H("pull.5", "<heave> on a rope {times}"),
    ),
    "throw": (
        T("throw.1", "<throw> a ball with {hand}"),
        T("throw.2", "<throw> something overarm with {hand}"),
        T("throw.3", "<wind> up and <throw> with {hand}"),
        T("throw.4", "<throw> an object forward with {hand}"),
        H("throw.5", "<hurl> a ball with {hand}"),
    ),
    "point": (
        T("point.1", "<point> {point_at} with {hand}"),
        T("point.2", "<point> {point_at}"),
        T("point.3", "<raise> {arm} and <point> {point_at}"),
        T("point.4", "<stretch> out {arm} to point {point_at}"),
        H("point.5", "<indicate> something {point_at} with {hand}"),
    ),
    "look_around": (
        T("look_around.1", "<look> around"),
        T("look_around.2", "<look> to the left and to the right"),
        T("look_around.3", "<turn> {pos} head to look around"),
        T("look_around.4", "<glance> around in both directions"),
        H("look_around.5", "<survey> the area around"),
    ),
    "shrug": (
        T("shrug.1", "<give> a shrug"),
        T("shrug.2", "<give> {reps}"),
        T("shrug.3", "<raise> {pos} hands in a shrug {times}"),
        H("shrug.4", "<make> a shrugging gesture {times}"),
    ),
    "salute": (
        T("salute.1", "<salute>"),
        T("salute.2", "<salute> with {hand}"),
        T("salute.3", "<raise> {hand} to {pos} forehead in a salute"),
        T("salute.4", "<give> a military salute"),
        H("salute.5", "<stand> to attention and <salute>"),
    ),
    "dance": (
        T("dance.1", "<dance> side to side"),
        T("dance.2", "<do> a step touch dance {times}"),
        T("dance.3", "<dance>, stepping from side to side {times}"),
        T("dance.4", "<sway> and <step> side to side in a dance"),
        H("dance.5", "<groove> from side to side {times}"),
    ),
    "uppercut": (
        T("uppercut.1", "<throw> {reps} with {fist}"),
        T("uppercut.2", "<do> an uppercut with {fist} {times}"),
        T("uppercut.3", "<punch> upward with {fist} {times}"),
        H("uppercut.4", "<drive> {fist} upward in an uppercut {times}"),
    ),
    "duck": (
        T("duck.1", "<duck> {times}"),
        T("duck.2", "<duck> and <weave> {times}"),
        T("duck.3", "<dodge> by ducking down {times}"),
        T("duck.4", "<duck> under a punch {times}"),
        H("duck.5", "<evade> a blow by ducking {times}"),
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
