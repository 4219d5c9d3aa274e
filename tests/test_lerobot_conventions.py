"""LeRobot 0.6.1's conventions where its own generic policy tests (``tests/policies/test_policies.py``) probe a policy,
for the four policies of this package, each through the paths users run: LeRobot's factory
(``make_policy_config``, ``get_policy_class``, ``make_pre_post_processors``), ``save_pretrained`` and
``from_pretrained``.

- One observation (no batch dimension) through the default preprocessor reaches ``select_action`` batched: the
  point cloud ``(P, 3)`` as well as the state ``(8,)``.
- A batch without ``task`` uses the demonstrations' one task (the demonstration dataset's, or the one handed in), and
  says what to pass where there are several.
- The policies without parameters save and load through both of LeRobot's save paths.
- Each policy's ``__init__`` annotates ``config`` with its config class itself, not a string.
"""

from __future__ import annotations

import inspect
import json

import pytest
import torch
from lerobot.policies.factory import get_policy_class, make_policy_config, make_pre_post_processors
from synthetic_demos import make_demonstration, object_pose, write_demo_dataset

import lerobot_instant_policy  # noqa: F401  (registers the policies, as LeRobot's plugin discovery does)
from lerobot_instant_policy.baselines.configuration_metaworld_expert import ENVIRONMENT_STATE_KEY
from lerobot_instant_policy.contract import NUM_POINTS, POINTCLOUD_KEY, STATE_KEY

pytestmark = pytest.mark.usefixtures("single_torch_thread")

POLICIES = ("instant_policy", "demo_replay", "do_nothing", "metaworld_expert")
PARAMETER_FREE = ("demo_replay", "do_nothing", "metaworld_expert")
TASK = "lift"
ONE_TASK_REPO, TWO_TASK_REPO = "local/conventions_one_task", "local/conventions_two_tasks"


def make(name: str, **overrides):
    """``(policy, preprocessor, postprocessor)`` as ``lerobot-eval --policy.type=name`` builds them."""
    config = make_policy_config(name, device="cpu", **overrides)
    policy = get_policy_class(name)(config)
    preprocessor, postprocessor = make_pre_post_processors(config)
    return policy, preprocessor, postprocessor


def one_observation(seed: int = 0) -> dict:
    """One frame of the lift task with the object moved, no batch dimension: ``(P, 3)`` and ``(8,)``."""
    demo = make_demonstration(object_pose(0.52, -0.05, 35.0), TASK, seed=seed)
    return {POINTCLOUD_KEY: torch.from_numpy(demo.points_world[0]), STATE_KEY: torch.from_numpy(demo.state[0])}


@pytest.fixture(scope="module")
def demo_roots(tmp_path_factory):
    """Two demonstration datasets: lift only, and lift and push."""
    root = tmp_path_factory.mktemp("conventions")
    poses = [object_pose(0.5, 0.0, 0.0), object_pose(0.45, 0.1, 20.0)]
    write_demo_dataset(root / "one", ONE_TASK_REPO, [(TASK, pose) for pose in poses])
    write_demo_dataset(root / "two", TWO_TASK_REPO, [(TASK, poses[0]), ("push", poses[1])])
    return {"one": root / "one", "two": root / "two"}


# ------------------------------------------------------------------------------------------ batch dimension
@pytest.mark.parametrize("name", POLICIES)
def test_the_preprocessor_batches_one_observation_cloud_and_state_alike(name, tmp_path):
    _, preprocessor, postprocessor = make(name)
    observation = {**one_observation(), ENVIRONMENT_STATE_KEY: torch.zeros(39)}
    batch = preprocessor(dict(observation))
    assert batch[STATE_KEY].shape == (1, 8) and batch[POINTCLOUD_KEY].shape == (1, NUM_POINTS, 3)
    torch.testing.assert_close(batch[POINTCLOUD_KEY][0], observation[POINTCLOUD_KEY], rtol=0, atol=0)
    batched = preprocessor({key: value[None] for key, value in observation.items()})
    assert batched[POINTCLOUD_KEY].shape == (1, NUM_POINTS, 3)  # already batched: unchanged
    # saved and loaded the way lerobot-eval --policy.path loads a checkpoint's processors
    preprocessor.save_pretrained(tmp_path)
    postprocessor.save_pretrained(tmp_path)
    config = make_policy_config(name, device="cpu")
    loaded, _ = make_pre_post_processors(config, pretrained_path=str(tmp_path),
                                         preprocessor_overrides={"device_processor": {"device": "cpu"}})
    assert [type(step).__name__ for step in loaded.steps] == [type(step).__name__ for step in preprocessor.steps]
    assert loaded(dict(observation))[POINTCLOUD_KEY].shape == (1, NUM_POINTS, 3)


def test_one_observation_through_the_preprocessor_reaches_select_action():
    """``instant_policy`` and ``demo_replay``, which read the cloud, act on one unbatched observation."""
    demonstrations = [make_demonstration(object_pose(0.5, 0.0, 0.0), TASK, seed=1),
                      make_demonstration(object_pose(0.45, 0.1, 20.0), TASK, seed=2)]
    for name in ("instant_policy", "demo_replay"):
        policy, preprocessor, postprocessor = make(name)
        policy.set_demonstrations(demonstrations)
        policy.reset()
        with torch.inference_mode():
            action = postprocessor(policy.select_action(preprocessor({**one_observation(), "task": TASK})))
        assert action.shape == (1, 8) and torch.isfinite(action).all(), name


# ------------------------------------------------------------------------------------------ the task
@pytest.mark.parametrize("name", ["instant_policy", "demo_replay"])
def test_a_batch_without_task_uses_the_demonstration_datasets_one_task(name, demo_roots):
    policy, preprocessor, _ = make(name, demo_repo_id=ONE_TASK_REPO, demo_root=str(demo_roots["one"]), num_demos=2)
    batch = preprocessor(one_observation())
    assert "task" not in batch
    with torch.inference_mode():
        policy.reset()
        without = policy.select_action(batch, **seeded(name))
        policy.reset()
        with_task = policy.select_action({**batch, "task": [TASK]}, **seeded(name))
    torch.testing.assert_close(without, with_task, rtol=0, atol=0)


@pytest.mark.parametrize("name", ["instant_policy", "demo_replay"])
def test_a_batch_without_task_is_refused_saying_what_to_pass(name, demo_roots):
    policy, preprocessor, _ = make(name, demo_repo_id=TWO_TASK_REPO, demo_root=str(demo_roots["two"]))
    batch = preprocessor(one_observation())
    with pytest.raises(KeyError, match=r"pass batch\['task'\].*has the tasks \['lift', 'push'\]"):
        policy.select_action(batch)
    policy, preprocessor, _ = make(name)  # no dataset: demonstrations handed in, of one task, then of two
    policy.set_demonstrations([make_demonstration(object_pose(0.5, 0.0, 0.0), TASK, seed=1)])
    with torch.inference_mode():
        assert policy.select_action(batch, **seeded(name)).shape == (1, 8)
    policy.set_demonstrations([make_demonstration(object_pose(0.5, 0.0, 0.0), "push", seed=1)])
    policy.reset()
    with pytest.raises(KeyError, match=r"pass batch\['task'\].*tasks \['lift', 'push'\] were handed in"):
        policy.select_action(batch)


def test_metaworld_expert_without_task_says_what_to_pass():
    policy, preprocessor, _ = make("metaworld_expert")
    batch = preprocessor({STATE_KEY: one_observation()[STATE_KEY], ENVIRONMENT_STATE_KEY: torch.zeros(39)})
    with pytest.raises(KeyError, match=r"pass batch\['task'\].*MetaWorld v3 task name"):
        policy.select_action(batch)


def seeded(name: str) -> dict:
    """``select_action``'s keyword arguments that fix its noise (``instant_policy`` samples; ``demo_replay`` not)."""
    return {"generator": torch.Generator().manual_seed(0)} if name == "instant_policy" else {}


# ------------------------------------------------------------------------------------------ save and load
@pytest.mark.parametrize("name", PARAMETER_FREE)
@pytest.mark.parametrize("path", ["state_dict", "module"])
def test_a_policy_without_parameters_saves_and_loads(name, path, tmp_path):
    """Both of LeRobot's save paths: with a handed-in state dict (``lerobot-train``'s under FSDP, ``push_to_hub``),
    which writes no file for an empty one, and from the module; and a folder saved without the weights file."""
    policy, _, _ = make(name)
    assert list(policy.parameters()) == []
    policy.save_pretrained(tmp_path, **({"state_dict": policy.state_dict()} if path == "state_dict" else {}))
    assert (tmp_path / "model.safetensors").is_file()
    loaded = get_policy_class(name).from_pretrained(tmp_path)
    assert type(loaded) is type(policy) and loaded.config == policy.config
    (tmp_path / "model.safetensors").unlink()
    assert get_policy_class(name).from_pretrained(tmp_path).config == policy.config
    assert json.loads((tmp_path / "config.json").read_text())["type"] == name


def test_a_policy_without_parameters_refuses_a_state_dict_with_tensors(tmp_path):
    policy, _, _ = make("do_nothing")
    with pytest.raises(ValueError, match="has no parameters"):
        policy.save_pretrained(tmp_path, state_dict={"weight": torch.zeros(1)})


# ------------------------------------------------------------------------------------------ annotations
@pytest.mark.parametrize("name", POLICIES)
def test_config_annotation_is_the_config_class(name):
    """LeRobot's ``test_get_policy_and_config_classes``: the config is an instance of the class that the policy's
    ``__init__`` annotates ``config`` with."""
    policy_cls, config = get_policy_class(name), make_policy_config(name)
    annotation = inspect.signature(policy_cls.__init__).parameters["config"].annotation
    assert policy_cls.name == name
    assert isinstance(annotation, type) and issubclass(config.__class__, annotation)
    assert policy_cls.config_class is annotation


def test_no_unbatched_cloud_reaches_the_policy_unnoticed():
    """Without the preprocessor, ``select_action`` still refuses a cloud without its batch dimension."""
    policy, _, _ = make("instant_policy")
    policy.set_demonstrations([make_demonstration(object_pose(0.5, 0.0, 0.0), TASK, seed=1)])
    observation = one_observation()
    with pytest.raises(ValueError, match=r"\(B, P, 3\)"):
        policy.select_action({**observation, STATE_KEY: observation[STATE_KEY][None], "task": [TASK]})
