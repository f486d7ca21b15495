/* ports/cortex_m4/main.c: the AN1017 firmware on a Cortex-M4 (the Arm MPS2 AN386 image, run in QEMU's
 * mps2-an386 machine): the same firmware and runtime as the dsPIC30F2010 and AVR ports, on the
 * runtime's shared Cortex-M4 port (firmware/runtime/ports/cortex_m4: startup code, memory map, UART0,
 * the clock scaled to the firmware's 20 MHz Tcy, WFI while idle, hrt_m4.c's main). All this file adds
 * is the power-on of the build's variant (AN1017_VARIANT, a make option), which hrt_m4.c asks for. */
#include "an1017.h"

static an1017_t fw;

hrt_t *hrt_firmware_init(void)
{
    an1017_init(&fw, AN1017_VARIANT);
    return &fw.rt;
}
