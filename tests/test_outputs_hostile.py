"""The second hostile-input audit's repros: other outputs onto a running recording (a step's or a
sweep's CSV, a plot, a save onto an NPZ's side files, through symlinks), hangs (a local cluster of
no workers, the close of a link at a few baud), tracebacks (a 400-digit int in a recording or a
sweep store, `ctl save /`, a control socket that is not a session's) and long quoted values."""

from __future__ import annotations

import json
import os
import socket
import threading
from pathlib import Path

import pytest

from hilbench.bench.recorder import Recorder
from hilbench.errors import ConfigError, RecordingError, TargetError

from _hostile import assert_one_line_error, hilbench


def _row(k: int) -> tuple:
    from hilbench.bench.recorder import COLUMNS

    return tuple([k * 5e-5, k] + [0] * (len(COLUMNS) - 2))


def _running_npz(path: Path) -> Recorder:
    rec = Recorder(path, {}, flush_rows=4)
    for k in range(10):
        rec.append(_row(k))
        rec.maybe_flush()
    return rec


@pytest.mark.parametrize("name", ["run.npz", "run.npz.journal", "run.npz.journal.events", "run.npz.tmp.npz"])
def test_no_output_lands_on_a_running_npz_recording_by_any_of_its_names(name: str, tmp_path: Path) -> None:
    """Repro: `ctl save run.npz.journal.events` replaced a running NPZ's events (lost after a kill);
    `step --csv run.npz.journal` cut its journal to 479 bytes; a plot through a symlink wrote a PNG
    into a recording. Every output goes through `open_output`, refused by any name or link."""
    from hilbench.bench.outputs import open_output
    from hilbench.bench.tuning import write_fragment

    rec = _running_npz(tmp_path / "run.npz")
    rec.event("press s2")
    rec.flush()
    (tmp_path / "link.png").symlink_to(tmp_path / name)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file() and not p.is_symlink()}
    for target in (tmp_path / name, tmp_path / "link.png"):
        with pytest.raises(OSError, match="another process is writing it"):
            write_fragment(target, "[target]\nkp = 0.1\n")
        with pytest.raises(OSError, match="another process is writing it"), open_output(target, binary=True):
            pass
    assert before == {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file() and not p.is_symlink()}
    rec.close()
    write_fragment(tmp_path / "run.npz.journal.events", "free again\n")  # (nothing records there now)


def test_step_csv_onto_a_running_csv_recording_is_refused(tmp_path: Path) -> None:
    """Repro: `step --csv live.csv` beside a run recording live.csv emptied it and exited 0. Refused
    before the steps run (their results would be lost at the end)."""
    live = tmp_path / "live.csv"
    rec = Recorder(live, {})
    rec.append(_row(0))
    rec.flush()
    kept = live.read_bytes()
    result = hilbench("step", "--settle", "0.05", "--after", "0.05", "--csv", str(live), cwd=tmp_path)
    assert_one_line_error(result, 2, "--csv", "live.csv", "another process is writing it")
    rec.close()
    assert live.read_bytes().startswith(kept)


def test_a_step_csv_to_a_fifo_with_no_reader_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Repro: `step --csv fifo` (and `sweep --csv`) hung for ever in open()."""
    from hilbench.bench import fileio
    from hilbench.bench.outputs import open_output

    monkeypatch.setattr(fileio, "FIFO_READER_WAIT_S", 0.05)
    fifo = tmp_path / "out.csv"
    os.mkfifo(fifo)
    with pytest.raises(OSError, match="a FIFO with no reader within 0.05 s"), open_output(fifo):
        pass


def test_an_output_write_error_names_the_file(tmp_path: Path) -> None:
    """Repro: `ctl save /dev/full` said only "No space left on device"."""
    from hilbench.bench.tuning import write_fragment

    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full here")
    with pytest.raises(OSError) as failed:
        write_fragment("/dev/full", "[target]\nkp = 0.1\n")
    assert failed.value.filename == "/dev/full" and failed.value.strerror


@pytest.mark.parametrize("path", ["/", "."])
def test_a_save_onto_a_folder_with_no_name_is_a_file_error(path: str) -> None:
    """Repro: `ctl save /` was a ValueError traceback (an empty name has no journal name)."""
    from hilbench.bench.tuning import write_fragment

    with pytest.raises(IsADirectoryError):
        write_fragment(path, "[target]\nkp = 0.1\n")


@pytest.mark.parametrize("workers", ["0", "-1", "100000"])
def test_a_local_dask_cluster_of_no_workers_is_refused(workers: str) -> None:
    """Repro: `sweep --executor local-dask:0` waited for ever for a worker."""
    from hilbench.bench.executors import open_executor

    with pytest.raises(ConfigError, match="expected local-dask:N with N a number of workers, 1 to 256"):
        with open_executor(f"local-dask:{workers}", None):
            pass


def test_a_400_digit_number_in_a_recording_or_a_sweep_store_is_one_line(tmp_path: Path) -> None:
    """Repro: `# period_us: 1000…0` (400 digits) in a CSV's header, or `itae` of 400 digits in a
    sweep store, was an OverflowError traceback."""
    from hilbench.bench.column_chunks import recording_chunks
    from hilbench.bench.recording_head import read_head

    rec = Recorder(tmp_path / "r.csv", {"period_us": 50})
    rec.append(_row(0))
    rec.close()
    text = (tmp_path / "r.csv").read_text()
    bad = tmp_path / "bad.csv"
    bad.write_text(text.replace("# period_us: 50", "# period_us: 1" + "0" * 400))
    with pytest.raises(RecordingError, match="period_us"):
        read_head(recording_chunks(bad))
    from hilbench.bench.sweep import _store_row
    from hilbench.bench.metrics import StepMetrics
    import dataclasses

    metrics = {f.name: 1 for f in dataclasses.fields(StepMetrics)}
    metrics["itae"] = 10**400
    with pytest.raises(RecordingError, match=r"s\.jsonl:1: metrics itae is .*, not a number"):
        _store_row(Path("s.jsonl"), 1, {"index": 0, "stalled": False, "cases": 1, "metrics": metrics}, 4)


@pytest.mark.parametrize("reply", [
    {"ok": True},
    {"ok": True, "data": [1]},
    {"ok": True, "data": {"params": "x", "tunable": []}},
    {"ok": True, "data": {"params": {"kp": 0.1}, "tunable": 5}},
    {"ok": True, "data": {"params": {"kp\n[motor]": 1.0}, "tunable": None}},
    {"ok": True, "data": {"params": {"kp": 10**400}, "tunable": ["kp"]}},
])
def test_ctl_save_from_a_socket_that_is_not_a_session_is_one_line(reply: dict, tmp_path: Path) -> None:
    """Repro: `ctl --socket fake.sock save g.toml` was a KeyError/AttributeError/TypeError traceback;
    a name with a line break was written into the TOML as it came."""
    from hilbench.bench.tuning import saved_fragment

    with pytest.raises(TargetError, match="ctl save: the session's `get` reply"):
        saved_fragment(reply.get("data"))
    path = tmp_path / "f.sock"
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(path))
    listener.listen()

    def answer() -> None:
        conn, _ = listener.accept()
        with conn:
            conn.recv(9999)
            conn.sendall(json.dumps(reply).encode() + b"\n")

    server = threading.Thread(target=answer, daemon=True)
    server.start()
    try:
        result = hilbench("ctl", "--socket", str(path), "save", str(tmp_path / "g.toml"), timeout_s=60)
    finally:
        server.join(timeout=30)
        listener.close()
    assert_one_line_error(result, 5, "ctl save: the session's `get` reply")
    assert not (tmp_path / "g.toml").exists()


def test_a_long_value_in_any_message_is_cut() -> None:
    """Repro: `step --gains <100 kB>` (and a dozen options) printed 100 kB on one line; click's
    own usage errors (`link-test --periods <100 kB>`) too."""
    long = "a" * 100_000
    for args in (("step", "--gains", long), ("link-test", "--periods", long)):
        result = hilbench(*args)
        assert result.returncode == 2 and len(result.stderr) < 1500, len(result.stderr)
        assert "aaa..." in result.stderr or "characters left out" in result.stderr  # (the word cut, or the line)


def test_a_recording_onto_a_running_npz_recordings_side_file_is_refused(tmp_path: Path) -> None:
    """Review: `run --record run.npz.tmp.npz` beside a run recording run.npz would write its archive
    over the first run's temporary one (a name no lock covered)."""
    rec = _running_npz(tmp_path / "run.npz")
    with pytest.raises(RecordingError, match=r"run\.npz\.tmp\.npz: cannot write \(another process is writing"):
        Recorder(tmp_path / "run.npz.tmp.npz", {})
    assert not (tmp_path / "run.npz.tmp.npz.journal").exists()
    rec.close()


def test_a_plot_takes_the_format_its_suffix_names(tmp_path: Path) -> None:
    """Review: writing the figure through a buffer made `step --plot steps.pdf` a PNG named .pdf."""
    pytest.importorskip("matplotlib")
    from hilbench.ui.plots import _pyplot, save_png

    plt = _pyplot()
    for name, magic in (("a.pdf", b"%PDF"), ("a.png", b"\x89PNG"), ("a", b"\x89PNG"), ("a.svg", b"<?xml")):
        fig, _ = plt.subplots()
        save_png(fig, tmp_path / name)
        plt.close(fig)
        assert (tmp_path / name).read_bytes().startswith(magic), name
    result = hilbench("step", "--plot", str(tmp_path / "x.gif"))
    assert_one_line_error(result, 2, "--plot", "x.gif", "png, pdf, svg")
