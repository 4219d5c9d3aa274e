"""The object library: meshes from ``pybullet_data`` and procedural trimesh primitives.

Object ids:

- ``urdf/000`` … ``urdf/999``: the procedurally made ``random_urdfs`` of ``pybullet_data``, except those in
  ``BROKEN_URDFS`` (``168.obj`` ships with NaN vertices), 999 objects;
- ``pb/<name>``: named ``pybullet_data`` meshes (duck, teddy, mug, lego, jenga, tray, …);
- ``prim/<shape>_<k>``: trimesh primitives, ``k`` in ``0 … 39`` sets the shape's proportions
  (box, cylinder, capsule, cone, torus, lidded box, drawer-like cabinet).

Meshes are decimated to at most ``MAX_FACES`` triangles (rendering cost grows with them). Every object is
normalised to its own frame: the bounding box is centred in x/y, rests on z = 0, and the
largest extent is a size between ``MIN_SIZE`` and ``MAX_SIZE`` fixed by the id. The held-out split
(``HELD_OUT``) is every id whose number ends in 9 (``urdf/009``, ``urdf/019`` … and ``prim/*_9``,
``prim/*_19`` …) plus ``pb/bunny``, ``pb/soccerball`` and ``pb/toy_prism``: 100 + 28 + 3 = 131 of the 1,295 objects that
pseudo-demonstrations never use unless asked.
"""

from __future__ import annotations

import functools
import os
import zlib
from dataclasses import dataclass

import numpy as np
import pybullet_data
import trimesh
from scipy.spatial.transform import Rotation

MIN_SIZE = 0.06
MAX_SIZE = 0.22
SURFACE_SAMPLES = 1024
MAX_FACES = 800
PRIMITIVE_SHAPES = ("box", "cylinder", "capsule", "cone", "torus", "lidded_box", "drawer")
PRIMITIVE_VARIANTS = 40

# name: (path in pybullet_data, per-axis scale, rpy of the mesh inside its URDF)
_PYBULLET_MESHES: dict[str, tuple[str, tuple[float, float, float], tuple[float, float, float]]] = {
    "duck": ("duck.obj", (1, 1, 1), (np.pi / 2, 0, 0)),
    "teddy": ("teddy2_VHACD_CHs.obj", (1, 1, 1), (np.pi / 2, 0, 0)),
    "mug": ("objects/mug.obj", (1, 1, 1), (0, 0, 0)),
    "lego": ("lego/lego.obj", (1, 1, 1), (np.pi / 2, 0, 0)),
    "jenga": ("jenga/jenga.obj", (0.15, 0.05, 0.03), (0, 0, 0)),
    "tray": ("tray/tray_textured.obj", (1, 1, 1), (0, 0, 0)),
    "domino": ("domino/domino.obj", (1, 1, 1), (0, 0, np.pi / 2)),
    "torus": ("torus/torus_textured.obj", (1, 1, 1), (np.pi / 2, 0, 0)),
    "bunny": ("bunny.obj", (1, 1, 1), (0, 0, 0)),
    "soccerball": ("soccerball.obj", (1, 1, 1), (0, 0, 0)),
    "shape_sorter": ("toys/shape_sorter.obj", (1, 1, 1), (0, 0, 0)),
    "concave_box": ("toys/concave_box.obj", (1, 1, 1), (0, 0, 0)),
    "toy_cylinder": ("toys/cylinder.obj", (1, 1, 1), (0, 0, 0)),
    "toy_prism": ("toys/prism.obj", (1, 1, 1), (0, 0, 0)),
    "toy_cube": ("toys/cube.obj", (1, 1, 1), (0, 0, 0)),
    "cube": ("cube.obj", (1, 1, 1), (0, 0, 0)),
}
_HELD_OUT_NAMED = ("pb/bunny", "pb/soccerball", "pb/toy_prism")
BROKEN_URDFS = frozenset({"168"})


@dataclass(frozen=True)
class ObjectModel:
    """A normalised object: a triangle mesh in its own frame and samples of its surface.

    ``vertices (V, 3)`` and ``faces (F, 3)`` in metres; ``surface_points (S, 3)`` and ``surface_normals (S, 3)``
    are area-uniform surface samples (outward normals), used to place waypoints and to find what a closing
    gripper can reach.
    """

    object_id: str
    vertices: np.ndarray
    faces: np.ndarray
    surface_points: np.ndarray
    surface_normals: np.ndarray

    @property
    def extents(self) -> np.ndarray:
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)

    @property
    def footprint_radius(self) -> float:
        """Radius of the object's footprint on the table (m), for non-overlapping placement."""
        return float(np.linalg.norm(self.vertices[:, :2], axis=1).max())


def all_object_ids() -> list[str]:
    """Every id in the library, sorted."""
    ids = [f"urdf/{index:03d}" for index in range(1000) if f"{index:03d}" not in BROKEN_URDFS]
    ids += [f"pb/{name}" for name in _PYBULLET_MESHES]
    ids += [f"prim/{shape}_{k}" for shape in PRIMITIVE_SHAPES for k in range(PRIMITIVE_VARIANTS)]
    return sorted(ids)


def is_held_out(object_id: str) -> bool:
    """Whether ``object_id`` belongs to the fixed held-out split (see the module docstring)."""
    if object_id in _HELD_OUT_NAMED:
        return True
    family, _, name = object_id.partition("/")
    if family == "urdf":
        return name.endswith("9")
    if family == "prim":
        return name.rsplit("_", 1)[-1].endswith("9")
    return False


def object_ids(split: str = "train") -> list[str]:
    """Ids of a split: ``"train"`` (default for generation), ``"held_out"`` or ``"all"``."""
    if split == "all":
        return all_object_ids()
    if split == "train":
        return [object_id for object_id in all_object_ids() if not is_held_out(object_id)]
    if split == "held_out":
        return [object_id for object_id in all_object_ids() if is_held_out(object_id)]
    raise ValueError(f"unknown object split {split!r}; expected 'train', 'held_out' or 'all'")


def validate_object_id(object_id: str) -> None:
    """Raise ``KeyError`` naming the id families when ``object_id`` is not in the library."""
    if object_id not in _known_ids():
        raise KeyError(
            f"unknown object id {object_id!r}: ids are 'urdf/000'…'urdf/999', "
            f"'pb/<{'|'.join(_PYBULLET_MESHES)}>' or 'prim/<{'|'.join(PRIMITIVE_SHAPES)}>_<0…{PRIMITIVE_VARIANTS - 1}>'"
        )


@functools.lru_cache(maxsize=512)
def load_object(object_id: str) -> ObjectModel:
    """Load and normalise one object (cached per process)."""
    validate_object_id(object_id)
    rng = np.random.default_rng(zlib.crc32(object_id.encode()))
    family, _, name = object_id.partition("/")
    if family == "urdf":
        mesh = _load_mesh(os.path.join("random_urdfs", name, f"{name}.obj"), (1, 1, 1), (0, 0, 0))
    elif family == "pb":
        mesh = _load_mesh(*_PYBULLET_MESHES[name])
    else:
        shape, _, variant = name.rpartition("_")
        mesh = _make_primitive(shape, np.random.default_rng([int(variant), PRIMITIVE_SHAPES.index(shape)]))
    if len(mesh.faces) > MAX_FACES:
        mesh = mesh.simplify_quadric_decimation(face_count=MAX_FACES)
    size = rng.uniform(MIN_SIZE, MAX_SIZE)
    lower, upper = mesh.bounds
    mesh.apply_translation([-(lower[0] + upper[0]) / 2, -(lower[1] + upper[1]) / 2, -lower[2]])
    mesh.apply_scale(size / mesh.extents.max())
    points, face_index = trimesh.sample.sample_surface(mesh, SURFACE_SAMPLES, seed=int(rng.integers(2**31)))
    normals = mesh.face_normals[face_index]
    return ObjectModel(
        object_id=object_id,
        vertices=np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        faces=np.ascontiguousarray(mesh.faces, dtype=np.int32),
        surface_points=np.asarray(points, dtype=np.float64),
        surface_normals=np.asarray(normals, dtype=np.float64),
    )


@functools.lru_cache(maxsize=1)
def _known_ids() -> frozenset[str]:
    return frozenset(all_object_ids())


def _load_mesh(path: str, scale: tuple[float, float, float], rpy: tuple[float, float, float]) -> trimesh.Trimesh:
    mesh = trimesh.load(os.path.join(pybullet_data.getDataPath(), path), force="mesh")
    mesh.apply_transform(np.diag([*scale, 1.0]))
    rotation = np.eye(4)
    rotation[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    mesh.apply_transform(rotation)
    return mesh


def _make_primitive(shape: str, rng: np.random.Generator) -> trimesh.Trimesh:
    """A primitive whose proportions come from ``rng``; its size is normalised by the caller."""
    a, b, c = rng.uniform(0.3, 1.0, size=3)
    if shape == "box":
        return trimesh.creation.box(extents=[a, b, c])
    if shape == "cylinder":
        return trimesh.creation.cylinder(radius=a / 2, height=c, sections=24)
    if shape == "capsule":
        return trimesh.creation.capsule(radius=a / 3, height=c, count=[12, 12])
    if shape == "cone":
        return trimesh.creation.cone(radius=a / 2, height=c, sections=24)
    if shape == "torus":
        return trimesh.creation.torus(major_radius=0.5, minor_radius=0.08 + 0.2 * b, major_sections=24, minor_sections=10)
    if shape == "lidded_box":
        return _lidded_box(a, b, c)
    if shape == "drawer":
        return _drawer(a, b, c, rng.uniform(0.2, 0.7))
    raise KeyError(f"unknown primitive shape {shape!r}")


def _lidded_box(width: float, depth: float, height: float) -> trimesh.Trimesh:
    """An open-top box with a slightly larger lid resting on it and a knob on the lid."""
    wall = 0.04
    parts = [trimesh.creation.box([width, depth, wall], _translation(0, 0, wall / 2))]
    for sign in (-1, 1):
        parts.append(trimesh.creation.box([wall, depth, height], _translation(sign * (width - wall) / 2, 0, height / 2)))
        parts.append(trimesh.creation.box([width, wall, height], _translation(0, sign * (depth - wall) / 2, height / 2)))
    parts.append(trimesh.creation.box([width * 1.05, depth * 1.05, wall], _translation(0, 0, height + wall / 2)))
    parts.append(trimesh.creation.cylinder(radius=0.05, height=0.08, sections=12, transform=_translation(0, 0, height + wall + 0.04)))
    return trimesh.util.concatenate(parts)


def _drawer(width: float, depth: float, height: float, opening: float) -> trimesh.Trimesh:
    """A cabinet shell with a drawer pulled out by ``opening`` of its depth, with a bar handle."""
    wall = 0.04
    parts = [
        trimesh.creation.box([width, depth, wall], _translation(0, 0, wall / 2)),
        trimesh.creation.box([width, depth, wall], _translation(0, 0, height - wall / 2)),
        trimesh.creation.box([width, wall, height], _translation(0, depth / 2 - wall / 2, height / 2)),
    ]
    for sign in (-1, 1):
        parts.append(trimesh.creation.box([wall, depth, height], _translation(sign * (width - wall) / 2, 0, height / 2)))
    drawer_height = height - 3 * wall
    front_y = -depth / 2 - opening * depth
    parts.append(trimesh.creation.box([width - 3 * wall, depth - wall, drawer_height * 0.6], _translation(0, front_y + depth / 2, height / 2 - drawer_height * 0.2)))
    parts.append(trimesh.creation.box([width - 2 * wall, wall, drawer_height], _translation(0, front_y, height / 2)))
    parts.append(trimesh.creation.box([width * 0.5, 0.04, 0.04], _translation(0, front_y - 0.06, height / 2)))
    for sign in (-1, 1):
        parts.append(trimesh.creation.box([0.03, 0.06, 0.03], _translation(sign * width * 0.22, front_y - 0.03, height / 2)))
    return trimesh.util.concatenate(parts)


def _translation(x: float, y: float, z: float) -> np.ndarray:
    transform = np.eye(4)
    transform[:3, 3] = (x, y, z)
    return transform
