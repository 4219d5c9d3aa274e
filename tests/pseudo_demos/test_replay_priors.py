"""Replay priors of pseudo-tasks (``pseudo_demos.replay_priors``): the plan inference makes, re-timed to the live
demonstration; a live demonstration that is one of its context's gets its own actions back; the stream and the pool
carry the priors only when asked, and keep a wrong prior with the probability asked."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.contract import REPLAY_PRIOR_KEPT_KEY, REPLAY_PRIOR_KEY, poses_from_vectors
from lerobot_instant_policy.data.replay_plan import REPLAY_REGISTRATION, ReplaySource, plan_replay
from lerobot_instant_policy.data.replay_segments import plan_is_wrong
from lerobot_instant_policy.model.geometry_encoder import encoder_preset
from lerobot_instant_policy.pseudo_demos.generation import GenerationConfig
from lerobot_instant_policy.pseudo_demos.replay_priors import aligned_frames, replay_prior_actions
from lerobot_instant_policy.pseudo_demos.stream import PseudoTaskStream, StreamConfig
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


def test_frames_map_waypoint_to_waypoint_and_stay_in_order(rendered):
    demos = rendered[0].frames.planned.demos
    live, planned = demos[-1], demos[0]
    assert len(live.waypoint_frames) == len(planned.waypoint_frames)
    assert np.array_equal(aligned_frames(live, planned, np.asarray(live.waypoint_frames)), planned.waypoint_frames)
    mapped = aligned_frames(live, planned, np.arange(live.num_frames + 5))
    assert mapped[0] == 0 and mapped[-1] == planned.num_frames - 1 and np.all(np.diff(mapped) >= 0)
    # without a waypoint correspondence: proportional to the episodes' lengths
    stripped = dataclasses.replace(planned, waypoint_frames=planned.waypoint_frames[:-1])
    proportional = aligned_frames(live, stripped, np.array([0, live.num_frames - 1]))
    assert proportional.tolist() == [0, planned.num_frames - 1]


def test_the_prior_is_the_inference_plan_re_timed_to_the_live_demonstration(rendered):
    task = rendered[0]
    live = task.frames.planned.demos[-1]
    assert task.replay_prior.shape == (3, 8, 8) and task.replay_prior.dtype == np.float32
    assert task.live_clouds.shape[0] == 3  # the live first cloud rendered for the plan is not a live frame
    # the plan of the first context demonstration (in every training context), as the policy's inference makes it
    first = task.frames.planned.demos[0]
    sources = [ReplaySource(task.context_clouds[0, 0].numpy(), first.action)]
    live_cloud = PseudoTaskStream(stream_config())._render([task.frames])[0][-1].numpy()  # the task's clouds again
    plan = plan_replay("t", sources, live_cloud, REPLAY_REGISTRATION, "per_object")
    steps = task.frames.live[:, None] + np.arange(8)
    expected = plan.actions[aligned_frames(live, first, steps)]
    np.testing.assert_allclose(task.replay_prior, expected, atol=1e-6)
    poses_from_vectors(task.replay_prior.reshape(-1, 8))  # valid poses


@pytest.mark.parametrize("plan", ["per_object", "whole", "anchored"])
def test_a_live_demonstration_from_the_context_gets_its_own_actions_back(rendered, plan):
    """Registration of a cloud onto itself is the identity and the re-timing of a demonstration onto itself too, so
    the prior of a live demonstration that is context demonstration 0 is its own actions."""
    task = rendered[1]
    context = task.frames.planned.demos[:-1]
    planned = dataclasses.replace(task.frames.planned, demos=[*context, context[0]])
    first_cloud = task.context_clouds[0, 0].numpy()
    frames = np.array([0, context[0].num_frames // 2, context[0].num_frames - 3])
    prior, wrong = replay_prior_actions(planned, first_cloud, first_cloud, frames, 8, plan)
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


def test_a_prior_read_off_time_is_the_plan_of_another_frame_and_the_same_for_a_seed(rendered):
    """``prior_time_shift`` M: each live frame's prior is the on-time prior of a frame at most M away (clamped to the
    episode), drawn the same for the same seed and task; 0 reads every prior on time (the faithful stream)."""
    shift = 6
    on_time = rendered[0]
    shifted = PseudoTaskStream(stream_config(prior_time_shift=shift)).render_tasks([3, 4])[0]
    again = PseudoTaskStream(stream_config(prior_time_shift=shift)).render_tasks([3, 4])[0]
    np.testing.assert_array_equal(shifted.replay_prior, again.replay_prior)
    np.testing.assert_array_equal(shifted.clouds.numpy(), on_time.clouds.numpy())  # only the prior's timing differs
    live = on_time.frames.planned.demos[-1]
    cloud = on_time.context_clouds[0, 0].numpy()
    live_cloud = PseudoTaskStream(stream_config())._render([on_time.frames])[0][-1].numpy()
    all_frames = np.arange(live.num_frames)
    every, _ = replay_prior_actions(on_time.frames.planned, cloud, live_cloud, all_frames, 8, "per_object")
    offsets = []
    for row, frame in enumerate(on_time.frames.live):
        matches = [other - frame for other in range(max(frame - shift, 0), min(frame + shift, live.num_frames - 1) + 1)
                   if np.allclose(shifted.replay_prior[row], every[other], atol=1e-6)]
        assert matches, f"frame {frame}: the prior is no on-time prior within {shift} frames"
        offsets.append(min(matches, key=abs))
    assert any(offset != 0 for offset in offsets)  # some prior is read off time
    with pytest.raises(ValueError, match="prior_time_shift must be a non-negative integer"):
        stream_config(prior_time_shift=-1)
