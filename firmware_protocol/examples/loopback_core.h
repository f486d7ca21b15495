/* loopback_core.h: the loopback target's protocol handling, shared by the PC and AVR examples. */
#ifndef LOOPBACK_CORE_H
#define LOOPBACK_CORE_H

#include <stdint.h>

#include "hbp.h"

/* The receive state machine: the platform feeds it every received byte (hbp_rx_byte). */
extern hbp_rx_t loopback_rx;

/* Handle one ready frame (loopback_rx.buf, loopback_rx.frame_len); returns loopback_send's result
 * (0 = sent or nothing to send). The caller then calls hbp_rx_release(&loopback_rx). */
int loopback_handle(const uint8_t *buf, uint8_t len);

/* Provided by the platform: write n wire bytes; 0 on success. */
int loopback_send(const uint8_t *wire, uint8_t n);

#endif /* LOOPBACK_CORE_H */
