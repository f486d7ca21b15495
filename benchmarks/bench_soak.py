"""Soak: resident memory during a long run and at the close of its NPZ recording (issues 16, 23).

A session keeps streaming statistics and a bounded history; a recording goes to disk as the run
goes and its NPZ archive is written from the journal in one pass, one chunk of rows read into a
buffer at a time (nothing of the journal mapped). So neither the run's RSS nor the close's peak may grow with the run's length.
Each run is its own process (its own peak); per run this prints the RSS every `--every`
simulated seconds, the largest RSS of the run, and the close's peak (the kernel's high-water
mark, reset just before the close) with its excess over the RSS the run had before it closed.

    python benchmarks/bench_soak.py --seconds 60 3600 --record-dir /tmp/soak      # the issue 23 figures
    python benchmarks/bench_soak.py --seconds 60 600 --record-dir /tmp/soak \\
        --baseline-python /work/venv-730876f/bin/python                           # against 730876f's tree

Goal (issue 23): the close's excess under 100 MB for a 1-hour simulated run, and not growing with
the run's length. A 3600 s run at 20 kHz writes a ~6 GB journal and a ~13 GB archive: give
--record-dir a disk with room (both are removed afterwards).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _status_mb(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _reset_peak() -> bool:
    """Reset VmHWM to the current RSS (Linux: `5` into clear_refs)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def child(seconds: float, every: float, target: str, record: str | None) -> dict[str, object]:
    """One run in this process; its figures as a dict (printed as JSON by --child)."""
    import hilbench
    from hilbench.bench.control import ControlServer

    with tempfile.TemporaryDirectory(prefix="soak-", ignore_cleanup_errors=True) as sock_dir, \
            ControlServer(Path(sock_dir) / "s" / "ctl.sock", publish=False) as control:  # both go however it ends
        samples: list[tuple[float, float, float]] = []
        started = time.perf_counter()
        bench = hilbench.Bench(target=target, record=record, keep_rows=False, control=control)
        try:
            bench.open()
            bench.set_reference(1500)
            bench.press("s2")
            t, step = 0.0, 0
            while t < seconds - 1e-9:
                chunk = min(every, seconds - t)
                bench.run(chunk)
                t += chunk
                step += 1
                bench.set_reference(1500 if step % 2 else 2000)  # reference changes: segments keep coming
                samples.append((t, time.perf_counter() - started, _status_mb("VmRSS")))
            before_close = _status_mb("VmRSS")
            reset = _reset_peak()
            closing = time.perf_counter()
            bench.close()
            close_s = time.perf_counter() - closing
            close_peak = _status_mb("VmHWM") if reset else float("nan")
            after_close = _status_mb("VmRSS")
        finally:
            bench.close()
    size = os.path.getsize(record) if record and os.path.exists(record) else 0
    return {"seconds": seconds, "samples": samples, "run_max_mb": max(r for _, _, r in samples),
            "before_close_mb": before_close, "close_peak_mb": close_peak, "after_close_mb": after_close,
            "close_s": close_s, "archive_bytes": size}


def _run_child(python: str, seconds: float, args: argparse.Namespace, label: str) -> dict[str, object]:
    record = None
    folder = None
    if args.record_dir:
        folder = Path(tempfile.mkdtemp(prefix=f"soak-{label}-", dir=args.record_dir))
        record = str(folder / "soak.npz")
    command = [python, "-P", os.path.abspath(__file__), "--child", "--seconds", str(seconds), "--every",
               str(args.every), "--target", args.target] + (["--record", record] if record else [])
    try:
        out = subprocess.run(command, capture_output=True, text=True, check=True, cwd=args.cwd).stdout
    except subprocess.CalledProcessError as exc:
        raise SystemExit(f"soak {label} {seconds:g} s failed: {exc.stderr.strip().splitlines()[-1:]}") from None
    finally:
        if folder is not None:
            for f in folder.iterdir():
                f.unlink()
            folder.rmdir()
    return json.loads(out.strip().splitlines()[-1])


def _print(label: str, result: dict[str, object]) -> None:
    samples = result["samples"]
    assert isinstance(samples, list)
    rss60 = next((r for t, _, r in samples if t >= 60.0 - 1e-9), float("nan"))
    excess = float(result["close_peak_mb"]) - float(result["before_close_mb"])  # type: ignore[arg-type]
    print(f"{label:>9} {float(result['seconds']):8.0f} {rss60:9.1f} {float(result['run_max_mb']):9.1f} "  # type: ignore[arg-type]
          f"{float(result['before_close_mb']):9.1f} {float(result['close_peak_mb']):10.1f} {excess:+9.1f} "  # type: ignore[arg-type]
          f"{float(result['close_s']):8.1f} {int(result['archive_bytes']) / 1e9:8.2f}", flush=True)  # type: ignore[arg-type]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, nargs="+", default=[60.0, 600.0], help="simulated seconds per run")
    parser.add_argument("--every", type=float, default=60.0, help="sample RSS every N simulated seconds")
    parser.add_argument("--target", default="inprocess:an1017")
    parser.add_argument("--record-dir", default=None, help="record each run as NPZ in a fresh folder here")
    parser.add_argument("--record", default=None, help=argparse.SUPPRESS)  # the child's file
    parser.add_argument("--baseline-python", default=None, help="also run each length with this interpreter's hilbench")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.seconds[0], args.every, args.target, args.record)))
        return
    args.cwd = tempfile.gettempdir()  # not the repo: the baseline interpreter must import its own hilbench
    print(f"soak on {args.target}, recording {'NPZ' if args.record_dir else 'none'}; MB of RSS")
    print(f"{'tree':>9} {'sim s':>8} {'at 60 s':>9} {'run max':>9} {'pre-close':>9} {'close peak':>10} "
          f"{'excess':>9} {'close s':>8} {'NPZ GB':>8}")
    results: dict[tuple[str, float], dict[str, object]] = {}
    for seconds in args.seconds:
        for label, python in (("this", sys.executable), ("baseline", args.baseline_python)):
            if python is None:
                continue
            results[label, seconds] = _run_child(python, seconds, args, label)
            _print(label, results[label, seconds])
    if args.record_dir and len(args.seconds) > 1:
        short, long = min(args.seconds), max(args.seconds)
        for label in ("this", "baseline"):
            if (label, short) in results and (label, long) in results:
                grow = [float(results[label, s]["close_peak_mb"]) - float(results[label, s]["before_close_mb"])  # type: ignore[arg-type]
                        for s in (short, long)]
                print(f"{label}: close excess {grow[0]:+.1f} MB at {short:g} s, {grow[1]:+.1f} MB at {long:g} s "
                      f"(goal: < 100 MB, not growing)")


if __name__ == "__main__":
    main()
