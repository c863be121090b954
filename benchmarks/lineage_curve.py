"""What more training has bought the velocity-state FIGNet*: its held-out errors stage by stage
against the training samples behind each, beside constant velocity, the PyBullet ceilings and
the issue's marks, with a power law fitted to the latest stages and the samples at which it
would reach each mark.

Reads benchmarks/results/lineage/lineage.json (the stages and their samples) and each stage's
measures in its directory: `eval.json` (`fignetctl evaluate`, 40 held-out trajectories, the
network alone) and `fvu.json` (`one_step_fvu.py`); and, for the stages whose model file is
kept, `lineage/regimes/RUN.json` (`regime_errors.py -n 6`: how much of an impact's change of
velocity and of spin the network's step follows). Nothing is trained or run here.

    python benchmarks/lineage_curve.py -o benchmarks/results/lineage/curve.json \
        --plot docs/images/velocity-lineage.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from fignetctl.core.atomic import write_json

RESULTS = Path(__file__).resolve().parent / "results"
HELD_OUT = "data/movi-b-test.h5"
MARKS = {"10_steps_m": 0.30, "50_steps_m": 2.0, "rotation_vs_cv_50_steps_deg": -15.0}
"""The issue's marks, network alone on the held-out set: translation RMSE after 10 and 50
steps, and the rotation error's difference from constant velocity's after 50 steps."""
PLOT_REACH = 20
"""The plotted law goes on to the mark, or to this many times the samples so far if that is nearer."""


def stage_figures(stage) -> dict:
    run = RESULTS / stage["run"]
    prefix = stage.get("prefix", "")
    evaluation = json.loads((run / f"{prefix}eval.json").read_text())
    model, comparison = evaluation["metrics"]["model"], evaluation["comparison"]["constant_velocity"]
    figures = {
        "run": stage["run"],
        "samples_added": stage["steps"] * stage["examples_per_step"] * stage["runs"],
        "10_steps_m": model["0.33_seconds"]["all"]["translation_rmse_m"],
        "50_steps_m": model["50_steps"]["all"]["translation_rmse_m"],
        "rotation_50_steps_deg": model["50_steps"]["all"]["rotation_error_deg"],
        "rotation_vs_cv_50_steps_deg": comparison["50_steps"]["rotation_error_difference_deg"],
        "rotation_vs_cv_50_steps_deg_95": comparison["50_steps"]["rotation_error_difference_deg_95"],
        "ratio_to_cv_10_steps_95": comparison["0.33_seconds"]["translation_rmse_ratio_95"],
        "ratio_to_cv_50_steps_95": comparison["50_steps"]["translation_rmse_ratio_95"],
    }
    fvu_path = run / f"{prefix}fvu.json"
    if fvu_path.exists():
        figures["fvu_held_out"] = json.loads(fvu_path.read_text())["files"][HELD_OUT]["all"]
    regimes_path = RESULTS / "lineage" / "regimes" / f"{stage['run']}.json"
    if regimes_path.exists():
        impact = json.loads(regimes_path.read_text())["regimes"]["impact"]
        if "response" in impact:
            figures["impact_linear_captured"] = impact["response"]["linear"]["captured"]
            figures["impact_angular_captured"] = impact["response"]["angular"]["captured"]
    return figures


def power_law(samples, errors) -> tuple[float, float]:
    """Least squares of log error = log a + b log samples: (a, b)."""
    slope, intercept = np.polyfit(np.log(samples), np.log(errors), 1)
    return float(np.exp(intercept)), float(slope)


def samples_for(target, law) -> float | None:
    """Samples at which error = a · samples^b reaches `target` (None when it does not fall)."""
    a, b = law
    return float((target / a) ** (1 / b)) if b < 0 else None


def baselines(evaluation) -> dict:
    cv = evaluation["metrics"]["constant_velocity"]
    ceilings = json.loads((RESULTS / "physics-ceilings-movi-b.json").read_text())["fresh_world"]["states"]
    at = {
        state: {row["steps"]: row["translation_rmse_m"] for row in rows} for state, rows in ceilings.items()
    }
    return {
        "constant_velocity": {
            "10_steps_m": cv["0.33_seconds"]["all"]["translation_rmse_m"],
            "50_steps_m": cv["50_steps"]["all"]["translation_rmse_m"],
        },
        "pybullet_pose_and_velocity": {"10_steps_m": at["velocity"][10], "50_steps_m": at["velocity"][50]},
        "pybullet_two_frames": {
            "10_steps_m": at["finite-difference"][10],
            "50_steps_m": at["finite-difference"][50],
        },
    }


def plot(stages, fits, beside, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    samples = np.array([s["samples"] for s in stages])
    figure, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    for axis, key, title in (
        (axes[0], "10_steps_m", "after 10 steps (0.33 s)"),
        (axes[1], "50_steps_m", "after 50 steps (1.67 s)"),
    ):
        axis.plot(samples, [s[key] for s in stages], "o-", color="C0", label="velocity-state FIGNet*")
        a, b = fits[key]["law"]
        reach = min(max(samples.max(), fits[key]["samples_to_mark"] or 0) * 1.3, samples.max() * PLOT_REACH)
        grid = np.geomspace(samples[fits["first_fitted"]], reach, 50)
        axis.plot(
            grid, a * grid**b, "--", color="C0", alpha=0.6, label=f"power law, last stages (b = {b:.3f})"
        )
        axis.axhline(MARKS[key], color="C3", label=f"mark {MARKS[key]} m")
        axis.axhline(beside["constant_velocity"][key], color="0.5", ls=":", label="constant velocity")
        axis.axhline(beside["pybullet_two_frames"][key], color="C2", ls="-.", label="PyBullet, two frames")
        axis.axhline(
            beside["pybullet_pose_and_velocity"][key], color="C2", ls=":", label="PyBullet, pose + velocity"
        )
        axis.set_xscale("log")
        axis.set_xlabel("training samples")
        axis.set_ylabel("translation RMSE (m), 40 held-out trajectories")
        axis.set_title(title)
        axis.legend(fontsize=7)
    rotation = axes[2]
    rotation.errorbar(
        samples,
        [s["rotation_vs_cv_50_steps_deg"] for s in stages],
        yerr=np.abs(
            np.array([s["rotation_vs_cv_50_steps_deg_95"] for s in stages]).T
            - [s["rotation_vs_cv_50_steps_deg"] for s in stages]
        ),
        fmt="o-",
        label="rotation error − constant velocity's, 50 steps (deg, 95 %)",
    )
    rotation.axhline(MARKS["rotation_vs_cv_50_steps_deg"], color="C3", label="mark: 15° better")
    rotation.axhline(0, color="0.5", ls=":")
    rotation.set_xscale("log")
    rotation.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    rotation.set_xlabel("training samples")
    rotation.set_ylabel("degrees")
    twin = rotation.twinx()
    caught = [
        (s["samples"], s.get("impact_angular_captured"), s.get("impact_linear_captured")) for s in stages
    ]
    caught = [c for c in caught if c[1] is not None]
    twin.plot(
        [c[0] for c in caught],
        [c[1] for c in caught],
        "s--",
        color="C1",
        label="share of an impact's spin change followed",
    )
    twin.plot(
        [c[0] for c in caught], [c[2] for c in caught], "^--", color="C4", label="… of its velocity change"
    )
    twin.set_ylim(0, 1)
    twin.set_ylabel("share followed (one step, 6 trajectories)")
    lines = rotation.get_legend_handles_labels()
    more = twin.get_legend_handles_labels()
    rotation.legend(
        lines[0] + more[0],
        lines[1] + more[1],
        fontsize=7,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.16),
        ncol=2,
    )
    rotation.set_title("rotation, and what one step of an impact follows")
    figure.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--lineage", default=str(RESULTS / "lineage" / "lineage.json"))
    parser.add_argument(
        "--fit-last", type=int, default=6, help="fit the power law to this many latest stages"
    )
    parser.add_argument("-o", "--output", default=None, help="json to write")
    parser.add_argument("--plot", default=None, help="png to write")
    args = parser.parse_args()
    stages = [stage_figures(stage) for stage in json.loads(Path(args.lineage).read_text())["stages"]]
    total = 0
    for stage in stages:
        total += stage["samples_added"]
        stage["samples"] = total
    first = max(0, len(stages) - args.fit_last)
    fits = {"first_fitted": first}
    for key in ("10_steps_m", "50_steps_m"):
        for name, fitted in (("", stages[first:]), ("all_stages_", stages)):
            law = power_law([s["samples"] for s in fitted], [s[key] for s in fitted])
            fits[name + key] = {
                "law": law,
                "samples_to_mark": samples_for(MARKS[key], law),
                "stages": len(fitted),
            }
    beside = baselines(json.loads((RESULTS / stages[-1]["run"] / "eval.json").read_text()))

    print(
        f"{'stage':52s} {'samples':>9s} {'FVU':>6s} {'10 steps':>9s} {'50 steps':>9s} {'rot-CV':>7s} {'spin':>5s} {'vel':>5s}"
    )
    for s in stages:
        spin, vel = s.get("impact_angular_captured"), s.get("impact_linear_captured")
        print(
            f"{s['run']:52s} {s['samples']:9d} {s.get('fvu_held_out', float('nan')):6.3f} {s['10_steps_m']:9.3f}"
            f" {s['50_steps_m']:9.3f} {s['rotation_vs_cv_50_steps_deg']:+7.1f}"
            f" {spin if spin is not None else float('nan'):5.2f} {vel if vel is not None else float('nan'):5.2f}"
        )
    print("(spin, vel: the share of an impact's change of spin and of velocity one step follows)")
    for key in ("10_steps_m", "50_steps_m", "all_stages_10_steps_m", "all_stages_50_steps_m"):
        (a, b), reach = fits[key]["law"], fits[key]["samples_to_mark"]
        where = (
            f"{reach:,.0f} samples ({reach / total:.1f} × so far)" if reach else "never (it does not fall)"
        )
        mark = MARKS[key.removeprefix("all_stages_")]
        print(
            f"{key}: error ≈ {a:.3g} · samples^{b:.3f} over {fits[key]['stages']} stages; mark {mark} at {where}"
        )
    if args.output:
        write_json(args.output, {"marks": MARKS, "baselines": beside, "fits": fits, "stages": stages})
        print(args.output)
    if args.plot:
        plot(stages, fits, beside, args.plot)
        print(args.plot)


if __name__ == "__main__":
    main()
