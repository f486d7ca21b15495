"""What a target spec offers a test: readable ids, capabilities, and the process behind a bench.

Capabilities are the profile's own (``speed_loop``, ``realtime``, ``fault_injection``, ``tuning``,
``hall_sensors``, …, see `hilbench.targets.profile.CAPABILITIES`) plus what the spec itself says:

- ``inprocess``: the model stepped in the test's process;
- ``emulator``: the model as its own process on a virtual serial pair;
- ``link``: frames go over a link (every spec but ``inprocess:``) — needed for link faults;
- ``board``: a port (``serial:``, a device path, ``socket://``, ``rfc2217://``): a board, or
  whatever speaks the protocol there.

A firmware is matched by the name its HELLO carries (``hil_requires(firmware="AN1017")``).
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable, Sequence

if TYPE_CHECKING:
    from hilbench.bench.bench import Bench
    from hilbench.protocol import TargetHello
    from hilbench.targets.profile import TargetProfile

#: capabilities that come from the spec, not from the profile
SPEC_CAPABILITIES = ("inprocess", "emulator", "link", "board")


@dataclass(frozen=True)
class TargetInfo:
    """A target spec as a test sees it, before any bench is opened."""

    spec: str
    id: str  # the readable test id, e.g. "emulator-an1017"
    kind: str  # inprocess | emulator | board
    profile_name: str | None  # the registered target, when the spec or the config names one
    firmware_name: str | None  # the firmware its profile declares (a board's: from its HELLO)
    capabilities: frozenset[str]

    def lacks(self, wanted: Iterable[str], firmware: str | None = None) -> str | None:
        """Why this target cannot run a test needing ``wanted`` (and ``firmware``), else None."""
        missing = [c for c in wanted if c not in self.capabilities]
        reasons = []
        if missing:
            has = ", ".join(sorted(self.capabilities)) or "nothing"
            reasons.append(f"lacks {', '.join(missing)} (has: {has})")
        if firmware is not None and (self.firmware_name or "").upper() != firmware.upper():
            reasons.append(f"runs {self.firmware_name or 'an unknown firmware'}, not {firmware}")
        return f"target {self.spec} " + "; ".join(reasons) if reasons else None


def target_id(spec: str) -> str:
    """A readable test id: `inprocess:an1017` -> `inprocess-an1017`,
    `serial:/dev/ttyUSB0?baud=250000` -> `serial-dev-ttyUSB0-baud-250000`."""
    text = re.sub(r"[^A-Za-z0-9_.]+", "-", spec).strip("-")
    return text or "target"


def unique_ids(specs: Sequence[str]) -> list[str]:
    """Ids for several specs, made unique with a suffix where two read the same."""
    ids: list[str] = []
    for spec in specs:
        base = target_id(spec)
        name, n = base, 2
        while name in ids:
            name, n = f"{base}-{n}", n + 1
        ids.append(name)
    return ids


def spec_kind(spec: str) -> tuple[str, str | None]:
    """(kind, registered target name or None) of a spec."""
    kind, sep, rest = spec.partition(":")
    if sep and kind in ("inprocess", "emulator", "sil", "simavr", "qemu") and not rest.startswith("//"):
        name = re.split(r"[?&]", rest, maxsplit=1)[0]
        return ("inprocess" if kind == "inprocess" else "emulator"), name
    return "board", None


def describe_target(spec: str, firmware: str | None = None, hello_firmware: str | None = None) -> TargetInfo:
    """The TargetInfo of ``spec``; ``firmware``: the registered target a board runs ([link]
    firmware), ``hello_firmware``: the name a board's HELLO gave (profile found by it)."""
    from hilbench.targets.registry import get_profile, profile_for_firmware

    kind, name = spec_kind(spec)
    profile: TargetProfile | None = None
    if name is not None:
        profile = get_profile(name)
    elif firmware is not None:
        profile = get_profile(firmware)
    elif hello_firmware is not None:
        profile = profile_for_firmware(hello_firmware)
    caps = set(profile.capabilities if profile is not None else ())
    caps.add(kind)
    if kind != "inprocess":
        caps.add("link")
    firmware_name = profile.firmware_name if profile is not None else hello_firmware
    if hello_firmware:
        firmware_name = hello_firmware
    return TargetInfo(spec, target_id(spec), kind, profile.name if profile is not None else None, firmware_name,
                      frozenset(caps))


def check_spec(spec: str) -> None:
    """ConfigError (one line) when ``spec`` is not a target spec or names no registered target:
    what `hilbench run --target SPEC` refuses, refused before any test runs."""
    from hilbench.link import parse_target_spec
    from hilbench.targets.registry import get_profile

    from hilbench.targets.starters import FIRMWARE_KINDS

    parsed = parse_target_spec(spec)
    if parsed.kind in ("inprocess", "emulator") or (parsed.kind in FIRMWARE_KINDS and not parsed.program):
        get_profile(parsed.name)  # a build at a path (sil:PATH, simavr:PATH, qemu:PATH) describes itself


def hello_text(hello: "TargetHello") -> str:
    """`AN1017 version 1 (protocol 2)`: the firmware as its HELLO names it (the version is the
    firmware's own u16, PROTOCOL.md)."""
    return f"{hello.firmware_name} version {hello.firmware_version} (protocol {hello.protocol_version})"


def bench_process(bench: "Bench") -> subprocess.Popen[bytes] | None:
    """The emulator process a bench started (None for in-process targets and ports): a test may
    kill it to see the firmware's host go away; the bench reaps it on close."""
    return bench.target_process


__all__ = ["SPEC_CAPABILITIES", "TargetInfo", "bench_process", "check_spec", "describe_target", "hello_text", "spec_kind",
           "target_id", "unique_ids"]
