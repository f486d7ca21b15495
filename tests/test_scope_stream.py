"""The scope's display stream: envelopes, frames against the full-rate recording, markers, the
hand-over before a recorder flush, and the control socket's stream/press request shapes."""

from __future__ import annotations

import base64
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import hilbench
from hilbench.bench.control import validate_request
from hilbench.bench.display import MAX_FRAME_BUCKETS, envelope


class Request:
    """A control request answered in process (what the control socket hands the session)."""

    def __init__(self, cmd: str, **args: Any) -> None:
        self.cmd, self.args = cmd, args
        self.answer: tuple[bool, str, Any] | None = None

    def reply(self, ok: bool, text: str, data: dict[str, Any] | None = None) -> None:
        assert self.answer is None, "answered twice"
        self.answer = (ok, text, data)


def ask(bench: hilbench.Bench, since: int, columns: list[str]) -> dict[str, Any]:
    request = Request("stream", since=since, columns=columns)
    bench.session.handle_control(request, bench.t_s)  # type: ignore[union-attr]
    assert request.answer is not None and request.answer[0], request.answer
    return request.answer[2]


def decode(text: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(text), dtype="<f4")


def test_envelope_by_hand() -> None:
    values = np.array([3, 1, 4, 1, 5, 9, 2, 6, 5, 3], dtype=float)
    lo, hi = envelope(values, 4)  # buckets [3 1 4 1] [5 9 2 6] [5 3]
    assert lo.tolist() == [1, 2, 3] and hi.tolist() == [4, 9, 5]
    table = np.column_stack([values, -values])
    lo2, hi2 = envelope(table, 5)  # [3 1 4 1 5] [9 2 6 5 3]
    assert lo2.tolist() == [[1, -5], [2, -9]] and hi2.tolist() == [[5, -1], [9, -2]]
    with pytest.raises(ValueError):
        envelope(values, 0)


def test_stream_sleeps_until_asked() -> None:
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.run(0.05)
        assert bench.session.display is None  # type: ignore[union-attr]


def test_frames_are_the_envelopes_of_the_recorded_rows() -> None:
    columns = ["t_s", "speed_rpm", "ia_a", "hall", "hall_a", "hall_b", "hall_c", "duty_a"]
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.12)
        first = ask(bench, -1, columns)
        bench.run(0.3)
        later = ask(bench, first["seq"], columns)
        signals = bench.signals()
    meta = first["meta"]
    units = dict(meta["columns"])
    assert units["speed_rpm"] == "rpm" and units["ia_a"] == "A" and units["hall_a"] == "bit"
    assert meta["params"]["kp"]["min"] == 0.0 and meta["params"]["kp"]["max"] == pytest.approx(32767 / 32768)
    frames = first["frames"] + later["frames"]
    assert frames and all(f["n"] <= MAX_FRAME_BUCKETS for f in frames)
    t = signals["t_s"]
    period_s = 50e-6
    hall = signals["hall"].astype(int)
    reference = {"speed_rpm": signals["speed_rpm"], "ia_a": signals["ia_a"], "duty_a": signals["duty_a"],
                 "hall_a": hall & 1, "hall_b": (hall >> 1) & 1, "hall_c": (hall >> 2) & 1}
    covered = 0
    starts = [int(round(f["t0"] / period_s)) for f in frames] + [len(t)]  # each frame's rows end where the next begin
    for frame, start, end in zip(frames, starts, starts[1:]):
        per_bucket = int(round(frame["dt"] / period_s))
        assert per_bucket >= 10
        for name, values in reference.items():
            lo, hi = decode(frame["cols"][name][0]), decode(frame["cols"][name][1])
            assert len(lo) == frame["n"]
            for i in range(frame["n"]):  # a plain loop over the rows: the reference
                rows = values[start + i * per_bucket: min(end, start + (i + 1) * per_bucket)]
                if i < frame["n"] - 1:
                    assert len(rows) == per_bucket
                assert lo[i] == np.float32(min(rows)) and hi[i] == np.float32(max(rows)), (name, frame["seq"], i)
        covered += 1
    # consecutive frames follow each other without a gap or an overlap
    for a, b in zip(frames, frames[1:]):
        assert a["t0"] + (a["n"] - 1) * a["dt"] < b["t0"] <= a["t0"] + a["n"] * a["dt"] + 1e-9
    assert frames[-1]["t0"] + frames[-1]["n"] * frames[-1]["dt"] >= t[-1] - 1e-9 or covered


def test_markers_for_parameter_writes_and_actions() -> None:
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.05)
        first = ask(bench, -1, ["t_s"])
        bench.set_params(kp=0.2)
        bench.run(0.05)
        later = ask(bench, first["seq"], ["t_s"])
    assert [0.0, "event", "ref 1500 rpm"] in first["markers"]
    assert [0.0, "event", "press s2"] in first["markers"]
    assert later["markers"] == [[pytest.approx(0.05), "param", "set kp=0.2"]]
    assert later["status"]["params"]["kp"] == pytest.approx(0.2, abs=1 / 32768)


def test_rows_are_taken_before_the_recorder_flushes(tmp_path: Path) -> None:
    with hilbench.Bench(target="inprocess:an1017", record=tmp_path / "run.npz") as bench:
        bench.run(0.1)
        first = ask(bench, -1, ["t_s", "speed_rpm"])
        bench.run(2.5)  # the file recorder empties its buffer every simulated second
        later = ask(bench, first["seq"], ["t_s", "speed_rpm"])
    frames = first["frames"] + later["frames"]
    assert frames[0]["t0"] == 0.0
    for a, b in zip(frames, frames[1:]):
        assert a["t0"] + (a["n"] - 1) * a["dt"] < b["t0"] <= a["t0"] + a["n"] * a["dt"] + 1e-9
    end = frames[-1]["t0"] + frames[-1]["n"] * frames[-1]["dt"]
    assert end == pytest.approx(2.6, abs=1e-3)


def test_press_and_stream_over_the_control_path() -> None:
    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.set_reference(1500)
        request = Request("press", button="s2")
        bench.session.handle_control(request, bench.t_s)  # type: ignore[union-attr]
        bench.run(0.3)
        assert request.answer is not None and request.answer[0]
        assert bench.speed_rpm > 500  # the firmware started the motor
        assert any("press s2 (ctl)" in e for e in bench.events)


@pytest.mark.parametrize("obj, reason", [
    ({"cmd": "stream", "since": -2, "columns": []}, "since"),
    ({"cmd": "stream", "since": 1.5, "columns": []}, "since"),
    ({"cmd": "stream", "since": 0, "columns": "speed_rpm"}, "columns"),
    ({"cmd": "stream", "since": 0, "columns": ["bad name"]}, "columns"),
    ({"cmd": "stream", "since": 0}, "missing"),
    ({"cmd": "press", "button": "s9"}, "button"),
])
def test_stream_and_press_request_shapes(obj: dict[str, Any], reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        validate_request(obj)
    assert validate_request({"cmd": "stream", "since": -1, "columns": ["speed_rpm"]}) == (
        "stream", {"since": -1, "columns": ["speed_rpm"]})


def test_a_failing_stream_never_ends_the_run(monkeypatch: pytest.MonkeyPatch) -> None:
    from hilbench.bench.display import DisplayStream

    with hilbench.Bench(target="inprocess:an1017") as bench:
        bench.run(0.02)
        ask(bench, -1, ["speed_rpm"])

        def broken(self: DisplayStream) -> None:
            raise RuntimeError("boom")

        monkeypatch.setattr(DisplayStream, "take", broken)
        bench.session.display.take_every_s = 0.0  # type: ignore[union-attr]  # a take at every chance
        assert bench.run(0.5)  # the take due during the run fails: the stream sleeps, the run goes on
        assert "boom" in (bench.session.display.error or "")  # type: ignore[union-attr]
        request = Request("stream", since=-1, columns=["speed_rpm"])
        bench.session.handle_control(request, bench.t_s)  # type: ignore[union-attr]
        assert request.answer is not None and not request.answer[0] and "boom" in request.answer[1]
        assert bench.run(0.05)


def test_a_run_without_a_recording_streams_a_bounded_window() -> None:
    """`hilbench run` without --record keeps no rows (keep_rows=False): a scope's request opens a
    bounded window of rows, the frames are the envelopes of the very rows a recorded twin run keeps,
    and the window is dropped when no scope has asked for a while."""
    from hilbench.bench.display import IDLE_AFTER_S
    from hilbench.bench.recorder import WindowRecorder

    columns = ["t_s", "speed_rpm", "ia_a"]
    with hilbench.Bench(target="inprocess:an1017") as twin:  # the same seed and inputs, every row kept
        twin.set_reference(1500)
        twin.press("s2")
        twin.run(2.6)
        kept = twin.signals()
    with hilbench.Bench(target="inprocess:an1017", keep_rows=False) as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.1)
        assert bench.session.recorder is None  # type: ignore[union-attr]
        first = ask(bench, -1, columns)
        window = bench.session.recorder  # type: ignore[union-attr]
        assert isinstance(window, WindowRecorder)
        bench.run(2.5)  # the window drops its rows every simulated second; the stream takes them first
        assert len(window.rows) <= window.flush_rows
        later = ask(bench, first["seq"], columns)
        display = bench.session.display  # type: ignore[union-attr]
        now = display.clock()
        display.clock = lambda: now + IDLE_AFTER_S + 1  # no scope asked for longer than the idle time
        bench.run(0.05)
        assert bench.session.recorder is None  # type: ignore[union-attr]
        summary = bench.summary()
    assert summary.recording is None and summary.rows_recorded == 0
    frames = first["frames"] + later["frames"]
    assert frames and frames[0]["t0"] == pytest.approx(0.1, abs=0.002)
    for a, b in zip(frames, frames[1:]):  # contiguous across the window's drops
        assert a["t0"] + (a["n"] - 1) * a["dt"] < b["t0"] <= a["t0"] + a["n"] * a["dt"] + 1e-9
    t = kept["t_s"]
    ends = [int(round(f["t0"] / 50e-6)) for f in frames[1:]] + [None]
    for frame, stop in zip(frames, ends):
        bucket = int(round(frame["dt"] / 50e-6))
        start = int(round(frame["t0"] / 50e-6))
        rows = kept["speed_rpm"][start:stop if stop is not None else start + frame["n"] * bucket]
        lo, hi = envelope(rows, bucket)
        assert np.allclose(decode(frame["cols"]["speed_rpm"][0]), lo, rtol=1e-6, atol=1e-3)
        assert np.allclose(decode(frame["cols"]["speed_rpm"][1]), hi, rtol=1e-6, atol=1e-3)
    end = frames[-1]["t0"] + frames[-1]["n"] * frames[-1]["dt"]
    assert end == pytest.approx(2.6, abs=1e-3) and t[-1] >= end - 1e-3


def test_a_scope_watching_a_planned_npz_run_gets_every_row(tmp_path: Path) -> None:
    """A planned NPZ run hands its chunks to the archive's thread from inside the C span; while a
    scope watches, the span leaves that to the parts, so the display takes each chunk before the
    recorder lets it go: frames follow each other without a gap over the whole run, and each
    frame's envelope holds the recording's rows."""
    with hilbench.Bench(target="inprocess:an1017", record=tmp_path / "run.npz",
                        overrides=["run.duration_s=1.5"]) as bench:
        session = bench.session
        assert session is not None and session.planned_periods == 30_000
        first = ask(bench, -1, ["t_s", "speed_rpm"])
        bench.run()  # the whole planned run in one call: its archive written as it goes
        assert bench.recorder is not None and bench.recorder.hand_over_at() > 0  # (a planned archive)
        assert not session.rows_in_c
        display = session.display
        assert display is not None
        session.end()  # the close writes the last chunk out: the display takes it first (its `closing`)
        later = display.request(first["seq"], ["t_s", "speed_rpm"], session.now_s)
    with np.load(tmp_path / "run.npz") as archive:
        speed = archive["speed_rpm"]
    frames = first["frames"] + later["frames"]
    assert frames[0]["t0"] == 0.0
    for a, b in zip(frames, frames[1:]):
        assert a["t0"] + (a["n"] - 1) * a["dt"] < b["t0"] <= a["t0"] + a["n"] * a["dt"] + 1e-9
    assert frames[-1]["t0"] + frames[-1]["n"] * frames[-1]["dt"] == pytest.approx(1.5, abs=1e-3)
    period_s = 50e-6
    starts = [int(round(f["t0"] / period_s)) for f in frames] + [len(speed)]
    for frame, start, end in zip(frames, starts, starts[1:]):  # each bucket the envelope of its rows
        lo, hi = envelope(speed[start:end], int(round(frame["dt"] / period_s)))
        assert np.array_equal(decode(frame["cols"]["speed_rpm"][0]), lo.astype(np.float32))
        assert np.array_equal(decode(frame["cols"]["speed_rpm"][1]), hi.astype(np.float32))
