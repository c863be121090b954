"""Stand-in shapes for the MOVi tests, made from trimesh primitives so that the tests do not
depend on the preset shape library: a 2 m cube, an icosphere of radius 1 m and an L of two
boxes whose principal frame is not the object frame."""

import numpy as np

from fignetctl.core.shapes import ShapeAsset


def shape(name, mesh, parts=None):
    """A ShapeAsset of a trimesh mesh moved to its centre of mass; parts default to the mesh."""
    centre = np.asarray(mesh.center_mass)
    parts = [mesh.vertices] if parts is None else parts
    return ShapeAsset(
        name=name,
        vertices=np.asarray(mesh.vertices - centre, np.float32),
        faces=np.asarray(mesh.faces, np.int32),
        convex_parts=tuple(np.asarray(part - centre, np.float32) for part in parts),
        source="test",
    )


def l_shape():
    """Two boxes (2 x 1 x 1 and 1 x 1 x 1) touching along a face: an L with the two as convex parts."""
    import trimesh

    long = trimesh.creation.box((2.0, 1.0, 1.0))
    foot = trimesh.creation.box((1.0, 1.0, 1.0), trimesh.transformations.translation_matrix([0.5, 1.0, 0.0]))
    return shape("ell", trimesh.util.concatenate([long, foot]), parts=[long.vertices, foot.vertices])


def stand_in_shapes():
    """[cube, ball, ell]."""
    import trimesh

    return [
        shape("cube", trimesh.creation.box((2.0, 2.0, 2.0))),
        shape("ball", trimesh.creation.icosphere(subdivisions=2, radius=1.0)),
        l_shape(),
    ]
