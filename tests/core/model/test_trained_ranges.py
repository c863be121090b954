"""The training data's physical properties, and the check of a scene against them."""

import numpy as np

from fignetctl.core.model.trained_ranges import (
    outside_ranges,
    property_ranges,
    ranges_from_json,
    ranges_to_json,
)


def scene(friction, restitution, mass=1.0):
    """A floor (static) and one moving object."""
    return np.array([[0.0, 0.3, 0.5], [mass, friction, restitution]]), np.array([True, False])


def test_discrete_materials_are_checked_as_pairs():
    ranges = ranges_from_json(ranges_to_json(property_ranges([scene(0.4, 0.3, 2.0), scene(0.8, 0.7, 9.0)])))
    assert ranges["dynamic"]["materials"] == [[0.4, 0.3], [0.8, 0.7]] and ranges["dynamic"]["mass"] == [
        2.0,
        9.0,
    ]
    assert ranges["static"] == {"friction": [0.3, 0.3], "restitution": [0.5, 0.5], "materials": [[0.3, 0.5]]}
    names = ["floor", "ball"]
    properties, static = scene(0.81, 0.69, 5.0)
    assert outside_ranges(ranges, names, static, properties) == []  # within the tolerance of rubber
    properties, static = scene(0.5, 0.5, 5.0)
    (found,) = outside_ranges(ranges, names, static, properties)
    assert "'ball' has friction 0.5 and restitution 0.5, not a material" in found
    properties, static = scene(0.8, 0.7, 100.0)
    (found,) = outside_ranges(ranges, names, static, properties)
    assert "'ball' has mass 100, outside the 2-9" in found
    assert outside_ranges(None, names, static, properties) == []  # a model file from before the ranges


def test_continuous_properties_are_checked_value_by_value():
    rng = np.random.default_rng(0)
    ranges = property_ranges([scene(*rng.uniform([0.2, 0.1], [0.9, 0.8])) for _ in range(40)])
    assert "materials" not in ranges["dynamic"]
    low, high = ranges["dynamic"]["friction"]
    properties, static = scene((low + high) / 2, 0.5)
    assert outside_ranges(ranges, ["floor", "ball"], static, properties) == []
    properties, static = scene(high + 0.05, 0.5)
    (found,) = outside_ranges(ranges, ["floor", "ball"], static, properties)
    assert "'ball' has friction" in found and "outside the" in found
