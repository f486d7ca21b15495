/* an1017_dspic30f2010.c: the whole dsPIC30F2010 build as ONE translation unit (the Makefile compiles this
 * file alone; it holds no code of its own, only the build's sources, each still compiled on its own by
 * every other build and by tests/test_firmware_dspic.py).
 *
 * Why: the runtime reads the firmware's declaration (`hrt_firmware`: its timers, edges, bodies,
 * PWM timing, parameter table) through a const object. Compiled apart, every field is a load and every
 * body an indirect call; in one unit the compiler folds the constants and calls the bodies directly.
 * XC16 has no link-time optimisation to do that across files, and its free licence stops at -O1, which
 * folds constant loads (GCC's CCP) in a unit. By the flash estimate (docs/board.md section 3a) this
 * saves about 200 of the chip's 4 096 instruction words. */
#include "main.c"
#include "an1017.c"
#include "hrt.c"
#include "hrt_link.c"
#include "hbp.c"
