"""A bundled capture: a tabletop scene rendered with PyBullet's TinyRenderer from an orbit.

No real capture can be downloaded here, so the perception pipeline (`capture-poses`,
`fit-nerf`, `extract-mesh`) starts from this one. The scene is a richly textured table top
(2.4 m square, top surface at z = 0) closed by four textured backdrop walls 1 m high, a metal
tray at the centre and 2-4 everyday objects resting in it (duck, teddy, ball, brick, mug from
`pybullet_data`, at real sizes). World: metres, z up. Textures are made procedurally with numpy
and OpenCV from the seed and do not repeat, so COLMAP finds features everywhere; everything a
camera sees lies inside `scene.json`'s `bounds` box, so a NeRF can fit it in that box.

Cameras orbit the tray on a wavy ring (elevation between 25 and 50 degrees, two waves per turn),
all looking at the tray's centre; the video follows the same closed path with `video_step`
frames per view, so video frame `k * video_step` is view `k`.

`render_capture` renders it in memory (a `Capture`); the render-views stage
(`fignetctl.stages.render_views.write_capture`) writes the folder, to a temporary sibling then
renamed into place:

    images/view_000.png ...        RGB PNG, width x height
    video.mp4                      the orbit, H.264, frame k*video_step == view k (optional)
    ground_truth/cameras.npz       fignetctl.core.cameras format: K, c2w (OpenCV), points,
                                   point_colors (a few thousand points unprojected from GT depth)
    ground_truth/depth.npz         depth (N,H,W) float32 metres, z along the optical axis;
                                   image_names
    ground_truth/masks.npz         masks (N,H,W) int16 scene-object id per pixel (-1: nothing);
                                   ids (K,) int16, names (K,) str; image_names
    ground_truth/objects/<name>.obj  each scene object's mesh in world coordinates at its pose
    ground_truth/scene.json        objects (id, name, role, movable, urdf, mesh file, scale,
                                   position, quaternion wxyz), bounds, camera path, settings
    prompts.json                   per movable object, point prompts {image, u, v} in >= 2 views
    measurements.json              camera_height_m: the cameras' mean height above the table
                                   top, as a user would measure it (capture-poses --camera-height)

Pixel convention: pixel (u, v) (column, row, from the top left) is the ray through the image
point (u + 0.5, v + 0.5) of K, as in COLMAP and nerfstudio. TinyRenderer samples a pixel at its
corner, so K's principal point is (width / 2 + 0.5, height / 2 - 0.5), not the image's middle
(see `intrinsics`); GT depth, masks and projections of the GT meshes agree to the pixel.

    from fignetctl.core.synthetic_capture import capture_settings
    from fignetctl.stages.render_views import write_capture
    write_capture("capture", capture_settings(views=40, width=320, height=240, seed=0))  # ~10 s on 2 cores
    write_capture("tiny", capture_settings(views=8, width=80, height=60, video=False))  # < 1 s, for tests
"""

from __future__ import annotations

import dataclasses
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from fignetctl.core import pinhole
from fignetctl.core.obj import read_obj
from fignetctl.errors import FignetError

PROMPTS_FORMAT = "fignetctl.prompts"
SCENE_FORMAT = "fignetctl.scene"
FORMAT_VERSION = 1


@dataclasses.dataclass(frozen=True)
class CaptureSettings:
    """Settings of one bundled capture (written into scene.json)."""

    views: int = 40  # number of still views on the orbit
    width: int = 320  # image width in pixels
    height: int = 240  # image height in pixels
    seed: int = 0  # chooses the objects, their poses and the textures
    video: bool = True  # also write video.mp4
    video_step: int = 3  # video frames per view interval (frame k*video_step is view k)
    video_fps: int = 24  # frames per second of video.mp4
    num_objects: int = 3  # movable objects in the tray, 2-4
    fov_y_deg: float = 48.0  # vertical field of view
    radius: float = 0.8  # distance from the cameras to the look-at point, metres
    elevation_deg: tuple = (25.0, 50.0)  # lowest and highest camera elevation on the orbit
    near: float = 0.05  # near plane of the projection, metres
    far: float = 6.0  # far plane, metres
    texture_size: int = 1024  # side of each procedural texture, pixels
    points: int = 4000  # GT points sampled into cameras.npz
    prompts_per_object: int = 3  # views with a point prompt per movable object (>= 2; at most views)

    def validate(self) -> CaptureSettings:
        checks = [
            (self.views >= 2, f"views must be at least 2, got {self.views}"),
            (16 <= self.width <= 4096, f"width must be in 16..4096 pixels, got {self.width}"),
            (16 <= self.height <= 4096, f"height must be in 16..4096 pixels, got {self.height}"),
            (self.video_step >= 1, f"video_step must be at least 1, got {self.video_step}"),
            (
                2 <= self.num_objects <= len(OBJECT_ASSETS),
                f"num_objects must be in 2..{len(OBJECT_ASSETS)}, got {self.num_objects}",
            ),
            (0 < self.fov_y_deg < 150, f"fov_y_deg must be in (0, 150), got {self.fov_y_deg}"),
            (
                self.prompts_per_object >= 2,
                f"prompts_per_object must be at least 2, got {self.prompts_per_object}",
            ),
        ]
        for ok, message in checks:
            if not ok:
                raise FignetError(message)
        return self


# Keyword arguments of capture_settings: capture_settings(**PRESETS["tiny"]).
PRESETS = {
    "default": {},  # 40 views 320x240 + a 120-frame video: ~10 s; COLMAP registers every view
    "tiny": dict(views=8, width=80, height=60, texture_size=256, points=500, video_step=2),  # < 1 s, tests
}


@dataclasses.dataclass(frozen=True)
class ObjectAsset:
    """An everyday object from pybullet_data, made upright and to real size."""

    name: str
    mesh: str  # visual mesh, relative to pybullet_data
    urdf: str  # the pybullet_data URDF it comes from
    scale: float  # uniform scale of the mesh file
    upright_euler: tuple  # rotation (x, y, z radians) that makes the mesh stand with z up
    rgba: tuple | None  # colour for meshes without a texture


OBJECT_ASSETS = (
    ObjectAsset("duck", "duck.obj", "duck_vhacd.urdf", 0.05, (math.pi / 2, 0, 0), None),
    ObjectAsset(
        "teddy", "teddy2_VHACD_CHs.obj", "teddy_vhacd.urdf", 0.15, (math.pi / 2, 0, 0), (0.62, 0.38, 0.2, 1)
    ),
    ObjectAsset("ball", "soccerball.obj", "soccerball.urdf", 0.12, (0, 0, 0), None),
    ObjectAsset("brick", "lego/lego.obj", "lego/lego.urdf", 0.2, (math.pi / 2, 0, 0), (0.85, 0.1, 0.1, 1)),
    ObjectAsset("mug", "objects/mug.obj", "objects/mug.urdf", 1.0, (0, 0, 0), (0.15, 0.35, 0.85, 1)),
)
TRAY = ObjectAsset("tray", "tray/tray_textured.obj", "tray/traybox.urdf", 0.45, (0, 0, 0), None)
TRAY_FLOOR_HALF = 0.42  # half side of the tray's flat inner floor in mesh units
TRAY_FLOOR_TOP = 0.01  # height of the tray's inner floor in mesh units
TABLE_HALF = 1.2  # the table top is 2.4 m square, its top at z = 0
TABLE_THICKNESS = 0.04
WALL_HEIGHT = 1.0
LIGHT = dict(
    lightDirection=[0.5, 0.3, 1.0],
    lightColor=[1, 1, 1],
    lightDistance=10.0,
    lightAmbientCoeff=0.55,
    lightDiffuseCoeff=0.5,
    lightSpecularCoeff=0.05,
)


@dataclasses.dataclass
class SceneObject:
    """One body of the scene, with its mesh in world coordinates."""

    id: int
    name: str
    role: str  # "support", "backdrop", "container" or "object"
    vertices: np.ndarray  # (V, 3) float world
    faces: np.ndarray  # (F, 3) int
    position: np.ndarray  # (3,) body position
    quaternion_wxyz: np.ndarray  # (4,) body orientation
    scale: float = 1.0
    mesh: str | None = None  # pybullet_data mesh file, None for procedural geometry
    urdf: str | None = None

    @property
    def movable(self) -> bool:
        return self.role == "object"


def capture_settings(views=40, width=320, height=240, seed=0, video=True, **settings) -> CaptureSettings:
    """CaptureSettings from loose values (numbers as text, numpy integers), validated: a one-line
    FignetError names a bad one. `settings` are further fields (video_step, num_objects,
    fov_y_deg, ...); `capture_settings(**PRESETS["tiny"])` gives the fast test settings."""
    try:
        return CaptureSettings(
            views=int(views),
            width=int(width),
            height=int(height),
            seed=int(seed),
            video=bool(video),
            **settings,
        ).validate()
    except TypeError as error:
        raise FignetError(f"bad capture setting: {error}") from None


@dataclasses.dataclass
class Capture:
    """A rendered capture in memory: what the capture folder holds (see the module docstring),
    but for the video, which `render_capture` hands over frame by frame."""

    config: CaptureSettings
    objects: list  # SceneObject, in id order
    cameras: object  # fignetctl.core.cameras.Cameras of the views, with the GT points
    rgb: np.ndarray  # (N, H, W, 3) uint8
    depth: np.ndarray  # (N, H, W) float32 metres along the optical axis (inf: nothing)
    masks: np.ndarray  # (N, H, W) int16 scene-object id per pixel (-1: nothing)
    prompts: dict  # prompts.json
    measurements: dict  # measurements.json
    scene: dict  # scene.json, less its summary
    summary: dict  # views, width, height, video_frames, objects, build_seconds, seconds_per_view
    render_seconds: float  # rendering the views (not the video)


def render_capture(config: CaptureSettings, progress=None, video_frame=None) -> Capture:
    """Render the bundled capture with `config` (see the module docstring). When `config.video`,
    each frame of the orbit video, (H, W, 3) uint8 RGB, is given to `video_frame` as it is
    rendered (the frames are not kept). `progress`, if given, wraps an iterable (e.g. a tqdm bar)."""
    import pybullet as p

    progress = progress or (lambda iterable, **kw: iterable)
    start = time.perf_counter()
    client = p.connect(p.DIRECT)
    try:
        with tempfile.TemporaryDirectory(prefix="fignetctl-textures-") as texture_dir:
            objects = build_scene(client, config, Path(texture_dir))
        build_seconds = time.perf_counter() - start
        cameras = ring_cameras(config, np.arange(config.views, dtype=float))
        renders, render_seconds = _render_views(client, config, cameras, progress)
        video_frames = 0
        if config.video:
            video_frames = _render_video(client, config, video_frame or (lambda rgb: None), progress)
    finally:
        p.disconnect(client)
    summary = {
        "views": config.views,
        "width": config.width,
        "height": config.height,
        "video_frames": video_frames,
        "objects": [o.name for o in objects if o.movable],
        "build_seconds": round(build_seconds, 3),
        "seconds_per_view": round(render_seconds / config.views, 4),
    }
    return _assemble(config, objects, cameras, renders, summary, render_seconds)


# Scene ------------------------------------------------------------------------------------


def build_scene(client, config: CaptureSettings, texture_dir: Path) -> list[SceneObject]:
    """Create the table, backdrop, tray and objects in PyBullet; return them in id order."""
    rng = np.random.default_rng(config.seed)
    texture_rngs = [
        np.random.default_rng([config.seed, k]) for k in (1, 2)
    ]  # textures do not shift the scene
    table = _procedural_body(
        client, 0, "table", "support", *table_mesh(), texture_rngs[0], config, texture_dir
    )
    backdrop = _procedural_body(
        client, 1, "backdrop", "backdrop", *backdrop_mesh(), texture_rngs[1], config, texture_dir
    )
    tray_position = np.array([0.0, 0.0, tray_lift()])  # its base on the table top
    tray = _file_body(client, 2, TRAY, "container", tray_position, np.array([1.0, 0, 0, 0]))
    chosen = rng.choice(len(OBJECT_ASSETS), size=config.num_objects, replace=False)
    assets = [OBJECT_ASSETS[i] for i in sorted(chosen)]
    poses = place_in_tray(assets, rng)
    items = [
        _file_body(client, 3 + i, asset, "object", *pose)
        for i, (asset, pose) in enumerate(zip(assets, poses))
    ]
    return [table, backdrop, tray, *items]


def table_mesh():
    """The table top: a 2.4 m square slab with its top at z = 0; the top face takes the whole
    texture. Returns vertices (V,3), faces (F,3), uvs (V,2)."""
    h = TABLE_HALF
    top = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)
    bottom = top - [0, 0, TABLE_THICKNESS]
    vertices = np.vstack([top, bottom])
    uvs = np.vstack([(top[:, :2] + h) / (2 * h)] * 2)
    faces = [[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]]
    for a in range(4):  # edge faces
        b = (a + 1) % 4
        faces += [[a, a + 4, b + 4], [a, b + 4, b]]
    return vertices, np.array(faces), uvs


def backdrop_mesh():
    """Four walls standing on the table's edges, facing inwards, each with its own quarter of
    the texture (so nothing repeats). Returns vertices (16,3), faces (8,3), uvs (16,2)."""
    h, z = TABLE_HALF, WALL_HEIGHT
    corners = np.array([[-h, -h], [h, -h], [h, h], [-h, h]], float)
    vertices, uvs, faces = [], [], []
    for wall in range(4):
        (x0, y0), (x1, y1) = corners[wall], corners[(wall + 1) % 4]
        base = len(vertices)
        vertices += [[x0, y0, -TABLE_THICKNESS], [x1, y1, -TABLE_THICKNESS], [x1, y1, z], [x0, y0, z]]
        u0, u1 = (4 - wall) / 4, (3 - wall) / 4  # seen from inside, so u runs backwards
        uvs += [[u0, 0], [u1, 0], [u1, 1], [u0, 1]]
        faces += [[base, base + 2, base + 1], [base, base + 3, base + 2]]  # normals point inwards
    return np.array(vertices), np.array(faces), np.array(uvs)


def place_in_tray(assets, rng, tries=500):
    """Random yaw and position for each asset on the tray's floor, footprints apart.
    Returns [(position (3,), quaternion wxyz (4,))]."""
    half = TRAY_FLOOR_HALF * TRAY.scale - 0.01
    floor = TRAY_FLOOR_TOP * TRAY.scale + tray_lift() + 0.001
    placed, poses = [], []
    for asset in assets:
        for _ in range(tries):
            yaw = rng.uniform(0, 2 * math.pi)
            orientation = object_orientation(asset.upright_euler, yaw)
            rotation = _matrix_from_wxyz(orientation)
            vertices = _asset_vertices(asset) @ rotation.T
            centre = 0.5 * (vertices[:, :2].min(0) + vertices[:, :2].max(0))
            radius = np.linalg.norm(vertices[:, :2] - centre, axis=1).max()
            if radius > half:
                raise FignetError(f"{asset.name} does not fit in the tray")
            target = rng.uniform(-half + radius, half - radius, size=2)
            if all(np.linalg.norm(target - c) > radius + r + 0.01 for c, r in placed):
                placed.append((target, radius))
                position = np.array([*(target - centre), floor - vertices[:, 2].min()])
                poses.append((position, orientation))
                break
        else:
            raise FignetError(f"could not place {asset.name} in the tray without overlap; try another `seed`")
    return poses


def tray_lift() -> float:
    """Height of the tray's origin above the table top, so that its base rests on it."""
    return float(-_asset_vertices(TRAY)[:, 2].min())


def object_orientation(upright_euler, yaw) -> np.ndarray:
    """Quaternion (w, x, y, z): make the mesh upright (PyBullet Euler angles: about x, then y,
    then z), then turn it by `yaw` about the world z axis."""
    import pybullet as p

    _, quaternion = p.multiplyTransforms(
        [0, 0, 0],
        p.getQuaternionFromEuler([0, 0, yaw]),
        [0, 0, 0],
        p.getQuaternionFromEuler(list(upright_euler)),
    )
    return _xyzw_to_wxyz(quaternion)


def _xyzw_to_wxyz(quaternion) -> np.ndarray:
    x, y, z, w = quaternion
    return np.array([w, x, y, z]) * (1 if w >= 0 else -1)


def _matrix_from_wxyz(q) -> np.ndarray:
    import pybullet as p

    return np.asarray(p.getMatrixFromQuaternion([q[1], q[2], q[3], q[0]]), float).reshape(3, 3)


_MESH_CACHE: dict = {}


def _asset_vertices(asset: ObjectAsset) -> np.ndarray:
    """(V,3) vertices of the asset's mesh file times its scale (object frame)."""
    return _load_mesh(asset.mesh)[0] * asset.scale


def _load_mesh(relative: str):
    """(vertices (V,3), faces (F,3)) of a pybullet_data OBJ file, its vertices as stored and its
    polygons fanned into triangles (as PyBullet's loader does)."""
    if relative not in _MESH_CACHE:
        import pybullet_data

        _MESH_CACHE[relative] = read_obj(os.path.join(pybullet_data.getDataPath(), relative))
    return _MESH_CACHE[relative]


def _file_body(client, index, asset: ObjectAsset, role, position, quaternion_wxyz) -> SceneObject:
    import pybullet as p
    import pybullet_data

    kwargs = {"rgbaColor": list(asset.rgba)} if asset.rgba else {}
    shape = p.createVisualShape(
        p.GEOM_MESH,
        fileName=os.path.join(pybullet_data.getDataPath(), asset.mesh),
        meshScale=[asset.scale] * 3,
        physicsClientId=client,
        **kwargs,
    )
    w, x, y, z = quaternion_wxyz
    body = p.createMultiBody(
        baseVisualShapeIndex=shape,
        basePosition=list(position),
        baseOrientation=[x, y, z, w],
        physicsClientId=client,
    )
    if body != index:
        raise FignetError(f"internal: body {asset.name} got PyBullet id {body}, expected {index}")
    vertices, faces = _load_mesh(asset.mesh)
    world = (vertices * asset.scale) @ _matrix_from_wxyz(quaternion_wxyz).T + position
    return SceneObject(
        index,
        asset.name,
        role,
        world,
        faces,
        np.asarray(position, float),
        np.asarray(quaternion_wxyz, float),
        asset.scale,
        asset.mesh,
        asset.urdf,
    )


def _procedural_body(
    client, index, name, role, vertices, faces, uvs, rng, config, texture_dir
) -> SceneObject:
    import cv2
    import pybullet as p

    texture = procedural_texture(
        rng,
        config.texture_size if role == "support" else config.texture_size // 2,
        aspect=1 if role == "support" else 4,
    )
    file = texture_dir / f"{name}.png"
    cv2.imwrite(str(file), texture[:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 0])
    normals = _vertex_normals(vertices, faces)
    shape = p.createVisualShape(
        p.GEOM_MESH,
        vertices=vertices.tolist(),
        indices=faces.reshape(-1).tolist(),
        uvs=uvs.tolist(),
        normals=normals.tolist(),
        physicsClientId=client,
    )
    body = p.createMultiBody(baseVisualShapeIndex=shape, physicsClientId=client)
    if body != index:
        raise FignetError(f"internal: body {name} got PyBullet id {body}, expected {index}")
    p.changeVisualShape(
        body,
        -1,
        textureUniqueId=p.loadTexture(str(file), physicsClientId=client),
        rgbaColor=[1, 1, 1, 1],
        physicsClientId=client,
    )
    return SceneObject(index, name, role, vertices, faces, np.zeros(3), np.array([1.0, 0, 0, 0]))


def _vertex_normals(vertices, faces):
    normals = np.zeros_like(vertices)
    triangle = vertices[faces]
    face_normals = np.cross(triangle[:, 1] - triangle[:, 0], triangle[:, 2] - triangle[:, 0])
    for corner in range(3):
        np.add.at(normals, faces[:, corner], face_normals)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)


def procedural_texture(rng, size: int, aspect: int = 1) -> np.ndarray:
    """(size, aspect*size, 3) uint8 RGB: smooth multi-scale colour noise under random
    coloured shapes and strokes; no two patches alike, detail coarse enough not to alias."""
    import cv2

    height, width = size, size * aspect
    image = np.zeros((height, width, 3), np.float32)
    for cells, weight in ((4, 0.45), (24, 0.3), (96, 0.25)):
        noise = rng.random((cells, cells * aspect, 3)).astype(np.float32)
        image += weight * cv2.resize(noise, (width, height), interpolation=cv2.INTER_CUBIC)
    image = (np.clip(image, 0, 1) * 200 + 30).astype(np.uint8)
    scale = size / 256
    for _ in range(int(250 * aspect)):
        _draw_random_mark(image, rng, scale)
    return cv2.GaussianBlur(image, (0, 0), max(0.5, scale * 0.3))


def _draw_random_mark(image, rng, scale):
    """One random ellipse, rectangle, stroke or 3-letter word, in a random colour."""
    import cv2

    height, width = image.shape[:2]
    colour = tuple(int(c) for c in rng.integers(0, 256, 3))
    centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
    size = rng.uniform(2, 12) * scale
    kind = rng.integers(0, 4)
    if kind == 0:
        axes = (int(size), int(size * rng.uniform(0.3, 1)))
        cv2.ellipse(image, centre, axes, float(rng.uniform(0, 180)), 0, 360, colour, -1, cv2.LINE_AA)
    elif kind == 1:
        corner = (
            centre[0] + int(rng.uniform(-1.5, 1.5) * size),
            centre[1] + int(rng.uniform(-1.5, 1.5) * size),
        )
        cv2.rectangle(image, centre, corner, colour, -1, cv2.LINE_AA)
    elif kind == 2:
        end = (centre[0] + int(rng.uniform(-3, 3) * size), centre[1] + int(rng.uniform(-3, 3) * size))
        cv2.line(image, centre, end, colour, max(1, int(scale)), cv2.LINE_AA)
    else:
        text = "".join(rng.choice(list("ABCDEFGHJKLMNPRSTUVWXYZ23456789"), 3))
        cv2.putText(
            image,
            text,
            centre,
            cv2.FONT_HERSHEY_SIMPLEX,
            size / 20,
            colour,
            max(1, int(size / 8)),
            cv2.LINE_AA,
        )


# Cameras ----------------------------------------------------------------------------------


def ring_target() -> np.ndarray:
    """The point every camera looks at: the tray's centre, a little above its floor."""
    return np.array([0.0, 0.0, 0.04])


def ring_cameras(config: CaptureSettings, steps: np.ndarray):
    """Cameras at fractional view indices `steps` (N,) on the closed wavy ring, as a dict:
    eyes (N,3), K (3,3), c2w (N,4,4) OpenCV, views (N PyBullet view matrices), projection."""
    import pybullet as p

    azimuth = 2 * math.pi * steps / config.views + 0.3
    low, high = np.radians(config.elevation_deg)
    elevation = 0.5 * (low + high) + 0.5 * (high - low) * np.sin(2 * azimuth)
    target = ring_target()
    eyes = target + config.radius * np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=1
    )
    views = [p.computeViewMatrix(eye.tolist(), target.tolist(), [0, 0, 1]) for eye in eyes]
    projection = p.computeProjectionMatrixFOV(
        config.fov_y_deg, config.width / config.height, config.near, config.far
    )
    c2w = np.stack([view_matrix_to_c2w(view) for view in views])
    return {"eyes": eyes, "K": intrinsics(config), "c2w": c2w, "views": views, "projection": projection}


def intrinsics(config: CaptureSettings) -> np.ndarray:
    """(3,3) K of the render, with pixel (u, v) the ray through (u + 0.5, v + 0.5).

    TinyRenderer samples pixel (u, v) at the image point (u, v + 1) of a camera whose principal
    point is the image's middle (measured: depth of tilted planes and edges of odd-sized images
    match to 0.2 mm at 1 m only so), hence the half-pixel shifts of the principal point."""
    f = 0.5 * config.height / math.tan(math.radians(config.fov_y_deg) / 2)
    return np.array([[f, 0, config.width / 2 + 0.5], [0, f, config.height / 2 - 0.5], [0, 0, 1.0]])


def view_matrix_to_c2w(view) -> np.ndarray:
    """PyBullet's (column-major, OpenGL) view matrix -> (4,4) camera-to-world, OpenCV axes."""
    world_to_gl = np.asarray(view, float).reshape(4, 4).T
    return np.linalg.inv(world_to_gl) @ np.diag([1.0, -1.0, -1.0, 1.0])


def linearize_depth(buffer: np.ndarray, near: float, far: float) -> np.ndarray:
    """TinyRenderer's depth buffer in [0, 1] -> z along the optical axis in metres."""
    buffer = np.asarray(buffer, np.float64)
    return (far * near / (far - (far - near) * buffer)).astype(np.float32)


# Rendering --------------------------------------------------------------------------------


def render_one(client, config: CaptureSettings, view, projection):
    """One TinyRenderer image: rgb (H,W,3) uint8, depth (H,W) float32 metres, seg (H,W) int."""
    import pybullet as p

    _, _, rgba, depth, seg = p.getCameraImage(
        config.width,
        config.height,
        view,
        projection,
        renderer=p.ER_TINY_RENDERER,
        shadow=1,
        physicsClientId=client,
        **LIGHT,
    )
    shape = (config.height, config.width)
    rgb = np.reshape(np.asarray(rgba, np.uint8), (*shape, 4))[:, :, :3]
    depth = linearize_depth(np.reshape(depth, shape), config.near, config.far)
    return rgb, depth, np.reshape(np.asarray(seg), shape)


def _render_views(client, config, cameras, progress):
    renders, start = [], time.perf_counter()
    for view in progress(cameras["views"], desc="render-views", unit="view"):
        renders.append(render_one(client, config, view, cameras["projection"]))
    return renders, time.perf_counter() - start


def _render_video(client, config, video_frame, progress) -> int:
    steps = np.arange(config.views * config.video_step) / config.video_step
    cameras = ring_cameras(config, steps)
    for view in progress(cameras["views"], desc="video", unit="frame"):
        rgb, _, _ = render_one(client, config, view, cameras["projection"])
        video_frame(rgb)
    return len(steps)


# Assembling -------------------------------------------------------------------------------


def _assemble(config, objects, cameras, renders, summary, render_seconds) -> Capture:
    """The capture's arrays and documents from the rendered views."""
    from fignetctl.core.cameras import Cameras

    names = [f"view_{i:03d}.png" for i in range(config.views)]
    rgb = np.stack([r[0] for r in renders])
    depth = np.stack([r[1] for r in renders])
    masks = np.stack([r[2] for r in renders]).astype(np.int16)
    masks[masks >= len(objects)] = -1
    depth[masks < 0] = np.inf  # nothing there (never happens inside the backdrop)
    K = np.repeat(cameras["K"][None], config.views, axis=0)
    points, colors = sample_points(
        depth, masks, rgb, cameras["K"], cameras["c2w"], config.points, config.seed
    )
    views = Cameras(np.array(names), K, cameras["c2w"], config.width, config.height, points, colors)
    prompts = prompts_document(objects, masks, names, cameras["eyes"], config)
    # What a user would measure with a tape: the cameras' mean height above the table top
    # (z = 0), for capture-poses --camera-height.
    measurements = {
        "format": "fignetctl.measurements",
        "format_version": 1,
        "camera_height_m": float(np.mean(cameras["eyes"][:, 2])),
    }
    scene = scene_document(objects, config, cameras, names)
    return Capture(
        config, objects, views, rgb, depth, masks, prompts, measurements, scene, summary, render_seconds
    )


def sample_points(depth, masks, rgb, K, c2w, count, seed):
    """`count` points spread over all views' visible surfaces, with their colours."""
    rng = np.random.default_rng(seed + 1)
    valid = np.argwhere(masks >= 0)  # (P, 3): view, row, column
    chosen = valid[rng.choice(len(valid), size=min(count, len(valid)), replace=False)]
    points, colors = [], []
    for view in np.unique(chosen[:, 0]):
        v, u = chosen[chosen[:, 0] == view][:, 1:].T
        points.append(pinhole.unproject(K, c2w[view], u, v, depth[view, v, u]))
        colors.append(rgb[view, v, u])
    return np.concatenate(points), np.concatenate(colors).astype(np.uint8)


def prompts_document(objects, masks, names, eyes, config) -> dict:
    """For each movable object, a point deep inside its mask (the distance transform's maximum)
    in the `prompts_per_object` views where it is seen best, spread around the orbit."""
    import cv2

    entries = []
    for item in (o for o in objects if o.movable):
        depths = []
        for mask in masks == item.id:
            inside = np.pad(mask.astype(np.uint8), 1)  # the image border counts as outside
            distance = cv2.distanceTransform(inside, cv2.DIST_L2, 5)[1:-1, 1:-1]
            row, column = np.unravel_index(np.argmax(distance), distance.shape)
            depths.append((float(distance[row, column]), int(column), int(row)))
        scores = [d[0] for d in depths]
        chosen = _spread_views(scores, eyes, config.prompts_per_object)
        if len(chosen) < 2:  # seen well only from one side of the orbit: take nearby views too
            chosen = _spread_views(scores, eyes, config.prompts_per_object, min_angle_deg=0.0)
        if len(chosen) < 2:
            raise FignetError(
                f"{item.name} is visible in fewer than 2 views; try another `seed` or more `views`"
            )
        points = [
            {
                "image": names[i],
                "u": depths[i][1],
                "v": depths[i][2],
                "inscribed_radius_px": round(depths[i][0], 2),
            }
            for i in chosen
        ]
        entries.append({"id": item.id, "name": item.name, "points": points})
    return {
        "format": PROMPTS_FORMAT,
        "format_version": FORMAT_VERSION,
        "image_dir": "images",
        "pixel_convention": "u column, v row, integer pixel index from the top left",
        "objects": entries,
    }


def _spread_views(score, eyes, count, min_angle_deg=40.0):
    """Indices of up to `count` views, best score first, each >= min_angle apart around the tray."""
    azimuth = np.arctan2(eyes[:, 1], eyes[:, 0])
    order = np.argsort(-np.asarray(score), kind="stable")
    chosen = []
    for i in order:
        if score[i] < 1.0:  # the object is not (or barely) visible
            break
        gaps = [abs((azimuth[i] - azimuth[j] + math.pi) % (2 * math.pi) - math.pi) for j in chosen]
        if all(g >= math.radians(min_angle_deg) for g in gaps):
            chosen.append(int(i))
        if len(chosen) == count:
            break
    return chosen


def scene_document(objects, config, cameras, names) -> dict:
    from fignetctl import __version__

    lows = np.min([o.vertices.min(0) for o in objects], axis=0)
    highs = np.max([o.vertices.max(0) for o in objects], axis=0)
    return {
        "format": SCENE_FORMAT,
        "format_version": FORMAT_VERSION,
        "source": "fignetctl render-views",
        "fignetctl_version": __version__,
        "inputs_sha256": {},  # made from settings alone (provenance.py)
        "units": "metres",
        "up": "+z",
        "world_vertex": "R(quaternion_wxyz) . (scale . mesh_file_vertex) + position; objects/<name>.obj is already in world",
        "objects": [
            {
                "id": o.id,
                "name": o.name,
                "role": o.role,
                "movable": o.movable,
                "urdf": o.urdf,
                "mesh_file": o.mesh,
                "gt_mesh": f"objects/{o.name}.obj",
                "scale": o.scale,
                "position": o.position.round(6).tolist(),
                "quaternion_wxyz": o.quaternion_wxyz.round(8).tolist(),
                "bounds": [o.vertices.min(0).round(5).tolist(), o.vertices.max(0).round(5).tolist()],
            }
            for o in objects
        ],
        "bounds": [lows.round(5).tolist(), highs.round(5).tolist()],
        "look_at": ring_target().tolist(),
        "image_names": names,
        "settings": dataclasses.asdict(config),
        "light": LIGHT,
    }
