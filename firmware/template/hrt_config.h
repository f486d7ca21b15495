/* hrt_config.h: the runtime's capacities for this firmware (firmware/runtime/hrt.h includes it from
 * the firmware's folder, so every file of a build sees the same). Size them to what the firmware
 * declares; an empty file takes the defaults (hrt.h, "capacities"). */
#ifndef TEMPLATE_HRT_CONFIG_H
#define TEMPLATE_HRT_CONFIG_H

#define HRT_MAX_TIMERS 1u /* the 1 kHz speed timer */
#define HRT_MAX_ADC 1u    /* the pot (read, not used) */
#define HRT_ENCODER 0     /* no encoder */

#endif /* TEMPLATE_HRT_CONFIG_H */
