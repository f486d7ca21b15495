"""Ctrl-C while the CSV writer's thread is behind (a slow disk: a 4 KiB pipe read late) loses and
repeats no row. Found by review7: a KeyboardInterrupt raised as `RowWriter.submit` returned left the
chunk counted as not handed over, so the close handed it over again (rows written twice); and an
interrupted close abandoned the queued chunks, the only copy of their rows, and a second close raised
ValueError. Each case runs in a child process (it sends itself SIGINT)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

_SETUP = """
import fcntl, os, signal, sys, threading, time
from pathlib import Path
from hilbench.bench import recorder as R

R.BACKGROUND_CHUNK_ROWS = 50
R.CSV_WRITER_MAX_ROWS = 100
rec = R.Recorder(Path(sys.argv[1]), {}, flush_rows=100_000)
rec.start()
r, w = os.pipe()
fcntl.fcntl(w, 1031, 4096)  # F_SETPIPE_SZ: a small pipe, read only after the interrupt (a slow disk)
rec._csv_writer.abandon()
rec._csv_writer = R._csv_row_writer(w, rec.rows.layout)  # the writer's thread writes to the pipe
os.close(w)
main = threading.get_ident()
out = bytearray()


def interrupt_when_waiting(read_size):
    deadline, seen = time.monotonic() + 60, 0
    while time.monotonic() < deadline and seen < 20:  # the main thread held in _hand_over_csv (submit waits)
        frame = sys._current_frames().get(main)
        seen = seen + 1 if frame is not None and frame.f_code.co_name == "_hand_over_csv" else 0
        time.sleep(0.005)
    os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C
    while chunk := os.read(r, read_size):  # the disk catches up
        out.extend(chunk)


def rows_read():
    return [line.split(",")[1] for line in out.decode().splitlines() if not line.startswith("#")]
"""

_DURING_RUN = """
watcher = threading.Thread(target=interrupt_when_waiting, args=(65536,))
watcher.start()
k = 0
try:
    while True:
        rec.append(tuple([float(k)] * R.N_COLUMNS))
        k += 1
        rec.maybe_flush()
except KeyboardInterrupt:
    pass
rec.close(f"interrupted at period {k}")
watcher.join(60)
seqs = rows_read()
print("appended", k, "written", len(seqs), "distinct", len(set(seqs)))
"""

_DURING_CLOSE = """
for k in range(140):
    rec.append(tuple([float(k)] * R.N_COLUMNS))
    rec.maybe_flush()
watcher = threading.Thread(target=interrupt_when_waiting, args=(512,))
watcher.start()
try:
    rec.close("interrupted at period 140")
except KeyboardInterrupt:
    print("interrupted close")
rec.close("again")  # the rows are on their way; a second close neither raises nor repeats them
watcher.join(60)
seqs = rows_read()
print("appended", 140, "written", len(seqs), "distinct", len(set(seqs)))
"""


def _run(body: str, tmp_path: Path) -> str:
    script = tmp_path / "case.py"
    script.write_text(textwrap.dedent(_SETUP) + textwrap.dedent(body), encoding="utf-8")
    done = subprocess.run([sys.executable, str(script), str(tmp_path / "run.csv")], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def test_ctrl_c_as_a_chunk_is_handed_over_writes_each_row_once(tmp_path: Path) -> None:
    out = _run(_DURING_RUN, tmp_path)
    appended = int(out.split("appended ")[1].split()[0])
    assert appended > 100 and f"written {appended} distinct {appended}" in out, out


def test_ctrl_c_during_the_close_loses_no_row_and_a_second_close_is_clean(tmp_path: Path) -> None:
    out = _run(_DURING_CLOSE, tmp_path)
    assert "interrupted close" in out and "appended 140 written 140 distinct 140" in out, out
