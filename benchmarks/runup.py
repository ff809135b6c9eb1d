"""A trained run-up (thesis §3.6.1) in figures: the deterministic run-up from the clip's start
against its reference, and the full motion's summary.

    python benchmarks/runup.py report RUNUP_DIR JUMP_DIR --name highjump_runup [--out docs]
        runs `takeoff motion RUNUP_DIR JUMP_DIR` into runs/<name>_motion (GIF, filmstrip, BVH,
        summary.json) and draws <out>/<name>_filmstrip.png: the grounded reference clip (top)
        and the simulated run-up (below it) at the same ten times from its start to the
        take-off, and both root paths on the ground seen from above; prints the summary's
        run-up and take-off figures and writes them to benchmarks/results/<name>.json

The training itself is `takeoff train configs/highjump_runup.toml` (docs/benchmarks.md, "The
run-up"). Needs the reference data (TAKEOFF_DATA, default ../shared/data).
"""

import argparse
import json
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.commands import motion_commands
from agents.commands.cli import run_errors
from agents.tasks import full_motion as fm
from jaxsim import render

RESULTS = Path(__file__).resolve().parent / "results"


def report(runup_dir, jump_dir, name, out, data_dir=None):
    summary, full = motion_commands.full_motion(runup_dir, jump_dir,
                                                Path("runs") / f"{name}_motion", data_dir)
    runup = motion_commands.load_run(runup_dir, data_dir)
    env = runup.env
    times, poses = fm.keyframes(full)
    upto = np.flatnonzero(times <= summary["switch_time"] + 1e-6)      # the run-up's frames
    picks = np.linspace(upto[0], upto[-1], 10).round().astype(int)
    reference = jax.vmap(env.reference)(jnp.asarray(times[picks], env.clip.poses.dtype))[0]
    frames = np.arange(upto[0], upto[-1] + 1)
    path_reference = jax.vmap(env.reference)(jnp.asarray(times[frames],
                                                          env.clip.poses.dtype))[0]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, qs in (("reference (grounded clip)", reference),
                          ("simulated run-up", poses[picks])):
            path = Path(tmp) / f"{len(rows)}.png"
            render.filmstrip(env.model, qs, path, n_panels=len(picks), times=times[picks],
                             title=f"{name}: {label}")
            rows.append(path)
        plt = render.pyplot()
        fig, ax = plt.subplots(figsize=(8, 3.2))
        for label, qs, style in (("reference", np.asarray(path_reference), "--"),
                                 ("simulated", poses[frames], "-")):
            ax.plot(qs[:, 0], qs[:, 2], style, label=f"{label} root path")
            ax.plot(qs[-1, 0], qs[-1, 2], "o", color=ax.lines[-1].get_color())
        ax.set_xlabel("x (m)")
        ax.set_ylabel("z (m)")
        ax.set_aspect("equal")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        path = Path(tmp) / "path.png"
        render.save_figure(fig, path, title=f"{name}: the root on the ground plane, seen from "
                                            "above (dots: take-off)")
        rows.append(path)
        from PIL import Image
        images = [Image.open(p).convert("RGB") for p in rows]
        sheet = Image.new("RGB", (max(i.width for i in images), sum(i.height for i in images)),
                          "white")
        y = 0
        for image in images:
            sheet.paste(image, (0, y))
            y += image.height
        Path(out).mkdir(parents=True, exist_ok=True)
        sheet.save(Path(out) / f"{name}_filmstrip.png")
    figures = {"runup_iterations": summary["runup_iterations"], "runup": summary["runup"],
               "switch_time": summary["switch_time"], "takeoff_time": summary["takeoff_time"],
               "takeoff_state_error": summary["takeoff_state_error"], "jump": summary["jump"]}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(figures, indent=2) + "\n")
    print(json.dumps(figures, indent=2))
    print(f"→ {Path(out) / f'{name}_filmstrip.png'}, runs/{name}_motion/")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("report")
    p.add_argument("runup_dir")
    p.add_argument("jump_dir")
    p.add_argument("--name", default="highjump_runup")
    p.add_argument("--out", default="docs")
    p.add_argument("--data-dir")
    args = parser.parse_args()
    try:
        report(args.runup_dir, args.jump_dir, args.name, args.out, args.data_dir)
    except run_errors() as error:
        raise SystemExit(f"runup.py: {error}")


if __name__ == "__main__":
    main()
