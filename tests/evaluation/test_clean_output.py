"""A healthy install prints no traceback (issue 15): LeRobot's torchcodec probe says one line when no system FFmpeg
is found, real torchcodec errors stay as they are, and a real ``lerobot-eval`` through the plugin prints none."""

from __future__ import annotations

import logging
import os
import subprocess

import pytest

from lerobot_instant_policy import video_backend
from lerobot_instant_policy.cli import record_demos
from lerobot_instant_policy.evaluation import suite

PROBE_WARNING = (
    "Could not load libtorchcodec. Likely causes: ...\n[start of libtorchcodec loading traceback]\nFFmpeg version 8:\n"
    "Traceback (most recent call last):\n  ...\nOSError: libavutil.so.60: cannot open shared object file\n"
    "'torchcodec' is installed but cannot be loaded (see the error above). Falling back to 'pyav' as a default decoder."
)


def _filtered(message: str) -> str:
    record = logging.LogRecord(video_backend.PROBE_LOGGER, logging.WARNING, __file__, 1, message, None, None)
    assert video_backend.MissingFFmpegFilter().filter(record)  # never drops a record
    return record.getMessage()


def test_probe_warning_is_one_line_without_system_ffmpeg(monkeypatch):
    monkeypatch.setattr(video_backend, "system_ffmpeg_found", lambda: False)
    assert _filtered(PROBE_WARNING) == video_backend.SHORT_MESSAGE
    assert "\n" not in video_backend.SHORT_MESSAGE and "PyAV" in video_backend.SHORT_MESSAGE
    # every other message passes unchanged, including %-formatted ones
    record = logging.LogRecord(video_backend.PROBE_LOGGER, logging.WARNING, __file__, 1, "plugin %s failed", ("x",), None)
    assert video_backend.MissingFFmpegFilter().filter(record) and record.getMessage() == "plugin x failed"


def test_probe_warning_is_kept_whole_when_ffmpeg_is_installed(monkeypatch):
    """With FFmpeg on the system, torchcodec's failure is a real error: the full traceback stays."""
    monkeypatch.setattr(video_backend, "system_ffmpeg_found", lambda: True)
    assert _filtered(PROBE_WARNING) == PROBE_WARNING


def test_filter_is_installed_once_on_import():
    logger = logging.getLogger(video_backend.PROBE_LOGGER)
    video_backend.install()
    assert sum(isinstance(f, video_backend.MissingFFmpegFilter) for f in logger.filters) == 1


@pytest.mark.slow  # CI: test_eval_suite.py's make demo test asserts the same of its two real lerobot-eval runs
def test_lerobot_eval_prints_no_traceback(tmp_path):
    """The real ``lerobot-eval --policy.type=demo_replay`` (it opens a LeRobot demo dataset, so LeRobot probes its
    video backend) on one push_button episode. Most of its time is a new interpreter importing LeRobot; in CI
    test_eval_suite.py::test_the_shipped_checkpoint_succeeds_on_the_demo_task_through_make_demo checks the output of
    the ``lerobot-eval`` processes it runs (``instant_policy`` and this ``demo_replay``, close_box) for the
    same: no traceback, and the probe's one line where no system FFmpeg is found."""
    demos = tmp_path / "demos"
    assert record_demos.main(["--task", "push_button", "--episodes", "2", "--out", str(demos),
                              "--repo-id", "local/push_button"]) == 0
    settings = suite.SuiteSettings(episodes=1, batch_size=1)
    command = suite.lerobot_eval_command(settings, "push_button", demos, 1000, tmp_path / "run")
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-4000:]
    assert "Traceback" not in output, output[-4000:]
    if not video_backend.system_ffmpeg_found():
        assert video_backend.SHORT_MESSAGE in output  # the probe ran and said its one line
