"""A capture the project did not make: a table in a room, ray cast with Embree, not TinyRenderer.

Test and benchmark infrastructure (not part of fignetctl): it renders a scene that
`render-views` (fignetctl.core.synthetic_capture, PyBullet's TinyRenderer) never makes, with
nothing of fignetctl's projection or rendering code, and writes the same folder layout, so the
documented commands (docs/your-capture.md) run on it as on a user's photographs.

The scene (world: metres, z up, the table top at z = 0):
- a room: a 6 m square floor at z = -`table_height` (0.75 m) and four walls 2.5 m high;
- a table: a 1.2 x 0.8 m top 4 cm thick on four legs, standing on the floor;
- 2-4 objects from `pybullet_data` (duck, soccer ball, teddy, lego brick), made upright,
  scaled so that their longest side is 5-25 cm, resting on the table top at random yaws;
- every surface textured procedurally (hashed value noise and Voronoi cells evaluated at the
  hit point: a mosaic table cloth, tiled floor, patchy walls, grained wood legs; the teddy
  and the brick get solid 3D textures), the duck and the ball their own UV texture images.

Lighting (unlike TinyRenderer's directional light with ambient/diffuse/specular): a square
area light under the ceiling, inverse-square falloff, Lambert shading of linear (sRGB-decoded)
albedo, soft shadows from one shadow ray per sub-pixel sample to a stratified point on the
light, an ambient term, then sRGB encoding and a little Gaussian sensor noise.

Cameras: a user walking once around the table holding a phone: the azimuth advances unevenly,
the distance from the table's centre and the height above its top wobble, the phone aims at the
objects with a few centimetres of error and a few degrees of roll. One pinhole camera with its
principal point at the image's middle (width / 2, height / 2). Pixel convention as fignetctl's
(docs/formats.md): pixel (u, v) (column, row) is the ray through the image point
(u + 0.5, v + 0.5) of K. Ground truth (depth, masks) is taken on that centre ray; the colour
averages `samples` x `samples` stratified sub-pixel rays.

Ray casting: each part is one Embree triangle mesh (`embreex`, a fignetctl dependency); the hit
is then recomputed in float64 against the hit triangle's plane, so GT depth is exact to the
triangles (not to Embree's float32).

Folder layout (as render-views writes, see fignetctl/core/synthetic_capture.py):

    images/view_000.png ...        RGB PNG
    ground_truth/cameras.npz       K, c2w (OpenCV), points, point_colors (from GT depth)
    ground_truth/depth.npz         depth (N,H,W) float32, z along the optical axis; image_names
    ground_truth/masks.npz         masks (N,H,W) int16 part id (-1: nothing); ids, names; image_names
    ground_truth/objects/<name>.obj  every part's mesh in world coordinates
    ground_truth/scene.json        parts (id, name, role, movable, mesh file, scale, pose, bounds),
                                   bounds, settings, light, renderer
    prompts.json                   per object, point prompts {image, u, v, inscribed_radius_px}
    measurements.json              camera_height_m: the cameras' mean height above the table top

    .venv/bin/python benchmarks/foreign_capture.py -o /tmp/foreign            # 48 views 320x240
    .venv/bin/python benchmarks/foreign_capture.py -o /tmp/tiny --views 12 --width 160 --height 120
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from pathlib import Path

import numpy as np

# Settings -----------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Asset:
    """An object from pybullet_data: its mesh, how to stand it up, its size, its look."""

    name: str
    mesh: str  # relative to pybullet_data
    upright_euler: tuple  # rotation about x, then y, then z (radians) that makes z up
    size: float  # longest side after scaling, metres
    look: str  # "uv": the mesh's texture image; "fur" or "plastic": a solid texture
    colour: tuple = (0.6, 0.6, 0.6)  # sRGB base colour of a solid texture


ASSETS = {
    "duck": Asset("duck", "duck.obj", (math.pi / 2, 0, 0), 0.15, "uv"),
    "ball": Asset("ball", "soccerball.obj", (0, 0, 0), 0.21, "uv"),
    "teddy": Asset("teddy", "teddy2_VHACD_CHs.obj", (math.pi / 2, 0, 0), 0.19, "fur", (0.58, 0.38, 0.22)),
    "brick": Asset("brick", "lego/lego.obj", (math.pi / 2, 0, 0), 0.065, "plastic", (0.82, 0.12, 0.08)),
}


@dataclasses.dataclass(frozen=True)
class ForeignSettings:
    views: int = 48
    width: int = 320
    height: int = 240
    seed: int = 0
    objects: tuple = ("duck", "ball", "teddy", "brick")
    samples: int = 2  # sub-pixel rays per axis for the colour (2: 4 per pixel)
    fov_y_deg: float = 50.0
    table_height: float = 0.75  # table top above the floor
    table_size: tuple = (1.0, 0.7)
    table_thickness: float = 0.04
    room_half: float = 4.5
    wall_height: float = 2.6  # above the floor
    distance: tuple = (0.8, 1.05)  # horizontal distance of the phone from the table's centre
    camera_height: tuple = (0.4, 0.6)  # phone height above the table top
    arc_deg: float = 360.0  # how far around the table the walk goes
    light_centre: tuple = (0.5, -0.4, 1.7)  # area light, metres (table top z = 0)
    light_size: float = 0.6  # side of the square area light
    light_power: float = 3.4  # irradiance scale: radiance = albedo (ambient + power cos / r^2)
    ambient: float = 0.22
    noise: float = 1.2  # sensor noise, std in 8-bit levels
    points: int = 4000  # GT points in cameras.npz
    prompts_per_object: int = 3


# Procedural textures --------------------------------------------------------------------------

_PRIMES = np.array([0x9E3779B1, 0x85EBCA77, 0xC2B2AE3D], np.uint64)


def _hash(cells: np.ndarray, seed: int) -> np.ndarray:
    """(N, D) integer lattice cells -> (N,) floats in [0, 1), a fixed function of the cell and seed."""
    cells = cells.astype(np.int64).astype(np.uint64)
    h = np.full(len(cells), np.uint64(seed * 0x27D4EB2F + 0x165667B1), np.uint64)
    with np.errstate(over="ignore"):
        for axis in range(cells.shape[1]):
            h = (h ^ (cells[:, axis] * _PRIMES[axis])) * np.uint64(0xFF51AFD7ED558CCD)
            h ^= h >> np.uint64(29)
        h = (h ^ (h >> np.uint64(32))) * np.uint64(0xC4CEB9FE1A85EC53)
        h ^= h >> np.uint64(31)
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def value_noise(points: np.ndarray, cell: float, seed: int) -> np.ndarray:
    """(N,) smooth value noise in [0, 1] of (N, D) points on a lattice of spacing `cell`."""
    p = points / cell
    base = np.floor(p)
    f = p - base
    f = f * f * (3 - 2 * f)
    dims = points.shape[1]
    total = np.zeros(len(points))
    for corner in range(1 << dims):
        offset = np.array([(corner >> a) & 1 for a in range(dims)])
        weight = np.prod(np.where(offset, f, 1 - f), axis=1)
        total += weight * _hash(base + offset, seed)
    return total


def fractal_noise(points, cell, seed, octaves=4) -> np.ndarray:
    """(N,) sum of value noise octaves (halving cells), normalised to about [0, 1]."""
    total, norm = np.zeros(len(points)), 0.0
    for octave in range(octaves):
        weight = 0.55**octave
        total += weight * value_noise(points, cell / 2**octave, seed + 101 * octave)
        norm += weight
    return total / norm


def voronoi(points: np.ndarray, cell: float, seed: int):
    """2D Voronoi of (N, 2) points with one jittered site per lattice cell of side `cell`:
    (site hash in [0, 1) (N,), distance to the nearest site F1, to the second F2) in metres."""
    p = points / cell
    base = np.floor(p)
    best = np.full((len(points), 2), np.inf)
    ident = np.zeros(len(points))
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            lattice = base + [dx, dy]
            site = lattice + np.stack([_hash(lattice, seed), _hash(lattice, seed + 7)], axis=1)
            distance = np.linalg.norm(p - site, axis=1)
            closer = distance < best[:, 0]
            second = ~closer & (distance < best[:, 1])
            best[:, 1] = np.where(closer, best[:, 0], np.where(second, distance, best[:, 1]))
            ident = np.where(closer, _hash(lattice, seed + 13), ident)
            best[:, 0] = np.where(closer, distance, best[:, 0])
    return ident, best[:, 0] * cell, best[:, 1] * cell


def _hsv(h, s, v) -> np.ndarray:
    """(N,) hue, saturation, value in [0, 1] -> (N, 3) RGB."""
    i = np.floor(h * 6) % 6
    f = h * 6 - np.floor(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    table = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)]
    out = np.zeros((len(h), 3))
    for k, (r, g, b) in enumerate(table):
        sel = i == k
        out[sel] = np.stack([r[sel], g[sel], b[sel]], axis=1)
    return out


def table_cloth(points, seed) -> np.ndarray:
    """A mosaic cloth: Voronoi tiles of ~3.5 cm in random colours with dark seams, mottled."""
    xy = points[:, :2]
    ident, f1, f2 = voronoi(xy, 0.035, seed)
    colour = _hsv(ident, 0.35 + 0.5 * _hash(np.floor(ident[:, None] * 1e6), seed), 0.55 + 0.4 * ident)
    colour *= (0.75 + 0.45 * fractal_noise(xy, 0.012, seed + 1, 3))[:, None]
    seam = np.clip((f2 - f1) / 0.0025, 0, 1)[:, None]
    return colour * (0.25 + 0.75 * seam)


def tiled_floor(points, seed) -> np.ndarray:
    """40 cm tiles of warm greys and terracotta with 8 mm grout, speckled and mottled."""
    xy = points[:, :2]
    tile = np.floor(xy / 0.4)
    shade = _hash(tile, seed)
    warm = np.stack([0.55 + 0.3 * shade, 0.42 + 0.2 * shade, 0.32 + 0.15 * _hash(tile, seed + 3)], axis=1)
    ident, _, _ = voronoi(xy, 0.06, seed + 5)
    warm *= (0.7 + 0.5 * ident)[:, None] * (0.8 + 0.4 * fractal_noise(xy, 0.03, seed + 9, 3))[:, None]
    local = xy / 0.4 - tile
    grout = np.minimum(np.minimum(local, 1 - local).min(axis=1) * 0.4 / 0.008, 1)[:, None]
    return warm * grout + (1 - grout) * 0.2


def wall_paper(points, seed) -> np.ndarray:
    """Large Voronoi patches in muted colours over fractal noise; (x + y, z) is the wall's plane."""
    plane = np.stack([points[:, 0] + points[:, 1], points[:, 2]], axis=1)
    ident, f1, f2 = voronoi(plane, 0.16, seed)
    colour = _hsv(ident, 0.3 + 0.3 * _hash(np.floor(plane / 0.16), seed + 2), 0.5 + 0.4 * ident)
    colour *= (0.7 + 0.5 * fractal_noise(plane, 0.05, seed + 4, 4))[:, None]
    edge = np.clip((f2 - f1) / 0.006, 0, 1)[:, None]
    return colour * (0.4 + 0.6 * edge)


def wood(points, seed) -> np.ndarray:
    """Dark grained wood (table edges and legs)."""
    grain = np.sin(points[:, 0] * 120 + points[:, 2] * 40 + 8 * fractal_noise(points, 0.05, seed, 3))
    value = 0.35 + 0.1 * grain + 0.15 * fractal_noise(points, 0.01, seed + 1, 2)
    return np.stack([value * 1.3, value * 0.85, value * 0.5], axis=1)


def solid(colour, cell, contrast, seed):
    """A solid 3D texture: `colour` mottled by fractal noise of `cell` (fur, plastic)."""

    def shade(points, _seed=seed):
        noise = fractal_noise(points, cell, _seed, 4)
        blotch = value_noise(points, cell * 6, _seed + 17)
        return (
            np.asarray(colour)[None] * (1 - contrast + 2 * contrast * noise * (0.6 + 0.8 * blotch))[:, None]
        )

    return shade


# Scene ----------------------------------------------------------------------------------------


@dataclasses.dataclass
class Part:
    """One body: its triangles in world coordinates and how its surface looks."""

    id: int
    name: str
    role: str  # "support" (table), "floor", "backdrop" (walls), "object"
    vertices: np.ndarray  # (V, 3) float64 world
    faces: np.ndarray  # (F, 3) int
    albedo: object  # callable((N,3) world points, (N,) face ids, (N,2) barycentrics) -> (N,3) sRGB
    smooth_normals: np.ndarray | None = None  # (V, 3) for curved meshes, else flat shading
    mesh_file: str | None = None
    scale: float = 1.0
    position: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    quaternion_wxyz: np.ndarray = dataclasses.field(default_factory=lambda: np.array([1.0, 0, 0, 0]))

    @property
    def movable(self) -> bool:
        return self.role == "object"


def box_mesh(low, high):
    """(8, 3) vertices and (12, 3) outward faces of an axis-aligned box."""
    (x0, y0, z0), (x1, y1, z1) = low, high
    vertices = np.array(
        [
            [x0, y0, z0],
            [x1, y0, z0],
            [x1, y1, z0],
            [x0, y1, z0],
            [x0, y0, z1],
            [x1, y0, z1],
            [x1, y1, z1],
            [x0, y1, z1],
        ],
        float,
    )
    faces = np.array(
        [
            [0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
            [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7],
        ]
    )  # fmt: skip
    return vertices, faces


def _merge(meshes):
    vertices, faces, offset = [], [], 0
    for v, f in meshes:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.vstack(vertices), np.vstack(faces)


def _procedural(function, seed):
    return lambda points, face, bary: function(points, seed)


def rotation_from_euler(euler) -> np.ndarray:
    """R = Rz Ry Rx: about x first, then y, then z (PyBullet's getQuaternionFromEuler order)."""
    ax, ay, az = euler
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


def quaternion_wxyz(rotation) -> np.ndarray:
    """(4,) w, x, y, z of a rotation matrix, w >= 0."""
    m = rotation
    w = math.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + m[0, 0] - m[1, 1] - m[2, 2])) / 2, m[2, 1] - m[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - m[0, 0] + m[1, 1] - m[2, 2])) / 2, m[0, 2] - m[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - m[0, 0] - m[1, 1] + m[2, 2])) / 2, m[1, 0] - m[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)


def load_asset(asset: Asset):
    """(vertices (V,3) as stored, faces, uv (V,2) or None, texture (H,W,3) float sRGB or None)
    of a pybullet_data mesh, read with trimesh (UV seams split into separate vertices)."""
    import pybullet_data
    import trimesh

    mesh = trimesh.load(os.path.join(pybullet_data.getDataPath(), asset.mesh), force="mesh", process=False)
    uv, texture = None, None
    visual = mesh.visual
    if asset.look == "uv" and getattr(visual, "uv", None) is not None:
        uv = np.asarray(visual.uv, float)
        image = getattr(visual.material, "image", None) or getattr(visual.material, "baseColorTexture", None)
        texture = np.asarray(image.convert("RGB"), np.float64) / 255.0
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64), uv, texture


def _uv_albedo(faces, uv, texture):
    """Bilinear lookup (wrapping) of `texture` at the interpolated UV of each hit."""
    height, width = texture.shape[:2]

    def shade(points, face, bary):
        corners = uv[faces[face]]  # (N, 3, 2)
        coords = np.einsum("nk,nkc->nc", bary, corners)
        x = (coords[:, 0] % 1.0) * width - 0.5
        y = (1 - coords[:, 1] % 1.0) * height - 0.5
        x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        x0, x1 = x0 % width, (x0 + 1) % width
        y0, y1 = y0 % height, (y0 + 1) % height
        top = texture[y0, x0] * (1 - fx) + texture[y0, x1] * fx
        bottom = texture[y1, x0] * (1 - fx) + texture[y1, x1] * fx
        return top * (1 - fy) + bottom * fy

    return shade


def _vertex_normals(vertices, faces) -> np.ndarray:
    normals = np.zeros_like(vertices)
    triangles = vertices[faces]
    face_normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    for corner in range(3):
        np.add.at(normals, faces[:, corner], face_normals)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)


def place_objects(settings: ForeignSettings, rng):
    """[(asset, rotation (3,3), scale, position (3,))]: upright, random yaw, resting on the
    table top (z = 0) inside the middle of the table, footprints >= 3 cm apart."""
    placed, out = [], []
    half = np.array([settings.table_size[0] / 2 - 0.25, settings.table_size[1] / 2 - 0.2])
    for name in settings.objects:
        asset = ASSETS[name]
        stored = load_asset(asset)[0]
        upright = rotation_from_euler(asset.upright_euler)
        size = np.ptp(stored @ upright.T, axis=0).max()
        scale = asset.size / size
        for _ in range(1000):
            rotation = rotation_from_euler((0, 0, rng.uniform(0, 2 * math.pi))) @ upright
            local = scale * stored @ rotation.T
            centre = 0.5 * (local[:, :2].min(0) + local[:, :2].max(0))
            radius = np.linalg.norm(local[:, :2] - centre, axis=1).max()
            target = rng.uniform(-half, half)
            if all(np.linalg.norm(target - c) > radius + r + 0.03 for c, r in placed):
                placed.append((target, radius))
                position = np.array([*(target - centre), -local[:, 2].min()])
                out.append((asset, rotation, scale, position))
                break
        else:
            raise RuntimeError(f"could not place {name} on the table; try another seed")
    return out


def build_scene(settings: ForeignSettings) -> list[Part]:
    """The room, the table and the objects as Parts, in id order: table 0, floor 1, walls 2, objects 3+."""
    rng = np.random.default_rng(settings.seed)
    seed = settings.seed * 1000
    sx, sy = settings.table_size[0] / 2, settings.table_size[1] / 2
    th, floor_z = settings.table_thickness, -settings.table_height
    top = box_mesh((-sx, -sy, -th), (sx, sy, 0.0))
    legs = [
        box_mesh((x - 0.025, y - 0.025, floor_z), (x + 0.025, y + 0.025, -th))
        for x in (-sx + 0.07, sx - 0.07 - 0.0)
        for y in (-sy + 0.07, sy - 0.07)
    ]
    table_vertices, table_faces = _merge([top, *legs])
    top_faces = np.zeros(len(table_faces), bool)
    top_faces[[2, 3]] = True  # the top's upward faces (box_mesh order: bottom, top, sides)

    def table_albedo(points, face, bary):
        out = wood(points, seed + 20)
        on_top = top_faces[face]
        if on_top.any():
            out[on_top] = table_cloth(points[on_top], seed + 10)
        return out

    r, h = settings.room_half, settings.wall_height
    floor_vertices = np.array([[-r, -r, floor_z], [r, -r, floor_z], [r, r, floor_z], [-r, r, floor_z]])
    floor_faces = np.array([[0, 1, 2], [0, 2, 3]])
    corners = np.array([[-r, -r], [r, -r], [r, r], [-r, r]])
    wall_vertices, wall_faces = [], []
    for k in range(4):
        (x0, y0), (x1, y1) = corners[k], corners[(k + 1) % 4]
        base = len(wall_vertices)
        wall_vertices += [[x0, y0, floor_z], [x1, y1, floor_z], [x1, y1, floor_z + h], [x0, y0, floor_z + h]]
        wall_faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]  # normals inwards
    parts = [
        Part(0, "table", "support", table_vertices, table_faces, table_albedo),
        Part(1, "floor", "floor", floor_vertices, floor_faces, _procedural(tiled_floor, seed + 30)),
        Part(
            2,
            "walls",
            "backdrop",
            np.array(wall_vertices, float),
            np.array(wall_faces),
            _procedural(wall_paper, seed + 40),
        ),
    ]
    for index, (asset, rotation, scale, position) in enumerate(place_objects(settings, rng)):
        stored, faces, uv, texture = load_asset(asset)
        vertices = scale * stored @ rotation.T + position
        if texture is not None:
            albedo = _uv_albedo(faces, uv, texture)
        else:
            cell, contrast = (0.004, 0.35) if asset.look == "fur" else (0.006, 0.12)
            base = solid(asset.colour, cell, contrast, seed + 50 + index)
            albedo = lambda points, face, bary, base=base: base(points)
        parts.append(
            Part(
                3 + index,
                asset.name,
                "object",
                vertices,
                faces,
                albedo,
                smooth_normals=_vertex_normals(vertices, faces),
                mesh_file=asset.mesh,
                scale=float(scale),
                position=position,
                quaternion_wxyz=quaternion_wxyz(rotation),
            )
        )
    return parts


# Ray casting ----------------------------------------------------------------------------------


class RayCaster:
    """Closest hits of rays against the parts (one Embree geometry per part), refined in float64."""

    def __init__(self, parts: list[Part]):
        from embreex import mesh_construction, rtcore_scene

        self.parts = parts
        self.scene = rtcore_scene.EmbreeScene()
        for part in parts:  # geometry ids follow the insertion order
            mesh_construction.TriangleMesh(
                self.scene, part.vertices.astype(np.float32), part.faces.astype(np.int32)
            )

    def cast(self, origins: np.ndarray, directions: np.ndarray):
        """(part index (N,) int, -1: miss; face (N,); t (N,) along the unit directions; barycentrics (N,3))."""
        result = self.scene.run(
            np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(directions, np.float32), output=1
        )
        part = result["geomID"].astype(np.int64)
        part[part < 0] = -1
        face = result["primID"].astype(np.int64)
        t = np.full(len(origins), np.inf)
        bary = np.zeros((len(origins), 3))
        for index, item in enumerate(self.parts):
            sel = np.flatnonzero(part == index)
            if len(sel) == 0:
                continue
            a, b, c = (item.vertices[item.faces[face[sel], k]] for k in range(3))
            normal = np.cross(b - a, c - a)
            o, d = origins[sel], directions[sel]
            denominator = np.einsum("ij,ij->i", d, normal)
            exact = np.einsum("ij,ij->i", a - o, normal) / np.where(denominator == 0, 1e-30, denominator)
            t[sel] = np.where(np.isfinite(exact) & (exact > 0), exact, result["tfar"][sel])
            hit = o + t[sel, None] * d
            # barycentrics of the hit in its triangle (least squares on the two edges)
            e1, e2, w = b - a, c - a, hit - a
            d11, d12, d22 = (np.einsum("ij,ij->i", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
            w1, w2 = np.einsum("ij,ij->i", w, e1), np.einsum("ij,ij->i", w, e2)
            det = np.maximum(d11 * d22 - d12 * d12, 1e-30)
            beta, gamma = (d22 * w1 - d12 * w2) / det, (d11 * w2 - d12 * w1) / det
            bary[sel] = np.stack([1 - beta - gamma, beta, gamma], axis=1)
        return part, face, t, bary

    def blocked(self, origins, directions, lengths) -> np.ndarray:
        """(N,) bool: something lies on the segment origin + s * direction, 0 < s < length."""
        result = self.scene.run(
            np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(directions, np.float32), output=1
        )
        return (result["geomID"] >= 0) & (result["tfar"] < lengths)


def pixel_rays(K, c2w, width, height, offsets=((0.5, 0.5),)):
    """Rays of every pixel for each sub-pixel offset: origins (S*H*W, 3), unit directions,
    and the z component of each unit direction in the camera frame (depth = t * that)."""
    v, u = np.mgrid[0:height, 0:width].astype(float)
    directions = []
    for du, dv in offsets:
        pixel = np.stack([(u + du).ravel(), (v + dv).ravel(), np.ones(u.size)], axis=1)
        directions.append(pixel @ np.linalg.inv(K).T)
    camera = np.concatenate(directions)
    camera /= np.linalg.norm(camera, axis=1, keepdims=True)
    world = camera @ c2w[:3, :3].T
    origins = np.broadcast_to(c2w[:3, 3], world.shape)
    return np.ascontiguousarray(origins), world, camera[:, 2]


def srgb_to_linear(c):
    c = np.clip(c, 0, 1)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    c = np.clip(c, 0, 1)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def shade(caster: RayCaster, settings: ForeignSettings, origins, directions, rng) -> np.ndarray:
    """(N, 3) linear radiance along the rays: Lambert, ambient, soft shadows of the area light."""
    part, face, t, bary = caster.cast(origins, directions)
    radiance = np.zeros((len(origins), 3))
    hit = part >= 0
    points = origins + np.where(hit, t, 0)[:, None] * directions
    normals = np.zeros_like(points)
    albedo = np.zeros_like(points)
    for index, item in enumerate(caster.parts):
        sel = np.flatnonzero(part == index)
        if len(sel) == 0:
            continue
        tri = item.faces[face[sel]]
        if item.smooth_normals is not None:
            n = np.einsum("nk,nkc->nc", bary[sel], item.smooth_normals[tri])
        else:
            a, b, c = (item.vertices[tri[:, k]] for k in range(3))
            n = np.cross(b - a, c - a)
        normals[sel] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        albedo[sel] = srgb_to_linear(item.albedo(points[sel], face[sel], bary[sel]))
    facing = np.einsum("ij,ij->i", normals, directions) > 0
    normals[facing] *= -1  # two-sided surfaces: the normal faces the camera
    # one stratified point on the square area light per ray
    n = len(origins)
    strata = math.ceil(math.sqrt(n))
    cells = rng.permutation(strata * strata)[:n]
    jitter = (np.stack([cells % strata, cells // strata], axis=1) + rng.random((n, 2))) / strata - 0.5
    light = np.asarray(settings.light_centre) + np.concatenate(
        [jitter * settings.light_size, np.zeros((n, 1))], axis=1
    )
    to_light = light - points
    distance = np.linalg.norm(to_light, axis=1)
    to_light /= np.maximum(distance, 1e-12)[:, None]
    cosine = np.clip(np.einsum("ij,ij->i", normals, to_light), 0, None)
    lit = hit & (cosine > 0)
    start = points + 1e-4 * normals
    shadowed = np.zeros(n, bool)
    shadowed[lit] = caster.blocked(start[lit], to_light[lit], distance[lit] - 1e-4)
    light_cosine = np.clip(-to_light[:, 2], 0, None)  # the light faces down
    irradiance = settings.light_power * cosine * light_cosine / np.maximum(distance, 0.05) ** 2
    irradiance = np.where(shadowed | ~lit, 0.0, irradiance) + settings.ambient
    radiance[hit] = albedo[hit] * irradiance[hit, None]
    return radiance


# Cameras --------------------------------------------------------------------------------------


def intrinsics(settings: ForeignSettings) -> np.ndarray:
    """K with the principal point at the image's middle; pixel (u, v) is the ray through (u + 0.5, v + 0.5)."""
    f = 0.5 * settings.height / math.tan(math.radians(settings.fov_y_deg) / 2)
    return np.array([[f, 0, settings.width / 2], [0, f, settings.height / 2], [0, 0, 1.0]])


def look_at_c2w(eye, target, roll=0.0) -> np.ndarray:
    """(4, 4) camera-to-world, OpenCV axes (x right, y down, z forward), z up world, rolled."""
    forward = target - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    c, s = math.cos(roll), math.sin(roll)
    right, down = c * right + s * down, -s * right + c * down
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, forward, eye
    return c2w


def walk_cameras(settings: ForeignSettings, target: np.ndarray, rng) -> np.ndarray:
    """(views, 4, 4) c2w of a phone carried once around the table, aimed near `target`."""
    steps = 1 + 0.35 * rng.uniform(-1, 1, settings.views)
    azimuth = 0.7 + math.radians(settings.arc_deg) * np.cumsum(steps) / steps.sum()
    phase = rng.uniform(0, 2 * math.pi, 2)
    low, high = settings.distance
    distance = low + (high - low) * (0.5 + 0.5 * np.sin(2 * azimuth + phase[0]))
    low, high = settings.camera_height
    height = low + (high - low) * (
        0.5 + 0.35 * np.sin(3 * azimuth + phase[1]) + 0.15 * rng.uniform(-1, 1, settings.views)
    )
    c2w = []
    for a, d, z in zip(azimuth, distance, height):
        eye = np.array([d * math.cos(a), d * math.sin(a), z])
        aim = target + rng.normal(0, 0.03, 3)
        c2w.append(look_at_c2w(eye, aim, math.radians(rng.normal(0, 3))))
    return np.array(c2w)


# Rendering ------------------------------------------------------------------------------------


@dataclasses.dataclass
class ForeignCapture:
    settings: ForeignSettings
    parts: list
    K: np.ndarray  # (3, 3)
    c2w: np.ndarray  # (N, 4, 4)
    rgb: np.ndarray  # (N, H, W, 3) uint8
    depth: np.ndarray  # (N, H, W) float32, inf: nothing
    masks: np.ndarray  # (N, H, W) int16
    seconds: float

    @property
    def image_names(self) -> list[str]:
        return [f"view_{i:03d}.png" for i in range(len(self.c2w))]


def render_view(caster, settings, K, c2w, rng):
    """rgb (H,W,3) uint8, depth (H,W) float32 (z along the optical axis), mask (H,W) int16."""
    w, h, s = settings.width, settings.height, settings.samples
    origins, directions, z = pixel_rays(K, c2w, w, h)
    part, _, t, _ = caster.cast(origins, directions)
    depth = np.where(part >= 0, t * z, np.inf).reshape(h, w).astype(np.float32)
    mask = part.reshape(h, w).astype(np.int16)
    offsets = [((i + 0.5) / s, (j + 0.5) / s) for j in range(s) for i in range(s)]
    origins, directions, _ = pixel_rays(K, c2w, w, h, offsets)
    radiance = shade(caster, settings, origins, directions, rng).reshape(len(offsets), h, w, 3).mean(0)
    colour = linear_to_srgb(radiance) * 255 + rng.normal(0, settings.noise, (h, w, 3))
    return np.clip(np.round(colour), 0, 255).astype(np.uint8), depth, mask


def render(settings: ForeignSettings, parts=None, c2w=None, progress=None) -> ForeignCapture:
    """Render the capture (the scene of `settings`, or `parts` seen from `c2w`)."""
    started = time.perf_counter()
    rng = np.random.default_rng([settings.seed, 1])
    parts = parts if parts is not None else build_scene(settings)
    if c2w is None:
        objects = [p for p in parts if p.movable]
        target = np.mean([0.5 * (p.vertices.min(0) + p.vertices.max(0)) for p in objects], axis=0)
        c2w = walk_cameras(settings, target, rng)
    caster = RayCaster(parts)
    K = intrinsics(settings)
    rgb, depth, masks = [], [], []
    for index, pose in enumerate(c2w):
        image, d, m = render_view(caster, settings, K, pose, np.random.default_rng([settings.seed, 2, index]))
        rgb.append(image)
        depth.append(d)
        masks.append(m)
        if progress:
            progress(index)
    return ForeignCapture(
        settings, parts, K, np.asarray(c2w), np.stack(rgb), np.stack(depth), np.stack(masks),
        time.perf_counter() - started,
    )  # fmt: skip


# Writing --------------------------------------------------------------------------------------


def unproject(K, c2w, u, v, depth) -> np.ndarray:
    """(N, 3) world points of pixels (u, v) (integer indices) at z-depth `depth`."""
    pixel = np.stack([u + 0.5, v + 0.5, np.ones(len(u))], axis=1)
    camera = (pixel @ np.linalg.inv(K).T) * depth[:, None]
    return camera @ c2w[:3, :3].T + c2w[:3, 3]


def sample_points(capture: ForeignCapture, count: int, seed: int):
    rng = np.random.default_rng(seed + 1)
    valid = np.argwhere(capture.masks >= 0)
    chosen = valid[rng.choice(len(valid), size=min(count, len(valid)), replace=False)]
    points, colours = [], []
    for view in np.unique(chosen[:, 0]):
        v, u = chosen[chosen[:, 0] == view][:, 1:].T
        points.append(unproject(capture.K, capture.c2w[view], u, v, capture.depth[view, v, u].astype(float)))
        colours.append(capture.rgb[view, v, u])
    return np.concatenate(points), np.concatenate(colours).astype(np.uint8)


def prompts_document(capture: ForeignCapture, per_object: int) -> dict:
    """Per object, the point deepest inside its mask in the `per_object` views where it is
    seen best, at least 40 degrees apart around the table (nearer when it must)."""
    import cv2

    names = capture.image_names
    eyes = capture.c2w[:, :3, 3]
    azimuth = np.arctan2(eyes[:, 1], eyes[:, 0])
    entries = []
    for part in (p for p in capture.parts if p.movable):
        best = []
        for mask in capture.masks == part.id:
            inside = np.pad(mask.astype(np.uint8), 1)
            distance = cv2.distanceTransform(inside, cv2.DIST_L2, 5)[1:-1, 1:-1]
            row, column = np.unravel_index(np.argmax(distance), distance.shape)
            best.append((float(distance[row, column]), int(column), int(row)))
        order = np.argsort([-b[0] for b in best], kind="stable")
        chosen = []
        for min_gap in (40.0, 0.0):
            for i in order:
                if best[i][0] < 1.5 or len(chosen) == per_object:
                    break
                gaps = [abs((azimuth[i] - azimuth[j] + math.pi) % (2 * math.pi) - math.pi) for j in chosen]
                if i not in chosen and all(g >= math.radians(min_gap) for g in gaps):
                    chosen.append(int(i))
            if len(chosen) >= 2:
                break
        if len(chosen) < 2:
            raise RuntimeError(f"{part.name} is visible in fewer than 2 views")
        points = [
            {"image": names[i], "u": best[i][1], "v": best[i][2], "inscribed_radius_px": round(best[i][0], 2)}
            for i in chosen
        ]
        entries.append({"id": part.id, "name": part.name, "points": points})
    return {
        "format": "fignetctl.prompts",
        "format_version": 1,
        "image_dir": "images",
        "pixel_convention": "u column, v row, integer pixel index from the top left",
        "objects": entries,
    }


def write_obj(path: Path, vertices, faces) -> None:
    lines = [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def write_capture(folder, settings: ForeignSettings = ForeignSettings(), progress=None) -> dict:
    """Render and write the capture folder (see the module docstring); returns a summary."""
    import cv2

    from fignetctl.core.cameras import Cameras, write_cameras  # the file format only

    folder = Path(folder)
    capture = render(settings, progress=progress)
    names = capture.image_names
    images, truth = folder / "images", folder / "ground_truth"
    (truth / "objects").mkdir(parents=True, exist_ok=True)
    images.mkdir(parents=True, exist_ok=True)
    for name, image in zip(names, capture.rgb):
        cv2.imwrite(str(images / name), np.ascontiguousarray(image[:, :, ::-1]))
    points, colours = sample_points(capture, settings.points, settings.seed)
    n = len(names)
    write_cameras(
        truth / "cameras.npz",
        Cameras(
            np.array(names), np.repeat(capture.K[None], n, 0), capture.c2w, settings.width, settings.height,
            points, colours,
        ),
    )  # fmt: skip
    np.savez_compressed(truth / "depth.npz", depth=capture.depth, image_names=np.array(names))
    np.savez_compressed(
        truth / "masks.npz",
        masks=capture.masks,
        ids=np.array([p.id for p in capture.parts], np.int16),
        names=np.array([p.name for p in capture.parts]),
        image_names=np.array(names),
    )
    for part in capture.parts:
        write_obj(truth / "objects" / f"{part.name}.obj", part.vertices, part.faces)
    lows = np.min([p.vertices.min(0) for p in capture.parts], axis=0)
    highs = np.max([p.vertices.max(0) for p in capture.parts], axis=0)
    scene = {
        "format": "fignetctl.scene",
        "format_version": 1,
        "source": "benchmarks/foreign_capture.py (Embree ray caster, not render-views)",
        "inputs_sha256": {},
        "units": "metres",
        "up": "+z",
        "world_vertex": "R(quaternion_wxyz) . (scale . mesh_file_vertex) + position; objects/<name>.obj is already in world",
        "objects": [
            {
                "id": p.id,
                "name": p.name,
                "role": p.role,
                "movable": p.movable,
                "mesh_file": p.mesh_file,
                "gt_mesh": f"objects/{p.name}.obj",
                "scale": p.scale,
                "position": np.round(p.position, 6).tolist(),
                "quaternion_wxyz": np.round(p.quaternion_wxyz, 8).tolist(),
                "bounds": [p.vertices.min(0).round(5).tolist(), p.vertices.max(0).round(5).tolist()],
            }
            for p in capture.parts
        ],
        "bounds": [lows.round(5).tolist(), highs.round(5).tolist()],
        "floor_z": -settings.table_height,
        "image_names": names,
        "settings": dataclasses.asdict(settings),
        "light": {
            "kind": "square area light facing down, Lambert, soft shadows, ambient",
            "centre": list(settings.light_centre),
            "size": settings.light_size,
            "power": settings.light_power,
            "ambient": settings.ambient,
        },
        "render_seconds": round(capture.seconds, 2),
    }
    (truth / "scene.json").write_text(json.dumps(scene, indent=1))
    (folder / "prompts.json").write_text(
        json.dumps(prompts_document(capture, settings.prompts_per_object), indent=1)
    )
    measurements = {
        "format": "fignetctl.measurements",
        "format_version": 1,
        "camera_height_m": float(capture.c2w[:, 2, 3].mean()),
        "measured_from": "the table top",
    }
    (folder / "measurements.json").write_text(json.dumps(measurements, indent=1))
    return {
        "output": str(folder),
        "views": n,
        "width": settings.width,
        "height": settings.height,
        "objects": {p.name: np.ptp(p.vertices, axis=0).round(4).tolist() for p in capture.parts if p.movable},
        "camera_height_m": measurements["camera_height_m"],
        "render_seconds": round(capture.seconds, 2),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--views", type=int, default=48)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--samples", type=int, default=2)
    parser.add_argument("--objects", nargs="+", default=list(ForeignSettings.objects), choices=sorted(ASSETS))
    args = parser.parse_args()
    settings = ForeignSettings(
        views=args.views,
        width=args.width,
        height=args.height,
        seed=args.seed,
        samples=args.samples,
        objects=tuple(args.objects),
    )
    print(json.dumps(write_capture(args.output, settings), indent=1))


if __name__ == "__main__":
    main()
