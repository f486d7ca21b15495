"""Issue 16, items 3, 4 and 5 and the config fuzz: no config, however broken, gives a traceback or a
hang; every error is one line with a non-zero exit."""

from __future__ import annotations

import copy
import json
import math
import random
import signal
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any, Iterator

import pytest
from click.testing import CliRunner

from hilbench.bench.session import first_period_at
from hilbench.cli import cli
from hilbench.bench.settings import load_config
from hilbench.config import default_config_text
from hilbench.errors import ConfigError

CASE_TIMEOUT_S = 20
SEED = 1616
N_CASES = 320
RUN_ARGS = ["--no-ui", "--no-control", "--target", "inprocess:an1017", "--duration", "0.002"]
EXTRA_TABLES = """
[run]
mode = "lockstep"
seed = 3

[link]
period_us = 50

[[scenario]]
at_s = 0.0
ref_rpm = 1000.0

[[scenario]]
at_s = 0.001
press = "s2"
"""


# ---------------------------------------------------------------- a small TOML writer (independent of the loader)
def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def to_toml(data: dict[str, Any]) -> str:
    lines: list[str] = []
    for key, value in data.items():
        if not isinstance(value, (dict, list)) or (isinstance(value, list) and not all(isinstance(x, dict) for x in value)) \
                or (isinstance(value, list) and not value):
            lines.insert(0, f"{json.dumps(key)} = {_value(value)}")
    for key, value in data.items():
        if isinstance(value, dict):
            lines.append(f"[{json.dumps(key)}]")
            lines += [f"{json.dumps(k)} = {_value(v)}" for k, v in value.items()]
        elif isinstance(value, list) and value and all(isinstance(x, dict) for x in value):
            for item in value:
                lines.append(f"[[{json.dumps(key)}]]")
                lines += [f"{json.dumps(k)} = {_value(v)}" for k, v in item.items()]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- mutations
WRONG_VALUES: list[Any] = [math.nan, math.inf, -math.inf, 0, 0.0, -1, -1e300, 1e300, 10**30, 2**63 - 1, -(2**63),
                           "", "x" * 5000, "1.5", True, [], [1, 2], {}, {"a": 1}, 1e-300, -0.0]


def _leaves(data: dict[str, Any]) -> list[tuple[Any, Any]]:
    """(container, key) of every scalar in the config."""
    out: list[tuple[Any, Any]] = []
    for value in data.values():
        items = value if isinstance(value, list) else [value]
        for item in items:
            if isinstance(item, dict):
                out += [(item, k) for k in item]
    return out


def mutated_configs(seed: int, n: int) -> Iterator[tuple[str, bytes]]:
    """(description, file bytes) of n mutations of the packaged config (with a run, link and scenario)."""
    rng = random.Random(seed)
    base_text = default_config_text() + EXTRA_TABLES
    base = tomllib.loads(base_text)
    for i in range(n):
        kind = i % 10
        data = copy.deepcopy(base)
        if kind in (0, 1, 2, 3):  # a wrong value (type, NaN/inf, zero/negative/huge)
            container, key = rng.choice(_leaves(data))
            value = rng.choice(WRONG_VALUES)
            container[key] = value
            yield f"{key}={value!r}"[:80], to_toml(data).encode()
        elif kind == 4:  # a deleted key or table
            if rng.random() < 0.3:
                table = rng.choice(list(data))
                del data[table]
                yield f"del [{table}]", to_toml(data).encode()
            else:
                container, key = rng.choice(_leaves(data))
                del container[key]
                yield f"del {key}", to_toml(data).encode()
        elif kind == 5:  # an unknown key or table, an item of a wrong type
            table = rng.choice(list(data))
            target = data[table][0] if isinstance(data[table], list) else data[table]
            if rng.random() < 0.5:
                target[f"nosuch_{i}"] = 1
            else:
                data[table] = rng.choice([1, "x", [1, 2], True])
            yield f"shape {table}", to_toml(data).encode()
        elif kind == 6:  # bad encodings
            text = to_toml(data)
            encoded = rng.choice([text.encode("utf-16"), text.encode("utf-32"), b"\xff\xfe" + text.encode(),
                                  text.encode()[:200] + b"\xc3\x28" + text.encode()[200:], b"\x00" * 50])
            yield "encoding", encoded
        elif kind == 7:  # deep nesting
            depth = rng.choice([50, 500, 1000, 5000, 20000])
            container, key = rng.choice(_leaves(data))
            nest = rng.choice(["[", "{ a = "])
            close = "]" if nest == "[" else "}"
            text = to_toml(data).replace(f"{json.dumps(key)} = ", f"{json.dumps(key)} = {nest * depth}1{close * depth} #", 1)
            yield f"nesting {depth}", text.encode()
        elif kind == 8:  # invalid TOML: truncated, garbage spliced in, a duplicated table
            text = to_toml(data)
            cut = rng.randrange(1, len(text))
            choice = rng.randrange(3)
            if choice == 0:
                text = text[:cut]
            elif choice == 1:
                text = text[:cut] + rng.choice(["= = =", "[[", "\"unterminated", "]]]", "\x07", "key = 1\nkey = 2"]) + text[cut:]
            else:
                text += "\n[motor]\nrs_ohm = 1.0\n"
            yield "invalid TOML", text.encode()
        else:  # scenario and run extremes (hangs: huge times; item 3)
            entry = rng.choice(data["scenario"])
            entry["at_s"] = rng.choice([1e17, 1e300, 2**60 * 1.0, -1.0, math.nan, 1e-300, 3600.0])
            if rng.random() < 0.5:
                data["run"]["duration_s"] = rng.choice([1e-9, 86400.0, 1e300, -1.0, 0.0])
            yield f"scenario at_s={entry['at_s']}", to_toml(data).encode()


class _CaseTimeout(Exception):
    pass


def _alarm(signum: int, frame: Any) -> None:
    raise _CaseTimeout()


def run_cli_in_process(args: list[str]) -> tuple[int, str, BaseException | None]:
    """The CLI's own entry (click), in this process, under a timeout."""
    runner = CliRunner()
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(CASE_TIMEOUT_S)
    try:
        result = runner.invoke(cli, args, catch_exceptions=True)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    exc = result.exception if not isinstance(result.exception, SystemExit) else None
    return result.exit_code, result.stderr, exc


def _check_outcome(what: str, code: int, stderr: str, exc: BaseException | None) -> None:
    assert exc is None, f"{what}: {type(exc).__name__}: {exc}"
    assert "Traceback" not in stderr, f"{what}: {stderr}"
    if code != 0:
        lines = [line for line in stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("hilbench: "), f"{what}: {stderr!r}"
        assert len(lines[0]) < 400, f"{what}: {lines[0]}"


@pytest.mark.slow
def test_config_fuzz_in_process(tmp_path: Path) -> None:
    """Acceptance: >= 300 mutations of the packaged config through the CLI's own function."""
    failures: list[str] = []
    rejected = 0
    for n, (what, blob) in enumerate(mutated_configs(SEED, N_CASES)):
        path = tmp_path / f"case{n}.toml"
        path.write_bytes(blob)
        code, stderr, exc = run_cli_in_process(["run", str(path), *RUN_ARGS])
        try:
            _check_outcome(f"case {n} ({what})", code, stderr, exc)
        except AssertionError as err:
            failures.append(str(err)[:300])
        rejected += code != 0
    assert not failures, "\n".join(failures[:20])
    assert rejected > N_CASES // 2  # most mutations are errors (a few are harmless values)


@pytest.mark.slow
def test_config_fuzz_sample_through_the_real_cli(tmp_path: Path) -> None:
    """A sample of the fuzz through `python -m hilbench` in its own process (killed on timeout)."""
    cases = list(mutated_configs(SEED + 1, 40))[::4]
    for n, (what, blob) in enumerate(cases):
        path = tmp_path / f"case{n}.toml"
        path.write_bytes(blob)
        proc = subprocess.Popen([sys.executable, "-m", "hilbench", "run", str(path), *RUN_ARGS],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            _, stderr = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        _check_outcome(f"cli case {n} ({what})", proc.returncode, stderr, None)


# ---------------------------------------------------------------- the named findings
def test_item3_first_period_at_huge_times_is_inf() -> None:
    """Item 3: `k += 1` stopped changing k*period_s for at_s >= 1e17: the run hung."""
    assert first_period_at(1e17, 50e-6) == math.inf
    assert first_period_at(2.0**60, 50e-6) == math.inf
    assert first_period_at(1.0, 50e-6) == 20000  # hand: 1 s / 50 us
    assert first_period_at(0.0, 50e-6) == 0


@pytest.mark.parametrize("override", ["motor.j_kgm2=1e-300", "motor.l_h=1e-300", "motor.l_h=2e-5", "motor.rs_ohm=300",
                                      "motor.b_nms_per_rad=10", "motor.j_kgm2=1e-12"])
def test_item5_stiff_motor_refused_with_the_substeps_named(override: str) -> None:
    """Items 4/5: these diverged into "cannot convert float NaN to integer" or "encode Sensors"."""
    with pytest.raises(ConfigError) as info:
        load_config(None, [override])
    text = str(info.value)
    assert "\n" not in text and "[plant] substeps" in text and text.startswith(f"--set {override.split('=')[0]}")


def test_item5_enough_substeps_make_a_stiff_motor_acceptable() -> None:
    """R/L = 2.54/2e-5 = 1.27e5/s; at 25 us a substep 1.27e5 * 25e-6 = 3.2 > 2.5: 2 substeps fail, 3 pass
    (3: 1.27e5 * 25e-6 / 3 = 1.06)."""
    with pytest.raises(ConfigError):
        load_config(None, ["motor.l_h=2e-5", "plant.substeps=2"])
    load_config(None, ["motor.l_h=2e-5", "plant.substeps=3"])


def test_item5_diverging_plant_reported_as_such() -> None:
    """Item 5: a 1000 N*m load (in range) made the run end "protocol error: encode Sensors"."""
    code, stderr, exc = run_cli_in_process(["run", *RUN_ARGS[:-1], "0.5", "--set", "load.torque_nm=1000",
                                            "--set", "protection.overspeed_rpm=0", "--set", "protection.overcurrent_a=0"])
    assert exc is None and code == 7, stderr  # (with the bench's limits on, overspeed ends it first: exit 8)
    assert stderr.startswith("hilbench: simulation error: the plant diverged at t=") and stderr.count("\n") == 1


@pytest.mark.parametrize("blob,reason", [
    ("[motor]\nrs_ohm = 1\n".encode("utf-16"), "not UTF-8"),
    (b"a = " + b"[" * 5000 + b"]" * 5000, "nested too deep"),
])
def test_item4_bad_encoding_and_deep_nesting_are_one_line(tmp_path: Path, blob: bytes, reason: str) -> None:
    """Item 4: a UTF-16 config (UnicodeDecodeError) and 5000-deep arrays (RecursionError) gave tracebacks."""
    path = tmp_path / "c.toml"
    path.write_bytes(blob)
    with pytest.raises(ConfigError, match=reason):
        load_config(path)


def test_item4_recordings_and_output_paths_fail_in_one_line(tmp_path: Path) -> None:
    """Item 4: truncated/random .npz (BadZipFile; NumPy's allow_pickle advice), --plot and --csv paths
    under a file or in /proc (NotADirectoryError, FileNotFoundError, FileExistsError)."""
    rec = tmp_path / "run.npz"
    code, stderr, exc = run_cli_in_process(["run", *RUN_ARGS, "--record", str(rec)])
    assert code == 0, stderr
    csv = tmp_path / "run.csv"
    code, stderr, exc = run_cli_in_process(["run", *RUN_ARGS, "--record", str(csv)])
    (tmp_path / "trunc.npz").write_bytes(rec.read_bytes()[:3000])
    (tmp_path / "random.npz").write_bytes(random.Random(4).randbytes(5000))
    (tmp_path / "npy.npz").write_bytes(b"\x93NUMPY\x01\x00" + bytes(100))
    cases = [["report", str(tmp_path / "trunc.npz")], ["report", str(tmp_path / "random.npz")],
             ["report", str(tmp_path / "npy.npz")],
             ["report", str(csv), "--plot", str(csv / "plots")], ["report", str(csv), "--plot", "/proc/x"],
             ["report", str(csv), "--csv", str(csv / "x.csv")],
             ["step", "--after", "0.05", "--settle", "0.05", "--plot", str(csv / "x.png")],
             ["step", "--after", "0.05", "--settle", "0.05", "--csv", str(csv / "x.csv")]]
    for args in cases:
        code, stderr, exc = run_cli_in_process(args)
        assert code != 0, args
        _check_outcome(" ".join(args), code, stderr, exc)
        assert "allow_pickle" not in stderr


# ---------------------------------------------------------------- item 16: extends, --scenario, array overrides
def test_item16_set_of_an_unknown_table_is_blamed_on_set() -> None:
    """Item 16: `--set nosuch.key=1` blamed "<packaged hurst_mclv.toml>"."""
    with pytest.raises(ConfigError) as info:
        load_config(None, ["nosuch.key=1"])
    assert str(info.value).startswith("--set nosuch.key: unknown table [nosuch]")


def test_item16_extends_the_packaged_default_and_another_file(tmp_path: Path) -> None:
    """Item 16: a config changing only the scenario had to repeat every table."""
    (tmp_path / "base.toml").write_text('extends = "packaged"\n[motor]\nrs_ohm = 3.0\n')
    child = tmp_path / "child.toml"
    child.write_text('extends = "base.toml"\n[run]\nseed = 5\n[[scenario]]\nat_s = 0.0\nref_rpm = 700.0\n')
    cfg = load_config(child)
    packaged = load_config(None)
    assert cfg.motor.rs_ohm == 3.0 and cfg.motor.l_h == packaged.motor.l_h  # merged key by key
    assert cfg.run.seed == 5 and [e.ref_rpm for e in cfg.scenario] == [700.0]
    assert cfg.adc == packaged.adc
    loop = tmp_path / "loop.toml"
    loop.write_text('extends = "loop.toml"\n')
    with pytest.raises(ConfigError, match="a loop"):
        load_config(loop)
    missing = tmp_path / "m.toml"
    missing.write_text('extends = "nowhere.toml"\n')
    with pytest.raises(ConfigError, match="nowhere.toml: cannot read"):
        load_config(missing)


def test_item16_scenario_file_and_array_of_tables_overrides(tmp_path: Path) -> None:
    """Item 16: [[adc]] and [[scenario]] entries could not be overridden; no --scenario FILE."""
    scenario = tmp_path / "s.toml"
    scenario.write_text("[[scenario]]\nat_s = 0.0\nref_rpm = 900.0\n[[scenario]]\nat_s = 0.5\nend = true\n")
    cfg = load_config(None, scenario_path=scenario)
    assert [e.at_s for e in cfg.scenario] == [0.0, 0.5]
    cfg = load_config(None, ["adc.1.gain_codes_per_unit=150", "scenario=[{at_s = 0.0, ref_rpm = 100.0}]"])
    assert cfg.adc[1].gain_codes_per_unit == 150 and cfg.scenario[0].ref_rpm == 100.0
    with pytest.raises(ConfigError, match="no \\[\\[scenario\\]\\] array to index"):
        load_config(None, ["scenario.0.at_s=1"])
    code, stderr, exc = run_cli_in_process(["run", *RUN_ARGS, "--scenario", str(scenario),
                                            "--set", "scenario=[{at_s = 0.0, ref_rpm = 100.0}]"])
    assert code == 0 and exc is None, stderr
