"""Our GLB read by a third-party glTF library (pygltflib, a dev dependency): a well-formed
skinned, animated asset whose joints, posed by its own animation, are where our rig puts them."""

import numpy as np
import pytest

from mogo import MotionGenerator
from mogo.motion import rig
from mogo.motion.bvh import NAMINGS
from mogo.motion.glb import save_glb
from mogo.motion.quaternion import qto_matrix
from mogo.motion.skeleton import SMPL_22

pygltflib = pytest.importorskip("pygltflib")
WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}
DTYPE = {5126: np.float32, 5123: np.uint16, 5125: np.uint32}


def _data(gltf, index: int) -> np.ndarray:
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    raw = gltf.binary_blob()[view.byteOffset : view.byteOffset + view.byteLength]
    return np.frombuffer(raw, DTYPE[accessor.componentType]).reshape(
        accessor.count, WIDTH[accessor.type]
    )


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    motion = MotionGenerator.load().generate(
        "a person spins around in a circle.", seconds=3.0, seed=0
    )
    path = tmp_path_factory.mktemp("glb") / "spin.glb"
    motion.save_glb(path)
    return motion, pygltflib.GLTF2().load(str(path))


def test_the_file_is_a_skinned_mesh_with_one_animation(written):
    motion, gltf = written
    assert gltf.asset.version == "2.0" and len(gltf.skins) == 1 and len(gltf.animations) == 1
    skin = gltf.skins[0]
    assert [gltf.nodes[j].name for j in skin.joints] == list(NAMINGS["mixamo"])
    primitive = gltf.meshes[0].primitives[0]
    positions = _data(gltf, primitive.attributes.POSITION)
    np.testing.assert_allclose(
        positions.min(0), gltf.accessors[primitive.attributes.POSITION].min, atol=1e-6
    )
    joints, weights = (
        _data(gltf, primitive.attributes.JOINTS_0),
        _data(gltf, primitive.attributes.WEIGHTS_0),
    )
    assert joints.max() < 22 and np.allclose(weights.sum(1), 1.0)
    assert _data(gltf, primitive.indices).max() < len(positions)
    assert positions[:, 1].min() > -0.06 and positions[:, 1].max() < 1.9  # stands on the floor
    times = _data(gltf, gltf.animations[0].samplers[0].input)[:, 0]
    np.testing.assert_allclose(times, np.arange(len(motion.joints)) / 20.0, atol=1e-6)


def test_the_animation_poses_the_joints_where_our_rig_puts_them(written):
    """Forward kinematics of the nodes under the file's own animation (rotations and the
    root's translation) against mogo.motion.rig; within a few cm of the generated joints."""
    motion, gltf = written
    frames = len(motion.joints)
    local = np.tile(np.eye(3), (frames, 22, 1, 1))
    translation = np.array([gltf.nodes[j].translation for j in range(22)])[None].repeat(frames, 0)
    animation = gltf.animations[0]
    for channel in animation.channels:
        values = _data(gltf, animation.samplers[channel.sampler].output).astype(np.float64)
        if channel.target.path == "rotation":
            local[:, channel.target.node] = qto_matrix(values[:, [3, 0, 1, 2]])
        else:
            translation[:, channel.target.node] = values
    world_rotation, world = np.zeros_like(local), np.zeros((frames, 22, 3))
    for joint in rig.depth_first(SMPL_22):
        parent = SMPL_22.parents[joint]
        if parent < 0:
            world_rotation[:, joint], world[:, joint] = local[:, joint], translation[:, joint]
        else:
            world_rotation[:, joint] = world_rotation[:, parent] @ local[:, joint]
            world[:, joint] = world[:, parent] + np.einsum(
                "tij,tj->ti", world_rotation[:, parent], translation[:, joint]
            )
    joints = motion.joints.astype(np.float64)
    np.testing.assert_allclose(world, rig.posed_joints(joints, SMPL_22), atol=1e-5)
    assert np.linalg.norm(world - joints, axis=-1).mean() < 0.02
    rotations = _data(gltf, animation.samplers[0].output)
    assert np.all(np.sum(rotations[1:] * rotations[:-1], axis=-1) > 0)  # one hemisphere


def test_bad_input_is_refused(tmp_path):
    with pytest.raises(ValueError, match="must be"):
        save_glb(tmp_path / "a.glb", np.zeros((5, 21, 3)), SMPL_22, 20.0, NAMINGS["mixamo"])
    assert not (tmp_path / "a.glb").exists()
