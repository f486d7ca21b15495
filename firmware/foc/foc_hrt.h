/* foc_hrt.h: the FOC firmware on the hilbench runtime (see foc_hrt.c). The runtime's shared ports
 * call hrt_firmware_init() (one static foc_app_t with the build's settings); a port of its own keeps
 * its foc_app_t, calls foc_app_init, and serves the wire with hrt_link (firmware/runtime/hrt_link.h). */
#ifndef FOC_HRT_H
#define FOC_HRT_H

#include "foc.h"
#include "hrt.h"

/* declared parameter ids */
#define FOC_PARAM_REF_RPM 0u
#define FOC_PARAM_ID_REF 1u
#define FOC_PARAM_SPD_KP 2u
#define FOC_PARAM_SPD_OUT_MAX 5u
#define FOC_PARAM_ID_OUT_MAX 9u
#define FOC_PARAM_IQ_OUT_MAX 13u
#define FOC_PARAM_TORQUE_MODE 14u
#define FOC_PARAM_IQ_REF_SET 15u
#define FOC_N_PARAMS 16u

typedef struct {
    hrt_t rt;         /* the runtime's state: first, so a body finds the firmware from rt */
    foc_t foc;        /* the firmware */
    int32_t ref_rpm;  /* the speed reference parameter as written */
} foc_app_t;

void foc_app_init(foc_app_t *app, const foc_config_t *config);

#endif /* FOC_HRT_H */
