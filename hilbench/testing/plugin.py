"""The hilbench pytest plugin (entry point `pytest11: hilbench`): bench tests on any target.

    pytest tests/ --hil-target inprocess:an1017 --hil-target emulator:an1017 --junitxml r.xml

Options: ``--hil-target SPEC`` (repeatable; also ``HILBENCH_TARGET``, several separated by
commas or spaces; default: the config's ``[link] target``), ``--hil-config FILE`` (also
``HILBENCH_CONFIG``; default: the packaged config), ``--hil-record DIR`` (keep every test's
recording there; default: only failed tests' are kept, under pytest's base temp directory).

Fixtures (a test that uses one runs once per target, with the target's readable id):

- ``bench``: a `hilbench.Bench` opened on the target for this test alone (a fresh target: a new
  in-process model or a new emulator process), closed and its process reaped whatever the test
  did — failed, raised, or was stopped by a timeout that raises (pytest-timeout's signal method);
- ``hil_open``: a factory for more benches in one test, ``hil_open(overrides=[...], scenario=True)``;
- ``hil_config``: the loaded config with the target in ``[link] target``;
- ``hil_target``: the spec; ``hil_target_info``: its `TargetInfo` (capabilities, firmware);
- ``hil_hello``: the target's HELLO (opens the bench).

Marker ``hil_requires("fault_injection", "link", firmware="AN1017")``: skipped with the reason on
a target that lacks one. Reports: a failed test keeps its recording and its plots (matplotlib, the
``plot`` extra) and names their paths in the failure, in JUnit ``<property>`` elements and in
``[[ATTACHMENT|path]]`` lines of ``<system-out>``; figures the assertions judged are properties;
the suite's properties name each target, its firmware (HELLO), the protocol version and schema
fingerprint, the hilbench version and the config's hash.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

import pytest

if TYPE_CHECKING:
    from hilbench.bench.bench import Bench
    from hilbench.config import BenchConfig
    from hilbench.testing.targets import TargetInfo

TARGET_ENV = "HILBENCH_TARGET"
CONFIG_ENV = "HILBENCH_CONFIG"
ATTACHMENT = "[[ATTACHMENT|{}]]"  # the Jenkins JUnit-attachments line (also read by GitLab)

_STATE = pytest.StashKey["_State"]()
_REPORTS = pytest.StashKey[dict]()
_ATTACHED = pytest.StashKey[list]()


# ---------------------------------------------------------------- options and configuration
def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("hilbench", "hilbench bench tests (hilbench.testing)")
    group.addoption("--hil-target", action="append", default=[], metavar="SPEC",
                    help=f"target spec to run bench tests on; repeat for several (tests run once per target). "
                         f"inprocess:NAME, emulator:NAME, serial:/dev/ttyUSB0?baud=250000, socket://HOST:PORT … "
                         f"Also ${TARGET_ENV}. Default: the config's [link] target.")
    group.addoption("--hil-config", default=None, metavar="FILE",
                    help=f"bench config (TOML) for the bench fixtures; also ${CONFIG_ENV}. Default: the packaged one.")
    group.addoption("--hil-record", default=None, metavar="DIR",
                    help="keep every bench test's recording in DIR (default: only failed tests' are kept, "
                         "with plots, under pytest's base temp directory).")


@dataclass
class _State:
    """The session's choices and what it learnt about its targets."""

    config_path: str | None
    targets: list[str]
    record_dir: Path | None
    fail_dir: Path | None = None
    infos: dict[str, "TargetInfo"] = field(default_factory=dict)
    suite_recorded: set[str] = field(default_factory=set)
    kept: list[tuple[str, list[str]]] = field(default_factory=list)  # (nodeid, paths) of failed tests


def _split_specs(text: str) -> list[str]:
    return [word for word in re.split(r"[\s,]+", text) if word]


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "hil_requires(*capabilities, firmware=None): skip where the bench target lacks a capability "
        "(speed_loop, realtime, fault_injection, tuning, hall_sensors, link, board, emulator, inprocess) "
        "or runs another firmware (the name its HELLO carries)",
    )
    config.addinivalue_line(
        "markers",
        "hil_conformance: a check of the conformance suite (pytest --pyargs hilbench.testing.conformance "
        "--hil-target SPEC)",
    )
    targets = list(config.getoption("hil_target") or []) or _split_specs(os.environ.get(TARGET_ENV, ""))
    config_path = config.getoption("hil_config") or os.environ.get(CONFIG_ENV) or None
    record = config.getoption("hil_record")
    _check_options(targets, config_path, TARGET_ENV if not config.getoption("hil_target") else "--hil-target")
    if record and Path(record).exists() and not Path(record).is_dir():
        raise pytest.UsageError(f"--hil-record {record}: not a folder (the recordings go into it, one file a test)")
    config.stash[_STATE] = _State(config_path, targets, Path(record).resolve() if record else None)
    config.pluginmanager.register(_Attachments(config), "hilbench-attachments")


def _check_options(targets: Sequence[str], config_path: str | None, where: str) -> None:
    """A bad target spec or config is one usage error before the session, not an error at every
    test's setup (hilbench's own ConfigError line, named by the option it came from)."""
    if not targets and config_path is None:
        return
    from hilbench.errors import HilbenchError
    from hilbench.testing.targets import check_spec

    for spec in targets:
        try:
            check_spec(spec)
        except HilbenchError as exc:
            raise pytest.UsageError(f"{where} {spec}: {exc}") from None
    if config_path is not None:
        from hilbench.bench.settings import load_config

        try:
            load_config(config_path)
        except HilbenchError as exc:
            raise pytest.UsageError(f"--hil-config: {exc}") from None


def _state(config: pytest.Config) -> _State:
    return config.stash[_STATE]


def _targets(config: pytest.Config) -> list[str]:
    """The targets given, else the config's own [link] target (read once)."""
    state = _state(config)
    if not state.targets:
        from hilbench.bench.settings import load_config

        state.targets = [load_config(state.config_path).link.target]
    return state.targets


def pytest_report_header(config: pytest.Config) -> str | None:
    state = _state(config)
    if not state.targets and state.config_path is None:
        return None  # no bench options: say nothing (the plugin is installed with hilbench)
    from hilbench import __version__

    return (f"hilbench {__version__}: targets {', '.join(_targets(config))}; "
            f"config {state.config_path or '<packaged default>'}")


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """Tests using the bench fixtures run once per target, with readable ids."""
    if "hil_target" not in metafunc.fixturenames:
        return
    for marker in metafunc.definition.iter_markers("parametrize"):
        names = marker.args[0] if marker.args else marker.kwargs.get("argnames", "")
        names = [n.strip() for n in names.split(",")] if isinstance(names, str) else list(names)
        if "hil_target" in names:
            return  # the test chose its targets itself (indirect=True)
    from hilbench.testing.targets import unique_ids

    specs = _targets(metafunc.config)
    metafunc.parametrize("hil_target", specs, indirect=True, ids=unique_ids(specs))


# ---------------------------------------------------------------- capabilities and skipping
def _info(config: pytest.Config, spec: str) -> "TargetInfo":
    """What a spec offers; a port's firmware comes from [link] firmware, else from its HELLO."""
    state = _state(config)
    if spec not in state.infos:
        from hilbench.testing.targets import describe_target, spec_kind

        kind, _ = spec_kind(spec)
        firmware = None
        hello_firmware = None
        if kind == "board":
            from hilbench.bench.settings import load_config

            firmware = load_config(state.config_path).link.firmware
            if firmware is None:
                hello_firmware = _probe_hello(state.config_path, spec)
        state.infos[spec] = describe_target(spec, firmware=firmware, hello_firmware=hello_firmware)
    return state.infos[spec]


def _probe_hello(config_path: str | None, spec: str) -> str:
    """Open a port once to learn which firmware answers there."""
    from hilbench.bench.bench import Bench

    with Bench(config_path, target=spec) as probe:
        return probe.hello.firmware_name


def pytest_runtest_setup(item: pytest.Item) -> None:
    markers = list(item.iter_markers("hil_requires"))
    if not markers:
        return
    callspec = getattr(item, "callspec", None)
    spec = callspec.params.get("hil_target") if callspec is not None else None
    spec = spec or _targets(item.config)[0]
    wanted = [str(a) for m in markers for a in m.args]
    firmware = next((m.kwargs["firmware"] for m in markers if m.kwargs.get("firmware")), None)
    why = _info(item.config, spec).lacks(wanted, firmware)
    if why:
        pytest.skip(why)


# ---------------------------------------------------------------- outcomes, reports, attachments
@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    outcome = yield
    report = outcome.get_result()
    item.stash.setdefault(_REPORTS, {})[report.when] = report
    kept = item.stash.get(_ATTACHED, None)
    if kept and report.when == "call" and report.failed:  # name the paths in the failure
        report.sections.append(("hilbench", "\n".join(f"kept: {p}" for p in kept)))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """While a test runs, the assertions' figures become its properties."""
    from hilbench.testing import assertions

    outer = assertions._metric_sink  # a pytest run inside a test (pytester) gives it back after
    assertions._metric_sink = lambda name, value: item.user_properties.append((f"hil.{name}", value))
    try:
        yield
    finally:
        assertions._metric_sink = outer


class _Attachments:
    """Attachment lines into the JUnit <system-out> when captured output is not written there, and
    the failed tests' kept files at the end of the terminal report (registered per config)."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config

    @pytest.hookimpl(tryfirst=True)
    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        if report.when != "teardown":
            return
        lines = [value for name, value in report.user_properties if name in ("hil_recording", "hil_plot")]
        if not lines:
            return
        try:
            from _pytest.junitxml import xml_key
        except ImportError:  # pragma: no cover - a pytest without junitxml
            return
        xml = self.config.stash.get(xml_key, None)
        if xml is None or self.config.getini("junit_logging") in ("system-out", "out-err", "all"):
            return  # no JUnit file, or the lines printed at teardown are already in <system-out>
        import xml.etree.ElementTree as ET

        node = ET.Element("system-out")
        node.text = "\n".join(ATTACHMENT.format(p) for p in lines) + "\n"
        xml.node_reporter(report).append(node)

    def pytest_terminal_summary(self, terminalreporter: Any) -> None:
        kept = _state(self.config).kept
        if not kept:
            return
        terminalreporter.section("hilbench: recordings of failed tests")
        for nodeid, paths in kept:
            terminalreporter.write_line(nodeid)
            for path in paths:
                terminalreporter.write_line(f"  {path}")


# ---------------------------------------------------------------- fixtures
@pytest.fixture
def hil_target(request: pytest.FixtureRequest) -> str:
    """The target spec this test runs on (parametrised over every --hil-target)."""
    return str(getattr(request, "param", None) or _targets(request.config)[0])


@pytest.fixture
def hil_target_info(request: pytest.FixtureRequest, hil_target: str) -> "TargetInfo":
    """The target's capabilities and firmware (`hilbench.testing.TargetInfo`)."""
    return _info(request.config, hil_target)


@pytest.fixture
def hil_config(request: pytest.FixtureRequest, hil_target: str) -> "BenchConfig":
    """The bench config (--hil-config, or the packaged one) with this test's target."""
    from hilbench.bench.settings import load_config

    return load_config(_state(request.config).config_path, [f"link.target={json.dumps(hil_target)}"])


def _config_hash(cfg: "BenchConfig") -> str:
    from hilbench.bench import settings

    data = settings.config_metadata(cfg)
    data.pop("link", None)  # the target varies per test; the rest is the config
    text = json.dumps(data, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _suite_properties(request: pytest.FixtureRequest, bench: "Bench", spec: str) -> None:
    """Once per session and once per target: the JUnit testsuite's properties."""
    state = _state(request.config)
    record = request.getfixturevalue("record_testsuite_property")
    if "" not in state.suite_recorded:
        from hilbench import __version__, protocol

        state.suite_recorded.add("")
        record("hilbench_version", __version__)
        record("hil_config", state.config_path or "<packaged default>")
        record("hil_config_sha256", _config_hash(bench.config))
        record("protocol_version", protocol.PROTOCOL_VERSION)
        fingerprint = getattr(protocol, "SCHEMA_FINGERPRINT", None)
        if fingerprint is not None:
            record("schema_fingerprint", f"0x{fingerprint:08x}")
    if spec not in state.suite_recorded:
        from hilbench.testing.targets import hello_text, target_id

        state.suite_recorded.add(spec)
        tid = target_id(spec)
        record(f"hil_target[{tid}]", spec)
        record(f"firmware[{tid}]", hello_text(bench.hello))
        target_fingerprint = getattr(bench.hello, "schema_fingerprint", None)
        if target_fingerprint is not None:
            record(f"schema_fingerprint[{tid}]", f"0x{target_fingerprint:08x}")


def _safe_name(nodeid: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", nodeid.split("::", 1)[-1]).strip("_")
    return name[:120] or "test"


@pytest.fixture
def hil_open(request: pytest.FixtureRequest, hil_target: str,
             tmp_path_factory: pytest.TempPathFactory) -> Iterator[Callable[..., "Bench"]]:
    """``hil_open(overrides=(), scenario=False, target=None)``: open a bench on this test's target (recorded);
    every bench it opened is closed, and its process reaped, when the test ends."""
    from hilbench.bench.bench import Bench

    state = _state(request.config)
    node = request.node
    if state.record_dir is not None:
        folder = state.record_dir / _safe_name(node.nodeid)
    else:
        if state.fail_dir is None:
            state.fail_dir = tmp_path_factory.getbasetemp() / "hilbench"
        folder = state.fail_dir / _safe_name(node.nodeid)
    opened: list[tuple[Bench, Path]] = []
    planned: list[str] = []

    def record_property(name: str, value: object) -> None:  # as pytest's fixture, without its xunit2 warning
        node.user_properties.append((name, value))

    node.stash[_ATTACHED] = planned

    def open_bench(overrides: Sequence[str] = (), *, scenario: bool = False, target: str | None = None) -> Bench:
        """``target``: another spec than the test's (e.g. the test's with link fault keys)."""
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / (f"bench{len(opened) + 1}.npz" if opened else "bench.npz")
        bench = Bench(state.config_path, target=target or hil_target, overrides=list(overrides), record=path,
                      scenario=scenario)
        planned.extend([str(path), str(folder / "plots")])
        bench.open()
        opened.append((bench, path))
        record_property("hil_target", hil_target)
        _suite_properties(request, bench, hil_target)
        return bench

    try:
        yield open_bench
    finally:
        errors: list[BaseException] = []
        for bench, _ in opened:
            try:
                bench.close()
            except BaseException as exc:  # noqa: BLE001 - every bench is closed, then the first error raised
                errors.append(exc)
        reports = node.stash.get(_REPORTS, {})
        failed = any(r.failed for r in reports.values())
        if opened and (failed or state.record_dir is not None):
            _keep(request, state, [p for _, p in opened], folder, failed, record_property)
        elif opened:
            shutil.rmtree(folder, ignore_errors=True)
        if errors:
            raise errors[0]


def _keep(request: pytest.FixtureRequest, state: _State, paths: list[Path], folder: Path, failed: bool,
          record_property: Callable[[str, object], None]) -> None:
    """Keep the recordings (and a failed test's plots) and attach their paths."""
    attached: list[str] = []
    notes: list[str] = []
    for path in paths:
        if path.exists():
            attached.append(str(path))
            record_property("hil_recording", str(path))
        else:
            notes.append(f"recording {path} was not written")
    if failed:
        for path in paths:
            if not path.exists():
                continue
            try:
                from hilbench.bench.recorder import read_recording
                from hilbench.ui.plots import PlotUnavailable, plot_recording
            except ImportError as exc:  # pragma: no cover
                notes.append(f"plots skipped: {exc}")
                break
            try:
                plots = plot_recording(read_recording(path), folder / "plots", stem=path.stem)
                for plot in plots:
                    attached.append(str(plot))
                    record_property("hil_plot", str(plot))
                if plots.note() is not None:
                    notes.append(f"{path.name}: {plots.note()}")
            except PlotUnavailable as exc:
                notes.append(f"plots skipped: {exc}")
                break
            except Exception as exc:  # noqa: BLE001 - a plot must never turn a failure into a teardown error
                notes.append(f"plots of {path.name} failed: {type(exc).__name__}: {exc}")
        state.kept.append((request.node.nodeid, attached + notes))
    for line in attached:  # captured into the report (and <system-out> with junit_logging=system-out)
        print(ATTACHMENT.format(line))
    for note in notes:
        print(f"hilbench: {note}")


@pytest.fixture
def bench(hil_open: Callable[..., "Bench"]) -> "Bench":
    """A `hilbench.Bench` opened on this test's target, for this test alone (see the module doc)."""
    return hil_open()


@pytest.fixture
def hil_hello(bench: "Bench") -> Any:
    """The target's HELLO (firmware name and version, protocol version, parameters, telemetry)."""
    return bench.hello
