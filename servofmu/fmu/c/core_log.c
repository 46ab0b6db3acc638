/* What both FMU cores (servo_core.c, sampled_core.c) share: the copy of the instance name and the log. Included by
 * each core's translation unit, after its header has defined SvInstance. */
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
