/* foc_stream.c: the FOC firmware (firmware/foc) driven by text lines, for tests/test_foc_firmware_c.py.
 *
 * Built with the strict flags and the sanitizers, it runs the firmware's own source outside the
 * CPython glue: each line is a command, each S line answers one line (the Drive's fields).
 *   S inputs encoder ia ib vdc halves   buttons, encoder (+ index bit 0x40), n halves -> Drive
 *   R rpm                               the speed reference
 *   G loop field value                  a gain: loop spd|id|iq, field kp|ki|kc|out_max
 *   START | STOP | TRIP                 commands (TRIP: the watchdog's stop)
 * Drive line: duty_a duty_b duty_c output_mode state sector ccw req_ccw fault t0 .. t7
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "foc.h"

static foc_pi_t *loop_of(foc_t *s, const char *name)
{
    if (strcmp(name, "spd") == 0) {
        return &s->pid_spd;
    }
    return strcmp(name, "id") == 0 ? &s->pid_id : &s->pid_iq;
}

int main(void)
{
    static foc_t fw;
    foc_config_t cfg;
    char line[256];
    foc_config_default(&cfg);
    foc_init(&fw, &cfg);
    while (fgets(line, sizeof line, stdin) != NULL) {
        long a[6];
        char loop[8], field[16];
        long value;
        if (sscanf(line, "S %ld %ld %ld %ld %ld %ld", &a[0], &a[1], &a[2], &a[3], &a[4], &a[5]) == 6) {
            uint16_t duty[3];
            foc_out_t o;
            int k;
            foc_buttons(&fw, (uint16_t)a[0]);
            fw.adc_result[0] = (uint16_t)a[2];
            fw.adc_result[1] = (uint16_t)a[3];
            fw.adc_result[2] = (uint16_t)a[4];
            foc_encoder(&fw, (uint16_t)a[1], (uint16_t)((a[0] & FOC_INPUT_INDEX) != 0));
            foc_run_halves(&fw, (uint32_t)a[5], duty);
            foc_outputs(&fw, &o);
            printf("%u %u %u %u %u %u %u %u %u", duty[0], duty[1], duty[2], o.output_mode, o.state, o.sector, o.ccw,
                   o.req_ccw, o.fault);
            for (k = 0; k < (int)FOC_N_TELEMETRY; k++) {
                printf(" %d", o.telemetry[k]);
            }
            printf("\n");
        } else if (sscanf(line, "R %ld", &value) == 1) {
            foc_set_speed_ref_rpm(&fw, (int32_t)value);
        } else if (sscanf(line, "G %7s %15s %ld", loop, field, &value) == 3) {
            foc_pi_t *p = loop_of(&fw, loop);
            if (strcmp(field, "kp") == 0) {
                p->kp = (int32_t)value;
            } else if (strcmp(field, "ki") == 0) {
                p->ki = (int32_t)value;
            } else if (strcmp(field, "kc") == 0) {
                p->kc = (int32_t)value;
            } else {
                p->out_max = (int32_t)value;
                p->out_min = (int32_t)-value;
            }
        } else if (strncmp(line, "START", 5) == 0) {
            foc_start(&fw);
        } else if (strncmp(line, "STOP", 4) == 0) {
            foc_stop(&fw, FOC_STATE_STOPPED, FOC_FAULT_NONE);
        } else if (strncmp(line, "TRIP", 4) == 0) {
            foc_stop(&fw, FOC_STATE_FAULT, FOC_FAULT_WATCHDOG);
        } else {
            fprintf(stderr, "foc_stream: bad line: %s", line);
            return 2;
        }
    }
    return 0;
}
