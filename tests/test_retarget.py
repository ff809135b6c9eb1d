"""Retargeting motion capture to the humanoid: round trips, rest-pose alignment, real CMU data."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import characters, kinematics, motion
from jaxsim.motion import retarget as rt
from jaxsim.motion.skeleton import Skeleton, SkeletonClip, axis_rotation, model_skeleton


@pytest.fixture(scope="module")
def humanoid():
    return characters.humanoid(dtype=jnp.float64)


def canonical(poses, model):
    """Poses with every quaternion's w made non-negative (q and −q are one rotation)."""
    poses = np.array(poses, float)
    topo = model.topology
    for start in [3] + list(topo.q_offsets[topo.links_of_type("spherical")]):
        poses[:, start:start + 4] *= np.where(poses[:, start:start + 1] < 0, -1.0, 1.0)
    return poses


def test_own_clip_survives_bvh_export_import_and_retargeting(data_dir, humanoid, tmp_path):
    clip = motion.load_motion(data_dir / "deepmimic/motions/humanoid3d_cartwheel.txt", humanoid)
    exported = motion.from_model_clip(humanoid, clip, frame_rate=60.0)
    motion.save_bvh(tmp_path / "cartwheel.bvh", exported)
    imported = motion.load_bvh(tmp_path / "cartwheel.bvh")
    result = rt.retarget(imported, humanoid, rt.identity_retargeting(humanoid))
    times = np.arange(exported.n_frames) / 60.0
    expected = jax.vmap(lambda t: motion.sample_pose(clip, t))(jnp.asarray(times))
    assert result.scale == pytest.approx(1.0)
    np.testing.assert_allclose(canonical(result.clip.poses, humanoid),
                               canonical(expected, humanoid), atol=1e-6)
    for residue in result.residue_degrees.values():
        assert residue.max() < 1e-4


def t_pose_source(model, scale=2.0):
    """The humanoid's skeleton, twice as large, facing +Z (as CMU does) and standing in a
    T-pose (arms out to the sides) at rest, with identity rest frames (as BVH has)."""
    skel = model_skeleton(model)
    turn = axis_rotation("Y", np.radians(-90.0))          # our +X (forward) → +Z
    positions, tips = skel.rest_positions.copy(), skel.rest_tips.copy()
    for side, sign in (("right", 1.0), ("left", -1.0)):
        shoulder = skel.index(f"{side}_shoulder")
        # Lift the arm about the forward axis (X) until it points along ±Z (sideways).
        lift = axis_rotation("X", np.radians(sign * -90.0))
        for joint in ("shoulder", "elbow", "wrist"):
            bone = skel.index(f"{side}_{joint}")
            positions[bone] = positions[shoulder] + lift @ (positions[bone] - positions[shoulder])
            tips[bone] = positions[shoulder] + lift @ (tips[bone] - positions[shoulder])
    n = skel.n_bones
    return Skeleton(skel.names, skel.parents, np.broadcast_to(np.eye(3), (n, 3, 3)),
                    scale * positions @ turn.T, scale * tips @ turn.T)


def test_rest_alignment_facing_and_leg_scale(humanoid):
    source = t_pose_source(humanoid)
    root = np.array([[0.4, 1.8, -1.0]] * 2)
    clip = SkeletonClip(source, 1 / 30, root, np.broadcast_to(np.eye(3), (2, source.n_bones, 3, 3)))
    rule = rt.identity_retargeting(humanoid)
    rule = rt.Retargeting(rule.joints, rule.leg, rule.model_leg, facing_yaw_degrees=90.0)
    result = rt.retarget(clip, humanoid, rule)
    assert result.scale == pytest.approx(0.5)
    q = np.asarray(result.clip.poses[0])
    # The root: position turned from the source's facing to ours and halved; no rotation.
    np.testing.assert_allclose(q[:3], 0.5 * axis_rotation("Y", np.radians(90.0)) @ root[0],
                               atol=1e-12)
    np.testing.assert_allclose(np.abs(q[3:7]), [1, 0, 0, 0], atol=1e-12)
    # The humanoid stands in the source's T-pose: hands level with the shoulders, out to the side.
    _, pos = kinematics.forward_kinematics(humanoid, jnp.asarray(q))
    names = humanoid.topology.names
    for side, sign in (("right", 1.0), ("left", -1.0)):
        shoulder, wrist = (np.asarray(pos[names.index(f"{side}_{j}")]) for j in ("shoulder",
                                                                                  "wrist"))
        arm = wrist - shoulder
        assert arm[1] == pytest.approx(0.0, abs=1e-9)
        assert sign * arm[2] == pytest.approx(np.linalg.norm(arm), rel=1e-9)
    # Everything else keeps its rest pose.
    for name in ("chest", "neck", "right_hip", "left_hip", "right_knee", "right_ankle"):
        start = humanoid.topology.q_offsets[names.index(name)]
        kind = humanoid.topology.joint_types[names.index(name)]
        expected = [1, 0, 0, 0] if kind == "spherical" else [0]
        np.testing.assert_allclose(np.abs(q[start:start + len(expected)]), expected, atol=1e-9)


@pytest.fixture(scope="module")
def cmu_walk(data_dir, humanoid):
    skeleton = motion.load_asf(data_dir / "cmu/02/02.asf")
    source = motion.load_amc(data_dir / "cmu/02/02_01.amc", skeleton)
    return source, rt.retarget(source, humanoid, rt.CMU_ASF)


def test_cmu_knees_and_elbows_become_exact_hinges(cmu_walk):
    # CMU's tibia and radius have one DoF each; once the hinge axes are lined up, nothing is
    # left off our knee and elbow axes (misaligned, the elbows were off by 14-20° on average).
    _, result = cmu_walk
    assert set(result.residue_degrees) == {"right_knee", "left_knee", "right_elbow",
                                           "left_elbow"}
    for name, residue in result.residue_degrees.items():
        assert residue.max() < 0.05, name


def test_cmu_walk_keeps_the_feet_on_the_ground_and_moves_forward(cmu_walk, humanoid):
    source, result = cmu_walk
    assert 0.85 < result.scale < 0.95       # CMU's root stands ~10 cm higher above its ankles
    poses = jnp.asarray(result.clip.poses)
    rot, pos = jax.vmap(lambda q: kinematics.forward_kinematics(humanoid, q))(poses)
    ankles = np.asarray(pos[:, [humanoid.topology.link_index(n)
                                for n in ("right_ankle", "left_ankle")], 1])
    lowest_ankle = ankles.min(axis=1)
    # The ankle joint sits 5 cm above the sole: the lower ankle stays near that height.
    assert 0.03 < np.median(lowest_ankle) < 0.1 and lowest_ankle.max() < 0.15
    # Our root follows the source's, turned to face +X and scaled.
    travel = np.asarray(poses[-1, :3] - poses[0, :3])
    source_travel = (source.root_positions[-1] - source.root_positions[0]) * result.scale
    np.testing.assert_allclose(travel, rt.CMU_ASF.facing @ source_travel, atol=1e-5)
    # The walk heads along its direction, and the root quaternion turns the body into it.
    forward = np.asarray(rot[len(poses) // 2, 0])[:, 0]
    heading = travel / np.linalg.norm(travel)
    assert forward @ heading > 0.8


def test_retargeting_names_what_is_missing(humanoid, cmu_walk):
    source, _ = cmu_walk
    with pytest.raises(ValueError, match="tail"):
        rt.retarget(source, humanoid, rt.Retargeting({"tail": rt.JointMap("root")},
                                                     leg=rt.CMU_ASF.leg))
    broken = dict(rt.CMU_ASF.joints, chest=rt.JointMap("spine9"))
    with pytest.raises(KeyError, match="spine9"):
        rt.retarget(source, humanoid, rt.Retargeting(broken, leg=rt.CMU_ASF.leg,
                                                     facing_yaw_degrees=90.0))
