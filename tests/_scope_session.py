"""A lockstep in-process session running in a thread with a control socket, for the scope's tests."""

from __future__ import annotations

import contextlib
import tempfile
import threading
from pathlib import Path
from typing import Iterator

import hilbench
from hilbench.bench.control import ControlServer


@contextlib.contextmanager
def running_session(chunk_s: float = 0.01, pause_s: float = 0.004, keep_rows: bool = True) -> Iterator[Path]:
    """Yields the control socket's path of an AN1017 session at 1500 rpm, running until the block ends.
    The session runs ``chunk_s`` simulated seconds, then rests ``pause_s`` (about twice real time,
    so its in-memory recording stays small however long a test takes). ``keep_rows=False``: no rows
    kept, as `hilbench run` without --record."""
    with tempfile.TemporaryDirectory(prefix="hb-scope-", ignore_cleanup_errors=True) as folder, \
            ControlServer(Path(folder) / "ctl" / "ctl.sock", publish=False) as control:  # both go however it ends
        stop = threading.Event()
        failure: list[BaseException] = []

        def drive() -> None:
            try:
                with hilbench.Bench(target="inprocess:an1017", control=control, keep_rows=keep_rows) as bench:
                    bench.set_reference(1500)
                    bench.press("s2")
                    while not stop.is_set() and bench.run(chunk_s):
                        stop.wait(pause_s)  # pacing, not synchronisation
            except BaseException as exc:  # noqa: BLE001 - reported to the test
                failure.append(exc)

        thread = threading.Thread(target=drive, name="scope-test-session", daemon=True)
        try:
            thread.start()
            yield control.path
        finally:
            stop.set()
            if thread.ident is not None:
                thread.join(30)  # before the control server closes, at the block's end
    assert not thread.is_alive(), "the session thread did not end"
    if failure:
        raise failure[0]
