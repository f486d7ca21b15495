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


def main() -> None:
    """Console-script entry point."""
    cli(prog_name="hilbench")


if __name__ == "__main__":
    main()
