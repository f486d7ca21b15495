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
#define HRT_HALF_PERIOD 0     /* duties reload at the next period (HRT_DUTY_NEXT_PERIOD) */
#define HRT_MAIN_RATE 0       /* the main body runs once per span */
/* The largest message sent (type..payload): TargetHello, 17 fixed + name (1 + 6) + ADC roles (1 + 3)
 * + telemetry ids (3) = 31 bytes; ParamInfo of "ph_adv_deg" in "deg", 17 + 11 + 3 = 31; TelemetryInfo of
 * "measured_speed" in "rpm", 13 + 15 + 3 = 31; Drive 11 + 6 = 17. (The link streams the wire bytes.) */
#define HRT_TX_FRAME_MAX 32u
/* Mode PREDICT (the next span's duties predicted from a copy of the state, for periods of many PWM
 * periods): room for the state, sizeof(an1017_t) on every build here (an1017.c checks it), and the
 * mean duties it needs. The dsPIC30F2010 build sets HRT_PREDICT_BYTES=0u on its command line (no RAM
 * for a second copy of the state): its runtime is then as without prediction. */
#ifndef HRT_PREDICT_BYTES
#define HRT_PREDICT_BYTES 192u
#endif
#if HRT_PREDICT_BYTES > 0
#define HRT_REPORT_MEAN 1
#endif
/* The declaration's clock and PWM period as constants (an1017.h), so the runtime's arithmetic on them
 * folds at compile time: 20 Tcy per us, 1000 Tcy a 20 kHz PWM period. */
#define HRT_TICKS_PER_US 20u
#define HRT_PWM_PERIOD_TICKS 1000u

#endif /* AN1017_HRT_CONFIG_H */
