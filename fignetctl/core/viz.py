"""Look at a trajectory: a rerun recording, or a CPU-rendered preview frame / mp4.

The preview renderer is deliberately simple: a fixed pinhole camera above the scene at an
angle, triangles projected in one vectorised step, back faces culled, the rest painted far
to near (painter's algorithm) with flat Lambert shading and one colour per object. A flat
static object (the floor) is drawn as a grid instead of its few huge triangles.

OpenCV and rerun are imported inside the functions that use them.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from fignetctl.core import pinhole
from fignetctl.core.atomic import atomic_path
from fignetctl.core.pinhole import Camera
from fignetctl.core.rerun_log import import_rerun, recording
from fignetctl.core.trajectory import Trajectory, TrajectoryFile
from fignetctl.core.trajectory_summary import energies, lowest_vertex_heights
from fignetctl.core.transforms import quat_to_matrix
from fignetctl.errors import FignetError

# Tableau-like palette, RGB; dynamic objects take these in turn, static ones are grey.
OBJECT_COLOURS = np.array(
    [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (188, 189, 34),
        (23, 190, 207),
        (127, 127, 127),
    ],
    np.float64,
)
STATIC_COLOUR = (170.0, 170.0, 160.0)
BACKGROUND_COLOUR = (235, 238, 242)
FLOOR_COLOUR = (214, 214, 206)
GRID_COLOUR = (160, 160, 150)
SHADOW_COLOUR = (180, 180, 172)
NEAR_PLANE = 0.05


def object_colours(trajectory: Trajectory) -> np.ndarray:
    """(O, 3) RGB colour per object: the palette for dynamic objects, grey for static ones."""
    colours = np.empty((trajectory.num_objects, 3))
    dynamic_index = 0
    for index in range(trajectory.num_objects):
        if trajectory.static[index]:
            colours[index] = STATIC_COLOUR
        else:
            colours[index] = OBJECT_COLOURS[dynamic_index % len(OBJECT_COLOURS)]
            dynamic_index += 1
    return colours


def _get_trajectory(data: TrajectoryFile, trajectory_id) -> Trajectory:
    key = str(trajectory_id)
    if key not in data.trajectories:
        raise FignetError(f"no trajectory {key!r}; the file has {', '.join(list(data.trajectories)[:5])}...")
    return data.trajectories[key]


# ----------------------------------------------------------------------------- camera


def look_at_camera(eye, target, size, fov_y_deg: float = 40.0) -> Camera:
    """A camera at `eye` looking at `target` with z up; size = (width, height)."""
    K = pinhole.intrinsics_from_fov(size[0], size[1], fov_y_deg)
    return Camera(K, pinhole.look_at(eye, target), int(size[0]), int(size[1]))


def _fixed_point(image_points: np.ndarray) -> np.ndarray:
    """Image points -> OpenCV drawing coordinates with 4 fractional bits (shift=4); OpenCV puts
    pixel centres at integers, pinhole at +0.5."""
    return np.round((image_points - pinhole.PIXEL_CENTRE) * 16).astype(np.int32)


def fit_camera(
    data, trajectory_id, size=(480, 360), azimuth_deg=-60.0, elevation_deg=35.0, fov_y_deg=40.0
) -> Camera:
    """A fixed camera that keeps every dynamic object of the trajectory in view at all frames.

    It looks at the centre of the box swept by the objects (down to the floor) from the
    given azimuth (around z, from +x) and elevation, as close as it can while the box's
    eight corners stay inside the image (with a small margin).
    """
    low, high = scene_bounds(data, trajectory_id)
    centre, radius = (low + high) / 2.0, max(float(np.linalg.norm(high - low)) / 2.0, 1e-3)
    half_fov_y = math.radians(fov_y_deg) / 2.0
    half_fov_x = math.atan(math.tan(half_fov_y) * size[0] / size[1])
    azimuth, elevation = math.radians(azimuth_deg), math.radians(elevation_deg)
    direction = np.array(
        [
            math.cos(azimuth) * math.cos(elevation),
            math.sin(azimuth) * math.cos(elevation),
            math.sin(elevation),
        ]
    )
    corners = np.array(
        [[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])]
    )

    def camera_at(distance):
        return look_at_camera(centre + distance * direction, centre, size, fov_y_deg)

    far = radius / math.sin(min(half_fov_x, half_fov_y))  # the bounding sphere fits: always in view
    near = 0.0
    for _ in range(30):  # bisection on the closest distance that keeps the corners in view
        middle = (near + far) / 2.0
        near, far = (near, middle) if _corners_in_view(camera_at(middle), corners) else (middle, far)
    return camera_at(far)


def _corners_in_view(camera: Camera, corners: np.ndarray, margin: float = 0.04) -> bool:
    pixels, depth = camera.project(corners)
    inside_x = (pixels[:, 0] >= margin * camera.width) & (pixels[:, 0] <= (1 - margin) * camera.width)
    inside_y = (pixels[:, 1] >= margin * camera.height) & (pixels[:, 1] <= (1 - margin) * camera.height)
    return bool(np.all((depth > NEAR_PLANE) & inside_x & inside_y))


def scene_bounds(data: TrajectoryFile, trajectory_id) -> tuple:
    """(3,) low and high corners of the box swept by the dynamic objects, down to the floor.

    Each object counts as a sphere of its scaled mesh's radius around its positions; with no
    dynamic object, every object counts.
    """
    trajectory = _get_trajectory(data, trajectory_id)
    chosen = ~np.asarray(trajectory.static, bool)
    if not chosen.any():
        chosen = np.ones_like(chosen)
    radii = np.array(
        [
            float(trajectory.scales[i]) * np.linalg.norm(data.meshes[str(n)].vertices, axis=1).max()
            for i, n in enumerate(trajectory.mesh_names)
        ]
    )
    positions = np.asarray(trajectory.positions, np.float64)[:, chosen]
    low = (positions - radii[chosen, None]).reshape(-1, 3).min(axis=0)
    high = (positions + radii[chosen, None]).reshape(-1, 3).max(axis=0)
    floor = floor_height(data, trajectory)
    if floor is not None:  # objects rest on the floor: nothing to see below it
        low[2], high[2] = floor, max(high[2], floor)
    return low, high


def _flat_static_objects(data: TrajectoryFile, trajectory: Trajectory) -> list:
    """(index, top z) of static objects at least 20 times wider than tall, at frame 0."""
    rotations = quat_to_matrix(trajectory.quaternions[0])
    result = []
    for index, name in enumerate(trajectory.mesh_names):
        if not trajectory.static[index]:
            continue
        local = float(trajectory.scales[index]) * np.asarray(data.meshes[str(name)].vertices, np.float64)
        world = local @ rotations[index].T + trajectory.positions[0, index]
        extent = np.ptp(world, axis=0)
        if extent[2] * 20.0 <= min(extent[0], extent[1]):
            result.append((index, float(world[:, 2].max())))
    return result


def floor_height(data: TrajectoryFile, trajectory: Trajectory):
    """Top z of the highest flat static object (the floor), or None if there is none."""
    flats = _flat_static_objects(data, trajectory)
    return max(top for _, top in flats) if flats else None


# ----------------------------------------------------------------------------- renderer


@dataclasses.dataclass
class _SceneMeshes:
    """Every drawn object's mesh concatenated, so a frame is posed in one step.

    local_vertices : (V, 3) scaled vertices in their object frames
    vertex_objects : (V,) object index of each vertex
    faces : (F, 3) indices into local_vertices
    face_colours : (F, 3) RGB
    """

    local_vertices: np.ndarray
    vertex_objects: np.ndarray
    faces: np.ndarray
    face_colours: np.ndarray


def _scene_meshes(data: TrajectoryFile, trajectory: Trajectory, skip: set) -> _SceneMeshes:
    colours = object_colours(trajectory)
    vertices, objects, faces, face_colours, offset = [], [], [], [], 0
    for index, name in enumerate(trajectory.mesh_names):
        if index in skip:
            continue
        mesh = data.meshes[str(name)]
        vertices.append(float(trajectory.scales[index]) * np.asarray(mesh.vertices, np.float64))
        objects.append(np.full(len(mesh.vertices), index))
        faces.append(np.asarray(mesh.faces, np.int64) + offset)
        face_colours.append(np.repeat(colours[index][None], len(mesh.faces), axis=0))
        offset += len(mesh.vertices)
    if not vertices:
        return _SceneMeshes(np.zeros((0, 3)), np.zeros(0, int), np.zeros((0, 3), int), np.zeros((0, 3)))
    return _SceneMeshes(*(np.concatenate(a) for a in (vertices, objects, faces, face_colours)))


class PreviewRenderer:
    """Renders frames of one trajectory from one fixed camera; set up once, render many."""

    def __init__(self, data: TrajectoryFile, trajectory_id, size=(480, 360), camera: Camera | None = None):
        self.trajectory = _get_trajectory(data, trajectory_id)
        self.trajectory_id = str(trajectory_id)
        self.dt = float(data.dt)
        self.camera = camera or fit_camera(data, trajectory_id, size)
        flats = _flat_static_objects(data, self.trajectory)
        self.floor_z = max(top for _, top in flats) if flats else None
        self.meshes = _scene_meshes(data, self.trajectory, {index for index, _ in flats})
        self.grid_low, self.grid_high = scene_bounds(data, trajectory_id)
        toward_camera = self.camera.eye - (self.grid_low + self.grid_high) / 2.0
        light = toward_camera / np.linalg.norm(toward_camera) + np.array([0.3, 0.2, 1.0])
        self.light = light / np.linalg.norm(light)

    def render(self, frame: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB image of one frame."""
        import cv2

        image = np.empty((self.camera.height, self.camera.width, 3), np.uint8)
        image[:] = BACKGROUND_COLOUR
        world = self._posed_vertices(frame)
        if self.floor_z is not None:
            self._draw_floor(image)
            self._draw_shadows(image, world)
        self._draw_triangles(image, world)
        label = f"trajectory {self.trajectory_id}  frame {frame}  t={frame * self.dt:.2f} s"
        cv2.putText(image, label, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (60, 60, 60), 1, cv2.LINE_AA)
        return image

    def _posed_vertices(self, frame: int) -> np.ndarray:
        rotations = quat_to_matrix(self.trajectory.quaternions[frame])
        positions = np.asarray(self.trajectory.positions[frame], np.float64)
        objects = self.meshes.vertex_objects
        return np.einsum("vij,vj->vi", rotations[objects], self.meshes.local_vertices) + positions[objects]

    def _visible_faces(self, world: np.ndarray, depth: np.ndarray) -> tuple:
        """Front-facing faces with all vertices before the near plane, far to near; and shading."""
        triangles = world[self.meshes.faces]
        normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        facing = np.einsum("fi,fi->f", normals, triangles.mean(axis=1) - self.camera.eye) < 0
        in_front = (depth[self.meshes.faces] > NEAR_PLANE).all(axis=1)
        chosen = np.flatnonzero(facing & in_front)
        face_depth = depth[self.meshes.faces[chosen]].mean(axis=1)
        chosen = chosen[np.argsort(-face_depth, kind="stable")]
        brightness = 0.35 + 0.65 * np.clip(normals[chosen] @ self.light, 0.0, 1.0)
        return chosen, brightness

    def _draw_shadows(self, image: np.ndarray, world: np.ndarray) -> None:
        """Each dynamic object's outline dropped straight down onto the floor: a height cue."""
        import cv2

        for index in np.flatnonzero(~np.asarray(self.trajectory.static, bool)):
            points = world[self.meshes.vertex_objects == index].copy()
            if len(points) < 3:
                continue
            points[:, 2] = self.floor_z
            pixels, depth = self.camera.project(points)
            if (depth > NEAR_PLANE).all():
                hull = cv2.convexHull(_fixed_point(pixels))
                cv2.fillConvexPoly(image, hull, SHADOW_COLOUR, cv2.LINE_AA, 4)

    def _draw_triangles(self, image: np.ndarray, world: np.ndarray) -> None:
        import cv2

        if len(self.meshes.faces) == 0:
            return
        pixels, depth = self.camera.project(world)
        chosen, brightness = self._visible_faces(world, depth)
        polygons = _fixed_point(pixels[self.meshes.faces[chosen]])
        colours = np.clip(self.meshes.face_colours[chosen] * brightness[:, None], 0, 255).astype(int).tolist()
        for polygon, colour in zip(polygons, colours):
            cv2.fillConvexPoly(image, polygon, colour, cv2.LINE_AA, 4)

    def _draw_floor(self, image: np.ndarray) -> None:
        low, high, step = _grid_extent(self.grid_low, self.grid_high)
        corners = np.array([[low[0], low[1]], [high[0], low[1]], [high[0], high[1]], [low[0], high[1]]])
        self._draw_polygon(image, corners, FLOOR_COLOUR, fill=True)
        for x in np.arange(low[0], high[0] + step / 2, step):
            self._draw_polygon(image, np.array([[x, low[1]], [x, high[1]]]), GRID_COLOUR)
        for y in np.arange(low[1], high[1] + step / 2, step):
            self._draw_polygon(image, np.array([[low[0], y], [high[0], y]]), GRID_COLOUR)

    def _draw_polygon(self, image, xy: np.ndarray, colour, fill: bool = False) -> None:
        import cv2

        points = np.column_stack([xy, np.full(len(xy), self.floor_z)])
        pixels, depth = self.camera.project(points)
        if (depth <= NEAR_PLANE).any():
            return
        pixels = _fixed_point(pixels)
        if fill:
            cv2.fillConvexPoly(image, pixels, colour, cv2.LINE_AA, 4)
        else:
            cv2.polylines(image, [pixels], False, colour, 1, cv2.LINE_AA, 4)


def _grid_extent(low: np.ndarray, high: np.ndarray) -> tuple:
    """Grid corners (xy) snapped to a round step that gives about 10 lines across."""
    span = float(max(high[0] - low[0], high[1] - low[1], 1e-6))
    step = 10 ** math.floor(math.log10(span / 10.0))
    for factor in (1, 2, 5, 10):
        if span / (step * factor) <= 12:
            step *= factor
            break
    grid_low = np.floor(low[:2] / step) * step - step
    grid_high = np.ceil(high[:2] / step) * step + step
    return grid_low, grid_high, step


def render_frame(
    data: TrajectoryFile, trajectory_id, frame: int = -1, size=(480, 360), camera: Camera | None = None
) -> np.ndarray:
    """(H, W, 3) uint8 RGB preview of one frame (negative frames count from the end)."""
    renderer = PreviewRenderer(data, trajectory_id, size, camera)
    frames = renderer.trajectory.num_frames
    if not -frames <= frame < frames:
        raise FignetError(
            f"frame {frame} is outside the trajectory's {frames} frames (0..{frames - 1}, or -1 for the last)"
        )
    return renderer.render(frame % frames)


def write_preview_png(
    data: TrajectoryFile, trajectory_id, path_png, frame: int = -1, size=(480, 360)
) -> Path:
    """Render one frame and write it as a PNG, atomically."""
    import cv2

    image = render_frame(data, trajectory_id, frame, size)
    path_png = Path(path_png)
    with atomic_path(path_png, suffix=".png") as tmp:
        if not cv2.imwrite(
            str(tmp), cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9]
        ):
            raise FignetError(f"{path_png}: OpenCV could not write the PNG")
    return path_png


def render_preview_video(
    data: TrajectoryFile, trajectory_id, path_mp4, size=(480, 360), fps=None, progress=None
) -> Path:
    """Render every frame of a trajectory to an H.264 mp4 (media.py), atomically.

    fps : frames per second of the video; default 1 / dt, so the video plays in real time
    progress : optional wrapper for the frame iterator (a progress bar)
    """
    from fignetctl.core.media import Mp4Writer

    renderer = PreviewRenderer(data, trajectory_id, size)
    fps = float(fps) if fps else 1.0 / float(data.dt)
    frames = range(renderer.trajectory.num_frames)
    path_mp4 = Path(path_mp4)
    with (
        atomic_path(path_mp4, suffix=".mp4") as tmp,
        Mp4Writer(tmp, fps, int(size[0]), int(size[1])) as writer,
    ):
        for frame in progress(frames) if progress else frames:
            writer.write(renderer.render(frame))
    return path_mp4


# ----------------------------------------------------------------------------- rerun


def _object_entity(root: str, index: int, name: str) -> str:
    return f"{root}/objects/{index:02d}_{name}"


def _log_meshes(rec, rr, data: TrajectoryFile, trajectory: Trajectory, root: str) -> None:
    """Each object's mesh once, static, in its object frame (unscaled; the transform scales)."""
    import trimesh

    colours = object_colours(trajectory).astype(np.uint8)
    rec.log(root, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for index, name in enumerate(trajectory.mesh_names):
        mesh = data.meshes[str(name)]
        normals = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals
        rec.log(
            _object_entity(root, index, str(name)),
            rr.Mesh3D(
                vertex_positions=np.asarray(mesh.vertices, np.float32),
                triangle_indices=np.asarray(mesh.faces, np.uint32),
                vertex_normals=np.asarray(normals, np.float32),
                albedo_factor=colours[index],
            ),
            static=True,
        )


def _log_traces(rec, rr, trajectory: Trajectory, root: str) -> None:
    """The whole path of each dynamic object's centre, as one static line strip."""
    colours = object_colours(trajectory).astype(np.uint8)
    for index, name in enumerate(trajectory.mesh_names):
        if trajectory.static[index]:
            continue
        rec.log(
            f"{root}/traces/{index:02d}_{name}",
            rr.LineStrips3D(
                [np.asarray(trajectory.positions[:, index], np.float32)], colors=[colours[index]], radii=0.01
            ),
            static=True,
        )


def _log_frames(rec, rr, data: TrajectoryFile, trajectory: Trajectory, root: str) -> None:
    """Per frame: every object's pose, and the energies and lowest vertex height as scalars;
    each series sent whole, in one `send_columns` call (docs/show.md times it against a `log`
    call per frame and object)."""
    frames = np.arange(trajectory.num_frames)
    terms = energies(data, trajectory)
    lowest = lowest_vertex_heights(data, trajectory)
    quaternions_xyzw = np.asarray(trajectory.quaternions, np.float32)[..., [1, 2, 3, 0]]
    positions = np.asarray(trajectory.positions, np.float32)

    def times(keep=slice(None)):
        return [
            rr.TimeColumn("frame", sequence=frames[keep]),
            rr.TimeColumn("time", duration=frames[keep] * float(data.dt)),
        ]

    for index, name in enumerate(trajectory.mesh_names):
        rec.send_columns(
            _object_entity(root, index, str(name)),
            indexes=times(),
            columns=rr.Transform3D.columns(
                translation=positions[:, index],
                quaternion=quaternions_xyzw[:, index],
                scale=np.full((len(frames), 3), float(trajectory.scales[index]), np.float32),
            ),
        )
    for term, values in terms.items():
        rec.send_columns(
            f"{root}/plots/energy/{term}",
            indexes=times(),
            columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)),
        )
    finite = np.isfinite(lowest)
    if finite.any():
        rec.send_columns(
            f"{root}/plots/lowest_vertex_z",
            indexes=times(finite),
            columns=rr.Scalars.columns(scalars=np.asarray(lowest, np.float64)[finite]),
        )


def log_trajectory(rec, data: TrajectoryFile, trajectory_id, entity_root: str = "world") -> None:
    """Log one trajectory into an open rerun RecordingStream `rec` under `entity_root`.

    Entities: <root>/objects/<i>_<mesh> (Mesh3D, static, plus a Transform3D per frame),
    <root>/traces/<i>_<mesh> (LineStrips3D), <root>/plots/energy/<term> and
    <root>/plots/lowest_vertex_z (Scalars). Timelines: "frame" (sequence) and "time" (s).
    """
    rr = import_rerun()
    trajectory = _get_trajectory(data, trajectory_id)
    _log_meshes(rec, rr, data, trajectory, entity_root)
    _log_traces(rec, rr, trajectory, entity_root)
    _log_frames(rec, rr, data, trajectory, entity_root)


def _blueprint(entity_root: str):
    rrb = import_rerun().blueprint

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                origin=entity_root, contents=[f"{entity_root}/objects/**", f"{entity_root}/traces/**"]
            ),
            rrb.TimeSeriesView(origin=f"{entity_root}/plots"),
            column_shares=[2, 1],
        )
    )


def log_trajectory_to_rerun(
    data: TrajectoryFile, trajectory_id, path_rrd, entity_root: str = "world"
) -> Path:
    """Write one trajectory to a rerun recording file (.rrd), atomically.

    Open it with `rerun FILE.rrd`: the meshes move on the "frame" and "time" timelines,
    with energy plots beside them.
    """
    _get_trajectory(data, trajectory_id)
    with recording(path_rrd, _blueprint(entity_root)) as (_, rec):
        log_trajectory(rec, data, trajectory_id, entity_root)
    return Path(path_rrd)


def log_scalars_to_rerun(path_rrd, entity_root: str, series: dict) -> Path:
    """Write scalar curves to a rerun recording (.rrd), atomically.

    series : name -> list of (step, value); logged as <root>/<name> on the "step" timeline
    """
    with recording(path_rrd) as (rr, rec):
        log_scalar_series(rr, rec, entity_root, series)
    return Path(path_rrd)


def log_scalar_series(rr, rec, entity_root: str, series: dict) -> None:
    """Scalar curves (name -> list of (step, value)) into an open stream `rec`, as
    <root>/<name> on the "step" timeline: each curve in one `send_columns` call."""
    for name, points in series.items():
        if len(points) == 0:
            continue
        steps, values = zip(*points)
        rec.send_columns(
            f"{entity_root}/{name}",
            indexes=[rr.TimeColumn("step", sequence=np.asarray(steps, np.int64))],
            columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)),
        )


def log_scalar_step(rr, rec, entity_root: str, step: int, values: dict) -> None:
    """One step of scalar curves (name -> value) into `rec`: the entities of
    `log_scalar_series`, for a viewer watching a run (`live_recording`)."""
    rec.set_time("step", sequence=int(step))
    for name, value in values.items():
        rec.log(f"{entity_root}/{name}", rr.Scalars(float(value)))
