"""What an open scope costs the session, measured against the same loop without it in one run.

    python benchmarks/bench_scope.py [--seconds 3] [--repeats 5] [--realtime-seconds 20]

(a) Lockstep, firmware in process (the fastest loop, so the worst case for a relative cost): the
    AN1017 bench at 20 kHz periods with its control socket open, every period recorded in memory,
    run ``--seconds`` simulated seconds; alternately without a scope and with `run --scope`'s
    arrangement: the scope's server in a thread of the same process, relaying the stream to a
    WebSocket client that subscribes to the page's default columns and reads every frame (the
    page's part, without a browser). Medians over ``--repeats`` pairs and their ratio (goal: the
    scope costs <= 10 %).
(b) Real time at 1 kHz against the emulator process (as benchmarks/bench_realtime.py), for
    ``--realtime-seconds`` without and then with the scope open: overruns and lateness p99.
    Skipped with --realtime-seconds 0.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import hilbench
from hilbench.bench.control import ControlServer
from hilbench.scope.server import ControlSource, ScopeServer

PAGE_COLUMNS = ["speed_rpm", "ref_speed_rpm", "ia_a", "ib_a", "ic_a", "duty_a", "hall_a", "hall_b", "hall_c", "sector"]


class PageClient:
    """A WebSocket client that subscribes like the page and reads every message, in a thread."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.messages = 0
        self.bytes = 0
        self.buckets = 0
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)

    async def _run(self) -> None:
        import aiohttp

        async with aiohttp.ClientSession() as client:
            async with client.ws_connect(self.url, max_msg_size=0) as ws:
                await ws.send_str(json.dumps({"type": "subscribe", "columns": PAGE_COLUMNS}))
                self._ready.set()
                while not self._stop.is_set():
                    try:
                        msg = await ws.receive(timeout=0.2)
                    except asyncio.TimeoutError:
                        continue
                    if msg.type != aiohttp.WSMsgType.TEXT:
                        break
                    self.messages += 1
                    self.bytes += len(msg.data)
                    self.buckets += sum(f["n"] for f in json.loads(msg.data).get("frames", ()))

    def __enter__(self) -> "PageClient":
        self._thread.start()
        self._ready.wait(10)
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(10)


def lockstep_once(seconds: float, scope: bool) -> tuple[float, str]:
    """Wall seconds for ``seconds`` simulated seconds (and a note on what the page received)."""
    folder = Path(tempfile.mkdtemp(prefix="hb-bench-scope-"))
    control = ControlServer(folder / "ctl" / "ctl.sock", publish=False)
    try:
        with hilbench.Bench(target="inprocess:an1017", control=control) as bench:
            bench.set_reference(1500)
            bench.press("s2")
            bench.run(0.05)  # warm up (and a scope's first stream request is answered here)
            if not scope:
                start = time.perf_counter()
                bench.run(seconds)
                return time.perf_counter() - start, ""
            with ScopeServer(ControlSource(control.path)) as server, PageClient(server.url + "ws") as page:
                while page.messages < 2:  # the page is connected and subscribed
                    bench.run(0.01)
                start = time.perf_counter()
                bench.run(seconds)
                wall = time.perf_counter() - start
                takes = bench.session.display.takes  # type: ignore[union-attr]
            return wall, f"{page.messages} messages, {page.bytes / 1e6:.1f} MB, {page.buckets} buckets, {takes} takes"
    finally:
        control.close()


def realtime_once(seconds: float, scope: bool) -> Any:
    from hilbench.bench.run import RunRequest, load_run_config, run_bench
    from hilbench.config import default_config_text

    config = Path(tempfile.mkdtemp()) / "realtime.toml"
    config.write_text(default_config_text() + "\n[[scenario]]\nat_s = 0.0\nref_rpm = 1500.0\nramp_s = 0.3\n\n"
                      "[[scenario]]\nat_s = 0.03\npress = \"s2\"\n")
    cfg = load_run_config(RunRequest(str(config), overrides=("link.period_us=1000",), target="emulator:an1017",
                                     mode="realtime", duration_s=seconds))
    folder = Path(tempfile.mkdtemp(prefix="hb-bench-scope-"))
    control = ControlServer(folder / "ctl" / "ctl.sock", publish=False)
    try:
        if not scope:
            return run_bench(cfg, control=control), ""
        with ScopeServer(ControlSource(control.path)) as server, PageClient(server.url + "ws") as page:
            summary = run_bench(cfg, control=control)
            return summary, f"{page.messages} messages, {page.bytes / 1e6:.1f} MB"
    finally:
        control.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--realtime-seconds", type=float, default=20.0)
    args = parser.parse_args()

    without: list[float] = []
    with_scope: list[float] = []
    note = ""
    for _ in range(args.repeats):  # interleaved, so the machine's load drifts into both alike
        without.append(lockstep_once(args.seconds, scope=False)[0])
        wall, note = lockstep_once(args.seconds, scope=True)
        with_scope.append(wall)
    base, scoped = statistics.median(without), statistics.median(with_scope)
    periods = args.seconds / 50e-6
    print(f"(a) lockstep in process, AN1017 at 20 kHz, {args.seconds:g} s simulated, median of {args.repeats}:")
    print(f"    without a scope   {base:7.3f} s wall  {periods / base:10,.0f} periods/s")
    print(f"    with a scope open {scoped:7.3f} s wall  {periods / scoped:10,.0f} periods/s   ({note})")
    print(f"    ratio {scoped / base:.3f}  (the scope costs {100 * (scoped / base - 1):+.1f} %; goal <= +10 %)")
    sys.stdout.flush()
    if args.realtime_seconds > 0:
        print(f"(b) real time at 1 kHz against the emulator process, {args.realtime_seconds:g} s each:")
        for scope in (False, True):
            summary, note = realtime_once(args.realtime_seconds, scope)
            lat = summary.lateness_us
            print(f"    {'with a scope open' if scope else 'without a scope  '}  overruns {summary.overruns} of {summary.periods} "
                  f"({summary.overruns / max(1, summary.periods):.3%}), lateness p99 {lat['p99']:.1f} us, "
                  f"max {lat['max']:.1f} us {('(' + note + ')') if note else ''}")


if __name__ == "__main__":
    main()
