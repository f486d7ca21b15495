"""The command line: click commands that turn options into calls and results into rich output.

No physics and no protocol logic lives here. Every HilbenchError becomes one line on stderr
and the error kind's exit code; nothing prints a traceback for a user's mistake.
"""

from __future__ import annotations

import functools
import sys
from typing import Any, Callable

import click

from hilbench import __version__
from hilbench.errors import HilbenchError


def _friendly(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn HilbenchError (and Ctrl-C) into one line and a non-zero exit code."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except HilbenchError as exc:
            click.echo(f"hilbench: {exc.kind}: {exc}", err=True)
            sys.exit(exc.exit_code)
        except KeyboardInterrupt:
            click.echo("hilbench: interrupted", err=True)
            sys.exit(130)

    return wrapper


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="hilbench")
def cli() -> None:
    """hilbench: hardware-in-the-loop bench for PMSM motor-control firmware.

    A host-side plant (PMSM, inverter, hall/encoder/ADC sensors, load) exchanges sensor values
    and PWM duties with a target every period: a dsPIC30F2010 running AN1017 on a serial port,
    or the included emulator of that firmware on a virtual serial pair.

    \b
    Start here:
      hilbench run                      the default bench: AN1017 emulator + Hurst motor
      hilbench link-test                round trips against the loopback target on a pty
      hilbench ports                    list serial ports
      hilbench emulate an1017           serve the emulated firmware on a virtual serial pair
    """


@cli.command()
@_friendly
def ports() -> None:
    """List serial ports (pyserial's list_ports) in a table."""
    from rich.console import Console
    from rich.table import Table
    from serial.tools import list_ports

    table = Table(title="serial ports")
    for column in ("device", "description", "hwid"):
        table.add_column(column)
    found = sorted(list_ports.comports(), key=lambda p: p.device)
    for port in found:
        table.add_row(port.device, port.description or "", port.hwid or "")
    console = Console()
    if found:
        console.print(table)
    else:
        console.print("no serial ports found (a virtual pair: `hilbench emulate an1017 --port pty`)")


_MODES = {"auto": None, "lockstep": 0, "realtime": 1}


@cli.command()
@click.argument("target", default="an1017")
@click.option("--port", "port_spec", default="pty", show_default=True,
              help="`pty` makes a virtual serial pair and prints the path to connect to; "
                   "or a tty PATH / serial:PATH?baud=N to serve on.")
@click.option("--mode", type=click.Choice(sorted(_MODES)), default="auto", show_default=True,
              help="auto follows the host's handshake; lockstep/realtime refuse a host asking otherwise.")
@click.option("--watchdog-ms", type=click.IntRange(0, 65535), default=None,
              help="Override the host's watchdog time in real-time mode (0 disables it).")
@click.option("--quiet", "-q", is_flag=True, help="Log only warnings and errors.")
@_friendly
def emulate(target: str, port_spec: str, mode: str, watchdog_ms: int | None, quiet: bool) -> None:
    """Serve an emulated TARGET (an1017, loopback) on a virtual serial pair or a tty.

    The first line on stdout is the path the host opens, e.g.
    `hilbench link-test serial:/dev/pts/5`. Serves until the host hangs up or Ctrl-C.
    """
    import logging

    from hilbench.targets.emulator import serve_on_port

    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO, stream=sys.stderr,
                        format="hilbench emulate: %(message)s")

    def announce(path: str) -> None:
        click.echo(path)
        sys.stdout.flush()

    report = serve_on_port(target, port_spec, _MODES[mode], {}, watchdog_ms=watchdog_ms, announce=announce)
    logging.getLogger("hilbench.serve").info(
        "served %d periods and %d requests; %s", report.sensors, report.requests, report.reason or "done"
    )


@cli.command("link-test")
@click.argument("target", default="pty")
@click.option("--periods", type=click.IntRange(min=1), default=10_000, show_default=True,
              help="Lockstep exchanges to run.")
@click.option("--period-us", type=click.IntRange(1, 65535), default=50, show_default=True,
              help="Period announced in the handshake (lockstep runs as fast as the link allows).")
@click.option("--timeout-ms", type=click.IntRange(1, 60_000), default=1000, show_default=True,
              help="How long to wait for each answer.")
@_friendly
def link_test(target: str, periods: int, period_us: int, timeout_ms: int) -> None:
    """Round trips against TARGET: `pty` (default: the loopback target as its own process on a
    virtual serial pair), exec:PROGRAM (a host-built target given the pty path, e.g. the C
    loopback target) or a link spec such as serial:/dev/ttyUSB0?baud=250000.

    Prints round trips/s, RTT p50/p99/max and every error counter.
    """
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    from hilbench.bench.linktest import run_link_test

    console = Console()
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("link test", total=periods)
        result = run_link_test(target, periods=periods, period_us=period_us, timeout_s=timeout_ms / 1000.0,
                               progress=lambda k: progress.update(task, completed=k))
    table = Table(title=f"link test: {result.firmware_name} via {result.target}")
    table.add_column("figure")
    table.add_column("value", justify="right")
    rows: list[tuple[str, str]] = [
        ("periods (good / asked)", f"{result.good} / {result.periods}"),
        ("round trips/s", f"{result.round_trips_per_s:,.0f}"),
        ("RTT p50", f"{result.rtt_p50_us:.1f} µs"),
        ("RTT p99", f"{result.rtt_p99_us:.1f} µs"),
        ("RTT max", f"{result.rtt_max_us:.1f} µs"),
        ("timeouts", str(result.timeouts)),
        ("mismatched Drives", str(result.mismatches) if result.firmware_name == "loopback" else "n/a"),
    ]
    rows += [(f"host link {key}", str(value)) for key, value in result.link.items()]
    rows += [(f"host {key}", str(value)) for key, value in result.remote.items()]
    rows += [(f"target {key}", str(value)) for key, value in result.target_status.items()]
    for name, value in rows:
        table.add_row(name, value)
    console.print(table)
    if result.errors:
        console.print(f"[yellow]{result.errors} errors counted[/yellow]")


def main() -> None:
    """Console-script entry point."""
    cli(prog_name="hilbench")


if __name__ == "__main__":
    main()
