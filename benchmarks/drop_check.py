"""Did the dropped object land and come to rest? Checks a rollout file of a drop (build-graph
scene: one moving object, a static environment).

    python benchmarks/drop_check.py out/scene/rollout.h5                 # one line
    python benchmarks/drop_check.py out/scene/rollout.h5 --json drop.json

Per frame, the clearance of the object's lowest point above the static surface right under it
(every vertex against the highest static face below it; negative = inside the environment),
and whether the object came to rest (its fastest vertex slower than 2 cm/s over the last 10
frames). Exit status 1 when the object went more than --max-penetration into the environment
or did not come to rest.
"""

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rollout", type=Path)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--max-penetration", type=float, default=0.03, help="metres (default 0.03)")
    args = parser.parse_args()
    from fignetctl.core.atomic import write_json
    from fignetctl.core.scene_building import drop_report
    from fignetctl.core.trajectory import read_trajectories
    from fignetctl.errors import FignetError

    try:
        report = drop_report(read_trajectories(args.rollout))
    except FignetError as error:
        sys.exit(f"error: {error}")
    if args.json:
        write_json(args.json, report)
    clearance = report["min_clearance_m"]
    rest = (
        f"at rest after {report['rest_time_s']:.2f} s"
        if report["at_rest"]
        else f"still moving ({report['final_speed_m_s']:.3f} m/s)"
    )
    lowest = (
        "nothing under it"
        if clearance is None
        else f"lowest point {1000 * clearance:+.1f} mm from the surface under it at worst"
    )
    print(f"drop: {lowest}; {rest} ({report['frames']} frames, dt {report['dt']:.4f} s)")
    sys.exit(0 if report["at_rest"] and clearance is not None and clearance > -args.max_penetration else 1)


if __name__ == "__main__":
    main()
