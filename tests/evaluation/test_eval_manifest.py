"""Columns joined only when comparable, and compared episode by episode: each suite cell records its seeds (as
lerobot-eval reports them), demonstration set and conditions (checkpoint digest, policy options, success criterion,
hold steps, step limit, env arguments, video size); ``lerobot-ip-eval-table`` refuses columns whose cells, seeds,
demonstration sets or conditions differ (each refusal tested; a condition named with ``--allow-difference`` is
joined), reads manifests written before a field was recorded and says what it could not check, amends a manifest's
column with a run of some of its cells (only cells it holds, on its seeds, settings and conditions), and the paired
difference with its cluster bootstrap interval (over tasks, or cells) on small known cases and on the committed
MetaWorld manifest."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from lerobot_instant_policy.cli.eval_table import main as eval_table
from lerobot_instant_policy.evaluation import lerobot_eval_seeds, suite
from lerobot_instant_policy.evaluation.manifest import (
    CELL_FILE,
    CONDITIONS,
    CellOutcome,
    ManifestError,
    checkpoint_fingerprint,
    column_manifest,
)
from lerobot_instant_policy.evaluation.paired import paired_difference
from lerobot_instant_policy.evaluation.suite import SuiteError, SuiteSettings
from lerobot_instant_policy.sim.task_api import get_task

TASKS = ["push_button", "open_drawer"]
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def fake_suite(monkeypatch):
    """``run_suite`` with lerobot-eval and the recorder replaced: each cell's episodes succeed as ``outcomes[policy
    name][(task, set)]`` says, and the stand-in reports the seeds its command names (``lerobot_eval_seeds``), or
    none, or others, as ``seeds[policy name]`` says (``"as run"`` by default: ``"none"``, or an offset); each
    demonstration set is a file whose bytes name its source and seed."""
    outcomes: dict[str, dict[tuple[str, int], list[bool]]] = {}
    seeds: dict[str, str | int] = {}

    def fake_lerobot_eval(command, runs_dir, task, demo_set):
        output_dir = runs_dir / task / f"set-{demo_set}"
        output_dir.mkdir(parents=True, exist_ok=True)
        successes = outcomes[runs_dir.name][(task, demo_set)]
        metrics = {"successes": successes}
        report = seeds.get(runs_dir.name, "as run")
        if report != "none":
            first = int(next(part for part in command if part.startswith("--seed=")).split("=")[1])
            metrics["seeds"] = [first + (0 if report == "as run" else report) + i for i in range(len(successes))]
        info = {"per_task": [{"task_group": task, "task_id": 0, "metrics": metrics}]}
        (output_dir / "eval_info.json").write_text(json.dumps(info))
        return output_dir

    def fake_record(settings, task, demos, seed, source):
        (demos / "data").mkdir(parents=True)
        (demos / "data" / "file.parquet").write_text(f"{source} {seed} {settings.demonstrator}")
        (demos / "meta").mkdir()
        (demos / "meta" / "info.json").write_text("{}")

    monkeypatch.setattr(suite, "run_lerobot_eval", fake_lerobot_eval)
    monkeypatch.setitem(suite.SUITE_ENVS, "bullet_tabletop",
                        dataclasses.replace(suite.SUITE_ENVS["bullet_tabletop"], record=fake_record))

    def run(settings: SuiteSettings, cells: dict[tuple[str, int], list[bool]], tasks: list[str] = TASKS,
            report_seeds: str | int = "as run"):
        outcomes[settings.name] = cells
        seeds[settings.name] = report_seeds
        suite.run_suite(settings, tasks, report=lambda line: None)
        return settings.runs_dir

    return run


def two_cells(first: list[bool], second: list[bool]) -> dict[tuple[str, int], list[bool]]:
    return {("push_button", 0): first, ("open_drawer", 0): second}


def test_cells_record_their_seeds_and_demonstrations(fake_suite, tmp_path):
    runs = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, split="test", demo_seed=50_000,
                                    eval_seed=60_000), two_cells([True, False], [False, False]))
    manifest = column_manifest(runs)
    cells = {(cell["task"], cell["demo_set"]): cell for cell in manifest["cells"]}
    assert cells[("push_button", 0)]["eval_seeds"] == [60_000, 60_001]
    assert cells[("push_button", 0)]["successes"] == [True, False]
    assert cells[("open_drawer", 0)]["demo_seed"] == 50_000 and len(cells[("open_drawer", 0)]["demo_fingerprint"]) == 64
    assert manifest["settings"]["policy"] == "demo_replay" and manifest["settings"]["success"] == "held"
    nothing = fake_suite(SuiteSettings(policy="do_nothing", out=tmp_path, episodes=2, demo_sets=1), two_cells(
        [False, False], [False, False]))
    assert {cell["demo_fingerprint"] for cell in column_manifest(nothing)["cells"]} == {None}
    assert {cell["seeds_reported"] for cell in manifest["cells"]} == {True}


def fake_checkpoint(path: Path, weights: bytes) -> Path:
    path.mkdir(parents=True)
    (path / "model.safetensors").write_bytes(weights)
    (path / "config.json").write_text("{}")
    (path / "README.md").write_text("a model card")
    return path


def test_cells_record_the_conditions_they_ran_under(fake_suite, tmp_path):
    """Each cell records the checkpoint's SHA-256 (over its files but the model card), the policy options, the
    criterion and the task's hold steps, its step limit, the env arguments and the video size; ``--resume`` refuses
    finished cells evaluated with another checkpoint."""
    checkpoint = fake_checkpoint(tmp_path / "ckpt", b"weights")
    settings = SuiteSettings(policy="instant_policy", policy_path=str(checkpoint), out=tmp_path, episodes=2,
                             demo_sets=1, policy_args=("--policy.inference_steps=8",),
                             env_args=("--env.render_size=64", "--env.depth_noise_std=0.002"))
    runs = fake_suite(settings, two_cells([True, False], [False, False]))
    cells = {cell["task"]: cell["conditions"] for cell in column_manifest(runs)["cells"]}
    digest = hashlib.sha256()
    for name in ("config.json", "model.safetensors"):
        digest.update(name.encode() + b"\0" + (checkpoint / name).read_bytes())
    drawer = get_task("open_drawer")
    assert cells["open_drawer"] == {
        "checkpoint_sha256": digest.hexdigest(), "language_head_sha256": None,
        "policy_options": ["--policy.inference_steps=8"],
        "env_args": ["--env.depth_noise_std=0.002"], "success": "held", "hold_steps": drawer.success_hold_steps,
        "episode_length": drawer.max_episode_steps, "render_size": 64, "obs_type": "pointcloud",
        "pointcloud_every": None}
    assert drawer.success_hold_steps > 1 and cells["push_button"]["hold_steps"] == 1
    assert checkpoint_fingerprint(checkpoint) == digest.hexdigest()
    (checkpoint / "README.md").write_text("another model card")
    assert checkpoint_fingerprint(checkpoint) == digest.hexdigest()
    (checkpoint / "model.safetensors").write_bytes(b"other weights")
    with pytest.raises(SuiteError, match="checkpoint_sha256"):
        suite.run_suite(dataclasses.replace(settings, resume=True), TASKS, report=lambda line: None)


def test_columns_said_in_words_record_their_language_head(fake_suite, tmp_path, capsys):
    """A column told ``context=language`` records the SHA-256 of the head it reads (the shipped one by default, or
    ``--policy.language_head_path``): two such columns with other heads join only with ``--allow-difference
    language_head``, and ``--resume`` refuses cells said with another head."""
    checkpoint = str(fake_checkpoint(tmp_path / "ckpt", b"weights"))
    heads = {name: fake_checkpoint(tmp_path / name, name.encode()) for name in ("head_a", "head_b")}
    words = ("--policy.context=language",)
    shipped = SuiteSettings(policy="instant_policy", policy_path=checkpoint, out=tmp_path, episodes=2, demo_sets=1,
                            policy_args=words, run_name="shipped")
    cells = two_cells([True, False], [True, True])
    shipped_runs = fake_suite(shipped, cells)
    column = column_manifest(shipped_runs)["cells"]
    assert {cell["conditions"]["language_head_sha256"] for cell in column} == {
        checkpoint_fingerprint(suite.SHIPPED_LANGUAGE_HEAD)}
    runs = {}
    for name, head in heads.items():
        settings = dataclasses.replace(shipped, run_name=name,
                                       policy_args=(*words, f"--policy.language_head_path={head}"))
        runs[name] = fake_suite(settings, cells)
    assert {cell["conditions"]["language_head_sha256"] for cell in column_manifest(runs["head_a"])["cells"]} == {
        checkpoint_fingerprint(heads["head_a"])}
    columns = [f"a={runs['head_a']}", f"b={runs['head_b']}", "--out", str(tmp_path / "table"),
               "--allow-difference", "policy_options"]
    assert eval_table(columns) == 2
    assert "differ in language_head" in capsys.readouterr().err
    assert eval_table([*columns, "--allow-difference", "language_head"]) == 0
    (heads["head_a"] / "model.safetensors").write_bytes(b"retrained")
    with pytest.raises(SuiteError, match="language_head_sha256"):
        suite.run_suite(dataclasses.replace(shipped, run_name="head_a", resume=True,
                                            policy_args=(*words, f"--policy.language_head_path={heads['head_a']}")),
                        TASKS, report=lambda line: None)


def test_seeds_are_read_as_lerobot_eval_reports_them(fake_suite, tmp_path):
    """A cell whose lerobot-eval report names other seeds than the suite asked for is refused; one with no report
    (a run without ``lerobot_eval_seeds``) keeps the suite's seeds and says they were not reported."""
    shifted = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1), two_cells([True, True], [True, True]),
                         report_seeds=5)
    with pytest.raises(ManifestError, match="lerobot-eval ran seeds 1005…1006, the cell records 1000…1001"):
        column_manifest(shifted)
    unreported = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, run_name="plain"),
                            two_cells([True, True], [True, True]), report_seeds="none")
    assert {cell["seeds_reported"] for cell in column_manifest(unreported)["cells"]} == {False}


def test_lerobot_eval_seeds_keeps_what_eval_policy_reports(monkeypatch):
    """The wrapper around LeRobot's ``eval_one`` adds the seeds its ``eval_policy`` call reported per episode to the
    metrics that ``eval_info.json`` holds, and changes nothing else."""
    from lerobot.scripts import lerobot_eval

    def fake_eval_policy(**kwargs):
        return {"per_episode": [{"episode_ix": i, "sum_reward": 0.0, "max_reward": 0.0, "success": i == 1,
                                 "seed": kwargs["start_seed"] + i} for i in range(3)]}

    monkeypatch.setattr(lerobot_eval, "eval_policy", fake_eval_policy)
    monkeypatch.setattr(lerobot_eval, "eval_one", lerobot_eval.eval_one)
    lerobot_eval_seeds.install()
    lerobot_eval_seeds.install()  # once per process
    metrics = lerobot_eval.eval_one(None, policy=None, env_preprocessor=None, env_postprocessor=None,
                                    preprocessor=None, postprocessor=None, n_episodes=3, max_episodes_rendered=0,
                                    videos_dir=None, return_episode_data=False, start_seed=60_000)
    assert metrics["seeds"] == [60_000, 60_001, 60_002] and metrics["successes"] == [False, True, False]


def test_table_joins_same_seeds_and_sets_and_refuses_others(fake_suite, tmp_path, capsys):
    replay = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1), two_cells([True, True], [True, False]))
    option = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, run_name="option"),
                        two_cells([True, True], [True, True]))
    swapped = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, swap=True),
                         two_cells([False, False], [False, False]))
    out = tmp_path / "table"
    assert eval_table([f"demo_replay={replay}", f"option={option}", f"swap={swapped}", "--out", str(out),
                       "--paired", "option=demo_replay"]) == 0
    assert "option - demo_replay: +25.0 points" in capsys.readouterr().out
    manifests = json.loads(out.with_suffix(".manifest.json").read_text())
    assert set(manifests) == {"demo_replay", "option", "swap"}
    assert json.loads(out.with_suffix(".json").read_text())["paired"][0]["difference"] == 0.25

    other_seeds = fake_suite(SuiteSettings(out=tmp_path / "test", episodes=2, demo_sets=1, split="test",
                                           demo_seed=50_000, eval_seed=60_000), two_cells([True, True], [True, True]))
    assert eval_table([f"demo_replay={replay}", f"test={other_seeds}", "--out", str(out)]) == 2
    assert "different seeds" in capsys.readouterr().err
    other_demos = fake_suite(SuiteSettings(out=tmp_path / "other", episodes=2, demo_sets=1, demo_seed=500),
                             two_cells([True, True], [True, True]))
    assert eval_table([f"demo_replay={replay}", f"other={other_demos}", "--out", str(out)]) == 2
    assert "different demonstration sets" in capsys.readouterr().err
    fewer = fake_suite(SuiteSettings(out=tmp_path / "fewer", episodes=2, demo_sets=1),
                       {("push_button", 0): [True, True]}, tasks=["push_button"])
    assert eval_table([f"demo_replay={replay}", f"fewer={fewer}", "--out", str(out)]) == 2
    assert "hold different cells (task, set): [('open_drawer', 0)]" in capsys.readouterr().err


def test_a_hands_demonstrations_are_another_source_than_the_grippers(fake_suite, tmp_path, capsys):
    """A column reading the hand's demonstrations of the same seeds pairs with the gripper's (what the hand costs);
    two hand columns of other demonstration sets are still refused."""
    gripper = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1), two_cells([True, True], [True, False]))
    hand = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, demonstrator="hand", run_name="hand"),
                      two_cells([True, False], [False, False]))
    out = tmp_path / "table"
    paired = ["--paired", "hand=demo_replay"]
    assert eval_table([f"demo_replay={gripper}", f"hand={hand}", "--out", str(out), *paired]) == 0
    assert "hand - demo_replay: -50.0 points" in capsys.readouterr().out
    manifests = json.loads(out.with_suffix(".manifest.json").read_text())
    assert {cell["demonstrator"] for cell in manifests["hand"]["cells"]} == {"hand"}
    assert {cell["demonstrator"] for cell in manifests["demo_replay"]["cells"]} == {"gripper"}
    other = fake_suite(SuiteSettings(out=tmp_path / "other", episodes=2, demo_sets=1, demo_seed=500,
                                     demonstrator="hand", run_name="hand"), two_cells([True, True], [True, True]))
    assert eval_table([f"hand={hand}", f"other={other}", "--out", str(out)]) == 2
    assert "different demonstration sets" in capsys.readouterr().err


# Per condition: the settings of a column that differs from the base one in it (and in those named beside it).
VARIANTS = {
    "checkpoint": ({"policy_path": "other"}, ()),
    "policy_options": ({"policy_args": ("--policy.inference_steps=8",)}, ()),
    "success": ({"success": "instant"}, ("hold_steps",)),  # open_drawer then holds 1 step, not 5
    "hold_steps": ({}, ()),  # open_drawer's hold steps changed in the task itself
    "episode_length": ({"env_args": ("--env.episode_length=60",)}, ("env_args",)),
    "env_args": ({"env_args": ("--env.depth_noise_std=0.002",)}, ()),
    "render_size": ({"env_args": ("--env.render_size=64",)}, ()),
}


@pytest.mark.parametrize("condition", list(VARIANTS))
def test_table_refuses_columns_that_differ_in_a_condition_unless_it_is_named(condition, fake_suite, tmp_path,
                                                                           capsys, monkeypatch):
    checkpoints = {name: str(fake_checkpoint(tmp_path / name, name.encode())) for name in ("base", "other")}
    base = SuiteSettings(policy="instant_policy", policy_path=checkpoints["base"], out=tmp_path, episodes=2,
                         demo_sets=1, run_name="base")
    cells = two_cells([True, False], [True, True])
    base_runs = fake_suite(base, cells)
    changes, also = VARIANTS[condition]
    if condition == "hold_steps":
        monkeypatch.setattr(get_task("open_drawer"), "success_hold_steps", 9)
    changes = {**changes, "policy_path": checkpoints[changes["policy_path"]]} if "policy_path" in changes else changes
    variant_runs = fake_suite(dataclasses.replace(base, run_name="variant", **changes), cells)
    columns = [f"base={base_runs}", f"variant={variant_runs}", "--out", str(tmp_path / "table")]
    assert eval_table(columns) == 2
    assert f"differ in {condition}" in (error := capsys.readouterr().err)
    assert f"--allow-difference {condition}" in error and CONDITIONS[condition][1] in error
    allowed = [argument for name in (condition, *also) for argument in ("--allow-difference", name)]
    assert eval_table([*columns, *allowed, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["allowed_differences"] == sorted([condition, *also])


def test_checkpoints_and_policy_options_are_compared_where_they_apply(fake_suite, tmp_path, capsys):
    """A replay column (no checkpoint, no options) beside a checkpoint with options is no difference; an unknown
    ``--allow-difference`` name is refused."""
    checkpoint = str(fake_checkpoint(tmp_path / "ckpt", b"weights"))
    cells = two_cells([True, False], [True, True])
    learned = fake_suite(SuiteSettings(policy="instant_policy", policy_path=checkpoint, out=tmp_path, episodes=2,
                                       demo_sets=1, policy_args=("--policy.inference_steps=8",)), cells)
    replay = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1), cells)
    assert eval_table([f"learned={learned}", f"replay={replay}", "--out", str(tmp_path / "t")]) == 0
    assert "not recorded" not in capsys.readouterr().err
    with pytest.raises(SystemExit):
        eval_table([f"learned={learned}", f"replay={replay}", "--out", str(tmp_path / "t"), "--allow-difference",
                    "seeds"])
    assert "invalid choice: 'seeds'" in capsys.readouterr().err


def test_manifests_written_before_the_conditions_are_read_and_what_they_lack_is_named(fake_suite, tmp_path, capsys):
    """A manifest file without the conditions and reported seeds (as committed before they were recorded) is read
    as columns: what it lacks is listed as not checked, what its settings hold (the policy options) still is."""
    cells = two_cells([True, False], [True, True])
    replay = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1), cells)
    per_object = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, run_name="per_object",
                                          policy_args=("--policy.replay_per_object=true",)), cells)
    assert eval_table([f"demo_replay={replay}", f"per_object={per_object}", "--allow-difference", "policy_options",
                       "--out", str(tmp_path / "new")]) == 0
    manifests = json.loads((tmp_path / "new.manifest.json").read_text())
    for manifest in manifests.values():
        for cell in manifest["cells"]:
            del cell["conditions"], cell["seeds_reported"]
    old = tmp_path / "old.manifest.json"
    old.write_text(json.dumps(manifests))
    capsys.readouterr()
    assert eval_table([str(old), "--out", str(tmp_path / "again")]) == 2
    assert "differ in policy_options" in capsys.readouterr().err
    assert eval_table([str(old), "--allow-difference", "policy_options", "--out", str(tmp_path / "again"), "--json",
                       "--paired", "per_object=demo_replay"]) == 0
    output = capsys.readouterr()
    table = json.loads(output.out)
    assert table["not_recorded"]["demo_replay"] == ["checkpoint", "hold_steps", "episode_length", "render_size",
                                                    "seeds as run"]
    assert "not recorded in per_object's manifest, so not checked: checkpoint" in output.err
    assert table["overall"]["demo_replay"]["successes"] == 3 and table["paired"][0]["difference"] == 0.0
    assert eval_table([f"per_object={old}", "--out", str(tmp_path / "one")]) == 0
    assert eval_table([f"missing={old}", "--out", str(tmp_path / "one")]) == 2
    assert "has no column 'missing'" in capsys.readouterr().err


def amendable_manifest(fake_suite, tmp_path) -> Path:
    """The manifest file of a table of two columns evaluated alike, ``demo_replay`` and ``other``: push_button 1/2
    and open_drawer 0/2 each."""
    cells = two_cells([True, False], [False, False])
    replay = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1), cells)
    other = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, run_name="other"), cells)
    assert eval_table([f"demo_replay={replay}", f"other={other}", "--out", str(tmp_path / "table")]) == 0
    return tmp_path / "table.manifest.json"


def test_a_run_after_a_manifest_replaces_that_columns_cells_of_its_tasks(fake_suite, tmp_path, capsys):
    """open_drawer evaluated again under demo_replay's name, after the manifest: demo_replay's open_drawer cell is
    the run's (its demonstrations recorded again, which is noted), every other cell stays; the counts and the paired
    difference are the amended column's, and the written manifest names the replaced cell and its run and is read
    back as the same table."""
    manifest = amendable_manifest(fake_suite, tmp_path)
    columns = json.loads(manifest.read_text())
    (drawer,) = [cell for cell in columns["demo_replay"]["cells"] if cell["task"] == "open_drawer"]
    drawer["demo_fingerprint"] = "0" * 64
    manifest.write_text(json.dumps(columns))
    rerun = fake_suite(SuiteSettings(out=tmp_path / "rerun", episodes=2, demo_sets=1),
                       {("open_drawer", 0): [True, True]}, tasks=["open_drawer"])
    capsys.readouterr()
    out = tmp_path / "amended"
    assert eval_table([str(manifest), f"demo_replay={rerun}", "--paired", "other=demo_replay", "--json", "--out",
                       str(out)]) == 0
    output = capsys.readouterr()
    table = json.loads(output.out)
    assert {(row["task"], row["policy"]): row["successes"] for row in table["rows"]} == {
        ("open_drawer", "demo_replay"): 2, ("open_drawer", "other"): 0, ("push_button", "demo_replay"): 1,
        ("push_button", "other"): 1}
    assert table["overall"]["demo_replay"]["successes"] == 3 and table["overall"]["other"]["successes"] == 1
    assert table["paired"][0]["difference"] == -0.5
    assert f"demo_replay: the cells of open_drawer (1 of 2) replaced by those of {rerun}" in output.err
    assert f"demo_replay: open_drawer, set 0 from {rerun}: its demonstrations were recorded again" in output.err
    written = json.loads(out.with_suffix(".manifest.json").read_text())
    assert written["demo_replay"]["replaced_cells"] == [{"task": "open_drawer", "demo_set": 0, "from": str(rerun)}]
    assert {cell["task"]: cell["successes"] for cell in written["demo_replay"]["cells"]} == {
        "open_drawer": [True, True], "push_button": [True, False]}
    assert written["demo_replay"]["run_dir"] == columns["demo_replay"]["run_dir"]
    assert written["other"] == columns["other"]
    assert eval_table([str(out.with_suffix(".manifest.json")), "--json", "--out", str(tmp_path / "again")]) == 0
    assert json.loads(capsys.readouterr().out)["rows"] == table["rows"]


def test_sets_recorded_differently_elsewhere_are_listed_and_evaluated_again_here_pair_the_columns(
        fake_suite, tmp_path, capsys):
    """A committed table whose open_drawer set was recorded on another machine (the same seed, other bytes): a
    candidate evaluated here cannot join it; --recorded-differently names open_drawer and writes nothing; the
    committed columns' open_drawer evaluated again here amend them, and the candidate joins and pairs. Where every set
    matches, the listing is empty."""
    manifest = amendable_manifest(fake_suite, tmp_path)
    columns = json.loads(manifest.read_text())
    for column in columns.values():
        for cell in column["cells"]:
            if cell["task"] == "open_drawer":
                cell["demo_fingerprint"] = "f" * 64
    manifest.write_text(json.dumps(columns))
    candidate = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, run_name="candidate"),
                           two_cells([True, True], [True, False]))
    given = [f"candidate={candidate}", f"demo_replay={manifest}", f"other={manifest}"]
    capsys.readouterr()
    assert eval_table([*given, "--out", str(tmp_path / "refused")]) == 2
    assert "open_drawer, set 0:" in capsys.readouterr().err
    assert eval_table([*given, "--recorded-differently", "--out", str(tmp_path / "listed")]) == 0
    assert capsys.readouterr().out.strip() == "open_drawer"
    assert not (tmp_path / "listed.json").exists()
    again = {name: fake_suite(SuiteSettings(out=tmp_path / "here", episodes=2, demo_sets=1, run_name=name),
                              {("open_drawer", 0): [False, True]}, tasks=["open_drawer"])
             for name in ("demo_replay", "other")}
    capsys.readouterr()
    amended = [*given, *(f"{name}={run}" for name, run in again.items())]
    assert eval_table([*amended, "--paired", "candidate=demo_replay", "--json", "--out", str(tmp_path / "t")]) == 0
    table = json.loads(capsys.readouterr().out)
    assert table["overall"]["candidate"]["successes"] == 3 and table["overall"]["demo_replay"]["successes"] == 2
    assert table["paired"][0]["difference"] == pytest.approx(0.25)
    assert eval_table([*amended, "--recorded-differently", "--out", str(tmp_path / "none")]) == 0
    assert capsys.readouterr().out == "\n"
    assert eval_table([f"candidate={candidate}", "--recorded-differently", "--out", str(tmp_path / "one")]) == 2
    assert "at least two columns" in capsys.readouterr().err


def test_a_run_that_does_not_match_the_column_it_amends_is_refused(fake_suite, tmp_path, capsys):
    """Refused: a run holding a cell the column lacks, one on other seeds, one with another setting, one with
    another condition (its setting and the conditions it sets, unless named with --allow-difference), and a run
    given before the manifest that holds its column."""
    manifest = amendable_manifest(fake_suite, tmp_path)
    base = SuiteSettings(out=tmp_path / "rerun", episodes=2, demo_sets=1)

    def amend(settings: SuiteSettings, *arguments: str) -> tuple[int, str]:
        run = fake_suite(settings, {("open_drawer", s): [True, True] for s in range(settings.demo_sets)},
                         tasks=["open_drawer"])
        capsys.readouterr()
        code = eval_table([str(manifest), f"demo_replay={run}", *arguments, "--out", str(tmp_path / "t")])
        return code, capsys.readouterr().err

    code, error = amend(dataclasses.replace(base, demo_sets=2, run_name="more"))
    assert code == 2 and "holds cells (task, set) that column 'demo_replay' lacks: [('open_drawer', 1)]" in error
    code, error = amend(dataclasses.replace(base, eval_seed=2000, run_name="seeds"))
    assert code == 2 and "open_drawer, set 0:" in error and "ran seeds 2000…2001, column 'demo_replay' 1000…1001" in error
    code, error = amend(dataclasses.replace(base, batch_size=1, run_name="batch"))
    assert code == 2 and "batch_size: 2 in the column, 1 in the run" in error and "--allow-difference" not in error
    options = dataclasses.replace(base, policy_args=("--policy.replay_per_object=true",), run_name="options")
    code, error = amend(options)
    assert code == 2 and "policy_args" in error and "--allow-difference policy_options" in error
    assert amend(options, "--allow-difference", "policy_options")[0] == 0
    instant = dataclasses.replace(base, success="instant", run_name="instant")
    code, error = amend(instant, "--allow-difference", "success")
    assert code == 2 and "differ in hold_steps" in error
    assert amend(instant, "--allow-difference", "success", "--allow-difference", "hold_steps")[0] == 0
    assert eval_table([f"demo_replay={instant.runs_dir}", str(manifest), "--out", str(tmp_path / "t")]) == 2
    assert "put the manifest file first" in capsys.readouterr().err


def test_the_committed_metaworld_manifest_rederives_its_paired_differences(tmp_path, capsys):
    """From every episode of the committed MT10 test-split manifest: the shipped checkpoint − demo_replay resampling
    tasks, and resampling cells (the interval the table gave before tasks were the default)."""
    manifest = REPO / "docs" / "results_metaworld_mt10_test.manifest.json"
    arguments = [str(manifest), "--env-type", "metaworld_pointcloud", "--paired", "instant_policy=demo_replay",
                 "--allow-difference", "policy_options",  # its demo_replay_per_object column
                 "--json", "--out", str(tmp_path / "t")]
    assert eval_table(arguments) == 0
    table = json.loads(capsys.readouterr().out)
    (by_task,) = table["paired"]
    assert (by_task["difference"], by_task["ci95_low"], by_task["ci95_high"]) == pytest.approx(
        (-47 / 300, -0.293, -0.027), abs=5e-4)
    assert by_task["b_only_successes"] - by_task["a_only_successes"] == 47
    assert by_task["unit"] == "task" and by_task["clusters"] == 10 and by_task["cells"] == 30
    assert table["overall"]["instant_policy"]["successes"] == 127
    assert eval_table([*arguments, "--paired-unit", "cell"]) == 0
    (by_cell,) = json.loads(capsys.readouterr().out)["paired"]
    assert (by_cell["ci95_low"], by_cell["ci95_high"]) == pytest.approx((-0.2533, -0.06), abs=5e-4)


def test_runs_without_cell_records_need_unchecked(fake_suite, tmp_path, capsys):
    """A run from before cells recorded their identity is refused by name; ``--resume`` writes the record of the
    cells it keeps."""
    settings = SuiteSettings(out=tmp_path, episodes=2, demo_sets=1)
    runs = fake_suite(settings, two_cells([True, False], [False, False]))
    record_path = runs / "push_button" / "set-0" / CELL_FILE
    record = json.loads(record_path.read_text())
    identity = record.pop("cell")
    record_path.write_text(json.dumps(record))
    assert eval_table([f"demo_replay={runs}", "--out", str(tmp_path / "t")]) == 2
    assert "--unchecked" in capsys.readouterr().err
    assert eval_table([f"demo_replay={runs}", "--out", str(tmp_path / "t"), "--unchecked"]) == 0
    suite.run_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, resume=True), TASKS, report=lambda l: None)
    assert json.loads(record_path.read_text())["cell"] == identity


def cell(task: str, successes: list[bool], seed: int = 1000) -> CellOutcome:
    return CellOutcome(task, 0, tuple(range(seed, seed + len(successes))), 0, 2, "f", None, tuple(successes))


def test_paired_difference_resamples_tasks_by_default():
    """Task t1 favours A in all three of its cells (+2/2 each), t2 in none: resampling the two tasks draws t2 twice a
    quarter of the time, so the interval is [0, 1]; resampling the six cells draws all three of t2's every 1/64 of the
    time (< 2.5%), so it is [1/6, 5/6]. Identical columns give a zero-width interval at 0; a single task, none."""
    a = {(task, s): CellOutcome(task, s, (1000 + 2 * s, 1001 + 2 * s), 0, 2, "f", None, (task == "t1",) * 2)
         for task in ("t1", "t2") for s in range(3)}
    b = {key: dataclasses.replace(outcome, successes=(False, False)) for key, outcome in a.items()}
    by_task = paired_difference("a", a, "b", b)
    assert by_task.difference == 0.5 and (by_task.low, by_task.high) == (0.0, 1.0) and by_task.clusters == 2
    assert by_task.verdict == "no difference shown" and by_task.unit == "task" and by_task.cells == 6
    by_cell = paired_difference("a", a, "b", b, unit="cell")
    assert (by_cell.low, by_cell.high) == pytest.approx((1 / 6, 5 / 6)) and by_cell.verdict == "a beats b"
    assert paired_difference("a", a, "b", b, seed=3) == paired_difference("a", a, "b", b, seed=3)
    same = paired_difference("a", a, "a'", a)
    assert (same.difference, same.low, same.high) == (0.0, 0.0, 0.0)
    one_task = {key: outcome for key, outcome in a.items() if key[0] == "t1"}
    single = paired_difference("a", one_task, "b", {key: b[key] for key in one_task})
    assert single.difference == 1.0 and np.isnan(single.low) and single.verdict == "no difference shown"
    assert single.as_json()["ci95_low"] is None and paired_difference(
        "a", one_task, "b", {key: b[key] for key in one_task}, unit="cell").low == 1.0
    with pytest.raises(ValueError, match="unit must be one of"):
        paired_difference("a", a, "b", b, unit="episode")


def test_paired_difference_on_known_cases():
    """Two cells with differences 2/2 and 0/2: Δ = 0.5; the bootstrap draws each cell twice (Δ* = 1), once each
    (0.5) or the second twice (0), so its 95% interval is [0, 1]: no difference shown. When every cell favours A
    the interval lies above zero."""
    a = {("t1", 0): cell("t1", [True, True]), ("t2", 0): cell("t2", [True, False])}
    b = {("t1", 0): cell("t1", [False, False]), ("t2", 0): cell("t2", [True, False])}
    difference = paired_difference("a", a, "b", b)
    assert difference.difference == 0.5 and (difference.low, difference.high) == (0.0, 1.0)
    assert (difference.a_only, difference.b_only) == (2, 0)
    assert difference.verdict == "no difference shown" and difference.episodes == 4 and difference.cells == 2
    many_a = {(f"t{i}", 0): cell(f"t{i}", [True, True, False]) for i in range(8)}
    many_b = {(f"t{i}", 0): cell(f"t{i}", [True, False, False]) for i in range(8)}
    better = paired_difference("a", many_a, "b", many_b)
    assert better.low == better.high == pytest.approx(1 / 3) and better.verdict == "a beats b"
    assert paired_difference("b", many_b, "a", many_a).verdict == "a beats b"
    assert (better.a_only, better.b_only) == (8, 0)
    shifted = {key: cell(key[0], [True, True, False], seed=2000) for key in many_a}
    with pytest.raises(ManifestError, match="different seeds"):
        paired_difference("a", shifted, "b", many_b)


def test_the_discordant_episodes_show_what_a_level_difference_hides():
    """Two columns level in Δ: one agreeing episode for episode, one trading three successes each way; the line
    names both counts."""
    a = {("t1", 0): cell("t1", [True, True, True, False, False, False])}
    same = {("t1", 0): cell("t1", [True, True, True, False, False, False])}
    traded = {("t1", 0): cell("t1", [False, False, False, True, True, True])}
    agreeing, trading = paired_difference("a", a, "b", same), paired_difference("a", a, "b", traded)
    assert agreeing.difference == trading.difference == 0.0
    assert (agreeing.a_only, agreeing.b_only) == (0, 0) and (trading.a_only, trading.b_only) == (3, 3)
    assert trading.line().endswith("a alone succeeds in 3, b alone in 3")
    assert trading.as_json()["a_only_successes"] == trading.as_json()["b_only_successes"] == 3
