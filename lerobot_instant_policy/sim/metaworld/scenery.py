"""Which geoms of a MetaWorld model belong to the task, found from the model and MetaWorld's own scene file.

Every MetaWorld v3 task model is made of three parts:

* MetaWorld's scene: the table, on most tasks a retaining wall around it, and the floor (a geom of the world body),
  declared in the ``scene/basic_scene*.xml`` file that the task's XML includes (which one differs between tasks:
  ``hand-insert-v3`` and ``sweep-into-v3`` have a table with a hole and no retaining wall);
* the robot: the tree of bodies welded to the mocap body that drives the hand (the Sawyer), and the mocap body;
* the task's own bodies: objects, fixtures such as a drawer case, a shelf or a coffee machine, walls a task adds.

A geom is the task's when it belongs to none of the first two. Nothing here is a list of body names: the scene's
bodies are read from the scene file the task's model includes, the robot from the model's weld constraints.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path

import mujoco
import numpy as np

SCENE_FOLDER = "scene"  # MetaWorld's assets/scene/: the files every task model includes for its table and floor


def scene_body_names(model_xml: Path) -> set[str]:
    """The names of the bodies declared by the scene files (those in a ``scene`` folder) that ``model_xml``, a
    MetaWorld task's XML, includes. ``ValueError`` when it includes none."""
    names: set[str] = set()
    included = False
    for include in ElementTree.parse(model_xml).getroot().iter("include"):
        path = (model_xml.parent / include.get("file", "")).resolve()
        if path.parent.name != SCENE_FOLDER:
            continue
        included = True
        names |= {body.get("name") for body in ElementTree.parse(path).getroot().iter("body") if body.get("name")}
    if not included:
        raise ValueError(f"{model_xml} includes no MetaWorld scene file (a {SCENE_FOLDER}/*.xml): not a MetaWorld "
                         f"task model")
    return names


def robot_root_bodies(model: mujoco.MjModel) -> set[int]:
    """Ids of the root bodies (children of the world body) of the trees welded to a mocap body: the robot, whose hand
    the mocap body drives. ``ValueError`` when no weld joins a mocap body."""
    roots = set()
    for index in range(model.neq):
        if model.eq_type[index] != mujoco.mjtEq.mjEQ_WELD:
            continue
        first, second = int(model.eq_obj1id[index]), int(model.eq_obj2id[index])
        for mocap, other in ((first, second), (second, first)):
            if model.body_mocapid[mocap] >= 0 and model.body_mocapid[other] < 0:
                roots.add(int(model.body_rootid[other]))
    if not roots:
        raise ValueError("no weld joins a mocap body to the robot: not a MetaWorld task model")
    return roots


def task_object_geoms(model: mujoco.MjModel, model_xml: Path) -> np.ndarray:
    """``(ngeom,)`` bool: the geoms of the task's own bodies (module docstring): not the world body's (the floor), not
    the robot's or a mocap body's, not the scene's (``model_xml``: the task's XML, MetaWorld's ``model_name``)."""
    scene_names = scene_body_names(model_xml)
    scene = {index for index in range(model.nbody) if model.body(index).name in scene_names}
    mocap = set(np.flatnonzero(model.body_mocapid >= 0).tolist())
    not_task = scene | mocap | robot_root_bodies(model) | {0}
    roots = model.body_rootid[model.geom_bodyid]
    return ~np.isin(roots, list(not_task)) & (model.geom_bodyid != 0)
