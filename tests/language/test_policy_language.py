"""The policy's language path (``--policy.context=language``): the shipped head matches the shipped checkpoint,
``select_action`` acts on the batch's task string through it, the words decide the actions, the errors say what to
do, ``lerobot-eval`` runs it on ``bullet_tabletop``, and it runs with the network blocked."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from synthetic_demos import make_demonstration, object_pose

from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT, InstantPolicyConfig
from lerobot_instant_policy.evaluation.success_table import TASK_GROUPS
from lerobot_instant_policy.evaluation.suite import SuiteError, SuiteSettings, lerobot_eval_command, swap_sources
from lerobot_instant_policy.language.language_head import LanguageHead, LanguageHeadError
from lerobot_instant_policy.language.task_language import SHIPPED_LANGUAGE_HEAD, TaskLanguageError
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

REPO = Path(__file__).resolve().parents[2]


def language_policy(*overrides: str) -> InstantPolicyPolicy:
    """The shipped checkpoint with ``--policy.context=language`` and ``overrides`` (``--KEY=VALUE``), built as
    ``lerobot-eval --policy.path=... --policy.context=language`` builds it."""
    config = InstantPolicyConfig.from_pretrained(SHIPPED_CHECKPOINT, cli_overrides=["--context=language", *overrides])
    return InstantPolicyPolicy.from_pretrained(SHIPPED_CHECKPOINT, config=config).eval()


@pytest.fixture(scope="module")
def policy() -> InstantPolicyPolicy:
    return language_policy()


@pytest.fixture(scope="module")
def observation() -> dict[str, torch.Tensor]:
    """One frame, a batch of one: a mug on the table and the gripper open 25 cm above it."""
    demo = make_demonstration(object_pose(0.5, 0.0, 0.0), "pick_and_lift", seed=0, object_id="pb/mug")
    return {"observation.pointcloud": torch.from_numpy(demo.points_world[:1]),
            "observation.state": torch.from_numpy(demo.state[:1]).float()}


def first_action(policy: InstantPolicyPolicy, batch: dict, seed: int = 0) -> torch.Tensor:
    policy.reset()
    return policy.select_action(batch, generator=torch.Generator().manual_seed(seed))


def test_the_shipped_head_is_the_default_and_matches_the_shipped_checkpoint(shipped_policy, wordllama):
    head = LanguageHead.load(SHIPPED_LANGUAGE_HEAD)
    head.check_binding(shipped_policy.network, wordllama)
    size = sum(path.stat().st_size for path in SHIPPED_LANGUAGE_HEAD.iterdir())
    assert size < 4 * 2**20, f"the shipped head takes {size} bytes"
    assert InstantPolicyConfig(context="language").language_head_path is None


def test_select_action_acts_on_the_task_string(policy, observation):
    batch = {**observation, "task": ["push_button"]}
    action = first_action(policy, batch)
    assert action.shape == (1, 8) and action.dtype == torch.float32 and torch.isfinite(action).all()
    assert action[0, 7] in (0.0, 1.0) and torch.isclose(action[0, 3:7].norm(), torch.tensor(1.0), atol=1e-5)
    torch.testing.assert_close(first_action(policy, batch), action, rtol=0, atol=0)  # a seed repeats the actions
    # a batch of two rows with one task string for both: finite actions per row
    pair = {key: value.expand(2, *value.shape[1:]) for key, value in observation.items()}
    actions = first_action(policy, {**pair, "task": "push_button"})
    assert actions.shape == (2, 8) and torch.isfinite(actions).all()


def test_the_words_decide_the_actions(policy, observation, paraphrases):
    """Another task's words change the actions drawn from the same noise; a suite task's name is said with its first
    seen paraphrase, and ``language_paraphrase`` chooses another."""
    actions = {task: first_action(policy, {**observation, "task": [task]})
               for task in ("push_button", "open_drawer", paraphrases["push_button"].seen[0])}
    assert (actions["push_button"] - actions["open_drawer"]).abs().max() > 1e-3
    torch.testing.assert_close(actions[paraphrases["push_button"].seen[0]], actions["push_button"], rtol=0, atol=0)
    held_out = language_policy("--language_paraphrase=held_out:1")
    torch.testing.assert_close(first_action(held_out, {**observation, "task": ["push_button"]}),
                               first_action(policy, {**observation, "task": [paraphrases["push_button"].held_out[1]]}),
                               rtol=0, atol=0)


def test_an_instruction_replaces_every_rows_task(policy, observation, paraphrases):
    """``language_instruction`` tells every row the same words whatever its task: a task name is said with its
    paraphrase, a sentence as itself."""
    told = language_policy("--language_instruction=open_drawer")
    torch.testing.assert_close(first_action(told, {**observation, "task": ["push_button"]}),
                               first_action(policy, {**observation, "task": ["open_drawer"]}), rtol=0, atol=0)
    sentence = paraphrases["open_drawer"].held_out[0]
    told = language_policy(f"--language_instruction={sentence}")
    torch.testing.assert_close(first_action(told, {**observation, "task": ["push_button"]}),
                               first_action(policy, {**observation, "task": [sentence]}), rtol=0, atol=0)


def test_handed_in_demonstrations_take_precedence_over_the_words(policy, observation):
    """A task whose demonstrations were handed in acts on them, as with the demonstrations context."""
    demos = [make_demonstration(object_pose(0.45 + 0.05 * i, 0.05 * i, 10.0 * i), "pick_and_lift", seed=i)
             for i in range(2)]
    config = InstantPolicyConfig.from_pretrained(SHIPPED_CHECKPOINT)
    with_demos = InstantPolicyPolicy.from_pretrained(SHIPPED_CHECKPOINT, config=config).eval()
    with_demos.set_demonstrations(demos)
    fresh = language_policy()
    fresh.set_demonstrations(demos)
    batch = {**observation, "task": ["pick_and_lift"]}
    torch.testing.assert_close(first_action(fresh, batch), first_action(with_demos, batch), rtol=0, atol=0)
    assert (first_action(policy, batch) - first_action(fresh, batch)).abs().max() > 1e-3


def test_a_missing_or_blank_task_is_refused(policy, observation):
    with pytest.raises(KeyError, match="context='language' needs the task of its batch rows: pass batch\\['task'\\]"):
        first_action(policy, observation)
    for blank in ("", "   "):
        with pytest.raises(TaskLanguageError, match="non-blank task name or sentence"):
            first_action(policy, {**observation, "task": [blank]})
    with pytest.raises(TaskLanguageError, match="has 2 held_out paraphrases"):
        first_action(language_policy("--language_paraphrase=held_out:2"), {**observation, "task": ["push_button"]})


def test_a_missing_head_or_one_of_another_network_is_refused(tmp_path, observation):
    batch = {**observation, "task": ["push_button"]}
    with pytest.raises(LanguageHeadError, match=f"no language head at {tmp_path}.*lerobot-ip-train-language"):
        first_action(language_policy(f"--language_head_path={tmp_path}"), batch)
    policy = language_policy()
    first_action(policy, batch)
    with torch.no_grad():  # the weights change after the head was checked: it is checked again
        policy.network.scene_projection.weight.add_(1e-3)
    with pytest.raises(LanguageHeadError, match="bottleneck of another network.*lerobot-ip-train-language"):
        first_action(policy, batch)


@pytest.mark.parametrize("overrides, message", [
    ({"context": "words"}, "context must be one of"),
    ({"context": "language", "demo_repo_id": "local/push_button"}, "drop demo_repo_id"),
    ({"context": "language", "preset": "refined"}, "no demonstrations to replay"),
    ({"language_paraphrase": "held_out"}, "language_paraphrase: a paraphrase is chosen as SPLIT:K"),
    ({"language_paraphrase": "unseen:0"}, "language_paraphrase: a paraphrase is chosen as SPLIT:K"),
    ({"language_instruction": "open_drawer"}, "said in words only with context='language'"),
    ({"context": "language", "language_instruction": "  "}, "non-blank task name or sentence"),
])
def test_bad_language_settings_are_refused(overrides, message):
    with pytest.raises(ValueError, match=message):
        InstantPolicyConfig(**overrides)


def test_the_language_path_runs_with_the_network_blocked(no_network, observation):
    """Built, loaded (head, text encoder, paraphrases) and run with every connection refused."""
    action = first_action(language_policy(), {**observation, "task": ["put the cube in the tray"]})
    assert action.shape == (1, 8) and torch.isfinite(action).all()


def test_the_suite_runs_the_language_context_without_demonstrations(tmp_path):
    settings = SuiteSettings(policy="instant_policy", policy_path=str(SHIPPED_CHECKPOINT), out=tmp_path,
                             policy_args=("--policy.context=language",))
    assert not settings.reads_demonstrations and settings.demos_of("push_button", 0, None) is None
    command = lerobot_eval_command(settings, "push_button", None, 1000, tmp_path / "run")
    assert "--policy.context=language" in command and not any("demo_" in arg for arg in command)
    with_demos = SuiteSettings(policy="instant_policy", policy_path=str(SHIPPED_CHECKPOINT), out=tmp_path)
    assert with_demos.reads_demonstrations and with_demos.demos_of("push_button", 0, None) is not None


def test_the_swap_control_tells_each_task_another_tasks_name(tmp_path):
    """With the language context the swap reads no demonstrations: each task's run is told its source task's name,
    a task of another group (``swap_sources``)."""
    settings = SuiteSettings(policy="instant_policy", policy_path=str(SHIPPED_CHECKPOINT), out=tmp_path, swap=True,
                             policy_args=("--policy.context=language",))
    settings.validate()
    sources = swap_sources(sorted(task for group in TASK_GROUPS.values() for task in group), settings.env.group_of)
    assert all(settings.env.group_of(source) != settings.env.group_of(task) for task, source in sources.items())
    command = lerobot_eval_command(settings, "push_button", None, 1000, tmp_path / "run", sources["push_button"])
    assert f"--policy.language_instruction={sources['push_button']}" in command
    assert not any("demo_" in arg for arg in command) and settings.name == "instant_policy-swap"
    unswapped = lerobot_eval_command(settings, "push_button", None, 1000, tmp_path / "run")
    assert not any("language_instruction" in arg for arg in unswapped)
    with pytest.raises(SuiteError, match="reads demonstrations or the task in words"):
        SuiteSettings(policy="do_nothing", out=tmp_path, swap=True).validate()


def test_lerobot_eval_runs_a_task_said_in_words(tmp_path):
    """The real ``lerobot-eval`` on ``bullet_tabletop`` with ``--policy.context=language``: one episode of 8 steps
    (one prediction), the env's task string said through the shipped head."""
    output_dir = tmp_path / "eval"
    command = [str(Path(sys.executable).with_name("lerobot-eval")), "--env.type=bullet_tabletop",
               "--env.task=push_button", "--env.episode_length=8", "--env.render_size=64",
               f"--policy.path={SHIPPED_CHECKPOINT}", "--policy.context=language", "--policy.device=cpu",
               "--eval.n_episodes=1", "--eval.batch_size=1", "--eval.use_async_envs=false", "--seed=1000",
               f"--output_dir={output_dir}"]
    completed = subprocess.run(command, capture_output=True, text=True, cwd=REPO, timeout=600,
                               env={**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"})
    output = completed.stdout + completed.stderr
    assert completed.returncode == 0 and "Traceback" not in output, output[-4000:]
    per_task = json.loads((output_dir / "eval_info.json").read_text())["per_task"]
    assert [entry["task_group"] for entry in per_task] == ["push_button"]
    assert len(per_task[0]["metrics"]["successes"]) == 1
    assert np.isfinite(per_task[0]["metrics"]["sum_rewards"]).all()

