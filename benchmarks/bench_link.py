"""Lockstep round trips/s: RemoteTarget against the loopback emulator process over a pty, beside
a raw two-process pty echo of the same frame sizes measured in the same run.

    python benchmarks/bench_link.py [--periods 20000] [--repeats 5]

Prints the median of each over the repeats (interleaved, so drifts of this noisy VM hit both
alike) and their ratio; the goal is framed >= 60 % of raw.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

from hilbench.bench.linktest import _Spawned, sensors_for_period
from hilbench.link import open_pty_pair
from hilbench.protocol import MODE_LOCKSTEP, encode_frame
from hilbench.targets.loopback import LoopbackTarget
from hilbench.targets.remote import RemoteTarget

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


def frame_sizes() -> tuple[int, int]:
    """Wire bytes of the Sensors and Drive frames the framed run exchanges."""
    sensors = sensors_for_period(1)
    return len(encode_frame(sensors)), len(encode_frame(LoopbackTarget().step(sensors)))


def raw_echo_rate(periods: int, req_len: int, resp_len: int) -> float:
    """Round trips/s of os.write/os.read against a child echoing fixed-size replies on a pty."""
    pair = open_pty_pair()
    proc = subprocess.Popen([sys.executable, "-c", _ECHO_CHILD, pair.slave_path, str(req_len), str(resp_len)],
                            stdout=subprocess.PIPE)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()
        os.close(pair.slave_fd)
        fd = pair.master_fd
        req = b"\xaa" * req_len
        t0 = time.perf_counter()
        for _ in range(periods):
            os.write(fd, req)
            got = 0
            while got < resp_len:
                got += len(os.read(fd, 4096))
        return periods / (time.perf_counter() - t0)
    finally:
        os.close(pair.master_fd)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def framed_rate(periods: int) -> float:
    """Round trips/s of RemoteTarget.step against the loopback emulator process on a pty."""
    spawned = _Spawned("loopback", timeout_s=2.0)
    try:
        remote = RemoteTarget(spawned.link, timeout_s=2.0)
        remote.handshake(50, MODE_LOCKSTEP, 0)
        frames = [sensors_for_period(k) for k in range(256)]
        step = remote.step
        t0 = time.perf_counter()
        for k in range(periods):
            step(frames[k & 0xFF])
        return periods / (time.perf_counter() - t0)
    finally:
        spawned.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    req_len, resp_len = frame_sizes()
    raw: list[float] = []
    framed: list[float] = []
    for i in range(args.repeats):
        raw.append(raw_echo_rate(args.periods, req_len, resp_len))
        framed.append(framed_rate(args.periods))
        print(f"repeat {i + 1}: raw echo {raw[-1]:8.0f}/s   framed {framed[-1]:8.0f}/s", flush=True)
    raw_med, framed_med = statistics.median(raw), statistics.median(framed)
    print(f"frames: Sensors {req_len} B, Drive {resp_len} B on the wire; {args.periods} periods x {args.repeats}")
    print(f"raw two-process pty echo   median {raw_med:8.0f} round trips/s")
    print(f"framed RemoteTarget<->loopback median {framed_med:8.0f} round trips/s")
    print(f"ratio framed/raw: {framed_med / raw_med:.1%} (goal >= 60 %)")


if __name__ == "__main__":
    main()
