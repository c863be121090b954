"""Learning curves: training loss and held-out rollout error against steps and wall time.

A run is one or more stages, each a model file trained from the previous stage's weights
(`train --init-from`). Each stage's loss history is read from its model file (the full file
with its training state, not an export) and placed after the previous stages, so the steps and
seconds add up over the whole run. Snapshots (copies of a stage's model file taken while it
trained) and each stage's final file are evaluated on held-out trajectories.

    python benchmarks/learning_curve.py \
        --stage data/v3/fignet-star-movi-b.pt 'data/v3/snapshots/step-*000.pt' \
        --stage data/v7/fignet-star-movi-b.pt \
        --stage data/v9/fignet-star-movi-b.pt data/v9/snap.pt \
        --test data/movi-b-test.h5 -n 8 \
        --out docs/results/learning-curve-fignet-star.json --plot docs/images/learning-curve-fignet-star.png

With --reuse, the points already in --out (same stage, same step, same trajectories) are kept
rather than evaluated again, so the curve of a run still training can be extended.
"""

import argparse
import glob
import json
import os

import torch

from fignetctl.core.atomic import atomic_path, write_json
from fignetctl.core.model.apply import evaluate_trajectories
from fignetctl.core.model.checkpoint import load_checkpoint, read_checkpoint_payload
from fignetctl.core.trajectory import read_trajectories


def training_history(path):
    """(loss history, step) stored in a model file that kept its training state."""
    payload = read_checkpoint_payload(path)
    state = payload.get("training_state") or {}
    if not state.get("history"):
        raise SystemExit(
            f"error: {path} has no training history (an exported model?); pass the file `train` wrote"
        )
    return json.loads(state["history"]), int(state["step"])


def join_stages(finals):
    """The stages' loss histories end to end: (history with run-wide step and seconds, stages)."""
    run, stages, steps, seconds = [], [], 0, 0.0
    for index, path in enumerate(finals):
        history, step = training_history(path)
        run += [
            {**h, "step": h["step"] + steps, "seconds": h["seconds"] + seconds, "stage": index}
            for h in history
        ]
        stages.append(
            {
                "model": path,
                "first_step": steps + 1,
                "last_step": steps + step,
                "start_seconds": seconds,
                "seconds": history[-1]["seconds"],
            }
        )
        steps, seconds = steps + step, seconds + history[-1]["seconds"]
    return run, stages


def held_out_points(stages, snapshot_globs, test_path, max_trajectories, known=None):
    """One point per snapshot and per stage end; `known` maps (stage, step) to a point already measured."""
    points = []
    for index, (stage, pattern) in enumerate(zip(stages, snapshot_globs)):
        paths = (sorted(glob.glob(pattern)) if pattern else []) + [stage["model"]]
        for path in paths:
            history, step = training_history(path)
            if any(p["stage"] == index and p["stage_step"] == step for p in points):
                continue  # the final model file is also the last snapshot
            if known and (index, step) in known:
                points.append(known[(index, step)])
                continue
            metrics = evaluate_trajectories(
                load_checkpoint(path), read_trajectories(test_path), max_trajectories
            )["metrics"]["model"]
            points.append(
                {
                    "stage": index,
                    "stage_step": step,
                    "step": stage["first_step"] - 1 + step,
                    "seconds": stage["start_seconds"] + history[-1]["seconds"],
                    **{h: m["all"] for h, m in metrics.items()},
                }
            )
            print(f"stage {index} step {step}: {points[-1]}", flush=True)
    return sorted(points, key=lambda p: p["step"])


def plot(history, stages, points, path, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for index in range(len(stages)):  # the loss is smoothed within a stage: stages may change the target
        part = [h for h in history if h["stage"] == index]
        window = min(50, len(part))
        smooth = torch.tensor([h["loss"] for h in part]).unfold(0, window, 1).mean(1).tolist()
        axes[0].plot([h["step"] for h in part][window - 1 :], smooth, color="tab:blue")
    axes[0].set(xlabel="step", ylabel="training loss (mean of 50)", yscale="log", title=title)
    for axis, key, label in ((axes[1], "step", "step"), (axes[2], "seconds", "training wall time (s)")):
        shown = [p for p in points if p.get("50_steps")]
        xs = [p[key] for p in shown]
        axis.plot(
            xs, [p["50_steps"]["translation_rmse_m"] for p in shown], "o-", label="translation RMSE (m)"
        )
        axis.set(xlabel=label, ylabel="held-out error after 50 steps")
        twin = axis.twinx()
        twin.plot(
            xs,
            [p["50_steps"]["rotation_error_deg"] for p in shown],
            "s--",
            color="tab:red",
            label="rotation (deg)",
        )
        twin.set_ylabel("rotation error (deg)", color="tab:red")
        axis.legend(loc="upper right", fontsize=8)
    for stage in stages[1:]:  # where each later stage began
        for axis, key in ((axes[0], "first_step"), (axes[1], "first_step"), (axes[2], "start_seconds")):
            axis.axvline(stage[key], color="grey", linestyle=":", linewidth=1)
    figure.tight_layout()
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=90, format="png")


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--stage",
        nargs="+",
        action="append",
        required=True,
        metavar=("MODEL", "SNAPSHOTS"),
        help="a stage's final model file, then optionally a glob of its snapshots; repeat in order",
    )
    parser.add_argument("--test", required=True)
    parser.add_argument("-n", type=int, default=10)
    parser.add_argument("--out", required=True)
    parser.add_argument("--plot", required=True)
    parser.add_argument("--title", default="")
    parser.add_argument("--reuse", action="store_true", help="keep the points already in --out")
    args = parser.parse_args()
    if any(len(stage) > 2 for stage in args.stage):
        parser.error("--stage takes a model file and at most one (quoted) snapshot glob")
    history, stages = join_stages([stage[0] for stage in args.stage])
    known = {}
    if args.reuse and os.path.exists(args.out):
        with open(args.out) as f:
            previous = json.load(f)
        if previous["test"] == args.test and previous["trajectories"] == args.n:
            for point in previous["held_out"]:  # files written before stages existed hold one stage
                point.setdefault("stage", 0)
                point.setdefault("stage_step", point["step"])
                known[(point["stage"], point["stage_step"])] = point
    points = held_out_points(
        stages, [stage[1] if len(stage) > 1 else None for stage in args.stage], args.test, args.n, known
    )
    write_json(
        args.out,
        {
            "test": args.test,
            "trajectories": args.n,
            "stages": stages,
            "held_out": points,
            "loss": history[::10],
        },
    )
    plot(history, stages, points, args.plot, args.title)
    print(args.out, args.plot)


if __name__ == "__main__":
    main()
