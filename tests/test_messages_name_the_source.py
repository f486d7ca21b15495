"""A config error names where the user wrote the value: a `--scenario` file, a `--gains-file`, the
option (`--target`), never the packaged config or a `--set` the user did not write; a 100 kB word
is cut in the message. Output options that cannot work are refused before the work, not after."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from hilbench.bench.run import RunRequest, check_overrides, load_run_config
from hilbench.bench.settings import load_config, params_file_overrides
from hilbench.cli import cli
from hilbench.errors import ConfigError


def _message(request: RunRequest) -> str:
    with pytest.raises(ConfigError) as refused:
        load_run_config(request)
    return str(refused.value)


def test_an_error_in_a_scenario_file_names_that_file(tmp_path: Path) -> None:
    """Repro: `--scenario s.toml` with a bad at_s said `<packaged hurst_mclv.toml> [scenario] ...`."""
    scenario = tmp_path / "s.toml"
    scenario.write_text('[[scenario]]\nat_s = "soon"\nref_rpm = 900.0\n')
    message = _message(RunRequest(scenario=str(scenario)))
    assert message.startswith(str(scenario)) and "at_s" in message and "packaged" not in message


def test_an_error_in_a_gains_file_names_that_file_and_key(tmp_path: Path) -> None:
    """Repro: a gains file's bad value was blamed on `--set target.kp`, which the user never typed."""
    gains = tmp_path / "gains.toml"
    gains.write_text('[target]\nkp = "high"\n')
    message = _message(RunRequest(overrides=params_file_overrides(str(gains))))
    assert message.startswith(f"{gains} [target] kp:") and "--set" not in message


def test_a_bad_duration_or_mode_names_its_option() -> None:
    assert _message(RunRequest(mode="fast")).startswith("--mode")
    assert _message(RunRequest(duration_s=-1.0)).startswith("--duration")


def test_a_huge_set_word_is_cut_in_the_message() -> None:
    """Repro: `--set motor.rs_ohm=<100 kB>` and a 100 kB key were echoed in full."""
    huge = "9" * 100_000
    for words in ([f"motor.rs_ohm={huge}x"], [f"{'a' * 100_000}.b=1"], [f"motor.{'k' * 100_000}=1"]):
        with pytest.raises(ConfigError) as refused:
            load_config(None, words)
        assert len(str(refused.value)) < 400, str(refused.value)[:200]
    with pytest.raises(ConfigError) as refused:
        check_overrides([huge])
    assert len(str(refused.value)) < 200


def test_report_window_without_plot_is_refused(tmp_path: Path) -> None:
    """Repro: `report run.csv --window 0:1` printed the summary of every row, the window ignored."""
    recording = tmp_path / "run.csv"
    assert CliRunner().invoke(cli, ["run", "--no-ui", "--no-control", "--duration", "0.01",
                                    "--record", str(recording)]).exit_code == 0
    result = CliRunner().invoke(cli, ["report", str(recording), "--window", "0:0.005", "--csv", str(tmp_path / "o.csv")])
    assert result.exit_code == 2 and "--window chooses what --plot draws: give --plot DIR" in result.output
    assert not (tmp_path / "o.csv").exists()  # (refused before the export)


@pytest.mark.parametrize("option", ["--plot", "--csv"])
def test_step_refuses_an_output_in_a_missing_folder_before_the_steps(option: str, tmp_path: Path) -> None:
    """Repro: `step --plot /nonexistent/x.png` made the folder; `--csv` there failed after every step ran."""
    missing = tmp_path / "nope" / "x.out"
    result = CliRunner().invoke(cli, ["step", option, str(missing)])
    assert result.exit_code == 2 and f"{option} {missing}: no folder {missing.parent}" in result.output
    assert not missing.parent.exists()


def test_a_delay_that_holds_the_run_for_long_is_said_before_it() -> None:
    """Repro: `?delay_ms=60000&delay_rate=1` held every exchange a minute, with nothing said."""
    from hilbench.bench.feasibility import check_run

    cfg = load_run_config(RunRequest(target="emulator:an1017?delay_ms=60000&delay_rate=1", duration_s=2.0))
    assert any("delay_ms=60000 on 100% of the frames" in text and "h in all" in text for text in check_run(cfg))
    cfg = load_run_config(RunRequest(target="emulator:an1017?delay_ms=1&delay_rate=0.01", duration_s=2.0))
    assert not any("delay_ms" in text for text in check_run(cfg))


def test_a_number_longer_than_python_converts_is_one_line(tmp_path: Path) -> None:
    """Repro: `rs_ohm = 999…9` (5000 digits) in a config or a gains file was a ValueError traceback
    (tomllib's int() past Python's 4300-digit limit); in a --set it is a word like any other."""
    huge = "9" * 5000
    config = tmp_path / "big.toml"
    config.write_text(f"[motor]\nrs_ohm = {huge}\n")
    with pytest.raises(ConfigError, match=r"big\.toml: not valid TOML for hilbench: a number of over \d+ digits"):
        load_config(str(config))
    gains = tmp_path / "gains.toml"
    gains.write_text(f"[target]\nkp = {huge}\n")
    with pytest.raises(ConfigError, match=r"gains\.toml: not valid TOML for hilbench: a number of over"):
        params_file_overrides(str(gains))
    with pytest.raises(ConfigError, match=r"^--set motor\.rs_ohm \[motor\] rs_ohm: expected a number, got str '9999"):
        load_config(None, [f"motor.rs_ohm={huge}"])


def test_the_readme_scenario_example_loads(tmp_path: Path) -> None:
    """Repro: the README's example wrote `kp = 0.12` in a [[scenario]] table, which is refused
    ("unknown key"); the example is loaded as a --scenario file here."""
    readme = (Path(__file__).resolve().parent.parent / "README.md").read_text(encoding="utf-8")
    block = next(b.split("```", 1)[0] for b in readme.split("```toml\n")[1:] if b.startswith("[[scenario]]"))
    scenario = tmp_path / "example.toml"
    scenario.write_text(block)
    cfg = load_run_config(RunRequest(scenario=str(scenario)))
    assert [dict(e.set or {}) for e in cfg.scenario if e.set] == [{"kp": 0.12}]


def test_a_scenario_set_the_target_does_not_declare_is_refused_before_the_run(tmp_path: Path) -> None:
    """Repro: `set = { zz = 1 }` (a typo) was refused in the run, on a line only the dashboard shows,
    and the run passed; an empty `set = {}` was recorded as an event and did nothing."""
    from hilbench.bench.run import run_bench

    scenario = tmp_path / "s.toml"
    scenario.write_text("[[scenario]]\nat_s = 0.0\nref_rpm = 1500.0\n[[scenario]]\nat_s = 0.01\nset = { zz = 1 }\n")
    record = tmp_path / "run.csv"
    cfg = load_run_config(RunRequest(scenario=str(scenario), target="inprocess:an1017", duration_s=0.02))
    with pytest.raises(ConfigError, match=r"at_s = 0.01: set 'zz': inprocess:an1017 declares no such parameter"):
        run_bench(cfg, record=record)
    assert not record.exists()  # refused at the handshake: no recording with its header only
    scenario.write_text("[[scenario]]\nat_s = 0.0\nset = {}\n")
    with pytest.raises(ConfigError, match=r"set: names no parameter"):
        load_run_config(RunRequest(scenario=str(scenario)))


def test_a_scenario_set_the_target_refuses_is_a_warning_and_an_event(tmp_path: Path) -> None:
    """Repro: a set the firmware's constraint refuses was logged in the recording as if applied."""
    from hilbench.bench.run import run_bench
    from hilbench.bench.recorder import read_recording

    scenario = tmp_path / "s.toml"
    scenario.write_text("[[scenario]]\nat_s = 0.0\nref_rpm = 1500.0\n"
                        "[[scenario]]\nat_s = 0.01\nset = { kp = 0.5, ki = 0.5, kd = 0.5 }\n")
    cfg = load_run_config(RunRequest(scenario=str(scenario), target="inprocess:an1017", duration_s=0.02))
    summary = run_bench(cfg, record=tmp_path / "r.csv")
    assert any("set kp=0.5 ki=0.5 kd=0.5 at 0.010 s refused" in w for w in summary.warnings)
    events = read_recording(tmp_path / "r.csv").events
    assert any("refused set kp=0.5" in e for e in events) and not any(" set kp=0.5" in e and "refused" not in e
                                                                       for e in events)


def test_a_gain_or_tolerance_given_twice_is_refused() -> None:
    """Repro (second audit): `step --gains kp=0.1,kp=0.2` and `sweep --tolerance rs=0.1,rs=0.2` took
    the last value; `ctl set` refuses the same."""
    from hilbench.bench.steptest import parse_gain_sets

    with pytest.raises(ConfigError, match="kp given twice"):
        parse_gain_sets(["kp=0.1,kp=0.2"], ("kp", "ki", "kd"))
    result = CliRunner().invoke(cli, ["sweep", "--tolerance", "rs=0.1,rs=0.2"])
    assert result.exit_code == 2 and "rs given twice" in result.output


def test_a_window_that_is_not_finite_says_so() -> None:
    """Repro (second audit): `--window nan:1` said "T1 must be after T0"."""
    from hilbench.ui.plots import parse_window

    for text in ("nan:1", "0:inf"):
        with pytest.raises(ConfigError, match="must be finite numbers of seconds"):
            parse_window(text)
