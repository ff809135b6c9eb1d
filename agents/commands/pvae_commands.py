"""`takeoff pvae dataset` and `takeoff pvae train`: the P-VAE's data and training runs."""

import time
from pathlib import Path

from agents import config as config_io
from agents.pose import pose_dataset, pvae, pvae_report
from jaxsim import characters
from jaxsim.atomic import check_writable

PCA_SHARE = 0.85


def build_dataset(data_dir, out, echo=print):
    """Build, save and summarise the pose dataset; a PCA plot goes beside it as <out>_pca.png."""
    check_writable(Path(out).parent, what="the pose dataset")
    model = characters.humanoid()
    start = time.perf_counter()
    echo(f"collecting poses from {data_dir} at {pose_dataset.FRAME_RATE:g} Hz")
    dataset = pose_dataset.build(data_dir, model, echo)
    pose_dataset.save(dataset, out)
    shares = {kind: pose_dataset.principal_variance(dataset.features, kind == "standardised")
              for kind in ("raw", "standardised")}
    needed = {kind: pose_dataset.components_needed(s, PCA_SHARE) for kind, s in shares.items()}
    echo(f"{len(dataset)} poses from {len(dataset.clip_names)} clips, "
         f"{dataset.features.shape[1]} features, {dataset.targets.shape[1]} target numbers, "
         f"in {time.perf_counter() - start:.0f} s → {out}")
    echo(f"PCA: {needed['raw']} principal components explain {PCA_SHARE:.0%} of the variance "
         f"of the features ({needed['standardised']} once each feature is standardised)")
    plot = Path(out).with_name(Path(out).stem + "_pca.png")
    if pvae_report.plot_pca(shares, PCA_SHARE, plot):
        echo(f"PCA curve → {plot}")
    return dataset, needed


def train(config_path, out_dir=None, overrides=(), echo=print):
    """Train a P-VAE from a config; weights, normalisation, config and report in out_dir
    (default runs/<config name>), which must be new or empty."""
    config = config_io.load(config_path, pvae.PVAEConfig, overrides)
    out_dir = config_io.run_directory(config_path, out_dir,
                                      lambda d: d.is_dir() and any(d.iterdir()),
                                      "pick another --out, or empty it first")
    check_writable(out_dir, what="the P-VAE's weights and report")
    model = characters.humanoid()
    dataset = pose_dataset.load(config.data.dataset, model)
    echo(f"P-VAE: {len(dataset)} poses from {config.data.dataset}, latent "
         f"{config.model.latent_size}, {config.train.epochs} epochs → {out_dir}")
    result = pvae.train(config, dataset, echo)
    pvae.save(result, config, out_dir)
    pvae_report.write_report(model, config, dataset, result, out_dir, echo)
    echo(f"trained in {result.seconds:.1f} s; weights, normalisation and report in {out_dir}")
    return result
