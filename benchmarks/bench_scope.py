"""What an open scope costs the session, measured against the same loop without it in one run.

    python benchmarks/bench_scope.py [--seconds 15] [--repeats 7] [--realtime-seconds 15] [--realtime-repeats 2]

(a) Lockstep, firmware in process (the fastest loop, so the worst case for a relative cost): the
    AN1017 bench at 20 kHz periods with its control socket open, every period recorded in memory,
    run ``--seconds`` simulated seconds, interleaved: without a scope; with `run --scope`'s
    arrangement (`hilbench scope` as a child process on the control socket, and a page — a
    WebSocket client subscribed to the page's default columns reading every frame — in another
    process, as a browser is); and with server and page both as threads of the session's own process
    (the worst case). Medians over ``--repeats`` and their ratios (goal: the scope costs <= 10 %).
(b) Real time at 1 kHz against the emulator process (as benchmarks/bench_realtime.py), without and
    with `run --scope`'s arrangement, alternated ``--realtime-repeats`` times: overruns and lateness
    p99. Skipped with --realtime-seconds 0. The figures move with the machine's load.
(c) Write-to-drawn latency (issue 22): `hilbench run --no-ui --scope` without a recording, lockstep
    flat out, the page in headless chromium (Playwright). ``--latency-writes`` times the page sets
    the reference (1500 <-> 1800 rpm, its "set" button), and the page times, with its own clock, until
    the firmware's reference (`ref_speed_rpm`, the target's telemetry) has crossed the midpoint in
    a frame that arrived after the write and a frame has been drawn since. Median and p95 of wall
    time (goal: median <= 150 ms), beside the page's stream poll interval measured in the same run.
    Skipped with --latency-writes 0 or without chromium/Playwright.

    python benchmarks/bench_scope.py --repeats 0 --realtime-seconds 0 --latency-writes 30   # (c) alone
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import subprocess
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


class PageProcess:
    """The page as its own process (this script with --page URL), as a browser is."""

    def __init__(self, url: str) -> None:
        self.proc = subprocess.Popen([sys.executable, __file__, "--page", url], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True)
        self.proc.stdout.readline()  # "subscribed"  # type: ignore[union-attr]
        self.stats: dict[str, Any] = {}

    @property
    def messages(self) -> int:
        return 2  # subscribed: its first replies are on their way

    def close(self) -> None:
        try:
            out, _ = self.proc.communicate("", timeout=20)
            self.stats = json.loads(out.strip().splitlines()[-1])
        except (subprocess.TimeoutExpired, ValueError, IndexError):
            self.proc.kill()
            self.proc.wait(10)


def page_main(url: str) -> None:
    """--page URL: subscribe, read every message until stdin closes, print counts as JSON."""
    page = PageClient(url)
    with page:
        print("subscribed", flush=True)
        sys.stdin.read()
    print(json.dumps({"messages": page.messages, "bytes": page.bytes, "buckets": page.buckets}), flush=True)


def lockstep_once(seconds: float, scope: str) -> tuple[float, float, str]:
    """Wall and CPU seconds of this process (all its threads) for ``seconds`` simulated seconds,
    and a note on what the page received.
    ``scope``: "none", "process" (`run --scope`'s arrangement) or "thread" (all in this process)."""
    from hilbench.scope.launch import ScopeProcess

    with tempfile.TemporaryDirectory(prefix="hb-bench-scope-", ignore_cleanup_errors=True) as folder, \
            ControlServer(Path(folder) / "ctl" / "ctl.sock", publish=False) as control:  # both go however it ends
        with hilbench.Bench(target="inprocess:an1017", control=control) as bench:
            bench.set_reference(1500)
            bench.press("s2")
            bench.run(0.05)  # warm up
            if scope == "none":
                start, cpu = time.perf_counter(), time.process_time()
                bench.run(seconds)
                return time.perf_counter() - start, time.process_time() - cpu, ""
            if scope == "thread":
                with ScopeServer(ControlSource(control.path)) as server, PageClient(server.url + "ws") as page:
                    while bench.session.display is None or not bench.session.display.frames:  # type: ignore[union-attr]
                        bench.run(0.01)  # the page is connected, subscribed and served
                    start, cpu = time.perf_counter(), time.process_time()
                    bench.run(seconds)
                    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
                return wall, cpu, f"{page.messages} messages, {page.bytes / 1e6:.1f} MB, {page.buckets} buckets"
            server_process = ScopeProcess(control.path)
            page_process = PageProcess(server_process.url + "ws")
            try:
                while bench.session.display is None or not bench.session.display.frames:  # type: ignore[union-attr]
                    bench.run(0.01)
                start, cpu = time.perf_counter(), time.process_time()
                bench.run(seconds)
                wall, cpu = time.perf_counter() - start, time.process_time() - cpu
            finally:
                page_process.close()
                server_process.close()
            stats = page_process.stats
            return wall, cpu, f"{stats.get('messages')} messages, {stats.get('bytes', 0) / 1e6:.1f} MB, {stats.get('buckets')} buckets"


def realtime_once(seconds: float, scope: bool) -> Any:
    from hilbench.bench.run import RunRequest, load_run_config, run_bench
    from hilbench.config import default_config_text

    with tempfile.TemporaryDirectory(prefix="hb-bench-") as config_folder:  # the config, read at once
        config = Path(config_folder) / "realtime.toml"
        config.write_text(default_config_text() + "\n[[scenario]]\nat_s = 0.0\nref_rpm = 1500.0\nramp_s = 0.3\n\n"
                          "[[scenario]]\nat_s = 0.03\npress = \"s2\"\n")
        cfg = load_run_config(RunRequest(str(config), overrides=("link.period_us=1000",), target="emulator:an1017",
                                         mode="realtime", duration_s=seconds))
    with tempfile.TemporaryDirectory(prefix="hb-bench-scope-", ignore_cleanup_errors=True) as folder, \
            ControlServer(Path(folder) / "ctl" / "ctl.sock", publish=False) as control:  # both go however it ends
        if not scope:
            return run_bench(cfg, control=control), ""
        from hilbench.scope.launch import ScopeProcess

        server_process = ScopeProcess(control.path)
        page_process = PageProcess(server_process.url + "ws")
        try:
            summary = run_bench(cfg, control=control)
        finally:
            page_process.close()
            server_process.close()
        stats = page_process.stats
        return summary, f"{stats.get('messages')} messages, {stats.get('bytes', 0) / 1e6:.1f} MB"


#: in the page: set the reference from its form, then resolve with the milliseconds until the new value
#: is in a frame that arrived after the write and a frame has been drawn since (two animation frames)
LATENCY_JS = """async ([target, threshold, rising]) => {
  const S = window.scope, t0 = performance.now(), old = S.data.get('ref_speed_rpm') || [];
  const last = old[old.length - 1];  // frames after this one arrived after the write (the page trims old ones)
  document.getElementById('ref-input').value = String(target);
  document.getElementById('ref-set').click();
  const arrived = () => {
    const segs = S.data.get('ref_speed_rpm') || [];
    for (let k = segs.indexOf(last) + 1; k < segs.length; k++) {
      const s = segs[k];
      for (let i = 0; i < s.n; i++) if (rising ? s.hi[i] >= threshold : s.lo[i] <= threshold) return true;
    }
    return false;
  };
  const frame = () => new Promise((resolve) => requestAnimationFrame(resolve));
  while (!arrived()) { await frame(); if (performance.now() - t0 > 10000) return -1; }
  await frame(); await frame();
  return performance.now() - t0;
}"""

#: in the page: the intervals between stream messages over ``ms`` milliseconds
POLL_JS = """async (ms) => {
  const S = window.scope, times = [], t0 = performance.now();
  let last = S.frames;
  while (performance.now() - t0 < ms) {
    await new Promise((resolve) => requestAnimationFrame(resolve));
    if (S.frames !== last) { times.push(performance.now()); last = S.frames; }
  }
  return times.slice(1).map((t, i) => t - times[i]);
}"""


def latency(writes: int) -> None:
    """(c): see the module's docstring."""
    import os
    import re
    import shutil

    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        print("(c) skipped: Playwright is not installed")
        return
    chromium = os.environ.get("HILBENCH_CHROMIUM", "/usr/bin/chromium")
    chromium = chromium if os.path.exists(chromium) else shutil.which("chromium")
    if not chromium:
        print("(c) skipped: no chromium")
        return
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "hilbench", "run", "--target", "inprocess:an1017", "--duration", "3600",
                             "--no-ui", "--scope"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    url = socket = ""
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            found = re.search(r"control socket (\S+)", line)
            socket = found.group(1) if found else socket
            found = re.search(r"scope: (http://\S+)", line)
            if found:
                url = found.group(1)
                break
        if not url:
            print("(c) failed: the run printed no scope URL")
            return
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium, args=["--headless", "--no-sandbox", "--disable-gpu"])
            page = browser.new_page(viewport={"width": 1280, "height": 820})
            page.goto(url)
            page.wait_for_function("window.scope.frames > 2 && window.scope.selected.includes('ref_speed_rpm')", timeout=30_000)
            page.fill("#ref-input", "1500")
            page.click("#ref-set")
            page.wait_for_timeout(1000)  # the motor follows the first reference (settling, not synchronisation)
            polls = page.evaluate(POLL_JS, 3000)
            samples = []
            for n in range(writes):
                target = 1800 if n % 2 == 0 else 1500
                samples.append(page.evaluate(LATENCY_JS, [target, 1650, target > 1650]))
                page.wait_for_timeout(300)  # the firmware's reference settles before the next write
            browser.close()
    finally:
        if socket:
            subprocess.run([sys.executable, "-m", "hilbench", "ctl", "--socket", socket, "stop"], capture_output=True, timeout=30)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    good = sorted(x for x in samples if x >= 0)
    lost = len(samples) - len(good)
    if not good:
        print("(c) failed: no write was seen drawn within 10 s")
        return
    p95 = good[min(len(good) - 1, int(0.95 * (len(good) - 1) + 0.5))]
    poll = statistics.median(polls) if polls else float("nan")
    print(f"(c) write-to-drawn latency, `run --scope` without a recording, lockstep, headless chromium, {len(good)} writes"
          f"{f' ({lost} not seen within 10 s)' if lost else ''}:")
    print(f"    median {statistics.median(good):6.1f} ms   p95 {p95:6.1f} ms   min {good[0]:6.1f} ms   max {good[-1]:6.1f} ms"
          f"   (goal: median <= 150 ms); the page's stream messages every {poll:.1f} ms (median)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--page", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--realtime-seconds", type=float, default=15.0)
    parser.add_argument("--realtime-repeats", type=int, default=1)
    parser.add_argument("--latency-writes", type=int, default=20)
    args = parser.parse_args()
    if args.page:
        page_main(args.page)
        return
    if args.latency_writes > 0:
        latency(args.latency_writes)
        sys.stdout.flush()
    if args.repeats <= 0:
        return

    walls: dict[str, list[float]] = {"none": [], "process": [], "thread": []}
    cpus: dict[str, list[float]] = {kind: [] for kind in walls}
    notes: dict[str, str] = {}
    for _ in range(args.repeats):  # interleaved, so the machine's load drifts into all alike
        for kind in walls:
            wall, cpu, notes[kind] = lockstep_once(args.seconds, kind)
            walls[kind].append(wall)
            cpus[kind].append(cpu)
    base, base_cpu = statistics.median(walls["none"]), statistics.median(cpus["none"])
    periods = args.seconds / 50e-6
    print(f"(a) lockstep in process, AN1017 at 20 kHz, {args.seconds:g} s simulated, median of {args.repeats}; wall time, and")
    print("    the CPU time of the session's process (all its threads: on a busy machine wall time also counts other processes)")
    print(f"    without a scope                  wall {base:6.3f} s {periods / base:9,.0f} periods/s   CPU {base_cpu:6.3f} s")
    for kind, label in (("process", "with a scope (run --scope)     "), ("thread", "with a scope, all in-process   ")):
        wall, cpu = statistics.median(walls[kind]), statistics.median(cpus[kind])
        print(f"    {label}  wall {wall:6.3f} s {periods / wall:9,.0f} periods/s   CPU {cpu:6.3f} s   "
              f"ratio wall {wall / base:.3f}, CPU {cpu / base_cpu:.3f} (goal <= 1.10)   [{notes[kind]}]")
    sys.stdout.flush()
    if args.realtime_seconds > 0:
        print(f"(b) real time at 1 kHz against the emulator process, {args.realtime_seconds:g} s each, "
              f"{args.realtime_repeats} pair(s) alternated:")
        for scope in [False, True] * args.realtime_repeats:
            summary, note = realtime_once(args.realtime_seconds, scope)
            lat = summary.lateness_us
            print(f"    {'with a scope open' if scope else 'without a scope  '}  overruns {summary.overruns} of {summary.periods} "
                  f"({summary.overruns / max(1, summary.periods):.3%}), lateness p99 {lat['p99']:.1f} us, "
                  f"max {lat['max']:.1f} us {('(' + note + ')') if note else ''}")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
