"""The physical properties a model was trained on, and a check of a scene against them.

The network reads mass, friction and restitution as node features, so it only knows the
values its training data held. MOVi-B has two materials for moving objects (friction 0.4 and
restitution 0.3, or 0.8 and 0.7) and one for the floor (0.3, 0.5): anything else is
extrapolation, even a pair whose values each lie between the materials' (friction 0.5 with
restitution 0.5). Measured on the two-frame FIGNet* (docs/simulator.md, "Physical properties"):
a resting cube of friction 0.5 and restitution 0.5 slid 13 cm in 30 steps; of MOVi-B's rubber,
7 mm.

`trained_properties` is stored in the model file by `fignetctl train` (and kept by export):

    {"dynamic": {"mass": [lo, hi], "friction": [lo, hi], "restitution": [lo, hi],
                 "materials": [[friction, restitution], ...],
                 "largest_side": [lo, median, hi]},
     "static": {"friction": [lo, hi], "restitution": [lo, hi], "materials": [...]}}

`largest_side` (metres, each moving object's largest bounding-box side in its own frame) tells
`rollout --sim-scale auto` which sizes the model knows (froude.py); files without it are
taken to know the bundled models' movi-b sizes.

`materials` lists the distinct (friction, restitution) pairs when there are at most
MAX_MATERIALS of them (data with discrete materials, like Kubric's); a scene's pair must then
be within MATERIAL_TOLERANCE of one of them. Otherwise each value is checked against its range.
"""

from __future__ import annotations

import json

import numpy as np

NAMES = ("mass", "friction", "restitution")
RELATIVE_SLACK = 1e-3  # float32 rounding of the stored values
MAX_MATERIALS = 16
MATERIAL_TOLERANCE = 0.02


def property_ranges(properties_and_static, largest_sides=None) -> dict:
    """The ranges (and materials) of an iterable of ((O, 3) mass/friction/restitution, (O,)
    static) pairs, and the range and median of the moving objects' `largest_sides` (m) if given."""
    rows = {False: [], True: []}
    for properties, static in properties_and_static:
        properties, static = np.asarray(properties, np.float64), np.asarray(static, bool)
        rows[False].append(properties[~static])
        rows[True].append(properties[static])
    ranges = {}
    for kind, is_static in (("dynamic", False), ("static", True)):
        values = np.concatenate(rows[is_static]) if rows[is_static] else np.empty((0, 3))
        if len(values):
            names = NAMES[1:] if is_static else NAMES  # a static object's mass is always 0
            ranges[kind] = {
                name: [float(values[:, NAMES.index(name)].min()), float(values[:, NAMES.index(name)].max())]
                for name in names
            }
            materials = np.unique(values[:, 1:].astype(np.float32), axis=0)
            if len(materials) <= MAX_MATERIALS:
                ranges[kind]["materials"] = [[round(float(f), 6), round(float(r), 6)] for f, r in materials]
    sides = np.asarray([] if largest_sides is None else largest_sides, np.float64)
    if sides.size and "dynamic" in ranges:
        ranges["dynamic"]["largest_side"] = [float(v) for v in np.percentile(sides, [0, 50, 100])]
    return ranges


def trajectory_largest_sides(data, key) -> np.ndarray:
    """(D,) the largest side (m) of each moving object's scaled mesh in trajectory `key` of a
    TrajectoryFile (its bounding box in the object frame)."""
    trajectory = data.trajectories[key]
    return np.asarray(
        [
            float(np.ptp(np.asarray(data.meshes[name].vertices, np.float64), axis=0).max() * scale)
            for name, scale, static in zip(trajectory.mesh_names, trajectory.scales, trajectory.static)
            if not static
        ],
        np.float64,
    )


def largest_side(rest_vertices) -> float:
    """The largest side (m) of the bounding box of (V, 3) scaled vertices in the object frame."""
    return float((rest_vertices.max(axis=0) - rest_vertices.min(axis=0)).max())


def largest_sides(geometry) -> np.ndarray:
    """(D,) the largest side (m) of each moving object's bounding box in its own frame."""
    return np.asarray(
        [
            largest_side(geometry.rest_vertices[geometry.vertex_object == index])
            for index in np.flatnonzero(~geometry.static)
        ],
        np.float64,
    )


def ranges_to_json(ranges) -> str:
    return json.dumps(ranges, sort_keys=True)


def ranges_from_json(text):
    """The ranges of a model file's `trained_properties`, or None (a file from before it)."""
    return None if text is None else json.loads(text)


def outside_ranges(ranges, names, static, properties) -> list[str]:
    """One sentence per object property the model was not trained on; [] when ranges is None."""
    if not ranges:
        return []
    found = []
    for name, is_static, values in zip(names, np.asarray(static, bool), np.asarray(properties, np.float64)):
        kind = "static" if is_static else "dynamic"
        known = ranges.get(kind, {})
        materials = known.get("materials")
        for property_name in ("mass",) if materials else NAMES:
            if property_name not in known:
                continue
            low, high = known[property_name]
            value = float(values[NAMES.index(property_name)])
            slack = RELATIVE_SLACK * max(abs(low), abs(high), 1e-12)
            if not low - slack <= value <= high + slack:
                span = f"{low:g}" if low == high else f"{low:g}-{high:g}"
                found.append(
                    f"{kind} object {name!r} has {property_name} {value:g}, outside the {span} the model was trained on"
                )
        if (
            materials
            and not (np.abs(np.asarray(materials) - values[1:]).max(axis=1) <= MATERIAL_TOLERANCE).any()
        ):
            seen = ", ".join(f"({f:g}, {r:g})" for f, r in materials)
            found.append(
                f"{kind} object {name!r} has friction {values[1]:g} and restitution {values[2]:g}, "
                f"not a material the model was trained on (friction, restitution: {seen})"
            )
    return found
