"""The sentences that say each task: paraphrases per task, some seen in training, some held out for evaluation.

The file that ships (``assets/language/paraphrases.json``) covers the 12 ``bullet_tabletop`` tasks and MetaWorld's
50 v3 tasks (MT50), keyed by the task string each env gives (``pick_and_place``, ``pick-place-v3``): the string a
demonstration dataset's episodes carry, so a frame's task finds its sentences. Every task has 4 seen paraphrases and
2 held out; a MetaWorld task's first seen sentence is the description LeRobot's own MetaWorld env gives it
(``TASK_DESCRIPTIONS`` of ``lerobot/envs/metaworld_config.json``), except ``push-back-v3``, whose description there
is ``push-v3``'s.

Format: ``{suite: {task: {"seen": [sentence, …], "held_out": [sentence, …]}}}``. A file is checked when it is read
(:class:`ParaphraseError` naming the file, the task and the problem): every task has at least one seen and one held-out
sentence, every sentence is a non-blank string, no task appears in two suites, and no sentence appears twice in the
whole file, compared case-folded with whitespace collapsed and a final full stop dropped (a sentence that says two
tasks would have two answers).
"""

from __future__ import annotations

import difflib
import json
from dataclasses import dataclass
from pathlib import Path

PARAPHRASES_FILE = Path(__file__).resolve().parent.parent / "assets" / "language" / "paraphrases.json"
SPLITS = ("seen", "held_out")


class ParaphraseError(ValueError):
    """A paraphrase file that breaks the format, or a task it does not have."""


@dataclass(frozen=True)
class TaskSentences:
    """The sentences of one task: ``seen`` (training) and ``held_out`` (evaluation only)."""

    task: str
    suite: str
    seen: tuple[str, ...]
    held_out: tuple[str, ...]

    def split(self, name: str) -> tuple[str, ...]:
        """``seen`` or ``held_out``."""
        if name not in SPLITS:
            raise ParaphraseError(f"unknown paraphrase split {name!r}; expected one of {SPLITS}")
        return getattr(self, name)


class Paraphrases:
    """Every task's :class:`TaskSentences`, checked (module docstring); ``source`` names the file in errors."""

    def __init__(self, data: dict, source: str = "<dict>"):
        self.source = source
        if not isinstance(data, dict) or not data:
            raise ParaphraseError(f"{source}: expected a non-empty object {{suite: {{task: {{seen, held_out}}}}}}")
        self._tasks: dict[str, TaskSentences] = {}
        owner: dict[str, str] = {}  # normalised sentence → the task that says it
        for suite, tasks in data.items():
            if not isinstance(tasks, dict) or not tasks:
                raise ParaphraseError(f"{source}: suite {suite!r} must map task names to their sentences")
            for task, entry in tasks.items():
                if task in self._tasks:
                    raise ParaphraseError(f"{source}: task {task!r} is in suites {self._tasks[task].suite!r} and "
                                          f"{suite!r}")
                sentences = self._read_task(suite, task, entry)
                for sentence in (*sentences.seen, *sentences.held_out):
                    key = normalise(sentence)
                    if key in owner:
                        where = "twice" if owner[key] == task else f"also for task {owner[key]!r}"
                        raise ParaphraseError(f"{source}: task {task!r}: the sentence {sentence!r} appears {where}")
                    owner[key] = task
                self._tasks[task] = sentences

    def _read_task(self, suite: str, task: str, entry) -> TaskSentences:
        if not isinstance(entry, dict) or set(entry) != set(SPLITS):
            keys = sorted(entry) if isinstance(entry, dict) else type(entry).__name__
            raise ParaphraseError(f"{self.source}: task {task!r} must have exactly the keys {list(SPLITS)}, got {keys}")
        splits = {}
        for name in SPLITS:
            sentences = entry[name]
            if not isinstance(sentences, list) or not sentences:
                raise ParaphraseError(f"{self.source}: task {task!r} needs at least one {name} sentence")
            for sentence in sentences:
                if not isinstance(sentence, str) or not sentence.strip():
                    raise ParaphraseError(f"{self.source}: task {task!r}: {name} sentence {sentence!r} is not a "
                                          "non-blank string")
            splits[name] = tuple(sentences)
        return TaskSentences(task, suite, **splits)

    @classmethod
    def load(cls, path: str | Path = PARAPHRASES_FILE) -> Paraphrases:
        """The paraphrase file at ``path`` (default: the one that ships)."""
        path = Path(path)
        if not path.is_file():
            raise ParaphraseError(f"no paraphrase file at {path}")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as error:
            raise ParaphraseError(f"{path} is not valid JSON: {error}") from error
        return cls(data, source=str(path))

    @property
    def tasks(self) -> list[str]:
        """Every task, in file order."""
        return list(self._tasks)

    def __getitem__(self, task: str) -> TaskSentences:
        if task not in self._tasks:
            close = difflib.get_close_matches(task, self._tasks, n=3)
            hint = f"; close: {close}" if close else ""
            raise ParaphraseError(f"{self.source} has no sentences for task {task!r}{hint} (add the task to a "
                                  "paraphrase file of your own and pass it)")
        return self._tasks[task]

    def check_tasks(self, tasks) -> None:
        """Raise :class:`ParaphraseError` naming every task of ``tasks`` without sentences here."""
        missing = sorted(set(tasks) - set(self._tasks))
        if missing:
            raise ParaphraseError(f"{self.source} has no sentences for the tasks {missing} (add them to a paraphrase "
                                  "file of your own and pass it)")


def paraphrase_choice(spec: str) -> tuple[str, int]:
    """``"SPLIT:K"`` (``seen:0``, ``held_out:1``: the K-th sentence of a task's split, from 0) → ``(SPLIT, K)``;
    :class:`ParaphraseError` saying the form for anything else."""
    split, _, index = spec.partition(":") if isinstance(spec, str) else ("", "", "")
    if split not in SPLITS or not index.isdigit():
        raise ParaphraseError(f"a paraphrase is chosen as SPLIT:K with SPLIT one of {list(SPLITS)} and K = 0, 1, …, "
                              f"got {spec!r}")
    return split, int(index)


def normalise(sentence: str) -> str:
    """The form sentences are compared in: case-folded, whitespace collapsed, a final full stop dropped."""
    return " ".join(sentence.casefold().split()).rstrip(".")
