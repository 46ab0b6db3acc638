/* servofmu sampled component: a discrete-time Co-Simulation FMU (a drive's controller, a reference source) behind
 * the same FMI wrappers as the plant (fmi2_api.c, fmi3_api.c), through the same interface as servo_core.h
 * (SvInstance, sv_*).  It has no continuous states: the Model Exchange functions exist but are never offered.
 *
 * A component provides, in component.h, its state type ScState and the hooks below; model_config.h (generated)
 * gives the instantiation token, the numbers of inputs, outputs and parameters, the parameter start values and
 * the value references: SV_VR_TIME, SV_VR_IN0 (inputs), SV_VR_OUT0 (outputs), SV_VR_P0 (parameters). */
#ifndef SAMPLED_CORE_H
#define SAMPLED_CORE_H

#include <stddef.h>
#include "model_config.h"

#define SV_NX 0 /* no continuous states */

typedef struct SvInstance SvInstance;
#include "component.h" /* ScState, the component's own state */


/* Everything that defines where the component is: what an FMU state saves. */
typedef struct {
    unsigned magic;
    double time, start_time;
    double x[1];                /* no continuous states (the wrappers' Model Exchange functions copy none) */
    double p[SV_NP + 1], in[SC_NIN + 1], out[SC_NOUT + 1]; /* + 1: a component may have none */
    double rtol, atol;
    int mode;
    ScState c;
} SvState;

typedef void (*sv_logger)(SvInstance *inst, int level, const char *category, const char *message);

struct SvInstance {
    SvState s;
    int is_cosim, logging_on, dirty;
    double xdot[1];
    char *name;
    sv_logger log;
};

extern const double sv_x_nominal[1];

#include "core_api.h"

/* ---- What a component provides ---- */
/* The reason a parameter value is refused, or NULL when it is acceptable (called on every set). */
const char *sc_parameter_error(int index, double value);
/* The reason the parameters together are refused, or NULL (called when initialisation ends). */
const char *sc_parameters_error(const double *p);
/* Start: the state and outputs at s.start_time, from the parameters and the inputs set so far. */
void sc_start(SvInstance *inst);
/* Advance from t0 to t1: run what falls in [t0, t1), leave the outputs valid at t1.  0 ok, -1 failure (logged). */
int sc_step(SvInstance *inst, double t0, double t1);

#endif
