"""Two training runs' losses compared step by step, in windows.

Runs with the same seed, batch and schedule draw the same frames and noise at every step, so
the difference of their losses at each step leaves out which frames happened to be drawn,
which dominates either loss curve alone. For each window of `--window` steps: both means and
the mean paired difference (second − first) with its standard error.

    python benchmarks/paired_loss.py control.csv inertia.csv --window 500 -o paired.json
"""

import argparse
import csv
import math

from fignetctl.core.atomic import write_json


def losses(path) -> dict[int, float]:
    """step -> loss of a `fignetctl train --log-csv` file."""
    with open(path, newline="") as handle:
        return {int(row["step"]): float(row["loss"]) for row in csv.DictReader(handle)}


def paired_windows(first: dict, second: dict, window: int) -> list[dict]:
    """For each window of the steps both runs logged: both means, the mean paired difference
    (second − first) and its standard error."""
    steps = sorted(set(first) & set(second))
    rows = []
    for start in range(0, steps[-1] if steps else 0, window):
        inside = [step for step in steps if start < step <= start + window]
        if len(inside) < 2:
            continue
        differences = [second[step] - first[step] for step in inside]
        mean = sum(differences) / len(differences)
        variance = sum((d - mean) ** 2 for d in differences) / (len(differences) - 1)
        rows.append(
            {
                "steps": [inside[0], inside[-1]],
                "first_mean": sum(first[step] for step in inside) / len(inside),
                "second_mean": sum(second[step] for step in inside) / len(inside),
                "difference": mean,
                "standard_error": math.sqrt(variance / len(differences)),
            }
        )
    return rows


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("first", help="the control's loss csv")
    parser.add_argument("second", help="the other run's loss csv")
    parser.add_argument("--window", type=int, default=500, help="steps per window")
    parser.add_argument("-o", "--output", help="json to write")
    args = parser.parse_args()
    rows = paired_windows(losses(args.first), losses(args.second), args.window)
    for row in rows:
        print(
            f"steps {row['steps'][0]}-{row['steps'][1]}: {row['first_mean']:.4f} and {row['second_mean']:.4f}, "
            f"difference {row['difference']:+.4f} ({row['standard_error']:.4f})"
        )
    if args.output:
        result = {"first": args.first, "second": args.second, "window": args.window, "windows": rows}
        write_json(args.output, result)


if __name__ == "__main__":
    main()
