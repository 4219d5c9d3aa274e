"""Sentence encoders: a task said in words → a unit vector, the language head's input (the paper's ``f_lang``, made
there by Sentence-BERT).

Every encoder loads from files already on the machine and never downloads:

* ``wordllama`` (the default): WordLlama's static token embeddings (``l2_supercat``, 256 dimensions, 16 MB) that ship
  inside the ``wordllama`` wheel, average-pooled over a sentence's tokens. No neural network runs: about 0.2 s to
  load and microseconds a sentence on a CPU.
* ``hub:DIR``: a sentence-transformers model in the local directory ``DIR`` (as ``hf download REPO --local-dir DIR``
  leaves it): its transformer through ``transformers`` (``AutoModel``, ``AutoTokenizer``; weights in safetensors
  only) and the pooling its ``modules.json`` names (``1_Pooling/config.json``: CLS token, mean or max over the
  tokens), as sentence-transformers computes them. A directory without ``modules.json`` is read as a plain
  transformer with mean pooling (what sentence-transformers does with one). ``transformers`` comes with the
  ``language-hub`` extra.

:meth:`TextEncoder.encode` returns ``(S, E)`` float32 rows of unit length whatever the model's own last step is, so
cosine similarity is a dot product. :attr:`TextEncoder.fingerprint` is a SHA-256 of everything that determines the
vectors (the weights, the tokenizer, the pooling): a language head records it and refuses another encoder.
"""

from __future__ import annotations

import hashlib
import json
import logging
from abc import ABC, abstractmethod
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from ..model.fingerprint import encoder_fingerprint

DEFAULT_TEXT_ENCODER = "wordllama"
HUB_PREFIX = "hub:"
SPEC_FORMS = f"{DEFAULT_TEXT_ENCODER!r} or '{HUB_PREFIX}DIR' (a sentence-transformers model in a local directory)"


class TextEncoderError(ValueError):
    """A text encoder that cannot be built (unknown spec, missing or unsupported files), or sentences it refuses."""


class TextEncoder(ABC):
    """Sentences → ``(S, E)`` float32 unit vectors.

    Attributes:
        spec: the string :func:`make_text_encoder` builds this encoder from (``wordllama``, ``hub:/abs/dir``).
        dim: ``E``, the vectors' length.
        fingerprint: SHA-256 of what determines the vectors.
    """

    spec: str
    dim: int
    fingerprint: str

    def encode(self, sentences: Sequence[str]) -> np.ndarray:
        """``(S, E)`` float32, each row of unit L2 norm, for ``S ≥ 1`` non-blank sentences (a list or tuple of
        strings; a bare string is refused, it would read as its characters)."""
        if isinstance(sentences, str) or not isinstance(sentences, Sequence):
            raise TextEncoderError(f"encode takes a list of sentences, got {type(sentences).__name__}")
        if len(sentences) == 0:
            raise TextEncoderError("encode needs at least one sentence, got an empty list")
        for index, sentence in enumerate(sentences):
            if not isinstance(sentence, str) or not sentence.strip():
                raise TextEncoderError(f"sentence {index} is not a non-blank string: {sentence!r}")
        vectors = np.asarray(self._embed(list(sentences)), dtype=np.float32)
        norms = np.linalg.norm(vectors, axis=1, keepdims=True)
        if not np.all(np.isfinite(norms)) or np.any(norms == 0.0):
            bad = [sentences[i] for i in np.flatnonzero(~np.isfinite(norms[:, 0]) | (norms[:, 0] == 0.0))]
            raise TextEncoderError(f"{self.spec} gives no embedding (zero or non-finite vector) for {bad}")
        return vectors / norms

    @abstractmethod
    def _embed(self, sentences: list[str]) -> np.ndarray:
        """``(S, E)`` sentence vectors, not yet normalised."""


class WordLlamaEncoder(TextEncoder):
    """WordLlama ``l2_supercat`` at 256 dimensions, the weights and tokenizer inside the installed wheel
    (``WordLlama.load(cache_dir=<package folder>, disable_download=True)``)."""

    CONFIG = "l2_supercat"
    DIM = 256

    def __init__(self):
        wordllama = _import_wordllama()
        self.spec, self.dim = DEFAULT_TEXT_ENCODER, self.DIM
        package = Path(wordllama.__file__).resolve().parent
        try:
            self._model = wordllama.WordLlama.load(config=self.CONFIG, dim=self.DIM, cache_dir=package,
                                                   disable_download=True)
        except FileNotFoundError as error:
            raise TextEncoderError(f"the wordllama package at {package} lacks its {self.CONFIG} files: "
                                   f"{error}") from error
        digest = hashlib.sha256(f"wordllama:{self.CONFIG}:{self.DIM}".encode())
        digest.update(np.ascontiguousarray(self._model.embedding).tobytes())
        digest.update(self._model.tokenizer.to_str().encode())
        self.fingerprint = digest.hexdigest()

    def _embed(self, sentences: list[str]) -> np.ndarray:
        return self._model.embed(sentences, norm=False)


def _import_wordllama():
    """``import wordllama``, undoing the ``logging.basicConfig(level=INFO)`` it runs on import (it would turn on every
    library's INFO messages in the process that loads an encoder)."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    import wordllama

    root.handlers[:] = handlers
    root.setLevel(level)
    return wordllama


POOLING_MODES = {"pooling_mode_cls_token": "cls", "pooling_mode_mean_tokens": "mean", "pooling_mode_max_tokens": "max"}
TRANSFORMER_MODULE = "sentence_transformers.models.Transformer"
POOLING_MODULE = "sentence_transformers.models.Pooling"
NORMALIZE_MODULE = "sentence_transformers.models.Normalize"  # its output is normalised anyway (TextEncoder.encode)


class HubSentenceEncoder(TextEncoder):
    """A sentence-transformers model directory (module docstring): transformer, then pooling, then unit length.

    Args:
        path: the model's local directory.
        batch_size: sentences per forward pass.
    """

    def __init__(self, path: str | Path, batch_size: int = 64):
        root = Path(path).expanduser().resolve()
        if not root.is_dir():
            raise TextEncoderError(f"no sentence-transformers model directory at {root}")
        self.spec, self.batch_size = f"{HUB_PREFIX}{root}", batch_size
        transformer_dir, self.pooling = read_sentence_transformers_layout(root)
        if not any(transformer_dir.glob("*.safetensors")):
            raise TextEncoderError(f"{transformer_dir} holds no .safetensors weights (weights in pickle files are "
                                   "not loaded); save the model with safetensors")
        try:
            from transformers import AutoModel, AutoTokenizer
        except ImportError as error:
            raise TextEncoderError("hub: text encoders need transformers: pip install "
                                   "'lerobot_policy_instant_policy[language-hub]'") from error
        self._tokenizer = AutoTokenizer.from_pretrained(transformer_dir, local_files_only=True)
        self._model = AutoModel.from_pretrained(transformer_dir, local_files_only=True, use_safetensors=True).eval()
        self.max_length = _max_length(transformer_dir, self._tokenizer.model_max_length, self._model.config)
        self.dim = int(self._model.config.hidden_size)
        tokenizer = self._tokenizer.backend_tokenizer.to_str()
        self.fingerprint = encoder_fingerprint(
            self._model, {"pooling": self.pooling, "max_length": self.max_length, "tokenizer": tokenizer})

    def _embed(self, sentences: list[str]) -> np.ndarray:
        rows = []
        with torch.inference_mode():
            for start in range(0, len(sentences), self.batch_size):
                tokens = self._tokenizer(sentences[start:start + self.batch_size], padding=True, truncation=True,
                                         max_length=self.max_length, return_tensors="pt")
                hidden = self._model(**tokens).last_hidden_state  # (S, tokens, E)
                rows.append(pool_tokens(hidden, tokens["attention_mask"], self.pooling).float().numpy())
        return np.concatenate(rows)


def pool_tokens(hidden: torch.Tensor, attention_mask: torch.Tensor, mode: str) -> torch.Tensor:
    """sentence-transformers' pooling of token states ``hidden (S, N, E)`` with ``attention_mask (S, N)`` (1 for a
    real token, 0 for padding) → ``(S, E)``: ``cls`` the first token, ``mean`` the mean of the real tokens, ``max``
    their element-wise maximum."""
    if mode == "cls":
        return hidden[:, 0]
    mask = attention_mask[..., None].to(hidden.dtype)
    if mode == "mean":
        return (hidden * mask).sum(1) / mask.sum(1).clamp(min=1e-9)
    if mode == "max":
        return hidden.masked_fill(mask == 0, torch.finfo(hidden.dtype).min).amax(1)
    raise TextEncoderError(f"unsupported pooling {mode!r}; supported: {sorted(set(POOLING_MODES.values()))}")


def read_sentence_transformers_layout(root: Path) -> tuple[Path, str]:
    """The transformer's directory and the pooling mode of the sentence-transformers model at ``root``, from its
    ``modules.json`` (a Transformer, a Pooling, optionally a Normalize; other modules such as Dense are refused);
    without ``modules.json``: ``root`` itself and mean pooling."""
    modules_file = root / "modules.json"
    if not modules_file.is_file():
        return root, "mean"
    modules = json.loads(modules_file.read_text())
    by_type = {module.get("type"): root / module.get("path", "") for module in modules}
    unsupported = sorted(set(by_type) - {TRANSFORMER_MODULE, POOLING_MODULE, NORMALIZE_MODULE})
    if unsupported or TRANSFORMER_MODULE not in by_type or POOLING_MODULE not in by_type:
        raise TextEncoderError(f"{modules_file}: supported models are a Transformer, a Pooling and optionally a "
                               f"Normalize module; this one has {[module.get('type') for module in modules]}")
    pooling_config = json.loads((by_type[POOLING_MODULE] / "config.json").read_text())
    modes = [mode for key, mode in POOLING_MODES.items() if pooling_config.get(key)]
    others = sorted(key for key, value in pooling_config.items()
                    if key.startswith("pooling_mode_") and value and key not in POOLING_MODES)
    if len(modes) != 1 or others:
        raise TextEncoderError(f"{by_type[POOLING_MODULE] / 'config.json'}: one pooling mode of "
                               f"{sorted(POOLING_MODES)} is supported, got {modes + others}")
    return by_type[TRANSFORMER_MODULE], modes[0]


def _max_length(transformer_dir: Path, tokenizer_max: int, model_config) -> int:
    """Tokens read of a sentence: sentence-transformers' ``max_seq_length`` (``sentence_bert_config.json``), else the
    smaller of the tokenizer's and the model's position limit."""
    config_file = transformer_dir / "sentence_bert_config.json"
    if config_file.is_file():
        value = json.loads(config_file.read_text()).get("max_seq_length")
        if value:
            return int(value)
    positions = getattr(model_config, "max_position_embeddings", None) or tokenizer_max
    return int(min(tokenizer_max, positions))


def make_text_encoder(spec: str = DEFAULT_TEXT_ENCODER) -> TextEncoder:
    """The encoder ``spec`` names: ``wordllama``, or ``hub:DIR`` (an existing directory may also be given as it is).
    Nothing is downloaded: a Hub repo id that is not a local directory is refused with how to fetch it once."""
    if spec == DEFAULT_TEXT_ENCODER:
        return WordLlamaEncoder()
    path = spec[len(HUB_PREFIX):] if spec.startswith(HUB_PREFIX) else spec
    if Path(path).expanduser().is_dir():
        return HubSentenceEncoder(path)
    if spec.startswith(HUB_PREFIX):
        raise TextEncoderError(f"{spec!r}: no directory {path}; text encoders never download: fetch a model once "
                               f"with `hf download REPO --local-dir DIR` and pass {HUB_PREFIX}DIR")
    raise TextEncoderError(f"unknown text encoder {spec!r}: expected {SPEC_FORMS}")
