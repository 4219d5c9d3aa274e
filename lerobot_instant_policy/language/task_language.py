"""The policy's language path (``--policy.context=language``): a batch row's task string → the sentence that says
it → its vector → the language head's context for the row (:func:`~.context.language_context`), from which the
frozen network samples actions exactly as it does after demonstrations.

* The sentence: a task string that names a task of the paraphrase file (the strings ``bullet_tabletop``'s and
  MetaWorld's envs give, ``push_button``, ``reach-v3``) is said with its paraphrase ``SPLIT:K``, the K-th of its
  ``seen`` or ``held_out`` sentences (:func:`~.paraphrases.paraphrase_choice`); any other string is the sentence
  itself, a task said in the user's own words. An ``instruction`` given once replaces every row's task string.
* The vector: the text encoder the head was trained with (its :class:`~.language_head.HeadBinding`), once per
  distinct sentence.
* The head: read from its directory on first use (default :data:`SHIPPED_LANGUAGE_HEAD`, trained for the shipped
  checkpoint) onto the network's device, and checked against the network whenever the network's weights change: a
  head made for another checkpoint or text encoder is refused.

Nothing here downloads: the head, the paraphrases and the text encoder are files on the machine.
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..model.instant_policy_network import InstantPolicyContext, InstantPolicyNetwork
from .context import language_context
from .language_head import CONFIG_FILE, LanguageHead, LanguageHeadError
from .paraphrases import PARAPHRASES_FILE, Paraphrases, paraphrase_choice
from .text_encoder import TextEncoder, make_text_encoder

SHIPPED_LANGUAGE_HEAD = Path(__file__).resolve().parent.parent / "assets" / "language" / "head"
TRAIN_COMMAND = "lerobot-ip-train-language --checkpoint PRETRAINED_MODEL --dataset ROOT ... --out DIR"


class TaskLanguageError(ValueError):
    """A batch row whose task is not a non-blank string, or a paraphrase the file does not have."""


class TaskLanguage:
    """Task strings → contexts through a language head (module docstring).

    Args:
        head_path: the head's directory (``config.json`` + ``model.safetensors``); ``None``: the shipped head.
        paraphrase: ``SPLIT:K``, the paraphrase that says a task of ``paraphrases_file``.
        paraphrases_file: the paraphrase file (default: the shipped one).
        instruction: what every row is told instead of its task string (a task name or a sentence, said as a task
            string is); ``None``: each row's task.
    """

    def __init__(self, head_path: str | Path | None = None, paraphrase: str = "seen:0",
                 paraphrases_file: str | Path = PARAPHRASES_FILE, instruction: str | None = None):
        self.head_path = SHIPPED_LANGUAGE_HEAD if head_path is None else Path(head_path).expanduser()
        self.instruction = instruction
        self.split, self.index = paraphrase_choice(paraphrase)
        self.paraphrases = Paraphrases.load(paraphrases_file)
        self._known_tasks = set(self.paraphrases.tasks)
        self._head: LanguageHead | None = None
        self._text_encoder: TextEncoder | None = None
        self._vectors: dict[str, torch.Tensor] = {}  # sentence → (E,) float32 on the CPU
        self._checked_weights: tuple | None = None

    def sentence(self, task: str) -> str:
        """The sentence that says ``task``, or the instruction in its place (module docstring)."""
        if not isinstance(task, str) or not task.strip():
            raise TaskLanguageError(
                f"context=language reads the task in words, but a batch row's task is {task!r}: pass batch['task'], a "
                "non-blank task name or sentence per row (lerobot-eval passes the env's task)")
        task = self.instruction or task
        if task not in self._known_tasks:
            return task
        sentences = self.paraphrases[task].split(self.split)
        if self.index >= len(sentences):
            raise TaskLanguageError(f"task {task!r} has {len(sentences)} {self.split} paraphrases in "
                                    f"{self.paraphrases.source}; paraphrase {self.split}:{self.index} does not exist")
        return sentences[self.index]

    def context(self, network: InstantPolicyNetwork, task: str, points_world: torch.Tensor, T_world_ee: torch.Tensor,
                gripper: torch.Tensor) -> InstantPolicyContext:
        """The context of ``B`` rows of ``task`` at one control step.

        Args:
            network: the trained network (its weights must be the ones the head was made for).
            task: the rows' task string.
            points_world: ``(B, P, 3)`` the live clouds in the world frame.
            T_world_ee: ``(B, 4, 4)`` the current EE poses in the world frame.
            gripper: ``(B,)`` the current gripper states, 1 open, 0 closed.
        """
        sentence = self.sentence(task)
        head = self._head_for(network)
        vector = self._vector(sentence).to(device=points_world.device, dtype=points_world.dtype)
        return language_context(network, head, vector.expand(len(points_world), -1), points_world, T_world_ee,
                                gripper)

    def _vector(self, sentence: str) -> torch.Tensor:
        """``(E,)`` the unit vector of ``sentence`` by the head's text encoder, computed once per sentence."""
        if sentence not in self._vectors:
            self._vectors[sentence] = torch.from_numpy(self._text_encoder.encode([sentence])[0])
        return self._vectors[sentence]

    def _head_for(self, network: InstantPolicyNetwork) -> LanguageHead:
        """The head on ``network``'s device, loaded with its text encoder on first use and checked against
        ``network`` whenever its weights have changed; :class:`~.language_head.LanguageHeadError` saying how to
        train a head when there is none or it was made for another network or text encoder."""
        device = next(network.parameters()).device
        if self._head is None:
            if not (self.head_path / CONFIG_FILE).is_file():
                raise LanguageHeadError(f"no language head at {self.head_path}: train one for the checkpoint with "
                                        f"`{TRAIN_COMMAND}` and pass --policy.language_head_path=DIR/head")
            self._head = LanguageHead.load(self.head_path, device)
            self._text_encoder = make_text_encoder(self._head.binding.text_encoder)
        self._head.to(device)
        weights = tuple((parameter.device, parameter.dtype, parameter._version) for parameter in network.parameters())
        if weights != self._checked_weights:
            try:
                self._head.check_binding(network, self._text_encoder)
            except LanguageHeadError as error:
                raise LanguageHeadError(f"the language head at {self.head_path}: {error} (`{TRAIN_COMMAND}`, then "
                                        "--policy.language_head_path=DIR/head)") from error
            self._checked_weights = weights
        return self._head
