"""Reading Acclaim motion capture (CMU's format): an ASF skeleton and its AMC motions.

Conventions, as in the Acclaim specification:

* Units: the ASF's `:units` gives `length L` (lengths and translations are in inches × L) and
  `angle deg|rad`; an AMC's `:DEGREES`/`:RADIANS` header sets its own angle unit. Everything is
  converted to metres (value / L × 0.0254) and radians.
* A bone's `direction` (a unit vector) and `axis` are in world coordinates at rest. Its rest frame
  is C = euler_to_matrix(reversed order, reversed angles): for `axis ax ay az XYZ`,
  C = Rz(az)·Ry(ay)·Rx(ax), X applied first. It starts at its parent's tip and ends
  `direction × length` further on.
* Euler orders are listed innermost first (`dof rx ry rz` means M = Rz·Ry·Rx), for the `axis`,
  the bones' `dof` and the root's `order`. A bone's AMC angles give its rotation M in its rest
  frame, so its world rotation away from the rest pose is D = D_parent · C M Cᵀ (the known Acclaim
  formula; `world_pose` computes exactly this with rest_frames = C).
* The root is bone 0, named "root": it starts and ends at its `position`, its rest frame comes
  from `orientation` in the order of `axis`, and its AMC line holds the values in the order of
  `order` (TX TY TZ give its absolute position).

Bones are ordered depth-first from the root, children in the order `:hierarchy` lists them.
Malformed files raise `MotionFileError` with the message "path:line: reason" (lines from 1).
"""

import dataclasses
import os
from typing import NamedTuple

import numpy as np

from jaxsim.files import read_text
from jaxsim.motion.deepmimic import MotionFileError
from jaxsim.motion.textfile import fail, floats, positive, read_lines
from jaxsim.motion.skeleton import Skeleton, SkeletonClip, euler_to_matrix

_METRES_PER_INCH = 0.0254
_ROTATION_DOFS = ("rx", "ry", "rz")
_ROOT_DOFS = ("tx", "ty", "tz") + _ROTATION_DOFS


@dataclasses.dataclass(frozen=True)
class AsfSkeleton(Skeleton):
    """An ASF skeleton, with what reading its AMC motions needs: each bone's dofs in the order
    its AMC lines list them ("tx".."rz"; the root's come from `order`), the length unit in
    metres and whether angles are in degrees unless an AMC file says otherwise."""

    dofs: tuple[tuple[str, ...], ...]
    metres_per_unit: float
    degrees: bool


class _Bone(NamedTuple):
    name: str
    line: int                 # where the bone's block begins
    direction: np.ndarray     # world coordinates
    length: float             # file units
    frame: np.ndarray         # rest frame C
    dofs: tuple[str, ...]


def _rotation_matrices(axes: str, angles):
    """Rotations from Euler angles listed innermost first (Acclaim's order): `axes` such as
    "XYZ", angles (…, len(axes)) in radians."""
    return euler_to_matrix(axes[::-1], np.asarray(angles)[..., ::-1])


def _sections(path, lines):
    """{keyword: (line, body)} for the `:keyword` sections, where body is the section's
    [(line, tokens)] without comments and blank lines."""
    sections, body = {}, None
    for number, tokens in lines:
        if not tokens or tokens[0].startswith("#"):
            continue
        if tokens[0].startswith(":"):
            body = []
            sections[tokens[0][1:].lower()] = (number, body)
        elif body is None:
            raise fail(path, number, f"{tokens[0]!r} before the first :section")
        else:
            body.append((number, tokens))
    return sections


def _section(path, sections, name, lines):
    """(line, body) of a section the file must have."""
    if name not in sections:
        raise fail(path, len(lines), f"the file has no :{name} section")
    return sections[name]


def _units(path, body):
    """(metres per length unit, angles in degrees?) from the `:units` section."""
    length, degrees = 1.0, True
    for number, tokens in body:
        key = tokens[0].lower()
        if key == "length":
            (length,) = floats(path, number, tokens[1:], 1)
            if length <= 0:
                raise fail(path, number, "the length unit must be positive")
        elif key == "angle":
            unit = tokens[1].lower() if len(tokens) == 2 else ""
            if unit not in ("deg", "rad"):
                raise fail(path, number, "the angle unit must be 'deg' or 'rad'")
            degrees = unit == "deg"
    return _METRES_PER_INCH / length, degrees


def _rest_frame(path, line, angles, order, degrees):
    """C from three angles (file units) applied in `order` (such as XYZ, innermost first)."""
    if sorted(order.upper()) != ["X", "Y", "Z"]:
        raise fail(path, line, f"expected an axis order such as XYZ, got {order!r}")
    angles = np.radians(angles) if degrees else np.asarray(angles)
    return _rotation_matrices(order.upper(), angles)


def _root(path, section, degrees):
    """The root as a zero-length bone (dofs from `order`, rest frame from `axis` and
    `orientation`) and its rest `position` in file units."""
    line, body = section
    fields = {tokens[0].lower(): (number, tokens[1:]) for number, tokens in body}
    for key in ("order", "axis", "position", "orientation"):
        if key not in fields:
            raise fail(path, line, f":root has no {key!r}")
    number, order = fields["order"]
    dofs = tuple(d.lower() for d in order)
    if any(d not in _ROOT_DOFS for d in dofs) or len(set(dofs)) != len(dofs):
        raise fail(path, number, f"root order must list distinct channels among "
                                  f"{' '.join(d.upper() for d in _ROOT_DOFS)}")
    number, axis = fields["axis"]
    angles = floats(path, *fields["orientation"], 3)
    frame = _rest_frame(path, number, angles, " ".join(axis), degrees)
    position = np.asarray(floats(path, *fields["position"], 3))
    return _Bone("root", line, np.zeros(3), 0.0, frame, dofs), position


def _bone_blocks(path, body):
    """One {key: (line, values)} per `begin … end` block; `limits` continuation lines (which
    start with a parenthesis) are skipped, and the block's first line is kept under "begin"."""
    blocks, block = [], None
    for number, tokens in body:
        key = tokens[0].lower()
        if key == "begin":
            if block is not None:
                raise fail(path, number, "'begin' inside a bone block (missing 'end')")
            block = {"begin": (number, [])}
        elif key == "end":
            if block is None:
                raise fail(path, number, "'end' without 'begin'")
            blocks.append(block)
            block = None
        elif block is None:
            raise fail(path, number, f"{tokens[0]!r} outside a begin … end bone block")
        elif not key.startswith("("):
            block[key] = (number, tokens[1:])
    if block is not None:
        raise fail(path, block["begin"][0], "bone block without 'end'")
    return blocks


def _bone(path, block, degrees):
    begin = block["begin"][0]
    for key in ("name", "direction", "length", "axis"):
        if key not in block:
            raise fail(path, begin, f"bone has no {key!r}")
    number, name = block["name"]
    if len(name) != 1:
        raise fail(path, number, "a bone name is one word")
    direction = np.asarray(floats(path, *block["direction"], 3))
    (length,) = floats(path, *block["length"], 1)
    if length < 0:
        raise fail(path, block["length"][0], f"bone {name[0]!r} has a negative length {length}")
    number, axis = block["axis"]
    angles = floats(path, number, axis[:-1], 3)
    frame = _rest_frame(path, number, angles, axis[-1], degrees)
    number, dofs = block.get("dof", (begin, []))
    dofs = tuple(d.lower() for d in dofs)
    for d in dofs:
        if d not in _ROTATION_DOFS:
            raise fail(path, number, f"bone {name[0]!r}: dof {d!r} is not supported (only "
                                      f"rx ry rz; only the root translates)")
    if len(set(dofs)) != len(dofs):
        raise fail(path, number, f"bone {name[0]!r} repeats a dof")
    return _Bone(name[0], begin, direction, length, frame, dofs)


def _children(path, body, bones):
    """{parent: [children]} from the `:hierarchy` section's lines `parent child child …`."""
    children, has_parent = {}, set()
    for number, tokens in body:
        if tokens[0].lower() in ("begin", "end"):
            continue
        for name in tokens:
            if name not in bones:
                raise fail(path, number, f"unknown bone {name!r}")
        for child in tokens[1:]:
            if child == "root" or child in has_parent:
                raise fail(path, number, f"bone {child!r} has more than one parent")
            has_parent.add(child)
        children.setdefault(tokens[0], []).extend(tokens[1:])
    return children


def _depth_first(children, name="root"):
    order = [name]
    for child in children.get(name, []):
        order += _depth_first(children, child)
    return order


def load_asf(path) -> AsfSkeleton:
    """Read an ASF skeleton (see the module docstring for the conventions)."""
    path = os.fspath(path)
    lines = read_lines(path)
    sections = _sections(path, lines)
    metres, degrees = _units(path, sections.get("units", (0, []))[1])
    root, position = _root(path, _section(path, sections, "root", lines), degrees)
    bones = {"root": root}
    for block in _bone_blocks(path, _section(path, sections, "bonedata", lines)[1]):
        bone = _bone(path, block, degrees)
        if bone.name in bones:
            raise fail(path, bone.line, f"bone {bone.name!r} is defined twice")
        bones[bone.name] = bone
    children = _children(path, _section(path, sections, "hierarchy", lines)[1], bones)
    order = _depth_first(children)
    unplaced = [bone for name, bone in bones.items() if name not in order]
    if unplaced:
        raise fail(path, unplaced[0].line, f"bone {unplaced[0].name!r} is not below the root "
                                            f"in :hierarchy")

    index = {name: i for i, name in enumerate(order)}
    parents = [-1] * len(order)
    for parent, kids in children.items():
        for kid in kids:
            parents[index[kid]] = index[parent]
    starts, tips = np.empty((len(order), 3)), np.empty((len(order), 3))
    for i, name in enumerate(order):
        starts[i] = tips[parents[i]] if i else position * metres
        tips[i] = starts[i] + bones[name].direction * bones[name].length * metres
    return AsfSkeleton(tuple(order), tuple(parents), np.stack([bones[n].frame for n in order]),
                       starts, tips, tuple(bones[n].dofs for n in order), metres, degrees)


def _amc_lines(path, names):
    """Read an AMC file's lines: the frames [(line, frame number)]; for each bone, its lines as
    ([text after the name], [line]); and the angle unit the header sets (None if it sets none).
    Each frame is a line with its number (one more than the last) followed by lines
    `bone v1 v2 …`."""
    frames, entries, degrees = [], {name: ([], []) for name in names}, None
    for number, line in enumerate(read_text(path, MotionFileError).splitlines(), 1):
        parts = line.split(None, 1)
        if not parts:
            continue
        word = parts[0]
        bone = entries.get(word)
        if bone is not None and frames:
            bone[0].append(parts[1] if len(parts) == 2 else "")
            bone[1].append(number)
        elif word.startswith("#"):
            continue
        elif word.startswith(":"):
            degrees = {":DEGREES": True, ":RADIANS": False}.get(word.upper(), degrees)
        elif len(parts) == 1 and word.isdigit():
            if frames and int(word) != frames[-1][1] + 1:
                raise fail(path, number, f"frame {word} follows frame {frames[-1][1]}")
            frames.append((number, int(word)))
        elif not frames:
            raise fail(path, number, f"{word!r} before the first frame number")
        else:
            raise fail(path, number, f"bone {word!r} is not in the skeleton")
    return frames, entries, degrees


def _check_once_per_frame(path, name, frames, frame_lines, lines):
    """Raise unless bone `name` has exactly one line (`lines`) in every frame (which begin on
    `frame_lines`)."""
    index = np.searchsorted(frame_lines, lines) - 1       # the frame that each line is in
    expected = np.arange(len(frames))
    if np.array_equal(index, expected):
        return
    n = min(len(index), len(frames))
    mismatch = np.flatnonzero(index[:n] != expected[:n])
    i = int(mismatch[0]) if mismatch.size else n          # the first line out of step
    if i < len(index) and index[i] < i:
        raise fail(path, lines[i], f"bone {name!r} appears twice in frame {frames[index[i]][1]}")
    raise fail(path, frames[i][0], f"frame {frames[i][1]} has no values for bone {name!r}")


def _bone_values(path, texts, lines, count):
    """The values on a bone's lines, (len(lines), count): all at once with NumPy, or line by
    line when that fails or finds a non-finite value, so that the faulty line is reported."""
    tokens = " ".join(texts).split()
    if len(tokens) == len(texts) * count:
        try:
            values = np.array(tokens, float)
        except ValueError:
            values = None
        if values is not None and np.all(np.isfinite(values)):
            return values.reshape(len(texts), count)
    rows = [floats(path, line, text.split(), count) for text, line in zip(texts, lines)]
    return np.array(rows, float).reshape(len(texts), count)


def _amc_values(path, skeleton: AsfSkeleton):
    """([each bone's values (T, its dof count) in file units, in skeleton order], whether the
    angles are in degrees)."""
    frames, entries, degrees = _amc_lines(path, skeleton.names)
    if not frames:
        raise fail(path, 1, "the file holds no frames")
    frame_lines = np.array([line for line, _ in frames], int)
    values = []
    for name, dofs in zip(skeleton.names, skeleton.dofs):
        texts, lines = entries[name]
        if dofs:
            _check_once_per_frame(path, name, frames, frame_lines, np.array(lines, int))
        rows = _bone_values(path, texts, lines, len(dofs))
        values.append(rows if dofs else np.empty((len(frames), 0)))
    return values, skeleton.degrees if degrees is None else degrees


def load_amc(path, skeleton: AsfSkeleton, frame_rate: float = 120.0) -> SkeletonClip:
    """Read an AMC motion of `skeleton` (from `load_asf`), sampled at `frame_rate` Hz (CMU
    captures at 120). Each bone's rotation is M = Euler angles applied in its dof order, the
    first listed innermost; the root's TX TY TZ are its position; see the module docstring."""
    if not isinstance(skeleton, AsfSkeleton):
        raise TypeError("load_amc needs the skeleton that load_asf returns (it knows the dofs)")
    path = os.fspath(path)
    frame_rate = positive(path, "frame_rate", frame_rate, "frames per second")
    values, degrees = _amc_values(path, skeleton)
    n_frames = len(values[0])
    root_positions = np.tile(skeleton.rest_positions[0], (n_frames, 1))
    rotations = np.empty((n_frames, skeleton.n_bones, 3, 3))
    for b, (dofs, bone_values) in enumerate(zip(skeleton.dofs, values)):
        turns = [k for k, dof in enumerate(dofs) if dof in _ROTATION_DOFS]
        angles = np.radians(bone_values[:, turns]) if degrees else bone_values[:, turns]
        rotations[:, b] = _rotation_matrices("".join(dofs[k][1] for k in turns).upper(), angles)
        for k, dof in enumerate(dofs):
            if dof not in _ROTATION_DOFS:
                axis = "xyz".index(dof[1])
                root_positions[:, axis] = bone_values[:, k] * skeleton.metres_per_unit
    return SkeletonClip(skeleton, 1.0 / frame_rate, root_positions, rotations, source=path)
