"""P-VAE data path and training, measured; figures for docs/.

    python benchmarks/pvae.py retarget   # filmstrips: CMU walk and jump (ASF/AMC) and BVH 131_01,
                                         # source skeleton above, retargeted humanoid below
    python benchmarks/pvae.py train      # build the dataset and train configs/pvae.toml, timed;
                                         # PCA, loss, joint-error and sample figures into docs/
    python benchmarks/pvae.py unseen runs/pvae [runs/pvae_acro ...] [--out FILE.json]
                                         # how each trained P-VAE reconstructs the thesis's real
                                         # high jumps and sprint, which no P-VAE saw

Needs the reference data (TAKEOFF_DATA, default ../shared/data) and matplotlib.
"""

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np

from agents.commands import pvae_commands
from agents.pose import pose_dataset, pvae, pvae_report
from jaxsim import allocator, characters, motion, render
from jaxsim.atomic import write_text_atomic
from jaxsim.motion import retarget as rt
from spd import machine_info, reference_data

ROOT = Path(__file__).resolve().parents[1]
DOCS, RESULTS = ROOT / "docs", ROOT / "benchmarks" / "results"
# (figure, source kind, file, retargeting, first and last second shown)
CLIPS = [
    ("retarget_cmu_walk.png", "amc", "cmu/02/02_01.amc", rt.CMU_ASF, 0.0, 2.8),
    ("retarget_cmu_jump.png", "amc", "cmu/02/02_04.amc", rt.CMU_ASF, 0.0, 4.0),
    ("retarget_bvh_131_01.png", "bvh", "cmu-bvh/131_01.bvh", rt.CMU_BVH, 0.0, 2.8),
]
BVH_SCALE = 0.0254 / 0.45    # cgspeed's CMU conversion keeps the ASF's length unit


def load_source(kind, path):
    if kind == "bvh":
        return motion.load_bvh(path, length_scale=BVH_SCALE)
    subject = path.parent
    return motion.load_amc(path, motion.load_asf(subject / f"{subject.name}.asf"))


def retarget_figures(args):
    model = characters.humanoid()
    for figure, kind, name, rule, start, stop in CLIPS:
        source = load_source(kind, reference_data("cmu") / name)
        result = rt.retarget(source, model, rule)
        _, starts, tips = motion.world_pose(source)
        bones = np.stack([starts, tips], 2) @ rule.facing.T * result.scale
        frames = np.arange(int(start * source.frame_rate),
                           min(int(stop * source.frame_rate), source.n_frames))
        residue = ", ".join(f"{k} {np.mean(v):.1f}°" for k, v in result.residue_degrees.items())
        render.comparison_filmstrip(
            model, np.asarray(result.clip.poses)[frames], bones[frames], DOCS / figure,
            n_panels=8, azimuth=args.azimuth, times=frames * source.frame_time,
            labels=(f"source ({kind.upper()})", "retargeted"),
            title=f"{name}: leg-length scale {result.scale:.3f}; off-axis residue {residue}")
        print(f"{figure}: {source.n_frames} frames, scale {result.scale:.3f}, mean off-axis "
              f"residue {residue}")


def train_and_figures(args):
    out = RESULTS / "pvae"
    if out.exists():
        shutil.rmtree(out)
    dataset_path = out / "poses.npz"
    start = time.perf_counter()
    dataset, needed = pvae_commands.build_dataset(reference_data("cmu"), dataset_path)
    build_seconds = time.perf_counter() - start
    start = time.perf_counter()
    result = pvae_commands.train(ROOT / "configs" / "pvae.toml", out / "run",
                                 [f'data.dataset="{dataset_path}"'])
    train_seconds = time.perf_counter() - start
    report = json.loads((out / "run" / "report.json").read_text())
    for source, target in [(out / "poses_pca.png", "pvae_pca.png"),
                           (out / "run" / "losses.png", "pvae_losses.png"),
                           (out / "run" / "joint_errors.png", "pvae_joint_errors.png"),
                           (out / "run" / "samples.png", "pvae_samples.png")]:
        shutil.copyfile(source, DOCS / target)
    summary = {"machine": machine_info(), "poses": len(dataset), "clips": len(dataset.clip_names),
               "pca_components_85": needed, "dataset_seconds": build_seconds,
               "train_seconds_epochs_only": result.seconds,
               "train_command_seconds": train_seconds,
               "held_out_mean_error_degrees": report["held_out_mean_error_degrees"],
               "final": report["final"]}
    write_text_atomic(RESULTS / "pvae.json", json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


# The thesis's own mocap (jump/motions), never in a P-VAE's dataset (thesis §3.4.2: "none of
# these databases consist of high jumps").
UNSEEN = {"flop": "VC5_high_jump__fosbury_flop_06.txt", "straddle": "VC5_high_jump__straddle_02.txt",
          "scissor": "VC5_high_jump__scissor_01.txt", "curved sprint": "VC5_sprint__curves_03.txt"}
HARDEST_WINDOW = 10      # frames at 30 Hz: the hardest third of a second of each clip


def unseen_errors(args):
    """Mean joint-angle error of each P-VAE on each unseen clip, over the clip and over its
    hardest third of a second (for the flop, its bar crossing)."""
    model = characters.humanoid()
    motions = reference_data("jump") / "jump" / "motions"
    clips = {name: pose_dataset.featurise(model, pose_dataset.resample(
        motion.load_motion(motions / file, model))) for name, file in UNSEEN.items()}
    table = {}
    for run in args.runs:
        decoder = pvae.load_decoder(run, model)
        table[run] = {}
        for name, (features, targets) in clips.items():
            vae, base = (np.degrees(np.asarray(e).mean(1)) for e in
                         pvae_report.reconstruction_errors(model, decoder, features, targets))
            window = np.convolve(vae, np.ones(HARDEST_WINDOW) / HARDEST_WINDOW, "valid")
            row = {"mean": float(vae.mean()), "hardest_third_second": float(window.max()),
                   "starting_at_second": float(window.argmax() / pose_dataset.FRAME_RATE),
                   "mean_pose": float(base.mean())}
            table[run][name] = row
            print(f"{run:<22} {name:<14} mean {row['mean']:5.1f}°  hardest 1/3 s "
                  f"{row['hardest_third_second']:5.1f}° starting at "
                  f"{row['starting_at_second']:4.2f} s  (mean pose {row['mean_pose']:5.1f}°)")
    if args.out:
        write_text_atomic(args.out, json.dumps({"machine": machine_info(), "errors_degrees":
                                                table}, indent=2) + "\n")


def main():
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("retarget")
    p.add_argument("--azimuth", type=float, default=20.0)
    p.set_defaults(run=retarget_figures)
    sub.add_parser("train").set_defaults(run=train_and_figures)
    p = sub.add_parser("unseen")
    p.add_argument("runs", nargs="+", help="P-VAE run directories (takeoff pvae train)")
    p.add_argument("--out", help="write the table as JSON here")
    p.set_defaults(run=unseen_errors)
    args = parser.parse_args()
    args.run(args)


if __name__ == "__main__":
    allocator.restart_with_tunables()
    main()
