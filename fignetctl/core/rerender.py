"""Re-render a rollout by bending the rays of a static NeRF (DESIGN.md, "Perception").

For a rigid transform R_t(x) = rot(q_t)·(x − origin) + p_t of the object at step t, which maps
its rest place to its place at step t, a sample at x reads the field at b(x):

    move:       b(x) = R_t⁻¹·x  if x ∈ R_t·V_o     (the object, read at its rest place)
                       R_t·x    if x ∈ V_o          (the old place reads where the object went,
                                                     empty space in the original scene)
                       x        otherwise
    duplicate:  b(x) = R_t⁻¹·x  if x ∈ R_t·V_o,  x otherwise   (the original stays)

Where the two boxes overlap the moved box wins, so the object is whole at small motions (the
paper lists V_o first; taken literally, a small move would cut the object where they overlap).
In move mode a sample outside R_t·V_o whose bent point lands in V_o reads empty space: R_t·x of
a point of the old place can land back in V_o when the boxes overlap, and would show a ghost of
the object there (the old place must be empty, what is behind it shows through).
View directions turn with the points. The warp is applied before the occupancy lookup, so a
bent sample is never skipped because its unbent place is empty; and bent rays are sampled over
the scene box grown to hold R_t·V_o, so an object moved partly out of the scene box stays whole.

Only rays that pass through V_o (move) or R_t·V_o (slab test on the oriented box) are bent; an
unedited background image is rendered once per camera and only those pixels are re-rendered.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from fignetctl.core.pinhole import PIXEL_CENTRE, Camera
from fignetctl.core.shapes import box_corners
from fignetctl.core.transforms import quat_to_matrix
from fignetctl.core.volume import Volume
from fignetctl.errors import FignetError

MODES = ("move", "duplicate")
EMPTY_COORDINATE = 1e6
"""A bent sample that must read nothing is sent to (1e6, 1e6, 1e6), far outside the scene box."""
FIT_TOLERANCE = 0.1
"""A rollout's rest mesh may stick out of V_o by this fraction of V_o's longest side."""


# ----------------------------------------------------------------------------- inputs


@dataclasses.dataclass(frozen=True)
class ObjectMotion:
    """The chosen object's rigid motion over the rollout, relative to its rest place.

    rotations : (T, 3, 3) rot(q_t); positions : (T, 3) p_t; origin : (3,) rest position
    name : mesh name; dt : seconds between frames
    """

    rotations: np.ndarray
    positions: np.ndarray
    origin: np.ndarray
    name: str
    dt: float

    def __len__(self) -> int:
        return len(self.positions)

    def forward(self, t: int, points):
        """R_t(x) = rot·(x − origin) + p_t; points (P, 3) numpy."""
        return (np.asarray(points, np.float64) - self.origin) @ self.rotations[t].T + self.positions[t]

    def inverse(self, t: int, points):
        """R_t⁻¹(x) = rotᵀ·(x − p_t) + origin; points (P, 3) numpy."""
        return (np.asarray(points, np.float64) - self.positions[t]) @ self.rotations[t] + self.origin


def choose_object(trajectory, object_name=None) -> int:
    """Index of the object to re-render: `object_name`, else the single dynamic object."""
    names = [str(n) for n in trajectory.mesh_names]
    if object_name is not None:
        if object_name not in names:
            raise FignetError(f"no object {object_name!r} in the rollout (it has {', '.join(names)})")
        index = names.index(object_name)
        if trajectory.static[index]:
            raise FignetError(
                f"object {object_name!r} is static in the rollout; choose a moving one with `object`"
            )
        return index
    dynamic = [i for i in range(len(names)) if not trajectory.static[i]]
    if len(dynamic) != 1:
        listed = ", ".join(names[i] for i in dynamic) or "none"
        raise FignetError(
            f"the rollout has {len(dynamic)} dynamic objects ({listed}); choose one with `object`"
        )
    return dynamic[0]


def object_motion(data, volume: Volume, trajectory_id=None, object_name=None) -> ObjectMotion:
    """The rigid motion of one object of a trajectory file, checked against the volume."""
    ids = list(data.trajectories)
    key = ids[0] if trajectory_id is None else str(trajectory_id)
    if key not in data.trajectories:
        raise FignetError(f"no trajectory {key!r} in the rollout (it has {', '.join(ids[:5])})")
    trajectory = data.trajectories[key]
    index = choose_object(trajectory, object_name)
    name = str(trajectory.mesh_names[index])
    check_object_fits_volume(data.meshes[name].vertices * float(trajectory.scales[index]), name, volume)
    return ObjectMotion(
        rotations=quat_to_matrix(np.asarray(trajectory.quaternions[:, index], np.float64)),
        positions=np.asarray(trajectory.positions[:, index], np.float64),
        origin=volume.origin,
        name=name,
        dt=float(data.dt),
    )


def check_object_fits_volume(object_vertices, name: str, volume: Volume) -> None:
    """Refuse a rollout object that is not the volume's: its rest mesh (object-frame vertices
    (V, 3) placed at the volume's `origin`) must lie in V_o, up to FIT_TOLERANCE."""
    rest = np.asarray(object_vertices, np.float64) + volume.origin
    slack = FIT_TOLERANCE * float((volume.upper - volume.lower).max())
    outside = np.maximum(volume.lower - rest, rest - volume.upper).max()
    if outside > slack:
        raise FignetError(
            f"the rollout's object {name!r} does not fit the volume: its rest mesh sticks out of V_o by "
            f"{outside:.3g} m (tolerance {slack:.3g} m); was the rollout made from this volume's mesh?"
        )


# ----------------------------------------------------------------------------- geometry


def rays_hit_box(origins, directions, lower, upper) -> np.ndarray:
    """(R,) bool: the ray o + t·d, t >= 0, meets the axis-aligned box (slab method).

    origins, directions : (R, 3) float; lower, upper : (3,)
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / np.where(directions == 0.0, 1e-300, directions)
        t_low, t_high = (lower - origins) * inverse, (upper - origins) * inverse
    near = np.maximum(np.minimum(t_low, t_high).max(axis=-1), 0.0)
    far = np.maximum(t_low, t_high).min(axis=-1)
    return near <= far


def rays_hit_moved_box(origins, directions, motion: ObjectMotion, t: int, lower, upper) -> np.ndarray:
    """(R,) bool: the ray meets R_t·V_o, an oriented box (the ray taken to the rest frame)."""
    rest_origins = motion.inverse(t, origins)
    rest_directions = np.asarray(directions, np.float64) @ motion.rotations[t]
    return rays_hit_box(rest_origins, rest_directions, lower, upper)


def bent_rays(origins, directions, motion: ObjectMotion, t: int, volume: Volume, mode: str) -> np.ndarray:
    """(R,) bool: the rays a bending changes at step t (through R_t·V_o, and V_o for move)."""
    hit = rays_hit_moved_box(origins, directions, motion, t, volume.lower, volume.upper)
    if mode == "move":
        hit |= rays_hit_box(origins, directions, volume.lower, volume.upper)
    return hit


def make_warp(motion: ObjectMotion, t: int, volume: Volume, mode: str, device="cpu"):
    """The bending b(x) at step t as a torch warp: points (P, 3), directions (P, 3) -> both bent."""
    import torch

    as_tensor = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)
    rotation, position, origin = (
        as_tensor(motion.rotations[t]),
        as_tensor(motion.positions[t]),
        as_tensor(motion.origin),
    )
    lower, upper = as_tensor(volume.lower), as_tensor(volume.upper)
    inside = lambda p: ((p >= lower) & (p <= upper)).all(dim=-1, keepdim=True)
    empty = torch.full((3,), EMPTY_COORDINATE, device=device)  # outside any scene box: no density there

    def warp(points, directions):
        rest = (points - position) @ rotation + origin  # R_t⁻¹·x
        in_moved = inside(rest)
        bent, turned = (
            torch.where(in_moved, rest, points),
            torch.where(in_moved, directions @ rotation, directions),
        )
        if mode == "move":
            in_old = inside(points) & ~in_moved
            forward = (points - origin) @ rotation.T + position  # R_t·x
            bent, turned = (
                torch.where(in_old, forward, bent),
                torch.where(in_old, directions @ rotation.T, turned),
            )
            bent = torch.where(
                ~in_moved & inside(bent), empty, bent
            )  # the object's rest box, read off its moved box
        return bent, turned

    return warp


# ----------------------------------------------------------------------------- rendering


def render_rays(model, origins, directions, warp=None, box=None, chunk: int = 16384) -> dict:
    """Volume-render rays (R, 3) numpy with `model`, sampled inside `box` (2, 3) (default: the
    scene box). Returns numpy rgb (R, 3), depth (R,) (ray parameter; z-depth for pixel rays),
    opacity (R,). The same sampling and compositing as NerfModel.render_rays; a warp here
    takes (points, directions), so view directions turn with the points."""
    import torch

    from fignetctl.core.nerf.renderer import render_samples, sample_along_rays

    device = model.field.density_grid.device
    box = model.bounds if box is None else np.asarray(box)
    low, high = (torch.as_tensor(b, dtype=torch.float32, device=device) for b in box)
    o_all = torch.as_tensor(np.asarray(origins), dtype=torch.float32, device=device).reshape(-1, 3)
    d_all = torch.as_tensor(np.asarray(directions), dtype=torch.float32, device=device).reshape(-1, 3)
    parts = []
    with torch.no_grad():
        for o, d in zip(o_all.split(chunk), d_all.split(chunk)):
            samples = sample_along_rays(o, d, low, high, model.step_length, near=model.config.near)
            bend = None if warp is None else _point_warp(warp, d, samples.valid)
            rgb, depth, opacity, _ = render_samples(
                model.field,
                model.occupancy,
                samples,
                d,
                model.background(d),
                bend,
                model.config.weight_threshold,
            )
            parts.append((rgb.clamp(0, 1), depth, opacity))
    if not parts:
        return {
            "rgb": np.zeros((0, 3), np.float32),
            "depth": np.zeros(0, np.float32),
            "opacity": np.zeros(0, np.float32),
        }
    return {
        key: torch.cat([p[i] for p in parts]).float().cpu().numpy()
        for i, key in enumerate(("rgb", "depth", "opacity"))
    }


def _point_warp(warp, directions, valid):
    """Adapt warp(points, directions) to render_samples' warp(points) -> (points, directions):
    render_samples queries the valid samples in row-major order, so their rays are known."""
    ray_of_sample = valid.nonzero(as_tuple=True)[0]
    return lambda points: warp(points, directions[ray_of_sample])


def bending_box(model, motion: ObjectMotion, t: int, volume: Volume) -> np.ndarray:
    """(2, 3) box to sample bent rays in: the scene box grown to hold R_t·V_o."""
    moved = motion.forward(t, box_corners(volume.lower, volume.upper))
    bounds = model.bounds
    return np.stack([np.minimum(bounds[0], moved.min(0)), np.maximum(bounds[1], moved.max(0))])


@dataclasses.dataclass
class Frame:
    """One re-rendered frame: rgb (H, W, 3) float32, depth (H, W), opacity (H, W), bent (H, W) bool."""

    rgb: np.ndarray
    depth: np.ndarray
    opacity: np.ndarray
    bent: np.ndarray
    seconds: float


class Rerenderer:
    """Renders the steps of an object's motion through one NeRF, reusing an unedited background
    image per camera and re-rendering only the pixels whose rays the bending changes."""

    def __init__(self, model, volume: Volume, motion: ObjectMotion, mode: str = "move"):
        if mode not in MODES:
            raise FignetError(f"mode {mode!r} is not one of {', '.join(MODES)}")
        self.model, self.volume, self.motion, self.mode = model, volume, motion, mode
        self.device = model.field.density_grid.device
        self._backgrounds = {}
        self.background_seconds = []

    def background(self, camera) -> dict:
        """The unedited render of a camera (K, c2w, width, height), cached by its pose."""
        key = _camera_key(camera)
        if key not in self._backgrounds:
            started = time.perf_counter()
            origins, directions = Camera(*camera).rays()
            self._backgrounds[key] = render_rays(self.model, origins, directions)
            self.background_seconds.append(time.perf_counter() - started)
        return self._backgrounds[key]

    def render(self, camera, t: int) -> Frame:
        """Step t seen by `camera` (K, c2w, width, height)."""
        background = self.background(camera)
        started = time.perf_counter()
        width, height = int(camera[2]), int(camera[3])
        origins, directions = Camera(*camera).rays()
        bent = bent_rays(origins, directions, self.motion, t, self.volume, self.mode)
        images = {key: value.copy() for key, value in background.items()}
        if bent.any():
            warp = make_warp(self.motion, t, self.volume, self.mode, self.device)
            box = bending_box(self.model, self.motion, t, self.volume)
            out = render_rays(self.model, origins[bent], directions[bent], warp, box)
            for key, image in images.items():
                image[bent] = out[key]
        shape = lambda a, *rest: a.reshape(height, width, *rest)
        return Frame(
            shape(images["rgb"], 3),
            shape(images["depth"]),
            shape(images["opacity"]),
            shape(bent),
            time.perf_counter() - started,
        )


def _camera_key(camera):
    K, c2w, width, height = camera
    return (
        np.asarray(K, np.float64).tobytes(),
        np.asarray(c2w, np.float64).tobytes(),
        int(width),
        int(height),
    )


# ----------------------------------------------------------------------------- cameras


def draw_trace(image, camera, positions, colour=(255, 210, 0)):
    """Draw the object's path so far (world positions (n, 3)) on an RGB uint8 image, in place."""
    import cv2

    pixels, depth = Camera(*camera).project(positions)
    front = depth > 1e-6
    points = np.round((pixels[front] - PIXEL_CENTRE) * 16).astype(
        np.int32
    )  # 4 fractional bits; OpenCV's pixel centres are at integers
    thickness = max(1, int(round(image.shape[0] / 240)))
    if len(points) > 1:
        cv2.polylines(image, [points.reshape(-1, 1, 2)], False, colour, thickness, cv2.LINE_AA, shift=4)
    if len(points) and front[-1]:
        cv2.circle(
            image, tuple(int(v) for v in points[-1]), 16 * (thickness + 2), colour, -1, cv2.LINE_AA, shift=4
        )
    return image


# ----------------------------------------------------------------------------- frames


def to_uint8(rgb) -> np.ndarray:
    """(H, W, 3) float in [0, 1] -> uint8."""
    return np.clip(np.round(np.asarray(rgb) * 255.0), 0, 255).astype(np.uint8)


def render_frames(renderer: Rerenderer, shots, trace=False):
    """Render each (step, camera (K, c2w, width, height)) of `shots` in order; yields (step,
    camera, Frame, image), the image the frame's RGB as uint8 (H, W, 3), with the object's path
    so far drawn on it when `trace`."""
    steps = []
    for step, camera in shots:
        steps.append(step)
        frame = renderer.render(camera, step)
        image = to_uint8(frame.rgb)
        if trace:
            draw_trace(image, camera, renderer.motion.positions[steps])
        yield step, camera, frame, image
