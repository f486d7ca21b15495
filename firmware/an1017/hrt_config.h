/* hrt_config.h: the runtime's capacities for the AN1017 firmware (firmware/runtime/hrt.h includes
 * this file from the firmware's folder, so every translation unit of a build sees the same).
 * Sized to what the firmware declares, to keep the dsPIC30F2010's 512 bytes of RAM. */
#ifndef AN1017_HRT_CONFIG_H
#define AN1017_HRT_CONFIG_H

#define HRT_MAX_TIMERS 2u     /* Timer1 and the end of ChargeBootstraps */
#define HRT_MAX_ADC 1u        /* only AN2 (the pot) is read; the other channels are ignored */
#define HRT_MAX_ATTACH 0u
#define HRT_ENCODER 0         /* no encoder */
#define HRT_MICROS 0          /* no micros() */
/* The largest frame sent (type..payload): TargetHello, 17 fixed + name (1 + 6) + ADC roles (1 + 3)
 * + telemetry ids (3) = 31 bytes; ParamInfo of "ref_override", 17 + 12 = 29; Drive 11 + 6 = 17. */
#define HRT_TX_FRAME_MAX 32u

#endif /* AN1017_HRT_CONFIG_H */
