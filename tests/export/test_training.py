import json
from fractions import Fraction
from itertools import pairwise

import pytest
import torch
from torch import nn

from mogo.export.models.runs import load_checkpoint
from mogo.export.train.training import (
    MetricsLog,
    Process,
    WeightAverage,
    batches,
    save_checkpoint,
    warmup_cosine,
)

SINGLE = Process(rank=0, world_size=1, device=torch.device("cpu"))


def test_warmup_then_cosine():
    lr = [warmup_cosine(s, warmup=10, total=110, peak=1.0, final=0.1) for s in range(120)]
    assert lr[0] == pytest.approx(0.1) and lr[9] == pytest.approx(1.0)
    assert lr[10] == pytest.approx(1.0) and lr[60] == pytest.approx(0.55)
    assert lr[110] == pytest.approx(0.1) and lr[119] == pytest.approx(0.1)
    assert all(a >= b for a, b in pairwise(lr[10:]))


def test_weight_average_follows_the_trained_parameters_only():
    model = nn.Sequential(nn.Linear(2, 2), nn.Linear(2, 1))
    model[0].requires_grad_(False)
    average = WeightAverage(model, decay=0.75)
    start = model[1].weight.detach().clone()
    with torch.no_grad():
        model[1].weight.add_(4.0)
        model[0].weight.add_(4.0)
    average.update(model)
    assert set(average.parameters) == {"1.weight", "1.bias"}
    averaged = average.averaged(model)
    assert torch.allclose(averaged[1].weight, start + 1.0)  # 0.75 * w + 0.25 * (w + 4)
    assert torch.equal(averaged[0].weight, model[0].weight)  # untrained: as it is
    assert torch.equal(model[1].weight, start + 4.0)  # the model itself is left alone
    with pytest.raises(ValueError, match="decay must be in"):
        WeightAverage(model, decay=1.0)


def test_checkpoint_round_trip(tmp_path):
    model = nn.Linear(3, 2)
    optimizer = torch.optim.AdamW(model.parameters())
    model(torch.ones(1, 3)).sum().backward()
    optimizer.step()
    path = tmp_path / "run" / "last.pt"
    save_checkpoint(path, model, optimizer, step=7, config={"width": 3}, best=0.5)
    state = load_checkpoint(path)
    assert state["step"] == 7 and state["config"] == {"width": 3} and state["best"] == 0.5
    again = nn.Linear(3, 2)
    again.load_state_dict(state["model"])
    assert torch.equal(again.weight, model.weight)
    torch.optim.AdamW(again.parameters()).load_state_dict(state["optimizer"])
    assert not list(tmp_path.glob("run/*.partial"))


def test_checkpoint_refuses_truncated_foreign_and_pickled_files(tmp_path):
    good = tmp_path / "good.pt"
    save_checkpoint(good, nn.Linear(2, 2), None, step=0, config={})
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[:100])
    with pytest.raises(ValueError, match="truncated.pt: not a readable"):
        load_checkpoint(truncated)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.ones(2)}, foreign)
    with pytest.raises(ValueError, match="not a mogo checkpoint"):
        load_checkpoint(foreign)
    pickled = tmp_path / "pickled.pt"
    torch.save({"format": 1, "anything": Fraction(1, 3)}, pickled)
    with pytest.raises(ValueError, match="pickled.pt: not a readable"):
        load_checkpoint(pickled)
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")


class _Items(torch.utils.data.Dataset):
    def __len__(self):
        return 10

    def __getitem__(self, index):
        return index


def _first(seed: int, count: int, start_epoch: int = 0) -> list[list[int]]:
    stream = batches(_Items(), 3, SINGLE, seed, start_epoch=start_epoch)
    return [next(stream).tolist() for _ in range(count)]


def test_batches_are_endless_and_depend_only_on_seed_and_epoch():
    run = _first(seed=1, count=9)  # three epochs of three full batches
    assert run == _first(seed=1, count=9) and run != _first(seed=2, count=9)
    assert run[3:6] == _first(seed=1, count=3, start_epoch=1)
    for epoch in range(3):
        items = sum(run[3 * epoch : 3 * epoch + 3], [])
        assert len(set(items)) == 9
    with pytest.raises(ValueError, match="fewer than one batch"):
        next(batches(_Items(), 11, SINGLE, 0))


def test_metrics_log_appends_json_lines(tmp_path):
    log = MetricsLog(tmp_path / "metrics.jsonl")
    log.write("train", 1, loss=torch.tensor(0.5))
    MetricsLog(tmp_path / "metrics.jsonl").write("val", 2, mpjpe=12.0)
    MetricsLog(tmp_path / "silent.jsonl", enabled=False).write("train", 1, loss=1.0)
    records = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert [(r["kind"], r["step"]) for r in records] == [("train", 1), ("val", 2)]
    assert records[0]["loss"] == 0.5 and records[1]["mpjpe"] == 12.0
    assert not (tmp_path / "silent.jsonl").exists()
