"""Reading and writing BVH motion capture files.

Conventions:

* Every joint is a bone whose rest frame is the identity; it starts at the sum of the OFFSETs from
  the ROOT down (the ROOT at its own OFFSET) and ends at its End Site, or else at the mean of its
  children's starts (at its own start when it has neither). End Sites are not bones.
* A joint's rotation channels, in the order its CHANNELS line lists them, compose with the first
  listed outermost: `Zrotation Xrotation Yrotation` means M = Rz·Rx·Ry (`euler_to_matrix`).
  Angles are in degrees. Each joint may list its own order.
* Only the ROOT may have position channels; its position is its OFFSET plus their values.
* Lengths are multiplied by `length_scale` to give metres (BVH has no unit; CMU's cgspeed
  conversions use inches / 0.45, so 0.0254 / 0.45 ≈ 0.0564).
* The MOTION section is `Frames: N`, `Frame Time: seconds`, then N lines, each with every channel's
  value in the order the joints appear in the hierarchy.

Malformed files raise `MotionFileError` with the message "path:line: reason" (lines from 1).
"""

import dataclasses
import io
import os

import numpy as np

from jaxsim.atomic import write_text_atomic
from jaxsim.motion.textfile import fail, floats, positive, read_lines
from jaxsim.motion.skeleton import Skeleton, SkeletonClip, euler_to_matrix, world_deltas

_POSITIONS = ("Xposition", "Yposition", "Zposition")
_ROTATIONS = ("Xrotation", "Yrotation", "Zrotation")
# Below this cos(pitch), the ZYX decomposition is in gimbal lock: yaw and roll turn about the same
# axis, so roll is set to zero. sqrt(machine epsilon) balances the two branches' rounding errors.
_GIMBAL_COS = 1e-8


@dataclasses.dataclass
class _Joint:
    name: str
    parent: int
    offset: np.ndarray
    channels: list
    end_site: np.ndarray | None = None


class _Tokens:
    """The hierarchy's words, each with its line number."""

    def __init__(self, path, lines):
        self.path = path
        self.words = [(word, number) for number, tokens in lines for word in tokens]
        self.last_line = lines[-1][0] if lines else 1
        self.at = 0

    def take(self, what):
        if self.at == len(self.words):
            raise fail(self.path, self.last_line, f"the hierarchy ends where {what} should be")
        self.at += 1
        return self.words[self.at - 1]

    def peek(self):
        return self.words[self.at][0] if self.at < len(self.words) else None

    def expect(self, keyword):
        word, number = self.take(repr(keyword))
        if word != keyword:
            raise fail(self.path, number, f"expected {keyword!r}, got {word!r}")
        return number

    def numbers(self, count, what):
        words = [self.take(what) for _ in range(count)]
        return floats(self.path, words[0][1], [word for word, _ in words])


def _offset(tokens):
    tokens.expect("OFFSET")
    return np.array(tokens.numbers(3, "an OFFSET value"))


def _channels(tokens, is_root):
    """The names on a joint's CHANNELS line."""
    number = tokens.expect("CHANNELS")
    word, _ = tokens.take("the channel count")
    if not word.isdigit():
        raise fail(tokens.path, number, f"the channel count must be a number, got {word!r}")
    names = [tokens.take("a channel name")[0] for _ in range(int(word))]
    for name in names:
        if name not in _ROTATIONS and (name not in _POSITIONS or not is_root):
            allowed = _ROTATIONS + (_POSITIONS if is_root else ())
            raise fail(tokens.path, number, f"channel {name!r} is not one of "
                                             f"{', '.join(allowed)}")
    return names


def _joint(tokens, joints, parent):
    """Read one ROOT or JOINT after its keyword, and its descendants, into `joints`."""
    name, _ = tokens.take("a joint name")
    tokens.expect("{")
    joint = _Joint(name, parent, _offset(tokens), [])
    joints.append(joint)
    index = len(joints) - 1
    if tokens.peek() == "CHANNELS":
        joint.channels = _channels(tokens, parent < 0)
    while True:
        word, number = tokens.take("'}'")
        if word == "}":
            return
        if word == "JOINT":
            _joint(tokens, joints, index)
        elif word == "End":
            tokens.expect("Site")
            tokens.expect("{")
            joint.end_site = _offset(tokens)
            tokens.expect("}")
        else:
            raise fail(tokens.path, number, f"expected JOINT, End Site or '}}', got {word!r}")


def _hierarchy(path, lines):
    """The joints of a HIERARCHY section, parents first (in the order the file lists them)."""
    tokens = _Tokens(path, lines)
    tokens.expect("HIERARCHY")
    tokens.expect("ROOT")
    joints = []
    _joint(tokens, joints, -1)
    if tokens.peek() is not None:
        word, number = tokens.take("MOTION")
        raise fail(path, number, f"expected MOTION after the ROOT joint, got {word!r}")
    return joints


def _header_value(path, line, label):
    """The number after `label` (such as "Frames:") on a MOTION header line."""
    number, tokens = line
    words = label.lower().split()
    if [t.lower() for t in tokens[:len(words)]] != words or len(tokens) != len(words) + 1:
        raise fail(path, number, f"expected '{label} <number>'")
    return floats(path, number, tokens[len(words):], 1)[0]


def _motion(path, lines, n_channels):
    """(frame time, values (T, n_channels)) from the lines after MOTION."""
    lines = [(number, tokens) for number, tokens in lines if tokens]
    end = lines[-1][0] if lines else 1
    if len(lines) < 2:
        raise fail(path, end, "MOTION needs 'Frames:' and 'Frame Time:' lines")
    n_frames = _header_value(path, lines[0], "Frames:")
    if n_frames != int(n_frames) or n_frames < 1:
        raise fail(path, lines[0][0], "the frame count must be a whole number ≥ 1")
    frame_time = _header_value(path, lines[1], "Frame Time:")
    if frame_time <= 0:
        raise fail(path, lines[1][0], "the frame time must be positive")
    rows = [floats(path, number, tokens, n_channels) for number, tokens in lines[2:]]
    if len(rows) != n_frames:
        raise fail(path, end, f"MOTION declares {int(n_frames)} frames but holds {len(rows)}")
    return frame_time, np.array(rows, float).reshape(len(rows), n_channels)


def _rest_pose(joints, length_scale):
    """(rest positions, rest tips) in metres."""
    positions = np.empty((len(joints), 3))
    for i, joint in enumerate(joints):
        parent = positions[joint.parent] if joint.parent >= 0 else 0.0
        positions[i] = parent + joint.offset * length_scale
    tips = positions.copy()
    for i, joint in enumerate(joints):
        children = [j for j, child in enumerate(joints) if child.parent == i]
        if joint.end_site is not None:
            tips[i] = positions[i] + joint.end_site * length_scale
        elif children:
            tips[i] = positions[children].mean(axis=0)
    return positions, tips


def load_bvh(path, length_scale: float = 1.0) -> SkeletonClip:
    """Read a BVH file as a clip of its joints (see the module docstring for the conventions);
    `length_scale` (a finite number > 0) converts its lengths to metres."""
    path = os.fspath(path)
    length_scale = positive(path, "length_scale", length_scale, "metres per BVH length unit")
    lines = read_lines(path)
    motion_at = next((i for i, (_, tokens) in enumerate(lines) if tokens[:1] == ["MOTION"]),
                     None)
    if motion_at is None:
        raise fail(path, len(lines), "the file has no MOTION section")
    joints = _hierarchy(path, lines[:motion_at])
    frame_time, values = _motion(path, lines[motion_at + 1:],
                                 sum(len(joint.channels) for joint in joints))
    positions, tips = _rest_pose(joints, length_scale)
    rotations, displacement = _channel_motion(joints, values)
    skeleton = Skeleton(tuple(j.name for j in joints), tuple(j.parent for j in joints),
                        np.tile(np.eye(3), (len(joints), 1, 1)), positions, tips)
    return SkeletonClip(skeleton, frame_time, positions[0] + displacement * length_scale,
                        rotations, source=path)


def _channel_motion(joints, values):
    """Each joint's rotations (T, n, 3, 3) and the root's position channels (T, 3), from the
    MOTION values (T, all channels) in file units."""
    rotations = np.empty((len(values), len(joints), 3, 3))
    displacement = np.zeros((len(values), 3))
    start = 0
    for b, joint in enumerate(joints):
        columns = values[:, start:start + len(joint.channels)]
        start += len(joint.channels)
        turns = [k for k, name in enumerate(joint.channels) if name in _ROTATIONS]
        axes = "".join(joint.channels[k][0] for k in turns)
        rotations[:, b] = euler_to_matrix(axes, np.radians(columns[:, turns]))
        for k, name in enumerate(joint.channels):
            if name in _POSITIONS:
                displacement[:, _POSITIONS.index(name)] = columns[:, k]
    return rotations, displacement


def _matrix_to_zyx(r):
    """Angles (…, 3) = (z, y, x) in radians with r = Rz(z)·Ry(y)·Rx(x), y in [−π/2, π/2]. In gimbal
    lock (y = ±π/2, where only z ∓ x is defined) x is zero."""
    cos_y = np.hypot(r[..., 0, 0], r[..., 1, 0])
    y = np.arctan2(-r[..., 2, 0], cos_y)
    locked = cos_y < _GIMBAL_COS
    z = np.where(locked, np.arctan2(-r[..., 0, 1], r[..., 1, 1]),
                 np.arctan2(r[..., 1, 0], r[..., 0, 0]))
    x = np.where(locked, 0.0, np.arctan2(r[..., 2, 1], r[..., 2, 2]))
    return np.stack([z, y, x], axis=-1)


def _format(values):
    return " ".join(f"{v:.9f}" for v in values)


def _write_joint(skeleton: Skeleton, bone, depth, out):
    """Write `bone` and its descendants as ROOT/JOINT blocks; return the bones in file order."""
    pad, parent = "\t" * depth, skeleton.parents[bone]
    start = skeleton.rest_positions[bone]
    if parent < 0:
        keyword, offset, channels = "ROOT", start, "6 Xposition Yposition Zposition"
    else:
        keyword, offset, channels = "JOINT", start - skeleton.rest_positions[parent], "3"
    out.write(f"{pad}{keyword} {skeleton.names[bone]}\n{pad}{{\n"
              f"{pad}\tOFFSET {_format(offset)}\n"
              f"{pad}\tCHANNELS {channels} Zrotation Yrotation Xrotation\n")
    order = [bone]
    children = [b for b, p in enumerate(skeleton.parents) if p == bone]
    for child in children:
        order += _write_joint(skeleton, child, depth + 1, out)
    if not children:
        tip = skeleton.rest_tips[bone] - start
        out.write(f"{pad}\tEnd Site\n{pad}\t{{\n{pad}\t\tOFFSET {_format(tip)}\n{pad}\t}}\n")
    out.write(f"{pad}}}\n")
    return order


def save_bvh(path, clip: SkeletonClip):
    """Write any skeleton clip as BVH (lengths in metres: read it back with length_scale 1).

    Joints get identity rest frames: each one's rotation is its world rotation relative to its
    parent's, D_parentᵀ D_b (D = `world_deltas`), written as `Zrotation Yrotation Xrotation` in
    degrees; the root's OFFSET is its rest position, and its position channels its displacement
    from there. Leaf bones end in an End Site at their tip; BVH has no place for other bones'
    tips, which a reader takes to be the mean of their children's starts. Joints are written
    depth-first, which may reorder the bones."""
    path = os.fspath(path)
    skeleton = clip.skeleton
    if skeleton.parents.count(-1) != 1 or any(len(name.split()) != 1 for name in skeleton.names):
        raise ValueError("BVH needs a single root and bone names without spaces")
    deltas = world_deltas(clip)
    parents = np.array(skeleton.parents)
    parent_deltas = np.where((parents < 0)[:, None, None], np.eye(3), deltas[:, parents])
    local = np.swapaxes(parent_deltas, -1, -2) @ deltas
    out = io.StringIO()
    out.write("HIERARCHY\n")
    order = _write_joint(skeleton, skeleton.parents.index(-1), 0, out)
    angles = np.degrees(_matrix_to_zyx(local[:, order])).reshape(clip.n_frames, -1)
    positions = clip.root_positions - skeleton.rest_positions[order[0]]
    out.write(f"MOTION\nFrames: {clip.n_frames}\nFrame Time: {float(clip.frame_time)!r}\n")
    np.savetxt(out, np.concatenate([positions, angles], axis=1), fmt="%.9f")
    write_text_atomic(path, out.getvalue())
