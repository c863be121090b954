"""Simulating a scene at the size the model was trained on (dynamic similarity).

A learned simulator only knows the sizes and speeds of its training data: the bundled models
saw make-dataset movi-b objects whose largest side is 1.4–2.8 m (median 2.1 m), while a cup on
a table is 0.1 m. Under gravity alone (friction and restitution are dimensionless), a scene
scaled by s in space behaves like the original slowed down by √s in time (Froude similarity:
x' = s·x, t' = √s·t, v' = √s·v). So a small scene can be simulated at the model's size with
the model's frame time dt, and the predicted frames mapped back: positions divided by s, the
frames then √s times closer in time (dt / √s).

Gravity is mapped the same way. A model learns the gravity of its data (it records it); a scene
under gravity g' behaves like one under the model's g with time running √(g'/g) times faster.
Both together: the model's world is the scene scaled by s in space, with c = √(s·g'/g) of the
model's seconds per second of the scene (x' = s·x, t' = c·t, v' = (s/c)·v, ω' = ω/c), and each
of the model's steps is dt / c of the scene's time. A scene whose gravity points elsewhere
than the model's, or that has none, cannot be mapped so (`gravity_ratio` refuses it).

The first frame (t−1) is moved so that the motion survives the change of frame time: each
dynamic object's centre is taken to fly on the parabola under gravity g through its two given
positions (x_{t−1} at −dt, x_t at 0), and x_{t−1} becomes that parabola at −dt/√s; its
rotation keeps its angular velocity (the step's angle shrinks by 1/√s). Static objects must
stand still over the given frames, since their given motion could not be re-timed.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fignetctl.core.model.trained_ranges import trajectory_largest_sides
from fignetctl.core.transforms import (
    quat_angle_deg,
    quat_conjugate,
    quat_from_axis_angle,
    quat_multiply,
    quat_normalize,
)
from fignetctl.errors import FignetError

TRAINING_OBJECT_SIDE = 2.1
"""Metres: the median largest side of the bundled models' training objects (movi-b, 1.4–2.8 m)."""
TRAINING_SIDE_RANGE = (1.4, 2.8)
"""Metres: the range of those largest sides; `auto_scale` leaves scenes inside it as they are."""

GRAVITY_TOLERANCE = 1e-3
"""A scene's gravity within this fraction (and a twentieth of a degree) of the model's is the model's."""


def largest_dynamic_side(data, key) -> float:
    """Largest side (m) of the axis-aligned box of any dynamic object's scaled mesh."""
    sides = trajectory_largest_sides(data, key)
    if not sides.size:
        raise FignetError("the scene has no dynamic object to simulate")
    return float(sides.max())


def auto_scale(data, key, trained_properties=None) -> float:
    """1 for a scene whose largest dynamic object is of a size the model trained on, else the
    scale that brings it to the training objects' median size. The sizes are the model's
    `trained_properties` largest_side (trained_ranges.py) where it records them, else the bundled
    models' (TRAINING_SIDE_RANGE, TRAINING_OBJECT_SIDE)."""
    side = largest_dynamic_side(data, key)
    known = (trained_properties or {}).get("dynamic", {}).get("largest_side")
    low, median, high = (
        known if known else (TRAINING_SIDE_RANGE[0], TRAINING_OBJECT_SIDE, TRAINING_SIDE_RANGE[1])
    )
    return 1.0 if low <= side <= high else median / side


def gravity_ratio(scene_gravity, model_gravity, where="scene") -> float:
    """|g'| / |g| of a scene's gravity g' to the gravity g a model was trained under; 1 when the
    model records none or they agree (GRAVITY_TOLERANCE). A FignetError when the scene has no
    gravity or it points elsewhere than the model's (`where` names the scene)."""
    if model_gravity is None:
        return 1.0
    scene_gravity, model_gravity = (
        np.asarray(scene_gravity, np.float64),
        np.asarray(model_gravity, np.float64),
    )
    scene_norm, model_norm = np.linalg.norm(scene_gravity), np.linalg.norm(model_gravity)
    model_text = f"({', '.join(f'{g:g}' for g in model_gravity)}) m/s²"
    if scene_norm == 0.0:
        raise FignetError(
            f"{where}: has no gravity, and the model learned to simulate under {model_text}; "
            "give the scene a gravity along the model's"
        )
    cosine = float(np.dot(scene_gravity, model_gravity) / (scene_norm * model_norm))
    if cosine < math.cos(math.radians(0.05)):
        raise FignetError(
            f"{where}: its gravity points along ({', '.join(f'{g:.3g}' for g in scene_gravity / scene_norm)}), "
            f"{math.degrees(math.acos(min(1.0, max(-1.0, cosine)))):.3g}° from the model's {model_text}; "
            "rotate the scene so that gravity points along the model's"
        )
    ratio = scene_norm / model_norm
    return 1.0 if abs(ratio - 1.0) <= GRAVITY_TOLERANCE else float(ratio)


def time_factor(scale: float, ratio: float = 1.0) -> float:
    """c = √(s·g'/g): the model's seconds per second of a scene scaled by s whose gravity is
    `ratio` (g'/g) times the model's (module docstring)."""
    return math.sqrt(scale * ratio)


def retimed_history(trajectory, dt: float, new_dt: float, gravity):
    """Frames (t−1, t) of `trajectory` with frame t−1 moved from −dt to −new_dt (module docstring).

    returns positions (2, O, 3), quaternions (2, O, 4) float64
    """
    positions = np.asarray(trajectory.positions[:2], np.float64).copy()
    quaternions = quat_normalize(trajectory.quaternions[:2])
    dynamic = ~np.asarray(trajectory.static, bool)
    gravity = np.asarray(gravity, np.float64)
    velocity = (
        positions[1, dynamic] - positions[0, dynamic]
    ) / dt + 0.5 * gravity * dt  # the parabola's, at frame t
    positions[0, dynamic] = positions[1, dynamic] - velocity * new_dt + 0.5 * gravity * new_dt**2
    fraction = new_dt / dt
    # world-frame rotation of the step: q_t = d ⊗ q_{t−1}; keep q_t, shrink d's angle
    step = quat_multiply(quaternions[1], quat_conjugate(quaternions[0]))
    axis = np.where(step[:, :1] < 0, -step, step)[:, 1:]  # the short way round
    shrunk = quat_from_axis_angle(axis, fraction * np.radians(quat_angle_deg(quaternions[0], quaternions[1])))
    quaternions[0] = quat_normalize(quat_multiply(quat_conjugate(shrunk), quaternions[1]))
    return positions, quaternions


def scaled_scene(data, key, scale: float, ratio: float = 1.0):
    """A copy of the file holding trajectory `key` at `scale` under the model's gravity (the
    file's over `ratio`, g'/g), history re-timed (module docstring), and the frames t−1 and
    t it started from at the original size (positions, quaternions, velocities, angular
    velocities; velocities None when the file has none).

    The copy has only frames t−1 and t; with c = time_factor(scale, ratio) its velocities are
    scaled by s/c, angular ones by 1/c, its gravity by s/c² (= 1/ratio).
    """
    if not (math.isfinite(scale) and scale > 0):
        raise FignetError(f"the simulation scale must be a positive number, not {scale}")
    trajectory = data.trajectories[key]
    static = np.asarray(trajectory.static, bool)
    moving = ~np.all(np.isclose(trajectory.positions, trajectory.positions[:1], atol=1e-6), axis=(0, 2))
    moving |= ~np.all(np.isclose(trajectory.quaternions, trajectory.quaternions[:1], atol=1e-6), axis=(0, 2))
    if np.any(static & moving):
        raise FignetError(
            f"trajectory {key!r}: static object {int(np.flatnonzero(static & moving)[0])} moves over the given frames, "
            "so the scene cannot be simulated at another scale or re-timed to the model's gravity; "
            "use `sim_scale=1` and give the scene the model's gravity"
        )
    factor = time_factor(scale, ratio)
    positions, quaternions = retimed_history(trajectory, data.dt, data.dt / factor, data.gravity)
    velocities = angular = None
    if trajectory.has_velocities:
        velocities = np.asarray(trajectory.velocities[:2], np.float64)
        angular = np.asarray(trajectory.angular_velocities[:2], np.float64)
    scaled = dataclasses.replace(
        trajectory,
        positions=positions * scale,
        quaternions=quaternions,
        velocities=None if velocities is None else velocities * (scale / factor),
        angular_velocities=None if angular is None else angular / factor,
        scales=np.asarray(trajectory.scales, np.float64) * scale,
        extras={},
    )
    gravity = np.asarray(data.gravity, np.float64) / ratio
    return dataclasses.replace(data, gravity=gravity, trajectories={key: scaled}), (
        positions,
        quaternions,
        velocities,
        angular,
    )


def unscaled_frames(frames, history, scale: float, ratio: float = 1.0):
    """A rollout of `scaled_scene`'s copy mapped back: `history` (its frames t−1, t at the
    original size) followed by the predicted frames, positions / s, velocities · c/s, angular
    velocities · c (c = time_factor(scale, ratio)).

    frames, history : positions (T, O, 3), quaternions (T, O, 4), velocities and angular
    velocities (T, O, 3) or None each
    """
    positions, quaternions, velocities, angular = frames
    factor = time_factor(scale, ratio)
    mapped = [
        np.concatenate([history[0], positions[2:] / scale]),
        np.concatenate([history[1], quaternions[2:]]),
    ]
    for k, (values, back) in enumerate(((velocities, factor / scale), (angular, factor)), start=2):
        if values is not None:
            values = (
                np.concatenate([values[:2] if history[k] is None else history[k] / back, values[2:]]) * back
            )
        mapped.append(values)
    return mapped
