"""`mogo bench serve --profile`: a served stream step split into its parts (torch-free)."""

from mogo.bench.speed.serve import PARTS, engine_profile, profile_table
from mogo.cli import main


def test_the_parts_and_the_rest_add_up_to_the_step():
    rows = engine_profile(2)
    assert [part for part, _ in rows[: len(PARTS)]] == list(PARTS)
    parts, whole = [ms for _, ms in rows[:-1]], rows[-1][1]
    assert all(ms > 0 for ms in parts)  # each part ran: none of PARTS names a function gone
    assert abs(sum(parts) - whole) < 1e-9 * whole
    assert profile_table(rows).splitlines()[-1].endswith("| 100% |")


def test_the_command_prints_the_table(capsys):
    assert main(["bench", "serve", "--profile", "1"]) == 0
    out = capsys.readouterr().out
    assert "| level graphs (onnxruntime) |" in out and "| a stream step |" in out
    assert "level graphs' weights: " in out  # which int8 products this CPU's numbers used
