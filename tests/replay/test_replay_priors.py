"""Training priors of pseudo-tasks (``replay/priors.py``): the plan inference makes, read at the plan step the live
demonstration has reached; a live demonstration that is one of its context's gets its own actions back; the stream
and the pool carry the priors only when asked, keep a wrong prior with the probability asked, and read a prior off
time by at most the shift asked."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.contract import REPLAY_PRIOR_KEPT_KEY, REPLAY_PRIOR_KEY, poses_from_vectors
from lerobot_instant_policy.model.geometry_encoder import encoder_preset
from lerobot_instant_policy.pseudo_demos.generation import GenerationConfig
from lerobot_instant_policy.pseudo_demos.stream import PseudoTaskStream, StreamConfig
from lerobot_instant_policy.replay.plan import REPLAY_REGISTRATION, ReplaySource, plan_replay
from lerobot_instant_policy.replay.priors import replay_prior_actions, replay_priors
from lerobot_instant_policy.replay.segments import plan_is_wrong
from lerobot_instant_policy.replay.timing import plan_steps, prior_steps
from lerobot_instant_policy.training.task_pool import EncoderSource, encode_task

WEIGHTS = InstantPolicyConfig(device="cpu").encoder_weights_path()


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread(single_torch_thread):
    yield


def stream_config(**overrides) -> StreamConfig:
    values = dict(generation=GenerationConfig(seed=11), num_demos=2, num_waypoints=10, horizon=8, samples_per_task=3,
                  tasks_per_render=2, surface_samples=1024, zbuffer_resolution=(160, 120), replay_priors=True)
    return StreamConfig(**(values | overrides))


@pytest.fixture(scope="module")
def rendered():
    """Two-object pick-and-place tasks of the full family, with priors."""
    return PseudoTaskStream(stream_config()).render_tasks([3, 4])


def test_the_prior_is_the_inference_plan_read_where_the_live_demonstration_has_got_to(rendered):
    task = rendered[0]
    live = task.frames.planned.demos[-1]
    assert task.replay_prior.shape == (3, 8, 8) and task.replay_prior.dtype == np.float32
    assert task.live_clouds.shape[0] == 3  # the live first cloud rendered for the plan is not a live frame
    # the plan of the first context demonstration (in every training context), as the policy's inference makes it
    first = task.frames.planned.demos[0]
    sources = [ReplaySource(task.context_clouds[0, 0].numpy(), first.action)]
    live_cloud = PseudoTaskStream(stream_config())._render([task.frames])[0][-1].numpy()  # the task's clouds again
    plan = plan_replay("t", sources, live_cloud, REPLAY_REGISTRATION, "per_object")
    expected = replay_priors(plan, plan_steps(live.state, plan.actions)[task.frames.live], 8)
    np.testing.assert_allclose(task.replay_prior, expected, atol=1e-6)
    poses_from_vectors(task.replay_prior.reshape(-1, 8))  # valid poses


@pytest.mark.parametrize("plan", ["per_object", "whole", "anchored"])
def test_a_live_demonstration_from_the_context_gets_its_own_actions_back(rendered, plan):
    """Registration of a cloud onto itself is the identity, and a demonstration that executed the plan exactly is at
    plan step t at its frame t, so the prior of a live demonstration that is context demonstration 0 is its own
    actions."""
    task = rendered[1]
    context = task.frames.planned.demos[:-1]
    first_cloud = task.context_clouds[0, 0].numpy()
    frames = np.array([0, context[0].num_frames // 2, context[0].num_frames - 3])
    prior, wrong = replay_prior_actions(ReplaySource(first_cloud, context[0].action), first_cloud, context[0].state,
                                        context[0].action, frames, 8, plan)
    assert not wrong  # a plan that is the live demonstration itself is right
    steps = np.minimum(frames[:, None] + np.arange(8), context[0].num_frames - 1)
    np.testing.assert_allclose(prior[..., :3], context[0].action[steps][..., :3], atol=2e-3)
    np.testing.assert_array_equal(prior[..., 7], context[0].action[steps][..., 7])


def test_the_pool_carries_priors_only_when_the_stream_plans_them(rendered):
    source = EncoderSource(encoder_preset("small"), weights=str(WEIGHTS)).build()
    with_priors = encode_task(rendered[0], source, 8)
    np.testing.assert_array_equal(with_priors.sample(2)[REPLAY_PRIOR_KEY].numpy(), rendered[0].replay_prior[2])
    stream = PseudoTaskStream(stream_config(replay_priors=False))
    plain = stream.render_tasks([3])[0]
    assert plain.replay_prior is None and REPLAY_PRIOR_KEY not in encode_task(plain, source, 8).sample(0)
    assert REPLAY_PRIOR_KEY not in stream._task_samples(plain)[0]
    # the same task's live frames and clouds either way: the prior's extra cloud is not among them
    np.testing.assert_array_equal(plain.clouds.numpy(), rendered[0].clouds.numpy())


def test_a_wrong_prior_is_kept_with_the_probability_asked_and_the_samples_say_so():
    """The anchored plan of tasks whose objects moved apart: judged against each live demonstration (the
    scene's ground truth), the wrong ones lose their prior for training at ``wrong_prior_keep`` 0 and keep it at 1;
    the right ones keep it either way. The draw is the task's own: the same at every render."""
    indices = [3, 4, 5, 6, 7, 8]
    kept_none = PseudoTaskStream(stream_config(replay_plan="anchored", wrong_prior_keep=0.0, tasks_per_render=6))
    tasks = kept_none.render_tasks(indices)
    wrong = []
    for task in tasks:
        first = task.frames.planned.demos[0]
        plan = plan_replay("t", [ReplaySource(task.context_clouds[0, 0].numpy(), first.action)],
                           kept_none._render([task.frames])[0][-1].numpy(), REPLAY_REGISTRATION, "anchored")
        wrong.append(plan_is_wrong(plan.actions, task.frames.planned.demos[-1].action))
    assert any(wrong) and not all(wrong)  # both kinds among these tasks
    assert [task.replay_prior_kept for task in tasks] == [not w for w in wrong]
    samples = kept_none._task_samples(tasks[wrong.index(True)])
    assert all(sample[REPLAY_PRIOR_KEPT_KEY].item() is False and REPLAY_PRIOR_KEY in sample for sample in samples)
    source = EncoderSource(encoder_preset("small"), weights=str(WEIGHTS)).build()
    assert encode_task(tasks[wrong.index(True)], source, 8).sample(0)[REPLAY_PRIOR_KEPT_KEY].item() is False
    kept_all = PseudoTaskStream(stream_config(replay_plan="anchored", tasks_per_render=6)).render_tasks(indices)
    assert all(task.replay_prior_kept for task in kept_all)
    with pytest.raises(ValueError, match="wrong_prior_keep must lie in"):
        stream_config(wrong_prior_keep=1.5)


def test_a_prior_read_off_time_is_the_plan_a_few_steps_away_and_the_same_for_a_seed(rendered):
    """``prior_time_shift`` M: each live frame's prior is the plan read at most M steps from the plan step the live
    demonstration has reached (clamped to the plan), drawn the same for the same seed and task; 0 reads every prior
    on time (the faithful stream)."""
    shift = 6
    on_time = rendered[0]
    shifted = PseudoTaskStream(stream_config(prior_time_shift=shift)).render_tasks([3, 4])[0]
    again = PseudoTaskStream(stream_config(prior_time_shift=shift)).render_tasks([3, 4])[0]
    np.testing.assert_array_equal(shifted.replay_prior, again.replay_prior)
    np.testing.assert_array_equal(shifted.clouds.numpy(), on_time.clouds.numpy())  # only the prior's timing differs
    live = on_time.frames.planned.demos[-1]
    source = ReplaySource(on_time.context_clouds[0, 0].numpy(), on_time.frames.planned.demos[0].action)
    live_cloud = PseudoTaskStream(stream_config())._render([on_time.frames])[0][-1].numpy()
    plan = plan_replay("t", [source], live_cloud, REPLAY_REGISTRATION, "per_object")
    reached = plan_steps(live.state, plan.actions)[on_time.frames.live]
    offsets = []
    for row, step in enumerate(reached):
        matches = [delta for delta in range(-shift, shift + 1) if np.allclose(
            shifted.replay_prior[row], plan.actions[prior_steps([step], 8, len(plan.actions), [delta])[0]], atol=1e-6)]
        assert matches, f"plan step {step}: the prior is not the plan read within {shift} steps of it"
        offsets.append(min(matches, key=abs))
    assert any(offset != 0 for offset in offsets)  # some prior is read off time
    with pytest.raises(ValueError, match="prior_time_shift must be a non-negative integer"):
        stream_config(prior_time_shift=-1)
