"""`mogo bench serve --low-latency` end to end at its smallest: a real `mogo serve` and a
client process, each burst and count run for both decoders; the tables, the JSON and the
charts it writes."""

import json

import pytest

from mogo.cli import main

pytest.importorskip("aiohttp")
pytest.importorskip("onnx")


def test_the_smallest_low_latency_run_compares_both_decoders(tmp_path, capsys):
    argv = ["bench", "serve", "--low-latency", "--burst", "1", "--clients", "1"]
    assert main([*argv, "--seconds", "3", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "| 1 | centred |" in printed and "| 1 | low latency |" in printed
    result = json.loads((tmp_path / "serve_bench.json").read_text())
    decoders = ["centred", "low latency"]
    for measured in (result["bursts"], result["rows"], result["engine"]):
        assert [r["decoder"] for r in measured] == decoders
    first = {r["decoder"]: r["first_frame_ms"]["p50"] for r in result["bursts"]}
    assert 0 < first["low latency"] < float("inf") and 0 < first["centred"] < float("inf")
    assert all(r["fps"] > 0 for r in result["rows"])
    assert set(result["largest_real_time"]) == set(decoders)
    assert (tmp_path / "serve_bench.png").stat().st_size and (
        tmp_path / "serve_bursts.png"
    ).exists()


def test_a_burst_beside_streaming_clients_reports_their_lateness_after_it(tmp_path, capsys):
    argv = ["bench", "serve", "--burst", "2", "--beside", "1", "--clients", "1"]
    assert main([*argv, "--seconds", "2", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "Clients arriving at once while 1 clients stream" in printed
    assert "| clients streaming | their lateness p99 after it |" in printed
    (row,) = json.loads((tmp_path / "serve_bench.json").read_text())["bursts"]
    assert row["burst"] == 2 and row["beside"] == 1
    assert 0 < row["first_frame_ms"]["max"] < float("inf")
    assert 0 <= row["beside_p99_ms"] < float("inf")  # the streaming client had frames after it


def test_beside_takes_no_negative_count(capsys):
    assert main(["bench", "serve", "--beside", "-1"]) == 2
    assert "--beside must be >= 0" in capsys.readouterr().err


def test_engine_costs_measure_each_run():
    """The engine alone, counts and decoders one after another: one row per run, in order,
    each stream stepping at least once a tick."""
    from mogo.bench.speed.serve import engine_costs

    rows = engine_costs([(1, False), (3, True)], 1, ticks=6)
    assert [(r["clients"], r["decoder"]) for r in rows] == [(1, "centred"), (3, "low latency")]
    for row in rows:
        assert row["steps"] >= row["clients"] * 6
        assert row["cpu_ms_per_step"] > 0 and row["wall_ms_per_tick"] > 0 and row["cores"] > 0


def test_both_weights_measures_each_count_with_int8_and_uint8(tmp_path, capsys):
    from mogo.serve.rowwise import signed_products_exact

    if not signed_products_exact():
        pytest.skip("this CPU's uint8 by int8 products saturate: no int8 weights to compare")
    args = ["bench", "serve", "--engine-only", "--both-weights", "--clients", "2"]
    assert main([*args, "--threads", "1", "--out", str(tmp_path)]) == 0
    engine = json.loads((tmp_path / "serve_engine.json").read_text())["engine"]
    assert [(r["clients"], r["weights"]) for r in engine] == [(2, "int8"), (2, "uint8")]
    assert "| 2 | centred | int8 |" in capsys.readouterr().out


def test_both_weights_needs_engine_only(capsys):
    assert main(["bench", "serve", "--both-weights"]) == 2
    assert "--both-weights goes with --engine-only" in capsys.readouterr().err
