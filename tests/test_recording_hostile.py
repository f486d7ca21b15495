"""Issue 23: `hilbench report` on damaged recordings is one line and exit 6, never a traceback.
Each repro of the issue runs as the real command (memory capped)."""

from __future__ import annotations

import json
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest

import hilbench
from _hostile import assert_one_line_error, hilbench as run_hilbench
from hilbench.bench.recorder import read_recording
from hilbench.errors import RecordingError


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A short run recorded as CSV and as NPZ (in process)."""
    folder = tmp_path_factory.mktemp("rec")
    out = {}
    for suffix in ("csv", "npz"):
        path = folder / f"run.{suffix}"
        with hilbench.Bench(target="inprocess:an1017", record=path) as bench:
            bench.set_reference(1000)
            bench.press("s2")
            bench.run(0.02)
        out[suffix] = path
    return out


def _npz_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def _save(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    np.savez(path, **arrays)  # type: ignore[arg-type]
    return path


@pytest.mark.parametrize("value, shown", [(np.nan, "nan"), (np.inf, "inf")])
def test_t_s_nan_or_inf(recorded: dict[str, Path], tmp_path: Path, value: float, shown: str) -> None:
    """Repro: a recording whose t_s is NaN (ValueError) or Inf (OverflowError)."""
    arrays = _npz_arrays(recorded["npz"])
    arrays["t_s"] = arrays["t_s"].copy()
    arrays["t_s"][5] = value
    path = _save(tmp_path / "bad.npz", arrays)
    result = run_hilbench("report", str(path), "--json")
    assert_one_line_error(result, 6, "bad.npz", f"t_s is {shown} at row 5")


def test_a_string_column(recorded: dict[str, Path], tmp_path: Path) -> None:
    arrays = _npz_arrays(recorded["npz"])
    arrays["speed_rpm"] = arrays["speed_rpm"].astype(str)
    path = _save(tmp_path / "text.npz", arrays)
    assert_one_line_error(run_hilbench("report", str(path)), 6, "text.npz", "column speed_rpm holds", "not numbers")


def test_garbled_csv_metadata(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Repro: garbled `#` metadata lines in a CSV (a hello that is no table, a period that is text)."""
    text = recorded["csv"].read_text()
    for line, words in (('# target_hello: [1, 2]\n', ("metadata target_hello", "not a table")),
                        ('# period_us: "fifty"\n', ("metadata period_us", "not a positive number")),
                        ('# history_every_periods: 0\n', ("metadata history_every_periods",))):
        path = tmp_path / "garbled.csv"
        path.write_text(text + line)  # a later line of a key wins
        assert_one_line_error(run_hilbench("report", str(path)), 6, "garbled.csv", *words)


def test_a_short_column_with_plot(recorded: dict[str, Path], tmp_path: Path) -> None:
    """Repro: a column shorter than the others, with --plot."""
    arrays = _npz_arrays(recorded["npz"])
    arrays["ia_a"] = arrays["ia_a"][:-3]
    path = _save(tmp_path / "short.npz", arrays)
    result = run_hilbench("report", str(path), "--plot", str(tmp_path / "plots"))
    assert_one_line_error(result, 6, "short.npz", "column ia_a has 397 rows, t_s has 400")


def test_a_header_that_promises_more_than_the_member_holds(recorded: dict[str, Path], tmp_path: Path) -> None:
    """np.load allocates what an array's header says: a member claiming 10**12 values is refused
    before NumPy reads it."""
    path = tmp_path / "liar.npz"
    with zipfile.ZipFile(recorded["npz"]) as src, zipfile.ZipFile(path, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "ia_a.npy":
                data = data.replace(b"(400,)", b"(10**12,)".replace(b"10**12", b"1000000000000"), 1)
            dst.writestr(info, data)
    result = run_hilbench("report", str(path))
    assert_one_line_error(result, 6, "liar.npz", "member ia_a.npy promises 1000000000000 values")


def test_a_journal_header_beyond_its_limit(recorded: dict[str, Path], tmp_path: Path) -> None:
    path = tmp_path / "run.npz.journal"
    path.write_bytes(b"HBJ2" + struct.pack("<I", 2**32 - 1) + b"{}")
    with pytest.raises(RecordingError, match="a header of 4294967295 bytes, more than the limit of 16 MiB"):
        read_recording(path)


def test_t_s_that_goes_back(recorded: dict[str, Path], tmp_path: Path) -> None:
    arrays = _npz_arrays(recorded["npz"])
    arrays["t_s"] = arrays["t_s"].copy()
    arrays["t_s"][10] = 0.0
    with pytest.raises(RecordingError, match="t_s does not increase at row 10"):
        read_recording(_save(tmp_path / "back.npz", arrays))


def test_a_segment_event_with_an_infinite_time(recorded: dict[str, Path], tmp_path: Path) -> None:
    arrays = _npz_arrays(recorded["npz"])
    meta = json.loads(str(arrays["metadata"]))
    meta["events"] = ["segment: ref at inf ref 1000.0 ramp 0.0"]
    arrays["metadata"] = np.asarray(json.dumps(meta))
    with pytest.raises(RecordingError, match="event 0: segment event .* not finite"):
        read_recording(_save(tmp_path / "inf.npz", arrays))


def test_a_csv_row_beyond_the_line_limit(recorded: dict[str, Path], tmp_path: Path) -> None:
    path = tmp_path / "long.csv"
    path.write_text(recorded["csv"].read_text() + "1" * 70_000 + "\n")
    with pytest.raises(RecordingError, match="longer than 65536 characters"):
        read_recording(path)


def test_the_recordings_read_back_whole(recorded: dict[str, Path]) -> None:
    """The checks take nothing away from a good recording: both formats read the same rows."""
    a, b = read_recording(recorded["csv"]), read_recording(recorded["npz"])
    assert a.n_rows == b.n_rows == 400
    np.testing.assert_allclose(a.columns["speed_rpm"], b.columns["speed_rpm"], atol=1e-3)
