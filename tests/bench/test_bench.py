"""`mogo bench latency`: a quick run end to end on the shipped bundle and a tiny model, and the pieces
its figures rest on (FLOP count, bytes read, clip interpolation, interleaving, plots)."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from PIL import Image
from torch.utils.flop_counter import FlopCounterMode

from mogo.bench.speed import latency, step, timing
from mogo.bench.speed.plot import log_line_chart
from mogo.bundle import read_manifest
from mogo.cli import main
from mogo.export.models.t2m import T2M, T2MConfig
from mogo.generator import DEFAULT_BUNDLE


@pytest.mark.parametrize("cached", [True, False])
def test_step_flops_equal_torch_flop_counter(cached):
    config = T2MConfig.tiny()
    model = T2M(config).eval()
    length = 7
    positions = torch.tensor([length]) if cached else torch.arange(length + 1)
    with torch.inference_mode(), FlopCounterMode(display=False) as counter:
        for level in range(config.num_levels):
            shape = (1, config.heads[level], length, config.head_dim)
            past = (
                [(torch.randn(shape), torch.randn(shape))] * config.layers[level]
                if cached
                else None
            )
            model.level_forward(
                level,
                torch.randn(1, config.text_dim),
                torch.zeros(1, dtype=torch.bool),
                torch.zeros(1, len(positions), config.num_levels, dtype=torch.long),
                positions,
                torch.arange(length) if cached else None,
                past,
            )
    expected = step.step_flops(config, length if cached else 0, 1 if cached else length + 1)
    assert counter.get_total_flops() == expected


def test_clip_interpolates_the_measured_step_times():
    flat = step.clip_seconds({1: 2.0, 200: 2.0})
    assert flat == pytest.approx(step.CLIP_FRAMES * 2.0 / 1e3)
    growing = step.clip_seconds({0: 0.0, 195: 195.0})  # step n takes n ms
    assert growing == pytest.approx(sum(range(step.CLIP_FRAMES)) / 1e3)


def test_interleaved_rotates_and_respects_rounds():
    order = []
    medians = timing.interleaved(
        {"a": lambda: order.append("a"), "b": lambda: order.append("b")},
        rounds=4,
        budget_s=100.0,
        warmup=0,
    )
    assert order == ["a", "b", "b", "a", "a", "b", "b", "a"] and set(medians) == {"a", "b"}


def test_touched_bytes_leave_out_embedding_tables(tmp_path):
    config = T2MConfig.tiny()
    model, folder, graphs = step.exported_model(config, tmp_path)
    fp32 = step.touched_weight_bytes([folder / g.file for g in graphs])
    int8 = step.touched_weight_bytes([folder / "int8" / g.file for g in graphs])
    tables = sum(p.numel() for p in model.token_embeddings.parameters()) * 4
    everything = sum(p.numel() for p in model.parameters()) * 4
    assert 0 < int8 < fp32 < everything - tables + 4096  # what the graph adds: folded constants
    again = step.exported_model(config, tmp_path)  # reused, not exported again
    assert again[1] == folder and again[2] == graphs


def test_plot_is_a_small_png(tmp_path):
    path = tmp_path / "plot.png"
    log_line_chart(
        path, "t", "x", "y", {"a": [(1, 0.5), (10, 0.7), (100, 3.0)], "b": [(1, 2.0), (100, 2.2)]}
    )
    image = Image.open(path)
    assert image.size == (760, 460) and path.stat().st_size < 200_000
    with pytest.raises(ValueError, match="log axes"):
        log_line_chart(path, "t", "x", "y", {"a": [(0, 1.0)]})


def test_quick_run_writes_tables_json_and_plots(tmp_path, capsys):
    settings = replace(timing.SMOKE, long_steps=2 * latency.SPAN)
    report = latency.run(DEFAULT_BUNDLE, tmp_path / "out", tmp_path / "work", settings)
    printed = capsys.readouterr().out
    assert "time to first frame" in printed and "tiny model: backend" in printed
    saved = json.loads((tmp_path / "out" / "bench.json").read_text())
    assert set(saved["steps"]) == {"tiny"} and saved["machine"] == report["machine"]
    product = saved["product"]
    assert set(product["threads"]) == {"1", "2"} and product["window"] == 128
    for t, row in product["threads"].items():  # times are the run's to report, not to check
        assert f"| {t} | {row['ttff_ms']:.1f} |" in printed
        times = [row[k] for k in ("ttff_ms", "clip_s", "real_time_factor", "stream_flatness")]
        assert all(np.isfinite(v) and v > 0 for v in times + list(row["stream_step_ms"].values()))
        assert row["real_time_factor"] * row["clip_s"] == pytest.approx(product["clip_seconds"])
        assert [int(n) for n in row["stream_step_ms"]] == latency.long_stream_points(
            settings.long_steps
        )
    shipped = read_manifest(DEFAULT_BUNDLE).total_bytes / 1e6  # every file the bundle lists
    assert product["disk_mb"] == pytest.approx(shipped) and product["peak_rss_mib"] > 50
    backends = saved["steps"]["tiny"]["backends"]
    assert len(backends) == 10  # 2 kinds x (1 thread, 2 threads, 2 level groups) + 4 torch
    for row in backends.values():
        assert all(np.isfinite(v) and v > 0 for v in row["step_ms"].values())
        assert all(0 < row["floor_ms"][n] for n in row["step_ms"])
    for name in ("step_vs_cache_tiny.png", "long_stream.png"):
        assert (tmp_path / "out" / name).stat().st_size < 200_000


def test_bad_options_are_refused(capsys):
    assert main(["bench", "latency", "--smoke", "--long-steps", "10"]) == 2
    assert "--long-steps must be at least" in capsys.readouterr().err
    assert main(["bench", "latency", "--smoke", "--threads", "0"]) == 2
    assert ">= 1" in capsys.readouterr().err
