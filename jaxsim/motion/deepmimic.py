"""Reading DeepMimic motion files: `{"Loop": "wrap"|"none", "Frames": [[dt, pose...], ...]}`.

Each frame is its duration dt followed by a pose in the character's q layout (43 numbers for the
humanoid, 83 for the dog). See the data README.
"""

import json
import os

from jaxsim.files import read_text
from jaxsim.model import Model
from jaxsim.motion.clip import Clip, make_clip

_LOOP_MODES = {"wrap": True, "none": False}


class MotionFileError(ValueError):
    """A motion file cannot be read; the message names the file and the problem."""


def load_motion(path, model: Model) -> Clip:
    """Read a DeepMimic motion file as a `Clip` of `model` (the pose length must match)."""
    path = os.fspath(path)
    try:
        data = json.loads(read_text(path, MotionFileError))
    except json.JSONDecodeError as e:
        raise MotionFileError(f"{path}: not valid JSON at line {e.lineno}, column {e.colno}: "
                              f"{e.msg}")
    if not isinstance(data, dict) or "Frames" not in data:
        raise MotionFileError(f"{path}: missing field 'Frames'")
    loop = data.get("Loop", "none")
    if loop not in _LOOP_MODES:
        raise MotionFileError(f"{path}: field 'Loop' must be 'wrap' or 'none', got {loop!r}")
    frames = data["Frames"]
    if not isinstance(frames, list) or not all(isinstance(f, list) for f in frames):
        raise MotionFileError(f"{path}: field 'Frames' must be a list of number lists")
    for k, frame in enumerate(frames):
        if len(frame) != model.nq + 1:
            raise MotionFileError(
                f"{path}: frame {k} has {len(frame)} numbers; this character needs 1 + "
                f"{model.nq} (frame duration and a pose of {model.topology.n_links} joints)")
        if not all(isinstance(x, (int, float)) for x in frame):
            raise MotionFileError(f"{path}: frame {k} holds something that is not a number")
    try:
        return make_clip(model, [f[0] for f in frames], [f[1:] for f in frames],
                         _LOOP_MODES[loop], source=path)
    except ValueError as e:
        raise MotionFileError(str(e)) from None
