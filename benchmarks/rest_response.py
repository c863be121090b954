"""How a model answers a resting object that is given a small velocity: does it stop it?

From the last frame of held-out trajectories, every object at rest there (it moved less than
0.1 mm in the last frame) is given a velocity v of 3 mm per frame along ±x, ±y, ±z (the
previous frame moved back by v; moving objects are lifted 50 m out of the way) and the model
takes one step. The response k = a·v / |v|² says what a rollout will do:

- k = −1: the object stops (a = −v), as PyBullet's resting objects do;
- k = −2: it is sent back as fast as it came (a = −2v): from then on it moves ±v every frame,
  a period-2 oscillation that never settles;
- k = 0: it keeps the velocity and drifts away.

    python benchmarks/rest_response.py --model fignetctl/assets/models/fignet-star-movi-b.pt \
        --data data/movi-b-test.h5 -n 6 --out docs/results/rest-response.json
"""

import argparse
import json

import numpy as np

from fignetctl.core.atomic import write_json
from fignetctl.core.model.checkpoint import load_checkpoint
from fignetctl.core.model.scene_data import EVALUATION_STATIC_REACH, scene_from_trajectory
from fignetctl.core.trajectory import read_trajectories

SPEED = 0.003  # metres per frame
AT_REST = 1e-4
DIRECTIONS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)


def responses(simulator, scene):
    """k = a·v/|v|² (one per resting object and direction) of one scene's last frame."""
    positions, quaternions = scene.positions[-1].copy(), scene.quaternions[-1]
    dynamic = ~scene.geometry.static
    resting = dynamic & (np.linalg.norm(scene.positions[-1] - scene.positions[-2], axis=1) < AT_REST)
    positions[dynamic & ~resting] += [0.0, 0.0, 50.0]
    found = []
    for direction in DIRECTIONS:
        velocity = SPEED * direction
        previous = positions.copy()
        previous[resting] -= velocity
        history_q = np.stack([quaternions] * 3)
        following, _ = simulator.step(scene.geometry, np.stack([previous, positions, positions]), history_q)
        acceleration = (following - 2 * positions + previous)[resting]
        found.append(acceleration @ velocity / SPEED**2)
    return np.concatenate(found)


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--model", required=True)
    parser.add_argument("--data", required=True)
    parser.add_argument("-n", type=int, default=6)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    simulator = load_checkpoint(args.model)
    data = read_trajectories(args.data)
    found = []
    for key in list(data.trajectories)[: args.n]:
        found.append(
            responses(
                simulator, scene_from_trajectory(data, key, simulator.config, {}, EVALUATION_STATIC_REACH)
            )
        )
    k = np.concatenate(found)
    summary = {"responses": int(k.size), "k_p10_p50_p90": np.percentile(k, [10, 50, 90]).round(3).tolist()}
    print(json.dumps(summary))
    write_json(
        args.out, {"model": args.model, "data": args.data, "speed_m_per_frame": SPEED, "summary": summary}
    )


if __name__ == "__main__":
    main()
