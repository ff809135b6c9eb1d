"""The Pose VAE (P-VAE, thesis §3.4.2) and the composite action it defines (eq. 3.4).

A β-VAE over the pose features of `agents.pose.pose_features`: the encoder (two tanh layers of 256) maps
the standardised features of a pose to the mean and log-variance of a 13-D Gaussian; the decoder
(two tanh layers of 256) maps a latent to the standardised decoder target, the joint rotations
that become PD targets. The loss per pose is the mean squared error of the standardised target
plus β times the KL divergence of the posterior from N(0, I) (β = 1e-5), trained with Adam.

The policy acts in the latent space: a PD target is decode(a_latent) + a_offset, the offset added
in exponential coordinates, and r_naturalness = 1 − clip((‖a_offset‖₁ / c_offset)², 0, 1)
(eq. 3.4) rewards small offsets. `PoseDecoder` carries what that needs (decoder weights and the target
normalisation) as a pytree, so both are jittable and differentiable.
"""

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import flax.linen as nn
import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np
import optax

from agents.pose import pose_dataset, pose_features
from agents import config as config_io
from agents.checkpoint import CheckpointError, fill, read_msgpack, write_msgpack
from jaxsim.atomic import atomic_path, write_text_atomic
from jaxsim.model import Model

WEIGHTS_FILE = "pvae.msgpack"
NORMALISATION_FILE = "normalisation.npz"
_STD_FLOOR = 1e-6


@dataclass(frozen=True)
class DataSettings:
    dataset: str = "poses.npz"             # built by `takeoff pvae dataset`
    validation_fraction: float = 0.1       # of the poses, held out as whole clips
    split_seed: int = 0
    repeat_clips: tuple[str, ...] = ()     # glob patterns of clip names whose training poses ...
    repeat_count: int = 1                  # ... appear this many times per epoch

    def __post_init__(self):
        if not 0.0 < self.validation_fraction < 0.5:
            raise ValueError(f"validation_fraction must be in (0, 0.5); got "
                             f"{self.validation_fraction}")
        if self.repeat_count < 1:
            raise ValueError(f"repeat_count must be at least 1; got {self.repeat_count}")
        if bool(self.repeat_clips) != (self.repeat_count > 1):
            raise ValueError(f"repeat_clips and a repeat_count above 1 go together; got "
                             f"repeat_clips = {list(self.repeat_clips)}, repeat_count = "
                             f"{self.repeat_count}")


@dataclass(frozen=True)
class ModelSettings:
    latent_size: int = 13
    hidden: tuple[int, ...] = (256, 256)
    beta: float = 1e-5

    def __post_init__(self):
        if self.latent_size < 1:
            raise ValueError(f"latent_size must be at least 1; got {self.latent_size}")
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError(f"hidden must list positive layer widths; got {self.hidden}")
        config_io.check_positive(self, ("beta",), allow_zero=True)


@dataclass(frozen=True)
class TrainSettings:
    learning_rate: float = 1e-4
    batch_size: int = 128
    epochs: int = 80
    seed: int = 0

    def __post_init__(self):
        config_io.check_positive(self, ("learning_rate",))
        if self.batch_size < 1 or self.epochs < 1:
            raise ValueError(f"batch_size and epochs must be at least 1; got "
                             f"{self.batch_size}, {self.epochs}")


@dataclass(frozen=True)
class PVAEConfig:
    data: DataSettings = field(default_factory=DataSettings)
    model: ModelSettings = field(default_factory=ModelSettings)
    train: TrainSettings = field(default_factory=TrainSettings)


class _MLP(nn.Module):
    hidden: tuple[int, ...]
    out: int

    @nn.compact
    def __call__(self, x):
        for width in self.hidden:
            x = jnp.tanh(nn.Dense(width)(x))
        return nn.Dense(self.out)(x)


class PVAE(nn.Module):
    """Encoder features → (mean, log-variance) of the latent; decoder latent → target."""

    latent_size: int
    hidden: tuple[int, ...]
    target_size: int

    def setup(self):
        self.encoder = _MLP(self.hidden, 2 * self.latent_size)
        self.decoder = _MLP(self.hidden, self.target_size)

    def encode(self, x):
        mean, log_var = jnp.split(self.encoder(x), 2, axis=-1)
        return mean, log_var

    def decode(self, z):
        return self.decoder(z)

    def __call__(self, x, key):
        mean, log_var = self.encode(x)
        z = mean + jnp.exp(0.5 * log_var) * jax.random.normal(key, mean.shape, mean.dtype)
        return self.decode(z), mean, log_var


@dataclasses.dataclass(frozen=True)
class Normalisation:
    """Means and standard deviations of the encoder features and of the decoder targets."""

    feature_mean: jax.Array
    feature_std: jax.Array
    target_mean: jax.Array
    target_std: jax.Array

    @classmethod
    def fit(cls, features, targets):
        return cls(*(jnp.asarray(a) for a in (
            features.mean(0), np.maximum(features.std(0), _STD_FLOOR),
            targets.mean(0), np.maximum(targets.std(0), _STD_FLOOR))))


jax.tree_util.register_dataclass(Normalisation, data_fields=[
    "feature_mean", "feature_std", "target_mean", "target_std"], meta_fields=[])


def _loss_terms(network: PVAE, params, x, y, key):
    """Per-batch (reconstruction MSE, KL) of standardised features x and targets y."""
    recon, mean, log_var = network.apply({"params": params}, x, key)
    mse = jnp.mean((recon - y) ** 2)
    kl = jnp.mean(0.5 * jnp.sum(jnp.exp(log_var) + mean**2 - 1.0 - log_var, axis=-1))
    return mse, kl


def _make_epoch(network: PVAE, optimiser, beta: float, batch_size: int):
    """One jitted epoch: shuffle, then a scan of Adam steps over whole minibatches."""

    def loss(params, x, y, key):
        mse, kl = _loss_terms(network, params, x, y, key)
        return mse + beta * kl, (mse, kl)

    def step(carry, batch):
        params, opt_state = carry
        x, y, key = batch
        (_, (mse, kl)), grads = jax.value_and_grad(loss, has_aux=True)(params, x, y, key)
        updates, opt_state = optimiser.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), (mse, kl)

    @jax.jit
    def epoch(params, opt_state, x, y, key):
        shuffle_key, noise_key = jax.random.split(key)
        n_batches = x.shape[0] // batch_size
        order = jax.random.permutation(shuffle_key, x.shape[0])[: n_batches * batch_size]
        order = order.reshape(n_batches, batch_size)
        keys = jax.random.split(noise_key, n_batches)
        (params, opt_state), (mse, kl) = jax.lax.scan(step, (params, opt_state),
                                                      (x[order], y[order], keys))
        return params, opt_state, jnp.mean(mse), jnp.mean(kl)

    return epoch


def reconstruction_mse(network: PVAE, params, x, y):
    """Held-out reconstruction error through the posterior mean (no sampling)."""
    mean, _ = network.apply({"params": params}, x, method=PVAE.encode)
    return jnp.mean((network.apply({"params": params}, mean, method=PVAE.decode) - y) ** 2)


@dataclasses.dataclass(frozen=True)
class TrainResult:
    params: dict
    normalisation: Normalisation
    history: list            # one dict per epoch
    seconds: float


def train(config: PVAEConfig, dataset: pose_dataset.PoseDataset, echo=print) -> TrainResult:
    """Fit the P-VAE on the training clips (those matching `data.repeat_clips` repeated
    `data.repeat_count` times, so rare motions weigh more: in the loss, in the normalisation and
    so in the decoder's mean pose, and in the number of steps an epoch takes); report held-out
    reconstruction every epoch. The held-out clips are never repeated."""
    train_mask, held_mask = pose_dataset.split_by_clip(dataset, config.data.validation_fraction,
                                                       config.data.split_seed)
    repeats = pose_dataset.pose_repeats(dataset, config.data.repeat_clips,
                                        config.data.repeat_count, config.data.dataset)
    train_rows = np.repeat(np.flatnonzero(train_mask), repeats[train_mask])
    if config.data.repeat_clips:
        echo(f"repeating the training poses of {', '.join(config.data.repeat_clips)} "
             f"{config.data.repeat_count} times: {len(train_rows)} training poses per epoch, "
             f"{int(train_mask.sum())} distinct")
    norm = Normalisation.fit(dataset.features[train_rows], dataset.targets[train_rows])
    x = (jnp.asarray(dataset.features) - norm.feature_mean) / norm.feature_std
    y = (jnp.asarray(dataset.targets) - norm.target_mean) / norm.target_std
    x_train, y_train, x_held, y_held = x[train_rows], y[train_rows], x[held_mask], y[held_mask]
    settings = config.train
    if x_train.shape[0] < settings.batch_size:
        raise pose_dataset.DatasetError(
            f"{config.data.dataset}: only {x_train.shape[0]} training poses (after holding out "
            f"data.validation_fraction = {config.data.validation_fraction}) for "
            f"train.batch_size = {settings.batch_size}")

    network = network_of(config, dataset.targets.shape[1])
    key = jax.random.PRNGKey(settings.seed)
    key, init_key, noise_key = jax.random.split(key, 3)
    params = network.init(init_key, x_train[:1], noise_key)["params"]
    optimiser = optax.adam(settings.learning_rate)
    opt_state = optimiser.init(params)
    epoch = _make_epoch(network, optimiser, config.model.beta, settings.batch_size)
    held_out = jax.jit(lambda p: reconstruction_mse(network, p, x_held, y_held))

    history, start = [], time.perf_counter()
    for index in range(settings.epochs):
        key, epoch_key = jax.random.split(key)
        params, opt_state, mse, kl = epoch(params, opt_state, x_train, y_train, epoch_key)
        record = {"epoch": index + 1, "train_mse": float(mse), "kl": float(kl),
                  "held_out_mse": float(held_out(params)),
                  "seconds": time.perf_counter() - start}
        history.append(record)
        echo(f"epoch {record['epoch']:3d}/{settings.epochs}  train mse {record['train_mse']:.4f}"
             f"  kl {record['kl']:8.2f}  held-out mse {record['held_out_mse']:.4f}"
             f"  {record['seconds']:6.1f} s")
    return TrainResult(params, norm, history, time.perf_counter() - start)


def network_of(config: PVAEConfig, target_size: int) -> PVAE:
    return PVAE(config.model.latent_size, tuple(config.model.hidden), target_size)


# ---- Using a trained P-VAE: decoding, the composite action, the naturalness reward ----------

@dataclasses.dataclass(frozen=True)
class PoseDecoder:
    """A trained decoder with its target normalisation: latent → decoder target."""

    params: dict
    normalisation: Normalisation
    network: PVAE

    def target(self, z):
        """Decoder target (6D per spherical joint, angle per revolute one) of latent z."""
        out = self.network.apply({"params": self.params}, z, method=PVAE.decode)
        return out * self.normalisation.target_std + self.normalisation.target_mean


jax.tree_util.register_dataclass(PoseDecoder, data_fields=["params", "normalisation"],
                                 meta_fields=["network"])


def composite_target(model: Model, decoder: PoseDecoder, latent, offset, root=None):
    """Eq. 3.4: the full PD target pose (nq) of decode(latent) + offset, the offset in
    exponential coordinates (a rotation vector per spherical joint, an angle per revolute)."""
    joint_targets = pose_features.target_to_exp(model, decoder.target(latent)) + offset
    return pose_features.exp_to_pose(model, joint_targets, root)


def naturalness(offset, c_offset):
    """Eq. 3.4: r_naturalness = 1 − clip((‖offset‖₁ / c_offset)², 0, 1) of offsets (..., k)."""
    return naturalness_of_norm(jnp.sum(jnp.abs(offset), axis=-1), c_offset)


def naturalness_of_norm(offset_norm, c_offset):
    """Eq. 3.4 of a given ‖offset‖₁: for a sparse task the episode's mean norm (§3.4.2)."""
    return 1.0 - jnp.clip((offset_norm / c_offset) ** 2, 0.0, 1.0)


# ---- Files ------------------------------------------------------------------------------------

def save(result: TrainResult, config: PVAEConfig, out_dir):
    """Weights (msgpack), normalisation record (npz) and the resolved config (JSON)."""
    out_dir = Path(out_dir)
    write_msgpack(out_dir / WEIGHTS_FILE, flax.serialization.to_state_dict(result.params))
    with atomic_path(out_dir / NORMALISATION_FILE) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **{k: np.asarray(v) for k, v in
                           dataclasses.asdict(result.normalisation).items()})
    write_text_atomic(out_dir / "config.json",
                      json.dumps(dataclasses.asdict(config), indent=2) + "\n")


def load_decoder(run_dir, model: Model) -> PoseDecoder:
    """The decoder of a P-VAE run directory written by `save`, for `model`'s layout. A missing
    file, or one that does not fit the run's config or the character (down to each weight
    array's shape and dtype), is a `CheckpointError` naming the file."""
    run_dir = Path(run_dir)
    what = f"is {run_dir} a P-VAE run directory (`takeoff pvae train`)?"
    for name in (WEIGHTS_FILE, NORMALISATION_FILE, "config.json"):
        if not (run_dir / name).exists():
            raise CheckpointError(f"{run_dir / name}: missing; {what}")
    config = config_io.build(PVAEConfig, config_io.read_stored(run_dir / "config.json"),
                             str(run_dir / "config.json"))
    target_size = pose_features.PoseLayout.of(model).target_size
    network = network_of(config, target_size)
    arrays = pose_dataset.read_npz(
        run_dir / NORMALISATION_FILE, ("feature_mean", "feature_std", "target_mean", "target_std"),
        CheckpointError, "not the normalisation record of a P-VAE run (`takeoff pvae train`)")
    norm = Normalisation(*(jnp.asarray(a) for a in arrays.values()))
    if norm.target_mean.shape != (target_size,):
        raise CheckpointError(f"{run_dir / NORMALISATION_FILE}: this P-VAE decodes "
                              f"{norm.target_mean.shape[0]} numbers; the character needs "
                              f"{target_size}")
    template = network.init(jax.random.PRNGKey(0), jnp.zeros((1, norm.feature_mean.shape[0])),
                            jax.random.PRNGKey(0))["params"]
    weights = run_dir / WEIGHTS_FILE
    stored = read_msgpack(weights, what)
    if not isinstance(stored, dict):
        raise CheckpointError(f"{weights}: not a table of network weights")
    try:
        params = flax.serialization.from_state_dict(template, stored)
    except ValueError as error:
        raise CheckpointError(f"{weights}: {error}") from None
    params = fill(template, jax.tree_util.tree_leaves(params), weights, "this P-VAE's config")
    return PoseDecoder(params, norm, network)
