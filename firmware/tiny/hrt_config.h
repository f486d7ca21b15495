/* hrt_config.h: the runtime's capacities for the tiny V/f drive: no timers, no ADC, no encoder, no
 * edge events (it reads only the S2 button, at the span's start). */
#ifndef TINY_HRT_CONFIG_H
#define TINY_HRT_CONFIG_H

#define HRT_MAX_TIMERS 1u
#define HRT_MAX_ADC 1u
#define HRT_ENCODER 0
#define HRT_HALF_PERIOD 0
#define HRT_MAIN_RATE 0

#endif /* TINY_HRT_CONFIG_H */
