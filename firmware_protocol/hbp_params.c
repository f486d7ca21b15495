/* hbp_params.c: a parameter table for a target on the bare protocol library (the loopback example);
 * a firmware on the runtime uses the runtime's (firmware/runtime/hrt.h). See hbp.h. C99, no heap. */
#include "hbp.h"

int32_t hbp_param_candidate(const hbp_params_t *params, const hbp_param_set_t *request, hbp_u8 id)
{
    hbp_u8 i;
    int32_t value = params->values[id];
    for (i = 0u; i < request->n_pairs; i++) {
        if (request->pairs[i].id == id) {
            value = request->pairs[i].value;
        }
    }
    return value;
}

hbp_u8 hbp_param_describe(const hbp_params_t *params, hbp_u8 id, hbp_u8 seq, hbp_param_info_t *out)
{
    const hbp_param_def_t *def;
    hbp_u8 i;
    out->seq = seq;
    if (id >= params->count) {
        return HBP_RESULT_UNKNOWN_ID;
    }
    def = &params->defs[id];
    out->param_id = id;
    out->ptype = def->ptype;
    out->access = def->access;
    out->min_value = def->min_value;
    out->max_value = def->max_value;
    out->value = params->values[id];
    for (i = 0u; i < HBP_MAX_NAME && def->name[i] != '\0'; i++) {
        out->name[i] = def->name[i];
    }
    out->name[i] = '\0';
    return HBP_RESULT_OK;
}

void hbp_param_get(const hbp_params_t *params, hbp_u8 id, hbp_u8 seq, hbp_param_value_t *out)
{
    out->seq = seq;
    out->param_id = id;
    if (id >= params->count) {
        out->result = HBP_RESULT_UNKNOWN_ID;
        out->value = 0;
        return;
    }
    out->result = HBP_RESULT_OK;
    out->value = params->values[id];
}

void hbp_param_set(hbp_params_t *params, const hbp_param_set_t *request, hbp_u8 seq,
                   hbp_param_set_result_t *out)
{
    hbp_u8 i;
    hbp_u8 j;
    out->seq = seq;
    out->param_id = 0u;
    out->detail = 0u;
    if (request->n_pairs == 0u || request->n_pairs > HBP_MAX_PARAM_PAIRS) {
        out->result = HBP_RESULT_BAD_REQUEST;
        return;
    }
    for (i = 0u; i < request->n_pairs; i++) {
        hbp_u8 id = request->pairs[i].id;
        int32_t value = request->pairs[i].value;
        out->param_id = id;
        if (id >= params->count) {
            out->result = HBP_RESULT_UNKNOWN_ID;
            return;
        }
        if (params->defs[id].access != HBP_ACCESS_RW) {
            out->result = HBP_RESULT_READ_ONLY;
            return;
        }
        if (value < params->defs[id].min_value || value > params->defs[id].max_value) {
            out->result = HBP_RESULT_OUT_OF_RANGE;
            return;
        }
        for (j = 0u; j < i; j++) {
            if (request->pairs[j].id == id) {
                out->result = HBP_RESULT_BAD_REQUEST; /* the same id twice */
                return;
            }
        }
    }
    if (params->check != 0) {
        hbp_u8 bad_id = 0u;
        hbp_u8 detail = 0u;
        hbp_u8 result = params->check(params, request, &bad_id, &detail);
        if (result != HBP_RESULT_OK) {
            out->result = result;
            out->param_id = bad_id;
            out->detail = detail;
            return;
        }
    }
    for (i = 0u; i < request->n_pairs; i++) {
        params->values[request->pairs[i].id] = request->pairs[i].value;
    }
    out->result = HBP_RESULT_OK;
    out->param_id = 0u;
}
