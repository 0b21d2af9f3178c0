"""`mogo bench deploy` end to end at its smallest: the resume cost of real streams and one
`mogo serve --workers 1` with one WebSocket client, the table and the JSON it writes."""

import json

import pytest

from mogo.cli import main

pytest.importorskip("aiohttp")


def test_the_smallest_run_measures_resumes_and_a_served_count(tmp_path, capsys):
    argv = ["bench", "deploy", "--workers", "1", "--clients", "1", "--seconds", "2"]
    assert main([*argv, "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "| workers | clients |" in printed and "largest count in real time" in printed
    result = json.loads((tmp_path / "deploy_bench.json").read_text())
    resume = result["resume"]
    assert resume["streams"] == 16 and 0 < resume["resume_ms"]["p50"] <= resume["resume_ms"]["max"]
    assert resume["state_chars"]["max"] > 0 and resume["replayed_steps"]["max"] >= 0
    [row] = result["rows"]
    assert row["workers"] == 1 and row["clients"] == 1 and row["fps"] > 0


@pytest.mark.parametrize("bad", [["--clients", "0"], ["--workers", "0"], ["--seconds", "0"]])
def test_bad_counts_are_one_line(bad, capsys):
    assert main(["bench", "deploy", *bad]) == 2
    assert "--clients and --workers take numbers >= 1" in capsys.readouterr().err
