"""Config loader: whole-file validation, did-you-mean, overrides, packaged default, extension."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from hilbench.bench.settings import SECTIONS, load_config
from hilbench.config import PLANT_SECTIONS, plant_from_config, spec
from hilbench.config import load_config as load_tables
from hilbench.errors import ConfigError

CONFIGS = Path(__file__).resolve().parent.parent / "bench_configs"
PKG_DEFAULT = Path(__file__).resolve().parent.parent / "hilbench" / "data" / "hurst_mclv.toml"


def test_bench_configs_load_and_build_plants():
    for name in ("hurst_mclv.toml", "servo_200w.toml"):
        cfg = load_config(CONFIGS / name)
        plant = plant_from_config(cfg)
        plant.step(0.5, 0.5, 0.5, 1, 50e-6)
    hurst = load_config(CONFIGS / "hurst_mclv.toml")
    assert hurst.motor.to_params().psi_wb == pytest.approx(7.32 / (math.sqrt(3) * 5 * 1000 * 2 * math.pi / 60))
    servo = load_config(CONFIGS / "servo_200w.toml")
    assert servo.encoder.lines == 2500 and servo.motor.pole_pairs == 3


def test_packaged_default_is_the_hurst_file():
    assert PKG_DEFAULT.read_bytes() == (CONFIGS / "hurst_mclv.toml").read_bytes()
    assert load_config(None).motor == load_config(CONFIGS / "hurst_mclv.toml").motor


def test_all_errors_reported_at_once(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(
        """
[motor]
rs_ohm = -2.0
l_h = "2 mH"
ke_v_per_krpm = 7.32
pole_pairs = 5
j_kgm2 = 5.5e-6
coulumb_nm = 0.1

[inverter]
vbus_v = 24
pwm_freq_hz = 20000.0
dead_time_enabled = 1

[load]
kind = "stpe"

[encodr]
lines = 4
""",
        encoding="utf-8",
    )
    with pytest.raises(ConfigError) as exc:
        load_config(bad)
    lines = str(exc.value).splitlines()
    f = str(bad)
    expected = [
        f"{f} [motor] rs_ohm:",
        f"{f} [motor] l_h: expected a number",
        f"{f} [motor] coulumb_nm: unknown key (did you mean 'coulomb_nm'?)",
        f"{f} [inverter] dead_time_enabled: expected true or false",
        f"{f} [load] kind:",
        f"{f}: unknown table [encodr] (did you mean 'encoder'?)",
    ]
    for start in expected:
        assert any(line.startswith(start) for line in lines), (start, lines)
    assert len(lines) == len(expected)
    assert "did you mean 'step'" in str(exc.value)


def test_missing_keys_and_tables(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text("[motor]\nrs_ohm = 1.0\npsi_wb = 0.01\nl_h = 1e-3\n", encoding="utf-8")
    with pytest.raises(ConfigError) as exc:
        load_config(p)
    msg = str(exc.value)
    assert f"{p} [motor] pole_pairs: missing" in msg and f"{p} [motor] j_kgm2: missing" in msg
    p.write_text("[plant]\nseed = 1\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"\[motor\]: missing table"):
        load_config(p)


def test_overrides_apply_and_are_validated():
    cfg = load_config(CONFIGS / "hurst_mclv.toml", ["motor.rs_ohm=2.6", 'load.kind="step"', "load.step_torque_nm=0.01"])
    assert cfg.motor.rs_ohm == 2.6 and cfg.load.kind == "step" and cfg.load.step_torque_nm == 0.01
    assert load_config(None, ["load.kind=locked"]).load.kind == "locked"  # bare word = string
    assert load_config(None, ["adc.1.noise_lsb=0"]).adc[1].noise_lsb == 0.0
    with pytest.raises(ConfigError) as exc:
        load_config(None, ["motor.rs_ohm=0", "motor.rs_ohms=1", "nonsense"])
    msg = str(exc.value)
    assert "--set motor.rs_ohm [motor] rs_ohm: 0.0 ohm is out of range" in msg
    assert "did you mean 'rs_ohm'" in msg
    assert "--set nonsense: expected TABLE.KEY=VALUE" in msg


def test_adc_array_items_validated(tmp_path):
    text = (CONFIGS / "hurst_mclv.toml").read_text(encoding="utf-8") + '\n[[adc]]\nrole = "ibs"\ngain_codes_per_unit = 1.0\n'
    p = tmp_path / "a.toml"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=r"\[adc\[3\]\] role: 'ibs' is not one of .*did you mean 'ibus'"):
        load_config(p)


@dataclass(frozen=True)
class Event:
    at_s: float = field(metadata=spec(unit="s", ge=0))
    action: Literal["start", "stop", "set_ref"] = "start"
    value: float | None = None


@dataclass(frozen=True)
class Scenario:
    name: str = "default"
    events: tuple[Event, ...] = ()


def test_a_registry_extends_with_nested_lists_and_choices(tmp_path):
    sections = SECTIONS.with_table("scenario_test", Scenario)
    p = tmp_path / "s.toml"
    base = (CONFIGS / "hurst_mclv.toml").read_text(encoding="utf-8")
    p.write_text(base + '\n[scenario_test]\nname = "x"\n[[scenario_test.events]]\nat_s = 0.1\naction = "stop"\n'
                 '[[scenario_test.events]]\nat_s = -1\naction = "strat"\n', encoding="utf-8")
    with pytest.raises(ConfigError) as exc:
        load_tables(p, sections=sections)
    msg = str(exc.value)
    assert "[scenario_test.events[1]] at_s: -1.0 s is out of range" in msg
    assert "[scenario_test.events[1]] action:" in msg and "did you mean 'start'" in msg
    cfg = load_tables(p, ["scenario_test.events.1.at_s=0.2", 'scenario_test.events.1.action="set_ref"'], sections=sections)
    assert cfg.scenario_test.events[1] == Event(0.2, "set_ref", None)
    assert load_tables(None, sections=sections).scenario_test == Scenario()
    with pytest.raises(ConfigError, match=r"unknown table \[scenario_test\]"):
        load_config(p)  # the bench's own registry: nothing was added to it by the extension


def test_the_plant_registry_alone_reads_a_plant_config_and_refuses_the_bench_tables(tmp_path):
    """Registries are explicit values: importing the bench registers nothing into the plant's."""
    import hilbench.bench.settings  # noqa: F401 - imported, and still no side effect

    plant_only = tmp_path / "plant.toml"
    plant_only.write_text("[motor]\nrs_ohm = 1.0\npole_pairs = 4\nj_kgm2 = 1e-4\nl_h = 1e-3\npsi_wb = 0.01\n")
    cfg = load_tables(plant_only, sections=PLANT_SECTIONS)
    assert cfg.motor.pole_pairs == 4 and "run" not in cfg.sections and cfg.plant.substeps == 2
    with pytest.raises(ConfigError, match=r"unknown table \[check\]"):  # a bench file: its bench tables are unknown
        load_tables(CONFIGS / "hurst_mclv.toml", sections=PLANT_SECTIONS)
    assert set(SECTIONS.names()) >= set(PLANT_SECTIONS.names()) | {"run", "link", "target", "scenario", "check"}
