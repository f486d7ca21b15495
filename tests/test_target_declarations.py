"""What a target declares of itself is checked at the handshake (third audit): a TargetHello with a
zero PWM scale crashed `run` with a traceback in the plant, one with a zero PWM frequency was
served; a self-description with two parameters of one name or a swapped range was accepted."""

from __future__ import annotations

import pytest

from hilbench.errors import TargetError
from hilbench.protocol import (
    ACCESS_RW,
    PROTOCOL_VERSION,
    PTYPE_Q15,
    SCHEMA_FINGERPRINT,
    ParamInfo,
    TargetHello,
    check_target_hello,
)
from hilbench.targets.describe import describe

GOOD = TargetHello(0, PROTOCOL_VERSION, SCHEMA_FINGERPRINT, 1, 1000, 20000, 2, 10, "mine", (), ())


@pytest.mark.parametrize(("field", "value", "says"), [
    ("pwm_period_counts", 0, "pwm_period_counts 0 (the compare count of 100 % duty must be positive)"),
    ("pwm_freq_hz", 0, "pwm_freq_hz 0 (the PWM frequency must be positive)"),
    ("adc_bits", 0, "adc_bits 0"),
    ("adc_bits", 17, "adc_bits 17"),
    ("firmware_name", "", "no firmware name"),
])
def test_a_hello_declaring_what_no_firmware_can_is_refused(field: str, value: object, says: str) -> None:
    check_target_hello(GOOD, where="socket://x")
    with pytest.raises(TargetError, match=r"^socket://x: its TargetHello declares " + says.replace("(", r"\(")
                       .replace(")", r"\)")):
        check_target_hello(GOOD._replace(**{field: value}), where="socket://x")


class _Describing:
    def __init__(self, *params: ParamInfo) -> None:
        self.params = params

    def describe(self, param_id: int) -> ParamInfo:
        return self.params[param_id]


def _param(param_id: int, name: str, low: int = 0, high: int = 32767) -> ParamInfo:
    return ParamInfo(0, param_id, int(PTYPE_Q15), int(ACCESS_RW), low, high, 0, name, "")


@pytest.mark.parametrize(("params", "says"), [
    ((_param(0, "kp"), _param(1, "kp")), "ParamDescribe 1: the name 'kp' is parameter 0's too"),
    ((_param(0, "kp"), _param(1, "ki", 5, -5)), "ParamDescribe 1 ('ki'): min 5 > max -5"),
    ((_param(0, "kp"), _param(0, "ki")), "ParamDescribe 1: answered for parameter 0"),
])
def test_a_self_description_that_cannot_be_tuned_by_name_is_refused(params: tuple[ParamInfo, ...],
                                                                     says: str) -> None:
    assert len(describe(_Describing(_param(0, "kp"), _param(1, "ki")), GOOD, "socket://x").params) == 2
    with pytest.raises(TargetError) as caught:
        describe(_Describing(*params), GOOD, "socket://x")
    assert str(caught.value) == f"socket://x: mine: {says}"
