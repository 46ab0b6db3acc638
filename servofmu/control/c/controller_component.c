/* The drive's controller as a sampled FMU component (sampled_core.h): inputs position_reference, position and
 * force_disturbance (a known force injected after the output limit), outputs force (applied: the delayed command
 * plus actuator noise plus the disturbance), force_command (as logged: the delayed command plus the disturbance),
 * position_measured (the encoder reading) and velocity_reference of the last sample; the law is
 * controller_law.h. */
#include "sampled_core.h"

static const double low[CP_COUNT] = CP_LOW, high[CP_COUNT] = CP_HIGH;
static const int low_open[CP_COUNT] = CP_LOW_OPEN, integer[CP_COUNT] = CP_INTEGER;

const char *sc_parameter_error(int i, double v) {
    if (v < low[i] || (low_open[i] && v == low[i])) return "below its range (servofmu.control.controller)";
    if (v > high[i]) return "above its range (servofmu.control.controller)";
    if (integer[i] && v != floor(v)) return "not a whole number";
    return NULL;
}

const char *sc_parameters_error(const double *p) {
    if (p[CP_FF_FS_POS] < p[CP_FF_FC_POS] && p[CP_FRICTION_FEEDFORWARD] > 0.0)
        return "feed-forward static friction ff_fs_pos below Coulomb friction ff_fc_pos";
    if (p[CP_FF_FS_NEG] < p[CP_FF_FC_NEG] && p[CP_FRICTION_FEEDFORWARD] > 0.0)
        return "feed-forward static friction ff_fs_neg below Coulomb friction ff_fc_neg";
    return NULL;
}

/* The disturbance input as set at the step's start is applied from the step's end on (the exchange's delay: a
 * source that leads by one sample makes up for it, servofmu.control.fmus.build_disturbance_fmu). */
static void outputs(SvInstance *inst) {
    CtrlState *law = &inst->s.c.law;
    ctrl_inject(law, inst->s.in[2]);
    inst->s.out[0] = law->total_applied;
    inst->s.out[1] = law->total_command;
    inst->s.out[2] = law->last_y;
    inst->s.out[3] = law->last_v_ref;
}

void sc_start(SvInstance *inst) {
    ctrl_reset(&inst->s.c.law, inst->s.p);
    inst->s.c.next = 0;
    outputs(inst);
    inst->s.out[2] = ctrl_encoder(inst->s.p, inst->s.in[1]);
}

/* Every sample in [t0, t1), with the inputs as set at t0 (co-simulate with the sample time as step). */
int sc_step(SvInstance *inst, double t0, double t1) {
    const double ts = inst->s.p[CP_SAMPLE_TIME], slack = 1e-6 * ts;
    for (;;) {
        double tk = inst->s.start_time + (double)inst->s.c.next * ts;
        if (tk >= t1 - slack) break;
        if (tk < t0 - slack) {
            sv_logf(inst, SV_LOG_ERROR, "logStatusError", "do step: sample at %.17g lies before the step's start "
                    "%.17g", tk, t0);
            return -1;
        }
        ctrl_sample(&inst->s.c.law, inst->s.p, inst->s.in[0], inst->s.in[1]);
        inst->s.c.next++;
    }
    outputs(inst);
    return 0;
}
