"""The session's lockstep span in C (hilbench/bench/_span.c) records what the Python loop records:
column for column, with live writes, sensor faults and buttons at the parts' periods, the
comparator's trip (its period goes back to Python), and an error inside a span."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import TextIO

import numpy as np
import pytest

import hilbench
from hilbench.bench.session import Session, _span
from hilbench.plant import model

ROOT = Path(__file__).resolve().parent.parent
RANDOM = ROOT / "tests" / "golden" / "random_an1017.toml"
SERVO = ROOT / "bench_configs" / "servo_200w.toml"

pytestmark = pytest.mark.skipif(_span is None or model._CPlant is None, reason="the C span is not built")


def _run(mode: str, target: str, config: Path | None, scenario: Path | None, seconds: float,
         overrides: tuple[str, ...] = ()) -> tuple[dict[str, np.ndarray], tuple[str, ...], int]:
    """One run: mode "c" (the C span), "python" (the tight Python loop), "readable" (period by period).
    Returns the columns, the events and how many periods the C span ran."""
    cfg = hilbench.load_config(config, [f'link.target="{target}"', f"run.duration_s={seconds}", *overrides],
                               scenario_path=scenario)
    spans: list = []
    with hilbench.Bench(cfg, scenario=True) as bench:
        session = bench.session
        assert session is not None
        session.c_span = mode == "c"  # type: ignore[misc]
        session._readable_periods = mode == "readable"  # type: ignore[attr-defined]
        make = session._c_span
        session._c_span = lambda rows: spans.append(make(rows)) or spans[-1]  # type: ignore[method-assign]
        bench.run()
        signals = bench.signals()
        columns = {name: np.asarray(signals[name]) for name in signals}
        events = bench.events
    periods = sum(span.k for span in spans if span is not None)  # lower bound: k where each runner's last span stopped
    return columns, events, periods


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> list[str]:
    assert a.keys() == b.keys() and len(a["t_s"]) > 1000
    return [name for name in a if not np.array_equal(a[name], b[name], equal_nan=True)]


@pytest.mark.parametrize("target, config, scenario, seconds, overrides", [
    ("inprocess:an1017", None, RANDOM, 1.7, ()),  # live writes, every sensor fault kind, load, bus, buttons
    ("inprocess:an1017", None, None, 0.5, ()),  # the default scenario
    # a comparator that trips under load: the trip's periods go back to Python, the stop re-arms it
    ("inprocess:an1017", None, RANDOM, 0.8, ("protection.overcurrent_a=0.35",)),
    ("inprocess:foc", SERVO, None, 0.6, ()),
    # protocol 3: 1 ms periods carry several hall edges each, which the AN1017 runtime reads in time
    ("inprocess:an1017", None, None, 1.5, ("link.period_us=1000",)),
])
def test_the_c_span_records_what_the_python_loop_records(target: str, config: Path | None, scenario: Path | None,
                                                         seconds: float, overrides: tuple[str, ...]) -> None:
    c, c_events, c_periods = _run("c", target, config, scenario, seconds, overrides)
    py, py_events, py_periods = _run("python", target, config, scenario, seconds, overrides)
    readable, readable_events, _ = _run("readable", target, config, scenario, seconds, overrides)
    assert not _same(c, py)
    assert not _same(c, readable)
    assert c_events == py_events == readable_events
    assert py_periods == 0
    assert c_periods > 0  # the C span ran
    if any("overcurrent" in o for o in overrides):
        assert any("comparator tripped" in e for e in c_events)


def test_an_error_inside_a_span_leaves_what_the_python_loop_leaves(monkeypatch: pytest.MonkeyPatch) -> None:
    """The plant's Python step raising in the middle of a span: the same period, the same rows
    (the failing period's own fields written, the plant's not), the same Drive and edge after it."""
    results = []
    for mode in ("c", "python"):
        calls = {"n": 0}
        step_py = model.Plant._step_py

        def failing(self: model.Plant, *args: float) -> None:
            calls["n"] += 1
            if calls["n"] == 4321:
                raise RuntimeError("boom")
            step_py(self, *args)

        monkeypatch.setattr(model.Plant, "_step_py", failing)
        cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.5"])
        with hilbench.Bench(cfg, scenario=True) as bench:
            session = bench.session
            assert isinstance(session, Session)
            session.c_span = mode == "c"  # type: ignore[misc]
            session.plant.track_energy = True  # every step through Plant._step_py
            with pytest.raises(RuntimeError, match="boom"):
                bench.run()
            recorder = session.recorder
            results.append((session.periods_done, session.drive, session._edge_s, session._hall_before, bytes(recorder.rows.data)
                            if recorder is not None and hasattr(recorder, "rows") else b""))
        monkeypatch.undo()
    assert results[0][0] > 100
    assert results[0] == results[1]


def test_a_plant_whose_sense_is_its_own_is_stepped_by_the_python_loop() -> None:
    """An instance (or a subclass) with its own `sense` in front of the C core's: the C span would
    read the C core's sensors past it, so the loop stays Python and records what the override reads."""
    halls = []
    for mode in ("c", "python"):
        cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.1"])
        with hilbench.Bench(cfg, scenario=True) as bench:
            session = bench.session
            assert isinstance(session, Session)
            session.c_span = mode == "c"  # type: ignore[misc]
            plant = session.plant
            c_sense = plant.sense

            def stuck_a(roles: tuple[int, ...], c_sense=c_sense) -> tuple:  # hall A stuck high at the sensor
                hall, tripped, index, count, adc = c_sense(roles)
                return hall | 1, tripped, index, count, adc

            plant.sense = stuck_a  # type: ignore[method-assign]
            assert plant.span_api() is None
            bench.run()
            halls.append(np.asarray(bench.signals()["hall"]))
    assert np.all(halls[0] % 2 == 1)  # what the override reads, every period
    assert np.array_equal(halls[0], halls[1])


def _bare_span(session: Session, rows: bytearray | None, rtt_append: object) -> object:
    """A C span over this session's plant and target (no recorder's row check)."""
    hello = session.hello
    assert hello is not None
    target_api, core = session.target.span_core()  # type: ignore[attr-defined]
    return _span.Span(plant=session.plant, plant_api=session.plant.span_api(), core=core, target_api=target_api,
                      roles=tuple(hello.adc_roles), edge_limit=session.options.period_us * 10 - 1,
                      read_index=session.profile.has("encoder"), rows=rows, n_telemetry=len(hello.telemetry_ids),
                      host_ref=False, rtt_append=rtt_append, max_edges=session.target_max_edges())


@pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="no interval timer here")
def test_ctrl_c_ends_a_long_span_between_periods_with_no_python_inside_it() -> None:
    """A span with no Python call in it (the servo's plant draws no noise, no round-trip sample)
    still stops at Ctrl-C: at a period's start, its rows whole, as the Python loop stops."""
    cfg = hilbench.load_config(SERVO, ['link.target="inprocess:foc"', "run.duration_s=0.01"])
    with hilbench.Bench(cfg) as bench:
        session = bench.session
        assert isinstance(session, Session)
        rows = bytearray()
        span = _bare_span(session, rows, None)
        stop = 5_000_000  # seconds of periods: the alarm comes long before the end

        def interrupt(signum: int, frame: object) -> None:
            raise KeyboardInterrupt

        before = signal.signal(signal.SIGALRM, interrupt)
        signal.setitimer(signal.ITIMER_REAL, 0.05)
        try:
            with pytest.raises(KeyboardInterrupt):
                span.run(0, stop, 0, 0.0, None, None, 0)  # type: ignore[attr-defined]
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGALRM, before)
        k = span.k  # type: ignore[attr-defined]
        assert 0 < k < stop and k % 64 == 0  # at a period's start
        assert len(rows) == k * span.row_bytes  # type: ignore[attr-defined]
        assert span.drive is not None and span.drive[0] == (k - 1) & 0xFF  # type: ignore[attr-defined]


def test_a_span_cannot_run_inside_itself_nor_uninitialised() -> None:
    """A Python call inside a span (its round-trip sample) that runs the span again would resize the
    rows under the running one: refused. A Span never initialised is refused, not dereferenced."""
    with pytest.raises(RuntimeError, match="not initialised"):
        _span.Span.__new__(_span.Span).run(0, 1, 0, 0.0, None, None, 0)
    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.01"])
    with hilbench.Bench(cfg) as bench:
        session = bench.session
        assert isinstance(session, Session)
        rows = bytearray()
        refused = []

        def again(rtt_s: float) -> None:  # swallows the refusal: the outer run goes on
            try:
                span.run(10_000, 10_100, 0, 0.0, None, None, 0)  # type: ignore[attr-defined]
            except RuntimeError as exc:
                refused.append(str(exc))

        span = _bare_span(session, rows, again)
        assert span.run(0, 200, 0, 0.0, None, None, 0) == 200  # type: ignore[attr-defined]
        assert len(refused) == 4 and "already running" in refused[0]  # periods 0, 64, 128, 192
        assert len(rows) == 200 * span.row_bytes  # type: ignore[attr-defined]
        size = span.row_bytes  # type: ignore[attr-defined]
        assert [int.from_bytes(rows[i * size:i * size + 8], "little") for i in range(200)] == list(range(200))


def _busy_scenario(path: Path) -> Path:
    """An event in nearly every period for 400 events: faults that start and end within a period or
    two, reference, load, bus, gain and button changes (spans of zero, one or two periods)."""
    import random

    draw = random.Random(5)
    period_s = 50e-6
    lines = ['[[scenario]]\nat_s = 0.0\npress = "s2"\n', '[[scenario]]\nat_s = 0.005\nref_rpm = 1500.0\nramp_s = 0.1\n']
    t_s = 0.15
    for _ in range(400):
        t_s += period_s * draw.choice([1, 1, 1, 2, 0.5])
        at, c = f"[[scenario]]\nat_s = {t_s:.7f}\n", draw.random()
        if c < 0.3:
            kind = draw.choice(["hall_a_high", "hall_b_low", "hall_missing_edge", "adc_offset", "clear"])
            lasting = kind != "clear" and draw.random() < 0.7
            lines.append(at + f'fault = "{kind}"\n' + (f"fault_duration_s = {period_s * draw.choice([0.5, 1, 2]):.7f}\n"
                                                       if lasting else ""))
        elif c < 0.5:
            lines.append(at + f"ref_rpm = {draw.uniform(500, 2500):.1f}\n")
        elif c < 0.65:
            lines.append(at + f"load_nm = {draw.uniform(0, 0.02):.4f}\n")
        elif c < 0.8:
            lines.append(at + f"set = {{ kp = {draw.uniform(0.1, 0.3):.3f} }}\n")
        elif c < 0.9:
            lines.append(at + f"vbus_v = {draw.uniform(20, 24):.2f}\n")
        else:
            lines.append(at + 'press = "s2"\n')
    path.write_text("".join(lines))
    return path


def test_an_event_in_nearly_every_period_records_what_the_python_loop_records(tmp_path: Path) -> None:
    scenario = _busy_scenario(tmp_path / "busy.toml")
    c, c_events, c_periods = _run("c", "inprocess:an1017", None, scenario, 0.2)
    py, py_events, _ = _run("python", "inprocess:an1017", None, scenario, 0.2)
    readable, readable_events, _ = _run("readable", "inprocess:an1017", None, scenario, 0.2)
    assert not _same(c, py) and not _same(c, readable)
    assert c_events == py_events == readable_events and len(c_events) > 400
    assert c_periods > 0


def test_the_c_span_builds_the_edges_sensing_builds() -> None:
    """Protocol 3's Sensors.edges in C (every hall edge and index mark of a period, the halls in force
    at a mark, time-ordered; None past the target's max_edges) equal hilbench.bench.sensing's, period
    after period of a coasting servo at long periods: several hall edges and index marks a period."""
    from hilbench.bench.sensing import hall_edges, with_index_marks
    from hilbench.protocol import OutputMode

    cfg = hilbench.load_config(SERVO, ['link.target="inprocess:foc"', "link.period_us=4000", "run.duration_s=0.1"])
    with hilbench.Bench(cfg, scenario=True) as bench:
        session = bench.session
        assert session is not None and session.profile.has("encoder")
        span, plant = session._c_span(None), session.plant
        assert span is not None
        limit, most = session.options.period_us * 10 - 1, session.target_max_edges()
        seen = {"marks": 0, "several": 0, "over": 0}
        for speed_rpm in (300.0, 1500.0, 3000.0, 6000.0, 30000.0):  # the last brakes through 16 edges
            plant.w_m = speed_rpm / model.RPM_PER_RAD_S
            hall_before = plant.hall_bits
            for _ in range(40):
                edge_s = plant.advance(0, 0, 0, int(OutputMode.OFF))
                index = plant.sense(())[2]
                edges = hall_edges(plant.edges(), limit) if edge_s is not None else ()
                if index:
                    edges = with_index_marks(edges, plant.index_marks(), limit, hall_before)
                    seen["marks"] += 1
                expected = None if len(edges) > most or len(plant.edges()) > most else edges
                seen["several"] += len(edges) > 2
                seen["over"] += expected is None
                assert span.edges(edge_s is not None, hall_before) == expected
                hall_before = plant.hall_bits
        assert seen["marks"] > 10 and seen["several"] > 10 and seen["over"] > 0


def _summary_run(mode: str, config: Path | None, scenario: Path | None, seconds: float, overrides: tuple[str, ...],
                 record: Path | None, observe: bool) -> tuple:
    """One run's history, segments, fault figures, periods, events and recording (mode as `_run`)."""
    cfg = hilbench.load_config(config, ['link.target="inprocess:an1017"' if config is None else 'link.target="inprocess:foc"',
                                        f"run.duration_s={seconds}", *overrides], scenario_path=scenario)
    snapshots: list[tuple] = []
    observer = (lambda snap: snapshots.append((snap.period, snap.measured_rpm, snap.speed_rpm))) if observe else None
    with hilbench.Bench(cfg, scenario=True, record=record, observer=observer) as bench:
        session = bench.session
        assert session is not None
        session.c_span = mode == "c"  # type: ignore[misc]
        session._readable_periods = mode == "readable"  # type: ignore[attr-defined]
        try:
            bench.run()
        except hilbench.HilbenchError as exc:
            ended = str(exc)
        else:
            ended = ""
        summary = session.summary
        figures = (list(session.history), repr(summary.segments), summary.fault_code, summary.fault_first_s,
                   summary.fault_last_s, session.periods_done, summary.end_reason, session.live.guard_ref_rpm, ended,
                   snapshots, bench.events)
        in_c = session._span_samples is not None
    data = hilbench.read_recording(record) if record is not None else None
    columns = {k: v for k, v in data.columns.items()} if data is not None else {}
    return figures, columns, in_c


@pytest.mark.parametrize("config, scenario, seconds, overrides, observe", [
    (None, RANDOM, 1.7, (), False),  # live writes, sensor faults (their periods in Python), faults of the firmware
    (None, None, 0.6, (), True),  # an observer: the part at every observe period
    (None, None, 0.9, ("protection.overspeed_rpm=1100",), False),  # the limit at a sample in the C span
    (None, RANDOM, 0.8, ("protection.overcurrent_a=0.35",), False),  # comparator trips: periods C leaves to Python
    (None, RANDOM, 0.8, ("protection.overcurrent_a=0.35",), "at a trip"),  # and one of them an observe period
    (SERVO, None, 0.6, (), False),
])
def test_the_c_span_samples_the_history_the_python_loop_samples(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                               config: Path | None, scenario: Path | None,
                                                               seconds: float, overrides: tuple[str, ...],
                                                               observe: bool | str) -> None:
    """The history samples the C span takes and hands over in bulk give the Python loop's history,
    segments, fault figures, guard reference, snapshots, end (an overspeed at its very period) and
    recording (its flushes at the same periods: a small chunk). "at a trip": the first comparator
    trip's period (one C leaves to Python) is a history and an observe period, observed once."""
    if observe == "at a trip":
        trip_k = _first_trip(config, scenario, seconds, overrides)
        _observe_at(monkeypatch, trip_k)
    runs = {}
    for mode in ("c", "python", "readable"):
        runs[mode] = _summary_run(mode, config, scenario, seconds, overrides, tmp_path / f"{mode}.npz", observe)
    assert runs["c"][2] and not runs["python"][2]  # the C span took the samples
    for mode in ("python", "readable"):
        assert runs["c"][0] == runs[mode][0]
        assert not _same(runs["c"][1], runs[mode][1])
    figures = runs["c"][0]
    assert len(figures[0]) > 20
    if any("overspeed" in o for o in overrides):
        assert "overspeed" in figures[8] and figures[5] % 20 == 0
    if observe == "at a trip":
        assert [snap[0] for snap in figures[9]].count(trip_k) == 1


def _first_trip(config: Path | None, scenario: Path | None, seconds: float, overrides: tuple[str, ...]) -> int:
    """The period of the run's first comparator trip (the Python loop's)."""
    cfg = hilbench.load_config(config, ['link.target="inprocess:an1017"', f"run.duration_s={seconds}", *overrides],
                               scenario_path=scenario)
    trips: list[int] = []
    with hilbench.Bench(cfg, scenario=True) as bench:
        session = bench.session
        assert session is not None
        session.c_span = False  # type: ignore[misc]
        comparator = session._comparator
        session._comparator = lambda k: (trips.append(k), comparator(k))  # type: ignore[method-assign]
        try:
            bench.run()
        except hilbench.HilbenchError:
            pass
    assert trips
    return trips[0]


def _observe_at(monkeypatch: pytest.MonkeyPatch, k: int) -> None:
    """Sessions whose history and observe periods both fall on period k."""
    import dataclasses
    import math

    from hilbench.bench import settings

    options = settings.session_options
    monkeypatch.setattr(settings, "session_options", lambda cfg: dataclasses.replace(
        options(cfg), history_every_periods=math.gcd(k, 20), observe_every_periods=k))


def test_a_plant_capsule_of_the_api_before_speed_rad_s_is_refused() -> None:
    """hb_plant_api_t gained speed_rad_s (the history samples): its capsule's name carries the
    version, so a plant module built before it (a stale build) is refused by the span by name,
    never read past the end of its older struct."""
    import ctypes

    cfg = hilbench.load_config(None, ['link.target="inprocess:an1017"', "run.duration_s=0.01"])
    with hilbench.Bench(cfg, scenario=True) as bench:
        session = bench.session
        assert isinstance(session, Session)
        capsule = session.plant.span_api()
        name = repr(capsule).split('"')[1]
        assert name == "hilbench.plant.span_api.v2"
        get_pointer, new_capsule = ctypes.pythonapi.PyCapsule_GetPointer, ctypes.pythonapi.PyCapsule_New
        get_pointer.restype, get_pointer.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
        new_capsule.restype, new_capsule.argtypes = ctypes.py_object, [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_void_p]
        old_name = ctypes.c_char_p(b"hilbench.plant.span_api")  # kept alive: the capsule holds its pointer
        old = new_capsule(get_pointer(capsule, name.encode()), old_name, None)
        session.plant.span_api = lambda: old  # type: ignore[method-assign]
        with pytest.raises(ValueError, match="incorrect name"):
            _bare_span(session, None, None)
        session.plant.span_api = lambda: capsule  # type: ignore[method-assign]
        assert _bare_span(session, None, None) is not None


@pytest.mark.parametrize("config, scenario, seconds", [
    (None, None, 1.0),  # the default scenario: events at 0, 10 ms (S2), 12 ms (its release) and the end
    (None, RANDOM, 1.7),  # live writes, sensor faults (their periods in Python), markers on the rows of events
    (SERVO, None, 0.6),
])
def test_the_c_span_hands_the_recorders_chunks_over_and_the_archive_is_the_python_loops(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, config: Path | None, scenario: Path | None, seconds: float) -> None:
    """A planned NPZ run: the C span hands each chunk to the recorder from inside the span
    (`Recorder.span_rows`), so the recorder's writes end no span; the archive is the Python loop's
    (which flushes at the parts' periods) byte for byte."""
    from hilbench.bench.recorder import Recorder

    if npzwriter_missing():
        pytest.skip("the compiled column writer is not built (no archive is written while the run goes on)")
    handed: list[int] = []  # (those of the mode "c")
    span_rows = Recorder.span_rows
    monkeypatch.setattr(Recorder, "span_rows", lambda self, n: handed.append(n) or span_rows(self, n))
    spans = {}
    for mode in ("c", "c, the parts flushing", "python"):
        cfg = hilbench.load_config(config, ['link.target="inprocess:an1017"' if config is None else 'link.target="inprocess:foc"',
                                            f"run.duration_s={seconds}"], scenario_path=scenario)
        with hilbench.Bench(cfg, scenario=True, record=tmp_path / f"{mode}.npz") as bench:
            session = bench.session
            assert session is not None
            session.c_span = mode != "python"  # type: ignore[misc]
            if mode == "c, the parts flushing":  # as before the spans handed over: a chunk ends a span
                monkeypatch.setattr(bench.session.recorder, "hand_over_at", lambda: 0)
            runs: list[int] = []
            make = session._c_span

            def counting(rows: bytearray | None, **kw: bool) -> object:
                span = make(rows, **kw)
                if span is None:
                    return None

                class Counted:  # the span, its runs counted
                    def __getattr__(self, name: str) -> object:
                        return getattr(span, name)

                    def run(self, *args: object) -> int:
                        runs.append(1)
                        return span.run(*args)
                return Counted()
            session._c_span = counting  # type: ignore[method-assign]
            bench.run()
        spans[mode] = len(runs)
    archive = (tmp_path / "c.npz").read_bytes()
    assert archive == (tmp_path / "python.npz").read_bytes() == (tmp_path / "c, the parts flushing.npz").read_bytes()
    n_rows = hilbench.read_recording(tmp_path / "c.npz").n_rows
    assert handed and sum(handed) < n_rows  # inside the spans (a sensor fault's periods: the parts'); the close takes the last
    assert spans["python"] == 0
    assert spans["c"] < spans["c, the parts flushing"]  # a chunk handed over ends no span


def npzwriter_missing() -> bool:
    from hilbench.bench import npzwriter

    return npzwriter._npzcolumns is None


@pytest.mark.parametrize("c_span, suffix", [(True, "npz"), (False, "npz"), (False, "csv")],
                         ids=["c span hand-over", "python loop flush", "python loop csv"])
def test_a_ctrl_c_just_after_a_chunk_is_written_loses_no_row_and_writes_none_twice(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, c_span: bool, suffix: str) -> None:
    """A Ctrl-C serviced after a chunk was written and counted, before the buffer let it go (the
    C span's hand-over, the Python loop's flush): the close writes every row once."""
    from hilbench.bench.recorder import Recorder

    if npzwriter_missing() and suffix == "npz":
        pytest.skip("the compiled column writer is not built (no archive is written while the run goes on)")
    write_out = Recorder._write_out
    chunks: list[int] = []

    def interrupted_after_the_second(self: Recorder, n_rows: int) -> None:
        write_out(self, n_rows)
        if n_rows and len(chunks) < 2:
            chunks.append(n_rows)
            if len(chunks) == 2:
                raise KeyboardInterrupt  # after rows_written counts them
    monkeypatch.setattr(Recorder, "_write_out", interrupted_after_the_second)
    out = tmp_path / f"run.{suffix}"
    seconds = 1.5 if suffix == "npz" else 2.5  # (a CSV's chunks are its flushes: one a simulated second)
    with hilbench.Bench(target="inprocess:an1017", record=out, overrides=[f"run.duration_s={seconds}"]) as bench:
        session = bench.session
        assert session is not None and session.recorder is not None
        session.c_span = c_span  # type: ignore[misc]
        with pytest.raises(KeyboardInterrupt):
            bench.run()
        periods = session.periods_done  # (the Python loop's flush is an after-part: its period's row is in)
    t_s = _each_row_and_event_once(out, periods)
    assert len(t_s) > sum(chunks) // 2, (len(t_s), periods, chunks)


def _each_row_and_event_once(out: Path, periods: int) -> np.ndarray:
    """The recording after an interrupted run: every event once, each period's row once and none
    missing (the row of the period the Ctrl-C came in may be there); its t_s column."""
    recording = hilbench.read_recording(out)
    assert recording.events and len(set(recording.events)) == len(recording.events), recording.events  # once each
    t_s = np.asarray(recording.columns["t_s"])
    assert len(t_s) in (periods, periods + 1), (len(t_s), periods)
    assert t_s[0] == 0.0 and np.allclose(np.diff(t_s), 50e-6)  # each period's row once, none missing
    return t_s


def test_a_ctrl_c_as_the_reference_csv_writes_a_chunk_writes_no_row_twice(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """A CSV without its C writer's thread (the reference): a Ctrl-C is raised as the file's write of
    a chunk returns (CPython delivers it when the call ends; a file's write runs to its end), and the
    close writes every row once (it wrote that chunk a second time, after its rows)."""
    from hilbench.bench import recorder as recorder_module
    from hilbench.bench.recorder import Recorder

    monkeypatch.setattr(recorder_module, "_csvrows", None)
    writes: list[int] = []

    class InterruptedSecondWrite:
        """The recorder's CSV file, its second write interrupted as it returns (where CPython raises)."""

        def __init__(self, file: TextIO) -> None:
            self.file = file

        def write(self, text: str) -> int:
            done = self.file.write(text)
            writes.append(len(text))
            if len(writes) == 2:
                raise KeyboardInterrupt
            return done

        def __getattr__(self, name: str) -> object:
            return getattr(self.file, name)

    start = Recorder.start

    def started(self: Recorder, *args: object, **kwargs: object) -> None:
        start(self, *args, **kwargs)  # type: ignore[arg-type]
        self._file = InterruptedSecondWrite(self._file)  # (the header written: the chunks' writes from here)

    monkeypatch.setattr(Recorder, "start", started)
    out = tmp_path / "run.csv"
    with hilbench.Bench(target="inprocess:an1017", record=out, overrides=["run.duration_s=2.5"]) as bench:
        session = bench.session
        assert session is not None and session.recorder is not None and session.recorder._csv_writer is None
        with pytest.raises(KeyboardInterrupt):
            bench.run()
        periods = session.periods_done
    assert len(writes) >= 3, writes  # two chunks, then the close's
    _each_row_and_event_once(out, periods)
