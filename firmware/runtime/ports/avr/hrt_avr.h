/* firmware/runtime/ports/avr/hrt_avr.h: what a firmware provides to the runtime's AVR port beyond
 * hrt_firmware and hrt_firmware_init() (hrt.h). */
#ifndef HRT_AVR_H
#define HRT_AVR_H

#include "hrt_link.h"

#if HRT_MONITOR
/* A monitor build's pins and timers (its bodies run from their interrupts), set up once after the
 * UART and Timer1 and before interrupts are enabled. */
void hrt_avr_monitor_start(void);
#endif

#endif
