"""The P-VAE's pose dataset: real motion capture retargeted to the humanoid (thesis §3.4.2).

Sources, read from the data directory the user names (never copied into the repository):
CMU subjects 01–03 (ASF/AMC, 120 Hz, retargeted with `jaxsim.motion.retarget.CMU_ASF`) and the
DeepMimic humanoid clips. Every clip is resampled at 30 Hz (looping clips for one cycle) and every
pose becomes the encoder features and the decoder target of `agents.pose.pose_features`. Each pose
keeps the index of its clip, so a validation split can hold out whole clips.
"""

import dataclasses
import fnmatch
import os
from pathlib import Path

import jax
import numpy as np

from agents.pose import pose_features
from jaxsim import motion
from jaxsim.atomic import atomic_path
from jaxsim.model import Model
from jaxsim.motion.clip import bucket_length
from jaxsim.motion.retarget import CMU_ASF, retarget

FRAME_RATE = 30.0
CMU_SUBJECTS = ("01", "02", "03")
_ARRAYS = ("features", "targets", "poses", "clip_index", "clip_names")


class DatasetError(ValueError):
    """A data directory or dataset file that cannot be used; the message names it."""


@dataclasses.dataclass(frozen=True)
class PoseDataset:
    """Poses (N, nq), encoder features (N, F), decoder targets (N, K), the clip of each pose (N,)
    as an index into `clip_names`."""

    features: np.ndarray
    targets: np.ndarray
    poses: np.ndarray
    clip_index: np.ndarray
    clip_names: np.ndarray

    def __len__(self):
        return len(self.poses)


def resample(clip: motion.Clip, rate: float = FRAME_RATE) -> np.ndarray:
    """The clip's poses every 1/rate seconds over [0, duration] (a looping clip's end, which
    repeats its start, is left out).

    Sampling never leaves the first cycle, so the clip can be padded (one-second frames holding
    the last pose) to power-of-two sizes: clips of any length then share a few compilations."""
    duration = float(clip.duration)
    count = int(np.floor(duration * rate + 1e-9)) + (0 if clip.loop else 1)
    times = np.arange(max(count, 1)) / rate
    frames = bucket_length(clip.n_frames)
    extra = np.arange(1, frames - clip.n_frames + 1)
    padded = motion.Clip(
        np.concatenate([np.asarray(clip.times), float(clip.times[-1]) + extra]),
        np.concatenate([np.asarray(clip.poses), np.repeat(np.asarray(clip.poses[-1:]),
                                                          len(extra), 0)]),
        clip.topology, loop=False)
    padded_times = np.pad(times, (0, bucket_length(len(times)) - len(times)), "edge")
    return np.asarray(_sample_poses(padded, padded_times.astype(clip.poses.dtype)))[:len(times)]


@jax.jit
def _sample_poses(clip: motion.Clip, times):
    return jax.vmap(motion.sample_pose, in_axes=(None, 0))(clip, times)


def source_clips(data_dir, model: Model):
    """(name, clip) for every CMU AMC of subjects 01–03 and every DeepMimic humanoid clip."""
    data_dir = Path(data_dir)
    cmu, deepmimic = data_dir / "cmu", data_dir / "deepmimic" / "motions"
    for folder in [cmu / s for s in CMU_SUBJECTS] + [deepmimic]:
        if not folder.is_dir():
            raise DatasetError(f"{folder}: missing; the data directory must hold cmu/01..03 and "
                               "deepmimic/motions (see the data README)")
    for subject in CMU_SUBJECTS:
        skeleton = motion.load_asf(cmu / subject / f"{subject}.asf")
        for path in sorted((cmu / subject).glob("*.amc")):
            clip = retarget(motion.load_amc(path, skeleton), model, CMU_ASF).clip
            yield f"cmu/{subject}/{path.stem}", clip
    for path in sorted(deepmimic.glob("humanoid3d_*.txt")):
        yield f"deepmimic/{path.stem}", motion.load_motion(path, model)


def build(data_dir, model: Model, echo=print) -> PoseDataset:
    """Collect, resample and featurise every source clip (see the module docstring)."""
    names, pose_blocks = [], []
    for name, clip in source_clips(data_dir, model):
        pose_blocks.append(resample(clip))
        names.append(name)
        echo(f"  {name:<40} {len(pose_blocks[-1]):>6} poses")
    poses = np.concatenate(pose_blocks)
    features, targets = (np.asarray(a) for a in featurise(model, poses))
    clip_index = np.repeat(np.arange(len(names)), [len(b) for b in pose_blocks])
    return PoseDataset(features.astype(np.float32), targets.astype(np.float32),
                       poses.astype(np.float32), clip_index.astype(np.int32), np.array(names))


def featurise(model: Model, poses):
    """The encoder features (N, F) and decoder targets (N, K) of poses (N, nq)."""
    return _featurise(model, jax.numpy.asarray(poses, model.mass.dtype))


@jax.jit
def _featurise(model: Model, poses):
    return jax.vmap(lambda q: (pose_features.pose_features(model, q),
                               pose_features.pd_target(model, q)))(poses)


def save(dataset: PoseDataset, path):
    """Write the dataset as an .npz file, atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **{k: getattr(dataset, k) for k in _ARRAYS})


def read_npz(path, names, error: type[Exception], what: str) -> dict:
    """The arrays `names` of the .npz archive `path`. A file that is not one numpy writes
    without pickles (text, an .npy array, a damaged archive, object arrays) or that lacks one of
    the arrays raises `error` with "path: `what` (why)"; pickles are never loaded."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
    except OSError as problem:
        raise error(f"{path}: {what} ({problem.strerror or problem})") from None
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):      # a zip archive, as np.savez writes
        raise error(f"{path}: {what} (not an .npz archive)")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in names if k not in data.files]
            if missing:
                raise error(f"{path}: {what} (it lacks {', '.join(missing)})")
            return {k: data[k] for k in names}
    except error:
        raise
    except ValueError:          # numpy refuses object arrays, which only pickles can hold
        raise error(f"{path}: {what} (it holds Python objects, not arrays of numbers)") from None
    except Exception as problem:        # zipfile, zlib and numpy's own for damaged bytes
        raise error(f"{path}: {what} (a damaged .npz archive: {problem})") from None


def load(path, model: Model | None = None) -> PoseDataset:
    """Read a dataset written by `save`; with `model`, check that its layout fits the model. A
    missing file or one that is not such a dataset is a `DatasetError` naming it."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise DatasetError(f"{path}: no such dataset file; build one with `takeoff pvae "
                           "dataset`")
    what = "not a pose dataset written by `takeoff pvae dataset`"
    arrays = read_npz(path, _ARRAYS, DatasetError, what)
    shapes = {k: a.shape for k, a in arrays.items()}
    if ([len(shapes[k]) for k in _ARRAYS] != [2, 2, 2, 1, 1]
            or len({shapes[k][0] for k in _ARRAYS[:4]}) != 1):
        raise DatasetError(f"{path}: {what} (arrays of shapes "
                           f"{', '.join(f'{k} {s}' for k, s in shapes.items())})")
    dataset = PoseDataset(**arrays)
    if model is not None:
        layout = pose_features.PoseLayout.of(model)
        if (dataset.features.shape[1], dataset.targets.shape[1], dataset.poses.shape[1]) != (
                layout.feature_size, layout.target_size, model.nq):
            raise DatasetError(f"{path}: features/targets/poses of width "
                               f"{dataset.features.shape[1]}/{dataset.targets.shape[1]}/"
                               f"{dataset.poses.shape[1]} do not fit this character "
                               f"({layout.feature_size}/{layout.target_size}/{model.nq})")
    return dataset


def split_by_clip(dataset: PoseDataset, validation_fraction: float, seed: int):
    """Boolean masks (train, validation) that hold out whole clips, about `validation_fraction`
    of the poses, chosen at random."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(dataset.clip_names))
    sizes = np.bincount(dataset.clip_index, minlength=len(dataset.clip_names))
    held, count = [], 0
    for clip in order:
        if count >= validation_fraction * len(dataset):
            break
        held.append(clip)
        count += sizes[clip]
    validation = np.isin(dataset.clip_index, held)
    return ~validation, validation


def principal_variance(features: np.ndarray, standardise: bool) -> np.ndarray:
    """Cumulative share of the variance explained by the principal components of the features,
    as they are (metres and 6D entries, both of order one: the thesis's measure) or
    standardised (each feature scaled to unit variance; constant ones dropped)."""
    centred = features.astype(np.float64) - features.mean(axis=0, dtype=np.float64)
    if standardise:
        std = centred.std(axis=0)
        varying = std > 1e-6    # the rest is rounding noise on structurally constant entries
        centred = centred[:, varying] / std[varying]
    singular = np.linalg.svd(centred, compute_uv=False)
    return np.cumsum(singular**2) / np.sum(singular**2)


def components_needed(share: np.ndarray, threshold: float) -> int:
    """How many principal components explain at least `threshold` of the variance."""
    return int(np.searchsorted(share, threshold) + 1)


def pose_repeats(dataset: PoseDataset, patterns, count: int, source) -> np.ndarray:
    """How many times each pose (N,) enters a training epoch: `count` for the poses of clips
    whose names match one of the glob `patterns` ("deepmimic/humanoid3d_*flip"), else 1. A
    pattern that matches no clip is a `DatasetError` naming it and `source`."""
    names = [str(n) for n in dataset.clip_names]
    chosen = np.zeros(len(names), bool)
    for pattern in patterns:
        matches = np.array([fnmatch.fnmatchcase(n, pattern) for n in names], bool)
        if not matches.any():
            raise DatasetError(f"{source}: data.repeat_clips pattern {pattern!r} matches none "
                               f"of its {len(names)} clips (names look like {names[0]!r})")
        chosen |= matches
    return np.where(chosen[dataset.clip_index], count, 1)
