/* A signal source as a sampled FMU component (sampled_core.h): one output, the table of source_table.h (SRC_N
 * points, times src_t increasing) interpolated linearly, held before the first and after the last point.
 *
 * The output at a communication point on the sample grid t_k = start + k*SRC_TS is the table at the time computed
 * from the step index k (start + (k + SRC_LEAD)*SRC_TS), not at the communication time the engine passes: engines
 * accumulate that time differently (libcosim in integer nanoseconds, FMPy by adding steps), and a table evaluated
 * at either would differ by rounding, which an encoder's quantiser downstream can turn into a whole quantum.
 * Off the grid (an engine stepping with another step than the sample time) the table is evaluated at the time
 * itself.  SRC_LEAD = 1 for a source whose value a sampled component passes on one exchange later (a disturbance
 * injected by the controller): its output at t_k is the value for t_k+1, and 0 at the start. */
#include <math.h>

#include "sampled_core.h"
#include "source_table.h"

static double at(double t) {
    long lo = 0, hi = SRC_N - 1;
    if (t <= src_t[0]) return src_x[0];
    if (t >= src_t[SRC_N - 1]) return src_x[SRC_N - 1];
    while (hi - lo > 1) {
        long mid = (lo + hi) / 2;
        if (src_t[mid] <= t) lo = mid; else hi = mid;
    }
    return src_x[lo] + (src_x[hi] - src_x[lo]) * (t - src_t[lo]) / (src_t[hi] - src_t[lo]);
}

/* The output at the communication point t. */
static double value(const SvInstance *inst, double t) {
    double start = inst->s.start_time, k = floor((t - start) / SRC_TS + 0.5);
    if (fabs(t - (start + k * SRC_TS)) > 1e-6 * SRC_TS) return at(t + SRC_LEAD * SRC_TS);
    return at(start + (k + SRC_LEAD) * SRC_TS);
}

const char *sc_parameter_error(int i, double v) { (void)i; (void)v; return NULL; }
const char *sc_parameters_error(const double *p) { (void)p; return NULL; }
/* A leading source starts at 0, as every engine starts a connection: an engine that passes start values on then
 * agrees with one that does not. */
void sc_start(SvInstance *inst) { inst->s.out[0] = SRC_LEAD ? 0.0 : value(inst, inst->s.start_time); }

int sc_step(SvInstance *inst, double t0, double t1) {
    (void)t0;
    inst->s.out[0] = value(inst, t1);
    return 0;
}
