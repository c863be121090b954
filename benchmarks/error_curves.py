"""Held-out error against rollout time, for the models and the baselines of `evaluate` files.

Plots the "curves" of one or more `fignetctl evaluate` json files (translation RMSE and mean
rotation error of the dynamic objects at every rollout step), prints the "comparison" of
each model with the baselines (RMSE ratio with its 95 % bootstrap interval over trajectories)
and a markdown table of every method's errors at each horizon.

    python benchmarks/error_curves.py docs/results/fignet-star-movi-b-test.json=FIGNet* \
        docs/results/fignet-movi-b-test.json=FIGNet --plot docs/images/error-curves-movi-b.png

The baselines and the PyBullet ceilings (`evaluate --ceilings`) are drawn once, from the first
file (every file must hold the same data).
"""

import argparse
import json
import os

BASELINES = {"constant_velocity": "constant velocity", "stand_still": "stand still"}
CEILINGS = {  # evaluate --ceilings
    "ceiling_velocity": "PyBullet restarted from pose + velocity",
    "ceiling_finite_difference": "PyBullet restarted from two frames",
}
NAMES = {**BASELINES, **CEILINGS}


def read(spec):
    path, _, label = spec.partition("=")
    with open(path) as f:
        report = json.load(f)
    if "curves" not in report:
        raise SystemExit(f"{path}: no per-step curves; evaluate it again with this version of fignetctl")
    return label or path, report


def comparison_lines(label, report):
    for baseline, horizons in report["comparison"].items():
        for horizon, c in horizons.items():
            low, high = c["translation_rmse_ratio_95"]
            rlow, rhigh = c["rotation_error_difference_deg_95"]
            yield (
                f"{label} vs {NAMES.get(baseline, baseline)}, {horizon}: translation RMSE ×{c['translation_rmse_ratio']:.3f} "
                f"[{low:.3f}, {high:.3f}], rotation {c['rotation_error_difference_deg']:+.1f}° [{rlow:+.1f}, {rhigh:+.1f}], "
                f"closer for {100 * c['objects_closer']:.0f} % of {c['objects']} objects ({c['trajectories']} trajectories)"
            )


HORIZONS = ("0.1_seconds", "0.2_seconds", "0.33_seconds", "0.5_seconds", "1_seconds", "50_steps", "2_seconds")


def markdown_table(reports):
    """One row per model (each file) and per baseline and ceiling (first file): translation
    RMSE (m) / mean rotation error (deg) at each horizon the first file has."""
    first = reports[0][1]
    horizons = [h for h in HORIZONS if h in first["metrics"]["model"]]
    rows = [(label, report["metrics"]["model"]) for label, report in reports]
    rows += [
        (f"{label}, with guards", report["metrics"]["model_with_guards"])
        for label, report in reports
        if "model_with_guards" in report["metrics"]
    ]
    rows += [(name, first["metrics"][key]) for key, name in NAMES.items() if key in first["metrics"]]
    steps = {
        h: round(float(h.split("_")[0]) / first["dt"]) if h.endswith("seconds") else int(h.split("_")[0])
        for h in horizons
    }
    names = [
        f"{h.replace('_seconds', ' s').replace('_steps', ' steps')} ({steps[h]} steps)"
        if h.endswith("seconds")
        else h.replace("_", " ")
        for h in horizons
    ]
    lines = ["| m / deg | " + " | ".join(names) + " |", "|---|" + "---:|" * len(horizons)]
    for label, metrics in rows:
        cells = [
            f"{metrics[h]['all']['translation_rmse_m']:.3f} / {metrics[h]['all']['rotation_error_deg']:.1f}"
            for h in horizons
        ]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(reports, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    first = reports[0][1]
    dt = first["dt"]
    lines = [(label, report["curves"]["model"], "-") for label, report in reports]
    lines += [
        (f"{label}, with guards", report["curves"]["model_with_guards"], "--")
        for label, report in reports
        if "model_with_guards" in report["curves"]
    ]
    lines += [(name, first["curves"][key], ":") for key, name in BASELINES.items() if key in first["curves"]]
    lines += [(name, first["curves"][key], "-.") for key, name in CEILINGS.items() if key in first["curves"]]
    for axis, key, ylabel in (
        (axes[0], "translation_rmse_m", "translation RMSE (m)"),
        (axes[1], "rotation_error_deg", "rotation error (deg)"),
    ):
        for label, curve, style in lines:
            axis.plot([k * dt for k in curve["step"]], curve[key], style, label=label)
        axis.axvline(50 * dt, color="grey", lw=0.8)
        axis.set(xlabel="rollout time (s); grey: 50 steps", ylabel=ylabel)
    axes[0].legend(fontsize=8)
    figure.suptitle(
        f"{first['trajectories']} held-out trajectories of {os.path.basename(first['data'])}", fontsize=9
    )
    figure.tight_layout()
    figure.savefig(path, dpi=90)


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "reports", nargs="+", metavar="FILE[=LABEL]", help="evaluate json files, each with an optional label"
    )
    parser.add_argument("--plot", help="PNG to write")
    args = parser.parse_args()
    reports = [read(spec) for spec in args.reports]
    for label, report in reports:
        for line in comparison_lines(label, report):
            print(line)
    print(markdown_table(reports))
    if args.plot:
        plot(reports, args.plot)
        print(args.plot)


if __name__ == "__main__":
    main()
