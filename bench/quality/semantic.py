"""Does a clip do what its caption says? Checks from the procedural corpus's ground-truth
programs (programs/ID.json), measured on joint positions (T, 22, 3), metres, Y up.

An item is a caption that covers exactly one program segment (its span is the segment's, or
the program has one segment), so the whole clip should show that one primitive with its
parameters: travel direction for walk / jog / run and the turn of a curved path, the turn's
angle, the spin's direction, which hand (wave, raise_arms, punch) or foot (kick), how many
jumps, squats, jumping jacks and claps, that a jump travels or stays, that sit goes down to
the floor, that bow bends the head down while the hips stay up, that stretch raises both arms
overhead, that idle stays in place. Distances of travel are judged against the real clip of
the same caption: a generated walk must travel between half and twice as far.

The checks are calibrated on the real test clips (which must pass at a high rate for the
checks to be honest; the report gives that rate next to the generated clips').
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.motion.skeleton import SKELETONS

SKELETON = SKELETONS["humanml3d"]
J = {name: index for index, name in enumerate(SKELETON.joint_names)}
FEET = [J["left_ankle"], J["right_ankle"], J["left_foot"], J["right_foot"]]
LOCOMOTION = ("walk", "jog", "run")
DIRECTIONS = dict(forward=(1.0, 0.0), backward=(-1.0, 0.0), left=(0.0, 1.0), right=(0.0, -1.0))
MIN_TRAVEL = 0.3  # metres: less is "in place"
DIRECTION_TOLERANCE = 50.0  # degrees between the travel and the asked direction
TURN_TOLERANCE = 50.0  # degrees between the body's turn and the asked angle


@dataclass(frozen=True)
class SemanticItem:
    clip_id: str
    caption: str
    primitive: str
    params: dict = field(hash=False)
    start: int  # joint frames [start, end) of the real clip
    end: int

    @property
    def frames(self) -> int:
        return self.end - self.start


def program_items(data: str | Path, ids: list[str]) -> list[SemanticItem]:
    """The captions of `ids` that cover exactly one program segment."""
    items = []
    for clip_id in ids:
        path = Path(data) / "programs" / f"{clip_id}.json"
        if not path.is_file():
            raise FileNotFoundError(
                f"{path}: no program (semantic checks need the procedural corpus's programs/)"
            )
        program = json.loads(path.read_text())
        segments = program["segments"]
        for caption in program["captions"]:
            span = caption["span"]
            matching = (
                [s for s in segments if list(s["span"]) == list(span)]
                if span
                else segments
                if len(segments) == 1
                else []
            )
            if len(matching) == 1:
                s = matching[0]
                items.append(
                    SemanticItem(
                        clip_id,
                        caption["text"],
                        s["primitive"],
                        s["params"],
                        int(s["span"][0]),
                        int(s["span"][1]),
                    )
                )
    return items


# -- measurements --------------------------------------------------------------------------


def facing(joints: np.ndarray) -> np.ndarray:
    """Unit facing directions (T, 2) as (x, z), from hips and shoulders (HumanML3D's rule)."""
    across = (
        joints[:, J["right_hip"]]
        - joints[:, J["left_hip"]]
        + joints[:, J["right_shoulder"]]
        - joints[:, J["left_shoulder"]]
    )
    forward = np.stack([across[:, 2], -across[:, 0]], 1)  # up x across, in (x, z)
    return forward / np.maximum(np.linalg.norm(forward, axis=1, keepdims=True), 1e-9)


def heading_change(joints: np.ndarray) -> float:
    """Degrees the body turned from the first frame to the last, left (counter-clockwise seen
    from above) positive, unwrapped so full spins count."""
    f = facing(joints)
    yaw = np.unwrap(np.arctan2(f[:, 0], f[:, 1]))
    return float(np.degrees(yaw[-1] - yaw[0]))


def travel(joints: np.ndarray) -> np.ndarray:
    """Root displacement (forward, left) in metres, in the body's facing frame of frame 0."""
    f = facing(joints[:1])[0]
    d = joints[-1, 0] - joints[0, 0]
    return np.array([d[0] * f[0] + d[2] * f[1], d[0] * f[1] - d[2] * f[0]])


def runs(flags: np.ndarray, min_length: int = 2) -> int:
    """Number of runs of at least `min_length` consecutive True frames."""
    padded = np.concatenate([[False], flags, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return int(np.sum(edges[1::2] - edges[::2] >= min_length))


def airborne(joints: np.ndarray) -> np.ndarray:
    """Frames where every foot joint is clear of the clip's floor (its lowest 5% of feet)."""
    lowest = joints[:, FEET, 1].min(1)
    return lowest > np.percentile(lowest, 5) + 0.06


def raised_hands(joints: np.ndarray) -> set[str]:
    """Hands whose wrist rises above the head's top at any point (the neck + 0.1 m)."""
    top = joints[:, J["neck"], 1] + 0.1
    return {
        side for side in ("left", "right") if np.mean(joints[:, J[f"{side}_wrist"], 1] > top) > 0.1
    }


def _side_set(value: str) -> set[str]:
    return {"left", "right"} if value == "both" else {value}


# -- checks --------------------------------------------------------------------------------


@dataclass
class Verdict:
    passed: bool
    measured: dict


def _locomotion(joints: np.ndarray, params: dict, reference: np.ndarray | None) -> Verdict:
    d = travel(joints)
    distance = float(np.linalg.norm(d))
    expected = np.array(DIRECTIONS[params["direction"]])
    angle = float(np.degrees(np.arccos(np.clip(d @ expected / max(distance, 1e-9), -1, 1))))
    turned = heading_change(joints)
    ok = distance >= MIN_TRAVEL and (angle <= DIRECTION_TOLERANCE or params.get("turn", 0) != 0)
    if params.get("turn", 0):
        ok = ok and abs(turned - params["turn"]) <= TURN_TOLERANCE
    measured = dict(distance=round(distance, 2), angle=round(angle), turned=round(turned))
    if reference is not None:
        ratio = distance / max(float(np.linalg.norm(travel(reference))), 1e-9)
        ok = ok and 0.5 <= ratio <= 2.0
        measured["ratio"] = round(ratio, 2)
    return Verdict(bool(ok), measured)


def _turn(joints, params, reference) -> Verdict:
    turned = heading_change(joints)
    return Verdict(abs(turned - params["angle"]) <= TURN_TOLERANCE, dict(turned=round(turned)))


def _spin(joints, params, reference) -> Verdict:
    turned = heading_change(joints)
    sign = 1 if params["direction"] == "left" else -1
    return Verdict(sign * turned >= 270, dict(turned=round(turned)))


def _jump(joints, params, reference) -> Verdict:
    count = runs(airborne(joints))
    forward = float(travel(joints)[0])
    moved = forward >= MIN_TRAVEL if params["forward"] else abs(forward) < MIN_TRAVEL
    return Verdict(count == params["count"] and moved, dict(count=count, forward=round(forward, 2)))


def _pelvis_dips(joints: np.ndarray, depth: float) -> int:
    pelvis = joints[:, J["pelvis"], 1]
    return runs(pelvis < pelvis.max() - depth)


def _squat(joints, params, reference) -> Verdict:
    count = _pelvis_dips(joints, 0.15)
    return Verdict(count == params["count"], dict(count=count))


def _jumping_jacks(joints, params, reference) -> Verdict:
    top = joints[:, J["head"], 1]
    up = (joints[:, J["left_wrist"], 1] > top) & (joints[:, J["right_wrist"], 1] > top)
    count = runs(up)
    return Verdict(count == params["count"], dict(count=count))


def _clap(joints, params, reference) -> Verdict:
    gap = np.linalg.norm(joints[:, J["left_wrist"]] - joints[:, J["right_wrist"]], axis=1)
    count = runs(gap < 0.12, min_length=1)
    return Verdict(count == params["count"], dict(count=count))


def _hands_up(joints, params, reference) -> Verdict:
    hands = raised_hands(joints)
    return Verdict(hands == _side_set(params["hand"]), dict(hands="+".join(sorted(hands))))


def _punch(joints, params, reference) -> Verdict:
    f = facing(joints)
    reach = {
        side: float(
            np.max(
                np.sum(
                    (joints[:, J[f"{side}_wrist"]] - joints[:, J[f"{side}_shoulder"]])[:, [0, 2]]
                    * f,
                    axis=1,
                )
            )
        )
        for side in ("left", "right")
    }
    hand = max(reach, key=reach.get)
    return Verdict(
        hand == params["hand"] and reach[hand] > 0.4, dict(hand=hand, reach=round(reach[hand], 2))
    )


def _kick(joints, params, reference) -> Verdict:
    lift = {side: float(np.ptp(joints[:, J[f"{side}_ankle"], 1])) for side in ("left", "right")}
    foot = max(lift, key=lift.get)
    return Verdict(
        foot == params["foot"] and lift[foot] > 0.2, dict(foot=foot, lift=round(lift[foot], 2))
    )


def _sit(joints, params, reference) -> Verdict:
    drop = float(np.ptp(joints[:, J["pelvis"], 1]))
    return Verdict(drop > 0.4, dict(drop=round(drop, 2)))


def _bow(joints, params, reference) -> Verdict:
    head = float(np.ptp(joints[:, J["head"], 1]))
    pelvis = float(np.ptp(joints[:, J["pelvis"], 1]))
    return Verdict(
        head > 0.08 and pelvis < 0.12, dict(head=round(head, 2), pelvis=round(pelvis, 2))
    )


def _stretch(joints, params, reference) -> Verdict:
    hands = raised_hands(joints)
    return Verdict(hands == {"left", "right"}, dict(hands="+".join(sorted(hands))))


def _idle(joints, params, reference) -> Verdict:
    """In place, upright, facing one way, the hands near where they hang."""
    distance = float(np.linalg.norm(travel(joints)))
    pelvis = float(np.ptp(joints[:, J["pelvis"], 1]))
    turned = abs(heading_change(joints))
    relative = joints[:, [J["left_wrist"], J["right_wrist"]]] - joints[:, J["pelvis"]][:, None]
    hands = float(np.max(np.ptp(relative, axis=0)))
    return Verdict(
        distance < MIN_TRAVEL and pelvis < 0.1 and turned < 30 and hands < 0.2,
        dict(
            distance=round(distance, 2),
            pelvis=round(pelvis, 2),
            turned=round(turned),
            hands=round(hands, 2),
        ),
    )


CHECKS: dict[str, Callable[[np.ndarray, dict, np.ndarray | None], Verdict]] = dict(
    walk=_locomotion,
    jog=_locomotion,
    run=_locomotion,
    turn=_turn,
    spin=_spin,
    jump=_jump,
    squat=_squat,
    jumping_jacks=_jumping_jacks,
    clap=_clap,
    wave=_hands_up,
    raise_arms=_hands_up,
    punch=_punch,
    kick=_kick,
    sit=_sit,
    bow=_bow,
    stretch=_stretch,
    idle=_idle,
    # corpus v2's stepping moves travel as walking does (forward where they have no direction);
    # its keyed moves have no check yet and are left out of the report
    crouch_walk=_locomotion,
    tiptoe=_locomotion,
    carry=_locomotion,
    **dict.fromkeys(
        ("march", "skip", "limp", "stumble"),
        lambda joints, params, reference: _locomotion(
            joints, {"direction": "forward", **params}, reference
        ),
    ),
)


def check(item: SemanticItem, joints: np.ndarray, reference: np.ndarray | None = None) -> Verdict:
    """Does `joints` (T, 22, 3) do what the item's primitive and parameters say? `reference`:
    the real clip of the item, for the checks judged against it (distance of travel)."""
    if item.primitive not in CHECKS:
        raise ValueError(f"no semantic check for primitive {item.primitive!r}")
    return CHECKS[item.primitive](joints, item.params, reference)


def pass_rates(items: list[SemanticItem], verdicts: list[Verdict]) -> dict[str, tuple[int, int]]:
    """-> {primitive: (passed, total)}, primitives in alphabetical order."""
    rates: dict[str, list[int]] = {}
    for item, verdict in zip(items, verdicts, strict=False):
        counts = rates.setdefault(item.primitive, [0, 0])
        counts[0] += verdict.passed
        counts[1] += 1
    return {name: tuple(rates[name]) for name in sorted(rates)}


def stratified(items: list[SemanticItem], per_primitive: int, seed: int) -> list[SemanticItem]:
    """A fixed random sample of `per_primitive` items of each primitive (all where fewer)."""
    rng = np.random.default_rng(seed)
    chosen = []
    for primitive in sorted({item.primitive for item in items}):
        group = [item for item in items if item.primitive == primitive]
        keep = np.sort(rng.permutation(len(group))[:per_primitive])
        chosen += [group[k] for k in keep]
    return chosen


def semantic_report(
    generator, data: str | Path, per_primitive: int = 20, seed: int = 0, threads: int = 1
) -> dict[str, dict[str, tuple[int, int]]]:
    """Pass rates per primitive -> {primitive: dict(real=..., generated=..., other=...)}, each
    (passed, total), of the primitives with a check: `real`, every single-segment caption of
    the test split on its real clip; `generated`, `per_primitive` of them generated by
    `generator` (a MotionGenerator) from the caption with the real length; `other`, the same sample's checks on the real clip of an item
    of another primitive (how often a check passes what it should not)."""
    from mogo.bench.quality.evaluate import generate_items

    folder = HumanML3DFolder(data, splits=("test",))
    items = [item for item in program_items(data, folder.ids("test")) if item.primitive in CHECKS]
    clips: dict[str, np.ndarray] = {}

    def real(item: SemanticItem) -> np.ndarray:
        if item.clip_id not in clips:
            clips[item.clip_id] = folder.joints(item.clip_id)
        return clips[item.clip_id][item.start : item.end]

    chosen = stratified(items, per_primitive, seed)
    rng = np.random.default_rng(seed)
    others = [[o for o in chosen if o.primitive != item.primitive] for item in chosen]
    other = [
        check(item, real(group[rng.integers(len(group))]), real(item))
        for item, group in zip(chosen, others, strict=False)
    ]
    motions = generate_items(generator, chosen, seed, threads, "semantic check")
    generated = [
        check(item, motion.joints, real(item))
        for item, motion in zip(chosen, motions, strict=False)
    ]
    columns = dict(
        real=pass_rates(items, [check(item, real(item), real(item)) for item in items]),
        generated=pass_rates(chosen, generated),
        other=pass_rates(chosen, other),
    )
    return {
        primitive: {name: rates[primitive] for name, rates in columns.items()}
        for primitive in columns["real"]
    }


def format_semantic(report: dict[str, dict[str, tuple[int, int]]]) -> str:
    def cell(counts: tuple[int, int]) -> str:
        return f"{counts[0] / counts[1]:.0%} ({counts[0]}/{counts[1]})"

    totals = {
        name: tuple(map(sum, zip(*(row[name] for row in report.values()), strict=False)))
        for name in ("real", "generated", "other")
    }
    lines = [
        "| primitive | real clips pass | generated clips pass | a real clip of another "
        "primitive passes |",
        "|---|---|---|---|",
    ]
    for primitive, row in {**report, "all": totals}.items():
        lines.append(
            f"| {primitive} | {cell(row['real'])} | {cell(row['generated'])} | "
            f"{cell(row['other'])} |"
        )
    return "\n".join(lines)
