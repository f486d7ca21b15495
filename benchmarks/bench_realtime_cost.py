"""What one real-time period costs: CPU, context switches and syscalls per period of the host's loop
thread and of the emulator process, this tree against a baseline venv, alternated in one run.

    python benchmarks/bench_realtime_cost.py [--baseline-python /work/venv-c0fb63a/bin/python]
        [--seconds 10] [--runs 3] [--period-us 1000] [--no-perf]

Overrun counts move with whatever else the shared VM runs; what a period costs moves much less.
Each run is `bench_realtime.py`'s bench (emulator:an1017 on a pty, the Hurst bench's motor running,
1 kHz, the CPU wake-up latency request, pinned, SCHED_FIFO 10 where the tree knows it) in a fresh
process with that python, started outside this tree so that a baseline venv imports its own
hilbench. The process tells us (a hook on the pacer's start) which thread runs the periods; after
a second of warm-up we take, over a window of ``--seconds``, from /proc (schedstat's CPU ns and
timeslices, status's voluntary/involuntary switches) and from ``perf stat`` (syscall tracepoints,
counting only: no ptrace) what the host's loop thread, the host's other threads and the emulator
process's threads did, and divide by the periods of the window; "per exchange" divides the loop's
CPU outside the pacer's wait and the emulator's by the Sensors the host wrote (a skipped period
exchanges nothing, so a run that skips more looks cheaper per period). Medians of the runs are
printed with the ratio tree / baseline.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_realtime import SCENARIO  # noqa: E402

#: runs in the python under test (either tree's hilbench): the bench of bench_realtime.py, and a
#: line naming the thread that runs the periods as they start
_DRIVER = r"""
import sys, tempfile, threading, time
from pathlib import Path
from hilbench.bench import clock
from hilbench.bench.run import RunRequest, load_run_config, run_bench
from hilbench.config import default_config_text
seconds, period_us, scenario, priority = float(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
start, wait_for, waited = clock.Pacer.start, clock.Pacer.wait_for, [0, 0]
def started(self):
    print(f"START {threading.get_native_id()}", flush=True)
    start(self)
def timed_wait(self, k, cpu=time.thread_time_ns):  # the loop thread's CPU in the pacer's wait (its spin)
    before = cpu()
    late = wait_for(self, k)
    waited[0] += cpu() - before
    waited[1] += 1
    return late
clock.Pacer.start, clock.Pacer.wait_for = started, timed_wait
words = [f"link.period_us={period_us}", "link.cpu_latency_qos=true", "link.pin_realtime=true",
         f"link.realtime_priority={priority}"]
with tempfile.TemporaryDirectory(prefix="hb-bench-") as folder:  # the config, read at once
    config = Path(folder) / "realtime.toml"
    config.write_text(default_config_text() + scenario)
    try:
        cfg = load_run_config(RunRequest(str(config), overrides=tuple(words), target="emulator:an1017",
                                         mode="realtime", duration_s=seconds))
    except Exception:  # a tree without [link] realtime_priority
        cfg = load_run_config(RunRequest(str(config), overrides=tuple(words[:-1]), target="emulator:an1017",
                                         mode="realtime", duration_s=seconds))
summary = run_bench(cfg)
print(f"END {summary.periods} {summary.overruns} {waited[0] / max(1, waited[1]) / 1e3} {summary.cpus}", flush=True)
"""

#: syscalls counted one by one (the rest are summed as "other")
SYSCALLS = ("read", "write", "pselect6", "poll", "ppoll", "epoll_wait", "clock_nanosleep", "futex", "ioctl")
WARMUP_S = 1.0


def _threads(pid: int) -> list[int]:
    try:
        return [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return []


def _children(pid: int) -> list[int]:
    found: list[int] = []
    for tid in _threads(pid):
        try:
            found += [int(c) for c in Path(f"/proc/{pid}/task/{tid}/children").read_text().split()]
        except OSError:
            pass
    return found


TICK_NS = 1e9 / os.sysconf("SC_CLK_TCK")


def _thread_counters(pid: int, tid: int) -> tuple[int, ...]:
    """(CPU ns, run-queue wait ns, voluntary switches, involuntary switches, user ns, system ns) of
    one thread (user and system in clock ticks: coarse, but a window of seconds holds many)."""
    base = f"/proc/{pid}/task/{tid}"
    try:
        cpu_ns, wait_ns, _slices = (int(v) for v in Path(f"{base}/schedstat").read_text().split())
        status = dict(line.split(":", 1) for line in Path(f"{base}/status").read_text().splitlines() if ":" in line)
        utime, stime = Path(f"{base}/stat").read_text().rsplit(")", 1)[1].split()[11:13]
        return (cpu_ns, wait_ns, int(status["voluntary_ctxt_switches"]), int(status["nonvoluntary_ctxt_switches"]),
                int(int(utime) * TICK_NS), int(int(stime) * TICK_NS))
    except (OSError, KeyError, ValueError):
        return 0, 0, 0, 0, 0, 0


def _snapshot(groups: dict[str, list[tuple[int, int]]]) -> dict[str, tuple[int, ...]]:
    out = {}
    for name, tids in groups.items():
        sums = [0] * 6
        for pid, tid in tids:
            for i, v in enumerate(_thread_counters(pid, tid)):
                sums[i] += v
        out[name] = tuple(sums)
    return out


def _perf(groups: dict[str, list[tuple[int, int]]], path: str) -> subprocess.Popen[bytes] | None:
    if shutil.which("perf") is None:
        return None
    events = ["raw_syscalls:sys_enter"] + [f"syscalls:sys_enter_{name}" for name in SYSCALLS]
    tids = sorted({tid for members in groups.values() for _pid, tid in members})
    return subprocess.Popen(["perf", "stat", "--per-thread", "-x", ",", "-o", path, "-e", ",".join(events),
                             "-t", ",".join(map(str, tids))], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _perf_counts(path: str, groups: dict[str, list[tuple[int, int]]]) -> dict[str, dict[str, int]]:
    """{group: {syscall or "all": count}} from perf stat's per-thread CSV ("comm-tid,count,,event,...")."""
    group_of = {tid: name for name, members in groups.items() for _pid, tid in members}
    counts: dict[str, dict[str, int]] = {name: {} for name in groups}
    for line in Path(path).read_text().splitlines():
        fields = line.split(",")
        if len(fields) < 4 or not fields[1].strip().isdigit():
            continue
        tid = int(fields[0].rsplit("-", 1)[-1])
        event = fields[3].split(":")[-1].removeprefix("sys_enter_")
        event = "all" if event == "sys_enter" else event
        name = group_of.get(tid)
        if name is not None:
            counts[name][event] = counts[name].get(event, 0) + int(fields[1])
    return counts


def measure(python: str, seconds: float, period_us: int, use_perf: bool, priority: int) -> dict[str, dict[str, float]]:
    """One run of the bench with ``python``: per-period figures of each group over the window."""
    total_s = WARMUP_S + seconds + 1.5
    with tempfile.TemporaryDirectory(prefix="rtcost-") as tmp:
        env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
        env.pop("PYTHONPATH", None)
        child = subprocess.Popen([python, "-c", _DRIVER, str(total_s), str(period_us), SCENARIO, str(priority)],
                                 cwd=tmp,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        try:
            assert child.stdout is not None
            line = child.stdout.readline()
            if not line.startswith("START"):
                raise SystemExit(f"{python}: the bench did not start: {line.strip()} {child.stderr.read()[-400:]}")  # type: ignore[union-attr]
            loop_tid = int(line.split()[1])
            time.sleep(WARMUP_S)
            emulators = [(c, t) for c in _children(child.pid) for t in _threads(c)]
            groups = {"host loop": [(child.pid, loop_tid)],
                      "host other": [(child.pid, t) for t in _threads(child.pid) if t != loop_tid],
                      "emulator": emulators}
            perf_out = os.path.join(tmp, "perf.csv")
            perf = _perf(groups, perf_out) if use_perf else None
            time.sleep(0.3 if perf is not None else 0.0)  # perf attached before the window opens
            before, t0 = _snapshot(groups), time.monotonic()
            time.sleep(seconds)
            after, t1 = _snapshot(groups), time.monotonic()
            if perf is not None:
                perf.send_signal(signal.SIGINT)
                perf.wait(10)
            end = child.stdout.read()
            child.wait(30)
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()
        periods = (t1 - t0) / (period_us * 1e-6)
        syscalls = _perf_counts(perf_out, groups) if perf is not None and os.path.exists(perf_out) else {}
    figures: dict[str, dict[str, float]] = {}
    for name in groups:
        d = [a - b for a, b in zip(after[name], before[name])]
        row = {"cpu_us": d[0] / 1e3 / periods, "runq_us": d[1] / 1e3 / periods,
               "vol_cs": d[2] / periods, "invol_cs": d[3] / periods,
               "user_us": d[4] / 1e3 / periods, "kernel_us": d[5] / 1e3 / periods}
        for event, count in syscalls.get(name, {}).items():
            row[f"sys_{event}"] = count * (periods and 1 / periods)
        figures[name] = row
    words = end.split() if end.startswith("END") else ["END", "0", "-1", "0"]
    figures["_run"] = {"overruns": float(words[2])}
    figures["host loop"]["wait_cpu_us"] = float(words[3])  # the pacer's sleep and spin, the whole run's mean
    figures["host loop"]["work_cpu_us"] = figures["host loop"]["cpu_us"] - float(words[3])
    return figures


def _print(label: str, runs: list[dict[str, dict[str, float]]]) -> dict[str, dict[str, float]]:
    medians: dict[str, dict[str, float]] = {}
    for group in ("host loop", "host other", "emulator"):
        keys = sorted({k for run in runs for k in run.get(group, {})}, key=lambda k: (not k.startswith("cpu"), k))
        medians[group] = {k: statistics.median(run[group].get(k, 0.0) for run in runs) for k in keys}
    print(f"{label}: per period, median of {len(runs)} runs "
          f"(overruns in the runs, not a figure here: {[int(r['_run']['overruns']) for r in runs]})")
    exchanges = medians["host loop"].get("sys_write")  # one Sensors written per exchange (a skipped period has none)
    if exchanges:
        for group in ("host loop", "emulator"):
            row = medians[group]
            row["exchange_cpu_us"] = row.get("work_cpu_us", row["cpu_us"]) / exchanges
    for group, row in medians.items():
        sys_all = row.get("sys_all")
        named = {k[4:]: v for k, v in row.items() if k.startswith("sys_") and k != "sys_all" and v >= 0.005}
        work = f" (outside the pacer's wait {row['work_cpu_us']:5.1f})" if "work_cpu_us" in row else ""
        if "exchange_cpu_us" in row:
            work += f" [{row['exchange_cpu_us']:5.1f} per exchange]"
        print(f"  {group:10s} CPU {row['cpu_us']:7.1f} us{work}  user {row['user_us']:5.1f} kernel {row['kernel_us']:5.1f}  "
              f"run-queue wait {row['runq_us']:6.1f} us  "
              f"switches vol {row['vol_cs']:5.2f} invol {row['invol_cs']:5.2f}"
              + (f"  syscalls {sys_all:5.2f} ({', '.join(f'{k} {v:.2f}' for k, v in sorted(named.items()))})"
                 if sys_all is not None else ""))
    return medians


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline-python", help="a venv's python whose hilbench is the baseline (e.g. c0fb63a's)")
    parser.add_argument("--seconds", type=float, default=10.0, help="the measured window of each run")
    parser.add_argument("--runs", type=int, default=3, help="runs of each, alternated")
    parser.add_argument("--period-us", type=int, default=1000)
    parser.add_argument("--no-perf", action="store_true", help="no syscall counts (perf stat not run)")
    parser.add_argument("--priority", type=int, default=10,
                        help="[link] realtime_priority of the runs (0: normal scheduling; a tree without it ignores it)")
    args = parser.parse_args()
    pythons = [("this tree", sys.executable)] + ([("baseline", args.baseline_python)] if args.baseline_python else [])
    results: dict[str, list[dict[str, dict[str, float]]]] = {label: [] for label, _ in pythons}
    for _ in range(args.runs):
        for label, python in pythons:
            results[label].append(measure(python, args.seconds, args.period_us, not args.no_perf, args.priority))
    print(f"real-time period cost, {args.period_us} us periods, {args.seconds:g} s windows "
          f"(emulator:an1017 on a pty; host loop = the thread that runs the periods)")
    medians = {label: _print(f"{label} ({python})", results[label]) for label, python in pythons}
    if args.baseline_python:
        tree, base = medians["this tree"], medians["baseline"]
        for group in ("host loop", "emulator"):
            for key in ("cpu_us", "work_cpu_us", "exchange_cpu_us", "sys_all", "vol_cs"):
                if key in tree[group] and base[group].get(key):
                    print(f"ratio {group} {key} this tree / baseline: {tree[group][key] / base[group][key]:.2f}")
        def work(m: dict[str, dict[str, float]]) -> float:
            return m["host loop"]["work_cpu_us"] + m["host other"]["cpu_us"] + m["emulator"]["cpu_us"]
        print(f"ratio CPU per period outside the pacer's wait, host + emulator, this tree / baseline: "
              f"{work(tree) / max(1e-9, work(base)):.2f}")


if __name__ == "__main__":
    main()
