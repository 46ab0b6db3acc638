/* servofmu sampled component core; see sampled_core.h. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sampled_core.h"

#define SV_MAGIC 0x53564331u /* "SVC1" */

static const double p_start[SV_NP + 1] = SV_P_START;
const double sv_x_nominal[1] = {1.0};

#include "core_common.c"

void sv_reset(SvInstance *inst) {
    memset(&inst->s, 0, sizeof inst->s);
    inst->s.magic = SV_MAGIC;
    memcpy(inst->s.p, p_start, sizeof inst->s.p);
    inst->s.rtol = inst->s.atol = 1e-10;
    inst->s.mode = SV_INSTANTIATED;
}

/* Value references: time, inputs, outputs, parameters (model_config.h). */
static double *variable(SvInstance *inst, unsigned vr, int *kind, int *index) {
    if (vr == SV_VR_TIME) { *kind = 0; return &inst->s.time; }
    if (vr >= SV_VR_IN0 && vr < SV_VR_IN0 + SC_NIN) { *kind = 1; return &inst->s.in[vr - SV_VR_IN0]; }
    if (vr >= SV_VR_OUT0 && vr < SV_VR_OUT0 + SC_NOUT) { *kind = 2; return &inst->s.out[vr - SV_VR_OUT0]; }
    if (vr >= SV_VR_P0 && vr < SV_VR_P0 + SV_NP) { *kind = 3; *index = (int)(vr - SV_VR_P0); return &inst->s.p[*index]; }
    return NULL;
}

int sv_get_checked(SvInstance *inst, unsigned vr, double *value) {
    int kind, index;
    double *v = variable(inst, vr, &kind, &index);
    if (!v) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "unknown value reference %u", vr);
        return -1;
    }
    *value = *v;
    return 0;
}

int sv_set_checked(SvInstance *inst, unsigned vr, double value) {
    int kind, index = -1;
    double *v = variable(inst, vr, &kind, &index);
    const char *why;
    if (!v || kind == 0 || kind == 2) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", v ? "variable %u cannot be set" : "unknown value reference %u", vr);
        return -1;
    }
    if (!isfinite(value)) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "variable %u: value is not finite", vr);
        return -3;
    }
    if (kind == 3) {
        if (inst->s.mode != SV_INSTANTIATED && inst->s.mode != SV_INITIALIZATION) {
            sv_logf(inst, SV_LOG_ERROR, "logStatusError", "parameter %u is fixed after initialisation", vr);
            return -2;
        }
        if ((why = sc_parameter_error(index, value)) != NULL) {
            sv_logf(inst, SV_LOG_ERROR, "logStatusError", "parameter %u = %g refused: %s", vr, value, why);
            return -4;
        }
    }
    *v = value;
    return 0;
}

void sv_eval(SvInstance *inst) { (void)inst; }

int sv_check_parameters(SvInstance *inst) { (void)inst; return 0; /* checked as they are set and at start */ }

int sv_derivative(SvInstance *inst, const unsigned *unknowns, size_t n_unknowns, const unsigned *knowns,
                  size_t n_knowns, const double *seed, double *sensitivity, int adjoint) {
    (void)unknowns; (void)n_unknowns; (void)knowns; (void)n_knowns; (void)seed; (void)sensitivity; (void)adjoint;
    sv_logf(inst, SV_LOG_ERROR, "logStatusError", "a sampled component provides no derivatives");
    return -1;
}

int sv_enter_initialization(SvInstance *inst, int tolerance_defined, double tolerance, double start_time) {
    (void)tolerance_defined; (void)tolerance;
    if (inst->s.mode != SV_INSTANTIATED) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "initialization mode can only be entered after instantiation");
        return -1;
    }
    inst->s.time = inst->s.start_time = start_time;
    inst->s.mode = SV_INITIALIZATION;
    return 0;
}

int sv_exit_initialization(SvInstance *inst) {
    const char *why;
    if (inst->s.mode != SV_INITIALIZATION) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "exit initialization mode: not in initialization mode");
        return -1;
    }
    if (!inst->is_cosim) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "a sampled component runs in Co-Simulation only");
        return -1;
    }
    if ((why = sc_parameters_error(inst->s.p)) != NULL) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "parameters refused: %s", why);
        inst->s.mode = SV_ERROR;
        return -1;
    }
    sc_start(inst);
    inst->s.mode = SV_STEP;
    return 0;
}

int sv_do_step(SvInstance *inst, double communication_point, double step_size) {
    if (check_step(inst, communication_point, step_size) != 0) return -1;
    if (sc_step(inst, communication_point, communication_point + step_size) != 0) return -1;
    inst->s.time = communication_point + step_size;
    return 0;
}

/* ---- FMU state: a copy of SvState ---- */
int sv_state_get(SvInstance *inst, void **state) {
    if (!*state) *state = malloc(sizeof(SvState));
    if (!*state) { sv_logf(inst, SV_LOG_ERROR, "logStatusError", "out of memory"); return -1; }
    memcpy(*state, &inst->s, sizeof(SvState));
    return 0;
}

int sv_state_set(SvInstance *inst, const void *state) {
    if (!state) { sv_logf(inst, SV_LOG_ERROR, "logStatusError", "no FMU state given"); return -1; }
    memcpy(&inst->s, state, sizeof(SvState));
    return 0;
}

int sv_state_serialize(SvInstance *inst, const void *state, unsigned char *bytes, size_t size) {
    if (!state || size < sizeof(SvState)) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "serialize FMU state: buffer too small");
        return -1;
    }
    memcpy(bytes, state, sizeof(SvState));
    return 0;
}

int sv_state_deserialize(SvInstance *inst, const unsigned char *bytes, size_t size, void **state) {
    SvState probe;
    if (size == sizeof(SvState)) memcpy(&probe, bytes, sizeof probe);
    if (size != sizeof(SvState) || probe.magic != SV_MAGIC) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "deserialize FMU state: not a state of this FMU");
        return -1;
    }
    if (!*state) *state = malloc(sizeof(SvState));
    if (!*state) { sv_logf(inst, SV_LOG_ERROR, "logStatusError", "out of memory"); return -1; }
    memcpy(*state, &probe, sizeof probe);
    return 0;
}
