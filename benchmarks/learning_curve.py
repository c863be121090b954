"""Learning curves: training loss and held-out rollout error against steps and wall time.

Reads the loss history stored in a model file and evaluates a series of snapshots of the same
run (copies of the model file taken while it trained) on held-out trajectories.

    python benchmarks/learning_curve.py --final data/fignet-star-movi-b.pt \
        --snapshots 'data/snapshots/fignet-star-*.pt' --test data/movi-b-test.h5 -n 10 \
        --out docs/results/learning-curve-fignet-star.json --plot docs/images/learning-curve-fignet-star.png

With --reuse, the points of snapshots already in --out (same step, same trajectories) are kept
rather than evaluated again, so the curve of a run still training can be extended.
"""

import argparse
import glob
import json
import os

import torch

from fignetctl.core.model.checkpoint import load_checkpoint, read_checkpoint_payload
from fignetctl.core.model.runs import evaluate_file


def training_history(path):
    payload = read_checkpoint_payload(path)
    state = payload.get("training_state") or payload.get("provenance") or {}
    return json.loads(state.get("history", "[]")), int(state.get("step", 0))


def held_out_points(snapshot_paths, test_path, max_trajectories, known=None):
    """One point per snapshot; `known` maps a step to a point already measured."""
    points = []
    for path in snapshot_paths:
        history, step = training_history(path)
        if any(p["step"] == step for p in points):
            continue  # the final model file is also the last snapshot
        if known and step in known:
            points.append(known[step])
            continue
        metrics = evaluate_file(load_checkpoint(path), test_path, max_trajectories)["metrics"]["model"]
        seconds = history[-1]["seconds"] if history else 0.0
        points.append({"step": step, "seconds": seconds, **{h: m["all"] for h, m in metrics.items()}})
        print(f"step {step}: {points[-1]}", flush=True)
    return sorted(points, key=lambda p: p["step"])


def plot(history, points, path, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    steps = [h["step"] for h in history]
    smooth = torch.tensor([h["loss"] for h in history]).unfold(0, min(50, len(history)), 1).mean(1).tolist() if history else []
    axes[0].plot(steps[len(steps) - len(smooth):], smooth)
    axes[0].set(xlabel="step", ylabel="training loss (mean of 50)", yscale="log", title=title)
    for axis, key, label in ((axes[1], "step", "step"), (axes[2], "seconds", "training wall time (s)")):
        for horizon in ("50_steps",):
            xs = [p[key] for p in points if p.get(horizon)]
            axis.plot(xs, [p[horizon]["translation_rmse_m"] for p in points if p.get(horizon)], "o-", label="translation RMSE (m)")
        axis.set(xlabel=label, ylabel="held-out error after 50 steps")
        twin = axis.twinx()
        twin.plot(xs, [p["50_steps"]["rotation_error_deg"] for p in points if p.get("50_steps")], "s--", color="tab:red", label="rotation (deg)")
        twin.set_ylabel("rotation error (deg)", color="tab:red")
        axis.legend(loc="upper right", fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=90)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--final", required=True)
    parser.add_argument("--snapshots", required=True, help="glob of snapshot model files")
    parser.add_argument("--test", required=True)
    parser.add_argument("-n", type=int, default=10)
    parser.add_argument("--out", required=True)
    parser.add_argument("--plot", required=True)
    parser.add_argument("--title", default="")
    parser.add_argument("--reuse", action="store_true", help="keep the points already in --out")
    args = parser.parse_args()
    history, _ = training_history(args.final)
    known = {}
    if args.reuse and os.path.exists(args.out):
        with open(args.out) as f:
            previous = json.load(f)
        if previous["test"] == args.test and previous["trajectories"] == args.n:
            known = {p["step"]: p for p in previous["held_out"]}
    points = held_out_points(sorted(glob.glob(args.snapshots)) + [args.final], args.test, args.n, known)
    with open(args.out, "w") as f:
        json.dump({"test": args.test, "trajectories": args.n, "held_out": points, "loss": history[::10]}, f, indent=1)
    plot(history, points, args.plot, args.title)
    print(args.out, args.plot)


if __name__ == "__main__":
    main()
