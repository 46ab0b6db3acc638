/* A reference trajectory as a sampled FMU component (sampled_core.h): output position_reference, the table of
 * reference_table.h (REF_N points, times ref_t increasing) interpolated linearly, held before the first and after
 * the last point. */
#include "sampled_core.h"
#include "reference_table.h"

static double at(double t) {
    long lo = 0, hi = REF_N - 1;
    if (t <= ref_t[0]) return ref_x[0];
    if (t >= ref_t[REF_N - 1]) return ref_x[REF_N - 1];
    while (hi - lo > 1) {
        long mid = (lo + hi) / 2;
        if (ref_t[mid] <= t) lo = mid; else hi = mid;
    }
    return ref_x[lo] + (ref_x[hi] - ref_x[lo]) * (t - ref_t[lo]) / (ref_t[hi] - ref_t[lo]);
}

const char *sc_parameter_error(int i, double v) { (void)i; (void)v; return NULL; }
const char *sc_parameters_error(const double *p) { (void)p; return NULL; }
void sc_start(SvInstance *inst) { inst->s.out[0] = at(inst->s.start_time); }

int sc_step(SvInstance *inst, double t0, double t1) {
    (void)t0;
    inst->s.out[0] = at(t1);
    return 0;
}
