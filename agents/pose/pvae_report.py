"""What a trained P-VAE is worth: held-out joint-angle errors, loss curves, decoded samples.

The held-out poses come from whole clips the training never saw. Each is encoded to its posterior
mean and decoded; the error per joint is the angle of the rotation between the decoded and the
true joint rotation. The baseline is the mean pose of the training set (its decoder target
averaged and projected back to rotations): a P-VAE that does not beat it has learned nothing.
"""

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.pose import pose_dataset, pose_features
from agents.pose.pvae import (PVAE, PoseDecoder, PVAEConfig, TrainResult, composite_target,
                         network_of)
from jaxsim.atomic import write_text_atomic
from jaxsim.model import Model

SAMPLE_ROOT = (0.0, 0.95, 0.0, 1.0, 0.0, 0.0, 0.0)   # where decoded samples are drawn


def held_out_errors(model: Model, config: PVAEConfig, dataset: pose_dataset.PoseDataset,
                    result: TrainResult):
    """Mean angle error in degrees per actuated joint on the held-out clips: {joint: (P-VAE,
    mean pose)}, and the number of held-out poses."""
    _, held = pose_dataset.split_by_clip(dataset, config.data.validation_fraction,
                                         config.data.split_seed)
    decoder = PoseDecoder(result.params, result.normalisation,
                          network_of(config, dataset.targets.shape[1]))
    vae, base = (np.degrees(np.asarray(e).mean(0)) for e in reconstruction_errors(
        model, decoder, dataset.features[held], dataset.targets[held]))
    names = [model.topology.names[i] for i in pose_features.PoseLayout.of(model).actuated]
    return {n: (float(v), float(b)) for n, v, b in zip(names, vae, base)}, int(held.sum())


def reconstruction_errors(model: Model, decoder: PoseDecoder, features, targets):
    """Per-pose, per-joint angle errors (radians, (N, k)) of each pose encoded to its posterior
    mean and decoded, and of the decoder's mean pose, against the true decoder targets."""
    @jax.jit
    def errors(decoder, features, truth):
        norm = decoder.normalisation
        x = (features - norm.feature_mean) / norm.feature_std
        mean, _ = decoder.network.apply({"params": decoder.params}, x, method=PVAE.encode)
        per_pose = jax.vmap(lambda a, b: pose_features.joint_angle_errors(model, a, b))
        baseline = jnp.broadcast_to(norm.target_mean, truth.shape)
        return per_pose(decoder.target(mean), truth), per_pose(baseline, truth)

    return errors(decoder, jnp.asarray(features), jnp.asarray(targets))


def decoded_samples(model: Model, decoder: PoseDecoder, latent_size: int, count: int,
                    seed: int = 0):
    """Poses (count, nq) decoded from latents drawn from the prior N(0, I)."""
    z = jax.random.normal(jax.random.PRNGKey(seed), (count, latent_size))
    root = jnp.asarray(SAMPLE_ROOT, z.dtype)
    zero = jnp.zeros(pose_features.PoseLayout.of(model).exp_size, z.dtype)
    return jax.jit(jax.vmap(lambda zi: composite_target(model, decoder, zi, zero, root)))(z)


def write_report(model: Model, config: PVAEConfig, dataset, result: TrainResult, out_dir,
                 echo=print):
    """report.json and report.md in out_dir; with matplotlib, also losses.png,
    joint_errors.png and samples.png (a grid of decoded random latents)."""
    out_dir = Path(out_dir)
    errors, n_held = held_out_errors(model, config, dataset, result)
    vae_mean = float(np.mean([v for v, _ in errors.values()]))
    base_mean = float(np.mean([b for _, b in errors.values()]))
    report = {"poses": len(dataset), "held_out_poses": n_held,
              "train_seconds": result.seconds, "final": result.history[-1],
              "held_out_joint_error_degrees": {k: {"pvae": v, "mean_pose": b}
                                              for k, (v, b) in errors.items()},
              "held_out_mean_error_degrees": {"pvae": vae_mean, "mean_pose": base_mean}}
    write_text_atomic(out_dir / "report.json", json.dumps(report, indent=2) + "\n")
    lines = ["# P-VAE training report", "",
             f"{len(dataset)} poses, {n_held} of them held out (whole clips); "
             f"{config.train.epochs} epochs in {result.seconds:.1f} s.", "",
             "| joint | P-VAE error (deg) | mean-pose error (deg) |", "|---|---:|---:|"]
    lines += [f"| {k} | {v:.2f} | {b:.2f} |" for k, (v, b) in errors.items()]
    lines += [f"| **mean** | **{vae_mean:.2f}** | **{base_mean:.2f}** |", ""]
    write_text_atomic(out_dir / "report.md", "\n".join(lines))
    echo(f"held-out mean joint error: P-VAE {vae_mean:.2f}°, mean pose {base_mean:.2f}°")
    try:
        from jaxsim import render
        render.pyplot()
    except ImportError as error:
        echo(f"no figures: {error}")
        return report
    _plot_losses(render, result.history, out_dir / "losses.png")
    _plot_joint_errors(render, errors, out_dir / "joint_errors.png")
    decoder = PoseDecoder(result.params, result.normalisation,
                          network_of(config, dataset.targets.shape[1]))
    samples = decoded_samples(model, decoder, config.model.latent_size, 18)
    render.pose_grid(model, samples, out_dir / "samples.png", columns=6,
                     title="P-VAE: poses decoded from random latents z ~ N(0, I)")
    return report


def _plot_losses(render, history, path):
    plt = render.pyplot()
    epochs = [h["epoch"] for h in history]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.plot(epochs, [h["train_mse"] for h in history], label="training")
    ax.plot(epochs, [h["held_out_mse"] for h in history], label="held-out clips")
    ax.set_xlabel("epoch")
    ax.set_ylabel("reconstruction MSE (standardised)")
    ax.set_yscale("log")
    ax.legend()
    render.save_figure(fig, path, dpi=110)


def _plot_joint_errors(render, errors, path):
    plt = render.pyplot()
    names = list(errors)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.bar(x - 0.2, [errors[n][1] for n in names], 0.4, label="mean pose", color="#bbbbbb")
    ax.bar(x + 0.2, [errors[n][0] for n in names], 0.4, label="P-VAE", color="#4c72b0")
    ax.set_xticks(x, [n.replace("_", " ") for n in names], rotation=45, ha="right")
    ax.set_ylabel("held-out error (degrees)")
    ax.set_ylim(0, 1.3 * max(max(pair) for pair in errors.values()))
    ax.legend(ncol=2, loc="upper center")
    render.save_figure(fig, path, dpi=110)


def plot_pca(shares, threshold, path) -> bool:
    """Cumulative explained-variance curves {label: shares} as a PNG; False without
    matplotlib."""
    try:
        from jaxsim import render
        plt = render.pyplot()
    except ImportError:
        return False
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for label, share in shares.items():
        needed = pose_dataset.components_needed(share, threshold)
        ax.plot(np.arange(1, len(share) + 1), share, marker=".", ms=3,
                label=f"{label} features: {needed} for {threshold:.0%}")
    ax.axhline(threshold, color="grey", ls="--", lw=1)
    ax.set_xlim(0, 60)
    ax.set_xlabel("principal components")
    ax.set_ylabel("share of variance explained")
    ax.legend(loc="lower right")
    render.save_figure(fig, path, title="PCA of the P-VAE pose features", dpi=110)
    return True
