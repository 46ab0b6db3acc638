/* What both FMU cores (servo_core.c, sampled_core.c) share: the copy of the instance name, the log and the checks of
 * a communication step. Included by each core's translation unit, after its header has defined SvInstance. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

char *sv_strdup(const char *text) {
    size_t n = strlen(text) + 1;
    char *copy = (char *)malloc(n);
    if (copy) memcpy(copy, text, n);
    return copy;
}

void sv_logf(SvInstance *inst, int level, const char *category, const char *fmt, ...) {
    char buf[512];
    va_list ap;
    if (!inst->log || (level == SV_LOG_OK && !inst->logging_on)) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    inst->log(inst, level, category, buf);
}

/* A doStep call fits the instance: Co-Simulation in step mode, a positive step from the instance's own time.
 * 0 ok, -1 refused (logged). */
static int check_step(SvInstance *inst, double communication_point, double step_size) {
    if (!inst->is_cosim || inst->s.mode != SV_STEP) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "do step: not in step mode of a Co-Simulation instance");
        return -1;
    }
    if (!(step_size > 0.0)) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "do step: step size %g is not positive", step_size);
        return -1;
    }
    if (fabs(communication_point - inst->s.time) > 1e-9 * fmax(1.0, fabs(inst->s.time))) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError",
                "do step: communication point %.17g differs from the FMU's time %.17g", communication_point,
                inst->s.time);
        return -1;
    }
    return 0;
}
