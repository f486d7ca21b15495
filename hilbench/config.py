"""Bench configuration: TOML tables -> frozen dataclasses, validated as a whole.

Every TOML table maps to a dataclass ("section"). Field metadata (see `spec`) gives the unit,
the physical range and a one-line doc. `load_config` collects *every* problem — missing key,
wrong type, out of range, unknown key (with a "did you mean"), bad choice — and raises one
`ConfigError` whose lines read `FILE [table] key: reason`.

The tables a config may hold are an explicit registry (`Sections`), passed to `load_config`: this
module owns the plant's (`PLANT_SECTIONS`); the bench adds its own to them
(`hilbench.bench.settings.SECTIONS`, what `hilbench.load_config` reads). Nothing registers a
table by being imported. A later layer extends a registry with a few lines, no edit here:

    @dataclass(frozen=True)
    class RunSection:
        duration_s: float = field(default=1.0, metadata=spec(unit="s", gt=0))
    sections = PLANT_SECTIONS.with_table("run", RunSection)   # optional table, defaults when absent
    cfg = load_config(path, sections=sections); cfg.run.duration_s  # or cfg.sections["run"]

Supported field types: float (ints accepted), int, bool, str, `Literal[...]` choices, nested
dataclasses (sub-tables), `tuple[Dataclass, ...]` (arrays of tables, validated per item),
`tuple[scalar, ...]`, `X | None` (optional, default None). A section may define
`check(self) -> list[tuple[str, str]]` for cross-field rules, returning (key, reason) pairs.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import sys
import tomllib
import types
import typing
from dataclasses import MISSING, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Literal, Mapping, Sequence

from hilbench.errors import ConfigError
from hilbench.limits import CONFIG_MAX_BYTES, clipped, read_text_bounded
from hilbench.fieldspec import spec
from hilbench.plant.params import (
    AdcChannel,
    EncoderParams,
    HallParams,
    InverterParams,
    LoadProfile,
    MotorParams,
    PlantParams,
    ProtectionParams,
    PwmTiming,
    default_adc_channels,
    psi_from_ke,
)

__all__ = [
    "BenchConfig",
    "MotorSection",
    "Override",
    "PlantSection",
    "load_config",
    "plant_from_config",
    "PLANT_SECTIONS",
    "Sections",
    "spec",
    "DEFAULT_CONFIG_NAME",
]

DEFAULT_CONFIG_NAME = "hurst_mclv.toml"


# ---------------------------------------------------------------- sections owned here
@dataclass(frozen=True)
class MotorSection:
    """[motor]: give psi_wb or ke_v_per_krpm (V line-line peak per 1000 rpm), and l_h or ld_h+lq_h."""

    rs_ohm: float = field(metadata=spec(unit="ohm", gt=0, le=1e3, doc="phase (line-neutral) resistance"))
    pole_pairs: int = field(metadata=spec(ge=1, le=64, doc="pole pairs"))
    j_kgm2: float = field(metadata=spec(unit="kg*m^2", gt=0, le=10, doc="rotor + load inertia"))
    l_h: float | None = field(default=None, metadata=spec(unit="H", gt=0, le=10, doc="Ld = Lq"))
    ld_h: float | None = field(default=None, metadata=spec(unit="H", gt=0, le=10))
    lq_h: float | None = field(default=None, metadata=spec(unit="H", gt=0, le=10))
    psi_wb: float | None = field(default=None, metadata=spec(unit="Wb", gt=0, le=10, doc="PM flux, peak per phase"))
    ke_v_per_krpm: float | None = field(default=None, metadata=spec(unit="V/krpm", gt=0, le=1e4))
    b_nms_per_rad: float = field(default=0.0, metadata=spec(unit="N*m*s/rad", ge=0, le=10))
    coulomb_nm: float = field(default=0.0, metadata=spec(unit="N*m", ge=0, le=1e3))
    name: str = field(default="", metadata=spec(doc="free text"))

    def check(self) -> list[tuple[str, str]]:
        bad: list[tuple[str, str]] = []
        if (self.psi_wb is None) == (self.ke_v_per_krpm is None):
            bad.append(("psi_wb", "give exactly one of psi_wb and ke_v_per_krpm"))
        if self.l_h is None and (self.ld_h is None or self.lq_h is None):
            bad.append(("l_h", "give l_h, or both ld_h and lq_h"))
        if self.l_h is not None and (self.ld_h is not None or self.lq_h is not None):
            bad.append(("l_h", "give l_h or ld_h/lq_h, not both"))
        return bad

    def to_params(self) -> MotorParams:
        psi = self.psi_wb if self.psi_wb is not None else psi_from_ke(self.ke_v_per_krpm or 0.0, self.pole_pairs)
        ld = self.ld_h if self.ld_h is not None else self.l_h
        lq = self.lq_h if self.lq_h is not None else self.l_h
        return MotorParams(rs_ohm=self.rs_ohm, ld_h=float(ld), lq_h=float(lq), psi_wb=psi,
                           pole_pairs=self.pole_pairs, j_kgm2=self.j_kgm2,
                           b_nms_per_rad=self.b_nms_per_rad, coulomb_nm=self.coulomb_nm)


@dataclass(frozen=True)
class PlantSection:
    """[plant]: the seed of the sensor noise generator and the RK4 substeps per period."""

    seed: int = field(default=0, metadata=spec(ge=0, doc="seed of the ADC noise generator"))
    substeps: int = field(default=2, metadata=spec(ge=1, le=64, doc="RK4 steps per period (2: energy balance < 1e-6 at 20 kHz)"))


# Range metadata for the plant's own parameter dataclasses (kept in one place, here).
_RANGES: dict[type, dict[str, dict[str, Any]]] = {
    InverterParams: {
        "vbus_v": spec(unit="V", gt=0, le=1500),
        "pwm_freq_hz": spec(unit="Hz", ge=100, le=1e6),
        "dead_time_s": spec(unit="s", ge=0, le=1e-4),
        "model": spec(doc="\"average\": each period's mean leg voltages (fast); \"switching\": every PWM edge "
                          "at its time, the dead time by the current at each edge (docs/design.md, inverter)"),
        "average_dead_time": spec(doc="the averaged model's dead band: \"sign\" of the current at the period's start "
                                      "(the default), or \"edges\": the current's sign at each PWM edge, ripple included"),
    },
    HallParams: {"offset_deg": spec(unit="deg", ge=-360, le=360)},
    EncoderParams: {"lines": spec(ge=1, le=1_000_000), "offset_counts": spec(ge=0, le=65535),
                    "index_counts": spec(ge=0, le=4_000_000)},
    AdcChannel: {
        "gain_codes_per_unit": spec(unit="codes/unit", ge=-1e6, le=1e6),
        "offset_codes": spec(unit="codes", ge=-65535, le=131070),
        "noise_lsb": spec(unit="codes", ge=0, le=65535),
        "bits": spec(ge=8, le=16),
    },
    ProtectionParams: {
        "overcurrent_a": spec(unit="A", ge=0, le=1e5, doc="overcurrent comparator on the peak phase current, drives FAULT (0: none)"),
        "overspeed_rpm": spec(unit="rpm", ge=0, le=1e6, doc="bench limit: the run ends with a fault (0: none)"),
        "bus_capacitance_f": spec(unit="F", ge=0, le=10, doc="bus capacitor charged by regeneration (0: a stiff bus)"),
        "overvoltage_v": spec(unit="V", ge=0, le=1e4, doc="bench limit on the bus voltage (0: none)"),
    },
    LoadProfile: {
        "torque_nm": spec(unit="N*m", ge=-1e3, le=1e3),
        "step_time_s": spec(unit="s", ge=0),
        "step_torque_nm": spec(unit="N*m", ge=-1e3, le=1e3),
        "coeff": spec(ge=0, le=1e3),
    },
}


@dataclass(frozen=True)
class _Section:
    name: str
    cls: type | None
    required: bool
    many: bool  # an array of tables
    #: a table whose dataclass depends on the others (the [target] table: the target's options)
    chooser: Callable[[Mapping[str, Any]], type | None] | None = None
    #: the tables the chooser reads: when one of them is wrong, this one is not judged (its dataclass is unknown)
    needs: tuple[str, ...] = ()
    #: the dotted keys whose values choose it: a chooser's error names the override that set one
    chosen_by: tuple[str, ...] = ()
    #: for a chosen table: who the keys the chosen dataclass does not know belong to (one line), or None
    explain: Callable[[frozenset[str]], str | None] | None = None


@dataclass(frozen=True)
class Sections:
    """The tables a config may hold, each validated into its dataclass: an explicit registry,
    extended by value (`with_table`) and handed to `load_config`."""

    tables: Mapping[str, _Section] = field(default_factory=lambda: types.MappingProxyType({}))

    def with_table(self, name: str, cls: type | None, *, required: bool = False, many: bool = False,
                   chooser: Callable[[Mapping[str, Any]], type | None] | None = None,
                   needs: tuple[str, ...] = (), chosen_by: tuple[str, ...] = (),
                   explain: Callable[[frozenset[str]], str | None] | None = None) -> "Sections":
        """These tables and `[name]` (or `[[name]]` when many) validated into dataclass `cls`.

        Optional tables are built from the dataclass defaults when absent (all fields need one).
        With ``chooser`` the dataclass is chosen after every other table is built (None: the table
        must be absent, and the section is None), from the tables ``needs`` names: when one of them
        has a problem (reported), this table is not judged against a dataclass chosen without it;
        its error names the override (`--target`, `--set`) that set a key of ``chosen_by``. ``explain`` names who several keys the chosen dataclass does not know belong to, said once
        instead of a line per key."""
        if chooser is None and not dataclasses.is_dataclass(cls):
            raise TypeError(f"Sections.with_table {name!r}: {cls!r} is not a dataclass")
        section = _Section(name, cls, required, many, chooser, needs=tuple(needs), chosen_by=tuple(chosen_by),
                           explain=explain)
        return Sections(types.MappingProxyType({**self.tables, name: section}))

    def __contains__(self, name: object) -> bool:
        return name in self.tables

    def names(self) -> list[str]:
        return list(self.tables)


#: the plant's tables: what a config of the plant alone holds
PLANT_SECTIONS = (
    Sections()
    .with_table("motor", MotorSection, required=True)
    .with_table("inverter", InverterParams)
    .with_table("hall", HallParams)
    .with_table("encoder", EncoderParams)
    .with_table("adc", AdcChannel, many=True)
    .with_table("load", LoadProfile)
    .with_table("plant", PlantSection)
    .with_table("protection", ProtectionParams)
)


@dataclass(frozen=True)
class BenchConfig:
    """A validated config: one attribute per registered table (`cfg.motor`, `cfg.adc`, ...)."""

    sections: Mapping[str, Any]
    source: str = "<default>"

    def __getattr__(self, name: str) -> Any:
        sections = self.__dict__.get("sections", {})
        if name in sections:
            return sections[name]
        raise AttributeError(name)

    def __getitem__(self, name: str) -> Any:
        return self.sections[name]

    def __reduce__(self) -> tuple[Any, ...]:  # picklable for process-pool sweeps
        return (_rebuild_config, (dict(self.sections), self.source))

    def replace(self, **sections: Any) -> "BenchConfig":
        """A copy with some tables replaced (e.g. ``cfg.replace(link=...)``)."""
        return BenchConfig(types.MappingProxyType({**self.sections, **sections}), self.source)


def _rebuild_config(sections: dict[str, Any], source: str) -> BenchConfig:
    return BenchConfig(types.MappingProxyType(sections), source)


# ---------------------------------------------------------------- validation
@dataclass(frozen=True)
class Override:
    """A "TABLE.KEY=VALUE" given elsewhere than `--set` (`--target`, a gains file's [target] key):
    a message about its value names ``origin``, where the user wrote it."""

    text: str
    origin: str


class _Collector:
    def __init__(self, source: str, table_sources: Mapping[str, str] = types.MappingProxyType({})) -> None:
        self.source = source
        self.table_sources = table_sources  # a table read from another file (--scenario FILE)
        self.override_keys: dict[str, str] = {}  # a dotted key an override set -> how messages name it
        self.lines: list[str] = []

    def add(self, table: str, key: str, reason: str) -> None:
        dotted = f"{table}.{key}" if key else table
        src = self.override_keys.get(dotted) or self.table_sources.get(table.split("[")[0], self.source)
        where = f"[{clipped(table)}]" if table else ""
        self.lines.append(f"{src} {where} {clipped(key)}: {reason}".replace("  ", " ").replace(" :", ":"))


def _suggest(name: str, known: Sequence[str]) -> str:
    """A "did you mean" for an unknown key: the closest known one, or the one that is this name with
    its unit (``rs`` → ``rs_ohm``: too short for a close match on spelling alone)."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    if not close:
        close = [key for key in known if key.startswith(name + "_")][:1] if name else []
    return f" (did you mean {close[0]!r}?)" if close else ""


def _show(value: Any) -> str:
    """A value as a message shows it: short, one line (a fuzzed value may be 5000 characters)."""
    return clipped(repr(value))


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp))


def _convert(value: Any, tp: Any, table: str, key: str, col: _Collector) -> tuple[bool, Any]:
    """Check/convert one value against a type annotation; report and return (ok, value)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:  # X | None: absent is the default, a given value is an X
            return _convert(value, args[0], table, key, col)
    by_origin = _CONVERT_BY_ORIGIN.get(origin)
    if by_origin is not None:
        return by_origin(value, tp, table, key, col)
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, f"{table}.{key}", col)
    if tp in _SCALARS:
        return _convert_scalar(value, tp, table, key, col)
    col.add(table, key, f"unsupported field type {_type_name(tp)}")
    return False, None


def _convert_literal(value: Any, tp: Any, table: str, key: str, col: _Collector) -> tuple[bool, Any]:
    """One of the `Literal[...]` choices."""
    choices = typing.get_args(tp)
    if value in choices:
        return True, value
    hint = _suggest(str(value), [str(c) for c in choices]) if isinstance(value, str) else ""
    col.add(table, key, f"{_show(value)} is not one of {', '.join(repr(c) for c in choices)}{hint}")
    return False, None


def _convert_tuple(value: Any, tp: Any, table: str, key: str, col: _Collector) -> tuple[bool, Any]:
    """An array: `tuple[Dataclass, ...]` (an array of tables, each validated) or of scalars."""
    item_tp = typing.get_args(tp)[0]
    if not isinstance(value, list):
        col.add(table, key, f"expected an array, got {type(value).__name__}")
        return False, None
    out = []
    ok = True
    for n, item in enumerate(value):
        if dataclasses.is_dataclass(item_tp):
            good, obj = _build(item_tp, item, f"{table}.{key}[{n}]" if key else f"{table}[{n}]", col)
        else:
            good, obj = _convert(item, item_tp, table, f"{key}[{n}]", col)
        ok = ok and good
        out.append(obj)
    return ok, tuple(out)


def _convert_dict(value: Any, tp: Any, table: str, key: str, col: _Collector) -> tuple[bool, Any]:
    """A table of named values, e.g. a scenario's `set = { kp = 0.1 }`."""
    _, item_tp = typing.get_args(tp)
    if not isinstance(value, dict):
        col.add(table, key, f"expected a table, got {type(value).__name__}")
        return False, None
    items = {}
    ok = True
    for name, item in value.items():
        good, obj = _convert(item, item_tp, table, f"{key}.{name}", col)
        ok = ok and good
        items[str(name)] = obj
    return ok, items


#: scalar type -> (whether a TOML value is one, what the message says was expected)
_SCALARS: dict[type, tuple[Callable[[Any], bool], str]] = {
    float: (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool), "a number"),
    int: (lambda v: isinstance(v, int) and not isinstance(v, bool), "an integer"),
    bool: (lambda v: isinstance(v, bool), "true or false"),
    str: (lambda v: isinstance(v, str), "a string"),
}


def _convert_scalar(value: Any, tp: type, table: str, key: str, col: _Collector) -> tuple[bool, Any]:
    """A float (an int is accepted; finite only), int, bool or str."""
    accepts, expected = _SCALARS[tp]
    if not accepts(value):
        col.add(table, key, f"expected {expected}, got {type(value).__name__} {_show(value)}")
        return False, None
    if tp is not float:
        return True, value
    if not math.isfinite(value):
        col.add(table, key, f"expected a finite number, got {_show(value)}")
        return False, None
    return True, float(value)


_CONVERT_BY_ORIGIN: dict[Any, Callable[[Any, Any, str, str, _Collector], tuple[bool, Any]]] = {
    Literal: _convert_literal, tuple: _convert_tuple, dict: _convert_dict,
}


def _range_reason(value: Any, meta: Mapping[str, Any]) -> str | None:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return None
    unit = f" {meta['unit']}" if meta.get("unit") else ""
    if meta.get("gt") is not None and not value > meta["gt"]:
        return f"{_show(value)}{unit} is out of range: must be > {meta['gt']}{unit}"
    if meta.get("ge") is not None and not value >= meta["ge"]:
        return f"{_show(value)}{unit} is out of range: must be >= {meta['ge']}{unit}"
    if meta.get("lt") is not None and not value < meta["lt"]:
        return f"{_show(value)}{unit} is out of range: must be < {meta['lt']}{unit}"
    if meta.get("le") is not None and not value <= meta["le"]:
        return f"{_show(value)}{unit} is out of range: must be <= {meta['le']}{unit}"
    return None


def _build(cls: type, data: Any, table: str, col: _Collector) -> tuple[bool, Any]:
    """Validate a TOML table into dataclass `cls`, reporting every problem to `col`."""
    if not isinstance(data, dict):
        col.add(table, "", f"expected a table, got {type(data).__name__}")
        return False, None
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    ok = True
    for key in data:
        if key not in fields:
            col.add(table, key, f"unknown key{_suggest(key, list(fields))}")
            ok = False
    kwargs: dict[str, Any] = {}
    extra_meta = _RANGES.get(cls, {})
    for name, f in fields.items():
        if name not in data:
            if f.default is MISSING and f.default_factory is MISSING:
                col.add(table, name, "missing")
                ok = False
            continue
        good, value = _convert(data[name], hints[name], table, name, col)
        if not good:
            ok = False
            continue
        meta = {**extra_meta.get(name, {}), **dict(f.metadata)}
        reason = _range_reason(value, meta)
        if reason:
            col.add(table, name, reason)
            ok = False
            continue
        kwargs[name] = value
    if not ok:
        return False, None
    obj = cls(**kwargs)
    check = getattr(obj, "check", None)
    if callable(check):
        for key, reason in check():
            col.add(table, key, reason)
            ok = False
    return ok, obj if ok else None


# ---------------------------------------------------------------- overrides
def parse_value(text: str) -> Any:
    """TOML value syntax; a bare word that is not valid TOML is taken as a string (so is a number
    longer than Python converts: ValueError, which TOMLDecodeError is too)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except (ValueError, RecursionError):
        return text.strip()


def _apply_override(data: dict[str, Any], item: str, col: _Collector, sections: Sections,
                    origin: str | None = None) -> str | None:
    """One `--set TABLE.KEY=VALUE` into the raw tables; returns the dotted key it set (None: refused,
    the message naming ``origin``, else the `--set` word)."""
    where = origin or f"--set {clipped(item, 80)}"
    if "=" not in item:
        col.lines.append(f"{where}: expected TABLE.KEY=VALUE")
        return None
    path, text = item.split("=", 1)
    parts = [p.strip() for p in path.strip().split(".")]
    if len(parts) == 1 and parts[0] in sections and sections.tables[parts[0]].many:  # scenario=[{...}, ...]
        data[parts[0]] = parse_value(text)
        return parts[0]
    if len(parts) < 2 or not all(parts):
        col.lines.append(f"{where}: expected TABLE.KEY=VALUE")
        return None
    node: Any = data
    for i, part in enumerate(parts[:-1]):
        if isinstance(node, dict) and part not in node and parts[i + 1].isdigit():
            col.lines.append(f"{where}: the config has no [[{clipped(part)}]] array to index (replace it whole: "
                             f"--set '{clipped(part)}=[{{...}}, ...]')")
            return None
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                col.lines.append(f"{where}: no item {clipped(part)} in this array")
                return None
            node = node[int(part)]
        else:
            node = node.setdefault(part, {})
    if not isinstance(node, dict):
        col.lines.append(f"{where}: {clipped('.'.join(parts[:-1]), 80)} is not a table")
        return None
    node[parts[-1]] = parse_value(text)
    table = ".".join(parts[:-1])
    return f"{table}.{parts[-1]}"


# ---------------------------------------------------------------- entry points
def default_config_text() -> str:
    """The packaged default config (the Hurst motor on the MCLV board)."""
    return packaged_config_text(DEFAULT_CONFIG_NAME)


def packaged_configs() -> tuple[str, ...]:
    """The names of the configs installed with hilbench (`packaged:NAME`, or NAME alone on the
    command line when no such file is here): the seed systems' benches."""
    folder = resources.files("hilbench").joinpath("data")
    return tuple(sorted(item.name[:-5] for item in folder.iterdir() if item.name.endswith(".toml")))


def packaged_config_text(name: str) -> str:
    return resources.files("hilbench").joinpath("data", name).read_text(encoding="utf-8")


def packaged_name(text: str) -> str | None:
    """The packaged config a name means (``packaged``, ``packaged:NAME``, or a bare ``NAME`` or
    ``NAME.toml`` that is no file here), as its file name; None for a path."""
    word = str(text).strip()
    if word == PACKAGED_PREFIX:
        return DEFAULT_CONFIG_NAME
    explicit = word.startswith(PACKAGED_PREFIX + ":")
    if explicit:
        word = word[len(PACKAGED_PREFIX) + 1:]
    elif os.sep in word or Path(word).exists():
        return None
    stem = word[:-5] if word.endswith(".toml") else word
    if stem in packaged_configs():
        return stem + ".toml"
    if explicit:
        raise ConfigError(f"{text}: no packaged config of that name (packaged: {', '.join(packaged_configs())})"
                          f"{_suggest(stem, packaged_configs())}")
    return None


def parse_toml(text: str, source: str) -> dict[str, Any]:
    """tomllib, with every failure one line naming the file."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {str(exc).splitlines()[0]}") from None
    except ValueError:  # (tomllib's int() of a number longer than Python converts)
        raise ConfigError(f"{source}: not valid TOML for hilbench: a number of over "
                          f"{sys.get_int_max_str_digits()} digits") from None
    except RecursionError:
        raise ConfigError(f"{source}: not valid TOML for hilbench: arrays or tables nested too deep") from None


#: how many configs an `extends` chain may hold
MAX_EXTENDS_DEPTH = 8
PACKAGED_PREFIX = "packaged"


def _packaged_source_name(source: str) -> str:
    """The file name in a packaged config's source ``<packaged NAME.toml>``."""
    return source[len("<packaged "):-1] if source.startswith("<packaged ") else DEFAULT_CONFIG_NAME


def _read_text(path: Path, source: str) -> str:
    """A config or scenario file as text, at most CONFIG_MAX_BYTES (`extends = "/dev/zero"` is refused)."""
    return read_text_bounded(path, CONFIG_MAX_BYTES, ConfigError, source)


def _merge(base: dict[str, Any], child: Mapping[str, Any]) -> dict[str, Any]:
    """``child`` over ``base``: tables merge key by key; arrays of tables ([[adc]], [[scenario]]) and
    values are replaced whole."""
    out = dict(base)
    for key, value in child.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _load_data(path: Path | None, source: str, chain: tuple[str, ...] = ()) -> dict[str, Any]:
    """A config file's tables with its ``extends = "other.toml"`` chain merged under them
    (``extends = "packaged"``: the packaged default; a relative name is beside the file)."""
    text = packaged_config_text(_packaged_source_name(source)) if path is None else _read_text(path, source)
    data = parse_toml(text, source)
    base = data.pop("extends", None)
    if base is None:
        return data
    if not isinstance(base, str) or not base.strip():
        raise ConfigError(f"{source}: extends: expected a config file name (or \"packaged\"), got {_show(base)}")
    if len(chain) >= MAX_EXTENDS_DEPTH:
        raise ConfigError(f"{source}: extends: more than {MAX_EXTENDS_DEPTH} configs in the chain")
    packaged = packaged_name(base) if base.strip().startswith(PACKAGED_PREFIX) else None
    if packaged is not None:
        parent_path, parent_source = None, f"<packaged {packaged}>"
    else:
        parent_path = Path(base) if path is None or Path(base).is_absolute() else path.parent / base
        parent_source = str(parent_path)
    key = parent_source if parent_path is None else str(parent_path.resolve())
    if key in chain:
        raise ConfigError(f"{source}: extends {base!r}: a loop ({' -> '.join(chain + (key,))})")
    parent = _load_data(parent_path, parent_source, chain + (key,))
    return _merge(parent, data)


def load_scenario_file(path: str | Path) -> list[Any]:
    """The [[scenario]] entries of a file (`--scenario FILE`): a file of [[scenario]] tables."""
    source = str(path)
    data = parse_toml(_read_text(Path(path), source), source)
    unknown = sorted(set(data) - {"scenario"})
    if unknown or not isinstance(data.get("scenario"), list):
        raise ConfigError(f"{source}: a scenario file holds [[scenario]] tables only"
                          + (f" (found [{unknown[0]}])" if unknown else " (none found)"))
    return list(data["scenario"])


def load_config(path: str | Path | None = None, overrides: Sequence[str | Override] = (), *, sections: Sections,
                scenario_path: str | Path | None = None) -> BenchConfig:
    """Read (with its `extends` chain), merge `overrides` ("table.key=value", TOML value syntax;
    "scenario=[...]" replaces a whole array of tables) and a scenario file, validate the tables
    ``sections`` registers (`PLANT_SECTIONS`; a whole bench: `hilbench.load_config`), build."""
    packaged = DEFAULT_CONFIG_NAME if path is None else packaged_name(str(path))
    source = f"<packaged {packaged}>" if packaged is not None else str(path)
    data = _load_data(None if packaged is not None else Path(path), source,  # type: ignore[arg-type]
                      (source,) if packaged is not None else (str(Path(path).resolve()),))  # type: ignore[arg-type]
    if scenario_path is not None:
        data["scenario"] = load_scenario_file(scenario_path)
    in_file = set(data)
    col = _Collector(source, {"scenario": str(scenario_path)} if scenario_path is not None else {})
    words = [item.text if isinstance(item, Override) else item for item in overrides]
    for item in overrides:
        text, origin = (item.text, item.origin) if isinstance(item, Override) else (item, None)
        key = _apply_override(data, text, col, sections, origin)
        if key:
            col.override_keys[key] = origin or f"--set {clipped(key, 80)}"
    _unknown_tables(data, in_file, words, sections, col)
    built = _build_tables(data, sections, col)
    if not col.lines:
        _check_integrator(built, col)
    if col.lines:
        err = ConfigError("\n".join(col.lines))
        err.lines = list(col.lines)  # type: ignore[attr-defined]
        raise err
    if "adc" in built and "adc" not in data and "inverter" in built:
        built["adc"] = default_adc_channels(built["inverter"].vbus_v)
    return BenchConfig(sections=types.MappingProxyType(built), source=source)


def _unknown_tables(data: Mapping[str, Any], in_file: set[str], overrides: Sequence[str], sections: Sections,
                    col: _Collector) -> None:
    """A table no section registers, blamed on the `--set` that made it when a file did not."""
    for key in data:
        if key not in sections:
            culprit = next((item for item in overrides if item.split("=", 1)[0].strip().split(".")[0] == key), None)
            where = f"--set {clipped(culprit.split('=', 1)[0].strip(), 80)}" if key not in in_file and culprit else col.source
            col.lines.append(f"{where}: unknown table [{clipped(key)}]{_suggest(key, sections.names())}")


def _build_tables(data: Mapping[str, Any], sections: Sections, col: _Collector) -> dict[str, Any]:
    """Every registered table, then those whose dataclass the others choose."""
    built: dict[str, Any] = {}
    for sec in sections.tables.values():
        if sec.chooser is None:
            _build_table(sec, data, built, col)
    for sec in sections.tables.values():
        if sec.chooser is not None:
            _build_chosen(sec, data, built, col)
    return built


def _build_table(sec: _Section, data: Mapping[str, Any], built: dict[str, Any], col: _Collector) -> None:
    """One table (absent: its defaults, an empty array, or "missing" when required)."""
    name = sec.name
    if name not in data:
        if sec.required:
            col.add(name, "", "missing table")
            return
        if sec.many:
            built[name] = default_adc_channels() if sec.cls is AdcChannel else ()
            return
        good, obj = _build(sec.cls, {}, name, col)  # type: ignore[arg-type]
    elif sec.many:
        good, obj = _convert(data[name], tuple[sec.cls, ...], name, "", col)  # type: ignore[name-defined]
    else:
        good, obj = _build(sec.cls, data[name], name, col)  # type: ignore[arg-type]
    if good:
        built[name] = obj


#: the config keys of each MotorParams field a stiffness depends on (the first overridden is blamed)
_MOTOR_KEYS = {"ld_h": ("l_h", "ld_h"), "lq_h": ("l_h", "lq_h"), "psi_wb": ("ke_v_per_krpm", "psi_wb")}


def _check_integrator(built: Mapping[str, Any], col: _Collector) -> None:
    """Refuse a motor whose fastest mode the plant's integrator cannot follow at the configured
    period (it would diverge): the plant says which (hilbench.plant.stiffness)."""
    from hilbench.plant.period import MAX_STEP_US
    from hilbench.plant.stiffness import stiff_modes

    motor, link, plant = built.get("motor"), built.get("link"), built.get("plant")
    if motor is None or plant is None:
        return
    period_us = getattr(link, "period_us", MAX_STEP_US)
    try:
        modes = stiff_modes(motor.to_params(), period_us, plant.substeps)
    except (ArithmeticError, ValueError):
        col.add("motor", "", "these values overflow the plant's equations")
        return
    if not modes:
        return
    mode = modes[0]
    needed = mode.substeps_needed
    n = "over 10^12" if needed > 1e12 else str(math.ceil(needed))
    keys = dict.fromkeys(key for name in mode.depends_on for key in _MOTOR_KEYS.get(name, (name,)))
    present = [k for k in keys if getattr(motor, k, None) is not None]
    key = next((k for k in present if f"motor.{k}" in col.override_keys), present[0])
    col.add("motor", key, f"too stiff for the plant's integrator: {mode.what} is {mode.rate_per_s:.3g}/s, so a "
                          f"{period_us} us period needs {n} [plant] substeps (have {plant.substeps}, at most 64)")


def _build_chosen(sec: _Section, data: Mapping[str, Any], built: dict[str, Any], col: _Collector) -> None:
    """Build a table whose dataclass the other tables choose (the target's options)."""
    assert sec.chooser is not None
    if any(name not in built for name in sec.needs):  # a table it is chosen by is wrong (and reported)
        return
    try:
        cls = sec.chooser(built)
    except ConfigError as exc:  # the chooser names the table at fault; the message, where it was set
        origin = next((col.override_keys[key] for key in sec.chosen_by if key in col.override_keys), col.source)
        col.lines.append(f"{origin}: {exc}")
        return
    if cls is None:
        if data.get(sec.name):
            col.add(sec.name, "", f"this target takes no [{sec.name}] options (keys: {', '.join(data[sec.name])})")
        built[sec.name] = None
        return
    table = data.get(sec.name, {})
    unknown = frozenset(table) - {f.name for f in dataclasses.fields(cls)} if isinstance(table, Mapping) else frozenset()
    hint = sec.explain(unknown) if sec.explain is not None and len(unknown) >= 2 else None
    if hint is not None:  # a table written for something else: one line, not one per key
        shown = ", ".join(sorted(unknown)[:4]) + (f", … ({len(unknown)} keys)" if len(unknown) > 4 else "")
        col.add(sec.name, "", f"{shown}: {hint}")
        return
    good, obj = _build(cls, table, sec.name, col)
    if good:
        built[sec.name] = obj


def plant_params_from_config(cfg: BenchConfig, pwm: PwmTiming | None = None) -> PlantParams:
    """The plant of a config; ``pwm``: the target's PWM timing (its profile's), else the default."""
    return PlantParams(
        motor=cfg.motor.to_params(),
        inverter=cfg.inverter,
        hall=cfg.hall,
        encoder=cfg.encoder,
        adc=tuple(cfg.adc),
        load=cfg.load,
        protection=cfg.protection,
        pwm=pwm if pwm is not None else PwmTiming(),
    )


def plant_from_config(cfg: BenchConfig, seed: int | None = None, pwm: PwmTiming | None = None) -> "Plant":
    """A Plant built from a validated config ([plant] substeps per period), seeded with ``seed``
    (None: [plant] seed; a bench passes its run's seed, `hilbench.bench.assembly.build_plant`), with
    the target's PWM timing ``pwm`` (its profile's; None: the default)."""
    from hilbench.plant.model import Plant

    return Plant(plant_params_from_config(cfg, pwm), seed=cfg.plant.seed if seed is None else seed,
                 substeps=cfg.plant.substeps)


if typing.TYPE_CHECKING:
    from hilbench.plant.model import Plant
