"""Saved arrays: written with a checksum, the previous file kept, and read back into the pytree
they must fill, checked leaf by leaf.

`write_msgpack` stores msgpack contents inside a small envelope that carries their SHA-256, and
moves the file it replaces to `<name>.previous<ext>`; `read_msgpack` refuses a file whose
contents no longer match their checksum (bytes overwritten on disk, a copy cut short), naming
the file, so damaged weights never run as if they were a policy. `newest_intact` picks the
newest of the two files that passes, for a run to continue from.

Neither a msgpack list of arrays nor `flax.serialization.from_bytes` checks that a stored array
has the shape and dtype of the leaf it replaces. `fill` does, so a file written for other
settings (network sizes, number of environments, another character) is an error naming the file
and the leaf, not arrays of the wrong size flowing into a computation.
"""

import hashlib
import os
import shutil
from pathlib import Path

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np

from jaxsim.atomic import atomic_path


class CheckpointError(ValueError):
    """A saved file that is missing, unreadable, or does not fit what it must be read into; the
    message names the file (and the leaf)."""


FORMAT = "takeoff-checked-msgpack-1"     # the envelope's mark


def previous_path(path) -> Path:
    """Where `write_msgpack` keeps the file it replaced: checkpoint.msgpack →
    checkpoint.previous.msgpack."""
    path = Path(path)
    return path.with_name(f"{path.stem}.previous{path.suffix}")


def write_msgpack(path, contents):
    """Write `contents` (what flax's msgpack serialises: arrays, lists, dicts of them) to `path`
    atomically, with their checksum; the file it replaces, if intact, becomes
    `previous_path(path)` (a damaged one is overwritten, so the previous stays a good one)."""
    path = Path(path)
    payload = flax.serialization.msgpack_serialize(contents)
    envelope = flax.serialization.msgpack_serialize(
        {"format": FORMAT, "sha256": hashlib.sha256(payload).hexdigest(), "payload": payload})
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(envelope)
        if intact(path):                    # a damaged one is overwritten, the previous kept
            _keep_as_previous(path)


def _keep_as_previous(path):
    """Make `previous_path(path)` a copy of the file at `path` (a hard link where the file
    system has them), which stays in place: no moment without either."""
    previous = previous_path(path)
    link = previous.with_name(previous.name + ".tmp")
    link.unlink(missing_ok=True)
    try:
        os.link(path, link)
    except OSError:
        shutil.copyfile(path, link)
    os.replace(link, previous)


def intact(path) -> bool:
    """Whether the file at `path` exists and reads, its checksum matching."""
    try:
        _unpack(path, "")
    except CheckpointError:
        return False
    return True


def read_msgpack(path, what):
    """The msgpack contents of the file `path`, checked against their checksum; a
    `CheckpointError` naming the file when it is missing (`what` says what it should be),
    unreadable or damaged. Files written before checksums (plain msgpack) are read unchecked."""
    return flax.serialization.msgpack_restore(_unpack(path, what))


def _unpack(path, what) -> bytes:
    """The msgpack bytes of the contents of the file `path`, their checksum checked (a file
    without the envelope is its own contents)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: missing; {what}")
    data = path.read_bytes()
    try:
        stored = flax.serialization.msgpack_restore(data)
    except Exception as error:      # msgpack raises its own types for damaged bytes
        raise CheckpointError(f"{path}: damaged, not a readable msgpack file ({error})") from None
    if not (isinstance(stored, dict) and stored.get("format") == FORMAT):
        return data
    payload = stored.get("payload")
    checksum = hashlib.sha256(payload).hexdigest() if isinstance(payload, bytes) else None
    if checksum is None or checksum != stored.get("sha256"):
        raise CheckpointError(f"{path}: damaged: its contents do not match their checksum")
    return payload


def newest_intact(path, read):
    """`read(path)` for the file at `path`, or, when that raises a CheckpointError and the
    previous file (`previous_path`) reads, the previous file's contents. Returns (contents, a
    note saying the newest file was passed over, or "")."""
    try:
        return read(path), ""
    except CheckpointError as newest:
        previous = previous_path(path)
        if not previous.is_file():
            raise
        try:
            contents = read(previous)
        except CheckpointError:
            raise newest from None
        passed = f"{path} is missing" if not Path(path).exists() else str(newest)
        return contents, f"{passed}; using the one before it, {previous}"


def fill(template, arrays, path, needs):
    """`template`'s structure with `arrays` (a list, in `template`'s leaf order) as its leaves;
    a CheckpointError naming `path` and the leaf when their number, a shape or a dtype differs
    from the template's. `needs` names what asks for the template's leaves ("this run's
    config")."""
    paths_leaves, treedef = jax.tree_util.tree_flatten_with_path(template)
    if not isinstance(arrays, list) or len(arrays) != len(paths_leaves):
        count = len(arrays) if isinstance(arrays, list) else "no list of"
        raise CheckpointError(f"{path}: the file holds {count} arrays, {needs} needs "
                              f"{len(paths_leaves)} (were they saved for other settings?)")
    for array, (where, leaf) in zip(arrays, paths_leaves):
        have, want = np.asarray(array), np.asarray(leaf)
        if have.shape != want.shape or have.dtype != want.dtype:
            raise CheckpointError(f"{path}: {jax.tree_util.keystr(where)} is {have.dtype}"
                                  f"{list(have.shape)} in the file but {needs} needs "
                                  f"{want.dtype}{list(want.shape)}")
    return jax.tree_util.tree_unflatten(treedef, [jnp.asarray(a) for a in arrays])
