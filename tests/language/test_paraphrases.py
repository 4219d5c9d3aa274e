"""The paraphrase file that ships covers both suites with seen and held-out sentences, and paraphrase files are
checked when read."""

from __future__ import annotations

import json
from importlib.resources import files

import numpy as np
import pytest

from lerobot_instant_policy.language.paraphrases import ParaphraseError, Paraphrases, normalise
from lerobot_instant_policy.sim.metaworld.configuration_metaworld import lerobot_metaworld_tasks
from lerobot_instant_policy.sim.task_api import get_task, task_names


def suite_tasks(paraphrases: Paraphrases, suite: str) -> list[str]:
    return [task for task in paraphrases.tasks if paraphrases[task].suite == suite]


def test_every_suite_task_has_four_seen_and_two_held_out_sentences(paraphrases):
    # the suite's own tasks: a test elsewhere may have registered one of its own in this process
    builtin = [name for name in task_names()
               if get_task(name).__module__.startswith("lerobot_instant_policy.sim.tasks")]
    assert len(builtin) == 12 and sorted(suite_tasks(paraphrases, "bullet_tabletop")) == builtin
    assert sorted(suite_tasks(paraphrases, "metaworld")) == sorted(lerobot_metaworld_tasks()[0])  # MT50
    for task in paraphrases.tasks:
        assert len(paraphrases[task].seen) >= 4 and len(paraphrases[task].held_out) == 2, task


def test_lerobot_metaworld_descriptions_are_seen_sentences(paraphrases):
    """The sentence LeRobot's own MetaWorld env says for a task is its first seen sentence, wherever LeRobot gives
    that sentence to one task only."""
    descriptions = json.loads(files("lerobot.envs").joinpath("metaworld_config.json").read_text())["TASK_DESCRIPTIONS"]
    shared = {text for text in descriptions.values() if list(descriptions.values()).count(text) > 1}
    assert shared == {"Push the puck to a goal"}  # push-v3's and push-back-v3's
    for task, text in descriptions.items():
        if text not in shared:
            assert paraphrases[task].seen[0] == text, task


def test_held_out_sentences_find_their_own_task_within_a_suite(paraphrases, wordllama):
    """With the default encoder, a held-out sentence is nearest (best cosine with any seen sentence) to its own task's
    seen sentences for at least 90% of the bullet_tabletop ones (measured 23/24) and 80% of MetaWorld's (86/100)."""
    for suite, least in [("bullet_tabletop", 0.9), ("metaworld", 0.8)]:
        tasks = suite_tasks(paraphrases, suite)
        seen = [wordllama.encode(list(paraphrases[task].seen)) for task in tasks]
        found = [int(np.argmax([float((vector @ group.T).max()) for group in seen])) == index
                 for index, task in enumerate(tasks) for vector in wordllama.encode(list(paraphrases[task].held_out))]
        assert np.mean(found) >= least, (suite, np.mean(found))


def write(tmp_path, data) -> str:
    path = tmp_path / "paraphrases.json"
    path.write_text(json.dumps(data))
    return str(path)


GOOD = {"seen": ["open the drawer"], "held_out": ["pull the drawer out"]}


@pytest.mark.parametrize("data, message", [
    ({"suite": {"a": GOOD, "b": {"seen": ["Open  the Drawer."], "held_out": ["x"]}}},
     "task 'b': the sentence 'Open  the Drawer.' appears also for task 'a'"),
    ({"suite": {"a": {"seen": ["open it", "open it"], "held_out": ["x"]}}}, "appears twice"),
    ({"suite": {"a": {"seen": ["open it"], "held_out": []}}}, "needs at least one held_out sentence"),
    ({"suite": {"a": {"seen": ["open it"]}}}, r"exactly the keys \['seen', 'held_out'\]"),
    ({"suite": {"a": {"seen": ["  "], "held_out": ["x"]}}}, "is not a non-blank string"),
    ({"one": {"a": GOOD}, "two": {"a": {"seen": ["y"], "held_out": ["z"]}}}, "task 'a' is in suites 'one' and 'two'"),
    ([], "expected a non-empty object"),
])
def test_broken_files_are_refused_naming_the_problem(tmp_path, data, message):
    with pytest.raises(ParaphraseError, match=message):
        Paraphrases.load(write(tmp_path, data))


def test_unknown_tasks_and_files_are_refused_clearly(tmp_path, paraphrases):
    with pytest.raises(ParaphraseError, match=r"no sentences for task 'pick_and_plac'.*close: \['pick_and_place'"):
        paraphrases["pick_and_plac"]
    with pytest.raises(ParaphraseError, match=r"no sentences for the tasks \['my_task'\]"):
        paraphrases.check_tasks(["open_drawer", "my_task"])
    with pytest.raises(ParaphraseError, match="unknown paraphrase split 'train'"):
        paraphrases["open_drawer"].split("train")
    with pytest.raises(ParaphraseError, match="no paraphrase file"):
        Paraphrases.load(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ParaphraseError, match="not valid JSON"):
        Paraphrases.load(tmp_path / "bad.json")


def test_a_file_of_ones_own_tasks_loads(tmp_path):
    loaded = Paraphrases.load(write(tmp_path, {"lab": {"wipe_table": {"seen": ["wipe the table", "clean the table"],
                                                                      "held_out": ["wipe down the table"]}}}))
    assert loaded.tasks == ["wipe_table"] and loaded["wipe_table"].split("held_out") == ("wipe down the table",)
    assert normalise(" Wipe  the TABLE. ") == "wipe the table"
