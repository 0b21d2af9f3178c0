"""`mogo bench latency` part 2, the step: one whole time step (every level, sampling included) of a
model size against the KV cache length, on onnxruntime fp32 and int8, torch eager with the KV
cache and torch eager recomputing the prefix, each row with its floor (bytes over bandwidth or
FLOPs over peak, whichever is larger). Random weights: the cost does not depend on them."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np
import onnx
import torch

from mogo.bench.speed.timing import Settings, interleaved, log
from mogo.bundle import Bundle
from mogo.export.models.t2m import T2M, T2MConfig
from mogo.export.onnx.bundle import DEFAULT_SAMPLING, quantize_level_graph
from mogo.export.onnx.t2m_graphs import export_level
from mogo.manifest import Graph
from mogo.motion.skeleton import MAX_FRAMES
from mogo.sampling import choose_token
from mogo.serve.onnx_graph import consumer_map
from mogo.token_generator import TokenGenerator

CLIP_FRAMES = MAX_FRAMES  # HumanML3D's longest clip: 9.8 s at 20 fps


def size_configs(bundle_dir: Path) -> dict[str, T2MConfig]:
    bundle_config = dict(Bundle.load(bundle_dir).manifest.t2m.config)
    return dict(bundle=T2MConfig(**bundle_config), paper=T2MConfig.paper(), tiny=T2MConfig.tiny())


def exported_model(config: T2MConfig, work: Path) -> tuple[T2M, Path, list[Graph]]:
    """The model with seed-0 random weights and its fp32 and int8 level graphs, exported once
    into `work` (keyed by the config and the torch version) and reused by later runs."""
    key = hashlib.sha256(json.dumps([asdict(config), torch.__version__]).encode()).hexdigest()
    folder = work / key[:16]
    torch.manual_seed(0)
    model = T2M(config).eval()
    index = folder / "graphs.json"
    if index.is_file():
        return (
            model,
            folder,
            [
                Graph(g["file"], tuple(g["inputs"]), tuple(g["outputs"]))
                for g in json.loads(index.read_text())
            ],
        )
    (folder / "int8").mkdir(parents=True, exist_ok=True)
    graphs = []
    for level in range(config.num_levels):
        log(
            f"exporting level {level + 1}/{config.num_levels} ({config.layers[level]} layers, "
            f"width {config.dim}) fp32 and int8 into {folder}"
        )
        path = folder / f"level_{level}.onnx"
        graphs.append(export_level(model, level, path))
        quantize_level_graph(path, folder / "int8" / path.name)
    index.write_text(json.dumps([asdict(g) for g in graphs]))
    return model, folder, graphs


def onnx_step(generator: TokenGenerator, config: T2MConfig, length: int) -> Callable[[], None]:
    """One whole time step on onnxruntime with a cache of `length` slots (random values)."""
    rng = np.random.default_rng(length)
    prompt = rng.standard_normal((1, config.text_dim)).astype(np.float32)
    uncond = np.zeros(1, bool)
    token_ids = np.zeros((1, 1, config.num_levels), np.int64)
    position = np.array([length], np.int64)
    past_positions = np.arange(length, dtype=np.int64)
    caches = [
        [
            rng.standard_normal((1, heads, length, head_dim)).astype(np.float32)
            for _ in range(2 * layers)
        ]
        for layers, heads, head_dim in generator.cache_shapes
    ]

    def step() -> None:
        outputs = generator.each_level(
            lambda level: generator.run(
                level, prompt, uncond, token_ids, position, past_positions, caches[level]
            )
        )
        for logits, _ in outputs:
            choose_token(logits[0], None, 0.5, DEFAULT_SAMPLING)

    return step


def torch_step(model: T2M, length: int, threads: int, cached: bool) -> Callable[[], None]:
    """One whole time step in torch eager: on a KV cache of `length` slots, or recomputing all
    `length` + 1 positions from scratch (no cache), as the public prototype does."""
    config = model.config
    g = torch.Generator().manual_seed(length)
    prompt = torch.randn(1, config.text_dim, generator=g)
    uncond = torch.zeros(1, dtype=torch.bool)
    positions = torch.tensor([length]) if cached else torch.arange(length + 1)
    token_ids = torch.zeros(1, len(positions), config.num_levels, dtype=torch.long)
    past_positions = torch.arange(length) if cached else None
    pasts = [
        [
            (
                torch.randn(1, config.heads[l], length, config.head_dim, generator=g),
                torch.randn(1, config.heads[l], length, config.head_dim, generator=g),
            )
            for _ in range(config.layers[l])
        ]
        if cached
        else None
        for l in range(config.num_levels)
    ]

    @torch.inference_mode()
    def step() -> None:
        torch.set_num_threads(threads)
        for level in range(config.num_levels):
            logits, _ = model.level_forward(
                level, prompt, uncond, token_ids, positions, past_positions, pasts[level]
            )
            choose_token(logits[0].numpy(), None, 0.5, DEFAULT_SAMPLING)

    return step


def step_backends(
    model: T2M, folder: Path, graphs: list[Graph], threads: tuple[int, ...]
) -> dict[str, tuple[str, int, Callable]]:
    """name -> (weights kind for the floor, cores used, factory(length) -> step callable)."""
    end = model.config.end_token
    backends = {}
    for kind, sub in (("fp32", folder), ("int8", folder / "int8")):
        paths = [sub / g.file for g in graphs]
        single = TokenGenerator(paths, graphs, end, intra_op_threads=1)
        for t in threads:
            generators = {f"onnxruntime {kind}, {t} thread{'s' * (t > 1)}": single}
            if t > 1:
                generators[f"onnxruntime {kind}, {t} threads"] = TokenGenerator(
                    paths, graphs, end, intra_op_threads=t
                )
                generators[f"onnxruntime {kind}, {t} level groups"] = single.with_level_workers(t)
            for name, generator in generators.items():
                backends[name] = (kind, t, lambda n, g=generator: onnx_step(g, model.config, n))
    for t in threads:
        plural = "s" * (t > 1)
        backends[f"torch eager + KV cache, {t} thread{plural}"] = (
            "fp32",
            t,
            lambda n, t=t: torch_step(model, n, t, cached=True),
        )
        backends[f"torch eager, recompute, {t} thread{plural}"] = (
            "fp32 recompute",
            t,
            lambda n, t=t: torch_step(model, n, t, cached=False),
        )
    return backends


def touched_weight_bytes(paths: list[Path]) -> int:
    """Bytes of the initializers a decode step reads in full: all but the tables only Gather
    reads (one row of a token embedding table per step)."""
    total = 0
    for path in paths:
        graph = onnx.load(path, load_external_data=False).graph
        readers = consumer_map(graph)
        for weight in graph.initializer:
            if {node.op_type for node in readers.get(weight.name, [])} - {"Gather"}:
                total += onnx.numpy_helper.to_array(weight).nbytes
    return total


def step_flops(config: T2MConfig, length: int, positions: int = 1) -> float:
    """FLOPs of one step: every level's matrix products for `positions` new positions
    attending to `length` past ones plus themselves."""
    D, dh, R = config.dim, config.head_dim, config.max_relative_distance
    macs = 0
    for level in range(config.num_levels):
        H = config.heads[level]
        per_layer = 4 * D * H * dh + 2 * D * config.mlp_ratio * D  # qkv + proj + mlp
        attention = H * dh * (2 * (length + positions) + R + 1)  # q.k, a.v, q.phi
        macs += config.layers[level] * positions * (per_layer + attention)
        macs += D * config.num_classes(level) + D * config.text_dim  # head, prompt projection
    return 2.0 * macs


def kv_bytes(config: T2MConfig, length: int) -> int:
    """float32 key and value bytes of a `length`-slot cache, all levels."""
    return sum(
        4 * 2 * config.layers[l] * config.heads[l] * config.head_dim * length
        for l in range(config.num_levels)
    )


def step_table(
    size: str,
    config: T2MConfig,
    work: Path,
    settings: Settings,
    bandwidth: dict[int, float],
    flops: dict[int, float],
) -> dict:
    """Part 2 for one model size."""
    model, folder, graphs = exported_model(config, work)
    backends = step_backends(model, folder, graphs, settings.threads)
    weights = {
        "fp32": touched_weight_bytes([folder / g.file for g in graphs]),
        "int8": touched_weight_bytes([folder / "int8" / g.file for g in graphs]),
    }
    weights["fp32 recompute"] = weights["fp32"]
    rows = {
        name: dict(kind=kind, threads=threads, step_ms={}, floor_ms={})
        for name, (kind, threads, _) in backends.items()
    }
    for length in settings.lengths:
        log(f"{size}: {len(backends)} backends at cache length {length}")
        calls = {name: factory(length) for name, (_, _, factory) in backends.items()}
        medians = interleaved(calls, settings.rounds, settings.round_budget_s)
        for name, seconds in medians.items():
            kind, threads = rows[name]["kind"], rows[name]["threads"]
            recompute = kind == "fp32 recompute"
            memory = weights[kind] + (0 if recompute else kv_bytes(config, length))
            compute = step_flops(config, 0 if recompute else length, length + 1 if recompute else 1)
            floor = max(memory / bandwidth[threads], compute / flops[threads])
            rows[name]["step_ms"][length] = 1e3 * seconds
            rows[name]["floor_ms"][length] = 1e3 * floor
    for row in rows.values():
        row["clip_s"] = clip_seconds(row["step_ms"])
    return dict(
        config=asdict(config),
        parameters=sum(p.numel() for p in model.parameters()),
        weight_mb={k: v / 1e6 for k, v in weights.items() if k != "fp32 recompute"},
        backends=rows,
    )


def clip_seconds(step_ms: dict[int, float]) -> float:
    """A 196-step clip from the measured step times: step n has n cache slots (no window),
    its time linearly interpolated between the measured lengths."""
    lengths = sorted(step_ms)
    return (
        float(np.interp(np.arange(CLIP_FRAMES), lengths, [step_ms[n] for n in lengths]).sum()) / 1e3
    )
