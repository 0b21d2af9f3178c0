"""Caption tokenizer (JSON-complete) and the small text encoder behind the TextEncoder seam."""

import pytest
import torch
from tokenizers import Tokenizer

from mogo.export.models.t2m import T2M, T2MConfig
from mogo.export.models.text_encoder import (
    PAD_ID,
    SPECIAL_TOKENS,
    SmallTextEncoder,
    SmallTextEncoderConfig,
    TextEncoder,
    encode_captions,
    train_tokenizer,
)

CAPTIONS = [
    "a person walks forward.",
    "someone jumps up and down!",
    "a man waves his right hand",
    "the person turns around slowly.",
    "a woman kicks with her left leg",
] * 3


@pytest.fixture(scope="module")
def tokenizer():
    return train_tokenizer(CAPTIONS, vocab_size=120, max_length=12)


def test_tokenizer_round_trip_and_specials(tokenizer):
    assert [tokenizer.token_to_id(t) for t in SPECIAL_TOKENS] == [0, 1, 2]
    encoding = tokenizer.encode("A Person  walks FORWARD.")
    assert encoding.ids[0] == tokenizer.token_to_id("[CLS]")
    assert tokenizer.decode(encoding.ids) == "a person walks forward."
    assert tokenizer.encode("the café").tokens == tokenizer.encode("the cafe").tokens
    assert tokenizer.encode("a ☃ waves").tokens == ["[CLS]", "a", "[UNK]", "waves"]
    assert len(tokenizer.encode(" ".join(["walks"] * 50)).ids) == 12


def test_tokenizer_training_is_deterministic(tokenizer):
    again = train_tokenizer(list(reversed(CAPTIONS)), vocab_size=120, max_length=12)
    assert again.to_str() == tokenizer.to_str()
    small = train_tokenizer(CAPTIONS, vocab_size=60, max_length=12)
    assert small.get_vocab_size() == 60
    assert small.decode(small.encode("a person walks forward.").ids) == "a person walks forward."


def test_tokenizer_json_round_trip_gives_identical_ids(tokenizer, tmp_path):
    path = tmp_path / "tokenizer.json"
    tokenizer.save(str(path))
    loaded = Tokenizer.from_file(str(path))
    texts = ["A man waves.", "someone jumps up and down while turning around " * 3, "", "é ü"]
    for a, b in zip(tokenizer.encode_batch(texts), loaded.encode_batch(texts), strict=False):
        assert a.ids == b.ids and a.attention_mask == b.attention_mask
    assert [e.ids for e in loaded.encode_batch(texts[:1])] == [tokenizer.encode(texts[0]).ids]


def test_encode_captions_pads_the_batch(tokenizer):
    ids, mask = encode_captions(tokenizer, ["a man", "a person walks forward"])
    assert ids.dtype == mask.dtype == torch.long and ids.shape == mask.shape == (2, 5)
    assert mask.tolist() == [[1, 1, 1, 0, 0], [1, 1, 1, 1, 1]] and ids[0, 3:].eq(PAD_ID).all()


def test_small_encoder_pools_real_tokens_only(tokenizer):
    torch.manual_seed(0)
    encoder = SmallTextEncoder(SmallTextEncoderConfig.tiny(tokenizer.get_vocab_size())).eval()
    assert isinstance(encoder, TextEncoder) and encoder.output_dim == 32
    ids, mask = encode_captions(tokenizer, ["a man", "a person walks forward slowly", ""])
    pooled = encoder.encode(ids, mask)
    alone = encoder.encode(*encode_captions(tokenizer, ["a man"]))
    assert pooled.shape == (3, 32) and torch.isfinite(pooled).all()
    torch.testing.assert_close(pooled[:1], alone, rtol=0, atol=1e-6)


def test_encoder_conditions_the_motion_model_end_to_end(tokenizer):
    torch.manual_seed(0)
    encoder = SmallTextEncoder(SmallTextEncoderConfig.tiny(tokenizer.get_vocab_size()))
    config = T2MConfig.tiny()
    config.text_dim = encoder.output_dim
    model = T2M(config)
    ids, mask = encode_captions(tokenizer, ["a man waves", "a woman kicks"])
    tokens = torch.randint(0, config.codebook_size, (2, 6, config.num_levels))
    total, _ = model.loss(encoder.encode(ids, mask), tokens, torch.tensor([6, 4]))
    total.backward()
    assert encoder.token_embedding.weight.grad.abs().sum() > 0
