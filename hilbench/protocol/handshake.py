"""The handshake's compatibility check: protocol version AND schema fingerprint, on both sides.

A protocol version alone misses a board flashed from an older schema.toml at the same version;
the schema fingerprint (first 4 bytes of SHA-256 over the schema's wire content, generated into
messages.SCHEMA_FINGERPRINT and the C HBP_SCHEMA_FINGERPRINT) catches that. Both hellos carry it,
and every ErrorReport carries its sender's, so a refused handshake can name both builds in one line.
No I/O here: the link layer and the targets call these.
"""

from __future__ import annotations

from hilbench.errors import TargetError, VersionMismatch
from hilbench.protocol.messages import (
    PROTOCOL_VERSION,
    SCHEMA_FINGERPRINT,
    ErrorCode,
    ErrorReport,
    HostHello,
    TargetHello,
)

REBUILD_HINT = "rebuild the firmware from this hilbench's firmware_protocol/"


def mismatch_message(where: str, target_fingerprint: int, target_version: int,
                     host_fingerprint: int = SCHEMA_FINGERPRINT, host_version: int = PROTOCOL_VERSION) -> str:
    """One line naming both schema fingerprints (hex) and both protocol versions."""
    return (f"{where}: firmware built from schema {target_fingerprint:#010x} (protocol version {target_version}), "
            f"this host speaks schema {host_fingerprint:#010x} (protocol version {host_version}); {REBUILD_HINT}")


def check_target_hello(hello: TargetHello, *, where: str) -> None:
    """Raise VersionMismatch unless the target speaks this host's protocol version and schema, and
    TargetError if it declares what no firmware can (`hello_problem`)."""
    if hello.protocol_version != PROTOCOL_VERSION or hello.schema_fingerprint != SCHEMA_FINGERPRINT:
        raise VersionMismatch(mismatch_message(where, hello.schema_fingerprint, hello.protocol_version))
    problem = hello_problem(hello)
    if problem is not None:
        raise TargetError(f"{where}: its TargetHello declares {problem}")


def hello_problem(hello: TargetHello) -> str | None:
    """What a TargetHello declares that no firmware can (the plant divides by the PWM scale and the
    ADC's full scale), or None."""
    if not hello.firmware_name:
        return "no firmware name"
    if hello.pwm_period_counts <= 0:
        return f"pwm_period_counts {hello.pwm_period_counts} (the compare count of 100 % duty must be positive)"
    if hello.pwm_freq_hz <= 0:
        return f"pwm_freq_hz {hello.pwm_freq_hz} (the PWM frequency must be positive)"
    if not 1 <= hello.adc_bits <= 16:
        return f"adc_bits {hello.adc_bits} (an ADC of 1 to 16 bits: Sensors carries u16 codes)"
    return None


def version_refusal(report: ErrorReport, host: HostHello, *, where: str) -> VersionMismatch:
    """The error for a target's ErrorReport(VERSION, its version) answer to the HostHello `host`."""
    return VersionMismatch(mismatch_message(where, report.schema_fingerprint, report.detail,
                                            host.schema_fingerprint, host.protocol_version))


def host_hello_mismatch(hello: HostHello) -> str | None:
    """Target side: why a HostHello is refused (answer ErrorReport(VERSION, PROTOCOL_VERSION)), or None."""
    if hello.protocol_version == PROTOCOL_VERSION and hello.schema_fingerprint == SCHEMA_FINGERPRINT:
        return None
    return (f"host built from schema {hello.schema_fingerprint:#010x} (protocol version {hello.protocol_version}), "
            f"this target speaks schema {SCHEMA_FINGERPRINT:#010x} (protocol version {PROTOCOL_VERSION})")


def is_version_refusal(msg: object) -> bool:
    """True for an ErrorReport(VERSION, ...): the target refused our HostHello's version or schema."""
    return type(msg) is ErrorReport and msg.code == ErrorCode.VERSION


__all__ = ["REBUILD_HINT", "mismatch_message", "check_target_hello", "hello_problem", "version_refusal", "host_hello_mismatch",
           "is_version_refusal"]
