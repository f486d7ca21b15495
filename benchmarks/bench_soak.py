"""Soak: resident memory against simulated time over a long run (issue 16, item 7).

A session keeps streaming statistics and a bounded history; a recording goes to disk as the run
goes and its NPZ archive is written from the journal in chunks. So RSS must stay flat: this run
prints RSS every `--every` simulated seconds and the growth from 60 s to the end (the target:
within 10 MB from 60 to 600 s). The baseline is the RSS at 60 simulated seconds of the same run.

    python benchmarks/bench_soak.py                       # 600 s in process, no recording
    python benchmarks/bench_soak.py --record /tmp/soak.npz --seconds 300
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0, help="simulated seconds")
    parser.add_argument("--every", type=float, default=60.0, help="print every N simulated seconds")
    parser.add_argument("--target", default="inprocess:an1017")
    parser.add_argument("--record", default=None, help="a .npz or .csv recording (default: none)")
    args = parser.parse_args()

    import hilbench
    from hilbench.bench.control import ControlServer

    import tempfile

    sock_dir = tempfile.mkdtemp(prefix="soak-")
    control = ControlServer(Path(sock_dir) / "s" / "ctl.sock", publish=False)
    print(f"soak: {args.seconds:g} simulated s on {args.target}, recording {args.record or 'none'}")
    print(f"{'sim s':>8} {'wall s':>8} {'RSS MB':>8} {'vs 60 s':>9}")
    baseline = None
    started = time.perf_counter()
    bench = hilbench.Bench(target=args.target, record=args.record, keep_rows=False, control=control)
    try:
        with bench:
            bench.set_reference(1500)
            bench.press("s2")
            t = 0.0
            step = 0
            while t < args.seconds - 1e-9:
                chunk = min(args.every, args.seconds - t)
                bench.run(chunk)
                t += chunk
                step += 1
                bench.set_reference(1500 if step % 2 else 2000)  # reference changes: segments keep coming
                rss = rss_mb()
                if baseline is None and t >= 60.0 - 1e-9:
                    baseline = rss
                delta = f"{rss - baseline:+9.1f}" if baseline is not None else f"{'':>9}"
                print(f"{t:8.0f} {time.perf_counter() - started:8.1f} {rss:8.1f} {delta}", flush=True)
            before_close = rss_mb()
            summary = bench.summary()
        after_close = rss_mb()
    finally:
        control.close()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"close: RSS {before_close:.1f} -> {after_close:.1f} MB; peak RSS of the process {peak:.1f} MB")
    print(f"segments: {len(summary.segments)}; rtt p50 {summary.rtt_us.get('p50', float('nan')):.2f} us over "
          f"{summary.rtt_us.get('n', 0):.0f} samples")
    if baseline is not None:
        growth = rss - baseline
        print(f"RSS growth from 60 s to {t:.0f} s: {growth:+.1f} MB ({'flat' if abs(growth) <= 10 else 'NOT flat'}, limit 10 MB)")


if __name__ == "__main__":
    main()
