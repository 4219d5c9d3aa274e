"""Sentence encoders: the default WordLlama one and a sentence-transformers directory, offline, deterministic, unit
vectors, paraphrases nearer each other than other tasks' sentences, clear refusals."""

from __future__ import annotations

import json
import socket

import numpy as np
import pytest
import torch

from lerobot_instant_policy.language.text_encoder import (
    HubSentenceEncoder,
    TextEncoderError,
    WordLlamaEncoder,
    make_text_encoder,
)


def test_wordllama_gives_deterministic_unit_vectors_of_256_dimensions(wordllama):
    sentences = ["open the drawer", "Pick up the cube and lift it.", "press the button"]
    vectors = wordllama.encode(sentences)
    assert vectors.shape == (3, 256) and vectors.dtype == np.float32 and wordllama.dim == 256
    np.testing.assert_allclose(np.linalg.norm(vectors, axis=1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(wordllama.encode(sentences), vectors)
    again = WordLlamaEncoder()
    np.testing.assert_array_equal(again.encode(sentences), vectors)
    assert again.fingerprint == wordllama.fingerprint and again.spec == "wordllama"
    # a sentence's vector does not depend on the others encoded with it (padding is pooled out)
    np.testing.assert_allclose(wordllama.encode([sentences[0]])[0], vectors[0], atol=1e-6)


def test_a_paraphrase_is_nearer_than_another_tasks_sentence(wordllama, paraphrases):
    """The held-out sentences of a few suite tasks are on average nearer their own task's seen sentences than those of
    a different task, by a clear margin."""
    for task, other in [("open_drawer", "push_button"), ("push_button", "pick_and_lift"),
                        ("pick_and_place", "knock_over"), ("door-open-v3", "window-close-v3")]:
        held_out = wordllama.encode(list(paraphrases[task].held_out))
        own = float((held_out @ wordllama.encode(list(paraphrases[task].seen)).T).mean())
        foreign = float((held_out @ wordllama.encode(list(paraphrases[other].seen)).T).mean())
        assert own > foreign + 0.2, (task, own, other, foreign)


def test_the_default_encoder_loads_and_encodes_with_the_network_blocked(no_network):
    encoder = make_text_encoder()
    with pytest.raises(OSError, match="network access attempted"):
        socket.create_connection(("127.0.0.1", 9))  # the block holds
    assert encoder.encode(["put the cube in the tray"]).shape == (1, 256)


@pytest.mark.parametrize("sentences, message", [
    ([], "at least one sentence"),
    (["open the drawer", "   "], "sentence 1 is not a non-blank string"),
    (["open the drawer", 3], "sentence 1 is not a non-blank string"),
    ("open the drawer", "a list of sentences"),
])
def test_bad_sentences_are_refused(wordllama, sentences, message):
    with pytest.raises(TextEncoderError, match=message):
        wordllama.encode(sentences)


def test_unknown_specs_are_refused_and_nothing_is_downloaded(tmp_path):
    with pytest.raises(TextEncoderError, match="unknown text encoder 'bert'"):
        make_text_encoder("bert")
    with pytest.raises(TextEncoderError, match="never download.*hf download"):
        make_text_encoder("hub:sentence-transformers/all-MiniLM-L6-v2")


# ---------------------------------------------------------------------------------------------- sentence-transformers
VOCAB = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", *"open close the a drawer box push press pick up cube lift button".split()]


def write_sentence_transformer(root, pooling: str = "mean", weights_seed: int = 0):
    """A tiny sentence-transformers model directory: a 1-layer BERT (hidden 32) in safetensors, a WordPiece tokenizer,
    ``modules.json`` with Transformer, Pooling (``pooling``) and Normalize."""
    transformers = pytest.importorskip("transformers", reason="hub: text encoders need the language-hub extra")
    from tokenizers import Tokenizer, models, normalizers, pre_tokenizers, processors

    tokenizer = Tokenizer(models.WordPiece({word: index for index, word in enumerate(VOCAB)}, unk_token="[UNK]"))
    tokenizer.normalizer = normalizers.BertNormalizer(lowercase=True)
    tokenizer.pre_tokenizer = pre_tokenizers.BertPreTokenizer()
    tokenizer.post_processor = processors.TemplateProcessing(single="[CLS] $A [SEP]",
                                                             special_tokens=[("[CLS]", 2), ("[SEP]", 3)])
    transformers.PreTrainedTokenizerFast(tokenizer_object=tokenizer, unk_token="[UNK]", pad_token="[PAD]",
                                         cls_token="[CLS]", sep_token="[SEP]").save_pretrained(root)
    config = transformers.BertConfig(vocab_size=len(VOCAB), hidden_size=32, num_hidden_layers=1, num_attention_heads=2,
                                     intermediate_size=37, max_position_embeddings=64)
    torch.manual_seed(weights_seed)
    transformers.BertModel(config).save_pretrained(root)
    (root / "1_Pooling").mkdir()
    (root / "1_Pooling" / "config.json").write_text(json.dumps({
        "word_embedding_dimension": 32, "pooling_mode_cls_token": pooling == "cls",
        "pooling_mode_mean_tokens": pooling == "mean", "pooling_mode_max_tokens": pooling == "max",
        "pooling_mode_mean_sqrt_len_tokens": False}))
    (root / "sentence_bert_config.json").write_text(json.dumps({"max_seq_length": 16, "do_lower_case": False}))
    (root / "modules.json").write_text(json.dumps([
        {"idx": 0, "name": "0", "path": "", "type": "sentence_transformers.models.Transformer"},
        {"idx": 1, "name": "1", "path": "1_Pooling", "type": "sentence_transformers.models.Pooling"},
        {"idx": 2, "name": "2", "path": "2_Normalize", "type": "sentence_transformers.models.Normalize"}]))
    return root


def reference_vectors(root, sentences: list[str], pooling: str) -> np.ndarray:
    """The model's token states pooled by hand, one sentence at a time (no padding), unit length."""
    from transformers import AutoModel, AutoTokenizer

    tokenizer, model = AutoTokenizer.from_pretrained(root), AutoModel.from_pretrained(root)
    rows = []
    with torch.no_grad():
        for sentence in sentences:
            states = model(**tokenizer([sentence], return_tensors="pt")).last_hidden_state[0]
            rows.append(states[0] if pooling == "cls" else states.mean(0) if pooling == "mean" else states.amax(0))
    vectors = torch.stack(rows).numpy()
    return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)


@pytest.mark.parametrize("pooling", ["mean", "cls", "max"])
def test_a_sentence_transformers_directory_pools_as_sentence_transformers_does(tmp_path, no_network, pooling):
    root = write_sentence_transformer(tmp_path / "model", pooling)
    encoder = make_text_encoder(f"hub:{root}")
    assert isinstance(encoder, HubSentenceEncoder)
    assert encoder.spec == f"hub:{root.resolve()}" and encoder.dim == 32 and encoder.max_length == 16
    sentences = ["open the drawer", "pick up the cube and lift the cube up", "press the button"]
    vectors = encoder.encode(sentences)  # batched: the short sentences are padded
    assert vectors.shape == (3, 32) and vectors.dtype == np.float32
    np.testing.assert_allclose(vectors, reference_vectors(root, sentences, pooling), atol=1e-5)
    np.testing.assert_array_equal(make_text_encoder(str(root)).encode(sentences), vectors)


def test_the_fingerprint_follows_the_weights_and_the_pooling(tmp_path):
    fingerprints = {make_text_encoder(f"hub:{write_sentence_transformer(tmp_path / name, pooling, seed)}").fingerprint
                    for name, pooling, seed in [("a", "mean", 0), ("b", "mean", 0), ("c", "cls", 0), ("d", "mean", 1)]}
    assert len(fingerprints) == 3  # a and b are the same model


def test_unsupported_sentence_transformers_directories_are_refused(tmp_path):
    root = write_sentence_transformer(tmp_path / "dense")
    modules = json.loads((root / "modules.json").read_text())
    modules.append({"idx": 3, "name": "3", "path": "3_Dense", "type": "sentence_transformers.models.Dense"})
    (root / "modules.json").write_text(json.dumps(modules))
    with pytest.raises(TextEncoderError, match="sentence_transformers.models.Dense"):
        make_text_encoder(f"hub:{root}")
    root = write_sentence_transformer(tmp_path / "pickle")
    (root / "model.safetensors").rename(root / "pytorch_model.bin")
    with pytest.raises(TextEncoderError, match="no .safetensors weights"):
        make_text_encoder(f"hub:{root}")
