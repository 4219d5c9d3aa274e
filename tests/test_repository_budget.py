"""The repository stays small: no tracked file over 10 MB outside the package's assets (the shipped checkpoints, the
encoder), and no folder under ``checkpoints/`` over its budget. A standing run's folder holds its compact last
save (one weights file: ``workbench.standing.write_compact``) and its best (the same file's bytes where the best
is the average, one blob in git), their records beside: two weights files of the small model, 8.4 MB each.
Read off ``git ls-files``, so it holds for what a clone brings, not what lies about this checkout."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LARGE_FILE_MB = 10.0
ALLOWED_LARGE = "lerobot_instant_policy/assets/"
CHECKPOINT_FOLDER_MB = 20.0


def tracked_sizes() -> dict[str, int]:
    """Each tracked file's size in bytes, by its path from the repository root (skips outside a git checkout)."""
    try:
        listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the budget is the repository's")
    paths = [path for path in listed.decode().split("\0") if path]
    return {path: (ROOT / path).stat().st_size for path in paths if (ROOT / path).is_file()}


def test_no_tracked_file_over_10_mb_lies_outside_the_assets():
    large = {path: round(size / 1e6, 1) for path, size in tracked_sizes().items()
             if size > LARGE_FILE_MB * 1e6 and not path.startswith(ALLOWED_LARGE)}
    assert not large, f"tracked files over {LARGE_FILE_MB} MB outside {ALLOWED_LARGE}: {large}"


def test_every_checkpoint_folder_keeps_to_its_budget():
    folders: dict[str, int] = {}
    for path, size in tracked_sizes().items():
        parts = path.split("/")
        if parts[0] == "checkpoints" and len(parts) > 2:
            folders[parts[1]] = folders.get(parts[1], 0) + size
    over = {name: round(size / 1e6, 1) for name, size in folders.items() if size > CHECKPOINT_FOLDER_MB * 1e6}
    assert not over, f"checkpoint folders over {CHECKPOINT_FOLDER_MB} MB (MB): {over}"
