"""Saved arrays read back into the pytree they must fill, checked leaf by leaf.

Neither a msgpack list of arrays nor `flax.serialization.from_bytes` checks that a stored array
has the shape and dtype of the leaf it replaces. `fill` does, so a file written for other
settings (network sizes, number of environments, another character) is an error naming the file
and the leaf, not arrays of the wrong size flowing into a computation.
"""

from pathlib import Path

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np


class CheckpointError(ValueError):
    """A saved file that is missing, unreadable, or does not fit what it must be read into; the
    message names the file (and the leaf)."""


def read_msgpack(path, what):
    """The msgpack contents of the file `path` (`what` says what it should be, for the message
    when it is missing)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: missing; {what}")
    try:
        return flax.serialization.msgpack_restore(path.read_bytes())
    except ValueError as error:
        raise CheckpointError(f"{path}: not a readable msgpack file ({error})") from None


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
