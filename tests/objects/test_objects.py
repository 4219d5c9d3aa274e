"""The object library: ids, splits and normalised meshes (``pseudo_demos.objects``)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lerobot_instant_policy.objects.library import (
    MAX_FACES,
    MAX_SIZE,
    MIN_SIZE,
    all_object_ids,
    is_held_out,
    load_object,
    object_ids,
    validate_object_id,
)

ONE_OF_EACH = [
    "urdf/000",
    "pb/duck",
    "prim/box_0",
    "prim/drawer_1",
    "prim/lidded_box_2",
    "prim/torus_3",
    "prim/capsule_0",
    "prim/cone_0",
    "prim/cylinder_0",
]


def test_library_size_and_splits():
    everything = all_object_ids()
    assert len(everything) == 1295 == len(set(everything))
    assert "urdf/168" not in everything  # its .obj in pybullet_data has NaN vertices
    assert everything == sorted(everything)
    assert object_ids("all") == everything
    train, held_out = object_ids("train"), object_ids("held_out")
    assert len(held_out) == 131
    assert not set(train) & set(held_out)
    assert set(train) | set(held_out) == set(everything)
    assert len(train) == 1295 - 131
    assert object_ids() == train  # train is the default
    assert {"pb/bunny", "pb/soccerball", "pb/toy_prism"} <= set(held_out)
    assert all(is_held_out(object_id) for object_id in held_out)
    assert not any(is_held_out(object_id) for object_id in train)


@pytest.mark.parametrize(
    ("object_id", "held_out"),
    [
        ("urdf/009", True),
        ("urdf/010", False),
        ("urdf/999", True),
        ("urdf/090", False),
        ("prim/box_9", True),
        ("prim/lidded_box_19", True),
        ("prim/box_0", False),
        ("prim/cylinder_0", False),
        ("prim/drawer_39", True),
        ("pb/bunny", True),
        ("pb/duck", False),
    ],
)
def test_is_held_out(object_id, held_out):
    assert is_held_out(object_id) is held_out


def test_unknown_id_raises_key_error_naming_families():
    for bad in ("urdf/1000", "pb/teapot", "prim/box_40", "prim/sphere_0", "duck"):
        with pytest.raises(KeyError) as info:
            load_object(bad)
        message = str(info.value)
        assert repr(bad) in message
        assert "urdf/" in message and "pb/" in message and "prim/" in message
    with pytest.raises(KeyError):
        validate_object_id("urdf/00")
    validate_object_id("urdf/000")  # a valid id passes silently


def test_unknown_split_raises_value_error():
    with pytest.raises(ValueError, match="unknown object split 'test'"):
        object_ids("test")


def _distance_to_mesh(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Exact unsigned distance of each point to the nearest triangle (brute force; small meshes only)."""
    triangles = mesh.triangles
    distances = np.empty(len(points))
    for start in range(0, len(points), 128):
        chunk = points[start : start + 128]
        closest = trimesh.triangles.closest_point(
            np.tile(triangles, (len(chunk), 1, 1)), np.repeat(chunk, len(triangles), axis=0)
        )
        gaps = np.linalg.norm(closest - np.repeat(chunk, len(triangles), axis=0), axis=1)
        distances[start : start + 128] = gaps.reshape(len(chunk), len(triangles)).min(axis=1)
    return distances


@pytest.mark.parametrize("object_id", ONE_OF_EACH)
def test_load_object_is_normalised(object_id):
    model = load_object(object_id)
    assert model.object_id == object_id
    assert model.vertices.ndim == 2 and model.vertices.shape[1] == 3
    assert model.faces.ndim == 2 and model.faces.shape[1] == 3
    assert 0 < len(model.faces) <= MAX_FACES
    assert model.faces.min() >= 0 and model.faces.max() < len(model.vertices)
    assert MIN_SIZE - 1e-9 <= model.extents.max() <= MAX_SIZE + 1e-9
    lower, upper = model.vertices.min(axis=0), model.vertices.max(axis=0)
    assert lower[2] == pytest.approx(0.0, abs=1e-9)  # rests on the table
    np.testing.assert_allclose((lower[:2] + upper[:2]) / 2, 0.0, atol=1e-9)  # centred in x/y
    assert model.footprint_radius >= np.abs(model.vertices[:, :2]).max() - 1e-12

    mesh = trimesh.Trimesh(model.vertices, model.faces, process=False)
    assert model.surface_points.shape == model.surface_normals.shape
    assert len(model.surface_points) >= 512
    np.testing.assert_allclose(np.linalg.norm(model.surface_normals, axis=1), 1.0, atol=1e-6)
    points = model.surface_points[:: max(1, len(model.surface_points) // 256)]
    assert _distance_to_mesh(mesh, points).max() < 1e-6  # on the surface
    # samples spread over the whole object, not a corner of it
    spread = model.surface_points.max(axis=0) - model.surface_points.min(axis=0)
    assert np.all(spread >= 0.8 * model.extents)


@pytest.mark.parametrize("object_id", ["prim/box_0", "prim/cylinder_0", "prim/cone_0", "prim/capsule_0"])
def test_convex_primitives_have_outward_normals(object_id):
    model = load_object(object_id)
    centre = (model.vertices.min(axis=0) + model.vertices.max(axis=0)) / 2
    outward = np.einsum("ij,ij->i", model.surface_points - centre, model.surface_normals)
    assert np.all(outward > -1e-9)


def test_load_object_is_deterministic():
    first = load_object.__wrapped__("urdf/000")  # bypass the per-process cache
    second = load_object.__wrapped__("urdf/000")
    assert first is not second
    for name in ("vertices", "faces", "surface_points", "surface_normals"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name))
    cached = load_object("urdf/000")
    np.testing.assert_array_equal(cached.vertices, first.vertices)
    assert load_object("urdf/000") is cached


def test_sizes_and_shapes_vary_with_the_id():
    sizes = {round(float(load_object(f"prim/box_{k}").extents.max()), 6) for k in range(4)}
    assert len(sizes) == 4
    a, b = load_object("prim/box_0"), load_object("prim/box_1")
    assert not np.allclose(a.extents / a.extents.max(), b.extents / b.extents.max())


def test_every_library_object_loads_as_a_finite_mesh():
    for object_id in all_object_ids():
        model = load_object(object_id)
        assert len(model.faces) > 0 and np.isfinite(model.vertices).all(), object_id
