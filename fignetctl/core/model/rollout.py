"""Rollouts: apply the learned simulator step after step, with checks that stop a bad one.

A rollout starts from frames 0 and 1 of a scene (t−1, t) and appends predicted frames, so frame
1 + k is step k, as in a rollout file. Static objects follow their given frames where the scene
has them and stay at their last given pose after. A non-finite pose, or an object farther than
`max_distance` from where it started, stops the rollout with `RolloutError`, which names the
step and the object and carries the frames computed so far.
"""

from __future__ import annotations

import numpy as np

from fignetctl.errors import FignetError

MAX_DISTANCE = 1000.0


class RolloutError(FignetError):
    """A rollout that went wrong; `positions`/`quaternions` hold the frames before the bad one."""

    def __init__(self, message, positions, quaternions):
        super().__init__(message)
        self.positions = positions
        self.quaternions = quaternions
        self.partial_file = None  # filled by runs.rollout_file: the frames so far, as a file


def given_static_pose(scene, frame):
    """(O, 3), (O, 4): the scene's pose at `frame`, or its last one past the end."""
    frame = min(frame, scene.positions.shape[0] - 1)
    return scene.positions[frame], scene.quaternions[frame]


def rollout(simulator, scene, num_steps, on_step=None, max_distance=MAX_DISTANCE):
    """Predict `num_steps` frames after frames 0 and 1 of `scene`.

    returns positions (2 + K, O, 3), quaternions (2 + K, O, 4) float64
    """
    positions = [scene.positions[0], scene.positions[1]]
    quaternions = [scene.quaternions[0], scene.quaternions[1]]
    for step in range(num_steps):
        next_static = given_static_pose(scene, step + 2)
        history_positions = np.stack([positions[-2], positions[-1], next_static[0]])
        history_quaternions = np.stack([quaternions[-2], quaternions[-1], next_static[1]])
        new_position, new_quaternion = simulator.step(scene.geometry, history_positions, history_quaternions)
        check_step(step, new_position, new_quaternion, positions, quaternions, max_distance)
        positions.append(new_position)
        quaternions.append(new_quaternion)
        if on_step is not None:
            on_step(step)
    return np.stack(positions), np.stack(quaternions)


def check_step(step, new_position, new_quaternion, positions, quaternions, max_distance):
    """Raise RolloutError (with the frames so far) for a non-finite or runaway object."""
    finite = np.isfinite(new_position).all(axis=1) & np.isfinite(new_quaternion).all(axis=1)
    distance = np.linalg.norm(np.nan_to_num(new_position, nan=np.inf) - positions[0], axis=1)
    bad = np.flatnonzero(~finite | (distance > max_distance))
    if bad.size:
        obj = int(bad[0])
        what = "a non-finite pose" if not finite[obj] else f"moved {distance[obj]:.3g} m from its start"
        raise RolloutError(
            f"rollout stopped at step {step}: object {obj} has {what}; "
            f"the {len(positions)} frames before it were kept",
            np.stack(positions),
            np.stack(quaternions),
        )
