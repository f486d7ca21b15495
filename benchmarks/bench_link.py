"""Lockstep round trips/s over a pty: RemoteTarget against the Python loopback emulator process and
against the C loopback target process (exec:), beside a raw two-process pty echo of the same frame
sizes, all measured in the same run; and the same framed exchange over TCP (socket://, the
loopback served by a child through hilbench.link.tcp).

    python benchmarks/bench_link.py [--periods 10000] [--repeats 7] [--no-c] [--no-tcp] [--baseline REV]

The runs are interleaved per repeat (so this noisy 2-core VM's drifts hit all alike) and the
medians and ratios printed; the goal (issue 2) is framed Python <-> Python >= 60 % of raw. Besides
wall-clock rates it prints CPU time per round trip on each side (host: this process; far end:
the child's /proc counters around the timed loop), which is much less sensitive to the other load on the VM
than the rates are.

--baseline REV also times the framed pty exchange with the code of git revision REV (exported to
a temporary directory), each side in its own fresh process, interleaved with the same exchange
with this tree's code: a before/after of a change to the link, in one run. Round trips between
processes swing by 2-5x on this shared VM, so it also times the link's own work alone: send +
recv on an fd whose far end is played by the same process (min of 5 runs, per tree, per repeat).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Iterator, NamedTuple

from hilbench.bench.linktest import _Spawned, sensors_for_period
from hilbench.link import open_link, open_pty_pair
from hilbench.protocol import MODE_LOCKSTEP, encode_frame
from hilbench.targets.loopback.target import LoopbackTarget
from hilbench.targets.remote import RemoteTarget

REPO = Path(__file__).resolve().parent.parent
_ECHO_CHILD = r"""
import os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
req, resp = int(sys.argv[2]), b"\x55" * int(sys.argv[3])
os.write(1, b"ready\n")
have = 0
while True:
    try:
        data = os.read(fd, 4096)
    except OSError:
        break
    if not data:
        break
    have += len(data)
    n, have = divmod(have, req)
    if n:
        os.write(fd, resp * n)
"""


class Run(NamedTuple):
    """One timed run: round trips/s and CPU microseconds per round trip on each side."""

    rate: float
    host_cpu_us: float
    far_cpu_us: float


_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def _proc_cpu_s(pid: int) -> float:
    """utime + stime of a live process from /proc (clock-tick resolution, 10 ms): read before and
    after the timed loop so the child's interpreter start-up is not charged to the round trips."""
    with open(f"/proc/{pid}/stat", "rb") as f:
        fields = f.read().rsplit(b")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) * _TICK_S


def frame_sizes() -> tuple[int, int]:
    """Wire bytes of the Sensors and Drive frames the framed runs exchange."""
    sensors = sensors_for_period(1)
    return len(encode_frame(sensors)), len(encode_frame(LoopbackTarget().step(sensors)))


@contextlib.contextmanager
def echo_child(req_len: int, resp_len: int) -> Iterator[tuple[int, subprocess.Popen[bytes]]]:
    """A child echoing a resp_len reply per req_len request on a pty; yields (our fd, child)."""
    pair = open_pty_pair()
    proc = subprocess.Popen([sys.executable, "-c", _ECHO_CHILD, pair.slave_path, str(req_len), str(resp_len)],
                            stdout=subprocess.PIPE)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()
        os.close(pair.slave_fd)
        yield pair.master_fd, proc
    finally:
        os.close(pair.master_fd)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def raw_echo(periods: int, req_len: int, resp_len: int) -> Run:
    """os.write/os.read against a child echoing fixed-size replies on a pty (blocking reads both sides)."""
    with echo_child(req_len, resp_len) as (fd, proc):
        req = b"\xaa" * req_len
        f0, c0, t0 = _proc_cpu_s(proc.pid), time.process_time(), time.perf_counter()
        for _ in range(periods):
            os.write(fd, req)
            got = 0
            while got < resp_len:
                got += len(os.read(fd, 4096))
        elapsed, host_cpu, far_cpu = time.perf_counter() - t0, time.process_time() - c0, _proc_cpu_s(proc.pid) - f0
    return Run(periods / elapsed, host_cpu / periods * 1e6, far_cpu / periods * 1e6)


def framed(periods: int, program: str | None = None) -> Run:
    """RemoteTarget.step against the loopback emulator process (or `program`) on a pty."""
    spawned = _Spawned("loopback", timeout_s=2.0, program=program)
    try:
        remote = RemoteTarget(spawned.link, timeout_s=2.0)
        remote.handshake(50, MODE_LOCKSTEP, 0, attempts=10)
        frames = [sensors_for_period(k) for k in range(256)]
        step = remote.step
        assert spawned.proc is not None
        pid = spawned.proc.pid
        f0, c0, t0 = _proc_cpu_s(pid), time.process_time(), time.perf_counter()
        for k in range(periods):
            step(frames[k & 0xFF])
        elapsed, host_cpu, far_cpu = time.perf_counter() - t0, time.process_time() - c0, _proc_cpu_s(pid) - f0
    finally:
        spawned.close()
    return Run(periods / elapsed, host_cpu / periods * 1e6, far_cpu / periods * 1e6)


_TCP_CHILD = r"""
from hilbench.link import serve_tcp_once
from hilbench.targets import make_target
from hilbench.targets.serve import serve
serve_tcp_once(0, lambda link: serve(make_target("loopback"), link), accept_timeout_s=60.0,
               announce=lambda url: print(url, flush=True))
"""


def framed_tcp(periods: int) -> Run:
    """RemoteTarget.step over socket:// against the loopback served by a child on 127.0.0.1."""
    proc = subprocess.Popen([sys.executable, "-c", _TCP_CHILD], stdout=subprocess.PIPE, stdin=subprocess.DEVNULL)
    try:
        assert proc.stdout is not None
        url = proc.stdout.readline().decode().strip()
        if not url.startswith("socket://"):
            raise RuntimeError(f"the TCP child announced {url!r}")
        link = open_link(url, timeout_s=2.0)
        try:
            remote = RemoteTarget(link, timeout_s=2.0)
            remote.handshake(50, MODE_LOCKSTEP, 0, attempts=10)
            frames = [sensors_for_period(k) for k in range(256)]
            step = remote.step
            f0, c0, t0 = _proc_cpu_s(proc.pid), time.process_time(), time.perf_counter()
            for k in range(periods):
                step(frames[k & 0xFF])
            elapsed = time.perf_counter() - t0
            host_cpu, far_cpu = time.process_time() - c0, _proc_cpu_s(proc.pid) - f0
        finally:
            link.close()
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
    return Run(periods / elapsed, host_cpu / periods * 1e6, far_cpu / periods * 1e6)


_FRAMED_CHILD = r"""
import sys
sys.path.insert(0, "benchmarks")
import hilbench
from bench_link import framed
assert hilbench.__file__.startswith(sys.argv[2]), (hilbench.__file__, sys.argv[2])
r = framed(int(sys.argv[1]))
print(r.rate, r.host_cpu_us, r.far_cpu_us)
"""


_HOST_CHILD = r"""
import os, socket, sys, time
import hilbench
from hilbench.link import open_link
from hilbench.bench.linktest import sensors_for_period
from hilbench.protocol import encode_frame
from hilbench.targets import make_target
assert hilbench.__file__.startswith(sys.argv[2]), (hilbench.__file__, sys.argv[2])
periods = int(sys.argv[1])
a, b = socket.socketpair()
link = open_link(f"fd:{a.detach()}", timeout_s=1.0)
fd = b.fileno()
sensors = [sensors_for_period(k) for k in range(256)]
loopback = make_target("loopback")
drives = [encode_frame(loopback.step(s)) for s in sensors]
best = []
for _ in range(5):
    t0 = time.perf_counter()
    for k in range(periods):
        link.send(sensors[k & 0xFF])
        os.read(fd, 4096)
        os.write(fd, drives[k & 0xFF])
        link.recv()
    best.append((time.perf_counter() - t0) / periods * 1e6)
print(min(best))
"""


def host_path_in_tree(tree: str, periods: int) -> float:
    """Microseconds per exchange of this end's send + recv on an fd (a socketpair whose other end
    this same process plays, so no scheduling between processes): min of 5, in a fresh process
    importing hilbench from tree. The link's own CPU cost, much steadier than round trips/s."""
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", _HOST_CHILD, str(periods), tree], cwd=tree, env=env,
                         capture_output=True, text=True, timeout=600)
    if out.returncode != 0:
        raise RuntimeError(f"host-path run in {tree} failed: {out.stderr.strip().splitlines()[-1:]}")
    return float(out.stdout.split()[-1])


def framed_in_tree(tree: str, periods: int) -> Run:
    """framed() in a fresh process importing hilbench (host and emulator child) from tree."""
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", _FRAMED_CHILD, str(periods), tree], cwd=tree, env=env,
                         capture_output=True, text=True, timeout=600)
    if out.returncode != 0:
        raise RuntimeError(f"framed run in {tree} failed: {out.stderr.strip().splitlines()[-1:]}")
    rate, host, far = (float(x) for x in out.stdout.split()[-3:])
    return Run(rate, host, far)


def export_tree(rev: str, out_dir: str) -> str:
    """git revision rev of this repository as a directory with its compiled cores built in place."""
    tree = os.path.join(out_dir, "baseline")
    os.makedirs(tree)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", rev], capture_output=True, check=True, timeout=120)
    subprocess.run(["tar", "-x", "-C", tree], input=archive.stdout, check=True, timeout=120)
    same_c = subprocess.run(["git", "-C", str(REPO), "diff", "--quiet", rev, "--", "*.c", "*.h", "setup.py"],
                            timeout=120).returncode == 0
    if same_c:  # the compiled cores are the same: reuse this tree's builds
        for lib in REPO.glob("hilbench/**/*.so"):
            shutil.copy2(lib, os.path.join(tree, lib.relative_to(REPO)))
    else:
        subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=tree, check=True,
                       capture_output=True, timeout=600)
    return tree


def build_c_loopback(out_dir: str) -> str | None:
    """Compile firmware_protocol's C loopback target (-O2); None without gcc."""
    gcc = shutil.which("gcc")
    if gcc is None:
        return None
    fw = REPO / "firmware_protocol"
    exe = os.path.join(out_dir, "loopback_target")
    library = sorted(str(source) for source in fw.glob("hbp*.c"))  # the wire library, whatever its files
    subprocess.run([gcc, "-std=c99", "-O2", f"-I{fw}", *library, str(fw / "examples" / "loopback_target.c"),
                    "-o", exe], check=True, timeout=120)
    return exe


def _median(runs: list[Run], field: str) -> float:
    return statistics.median(getattr(r, field) for r in runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--no-c", action="store_true", help="skip the C loopback target")
    parser.add_argument("--no-tcp", action="store_true", help="skip the framed exchange over socket://")
    parser.add_argument("--baseline", metavar="REV", help="also time the framed pty exchange at git REV")
    args = parser.parse_args()
    req_len, resp_len = frame_sizes()
    with tempfile.TemporaryDirectory(prefix="bench_link_") as tmp:
        c_program = None if args.no_c else build_c_loopback(tmp)
        baseline = None if args.baseline is None else export_tree(args.baseline, tmp)
        results: dict[str, list[Run]] = {"raw": [], "py": [], "c": [], "tcp": [], "base": [], "this": []}
        host_us: dict[str, list[float]] = {"base": [], "this": []}
        for i in range(args.repeats):
            results["raw"].append(raw_echo(args.periods, req_len, resp_len))
            results["py"].append(framed(args.periods))
            line = f"repeat {i + 1}: raw echo {results['raw'][-1].rate:7.0f}/s  framed py {results['py'][-1].rate:7.0f}/s"
            if c_program is not None:
                results["c"].append(framed(args.periods, c_program))
                line += f"  framed C {results['c'][-1].rate:7.0f}/s"
            if not args.no_tcp:
                results["tcp"].append(framed_tcp(args.periods))
                line += f"  framed tcp {results['tcp'][-1].rate:7.0f}/s"
            if baseline is not None:
                trees = [("base", baseline), ("this", str(REPO))]
                for key, tree in trees if i % 2 == 0 else trees[::-1]:  # alternate who goes first
                    results[key].append(framed_in_tree(tree, args.periods))
                    host_us[key].append(host_path_in_tree(tree, args.periods))
                line += f"  {args.baseline} {results['base'][-1].rate:7.0f}/s  this {results['this'][-1].rate:7.0f}/s"
            print(line, flush=True)
    raw = _median(results["raw"], "rate")
    print(f"frames: Sensors {req_len} B, Drive {resp_len} B on the wire; {args.periods} periods x {args.repeats}")
    print(f"{'':38s} {'median rt/s':>11s} {'vs raw':>7s} {'host CPU us/rt':>15s} {'far CPU us/rt':>14s}")
    names = {"raw": "raw two-process pty echo", "py": "framed RemoteTarget <-> py loopback",
             "c": "framed RemoteTarget <-> C loopback", "tcp": "framed over socket:// <-> py loopback",
             "base": f"framed py, code at {args.baseline}", "this": "framed py, this tree (subprocess)"}
    for key, runs in results.items():
        if not runs:
            continue
        rate = _median(runs, "rate")
        print(f"{names[key]:38s} {rate:11.0f} {rate / raw:7.1%} {_median(runs, 'host_cpu_us'):15.1f} "
              f"{_median(runs, 'far_cpu_us'):14.1f}")
    ratios = [p.rate / r.rate for p, r in zip(results["py"], results["raw"])]
    print(f"ratio framed py / raw: {_median(results['py'], 'rate') / raw:.1%} of medians, "
          f"per-repeat median {statistics.median(ratios):.1%} (goal >= 60 %)")
    if results["base"]:
        pairs = [t.rate / b.rate for t, b in zip(results["this"], results["base"])]
        cpu = _median(results["this"], "host_cpu_us") / _median(results["base"], "host_cpu_us")
        rates = _median(results["this"], "rate") / _median(results["base"], "rate")
        print(f"this tree / {args.baseline}: {rates:.3f} of median rates, per-repeat median "
              f"{statistics.median(pairs):.3f}; host CPU per round trip {cpu:.3f}")
        base_us, this_us = statistics.median(host_us["base"]), statistics.median(host_us["this"])
        print(f"link send+recv on an fd, one process (median of per-repeat minima): {args.baseline} "
              f"{base_us:.2f} us, this tree {this_us:.2f} us, ratio {this_us / base_us:.3f}")


if __name__ == "__main__":
    main()
