/* hrt_config.h: the runtime's capacities for the FOC firmware (firmware/runtime/hrt.h includes this
 * file from the firmware's folder, so every translation unit of a build sees the same). */
#ifndef FOC_HRT_CONFIG_H
#define FOC_HRT_CONFIG_H

#define HRT_MAX_TIMERS 1u     /* none declared (the main body runs once per span); C has no empty arrays */
#define HRT_REPORT_MEAN 1     /* the Drive's duties: the mean of the active ones over a span of n halves */
#define HRT_MAX_ADC 3u        /* i_a, i_b, Udc */
#define HRT_MAX_ATTACH 0u

#endif /* FOC_HRT_CONFIG_H */
