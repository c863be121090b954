"""The shape library of the `make-dataset` presets `movi-b` and `movi-c`.

Every shape is a `ShapeAsset`: a watertight triangle mesh for the learned simulator and the
convex parts PyBullet collides with. For a convex shape the mesh is its own single part; for a
concave shape the mesh is the union of its convex parts, so the surface the learned simulator
sees is, to float precision, the surface that collides in the ground truth. PyBullet adds a
1 mm collision margin around every convex part; `resting_gap` measures what that leaves
between a resting mesh and the floor. Parts that only touch (most V-HACD decompositions)
stay separate closed hulls in the mesh; parts that overlap are merged by a manifold3d
boolean union.

- movi-b: Kubric's 11 MOVi-B shapes at largest side 2 ("KuBasic" fits [-1, 1]^3). Eight are
  built here from convex pieces; spot, teapot and suzanne have no offline source and are
  replaced by pybullet_data's bunny, mug and duck (docs/shapes.md says why).
- movi-c: pybullet_data's 1000 `random_urdfs` (each OBJ is a V-HACD decomposition, one `o`
  group per convex part) plus its real scans, at largest side 1. 10% of the names are held
  out for `split="test"` by a stable hash of the name.

Mesh frame: origin at the centre of mass of the mesh (uniform density), unscaled.
Built assets are cached on disk under `$FIGNETCTL_CACHE/shapes` (default
`~/.cache/fignetctl/shapes`), keyed by a hash of the recipe and its input files, and written
atomically; a warm load only reads them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from fignetctl.core.atomic import atomic_path
from fignetctl.core.containers import NPZ_ERRORS
from fignetctl.core.obj import read_obj_groups, read_obj_vertices, write_convex_parts_obj
from fignetctl.errors import FignetError

logger = logging.getLogger(__name__)

RECIPE_VERSION = 1  # bump when a builder changes: it is part of every cache key
MOVI_B_LARGEST_SIDE = 2.0
MOVI_C_LARGEST_SIDE = 1.0
MOVI_B_KUBRIC_SHAPES = (
    "cube",
    "cylinder",
    "sphere",
    "cone",
    "torus",
    "gear",
    "torus_knot",
    "sponge",
    "spot",
    "teapot",
    "suzanne",
)
MOVI_B_REPLACEMENTS = {"spot": "bunny", "teapot": "mug", "suzanne": "duck"}
MOVI_B_VERTEX_RANGE = (250, 1200)
MOVI_C_VERTEX_RANGE = (0, 5000)
MAX_PART_VERTICES = 64  # V-HACD's default cap per convex hull; also bounds PyBullet's GJK cost
PART_VERTEX_CAPS = (MAX_PART_VERTICES, 48, 32, 24, 16)  # tried in turn until the union fits
TOUCHING_TOLERANCE = 1e-4  # of the largest side: parts buried no deeper than this are not unioned
MIN_PART_VOLUME_FRACTION = 1e-7  # parts thinner than this (of the bounding box) are dropped
TEST_SPLIT_PERCENT = 10
SURFACE_TOLERANCE = 2e-3  # m at scale 1: how far convex parts and mesh may disagree
PYBULLET_COLLISION_MARGIN = 1e-3  # m, measured: the gap a convex hull leaves on a plane
PHYSICS_HZ = 240
RANDOM_URDF_COUNT = 1000
MOVI_C_SCANS = {  # name -> (file in pybullet_data, how its convex parts are obtained)
    "bunny": ("bunny.obj", "vhacd"),
    "duck": ("duck_vhacd.obj", "groups"),
    "lego": ("lego/lego_vhacd.obj", "groups"),
    "mug": ("objects/mug_col.obj", "groups"),
    "soccerball": ("soccerball.obj", "hull"),
    "teddy": ("teddy2_VHACD_CHs.obj", "groups"),
}


@dataclasses.dataclass(frozen=True)
class ShapeAsset:
    """One shape of a dataset preset.

    name : unique within its preset, e.g. "torus", "mug", "random_urdfs_042"
    vertices : (V, 3) float32, object frame, origin at the centre of mass, unscaled
    faces : (F, 3) int32, counter-clockwise seen from outside
    convex_parts : tuple of (V_i, 3) float32, the convex pieces PyBullet collides with, in the
        same frame; their union is the mesh (a convex shape is its own single part)
    source : where it came from, e.g.
        "pybullet_data/duck_vhacd.obj via its V-HACD parts as shipped; 5 convex parts"
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    convex_parts: tuple
    source: str


@dataclasses.dataclass(frozen=True)
class ShapeRecipe:
    """How to build one asset; everything in it goes into the cache key.

    build : returns (convex parts as (n, 3) float arrays, surface mesh or None): parts and no
        surface are unioned; a surface and no parts is convex (its own part); both: the
        surface is already the union of the parts (a tube and its segments)
    input_files : files the build reads (their bytes are hashed into the cache key)
    """

    name: str
    build: Callable
    source: str
    input_files: tuple
    largest_side: float
    vertex_range: tuple
    parameters: dict = dataclasses.field(default_factory=dict)


# ----------------------------------------------------------------------------- public API


def movi_b_names() -> list[str]:
    """Our names of the 11 MOVi-B shapes, in Kubric's order (replacements substituted)."""
    return [MOVI_B_REPLACEMENTS.get(name, name) for name in MOVI_B_KUBRIC_SHAPES]


def movi_c_names(split: str = "all") -> list[str]:
    """The movi-c shape names of one split ("train", "test" or "all"), sorted.

    Names only: nothing is loaded or built.
    """
    check_split(split)
    names = [random_urdf_name(index) for index in range(RANDOM_URDF_COUNT)] + sorted(MOVI_C_SCANS)
    return [name for name in names if split in ("all", split_of(name))]


def split_of(name: str) -> str:
    """ "test" for the TEST_SPLIT_PERCENT of names whose SHA-256 falls in the held-out bucket."""
    bucket = int(hashlib.sha256(name.encode()).hexdigest()[:8], 16) % 100
    return "test" if bucket < TEST_SPLIT_PERCENT else "train"


def load_shapes(
    preset: str, split: str = "train", names=None, limit=None, cache_dir=None
) -> list[ShapeAsset]:
    """The shapes of a preset ("movi-b" or "movi-c") in one split ("train", "test", "all").

    movi-b has no held-out shapes (Kubric tests on new scenes of the same 11 shapes), so every
    split returns all 11. `names` picks shapes of the preset by name, `limit` keeps the first
    `limit` of them. Assets come from the disk cache when it holds them; a movi-b shape that
    cannot be built raises FignetError, a movi-c one is skipped with a logged warning.
    """
    check_split(split)
    recipes = recipes_of_preset(preset, split)
    if names is not None:
        recipes = pick_recipes(recipes, names, preset)
    recipes = recipes if limit is None else recipes[: int(limit)]
    cache = Path(cache_dir) if cache_dir is not None else shape_cache_dir()
    if preset == "movi-b":
        return [cached_asset(recipe, cache) for recipe in recipes]
    return [asset for asset in (cached_asset_or_none(recipe, cache) for recipe in recipes) if asset]


def shape_cache_dir() -> Path:
    """`$FIGNETCTL_CACHE/shapes`, or `~/.cache/fignetctl/shapes` when the variable is unset."""
    root = os.environ.get("FIGNETCTL_CACHE") or Path.home() / ".cache" / "fignetctl"
    return Path(root) / "shapes"


def resting_gap(
    asset: ShapeAsset,
    scale: float = 1.0,
    settle_seconds: float = 4.0,
    quaternion_wxyz=(1.0, 0.0, 0.0, 0.0),
    cache_dir=None,
) -> float:
    """Height (m) of the lowest mesh vertex above the floor after the shape settles in PyBullet.

    Kubric's settings (240 Hz, gravity -10, a static plane at z = 0), the asset as a compound of
    its convex parts, dropped from 1 cm above the floor in the given orientation. Positive:
    the mesh hovers (PyBullet's collision margin), negative: it sinks. `cache_dir` holds the
    parts' OBJ file (see `create_pybullet_collision_shape`).
    """
    import pybullet

    client = pybullet.connect(pybullet.DIRECT)
    try:
        configure_kubric_physics(client)
        floor_shape = pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=client)
        pybullet.createMultiBody(0.0, floor_shape, physicsClientId=client)
        body = drop_asset(asset, scale, quaternion_wxyz, client, cache_dir)
        for _ in range(int(round(settle_seconds * PHYSICS_HZ))):
            pybullet.stepSimulation(physicsClientId=client)
        return float(world_vertices(asset, scale, body, client)[:, 2].min())
    finally:
        pybullet.disconnect(client)


def create_pybullet_collision_shape(
    asset: ShapeAsset, scale: float = 1.0, physics_client_id: int = 0, cache_dir=None
) -> int:
    """A PyBullet collision shape made of the asset's convex parts, scaled uniformly.

    PyBullet turns every `o` group of an OBJ file into one convex hull of a compound shape,
    so the parts are written to an OBJ named by the hash of their contents (PyBullet caches
    OBJ files by name: a reused name would silently return an earlier shape).
    """
    import pybullet

    cache = Path(cache_dir) if cache_dir is not None else shape_cache_dir()
    path = convex_parts_obj_path(asset, cache)
    shape = pybullet.createCollisionShape(
        pybullet.GEOM_MESH,
        fileName=str(path),
        meshScale=[float(scale)] * 3,
        physicsClientId=physics_client_id,
    )
    if shape < 0:
        raise FignetError(f"PyBullet could not create a collision shape for {asset.name!r} from {path}")
    return shape


def surface_deviation(asset: ShapeAsset, samples: int = 4000, seed: int = 0) -> float:
    """How far (m, at scale 1) the mesh strays from the boundary of its convex parts' union.

    At every vertex and at `samples` points spread over the faces: the distance to the nearest
    part, negative when inside it (a hull's plane distance: exact inside, a lower bound
    outside). A point on the union's boundary scores 0; the largest magnitude is returned.
    """
    import trimesh

    mesh = trimesh.Trimesh(asset.vertices, asset.faces, process=False)
    sampled, _ = trimesh.sample.sample_surface(mesh, samples, seed=seed)
    points = np.concatenate([mesh.vertices, sampled])
    distances = np.min([hull_plane_distance(part, points) for part in asset.convex_parts], axis=0)
    return float(np.abs(distances).max())


def hull_plane_distance(part: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) float: the largest signed distance of each point to the planes of the part's hull."""
    from scipy.spatial import ConvexHull

    equations = ConvexHull(np.asarray(part, dtype=np.float64)).equations
    return (points @ equations[:, :3].T + equations[:, 3]).max(axis=1)


# ----------------------------------------------------------------------------- recipes


def check_split(split: str) -> None:
    """Raise FignetError unless `split` is "train", "test" or "all"."""
    if split not in ("train", "test", "all"):
        raise FignetError(f"unknown split {split!r}: use 'train', 'test' or 'all'")


def recipes_of_preset(preset: str, split: str) -> list[ShapeRecipe]:
    """The recipes of a preset's split, in a stable order."""
    if preset == "movi-b":
        return movi_b_recipes()
    if preset == "movi-c":
        return [movi_c_recipe(name) for name in movi_c_names(split)]
    raise FignetError(f"unknown shape preset {preset!r}: use 'movi-b' or 'movi-c'")


def pick_recipes(recipes: list, names, preset: str) -> list:
    """The recipes named in `names`, in that order; FignetError for a name not in the preset."""
    by_name = {recipe.name: recipe for recipe in recipes}
    unknown = [name for name in names if name not in by_name]
    if unknown:
        listed = ", ".join(map(repr, unknown))
        raise FignetError(f"no shape named {listed} in preset {preset!r} and this split")
    return [by_name[name] for name in names]


def movi_b_recipes() -> list[ShapeRecipe]:
    """The 11 movi-b recipes in Kubric's order."""
    procedural = {
        "cube": cube_surface,
        "cylinder": cylinder_surface,
        "sphere": sphere_surface,
        "cone": cone_surface,
        "torus": torus_parts,
        "gear": gear_parts,
        "torus_knot": torus_knot_parts,
        "sponge": sponge_parts,
    }
    recipes = []
    for name in movi_b_names():
        if name in procedural:
            recipes.append(procedural_recipe(name, procedural[name]))
        else:
            recipes.append(scan_recipe(name, MOVI_B_LARGEST_SIDE, MOVI_B_VERTEX_RANGE))
    return recipes


PROCEDURAL_SOURCES = {
    "cube": "procedural (trimesh box, subdivided; convex)",
    "cylinder": "procedural (trimesh revolve; convex)",
    "sphere": "procedural (trimesh icosphere; convex)",
    "cone": "procedural (trimesh revolve; convex)",
    "torus": "procedural (tube mesh; its convex segments)",
    "gear": "procedural (manifold3d union of a disk and 12 teeth, subdivided)",
    "torus_knot": "procedural ((2,3) knot tube mesh; its convex segments)",
    "sponge": "procedural (manifold3d union of a level-1 Menger sponge's 12 boxes, subdivided)",
}


def procedural_recipe(name: str, builder: Callable) -> ShapeRecipe:
    """A movi-b recipe built in code by `builder` (no input files)."""
    return ShapeRecipe(
        name=name,
        build=builder,
        source=PROCEDURAL_SOURCES[name],
        input_files=(),
        largest_side=MOVI_B_LARGEST_SIDE,
        vertex_range=MOVI_B_VERTEX_RANGE,
    )


def movi_c_recipe(name: str) -> ShapeRecipe:
    """The movi-c recipe of a random_urdfs name or a scan name."""
    if name in MOVI_C_SCANS:
        return scan_recipe(name, MOVI_C_LARGEST_SIDE, MOVI_C_VERTEX_RANGE)
    path = pybullet_data_path() / "random_urdfs" / name[-3:] / f"{name[-3:]}.obj"
    return ShapeRecipe(
        name=name,
        build=lambda: (read_obj_groups(path), None),
        source=f"pybullet_data/random_urdfs/{name[-3:]}/{name[-3:]}.obj (V-HACD parts as shipped)",
        input_files=(str(path),),
        largest_side=MOVI_C_LARGEST_SIDE,
        vertex_range=MOVI_C_VERTEX_RANGE,
    )


def scan_recipe(name: str, largest_side: float, vertex_range: tuple) -> ShapeRecipe:
    """A recipe for one of pybullet_data's scans (MOVI_C_SCANS), also used by movi-b."""
    relative, method = MOVI_C_SCANS[name]
    path = pybullet_data_path() / relative
    builders = {
        "groups": lambda: (read_obj_groups(path), None),
        "vhacd": lambda: (read_obj_groups_after_vhacd(path), None),
        "hull": lambda: ([], convex_hull_surface(read_obj_vertices(path), 1000)),
    }
    how = {"groups": "its V-HACD parts as shipped", "vhacd": "pybullet.vhacd", "hull": "its convex hull"}
    return ShapeRecipe(
        name=name,
        build=builders[method],
        source=f"pybullet_data/{relative} via {how[method]}",
        input_files=(str(path),),
        largest_side=largest_side,
        vertex_range=vertex_range,
        parameters={"method": method},
    )


def random_urdf_name(index: int) -> str:
    """ "random_urdfs_042" for index 42 (no "/": mesh names are HDF5 group names)."""
    return f"random_urdfs_{index:03d}"


def pybullet_data_path() -> Path:
    """The folder of the pybullet_data package that ships with the pybullet wheel."""
    import pybullet_data

    return Path(pybullet_data.getDataPath())


# ----------------------------------------------------------------------------- disk cache


def cached_asset_or_none(recipe: ShapeRecipe, cache: Path):
    """`cached_asset`, or None with a logged warning when the shape cannot be built."""
    try:
        return cached_asset(recipe, cache)
    except FignetError as error:
        logger.warning("skipping shape %s: %s", recipe.name, error)
        return None


def cached_asset(recipe: ShapeRecipe, cache: Path) -> ShapeAsset:
    """The asset from its cache file, building and writing it on a miss.

    A shape that failed to build is cached as its failure, so a warm load does not retry it;
    an unreadable cache file is rebuilt.
    """
    path = cache / f"{safe_file_stem(recipe.name)}-{recipe_key(recipe)[:20]}.npz"
    if path.exists():
        try:
            return read_cached_asset(path, recipe.name)
        except NPZ_ERRORS as error:
            logger.warning("rebuilding shape %s: cannot read %s (%s)", recipe.name, path, error)
    try:
        asset = build_asset(recipe)
    except FignetError as error:
        write_cache_file(path, {"failure": np.array(str(error))})
        raise
    write_cache_file(path, asset_arrays(asset))
    return asset


def recipe_key(recipe: ShapeRecipe) -> str:
    """SHA-256 of the recipe's name, settings, RECIPE_VERSION and the bytes of its input files."""
    digest = hashlib.sha256()
    settings = [RECIPE_VERSION, recipe.name, recipe.source, recipe.largest_side, list(recipe.vertex_range)]
    settings += [PART_VERTEX_CAPS, TOUCHING_TOLERANCE, MIN_PART_VOLUME_FRACTION, recipe.parameters]
    digest.update(json.dumps(settings, sort_keys=True).encode())
    for file_name in recipe.input_files:
        digest.update(Path(file_name).read_bytes())
    return digest.hexdigest()


def safe_file_stem(name: str) -> str:
    """The name with anything but letters, digits, '-' and '_' replaced by '_'."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


def asset_arrays(asset: ShapeAsset) -> dict:
    """The arrays that store an asset in a cache file (parts concatenated, with their sizes)."""
    return {
        "vertices": asset.vertices,
        "faces": asset.faces,
        "part_vertices": np.concatenate(asset.convex_parts, axis=0),
        "part_sizes": np.array([len(part) for part in asset.convex_parts], dtype=np.int64),
        "source": np.array(asset.source),
    }


def read_cached_asset(path: Path, name: str) -> ShapeAsset:
    """The asset stored in a cache file; FignetError if the file records a failed build."""
    with np.load(path, allow_pickle=False) as stored:
        if "failure" in stored:
            raise FignetError(str(stored["failure"]))
        parts = np.split(stored["part_vertices"], np.cumsum(stored["part_sizes"])[:-1])
        return ShapeAsset(
            name=name,
            vertices=stored["vertices"],
            faces=stored["faces"],
            convex_parts=tuple(parts),
            source=str(stored["source"]),
        )


def write_cache_file(path: Path, arrays: dict) -> None:
    """Write the arrays to an .npz atomically (readers never see a half-written file)."""
    with atomic_path(path) as temporary, open(temporary, "wb") as handle:
        np.savez(handle, **arrays)


def convex_parts_obj_path(asset: ShapeAsset, cache: Path) -> Path:
    """An OBJ file with one `o` group (the convex hull) per part, named by the parts' hash."""
    digest = hashlib.sha256()
    for part in asset.convex_parts:
        digest.update(np.ascontiguousarray(part, dtype=np.float32).tobytes())
    path = cache / "collision" / f"{safe_file_stem(asset.name)}-{digest.hexdigest()[:20]}.obj"
    if not path.exists():
        write_convex_parts_obj(asset.convex_parts, path)
    return path


def build_asset(recipe: ShapeRecipe) -> ShapeAsset:
    """Build a recipe: parts -> union mesh (or the given surface) -> normalized asset.

    Geometry errors from qhull, manifold3d or a malformed OBJ become FignetError.
    """
    try:
        return built_asset(recipe)
    except (ValueError, RuntimeError, IndexError) as error:
        raise FignetError(f"shape {recipe.name!r} could not be built: {error}") from error


def built_asset(recipe: ShapeRecipe) -> ShapeAsset:
    """`build_asset` without the error translation."""
    parts, surface = recipe.build()
    if surface is None:
        parts = solid_parts(parts, recipe.name)
        parts, mesh = union_within_vertex_range(parts, recipe.vertex_range)
    else:
        mesh = subdivide_to_vertex_range(surface, recipe.vertex_range)
        parts = parts or [np.asarray(mesh.vertices)]
    check_solid(mesh, recipe.name)
    return normalized_asset(recipe, mesh, parts)


def solid_parts(parts: list, name: str) -> list:
    """The hull vertices of the parts with a non-negligible volume; FignetError if none is left.

    Rows with NaN or infinity are dropped first (random_urdfs/168 is all NaN).
    """
    parts = [np.asarray(part, dtype=np.float64) for part in parts]
    parts = [part[np.isfinite(part).all(axis=1)] for part in parts]
    parts = [part for part in parts if len(part) >= 4]
    if not parts:
        raise FignetError(f"shape {name!r} has an empty convex decomposition (no part with 4 finite points)")
    extent = np.ptp(np.concatenate(parts), axis=0)
    minimum_volume = MIN_PART_VOLUME_FRACTION * max(float(np.prod(extent)), 1e-300)
    hulls = [hull for hull in map(convex_hull_or_none, parts) if hull is not None]
    hulls = [hull for hull in hulls if hull.volume > minimum_volume]
    if not hulls:
        raise FignetError(f"shape {name!r} has only zero-volume convex parts")
    return [hull.points[hull.vertices] for hull in hulls]


def convex_hull_or_none(points: np.ndarray):
    """scipy's ConvexHull of (n, 3) points, or None when they are flat or degenerate."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return ConvexHull(points)
    except (QhullError, ValueError):
        return None


def union_within_vertex_range(parts: list, vertex_range: tuple):
    """The parts and their union, with fewer hull vertices per part until the union fits.

    Tries the caps of PART_VERTEX_CAPS in turn; the last one is kept even if still too large.
    The union is then subdivided up to the lower end of the range.
    """
    for cap in PART_VERTEX_CAPS:
        capped = [simplified_convex_part(part, cap) for part in parts]
        mesh = union_of_convex_parts(capped)
        if len(mesh.vertices) <= vertex_range[1]:
            break
    return capped, subdivide_to_vertex_range(mesh, vertex_range)


def simplified_convex_part(points: np.ndarray, max_vertices: int) -> np.ndarray:
    """(n, 3) float: hull vertices, decimated to at most `max_vertices` (`points` if it fits).

    Quadric decimation of the hull, then the hull of what is left: still convex, and still
    the exact collision shape because the simplified part is the one stored.
    """
    import trimesh

    if len(points) <= max_vertices:
        return points
    hull = trimesh.convex.convex_hull(points)
    for _ in range(8):
        if len(hull.vertices) <= max_vertices:
            break
        target_faces = max(4, 2 * min(max_vertices, len(hull.vertices) - 1) - 4)
        hull = trimesh.convex.convex_hull(hull.simplify_quadric_decimation(face_count=target_faces).vertices)
    return np.asarray(hull.vertices, dtype=np.float64)


def union_of_convex_parts(parts: list):
    """The union of the parts' convex hulls as a watertight trimesh.Trimesh.

    V-HACD parts only touch (gaps of ~3e-5 of the size, or none): then the union is just the
    hulls side by side, each one closed, with qhull's clean triangles. Parts that overlap
    deeper than TOUCHING_TOLERANCE (of the largest side) go through a manifold3d boolean
    union instead, whose seams bring slivers and some zero-area triangles.
    """
    side_by_side = hulls_side_by_side(parts)
    tolerance = TOUCHING_TOLERANCE * float(np.max(side_by_side.extents))
    if len(parts) == 1 or deepest_buried_point(side_by_side, parts) <= tolerance:
        return side_by_side
    return boolean_union(parts)


def hulls_side_by_side(parts: list):
    """One mesh of the parts' convex hulls (qhull triangles, outward), not merged."""
    import trimesh

    vertices, faces, offset = [], [], 0
    for part in parts:
        hull = convex_hull_or_none(np.asarray(part, dtype=np.float64))
        remap = np.zeros(len(hull.points), dtype=np.int64)
        remap[hull.vertices] = np.arange(len(hull.vertices)) + offset
        triangles = hull.simplices.copy()
        outward = (
            np.einsum(
                "ij,ij->i",
                np.cross(
                    hull.points[triangles[:, 1]] - hull.points[triangles[:, 0]],
                    hull.points[triangles[:, 2]] - hull.points[triangles[:, 0]],
                ),
                hull.equations[:, :3],
            )
            > 0
        )
        triangles[~outward] = triangles[~outward][:, ::-1]
        vertices.append(hull.points[hull.vertices])
        faces.append(remap[triangles])
        offset += len(hull.vertices)
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


def deepest_buried_point(mesh, parts: list, samples: int = 2000) -> float:
    """How deep (m) the mesh's vertices and surface samples reach inside any part, at most.

    For hulls side by side, a point of one hull that lies inside another is buried; a point
    on its own hull scores 0. Only points inside a part's bounding box are tested against it.
    """
    import trimesh

    sampled, _ = trimesh.sample.sample_surface(mesh, samples, seed=0)
    points = np.concatenate([mesh.vertices, sampled])
    deepest = 0.0
    for part in parts:
        near = np.all((points >= part.min(axis=0)) & (points <= part.max(axis=0)), axis=1)
        if near.any():
            deepest = max(deepest, -float(hull_plane_distance(part, points[near]).min()))
    return deepest


def boolean_union(parts: list):
    """The manifold3d boolean union of the parts' convex hulls, as a trimesh.Trimesh."""
    import manifold3d
    import trimesh

    hulls = [manifold3d.Manifold.hull_points(np.asarray(part, dtype=np.float64)) for part in parts]
    union = manifold3d.Manifold.batch_boolean(hulls, manifold3d.OpType.Add).to_mesh()
    vertices = np.asarray(union.vert_properties)[:, :3]
    return trimesh.Trimesh(vertices, np.asarray(union.tri_verts), process=False)


def subdivide_to_vertex_range(mesh, vertex_range: tuple):
    """Split every triangle in four while the mesh is below the range and the split fits in it.

    Midpoint subdivision keeps the surface exactly (flat triangles stay where they are).
    """
    import trimesh

    while len(mesh.vertices) < vertex_range[0] and 4 * len(mesh.vertices) <= vertex_range[1]:
        vertices, faces = trimesh.remesh.subdivide(mesh.vertices, mesh.faces)
        mesh = trimesh.Trimesh(vertices, faces, process=False)
    return mesh


def check_solid(mesh, name: str) -> None:
    """FignetError unless the mesh is watertight with consistent winding and positive volume."""
    if len(mesh.faces) == 0 or not mesh.is_watertight:
        raise FignetError(f"shape {name!r}: the union of its convex parts is not watertight")
    if not mesh.is_winding_consistent or not mesh.volume > 0:
        raise FignetError(f"shape {name!r}: its mesh has zero volume or inward-facing triangles")


def normalized_asset(recipe: ShapeRecipe, mesh, parts: list) -> ShapeAsset:
    """Scale mesh and parts to the recipe's largest side, then move the centre of mass to 0."""
    import trimesh

    factor = recipe.largest_side / float(np.max(mesh.extents))
    scaled = trimesh.Trimesh(np.asarray(mesh.vertices) * factor, mesh.faces, process=False)
    centre_of_mass = np.asarray(scaled.center_mass)
    return ShapeAsset(
        name=recipe.name,
        vertices=(scaled.vertices - centre_of_mass).astype(np.float32),
        faces=np.asarray(mesh.faces, dtype=np.int32),
        convex_parts=tuple((part * factor - centre_of_mass).astype(np.float32) for part in parts),
        source=describe_source(recipe.source, parts),
    )


def describe_source(source: str, parts: list) -> str:
    """The recipe's source with the number of convex parts appended."""
    return f"{source}; {len(parts)} convex part{'s' if len(parts) != 1 else ''}"


# ----------------------------------------------------------------------------- OBJ input


def read_obj_groups_after_vhacd(path) -> list[np.ndarray]:
    """The convex parts PyBullet's V-HACD finds for an OBJ mesh (its console output muted)."""
    import pybullet

    with tempfile.TemporaryDirectory() as folder:
        output, log = Path(folder) / "parts.obj", Path(folder) / "vhacd.log"
        with muted_stdout():
            pybullet.vhacd(str(path), str(output), str(log))
        if not output.exists():
            raise FignetError(f"V-HACD wrote no decomposition of {path}")
        return read_obj_groups(output)


@contextlib.contextmanager
def muted_stdout():
    """Send file descriptor 1 to /dev/null for a while (V-HACD prints progress from C++)."""
    import sys

    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def convex_hull_surface(points: np.ndarray, max_vertices: int):
    """The convex hull of `points` as a mesh, decimated to at most `max_vertices` vertices."""
    import trimesh

    return trimesh.convex.convex_hull(simplified_convex_part(points, max_vertices))


# ----------------------------------------------------------------------------- movi-b shapes


def cube_surface():
    """A cube of side 2 (subdivided later into a grid of triangles)."""
    import trimesh

    return [], trimesh.creation.box(extents=(2.0, 2.0, 2.0))


def sphere_surface():
    """A unit icosphere, 642 vertices."""
    import trimesh

    return [], trimesh.creation.icosphere(subdivisions=3, radius=1.0)


def cylinder_surface():
    """A cylinder of radius 1 and height 2, with rings on the caps and the side."""
    profile = [
        (0.0, -1.0),
        (1 / 3, -1.0),
        (2 / 3, -1.0),
        (1.0, -1.0),
        (1.0, -0.5),
        (1.0, 0.0),
        (1.0, 0.5),
        (1.0, 1.0),
        (2 / 3, 1.0),
        (1 / 3, 1.0),
        (0.0, 1.0),
    ]
    return [], revolved_surface(profile, sections=40)


def cone_surface():
    """A cone of base radius 1 and height 2, with rings on the base and the side."""
    profile = [
        (0.0, -1.0),
        (1 / 3, -1.0),
        (2 / 3, -1.0),
        (1.0, -1.0),
        (0.8, -0.6),
        (0.6, -0.2),
        (0.4, 0.2),
        (0.2, 0.6),
        (0.0, 1.0),
    ]
    return [], revolved_surface(profile, sections=40)


def revolved_surface(profile, sections: int):
    """The watertight surface of revolution of (radius, z) points about the z axis."""
    import trimesh

    mesh = trimesh.creation.revolve(np.asarray(profile, dtype=np.float64), sections=sections)
    mesh.merge_vertices()
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def torus_parts():
    """A torus (major radius 1, tube radius 0.25): a 48 x 12 tube and its 48 convex segments."""
    angles = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
    radial = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    up = np.tile([0.0, 0.0, 1.0], (len(angles), 1))
    rings = tube_rings(radial, radial, up, radius=0.25, sides=12)
    return tube_segments(rings), tube_surface(rings)


def torus_knot_parts():
    """A (2, 3) torus knot (trefoil): an 84 x 10 tube of radius 0.6 and its 84 convex segments.

    The curve's smallest radius of curvature is 1.43 and its strands pass no closer than 1.66,
    so the tube neither folds nor touches itself.
    """
    parameter = np.linspace(0.0, 2 * np.pi, 84, endpoint=False)
    centres = torus_knot_curve(parameter)
    tangents = np.roll(centres, -1, axis=0) - np.roll(centres, 1, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    normals = closed_curve_normals(tangents)
    rings = tube_rings(centres, normals, np.cross(tangents, normals), radius=0.6, sides=10)
    return tube_segments(rings), tube_surface(rings)


def torus_knot_curve(parameter: np.ndarray) -> np.ndarray:
    """(n, 3) float: the (p, q) = (2, 3) torus knot on a torus of radii 2 and 1."""
    radius = 2.0 + np.cos(3 * parameter)
    x, y = radius * np.cos(2 * parameter), radius * np.sin(2 * parameter)
    return np.stack([x, y, np.sin(3 * parameter)], axis=1)


def closed_curve_normals(tangents: np.ndarray) -> np.ndarray:
    """(n, 3) float: unit normals carried along a closed curve's tangents with little twist.

    Parallel transport around the loop comes back rotated by some angle (its holonomy);
    that angle is spread evenly over the rings so the last ring lines up with the first.
    """
    seed = np.cross(tangents[0], [0.0, 0.0, 1.0])
    if np.linalg.norm(seed) < 1e-6:
        seed = np.cross(tangents[0], [1.0, 0.0, 0.0])
    normals = [seed / np.linalg.norm(seed)]
    for tangent in list(tangents[1:]) + [tangents[0]]:
        normal = normals[-1] - np.dot(normals[-1], tangent) * tangent
        normals.append(normal / np.linalg.norm(normal))
    returned = normals.pop()
    holonomy = np.arctan2(np.dot(np.cross(normals[0], returned), tangents[0]), np.dot(normals[0], returned))
    fractions = -holonomy * np.arange(len(tangents)) / len(tangents)
    binormals = np.cross(tangents, normals)
    return np.cos(fractions)[:, None] * np.asarray(normals) + np.sin(fractions)[:, None] * binormals


def tube_rings(centres, normals, binormals, radius: float, sides: int) -> np.ndarray:
    """(n, sides, 3) float: a ring of `sides` points around each centre of a closed curve.

    centres, normals, binormals : (n, 3) float, the curve and two unit vectors across it.
    """
    angles = np.linspace(0.0, 2 * np.pi, sides, endpoint=False)
    return (
        centres[:, None, :]
        + radius * np.cos(angles)[None, :, None] * normals[:, None, :]
        + radius * np.sin(angles)[None, :, None] * binormals[:, None, :]
    )


def tube_segments(rings: np.ndarray) -> list[np.ndarray]:
    """The convex parts of a closed tube: the points of each two consecutive rings.

    rings : (n, m, 3) float. Consecutive segments share a ring exactly (the last joins the
    first), so the union of their hulls is the tube of `tube_surface`.
    """
    return [np.concatenate([rings[i], rings[(i + 1) % len(rings)]]) for i in range(len(rings))]


def tube_surface(rings: np.ndarray):
    """The closed tube through (n, m, 3) rings, outward winding, each quad folded outward.

    A quad whose corners are not coplanar (the knot twists a little between rings) is split
    along the diagonal that bulges out, as the convex hull of its two rings does, so the
    surface stays the union of `tube_segments`.
    """
    import trimesh

    count, sides = rings.shape[:2]
    ring, side = np.meshgrid(np.arange(count), np.arange(sides), indexing="ij")
    a = (ring * sides + side).ravel()
    b = (((ring + 1) % count) * sides + side).ravel()
    c = (((ring + 1) % count) * sides + (side + 1) % sides).ravel()
    d = (ring * sides + (side + 1) % sides).ravel()
    points = rings.reshape(-1, 3)
    if trimesh.Trimesh(points, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])).volume < 0:
        a, b, c, d = d, c, b, a
    normal_abc = np.cross(points[b] - points[a], points[c] - points[a])
    fold_out = np.einsum("ij,ij->i", points[d] - points[a], normal_abc) <= 0
    first = np.where(fold_out[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    second = np.where(fold_out[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    return trimesh.Trimesh(points, np.concatenate([first, second]), process=False)


def gear_parts():
    """A spur gear: a 48-sided disk (radius 0.8, thickness 0.4) and 12 trapezoid teeth to radius 1."""
    disk = prism(regular_polygon(0.8, 48), thickness=0.4)
    teeth = []
    for angle in np.linspace(0.0, 2 * np.pi, 12, endpoint=False):
        outline = np.array([[0.7, -0.13], [1.0, -0.07], [1.0, 0.07], [0.7, 0.13]])
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        teeth.append(prism(outline @ rotation.T, thickness=0.4))
    return [disk] + teeth, None


def regular_polygon(radius: float, sides: int) -> np.ndarray:
    """(sides, 2) float: the corners of a regular polygon around the origin."""
    angles = np.linspace(0.0, 2 * np.pi, sides, endpoint=False)
    return radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def prism(outline: np.ndarray, thickness: float) -> np.ndarray:
    """(2n, 3) float: the corners of a convex 2D outline extruded symmetrically along z."""
    half = thickness / 2
    bottom = np.column_stack([outline, np.full(len(outline), -half)])
    top = np.column_stack([outline, np.full(len(outline), half)])
    return np.concatenate([bottom, top])


def sponge_parts():
    """A level-1 Menger sponge of side 3 as 12 boxes: 4 corner columns and 8 edge bars.

    The bars run the full length of their edge, so they overlap the columns at the corners.
    """
    parts = []
    for x in (-1.5, 0.5):
        for y in (-1.5, 0.5):
            parts.append(box_corners((x, y, -1.5), (x + 1, y + 1, 1.5)))
    for z in (-1.5, 0.5):
        for offset in (-1.5, 0.5):
            parts.append(box_corners((-1.5, offset, z), (1.5, offset + 1, z + 1)))
            parts.append(box_corners((offset, -1.5, z), (offset + 1, 1.5, z + 1)))
    return parts, None


def box_corners(low, high) -> np.ndarray:
    """(8, 3) float: the corners of the axis-aligned box from `low` to `high`."""
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    grid = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T
    return low + grid * (high - low)


# ----------------------------------------------------------------------------- PyBullet


def configure_kubric_physics(client: int, gravity=(0.0, 0.0, -10.0), hz: int = PHYSICS_HZ) -> None:
    """Kubric's PyBullet settings: `hz` steps a second (240), `gravity` ((0, 0, -10)) and its
    engine parameters (Kubric's against "sticky walls", bullet3 issue 3094)."""
    import pybullet

    pybullet.setGravity(*gravity, physicsClientId=client)
    pybullet.setTimeStep(1.0 / hz, physicsClientId=client)
    pybullet.setPhysicsEngineParameter(
        restitutionVelocityThreshold=0,
        warmStartingFactor=0,
        useSplitImpulse=True,
        contactSlop=0,
        enableConeFriction=False,
        deterministicOverlappingPairs=True,
        physicsClientId=client,
    )


def drop_asset(asset: ShapeAsset, scale: float, quaternion_wxyz, client: int, cache_dir=None) -> int:
    """A 1 kg body of the asset's parts, its lowest vertex 1 cm above z = 0 in that orientation."""
    import pybullet

    w, x, y, z = (float(value) for value in quaternion_wxyz)
    rotation = np.asarray(pybullet.getMatrixFromQuaternion([x, y, z, w])).reshape(3, 3)
    lowest = float((scale * asset.vertices.astype(np.float64) @ rotation.T)[:, 2].min())
    shape = create_pybullet_collision_shape(asset, scale, physics_client_id=client, cache_dir=cache_dir)
    return pybullet.createMultiBody(
        1.0,
        shape,
        basePosition=[0.0, 0.0, 0.01 - lowest],
        baseOrientation=[x, y, z, w],
        physicsClientId=client,
    )


def world_vertices(asset: ShapeAsset, scale: float, body: int, client: int) -> np.ndarray:
    """(V, 3) float: the asset's mesh vertices where PyBullet has put the body now."""
    import pybullet

    position, orientation = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
    rotation = np.asarray(pybullet.getMatrixFromQuaternion(orientation)).reshape(3, 3)
    return scale * asset.vertices.astype(np.float64) @ rotation.T + np.asarray(position)
