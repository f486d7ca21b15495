"""The target kit: what every target written in Python shares, written once.

* `ParamSpec` and `ParamTable`: a declarative parameter table (id, name, fixed-point type, access,
  range, unit) with `describe`, `get` and `set` speaking the protocol's result codes. A set is all
  or nothing, checked in the order the C runtime checks it (firmware_protocol/hbp.c
  `hbp_param_set`): the request's size, then per pair its id, access, range and no id twice, then
  the firmware's own constraint on the candidate values, and only then any write. OK names
  parameter 0, as `hbp_param_set` does, or the last one written for a firmware whose bridge says so
  (the AN1017 board firmware's, firmware/an1017/an1017_bridge.c).
* `RepeatAnswer`: the answer to a repeated sequence number (a duplicated Sensors frame): the last
  Drive again, the firmware not stepped.
* `served_mode`: a HostHello's mode, refused unless it is lockstep or real time (a Python target
  does not predict its next period's duties: mode PREDICT is the C runtime's, firmware/runtime).
* `core_field` and `realtime_core_of`: a target on a compiled core keeps the state its C paths
  share in the core's struct, and offers the core's C advance to real time's serve loop.

The same table describes a firmware's parameters to the bench (a profile's `params`), so a profile
built from a self-describing firmware's handshake holds the same `ParamSpec`s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping, Sequence

from hilbench.errors import ConfigError, ParamError
from hilbench.protocol import Access, Drive, HostHello, Mode, ParamInfo, ParamSetResult, ParamValue, Result, Sensors

#: the most pairs one ParamSet may carry (the C runtime's HBP_MAX_PARAM_PAIRS)
MAX_SET_PAIRS = 4
ACCESS_RW = int(Access.RW)
RESULT_OK = int(Result.OK)
RESULT_UNKNOWN_ID = int(Result.UNKNOWN_ID)
RESULT_READ_ONLY = int(Result.READ_ONLY)
RESULT_OUT_OF_RANGE = int(Result.OUT_OF_RANGE)
RESULT_CONSTRAINT = int(Result.CONSTRAINT)
RESULT_BAD_REQUEST = int(Result.BAD_REQUEST)


def core_field(name: str) -> property:
    """A target attribute kept in its compiled core's struct (``self.fw.<name>``): the core's own C
    paths (the session's C span, real time's serve loop) and the Python methods share one value."""
    return property(lambda self: getattr(self.fw, name), lambda self, value: setattr(self.fw, name, value))


def realtime_core_of(target: Any, advance: Callable[..., Drive], api: Any) -> tuple[Any, Any] | None:
    """What a target offers real time's serve loop in C (`serve._Server._realtime_in_c`): hbglue.h's
    target capsule ``api`` and the core ``target.fw``, whose C ``advance`` stands for ``advance`` (the
    Python method, held equal to it by tests/test_realtime_serve.py); None when the target's class
    has an ``advance`` of its own (the C loop would step past it)."""
    return (api, target.fw) if type(target).advance is advance else None


def served_mode(host: HostHello, where: str) -> int:
    """The mode of `host` when this target serves it (lockstep, real time); ConfigError otherwise, so a
    host asking for mode PREDICT learns it is not served (a wire target answers BAD_REQUEST)."""
    mode = int(host.mode)
    if mode not in (Mode.LOCKSTEP, Mode.REALTIME):
        raise ConfigError(f"{where} hello: mode {mode} is not served (0 lockstep, 1 realtime)")
    return mode


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter: raw values in [min_value, max_value] of its fixed-point type."""

    param_id: int
    name: str
    ptype: int  # ParamType
    access: int = ACCESS_RW  # Access
    min_value: int = 0
    max_value: int = 0
    unit: str = ""


#: the candidate values of a set (every declared id) and the ids it writes -> None, or the broken
#: constraint as (the parameter named, the constraint's number)
ConstraintCheck = Callable[[Mapping[int, int], tuple[int, ...]], "tuple[int, int] | None"]


class ParamTable:
    """A firmware's declared parameters: ``read(id)`` gives a value now, ``write(values, written)``
    applies a checked candidate set (every declared id; ``written``: the ids the request set)."""

    def __init__(self, specs: Iterable[ParamSpec], read: Callable[[int], int],
                 write: Callable[[dict[int, int], tuple[int, ...]], None], check: ConstraintCheck | None = None,
                 *, ok_names_last: bool = False) -> None:
        self.specs = {spec.param_id: spec for spec in specs}
        self.read = read
        self.write = write
        self.check = check
        self.ok_names_last = ok_names_last  # OK names the last parameter written (else 0)

    def __len__(self) -> int:
        return len(self.specs)

    def describe(self, param_id: int) -> ParamInfo:
        """The declaration of one parameter and its value; an unknown id raises ParamError."""
        spec = self.specs.get(param_id)
        if spec is None:
            raise ParamError(f"describe: unknown param id {param_id}")
        return ParamInfo(0, param_id, spec.ptype, spec.access, spec.min_value, spec.max_value, self.read(param_id),
                         spec.name, spec.unit)

    def get(self, param_id: int) -> ParamValue:
        """One value; result UNKNOWN_ID for an undeclared id."""
        if param_id not in self.specs:
            return ParamValue(0, param_id, RESULT_UNKNOWN_ID, 0)
        return ParamValue(0, param_id, RESULT_OK, self.read(param_id))

    def values(self) -> dict[int, int]:
        """Every declared value now."""
        return {pid: self.read(pid) for pid in self.specs}

    def set(self, pairs: Sequence[tuple[int, int]]) -> ParamSetResult:
        """All or nothing (see the module docstring)."""
        if not pairs or len(pairs) > MAX_SET_PAIRS:
            return ParamSetResult(0, RESULT_BAD_REQUEST, 0, 0)
        for index, (pid, value) in enumerate(pairs):
            refused = self._refusal(pid, value, pairs[:index])
            if refused is not None:
                return ParamSetResult(0, refused, pid, 0)
        candidate = self.values()
        written = tuple(pid for pid, _ in pairs)
        candidate.update(pairs)
        broken = self.check(candidate, written) if self.check is not None else None
        if broken is not None:
            return ParamSetResult(0, RESULT_CONSTRAINT, broken[0], broken[1])
        self.write(candidate, written)
        return ParamSetResult(0, RESULT_OK, written[-1] if self.ok_names_last else 0, 0)

    def _refusal(self, pid: int, value: int, before: Sequence[tuple[int, int]]) -> int | None:
        """Why one pair is refused (a result code), or None."""
        spec = self.specs.get(pid)
        if spec is None:
            return RESULT_UNKNOWN_ID
        if spec.access != ACCESS_RW:
            return RESULT_READ_ONLY
        if not spec.min_value <= value <= spec.max_value:
            return RESULT_OUT_OF_RANGE
        if any(other == pid for other, _ in before):
            return RESULT_BAD_REQUEST  # the same id twice
        return None


class RepeatAnswer:
    """A target's answer to a repeated seq: a Sensors with the seq of the last Drive gets that Drive
    again, and the firmware does not step (a duplicated frame is never acted on twice)."""

    __slots__ = ("last", "repeats", "step_new")

    def __init__(self, step_new: Callable[[Sensors], Drive]) -> None:
        self.step_new = step_new
        self.last: Drive | None = None
        self.repeats = 0  # repeated Sensors answered

    def step(self, sensors: Sensors) -> Drive:
        last = self.last
        if last is not None and sensors[0] == last[0]:
            self.repeats += 1
            return last
        self.last = drive = self.step_new(sensors)
        return drive

    def forget(self) -> None:
        """The next Sensors is a new period whatever its seq (a handshake, a stop, a watchdog trip)."""
        self.last = None


__all__ = ["MAX_SET_PAIRS", "ConstraintCheck", "ParamSpec", "ParamTable", "RepeatAnswer"]
