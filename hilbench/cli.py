"""The command line: click commands that turn options into calls and results into rich output.

No physics and no protocol logic lives here. Every HilbenchError becomes one line on stderr
and the error kind's exit code; nothing prints a traceback for a user's mistake.
"""

from __future__ import annotations

import functools
import math
import sys
from typing import Any, Callable, Sequence

import click

from hilbench import __version__
from hilbench.errors import ConfigError, HilbenchError


class FiniteRange(click.FloatRange):
    """A FloatRange that also refuses nan and inf: click's range lets nan through (every comparison
    with it is false), and nan, inf or 1e308 then end in a traceback deep inside (a socket timeout,
    a period count)."""

    def __init__(self, min: float | None = None, max: float | None = None, *, unit: str,
                 min_open: bool = False) -> None:
        super().__init__(min, max, min_open=min_open)
        self.unit = unit

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        number = click.FLOAT.convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value} is not a finite number of {self.unit}", param, ctx)
        return super().convert(number, param, ctx)


#: bounds of the speeds and times a step or a sweep takes: those of the config's [[scenario]]
#: ref_rpm and [run] duration_s
SPEED_RPM = FiniteRange(-20000, 20000, unit="rpm")
SECONDS = FiniteRange(0, 86400, unit="seconds", min_open=True)


def _json_text(value: Any) -> str:
    """A --json output: JSON proper (a figure that is not finite as "inf", "-inf" or "nan": JSON has
    no Infinity or NaN, and parsers refuse them)."""
    import json

    from hilbench.bench.report import json_safe

    return json.dumps(json_safe(value), indent=2, default=str, allow_nan=False)


def _refuse_unwritable_outputs(outputs: dict[str, str | None]) -> None:
    """Each output file can be written, checked before the work (a step or sweep of minutes must not
    fail at its end): a name, a folder that exists (none is made from a mistyped path), not a
    running session's recording."""
    from pathlib import Path

    from hilbench.bench.fileio import HELD_REASON
    from hilbench.bench.recorder import held_by_a_running_session

    for option, name in outputs.items():
        if name == "":
            raise ConfigError(f"{option}: an empty file name")
        if name is not None and not Path(name).absolute().parent.is_dir():
            raise ConfigError(f"{option} {name}: no folder {Path(name).absolute().parent} to write it in")
        if name is not None and option != "--resume" and held_by_a_running_session(name):
            raise ConfigError(f"{option} {name}: {HELD_REASON}")


#: the longest error line printed whole: a message quoting a 100 kB word the user gave is cut
ERROR_LINE_MAX_CHARS = 400


def _cut(line: str) -> str:
    """``line`` with its middle left out when it is longer than ERROR_LINE_MAX_CHARS."""
    if len(line) <= ERROR_LINE_MAX_CHARS:
        return line
    head, tail = line[:ERROR_LINE_MAX_CHARS - 100], line[-60:]
    return f"{head} ...({len(line) - len(head) - len(tail)} characters left out)... {tail}"


def _friendly(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn HilbenchError (and Ctrl-C) into one line and a non-zero exit code."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except HilbenchError as exc:
            lines = [_cut(line.strip()) for line in str(exc).splitlines() if line.strip()]
            text = lines[0] if len(lines) == 1 else f"{len(lines)} problems: " + "; ".join(lines)
            records = getattr(exc, "records", "")
            if records:  # a divergence's periods around it, both sides (stdout: the error stays one line)
                click.echo(records)
            click.echo(f"hilbench: {exc.kind}: {text}", err=True)  # one line, however many problems
            sys.exit(exc.exit_code)
        except KeyboardInterrupt:
            click.echo("hilbench: interrupted", err=True)
            sys.exit(130)
        except OSError as exc:  # a file the user named: a directory, a missing folder, no permission
            name = f"{exc.filename}: " if exc.filename else ""
            click.echo(f"hilbench: file error: {_cut(f'{name}{exc.strerror or exc}')}", err=True)
            sys.exit(1)

    return wrapper


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="hilbench")
def cli() -> None:
    """hilbench: hardware-in-the-loop bench for PMSM motor-control firmware.

    A host-side plant (PMSM, inverter, hall/encoder/ADC sensors, load) exchanges sensor values
    and PWM duties with a target every period: a board on a serial port running firmware built
    with hilbench's protocol library, or an emulator of that firmware on a virtual serial pair.

    \b
    Start here:
      hilbench run                      the default bench (emulator process + the Hurst motor)
      hilbench targets                  the targets this installation knows
      hilbench link-test                round trips against the loopback target on a pty
      hilbench ports                    list serial ports
      hilbench emulate                  serve the default firmware's emulator on a virtual serial pair
    """
    from hilbench.processes import watch_parent

    watch_parent()  # started by a bench (run --scope's scope, link-test's emulator): end with it


def _default_target_name() -> str:
    from hilbench.targets import DEFAULT_TARGET

    return DEFAULT_TARGET.partition(":")[2]


@cli.command()
@_friendly
def targets() -> None:
    """List the registered targets (built in, and from installed plug-ins) with what they offer."""
    from rich.console import Console
    from rich.table import Table

    from hilbench.targets.registry import broken_plugins, get_profile, known_targets

    table = Table(title="targets (use as inprocess:NAME or emulator:NAME)")
    for column in ("name", "firmware", "tunable", "reference", "telemetry", "description"):
        table.add_column(column)
    for name in known_targets():
        p = get_profile(name)
        table.add_row(name, p.firmware_name, " ".join(p.tunable) or "—", p.reference.kind if p.reference else "—",
                      " ".join(c.column for c in p.telemetry) or "—", p.description)
    Console().print(table)
    for problem in broken_plugins():
        click.echo(f"left out: {problem}", err=True)


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
        console.print("no serial ports found (a virtual pair: `hilbench emulate --port pty`)")


_MODES = {"auto": None, "lockstep": 0, "realtime": 1}
#: how long `run --scope` lets its scope process relay the last replies and close its pages
SCOPE_GRACE_S = 3.0


@cli.command()
@click.argument("target", default=None, required=False)
@click.option("--port", "port_spec", default="pty", show_default=True,
              help="`pty` makes a virtual serial pair and prints the path to connect to; tcp:PORT (0: any "
                   "free port) listens and prints the socket://HOST:PORT URL; or a tty PATH / serial:PATH?baud=N.")
@click.option("--mode", type=click.Choice(sorted(_MODES)), default="auto", show_default=True,
              help="auto follows the host's handshake; lockstep/realtime refuse a host asking otherwise.")
@click.option("--watchdog-ms", type=click.IntRange(0, 65535), default=None,
              help="Override the host's watchdog time in real-time mode (0 disables it).")
@click.option("--option", "-o", "options", multiple=True, metavar="KEY=VALUE",
              help="A [target] option of TARGET, e.g. -o variant=v11 (see the target's config docs).")
@click.option("--quiet", "-q", is_flag=True, help="Log only warnings and errors.")
@click.option("--once", is_flag=True, help="Exit when the first host hangs up (default: serve host after host, "
                                           "as a board does, until Ctrl-C).")
@_friendly
def emulate(target: str | None, port_spec: str, mode: str, watchdog_ms: int | None, options: tuple[str, ...],
            quiet: bool, once: bool) -> None:
    """Serve an emulated TARGET (default: the default target; `hilbench targets` lists them) on a
    virtual serial pair or a tty.

    The first line on stdout is the path the host opens, e.g.
    `hilbench link-test serial:/dev/pts/5`. Serves one host after another until Ctrl-C (--once: until
    the first host hangs up).
    """
    import logging

    from hilbench.targets.emulator import serve_on_port

    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO, stream=sys.stderr,
                        format="hilbench emulate: %(message)s")

    def announce(path: str) -> None:
        click.echo(path)
        sys.stdout.flush()

    from hilbench.config import clipped, parse_value

    values: dict[str, object] = {}
    texts: dict[str, str] = {}
    for word in options:
        key, sep, text = word.partition("=")
        if not sep:
            raise ConfigError(f"--option {clipped(repr(word), 80)}: expected KEY=VALUE, e.g. variant=v11")
        values[key.strip()], texts[key.strip()] = parse_value(text), text
    target = target or _default_target_name()
    _check_option_names(target, values)
    _check_option_values(target, texts)
    report = serve_on_port(target, port_spec, _MODES[mode], values, watchdog_ms=watchdog_ms, announce=announce,
                           keep_serving=not once)
    logging.getLogger("hilbench.serve").info(
        "served %d periods and %d requests; %s", report.sensors, report.requests, report.reason or "done"
    )


def _check_option_names(target: str, values: dict[str, object]) -> None:
    """Refuse an -o KEY the target does not have: the profile would drop it and serve without it."""
    from hilbench.targets import get_profile

    known = get_profile(target).option_names()  # an unknown target: ConfigError listing the known ones
    unknown = [key for key in values if key not in known]
    if unknown:
        offer = f"known: {', '.join(known)}" if known else "it takes no options"
        from hilbench.config import clipped

        raise ConfigError(f"--option {clipped(', '.join(unknown), 80)}: not an option of target {target!r} ({offer})")


def _check_option_values(target: str, texts: dict[str, str]) -> None:
    """The -o values checked as a config's [target] table is (types, ranges): the emulator would
    take `kp=abc` as it came, and serve without it."""
    import json

    from hilbench.bench.settings import load_config
    from hilbench.config import Override

    load_config(None, [Override(f"link.target={json.dumps('inprocess:' + target)}", f"target {target!r}"),
                       *(Override(f"target.{key}={text}", f"-o {key}") for key, text in texts.items())])


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
        ("periods (good / asked)", f"{result.good} / {result.periods}"
                                   + (f" (interrupted after {result.attempted})" if result.interrupted else "")),
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
    if result.interrupted:
        click.echo("hilbench: interrupted: the figures above are those of the periods run", err=True)
        sys.exit(130)
    if result.failure:  # the table stays: it says what was lost; the exit code says the link failed
        from hilbench.errors import LinkError

        raise LinkError(result.failure)


@cli.command()
@click.argument("target")
@click.option("--period-us", type=click.IntRange(1, 65535), default=50, show_default=True,
              help="Period announced in the handshakes (a multiple of the firmware's PWM period).")
@click.option("--only", "only", multiple=True, metavar="TEXT", help="Run only the checks whose names contain TEXT.")
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON.")
@_friendly
def conformance(target: str, period_us: int, only: tuple[str, ...], as_json: bool) -> None:
    """Check that TARGET keeps the protocol's promises: handshake and fingerprint, self-description,
    parameter describe/get/set (all or nothing, each result code), a repeated seq answered once,
    stop/start, the watchdog in lockstep and real time, bad frames counted and never acted on.

    TARGET is any spec: inprocess:NAME, emulator:NAME, sil:NAME|PATH, simavr:NAME|PATH, qemu:NAME|PATH,
    serial:/dev/ttyUSB0?baud=250000 (a board running a firmware on the hilbench runtime). Exit 1 if
    a check fails; what a build leaves out and refuses as the protocol says (real time, ParamDescribe)
    is "not served", no failure.
    """
    import json

    from hilbench.bench.conformance import as_dicts, run_checks

    results = run_checks(target, period_us=period_us, only=only)
    if as_json:
        click.echo(json.dumps({"target": target, "checks": as_dicts(results)}, indent=2))
    else:
        from rich.console import Console
        from rich.markup import escape
        from rich.table import Table

        table = Table(title=f"conformance: {escape(target)}")
        table.add_column("check")
        table.add_column("result")
        table.add_column("detail")
        colour = {"PASS": "green", "FAIL": "red", "skip": "yellow", "not served": "cyan"}
        for r in results:
            table.add_row(escape(r.name), f"[{colour[r.status]}]{r.status}[/{colour[r.status]}]", escape(r.detail))
        Console().print(table)
    if any(r.ok is False for r in results):
        sys.exit(1)


@cli.command(context_settings={"show_default": True})
@click.argument("config", required=False, type=click.Path(dir_okay=False))
@click.option("--target", "target_spec", default=None, metavar="SPEC",
              help="emulator:NAME (the default: its own process on a virtual serial pair), inprocess:NAME, "
                   "a board: serial:/dev/ttyUSB0?baud=250000, or a pyserial URL (socket://HOST:PORT, rfc2217://...). "
                   "`hilbench targets` lists the NAMEs.")
@click.option("--mode", type=click.Choice(["lockstep", "realtime", "monitor"]), default=None,
              help="lockstep: the host is the clock (deterministic); realtime: periods paced to the wall clock (idle CPUs kept awake while it runs when allowed: link.cpu_latency_qos); "
                   "monitor: the board runs its real motor (a real-motor build, make MODE=motor), no plant: its telemetry stream is recorded every link.period_us, gains and the reference are written live.")
@click.option("--duration", "duration_s", type=click.FloatRange(min=0, min_open=True), default=None,
              metavar="S", help="Simulated seconds (default: the scenario's end).")
@click.option("--record", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Keep every period in FILE (.csv or .npz), written as the run goes.")
@click.option("--set", "overrides", multiple=True, metavar="TABLE.KEY=VALUE",
              help="Override one config value, e.g. --set target.kp=0.2 --set link.period_us=100, an item of an "
                   "array of tables (--set adc.1.gain_codes_per_unit=150) or a whole one (--set 'scenario=[{...}]').")
@click.option("--scenario", "scenario_file", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="A file of [[scenario]] tables that replaces the config's scenario.")
@click.option("--gains-file", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Start with the parameters saved by `hilbench ctl save` or `hilbench sweep --save`.")
@click.option("--no-ui", is_flag=True, help="No live dashboard; print a plain summary at the end.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON (implies --no-ui).")
@click.option("--no-control", is_flag=True, help="Do not open the control socket for `hilbench ctl`.")
@click.option("--scope", "scope", is_flag=True, help="Serve the live scope page on 127.0.0.1 (URL printed; needs the scope extra).")
@click.option("--open", "open_browser", is_flag=True, help="With --scope: open the page in the browser.")
@_friendly
def run(config: str | None, target_spec: str | None, mode: str | None, duration_s: float | None,
        record: str | None, overrides: tuple[str, ...], gains_file: str | None, no_ui: bool, as_json: bool,
        no_control: bool, scope: bool = False, open_browser: bool = False, scenario_file: str | None = None) -> None:
    """Run a bench session: target + plant + scenario, live, recorded.

    With no arguments: the default target's emulator as its own process on a virtual serial pair,
    the Hurst DMB0224C10002 on the MCLV board, and the default scenario (S2, ramp to 1500 rpm, step to 2500,
    reverse to -1500, stop), lockstep at 20 kHz, with the live dashboard and a summary at the end.

    \b
    Examples:
      hilbench run
      hilbench run bench_configs/hurst_mclv.toml --record run.csv
      hilbench run --set target.kp=0.15 --duration 2 --no-ui
      hilbench run --target serial:/dev/ttyUSB0?baud=250000 --mode realtime --set link.period_us=1000
      hilbench run --target serial:/dev/ttyUSB0?baud=250000 --mode monitor --set link.period_us=2000 --record motor.csv
      hilbench run --target 'sil:NAME?wire_baud=250000&twin=auto'   (a build with a host twin: the twin
        runs ahead, the target confirms batches of periods; `hilbench targets` lists the NAMEs)
    While it runs, `hilbench ctl get|set|ref|load` talks to it from another terminal.
    The summary ends with the config's [[check]] verdicts; a failed check exits with code 9;
    a twin-speculative run whose target differs from its twin exits with code 10.
    """

    from rich.console import Console

    from hilbench.bench.run import RunRequest, check_overrides, load_run_config, run_bench
    from hilbench.ui.dashboard import Dashboard, summary_table, summary_text

    from hilbench.bench.settings import params_file_overrides

    extra = params_file_overrides(gains_file) if gains_file else ()
    request = RunRequest(config, check_overrides(overrides) + extra, target_spec, mode, duration_s, record,
                         scenario=scenario_file)
    cfg = load_run_config(request)  # (run_bench checks what the host and link allow, and warns)
    if cfg.run.mode == "monitor":
        _run_monitor(cfg, record, no_control, plain=no_ui or as_json, as_json=as_json, scope=scope,
                     open_browser=open_browser)
        return
    control = None
    if not no_control:
        from hilbench.bench.control import ControlServer

        control = ControlServer()

    def announce(session: Any) -> None:  # once the target answered: an error stays one line
        if control is not None:
            click.echo(f"hilbench: control socket {control.path} (hilbench ctl --socket {control.path} ...)", err=True)

    scope_server: Any = None
    if scope:  # `hilbench scope` on the run's control socket, as a child process
        from hilbench.scope.launch import ScopeProcess

        if control is None:
            raise ConfigError("run --scope needs the control socket (drop --no-control)")
        scope_server = ScopeProcess(control.path, open_browser=open_browser)
    console = Console()
    try:
        if no_ui or as_json or not console.is_terminal:
            summary = run_bench(cfg, record=record, control=control, on_ready=announce,
                                warn=lambda text: click.echo(f"hilbench: warning: {text}", err=True))
        else:
            dashboard = Dashboard(cfg.link.target, cfg.run.duration_s, console=console)

            import contextlib

            keys: Any = contextlib.nullcontext()
            if control is not None:
                from hilbench.ui.keys import CommandLine

                keys = dashboard.command_line = CommandLine(control.path, dashboard.replies.append)
            with keys, dashboard:
                summary = run_bench(cfg, record=record, observer=dashboard, control=control, on_ready=dashboard.attach,
                                    warn=dashboard.warnings.append)  # kept on top of every frame (and in the summary)
    finally:
        if control is not None:  # first: the scope sees its session gone, relays what is on its way, ends
            control.close()
            note = control.trouble()
            if note:
                click.echo(f"hilbench: warning: control socket: {note}", err=True)
        if scope_server is not None:
            scope_server.close(grace_s=SCOPE_GRACE_S)
    from hilbench.bench.checks import checks_text, raise_if_failed

    if as_json:
        click.echo(_json_text(summary.as_dict()))
    elif no_ui or not console.is_terminal:
        click.echo(summary_text(summary))
    else:
        console.print(summary_table(summary))
    if summary.checks and not as_json:
        click.echo(checks_text(summary.checks))
    raise_if_failed(summary.checks)  # exit code 9: a [[check]] did not hold (6: one could not read the recording)


def _run_monitor(cfg: Any, record: str | None, no_control: bool, plain: bool, as_json: bool = False,
                 scope: bool = False, open_browser: bool = False) -> None:
    """`run --mode monitor`: the board's stream recorded, `ctl` on the control socket, the live
    dashboard on a terminal (the measured speed; no plant currents), a summary."""
    import contextlib

    from rich.console import Console

    from hilbench.bench.checks import checks_text, raise_if_failed
    from hilbench.bench.monitorrun import run_monitor
    from hilbench.ui.dashboard import Dashboard, summary_text

    control = None
    if not no_control:
        from hilbench.bench.control import ControlServer

        control = ControlServer()

    def announce(session: Any) -> None:
        if control is not None:
            click.echo(f"hilbench: control socket {control.path} (hilbench ctl --socket {control.path} ...)", err=True)

    scope_server: Any = None
    if scope:  # the live scope on the run's control socket, as in a HIL run
        from hilbench.scope.launch import ScopeProcess

        if control is None:
            raise ConfigError("run --scope needs the control socket (drop --no-control)")
        scope_server = ScopeProcess(control.path, open_browser=open_browser)
    console = Console()
    try:
        if plain or not console.is_terminal:
            summary = run_monitor(cfg, record=record, control=control, on_ready=announce)
        else:
            dashboard = Dashboard(cfg.link.target, cfg.run.duration_s, console=console)
            keys: Any = contextlib.nullcontext()
            if control is not None:
                from hilbench.ui.keys import CommandLine

                keys = dashboard.command_line = CommandLine(control.path, dashboard.replies.append)

            def ready(session: Any) -> None:
                dashboard.params = session.param_values()
                session.on_params = dashboard.params.update

            with keys, dashboard:
                summary = run_monitor(cfg, record=record, control=control, on_ready=ready, observer=dashboard)
    finally:
        if control is not None:
            control.close()
        if scope_server is not None:
            scope_server.close(grace_s=SCOPE_GRACE_S)
    if as_json:
        click.echo(_json_text(summary.as_dict()))
    else:
        click.echo(summary_text(summary))
        if summary.checks:
            click.echo(checks_text(summary.checks))
    raise_if_failed(summary.checks)


@cli.command()
@click.argument("recording", type=click.Path(dir_okay=False))
@click.option("--plot", "plot_dir", type=click.Path(file_okay=False), default=None, metavar="DIR",
              help="Write PNG plots (speed, currents, duties, hall, link) into DIR (needs the plot extra); "
                   "a figure whose columns the recording lacks is left out and named in 'plots left out'.")
@click.option("--csv", "csv_file", type=click.Path(dir_okay=False), default=None, metavar="FILE.csv",
              help="Also write the recording as CSV (e.g. from a fast .npz run).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.option("--window", "window", default=None, metavar="T0:T1", help="Plot only simulated seconds T0..T1 (e.g. 1.0:1.05).")
@click.option("--open", "open_viewer", is_flag=True, help="Show the recording in the scope's viewer (served on 127.0.0.1 until Ctrl-C).")
@click.option("--overlay", "overlay", multiple=True, type=click.Path(dir_okay=False), metavar="OTHER",
              help="With --plot: one more figure with the speed of this recording and of OTHER on one time axis "
                   "(a HIL run and a real-motor run of the same scenario; repeat for more).")
@_friendly
def report(recording: str, plot_dir: str | None, csv_file: str | None, as_json: bool, window: str | None = None,
           open_viewer: bool = False, overlay: tuple[str, ...] = ()) -> None:
    """Summarise a recording (CSV, NPZ, or the journal of a run that was killed).

    \b
    Examples:
      hilbench report run.npz --plot plots/
      hilbench report run.npz --csv run.csv
      hilbench report run.npz --open
      hilbench report motor.csv --plot plots/ --overlay hil.csv
    """
    from pathlib import Path

    from rich.console import Console
    from rich.table import Table

    from hilbench.bench.column_chunks import recording_chunks
    from hilbench.bench.recording_head import read_head
    from hilbench.bench.report import summarise_chunks

    if plot_dir is None and (overlay or window is not None):  # (before anything is read or written)
        raise ConfigError(f"report {'--overlay' if overlay else '--window'} chooses what --plot draws: "
                          "give --plot DIR")
    source = recording_chunks(recording)  # read a chunk of rows at a time: memory bounded however long
    head = read_head(source)
    info = summarise_chunks(head, source)
    if csv_file is not None:
        from hilbench.bench.csv_export import export_csv_chunks

        info["csv"] = str(export_csv_chunks(head, source, csv_file))
    if plot_dir is not None:
        from hilbench.ui.plots import parse_window, plot_recording_chunks

        shown = parse_window(window)
        plots = plot_recording_chunks(head, source, Path(plot_dir), window=shown)
        if overlay:
            from hilbench.ui.plots import Plots, plot_speed_overlay_chunks

            others = [recording_chunks(other) for other in overlay]
            heads = [(head, source), *((read_head(other), other) for other in others)]
            overlaid = plot_speed_overlay_chunks(heads, Path(plot_dir), window=shown)
            plots = Plots(plots.paths + overlaid.paths, plots.left_out + overlaid.left_out)
        info["plots"] = [str(p) for p in plots]
        if plots.left_out:  # what the recording's columns could not draw (a monitor run: no plant currents)
            info["plots_left_out"] = "; ".join(plots.left_out)
    if as_json:
        click.echo(_json_text(info))
        return
    table = Table(title=f"recording {recording}", show_header=False)
    table.add_column("what", style="bold")
    table.add_column("value")
    for key, value in info.items():
        if isinstance(value, list):
            value = "\n".join(str(v) for v in value) or "—"
        table.add_row(key.replace("_", " "), str(value))
    Console().print(table)
    if open_viewer:
        from hilbench.scope.launch import scope_for_recording

        scope_for_recording(recording, open_browser=True).serve_forever()  # type: ignore[attr-defined]


@cli.command()
@click.option("--socket", "socket_path", default=None, metavar="PATH",
              help="The session's control socket (default: as `hilbench ctl` picks the session).")
@click.option("--session", "session_selector", default=None, metavar="PID|N",
              help="The session by its pid or its number in `hilbench ctl list`.")
@click.option("--port", type=click.IntRange(0, 65535), default=0, show_default=True, help="TCP port on 127.0.0.1 (0: any free one).")
@click.option("--open", "open_browser", is_flag=True, help="Open the page in the browser.")
@_friendly
def scope(socket_path: str | None, session_selector: str | None, port: int, open_browser: bool) -> None:
    """Serve the live scope page for a running `hilbench run` (until Ctrl-C).

    The page (127.0.0.1, a secret token in its URL) shows any recorded column live, with
    trigger, cursors and markers, and tunes the target's parameters through the control socket.
    """
    from hilbench.bench.control import read_discovery
    from hilbench.scope.launch import scope_for_socket

    if socket_path is not None and session_selector is not None:
        raise ConfigError("scope: give --socket or --session, not both")
    path = socket_path if socket_path is not None else read_discovery(selector=session_selector)
    scope_for_socket(path, port, open_browser).serve_forever()  # type: ignore[attr-defined]


@cli.command(context_settings={"ignore_unknown_options": True})
@click.argument("words", nargs=-1, type=click.UNPROCESSED)
@click.option("--socket", "socket_path", default=None, metavar="PATH",
              help="The session's control socket (default: the only running session, else the one started in this "
                   "directory or terminal; otherwise ctl refuses and lists them).")
@click.option("--session", "session_selector", default=None, metavar="PID|N",
              help="The session by its pid or its number in `hilbench ctl list` (1: the newest).")
@click.option("--timeout", "timeout_s", type=FiniteRange(0.1, 3600, unit="seconds"), default=None,
              help="Seconds to wait for the answer (default: 5; `step`: 120, it answers after the step).")
@click.option("--json", "as_json", is_flag=True, help="Print the session's whole reply as one JSON object.")
@_friendly
def ctl(words: tuple[str, ...], socket_path: str | None, session_selector: str | None, timeout_s: float | None,
        as_json: bool) -> None:
    """Talk to a running `hilbench run` through its control socket.

    \b
    hilbench ctl get                     gains and parameters now (JSON when piped)
    hilbench ctl set kp=0.1 ki=0.01      write a gain set (checked, applied atomically)
    hilbench ctl ref 1500                speed reference in rpm (negative: reverse)
    hilbench ctl load 0.02               load torque in N*m
    hilbench ctl step 1000 2000          reference step from 1000 to 2000 rpm
    hilbench ctl save gains.toml         write the gains as a config fragment
    hilbench ctl guard on|off            guarded tuning: restore gains after a bad response
    hilbench ctl press s2|s3             press a board button (S2 starts and stops the motor)
    hilbench ctl start                   the target's Start command (restart after a stop)
    hilbench ctl stop                    end the run (recording closed, target stopped)
    hilbench ctl list                    the running sessions, numbered (--session N picks one)

    With several sessions running, ctl talks to the one started in this directory (or terminal);
    otherwise it refuses and lists them: pick one with --session PID|N or --socket PATH.
    """
    import json as json_module

    from hilbench.bench.control import ControlClient, list_sessions, parse_ctl_args, read_discovery
    from hilbench.errors import TargetError

    if list(words[:1]) == ["list"]:
        sessions = list_sessions()
        rows = [{"socket": str(i.socket_path), "pid": i.pid, "started_s": i.started_s, "cwd": i.cwd} for i in sessions]
        if as_json:
            click.echo(json_module.dumps(rows))
        elif not rows:
            click.echo("no running sessions")
        else:
            import time as time_module

            for n, row in enumerate(rows, 1):
                age = time_module.time() - float(row["started_s"])
                click.echo(f"#{n}  pid {row['pid']}  {row['socket']}  started {age:.0f} s ago in {row['cwd']}")
        return
    request = parse_ctl_args(list(words))
    if timeout_s is None:
        timeout_s = 120.0 if request["cmd"] == "step" else 5.0
    if socket_path is None:  # never a guess among several sessions (hilbench.bench.control.choose_session)
        socket_path = str(read_discovery(selector=session_selector))
    elif session_selector is not None:
        raise ConfigError("ctl: give --socket or --session, not both")
    client = ControlClient(socket_path, timeout_s=timeout_s)
    if request["cmd"] == "save":  # the file is written here, where the user is, from the session's values
        from hilbench.bench.tuning import saved_fragment, write_fragment

        reply = client.request({"cmd": "get"}, timeout_s=timeout_s)
        if not reply.get("ok"):
            raise TargetError(str(reply.get("message", "refused")))
        text = saved_fragment(reply.get("data"))
        write_fragment(request["file"], text)  # (not onto a recording a session writes) an OSError: exit 1
        if as_json:
            click.echo(json_module.dumps({"ok": True, "message": f"wrote {request['file']}", "data": reply["data"]}))
        else:
            click.echo(f"wrote {request['file']}:\n{text}", nl=False)
        return
    reply = client.request(request, timeout_s=timeout_s)
    if as_json:  # the reply as it came, refusals included (exit status 5 then)
        click.echo(json_module.dumps(reply))
        if not reply.get("ok"):
            sys.exit(TargetError.exit_code)
        return
    if not reply.get("ok"):
        raise TargetError(str(reply.get("message", "refused")))
    if reply.get("data") and not sys.stdout.isatty():
        click.echo(json_module.dumps(reply["data"], indent=2, default=str))  # JSON alone on stdout: pipe it
        click.echo(reply.get("message", "ok"), err=True)
    elif reply.get("data"):  # a person reads it: one fact a line, as the dashboard shows them
        click.echo(ctl_text(str(request["cmd"]), reply))
    else:
        click.echo(reply.get("message", "ok"))


def ctl_text(cmd: str, reply: dict[str, Any]) -> str:
    """A control reply for a terminal: `get` as a table of parameters, others as their message."""
    data = reply.get("data") or {}
    if cmd != "get" or not isinstance(data, dict):
        return str(reply.get("message", "ok"))
    params = data.get("params") or {}
    tunable = set(data.get("tunable") or ())
    width = max((len(str(name)) for name in params), default=0)
    lines = [f"{name:<{width}}  {value:.6g}" + ("   (tunable)" if name in tunable else "")
             for name, value in params.items() if isinstance(value, (int, float))]
    lines.append(f"reference {data.get('ref_rpm', 0):g} rpm at t={data.get('t_s', 0):.3f} s")
    lines += [str(trip) for trip in data.get("guard_trips") or ()]  # "guard: why; restored ..."
    return "\n".join(lines)


@cli.command(context_settings={"show_default": True})
@click.argument("config", required=False, type=click.Path(dir_okay=False))
@click.option("--from", "from_rpm", type=SPEED_RPM, default=1000.0,
              help="Speed before the step, rpm (0: start from rest).")
@click.option("--to", "to_rpm", type=SPEED_RPM, default=2000.0, help="Speed after the step, rpm (negative: reverse).")
@click.option("--gains", "gains", multiple=True, metavar="V1,V2,...|NAME=V,...",
              help="A set of the target's tunable parameters (in their order, or by name); repeat to compare "
                   "several. Default: the firmware's own.")
@click.option("--target", "target_spec", default=None, metavar="SPEC",
              help="Default: the configured target's in-process model (fast); emulator:NAME (its own process "
                   "on a pty) or a board's serial port.")
@click.option("--settle", "settle_s", type=SECONDS, default=0.5, help="Seconds at --from before the step.")
@click.option("--after", "after_s", type=SECONDS, default=0.5, help="Seconds recorded after the step (0.5 + 0.5 s: the same test as `hilbench sweep`).")
@click.option("--set", "overrides", multiple=True, metavar="TABLE.KEY=VALUE", help="Override a config value.")
@click.option("--plot", "plot_file", type=click.Path(dir_okay=False), default=None, metavar="FILE.png",
              help="One overlay plot of every response (needs the plot extra).")
@click.option("--csv", "csv_file", type=click.Path(dir_okay=False), default=None, metavar="FILE.csv",
              help="Write the metrics of every gain set as CSV.")
@click.option("--json", "as_json", is_flag=True, help="Print the metrics as JSON.")
@click.option("--mode", type=click.Choice(["lockstep", "monitor"]), default="lockstep", show_default=True,
              help="monitor: the step on the board's real motor (--target its port; a real-motor build): the figures "
                   "from the firmware's measured speed, the reference written live.")
@click.option("--record", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="monitor: keep the run's rows in FILE (.csv or .npz), the same format as a HIL run's.")
@_friendly
def step(config: str | None, from_rpm: float, to_rpm: float, gains: tuple[str, ...], target_spec: str | None,
         settle_s: float, after_s: float, overrides: tuple[str, ...], plot_file: str | None,
         csv_file: str | None, as_json: bool, mode: str = "lockstep", record: str | None = None) -> None:
    """Run a speed step and measure it: rise (10-90 %), overshoot, settling (2 %), steady-state
    error and ripple, IAE, ITAE, peak current. Several --gains give one comparison table.

    \b
    Examples:
      hilbench step --from 1000 --to 2000
      hilbench step --gains 0.1,0.01,0 --gains 0.2,0.02,0 --plot steps.png
      hilbench step --gains kp=0.2,ki=0.02 --from 1500 --to -1500
      hilbench step --mode monitor --target serial:/dev/ttyUSB0?baud=250000 --from 1000 --to 1500
    The config's step_* [[check]] tables are judged on every gain set; a failed one exits with code 9.
    """
    from pathlib import Path

    from rich.console import Console
    from rich.progress import Progress

    from hilbench.bench.run import RunRequest, check_overrides, in_process, load_run_config, run_step_tests, settings_profile
    from hilbench.bench.steptest import StepTest, parse_gain_sets, require_speed_loop, result_row

    _refuse_unwritable_outputs({"--plot": plot_file, "--csv": csv_file, "--record": record})
    if plot_file and Path(plot_file).suffix:
        from hilbench.ui.plots import PLOT_FORMATS

        if Path(plot_file).suffix[1:].lower() not in PLOT_FORMATS:
            raise ConfigError(f"--plot {plot_file}: a plot is written as {', '.join(PLOT_FORMATS)} (the file's suffix)")
    test = StepTest(from_rpm, to_rpm, settle_s, after_s)
    cfg = load_run_config(RunRequest(config, check_overrides(overrides), target_spec, mode))
    if mode == "monitor" and target_spec is None:
        raise ConfigError("step --mode monitor needs --target: the board's port (e.g. serial:/dev/ttyUSB0?baud=250000)")
    if target_spec is None:
        cfg = in_process(cfg)
    profile = settings_profile(cfg)
    require_speed_loop(profile, "step")
    sets = parse_gain_sets(gains, profile.tunable)
    if record is not None and (mode != "monitor" or len(sets) > 1):
        raise ConfigError("step --record keeps the rows of one real step (--mode monitor, one gain set); "
                          + ("give one --gains" if mode == "monitor" else
                             "a lockstep step's rows: hilbench run --record with the same scenario"))
    target_spec = cfg.link.target
    console = Console(stderr=True)
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("step tests", total=max(1, len(sets)))
        if mode == "monitor":  # one real step per gain set, one after the other on the same motor
            from hilbench.bench.monitorrun import monitor_step

            results = []
            for index, gain_set in enumerate(sets or [{}]):
                results.append(monitor_step(cfg, test, gain_set, record=record,
                                            warn=lambda text: console.print(f"[yellow]warning:[/] {text}")))
                progress.update(task, completed=index + 1)
        else:
            results = run_step_tests(cfg, test, sets, progress=lambda done, total: progress.update(task, completed=done))
    from hilbench.bench.checks import checks_text, raise_if_failed, step_checks

    verdicts = [step_checks(cfg.check, r, profile.firmware_name) for r in results]
    rows = [result_row(r) for r in results]
    if csv_file:
        import csv

        from hilbench.bench.outputs import open_output

        with open_output(csv_file) as handle:  # (not onto a recording a session writes)
            writer = csv.DictWriter(handle, fieldnames=list(rows[0].keys()))
            writer.writeheader()
            writer.writerows(rows)
    if plot_file:
        from hilbench.ui.plots import plot_overlay

        # each curve named by its parameters; the reference as the firmware reports it (a firmware may
        # ramp it after an alignment), else the ideal step
        curves = [(" ".join(f"{k}={v:.4g}" for k, v in r.gains.items()) or r.label, r.t_s, r.speed_rpm) for r in results]
        first = results[0]
        reference = first.firmware_ref_rpm if first.firmware_ref_rpm is not None else [first.ref_rpm] * len(first.t_s)
        plot_overlay(curves, (first.t_s, reference), Path(plot_file), f"speed step {from_rpm:g} → {to_rpm:g} rpm",
                     reference_label="reference (firmware)" if first.firmware_ref_rpm is not None else "reference")
    every = [v for per_set in verdicts for v in per_set]
    if as_json:
        if every:  # each gain set's verdicts beside its metrics
            rows = [{**row, "checks": [v.as_dict() for v in per_set]} for row, per_set in zip(rows, verdicts)]
        click.echo(_json_text(rows))
        raise_if_failed(every)
        return
    _wide_console().print(step_table([(r.label, r.metrics) for r in results], f"speed step {from_rpm:g} → {to_rpm:g} rpm ({target_spec})"))
    if plot_file:
        Console().print(f"plot: {plot_file}")
    if every:
        click.echo(checks_text(every))
    raise_if_failed(every)  # exit code 9: a step [[check]] of the config did not hold


def _wide_console():  # type: ignore[no-untyped-def]
    """A console for tables: the terminal's width, or 120 columns when piped (not rich's 80)."""
    from rich.console import Console

    console = Console()
    return console if console.is_terminal else Console(width=120)


def step_table(rows, title: str, sort_by: str | None = None):  # type: ignore[no-untyped-def]
    """A compact comparison table of step metrics (fits 100 columns)."""
    from rich.table import Table

    from hilbench.bench.metrics import compare_table

    columns = (
        ("rise_time_s", "rise ms", 1e3, ".0f"), ("overshoot_pct", "ovs %", 1, ".1f"),
        ("settling_time_s", "settle ms", 1e3, ".0f"), ("ss_error_pct", "ss err %", 1, ".2f"),
        ("ss_ripple", "ripple rpm", 1, ".1f"), ("iae", "IAE", 1, ".1f"), ("itae", "ITAE", 1, ".2f"),
        ("peak_current_a", "peak A", 1, ".2f"),
    )
    table = Table(title=title)
    if sort_by:
        table.add_column("#", justify="right")
    table.add_column("gains", no_wrap=True)
    for _, header, _, _ in columns:
        table.add_column(header, justify="right", no_wrap=True)
    for row in compare_table(rows, sort_by=sort_by):
        cells = ["—" if row[key] is None else format(row[key] * scale, fmt) for key, _, scale, fmt in columns]
        table.add_row(*([str(row["rank"])] if sort_by else []), row["label"], *cells)
    return table


@cli.command(context_settings={"show_default": True})
@click.argument("config", required=False, type=click.Path(dir_okay=False))
@click.option("--param", "-p", "axes", multiple=True, metavar="NAME=A:B:N",
              help="A swept parameter: N values of NAME from A to B (or NAME=V). Repeat per parameter; "
                   "default: the target's own default grid (`hilbench targets`).")
@click.option("--sample", default="grid", metavar="grid|lhs:N|random:N",
              help="Where the points go: every grid combination, or N Latin-hypercube / uniform samples of the box.")
@click.option("--refine", "rounds", type=click.IntRange(1, 20), default=1,
              help="Grid rounds: each next one as many points, --shrink times as wide, around the best so far.")
@click.option("--shrink", type=click.FloatRange(0.05, 0.95), default=0.4, help="Window of each --refine round.")
@click.option("--seed", type=click.IntRange(min=0), default=0, help="Seed of --sample lhs/random.")
@click.option("--tolerance", "tolerance", default=None, metavar="rs=F,l=F,psi=F,j=F",
              help="Motor tolerances (fractions, e.g. rs=0.1,psi=0.05): each point runs at every corner and "
                   "reports its worst case.")
@click.option("--executor", default="local", metavar="SPEC",
              help="local (a process pool), local-dask[:N] (a Dask LocalCluster) or tcp://HOST:8786 (a Dask scheduler; "
                   "pip install 'hilbench[dask]').")
@click.option("--workers", type=click.IntRange(min=1, max=256), default=None,
              help="Local processes (default: one per core; 1: in this process).")
@click.option("--resume", "store", type=click.Path(dir_okay=False), default=None, metavar="FILE.jsonl",
              help="Append each finished point to FILE as it arrives; a sweep restarted with the same FILE runs only "
                   "the points it lacks.")
@click.option("--metric", type=click.Choice(["itae", "iae", "settling_time_s", "rise_time_s", "overshoot_pct", "ss_error"]),
              default="itae", help="What ranks the points (smaller is better).")
@click.option("--from", "from_rpm", type=SPEED_RPM, default=1000.0, help="Speed before the step, rpm.")
@click.option("--to", "to_rpm", type=SPEED_RPM, default=2000.0, help="Speed after the step, rpm.")
@click.option("--duration", "duration_s", type=SECONDS, default=1.0, help="Seconds per step test.")
@click.option("--step-at", "step_at_s", type=SECONDS, default=0.5, help="When the step comes, s.")
@click.option("--csv", "csv_file", type=click.Path(dir_okay=False), default=None, metavar="FILE", help="Every point as CSV.")
@click.option("--save", "save_file", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="The best parameters as a [target] fragment (load it with `hilbench run --gains-file FILE`).")
@click.option("--top", type=click.IntRange(1, 1000), default=10, help="Rows of the ranked table.")
@click.option("--set", "overrides", multiple=True, metavar="TABLE.KEY=VALUE", help="Override a config value.")
@click.option("--json", "as_json", is_flag=True, help="Print the ranked results as JSON.")
@_friendly
def sweep(config: str | None, axes: tuple[str, ...], sample: str, rounds: int, shrink: float, seed: int,
          tolerance: str | None, executor: str, workers: int | None, store: str | None, metric: str, from_rpm: float,
          to_rpm: float, duration_s: float, step_at_s: float, csv_file: str | None, save_file: str | None,
          top: int, overrides: tuple[str, ...], as_json: bool) -> None:
    """Find gains offline: speed-step tests on the configured target's in-process model, on every
    core or a Dask cluster, ranked; resumable; optionally worst-case over motor tolerances.

    Points that break the firmware's own constraints (its profile states them; the default
    target's are Kp+Ki+Kd < 0.9999, -Kp-2Kd > -1, Kd < 0.9999) are skipped and counted, not
    simulated. Every point can go to a CSV; the best to a config fragment.

    \b
    Examples:
      hilbench sweep
      hilbench sweep -p kp=0.1:0.9:9 -p ki=0.01:0.2:8 -p kd=0 --metric settling_time_s --save best.toml
      hilbench sweep -p kp=0.05:0.95:5 -p ki=0.005:0.2:5 --refine 3          # zoom in around the best
      hilbench sweep --sample lhs:64 -p kp=0.05:0.95:1 -p ki=0.005:0.2:1 --resume s.jsonl
      hilbench sweep --tolerance rs=0.1,psi=0.05,j=0.2 --executor local-dask:2
    """
    import time

    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from hilbench.bench.run import RunRequest, check_overrides, load_run_config, settings_profile
    from hilbench.bench.steptest import StepTest
    from hilbench.bench.sweep import refine, sweep_points, write_sweep_csv

    _refuse_unwritable_outputs({"--csv": csv_file, "--save": save_file, "--resume": store})
    cfg = load_run_config(RunRequest(config, check_overrides(overrides)))
    profile = settings_profile(cfg)
    box = _sweep_box(axes or tuple(f"{n}={g}" for n, g in profile.sweep_defaults))
    test = StepTest(from_rpm, to_rpm, step_at_s, duration_s - step_at_s)
    tolerances = _parse_tolerances(tolerance)
    kind = sample.partition(":")[0]
    if rounds > 1 and kind != "grid":
        raise ConfigError("sweep --refine works on a grid (--sample grid)")
    points = _sweep_sample(sample, box, seed)
    started = time.perf_counter()
    options = dict(executor=executor, workers=workers, tolerances=tolerances, store=store)
    with Progress(TextColumn("[bold]sweep"), BarColumn(), TextColumn("{task.completed}/{task.total} points"),
                  TimeElapsedColumn(), console=Console(stderr=True), transient=True) as progress:
        task = progress.add_task("sweep", total=None)
        report = lambda done, total: progress.update(task, completed=done, total=total)  # noqa: E731
        if rounds > 1:
            result = refine(cfg, box, test, metric, rounds=rounds, shrink=shrink, progress=report, **options)
        else:
            result = sweep_points(cfg, points, test, metric, progress=report, **options)
    wall_s = time.perf_counter() - started
    if csv_file:
        write_sweep_csv(csv_file, result)
    if save_file:
        _save_best(result, save_file, cfg)
    _show_sweep(result, top, as_json, wall_s, len(tolerances.cases()) > 1, csv_file, save_file)


def _sweep_box(words: Sequence[str]) -> list[Any]:
    """The swept box: one axis per `--param NAME=A:B:N` word."""
    from hilbench.bench import sampling
    from hilbench.bench.sweep import parse_axis

    return [sampling.Axis(name, values[0], values[-1], len(values)) for name, values in map(parse_axis, words)]


def _sweep_sample(sample: str, box: list[Any], seed: int) -> list[Any]:
    """`--sample grid | lhs:N | random:N`: the points of the box."""
    from hilbench.bench import sampling

    kind, _, count = sample.partition(":")
    if kind == "grid" and not count:
        return sampling.grid(box)
    if kind in ("lhs", "random") and count.isdigit() and 1 <= int(count) <= 100_000:
        return (sampling.latin_hypercube if kind == "lhs" else sampling.random_points)(box, int(count), seed)
    raise ConfigError(f"sweep --sample {sample!r}: expected grid, lhs:N or random:N")


def _save_best(result: Any, save_file: str, cfg: Any) -> None:
    from hilbench.bench.sweep import best_fragment, held_params
    from hilbench.bench.tuning import write_fragment

    best = result.best
    held = held_params(cfg, best.params) if best is not None and best.result is not None else None
    text = best_fragment(result, held)  # before opening the file: nothing simulated leaves no empty file
    try:
        write_fragment(save_file, text)  # (not onto a recording a session writes)
    except OSError as exc:
        raise ConfigError(f"sweep --save {save_file}: {exc.strerror}") from None


def _show_sweep(result: Any, top: int, as_json: bool, wall_s: float, worst_case: bool, csv_file: str | None,
                save_file: str | None) -> None:
    """The ranked table and the sweep's figures (or the ranked points as JSON)."""
    import json as json_module

    ranked = result.ranked[:top]
    if as_json:
        click.echo(json_module.dumps([
            {"rank": p.rank, **dict(p.params), "cases": p.cases, **p.result.metrics.as_dict()}
            for p in ranked if p.result is not None
        ], indent=2, default=str))
        return
    out = _wide_console()
    rows = [(p.label, p.result.metrics) for p in ranked if p.result is not None]
    worst = " (worst of each point's tolerance cases)" if worst_case else ""
    test = result.test
    out.print(step_table(rows, f"sweep: best {len(rows)} of {len(result.points)} by {result.metric}{worst} "
                               f"(step {test.from_rpm:g} → {test.to_rpm:g} rpm)", sort_by=result.metric))
    out.print(f"{'/'.join(result.axes)}: {len(result.points)} points ({result.skipped} skipped by the firmware's "
              f"constraints), {result.step_tests} step tests; {result.sim_s:.0f} simulated s "
              f"in {wall_s:.1f} s wall ({result.sim_s / wall_s:.1f} plant-s/s) on {result.extras.get('executor')}")
    if csv_file:
        out.print(f"every point: {csv_file}")
    if save_file:
        out.print(f"best gains: {save_file} (hilbench run --gains-file {save_file})")


def _parse_tolerances(text: str | None) -> "Tolerances":
    """`rs=0.1,l=0.1,psi=0.05,j=0.2` → Tolerances."""
    from hilbench.bench.sweep import Tolerances
    from hilbench.config import clipped

    if not text:
        return Tolerances()
    values: dict[str, float] = {}
    for word in text.split(","):
        name, sep, value = word.partition("=")
        try:
            if not sep or name.strip() not in ("rs", "l", "psi", "j"):
                raise ValueError
            if name.strip() in values:
                raise ConfigError(f"sweep --tolerance: {name.strip()} given twice")
            values[name.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"sweep --tolerance {clipped(repr(text), 60)}: expected rs=F,l=F,psi=F,j=F (fractions, "
                              "e.g. rs=0.1)") from None
    return Tolerances(**values)


def main() -> None:
    """Console-script entry point: click's own usage errors as click prints them, a value quoted in
    one cut as the bench's messages are (`_cut`)."""
    try:
        code = cli.main(prog_name="hilbench", standalone_mode=False)
    except click.ClickException as exc:
        if "\n" not in exc.message:  # (a help text shown for no arguments is whole)
            exc.message = _cut(exc.message)
        exc.show()
        sys.exit(exc.exit_code)
    except click.Abort:
        click.echo("Aborted!", err=True)
        sys.exit(1)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
