"""Motion capture in (mogo.motion.mocap): BVH files in several conventions and DeepMimic
motions, written here from known skeletons and rotations, come back as the source's joints.

The files are written with scipy's Euler angles and checked against forward kinematics done
here, so a wrong Euler order, axis turn or unit in the reader shows as an error in cm.
"""

import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mogo import Motion, MotionGenerator
from mogo.motion.bvh import save_bvh
from mogo.motion.mocap import read_mocap, resample
from mogo.motion.rigs import read_mapping
from mogo.motion.skeleton import SMPL_22

Y_UP_TO_Z_UP = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # (x, y, z) -> (x, -z, y)
TOLERANCE = 0.01  # metres


class Rig:
    """A BVH skeleton: names, parents and offsets (metres, Y up), and motion: local rotation
    matrices (T, J, 3, 3), root positions (T, 3), optional per-frame bone translations."""

    def __init__(self, joints: list[tuple[str, str | None, tuple]], rotations, root, fps):
        self.names = [name for name, _, _ in joints]
        self.parents = [self.names.index(p) if p else -1 for _, p, _ in joints]
        self.offsets = np.array([offset for _, _, offset in joints], dtype=np.float64)
        self.rotations, self.root, self.fps = rotations, root, fps
        self.translations = np.broadcast_to(self.offsets, (len(root),) + self.offsets.shape)

    def positions(self) -> np.ndarray:
        """World positions (T, J, 3) by forward kinematics, done here."""
        frames, count = len(self.root), len(self.names)
        world, place = np.zeros((frames, count, 3, 3)), np.zeros((frames, count, 3))
        for j, p in enumerate(self.parents):
            if p < 0:
                world[:, j], place[:, j] = self.rotations[:, j], self.root
            else:
                world[:, j] = world[:, p] @ self.rotations[:, j]
                place[:, j] = place[:, p] + np.einsum(
                    "tij,tj->ti", world[:, p], self.translations[:, j]
                )
        return place

    def write(self, path, order="ZXY", scale=1.0, z_up=False, everywhere=False):
        """The BVH: Euler `order` (intrinsic, as BVH channels mean), lengths times `scale`,
        Z up or Y up, position channels on every joint or on the root only."""
        turn = Y_UP_TO_Z_UP if z_up else np.eye(3)
        children = {
            j: [c for c, p in enumerate(self.parents) if p == j] for j in range(len(self.names))
        }
        lines, columns = ["HIERARCHY"], []

        def joint(j, depth):
            pad, moves = "  " * depth, depth == 0 or everywhere
            offset = turn @ self.offsets[j] * scale
            lines.extend(
                [
                    f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {self.names[j]}",
                    pad + "{",
                    f"{pad}  OFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}",
                    f"{pad}  CHANNELS {6 if moves else 3} "
                    + ("Xposition Yposition Zposition " if moves else "")
                    + " ".join(f"{axis}rotation" for axis in order),
                ]
            )
            if moves:
                place = self.root if depth == 0 else self.translations[:, j]
                columns.append(place @ turn.T * scale)
            local = turn @ self.rotations[:, j] @ turn.T
            columns.append(Rotation.from_matrix(local).as_euler(order, degrees=True))
            for child in children[j]:
                joint(child, depth + 1)
            if not children[j]:
                lines.extend(
                    [f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0 0.05 0", pad + "  }"]
                )
            lines.append(pad + "}")

        joint(0, 0)
        motion = np.concatenate(columns, axis=1)
        lines += ["MOTION", f"Frames: {len(motion)}", f"Frame Time: {1 / self.fps:.8f}"]
        lines += [" ".join(f"{v:.6f}" for v in row) for row in motion]
        path.write_text("\n".join(lines) + "\n")
        return path


def _swing(frames, count, seed, amplitude=0.5):
    """Smooth random local rotations (T, J, 3, 3)."""
    rng = np.random.default_rng(seed)
    phase, speed = rng.uniform(0, 6, (count, 3)), rng.uniform(1, 4, (count, 3))
    t = np.arange(frames)[:, None, None] / 30.0
    vectors = amplitude * np.sin(speed * t + phase)
    return Rotation.from_rotvec(vectors.reshape(-1, 3)).as_matrix().reshape(frames, count, 3, 3)


def _smpl_joints(names: dict[str, str]) -> list[tuple[str, str | None, tuple]]:
    """Our skeleton's rest offsets under a rig's names (ours -> theirs)."""
    return [
        (
            names.get(n, n),
            names.get(SMPL_22.joint_names[p], SMPL_22.joint_names[p]) if p >= 0 else None,
            tuple(SMPL_22.rest_offsets[j]),
        )
        for j, (n, p) in enumerate(zip(SMPL_22.joint_names, SMPL_22.parents, strict=False))
    ]


MIXAMO = {
    "pelvis": "mixamorig:Hips",
    "spine1": "mixamorig:Spine",
    "spine2": "mixamorig:Spine1",
    "spine3": "mixamorig:Spine2",
    "neck": "mixamorig:Neck",
    "head": "mixamorig:Head",
}
for side in ("Left", "Right"):
    low = side.lower()
    MIXAMO.update(
        {
            f"{low}_collar": f"mixamorig:{side}Shoulder",
            f"{low}_shoulder": f"mixamorig:{side}Arm",
            f"{low}_elbow": f"mixamorig:{side}ForeArm",
            f"{low}_wrist": f"mixamorig:{side}Hand",
            f"{low}_hip": f"mixamorig:{side}UpLeg",
            f"{low}_knee": f"mixamorig:{side}Leg",
            f"{low}_ankle": f"mixamorig:{side}Foot",
            f"{low}_foot": f"mixamorig:{side}ToeBase",
        }
    )


def _moving_rig(names, frames=30, fps=30.0, seed=0):
    joints = _smpl_joints(names)
    rotations = _swing(frames, len(joints), seed)
    root = np.stack(
        [
            np.linspace(0, 1.2, frames),
            0.95 + 0.03 * np.sin(np.arange(frames)),
            np.linspace(0, -0.4, frames),
        ],
        axis=-1,
    )
    return Rig(joints, rotations, root, fps)


def _error(clip, expected) -> float:
    return float(np.linalg.norm(clip.joints - expected, axis=-1).max())


def test_a_blender_style_z_up_centimetre_mixamo_file(tmp_path):
    rig = _moving_rig(MIXAMO)
    clip = read_mocap(rig.write(tmp_path / "blender.bvh", order="XYZ", scale=100, z_up=True))
    assert clip.description == "BVH, Mixamo naming, centimetres, Z up, 30 fps"
    assert _error(clip, rig.positions()) < TOLERANCE


def test_our_own_file_with_position_channels_on_every_joint(tmp_path):
    joints = _moving_rig({}).positions()
    save_bvh(tmp_path / "ours.bvh", joints, SMPL_22, 20.0, bone_translations=True)
    clip = read_mocap(tmp_path / "ours.bvh")
    assert re.fullmatch(r"BVH, (SMPL|Mixamo) naming, metres, Y up, 20 fps", clip.description)
    assert _error(clip, joints) < TOLERANCE


def test_position_channels_on_every_joint_replace_the_offsets(tmp_path):
    rig = _moving_rig(
        {n: n.replace("left_", "L_").replace("right_", "R_").title() for n in SMPL_22.joint_names}
    )  # SMPL-X style: L_Elbow
    stretch = 1 + 0.1 * np.sin(np.arange(len(rig.root)))[:, None, None]
    rig.translations = rig.offsets * stretch  # bones that stretch, as generated motion's do
    clip = read_mocap(rig.write(tmp_path / "stretchy.bvh", order="YXZ", everywhere=True))
    assert _error(clip, rig.positions()) < TOLERANCE


# -- DeepMimic --------------------------------------------------------------------------------------
DEEPMIMIC_BONES = {  # the humanoid3d: parent, offset (metres, facing +X, left is -Z)
    "chest": ("root", (0, 0.236151, 0)),
    "neck": ("chest", (0, 0.223894, 0)),
    "right_hip": ("root", (0, 0, 0.084887)),
    "right_knee": ("right_hip", (0, -0.421546, 0)),
    "right_ankle": ("right_knee", (0, -0.40987, 0)),
    "right_shoulder": ("chest", (-0.02405, 0.2435, 0.18311)),
    "right_elbow": ("right_shoulder", (0, -0.274788, 0)),
    "left_hip": ("root", (0, 0, -0.084887)),
    "left_knee": ("left_hip", (0, -0.421546, 0)),
    "left_ankle": ("left_knee", (0, -0.40987, 0)),
    "left_shoulder": ("chest", (-0.02405, 0.2435, -0.18311)),
    "left_elbow": ("left_shoulder", (0, -0.274788, 0)),
}
ORDER = [
    "chest",
    "neck",
    "right_hip",
    "right_knee",
    "right_ankle",
    "right_shoulder",
    "right_elbow",
    "left_hip",
    "left_knee",
    "left_ankle",
    "left_shoulder",
    "left_elbow",
]


def _deepmimic_sample(path, frames=12, seed=1):
    """A DeepMimic file of smooth random rotations at 30 fps; its local rotations (matrices
    by joint name) and root positions."""
    swings = _swing(frames, 1 + len(ORDER), seed, amplitude=0.4)
    rotations = {"root": swings[:, 0]}
    root = np.stack([np.linspace(0, 0.5, frames), np.full(frames, 0.85), np.zeros(frames)], -1)
    rows = [[1 / 30, *root[t]] for t in range(frames)]
    for k, name in enumerate(["root"] + ORDER):
        if name.endswith(("knee", "elbow")):
            angle = -0.3 - 0.5 * np.sin(np.arange(frames) / 4 + k)
            rotations[name] = Rotation.from_rotvec(angle[:, None] * [0, 0, 1]).as_matrix()
            values = angle[:, None]
        else:
            rotations[name] = swings[:, k]
            values = np.roll(Rotation.from_matrix(swings[:, k]).as_quat(), 1, axis=-1)  # wxyz
        for t in range(frames):
            rows[t].extend(values[t].tolist())
    path.write_text(json.dumps({"Loop": "wrap", "Frames": rows}))
    return rotations, root


def test_a_deepmimic_motion_gives_its_joints(tmp_path):
    rotations, root = _deepmimic_sample(tmp_path / "walk.txt")
    clip = read_mocap(tmp_path / "walk.txt")
    assert clip.description == "DeepMimic humanoid, metres, Y up, 30 fps"
    world, place = {"root": rotations["root"]}, {"root": root}
    for name in ORDER:
        parent, offset = DEEPMIMIC_BONES[name]
        world[name] = world[parent] @ rotations[name]
        place[name] = place[parent] + world[parent] @ np.array(offset)
    pelvis = place["root"] + rotations["root"] @ [0, 0.07, 0]  # 7 cm above the hips: SMPL's
    np.testing.assert_allclose(clip.joints[:, SMPL_22.index("pelvis")], pelvis, atol=1e-5)
    ours = {"spine2": "chest"} | {n: n for n in ORDER if n != "chest"}
    for joint, part in ours.items():
        np.testing.assert_allclose(clip.joints[:, SMPL_22.index(joint)], place[part], atol=1e-5)
    wrist = place["left_elbow"] + world["left_elbow"] @ [0, -0.258947, 0]
    np.testing.assert_allclose(clip.joints[:, SMPL_22.index("left_wrist")], wrist, atol=1e-5)


@pytest.mark.parametrize(
    "scale, unit", [(1 / 0.0254, "inches"), (0.45 / 0.0254, "CMU units (1/0.45 inch)")]
)
def test_a_cmu_style_zxy_file_of_deepmimic_motion(tmp_path, scale, unit):
    """CMU names and extra joints (zero-offset LowerBack and Neck, LHipJoint, fingers),
    Zrotation Xrotation Yrotation channels, inches or CMU's own unit, 30 fps: the DeepMimic
    motion as CMU's converter would write it, read back to the DeepMimic file's own joints."""
    rotations, root = _deepmimic_sample(tmp_path / "dance.txt", frames=16)
    source = read_mocap(tmp_path / "dance.txt")
    cmu_rig(rotations, root, 30.0).write(tmp_path / "cmu.bvh", order="ZXY", scale=scale)
    clip = read_mocap(tmp_path / "cmu.bvh")
    assert clip.description == f"BVH, CMU naming, {unit}, Y up, 30 fps"
    assert _error(clip, source.joints) < TOLERANCE


def cmu_rig(rotations: dict[str, np.ndarray], root: np.ndarray, fps: float) -> Rig:
    """DeepMimic motion (local rotation matrices by joint, root positions) on a CMU-named
    skeleton whose joints sit where the DeepMimic import puts ours."""
    rest = {
        name: np.array(offset, dtype=np.float64) for name, (_, offset) in DEEPMIMIC_BONES.items()
    }
    joints, moves = [("Hips", None, (0, 0, 0))], {"Hips": rotations["root"]}
    pelvis = np.array([0, 0.07, 0])  # the DeepMimic fill: the pelvis 7 cm above its root
    for side, z in (("Left", -1), ("Right", 1)):
        low = side.lower()
        collar = np.array([-0.01, 0.215, 0.075 * z])  # the DeepMimic fill, CMU's midpoint rule
        inner = 2 * collar - rest[f"{low}_shoulder"]
        joints += [
            (f"{side[0]}HipJoint", "Hips", -pelvis),
            (f"{side}UpLeg", f"{side[0]}HipJoint", rest[f"{low}_hip"]),
            (f"{side}Leg", f"{side}UpLeg", rest[f"{low}_knee"]),
            (f"{side}Foot", f"{side}Leg", rest[f"{low}_ankle"]),
            (f"{side}ToeBase", f"{side}Foot", (0.12, -0.035, 0)),
            (f"{side}Shoulder", "Spine1", inner),
            (f"{side}Arm", f"{side}Shoulder", rest[f"{low}_shoulder"] - inner),
            (f"{side}ForeArm", f"{side}Arm", rest[f"{low}_elbow"]),
            (f"{side}Hand", f"{side}ForeArm", (0, -0.258947, 0)),
            (f"{side}HandIndex1", f"{side}Hand", (0, -0.08, 0)),
        ]
        moves |= {
            f"{side}UpLeg": rotations[f"{low}_hip"],
            f"{side}Leg": rotations[f"{low}_knee"],
            f"{side}Foot": rotations[f"{low}_ankle"],
            f"{side}Arm": rotations[f"{low}_shoulder"],
            f"{side}ForeArm": rotations[f"{low}_elbow"],
        }
    spine = (0.236151 - 0.07) / 2  # the DeepMimic fill: spine1 halfway to the chest joint
    joints += [
        ("LowerBack", "Hips", (0, 0, 0)),
        ("Spine", "LowerBack", (0, spine, 0)),
        ("Spine1", "Spine", (0, spine, 0)),
        ("Neck", "Spine1", (0, 0, 0)),
        ("Neck1", "Neck", rest["neck"]),
        ("Head", "Neck1", (0.02, 0.10, 0)),
    ]
    moves |= {"Spine1": rotations["chest"], "Neck1": rotations["neck"]}
    joints = sorted(joints, key=lambda j: _depth(j, joints))  # parents first
    frames = len(root)
    local = np.stack(
        [moves.get(name, np.tile(np.eye(3), (frames, 1, 1))) for name, _, _ in joints], axis=1
    )
    return Rig(joints, local, root + rotations["root"] @ pelvis, fps)


def _depth(joint, joints):
    parents = {name: parent for name, parent, _ in joints}
    depth, name = 0, joint[0]
    while parents[name]:
        depth, name = depth + 1, parents[name]
    return depth


# -- mapping files, frame rates, errors -----------------------------------------------------------
def test_a_mapping_file_maps_other_names(tmp_path):
    names = {n: f"Bip01 {n.replace('_', ' ').title()}" for n in SMPL_22.joint_names}
    rig = _moving_rig(names)
    path = rig.write(tmp_path / "biped.bvh")
    with pytest.raises(
        ValueError, match=r"biped.bvh: cannot map .* lacks pelvis, left_hip, .*--map"
    ):
        read_mocap(path)
    table = dict(names, spine3=[names["spine2"], names["neck"], 0.5])
    (tmp_path / "map.json").write_text(json.dumps(table))
    clip = read_mocap(path, read_mapping(tmp_path / "map.json"))
    expected = rig.positions()
    spine = [SMPL_22.index(n) for n in ("spine2", "spine3", "neck")]
    expected[:, spine[1]] = 0.5 * (expected[:, spine[0]] + expected[:, spine[2]])
    assert clip.description.startswith("BVH, the mapping file naming")
    assert _error(clip, expected) < TOLERANCE


@pytest.mark.parametrize(
    "table, message",
    [
        ("[1, 2]", "must be a JSON object"),
        ('{"pelvis": 3}', "pelvis: expected a joint name"),
        ('{"hips": "Hips"}', "unknown joint.* hips"),
        ("{", "not valid JSON"),
    ],
)
def test_a_bad_mapping_file_is_one_clear_error(tmp_path, table, message):
    (tmp_path / "map.json").write_text(table)
    with pytest.raises(ValueError, match=message):
        read_mapping(tmp_path / "map.json")


def test_a_clip_at_another_frame_rate_is_resampled_to_20_fps(tmp_path):
    rig = _moving_rig(MIXAMO, frames=61, fps=60.0)
    motion = Motion.from_file(rig.write(tmp_path / "fast.bvh", scale=100))
    assert motion.fps == 20 and len(motion.joints) == 21  # every frame
    assert len(motion.features) == 20  # 21 frames: 20 feature rows, as HumanML3D's
    clip = read_mocap(tmp_path / "fast.bvh")
    every_third = rig.positions()[::3]
    assert np.abs(resample(clip.joints, 60.0, 20.0) - every_third).max() < TOLERANCE


@pytest.mark.parametrize(
    "text, message",
    [
        ("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0", "not a readable BVH"),
        (
            "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Wrotation\n}\n"
            "MOTION\nFrames: 1\nFrame Time: 0.1\n0 0 0\n",
            "unknown channel",
        ),
        (
            "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n}\n"
            "MOTION\nFrames: 2\nFrame Time: 0.1\n0 0 0\n",
            "3 motion values, expected 2 frames x 3",
        ),
        (
            "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n}\n"
            "MOTION\nFrames: 1\nFrame Time: 0.1\n0 0 0\n",
            "cannot map its skeleton onto the 22 joints: .* lacks",
        ),
        ('{"Frames": [[0.1, 1, 2]]}', "at least 2 rows of 44 numbers"),
        ('{"Frames": [[0.1, 1, 2], "x"]}', "not a DeepMimic motion file"),
        ("hello", "not a BVH file"),
    ],
)
def test_an_unreadable_or_unmappable_file_is_one_clear_error(tmp_path, text, message):
    (tmp_path / "bad.bvh").write_text(text)
    with pytest.raises(ValueError, match=message) as error:
        read_mocap(tmp_path / "bad.bvh")
    assert "\n" not in str(error.value) and str(error.value).startswith(str(tmp_path))


def test_a_stream_continues_from_an_imported_clip(tmp_path):
    _deepmimic_sample(tmp_path / "walk.txt", frames=40)
    walk = Motion.from_file(tmp_path / "walk.txt")
    generator = MotionGenerator.load()
    stream = generator.stream("a person jogs forward", seed=0)
    stream.continue_from(walk)
    frames = np.stack(list(stream.frames(20)))
    assert frames.shape == (20, 22, 3) and np.all(np.isfinite(frames))


def test_a_bvh_we_wrote_comes_back_with_every_frame(tmp_path):
    """81 frames written, 81 read (the last frame was dropped with the features' last row)."""
    motion = MotionGenerator.load().generate("a person walks forward.", seconds=4.05, seed=0)
    assert len(motion.joints) == 81
    back = Motion.from_file(motion.save_bvh(tmp_path / "walk.bvh"))
    assert back.joints.shape == (81, 22, 3) and back.features.shape == (80, 263)
    # our rigid character, put on the floor facing +Z as the generated clip already is
    error = np.linalg.norm(back.joints - motion.joints, axis=-1)
    assert error.mean() < 0.03, error.mean()
