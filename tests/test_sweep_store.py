"""Issue 23: a broken sweep store (`sweep --resume FILE`) is one line naming the file and the line,
exit 6, before any point runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from _hostile import assert_one_line_error, hilbench
from hilbench.bench.metrics import StepMetrics
from hilbench.bench.sweep import SweepStore
from hilbench.errors import ConfigError, RecordingError

SWEEP = ("sweep", "-p", "kp=0.1:0.2:2", "--workers", "1", "--duration", "0.3", "--step-at", "0.1")


@pytest.mark.parametrize("text, words", [
    ("[1,2,3]\n", ("s.jsonl:1", "a JSON list, not a sweep point")),
    ("[" * 100_000 + "\n", ("s.jsonl:1", "a line longer than 65536 bytes")),
    ("[" * 5000 + "\n" + "{}\n", ("s.jsonl:1", "nested too deep")),
])
def test_the_repros(tmp_path: Path, text: str, words: tuple[str, ...]) -> None:
    """Repro: a line `[1,2,3]` (AttributeError), `[` x 100000 (RecursionError)."""
    store = tmp_path / "s.jsonl"
    store.write_text(text)
    result = hilbench(*SWEEP, "--resume", str(store))
    assert_one_line_error(result, 6, *words)


def _row(**changes: object) -> str:
    metrics = StepMetrics(0.0, 1000.0, 1000.0, 0.1, 0.01, 0.11, 2.0, 0.2, 1020.0, 0.3, 0.02, 1.0, 0.1, 2.0, 0.2, 5.0,
                          1.0, None, 0.5, 100).as_dict()
    row: dict[str, object] = {"key": "K", "index": 0, "params": {"kp": 0.1}, "metrics": metrics, "stalled": False,
                              "cases": 1}
    row.update(changes)
    return json.dumps(row) + "\n"


def test_a_good_row_reads_back(tmp_path: Path) -> None:
    store = tmp_path / "s.jsonl"
    store.write_text(_row() + _row(index=1) + '{"key": "K", "ind')  # the last line cut by a kill
    done = SweepStore(store, "K", 2).done
    assert sorted(done) == [0, 1] and done[1][0].n_samples == 100


@pytest.mark.parametrize("line, match", [
    (_row(index=7), "s.jsonl:1: index 7 is not a point of this sweep"),
    (_row(index=True), "index True is not a point"),
    (_row(stalled="no"), "stalled must be true or false"),
    (_row(cases=0), "cases must be a whole number"),
    (_row(metrics={"y0": 1}), "metrics must hold exactly"),
    (_row(metrics=[1]), "metrics must hold exactly"),
    ("null\n", "a JSON NoneType, not a sweep point"),
    ('"text"\n', "a JSON str, not a sweep point"),
    ("\xff\n", "not a JSON line"),
])
def test_each_bad_row_is_named(tmp_path: Path, line: str, match: str) -> None:
    store = tmp_path / "s.jsonl"
    store.write_text(line + _row())
    with pytest.raises(RecordingError, match=match):
        SweepStore(store, "K", 2)


def test_a_metric_that_is_not_a_number(tmp_path: Path) -> None:
    row = json.loads(_row())
    row["metrics"]["itae"] = "x"
    store = tmp_path / "s.jsonl"
    store.write_text(json.dumps(row) + "\n")
    with pytest.raises(RecordingError, match="metrics itae is x, not a number"):
        SweepStore(store, "K", 1)


def test_another_sweeps_store_is_a_config_error(tmp_path: Path) -> None:
    store = tmp_path / "s.jsonl"
    store.write_text(_row(key="other"))
    with pytest.raises(ConfigError, match="holds another sweep"):
        SweepStore(store, "K", 1)


def test_a_store_beyond_its_limit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from hilbench import limits

    monkeypatch.setattr(limits, "STORE_MAX_BYTES", 100)
    store = tmp_path / "s.jsonl"
    store.write_text(_row())
    with pytest.raises(RecordingError, match="more than the limit of 100 bytes"):
        SweepStore(store, "K", 1)


def test_refine_resumes_every_round_from_one_store(tmp_path: Path) -> None:
    """Issue 22, item 11: `sweep --refine N --resume FILE` failed after round 1 ("it holds another
    sweep"), even on a new file: each round is a sweep of its own points. Now the rounds share the
    file as one family; a rerun resumes every round and runs nothing, another sweep is still refused."""
    from hilbench.bench.run import load_run_config, RunRequest
    from hilbench.bench.steptest import StepTest
    from hilbench.bench.sampling import Axis
    from hilbench.bench.sweep import refine

    cfg = load_run_config(RunRequest(None, target="inprocess:an1017"))
    test = StepTest(from_rpm=1000.0, to_rpm=1500.0, settle_s=0.3, after_s=0.3)
    axes = [Axis("kp", 0.05, 0.35, 2), Axis("ki", 0.005, 0.05, 2)]
    store = tmp_path / "s.jsonl"
    first = refine(cfg, axes, test, "itae", rounds=2, workers=1, store=store)
    rows = [json.loads(line) for line in store.read_text().splitlines()]
    assert len(rows) == len(first.points) and len({r["key"] for r in rows}) == 2  # two rounds, one file
    assert len({r["family"] for r in rows}) == 1
    again = refine(cfg, axes, test, "itae", rounds=2, workers=1, store=store)
    assert again.sim_s == 0.0 and store.read_text().count("\n") == len(rows)  # nothing ran again
    assert [p.params for p in again.ranked] == [p.params for p in first.ranked]
    with pytest.raises(ConfigError, match="holds another sweep"):
        refine(cfg, [Axis("kp", 0.05, 0.35, 2), Axis("ki", 0.005, 0.06, 2)], test, "itae", rounds=2, workers=1, store=store)
