"""The plant: PMSM + averaged inverter + hall/encoder/ADC sensors + load (no I/O, no wall clock).

Public: `Plant(params, seed)`, the parameter dataclasses, `plant_from_config`
(in hilbench.config).
"""

from hilbench.plant.model import HALL_BY_SECTOR, OUTPUT_LOW_SIDE, OUTPUT_OFF, OUTPUT_PWM, Plant
from hilbench.plant.params import (
    AdcChannel,
    EncoderParams,
    HallParams,
    InverterParams,
    LoadProfile,
    MotorParams,
    PlantParams,
    default_adc_channels,
    ke_from_psi,
    psi_from_ke,
)

__all__ = [
    "Plant",
    "PlantParams",
    "MotorParams",
    "InverterParams",
    "HallParams",
    "EncoderParams",
    "AdcChannel",
    "LoadProfile",
    "default_adc_channels",
    "psi_from_ke",
    "ke_from_psi",
    "HALL_BY_SECTOR",
    "OUTPUT_OFF",
    "OUTPUT_PWM",
    "OUTPUT_LOW_SIDE",
]
