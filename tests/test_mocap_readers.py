"""Motion capture readers: ASF/AMC and BVH, small hand-made files and the CMU reference data,
and the BVH writer's round trip."""

import re

import numpy as np
import pytest

from jaxsim import motion
from jaxsim.motion import Skeleton, SkeletonClip, world_deltas, world_pose

INCH = 0.0254
CMU_BVH_SCALE = INCH / 0.45          # cgspeed's BVH lengths are in the ASF's units (inches × 0.45)


def rx(degrees):
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(degrees):
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(degrees):
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def write_crlf(path, text):
    path.write_bytes(text.replace("\n", "\r\n").encode())
    return path


SMALL_ASF = """\
# a three-bone arm and a spine, in half inches
:version 1.10
:name test
:units
  mass 1.0
  length 0.5
  angle deg
:documentation
  free text: begin end
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name upper
     direction 1 0 0
     length 10
     axis 0 0 90  XYZ
    dof rx
    limits (-180.0 180.0)
  end
  begin
     id 2
     name lower
     direction 1 0 0
     length 5
     axis 0 0 0 XYZ
    dof rx ry
    limits (-180.0 180.0)
           (-180.0 180.0)
  end
  begin
     id 3
     name hand
     direction 0 1 0
     length 2
     axis 0 0 0 XYZ
    dof rz
    limits (-90.0 90.0)
  end
  begin
     id 4
     name spine
     direction 0 1 0
     length 4
     axis 0 0 0 XYZ
  end
:hierarchy
  begin
    root upper spine
    upper lower
    lower hand
  end
"""
SMALL_UNIT = INCH / 0.5


def small_amc(frames):
    """An AMC of SMALL_ASF: frames as (root 6, upper 1, lower 2, hand 1) values."""
    lines = ["#!OML:ASF test.asf", ":FULLY-SPECIFIED", ":DEGREES"]
    for k, (root, upper, lower, hand) in enumerate(frames, 1):
        lines += [str(k), "root " + " ".join(map(str, root)), f"upper {upper}",
                  f"lower {lower[0]} {lower[1]}", f"hand {hand}"]
    return "\n".join(lines) + "\n"


@pytest.fixture
def small_asf_clip(tmp_path):
    skeleton = motion.load_asf(write_crlf(tmp_path / "small.asf", SMALL_ASF))
    frames = [((1, 2, 3, 0, 0, 0), 0, (0, 0), 0),
              ((0, 0, 0, 0, 0, 0), 90, (0, 0), 0),
              ((0, 0, 0, 0, 0, 0), 0, (90, 90), 0),
              ((0, 0, 0, 0, 0, 0), 0, (0, 0), 90),
              ((1, 0, 0, 0, 90, 0), 0, (0, 0), 0)]
    return motion.load_amc(write_crlf(tmp_path / "small.amc", small_amc(frames)), skeleton)


def test_small_asf_rest_pose_in_metres(small_asf_clip):
    skeleton = small_asf_clip.skeleton
    assert skeleton.names == ("root", "upper", "lower", "hand", "spine")   # depth-first
    assert skeleton.parents == (-1, 0, 1, 2, 0)
    u = SMALL_UNIT
    np.testing.assert_allclose(skeleton.rest_positions,
                               [[0, 0, 0], [0, 0, 0], [10 * u, 0, 0], [15 * u, 0, 0], [0, 0, 0]],
                               atol=1e-12)
    np.testing.assert_allclose(skeleton.rest_tips,
                               [[0, 0, 0], [10 * u, 0, 0], [15 * u, 0, 0], [15 * u, 2 * u, 0],
                                [0, 4 * u, 0]], atol=1e-12)
    np.testing.assert_allclose(skeleton.rest_frames[1], rz(90), atol=1e-12)   # axis 0 0 90


def test_small_amc_moves_the_tips_where_the_acclaim_formula_puts_them(small_asf_clip):
    clip, u = small_asf_clip, SMALL_UNIT
    assert clip.n_frames == 5 and clip.frame_time == pytest.approx(1 / 120)
    _, _, tips = world_pose(clip)
    expected = {
        # frame 1: the root translated by (1, 2, 3) units, the rest pose otherwise
        0: [[u, 2 * u, 3 * u], [11 * u, 2 * u, 3 * u], [16 * u, 2 * u, 3 * u],
            [16 * u, 4 * u, 3 * u], [u, 6 * u, 3 * u]],
        # frame 2: upper's rx 90 about its axis x' = Rz(90) x = y, so D = Ry(90): x → −z
        1: [[0, 0, 0], [0, 0, -10 * u], [0, 0, -15 * u], [0, 2 * u, -15 * u], [0, 4 * u, 0]],
        # frame 3: lower's rx 90 then ry 90: M = Ry(90) Rx(90); x → −z, y → z → x
        2: [[0, 0, 0], [10 * u, 0, 0], [10 * u, 0, -5 * u], [12 * u, 0, -5 * u], [0, 4 * u, 0]],
        # frame 4: hand's rz 90 (axis 0 0 0): y → −x
        3: [[0, 0, 0], [10 * u, 0, 0], [15 * u, 0, 0], [13 * u, 0, 0], [0, 4 * u, 0]],
        # frame 5: the root at x = 1 unit turned by RY 90: x → −z
        4: [[u, 0, 0], [u, 0, -10 * u], [u, 0, -15 * u], [u, 2 * u, -15 * u], [u, 4 * u, 0]],
    }
    for frame, tip in expected.items():
        np.testing.assert_allclose(tips[frame], tip, atol=1e-12, err_msg=f"frame {frame}")


SMALL_BVH = """\
HIERARCHY
ROOT hips
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT arm
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
  JOINT leg
  {
    OFFSET 0 -4 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0 -6 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.04
0 0 0 0 0 0 0 0 0 0 0 0
1 1 1 90 0 0 0 90 90 0 0 90
"""


def test_small_bvh_rest_pose_and_a_hand_computed_pose(tmp_path):
    clip = motion.load_bvh(write_crlf(tmp_path / "small.bvh", SMALL_BVH), length_scale=0.1)
    skeleton = clip.skeleton
    assert skeleton.names == ("hips", "arm", "leg") and skeleton.parents == (-1, 0, 0)
    assert clip.n_frames == 2 and clip.frame_time == 0.04
    np.testing.assert_allclose(skeleton.rest_frames, np.tile(np.eye(3), (3, 1, 1)))
    np.testing.assert_allclose(skeleton.rest_positions, [[.1, .2, .3], [1.1, .2, .3],
                                                         [.1, -.2, .3]], atol=1e-12)
    # the hips end at the mean of their children's starts, the others at their End Sites
    np.testing.assert_allclose(skeleton.rest_tips, [[.6, 0, .3], [1.1, .7, .3], [.1, -.8, .3]],
                               atol=1e-12)
    np.testing.assert_allclose(clip.root_positions, [[.1, .2, .3], [.2, .3, .4]], atol=1e-12)
    # frame 2: hips Rz(90); arm Rz(0) Rx(90) Ry(90) (first listed outermost): its End Site
    # (0 5 0) → Ry: (0 5 0) → Rx: (0 0 5) → hips' Rz: (0 0 5); leg Rz(90) after the hips' Rz(90)
    np.testing.assert_allclose(clip.rotations[1, 1], rx(90) @ ry(90), atol=1e-12)
    _, starts, tips = world_pose(clip)
    np.testing.assert_allclose(starts[1], [[.2, .3, .4], [.2, 1.3, .4], [.6, .3, .4]], atol=1e-12)
    np.testing.assert_allclose(tips[1, 1:], [[.2, 1.3, .9], [.6, .9, .4]], atol=1e-12)


def frame_numbers(path):
    return len(re.findall(r"^\d+\s*$", path.read_text(), flags=re.MULTILINE))


def test_cmu_asf_rest_skeleton_is_a_plausible_adult(data_dir):
    skeleton = motion.load_asf(data_dir / "cmu/01/01.asf")
    assert skeleton.n_bones == 31 and skeleton.names[0] == "root"
    tibia = skeleton.index("ltibia")
    length = np.linalg.norm(skeleton.rest_tips[tibia] - skeleton.rest_positions[tibia])
    assert length == pytest.approx(7.49137 / 0.45 * INCH)
    leg = (skeleton.rest_positions[skeleton.index("lfoot")]
           - skeleton.rest_positions[skeleton.index("lfemur")])
    assert 0.75 < np.linalg.norm(leg) < 0.95
    for b, p in enumerate(skeleton.parents[1:], 1):   # bones start where their parents end
        np.testing.assert_allclose(skeleton.rest_positions[b], skeleton.rest_tips[p])


def test_cmu_amc_first_frame_values(data_dir):
    skeleton = motion.load_asf(data_dir / "cmu/01/01.asf")
    path = data_dir / "cmu/01/01_01.amc"
    clip = motion.load_amc(path, skeleton)
    assert clip.n_frames == frame_numbers(path) and clip.frame_time == pytest.approx(1 / 120)
    # frame 1: "root 9.37216 17.8693 -17.3198 -2.01677 -7.59696 -3.23164", "ltibia 20.088"
    np.testing.assert_allclose(clip.root_positions[0],
                               np.array([9.37216, 17.8693, -17.3198]) / 0.45 * INCH)
    np.testing.assert_allclose(clip.rotations[0, skeleton.index("ltibia")], rx(20.088),
                               atol=1e-12)
    np.testing.assert_allclose(clip.rotations[0, 0], rz(-3.23164) @ ry(-7.59696) @ rx(-2.01677),
                               atol=1e-12)


def test_every_cmu_amc_loads_and_a_walk_keeps_a_foot_on_the_ground(data_dir):
    total = 0
    for subject in ("01", "02", "03"):
        skeleton = motion.load_asf(data_dir / f"cmu/{subject}/{subject}.asf")
        for path in sorted((data_dir / f"cmu/{subject}").glob("*.amc")):
            clip = motion.load_amc(path, skeleton)
            assert clip.n_frames == frame_numbers(path), path.name
            total += clip.n_frames
            if path.name == "02_01.amc":
                walk = clip
    assert total == 77_754
    _, _, tips = world_pose(walk)
    lowest = tips[:, :, 1].min(axis=1)
    assert -0.05 < lowest.min() and lowest.max() < 0.1


def test_cmu_bvh_frames_channel_order_and_height(data_dir):
    path = data_dir / "cmu-bvh/131_01.bvh"
    clip = motion.load_bvh(path, length_scale=CMU_BVH_SCALE)
    assert clip.n_frames == 994 and clip.frame_time == pytest.approx(1 / 120, rel=1e-5)
    text = path.read_text()
    hierarchy, motion_text = text.split("MOTION")
    before = hierarchy.split("JOINT LeftShoulder")[0]
    column = sum(int(n) for n in re.findall(r"CHANNELS (\d+)", before))
    assert re.search(r"JOINT LeftShoulder\s*\{\s*OFFSET[^\n]*\n\s*CHANNELS 3 Zrotation "
                     r"Xrotation Yrotation", hierarchy)
    z, x, y = map(float, motion_text.splitlines()[3].split()[column:column + 3])
    np.testing.assert_allclose(clip.rotations[0, clip.skeleton.index("LeftShoulder")],
                               rz(z) @ rx(x) @ ry(y), atol=1e-12)

    skeleton = clip.skeleton
    hip, ankle = (skeleton.rest_positions[skeleton.index(n)] for n in ("LeftHip", "LeftAnkle"))
    assert 0.75 < np.linalg.norm(ankle - hip) < 0.95
    assert 0.85 < clip.root_positions[0, 1] < 1.05
    _, _, tips = world_pose(clip)
    assert -0.05 < tips[0, :, 1].min() < 0.1


def random_clip(seed, n_bones=7, n_frames=6):
    """A skeleton with random rest frames, a random tree and random motion; a non-leaf bone's
    tip is the mean of its children's starts (all that BVH can store)."""
    rng = np.random.default_rng(seed)
    parents = (-1,) + tuple(int(rng.integers(0, b)) for b in range(1, n_bones))
    rest_frames = np.linalg.qr(rng.normal(size=(n_bones, 3, 3)))[0]
    rest_frames[:, :, 0] *= np.sign(np.linalg.det(rest_frames))[:, None]
    starts = rng.normal(size=(n_bones, 3))
    tips = starts + rng.normal(size=(n_bones, 3))
    for b in range(n_bones):
        children = [c for c, p in enumerate(parents) if p == b]
        if children:
            tips[b] = starts[children].mean(axis=0)
    skeleton = Skeleton(tuple(f"bone{b}" for b in range(n_bones)), parents, rest_frames,
                        starts, tips)
    rotations = np.linalg.qr(rng.normal(size=(n_frames, n_bones, 3, 3)))[0]
    rotations[..., 0] *= np.sign(np.linalg.det(rotations))[..., None]
    # gimbal lock: bone 2's rotation relative to its parent is Rz(a) Ry(±90°) Rx(c) in frames 0, 1
    for frame, pitch in ((0, 90), (1, -90)):
        relative = rz(rng.uniform(-180, 180)) @ ry(pitch) @ rx(rng.uniform(-180, 180))
        rotations[frame, 2] = rest_frames[2].T @ relative @ rest_frames[2]
    return SkeletonClip(skeleton, 1 / 30, rng.normal(size=(n_frames, 3)), rotations)


@pytest.mark.parametrize("seed", [0, 1])
def test_bvh_round_trip_keeps_the_world_pose(tmp_path, seed):
    clip = random_clip(seed)
    path = tmp_path / "clip.bvh"
    motion.save_bvh(path, clip)
    back = motion.load_bvh(path)
    assert back.n_frames == clip.n_frames and back.frame_time == clip.frame_time
    assert [p.name for p in tmp_path.iterdir()] == ["clip.bvh"]
    order = [back.skeleton.index(name) for name in clip.skeleton.names]   # depth-first there
    _, starts, tips = world_pose(clip)
    _, back_starts, back_tips = world_pose(back)
    np.testing.assert_allclose(back_starts[:, order], starts, atol=1e-6)
    np.testing.assert_allclose(back_tips[:, order], tips, atol=1e-6)
    np.testing.assert_allclose(world_deltas(back)[:, order], world_deltas(clip), atol=1e-6)


def test_cmu_walk_survives_a_bvh_round_trip(data_dir, tmp_path):
    skeleton = motion.load_asf(data_dir / "cmu/02/02.asf")
    clip = motion.load_amc(data_dir / "cmu/02/02_01.amc", skeleton)
    motion.save_bvh(tmp_path / "walk.bvh", clip)
    back = motion.load_bvh(tmp_path / "walk.bvh")
    assert back.skeleton.names == skeleton.names      # the ASF's order is depth-first already
    for ours, theirs in zip(world_pose(clip)[1:], world_pose(back)[1:]):
        np.testing.assert_allclose(theirs, ours, atol=1e-6)
    np.testing.assert_allclose(world_deltas(back), world_deltas(clip), atol=1e-6)


@pytest.mark.parametrize("edit, line, reason", [
    (("lower 8 9", "elbow 8 9"), 12, "bone 'elbow' is not in the skeleton"),
    (("lower 8 9", "lower 8"), 12, "expected 2 values, got 1"),
    (("lower 8 9", "lower 8 x"), 12, "not a number"),
    (("lower 8 9", "upper 8"), 12, "bone 'upper' appears twice in frame 2"),
    (("lower 8 9\n", ""), 9, "frame 2 has no values for bone 'lower'"),
    (("\n2\n", "\n3\n"), 9, "frame 3 follows frame 1"),
    (("lower 8 9", "lower 8 nan"), 12, "not a finite number"),
    (("hand 10", "hand -inf"), 13, "not a finite number"),
])
def test_malformed_amc_names_file_and_line(tmp_path, edit, line, reason):
    skeleton = motion.load_asf(write_crlf(tmp_path / "small.asf", SMALL_ASF))
    text = small_amc([((0,) * 6, 0, (0, 0), 0), ((1, 2, 3, 4, 5, 6), 7, (8, 9), 10)])
    path = write_crlf(tmp_path / "bad.amc", text.replace(*edit))
    with pytest.raises(motion.MotionFileError) as error:
        motion.load_amc(path, skeleton)
    assert str(error.value).startswith(f"{path}:{line}: ") and reason in str(error.value)


@pytest.mark.parametrize("edit, line, reason", [
    (("0 0 0 0 0 0 0 0 0 0 0 0\n", "0 0 0 0 0 0 0 0 0 0 0\n"), 28, "expected 12 values, got 11"),
    (("Frame Time: 0.04\n", ""), 27, "Frame Time:"),
    (("JOINT leg", "JOINT"), 17, "expected '{'"),
    (("CHANNELS 3 Xrotation", "CHANNELS 3 Xposition"), 18, "'Xposition'"),
    (("Frames: 2\nFrame Time: 0.04\n0 0 0 0 0 0 0 0 0 0 0 0\n1 1 1 90 0 0 0 90 90 0 0 90\n",
      "Frames: 0\nFrame Time: 0.04\n"), 26, "frame count must be a whole number ≥ 1"),
    (("Frames: 2", "Frames: nan"), 26, "not a finite number"),
    (("Frames: 2", "Frames: inf"), 26, "not a finite number"),
    (("Frame Time: 0.04", "Frame Time: nan"), 27, "not a finite number"),
    (("Frame Time: 0.04", "Frame Time: inf"), 27, "not a finite number"),
    (("1 1 1 90 0 0", "1 1 NaN 90 0 0"), 29, "not a finite number"),
    (("OFFSET 1 2 3", "OFFSET 1 inf 3"), 4, "not a finite number"),
])
def test_malformed_bvh_names_file_and_line(tmp_path, edit, line, reason):
    path = write_crlf(tmp_path / "bad.bvh", SMALL_BVH.replace(*edit))
    with pytest.raises(motion.MotionFileError) as error:
        motion.load_bvh(path)
    assert str(error.value).startswith(f"{path}:{line}: ") and reason in str(error.value)


def test_an_amc_without_frames_is_an_error(tmp_path):
    skeleton = motion.load_asf(write_crlf(tmp_path / "small.asf", SMALL_ASF))
    path = write_crlf(tmp_path / "empty.amc", ":FULLY-SPECIFIED\n:DEGREES\n")
    with pytest.raises(motion.MotionFileError, match=f"{path}:1: the file holds no frames"):
        motion.load_amc(path, skeleton)


@pytest.mark.parametrize("frame_rate", [0.0, -120.0, float("nan"), float("inf")])
def test_amc_frame_rate_must_be_positive(tmp_path, frame_rate):
    skeleton = motion.load_asf(write_crlf(tmp_path / "small.asf", SMALL_ASF))
    path = write_crlf(tmp_path / "ok.amc", small_amc([((0,) * 6, 0, (0, 0), 0)] * 2))
    with pytest.raises(ValueError, match=f"{path}: frame_rate must be .*got {frame_rate}"):
        motion.load_amc(path, skeleton, frame_rate=frame_rate)


@pytest.mark.parametrize("edit, line, reason", [
    ((":bonedata", ":bones"), 56, "no :bonedata section"),
    (("lower hand", "lower hand finger"), 55, "unknown bone 'finger'"),
    (("dof rx ry", "dof rx tx"), 31, "'tx' is not supported"),
    (("axis 0 0 90  XYZ", "axis 0 0 90 XXY"), 21, "axis order"),
    (("length 0.5", "length nan"), 6, "not a finite number"),
    (("length 10", "length inf"), 20, "not a finite number"),
])
def test_malformed_asf_names_file_and_line(tmp_path, edit, line, reason):
    path = write_crlf(tmp_path / "bad.asf", SMALL_ASF.replace(*edit))
    with pytest.raises(motion.MotionFileError) as error:
        motion.load_asf(path)
    assert str(error.value).startswith(f"{path}:{line}: ") and reason in str(error.value)
