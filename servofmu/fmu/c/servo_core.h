/* servofmu FMU core: the plant's variables, its stiff integrator and its state,
 * independent of the FMI version.  The equations come from the CasADi-generated
 * model_eqs.c; the sizes, names and start values from the generated
 * model_config.h. */
#ifndef SERVO_CORE_H
#define SERVO_CORE_H

#include <stddef.h>
#include "model_config.h"

/* Value references: one fixed layout for FMI 2.0 and 3.0 (docs/fmu.md), generated into model_config.h from
 * servofmu/fmu/variables.py: SV_VR_TIME, SV_VR_U, SV_VR_Y0 (v, position, friction_force), SV_VR_P0 (parameters),
 * SV_VR_X0 (continuous states; the position state is the output `position`), SV_VR_DX0 (their derivatives). */

enum sv_kind { SV_UNKNOWN, SV_TIME, SV_INPUT, SV_OUTPUT, SV_PARAM, SV_STATE, SV_DERIV };

/* Everything that defines where the model is: what an FMU state saves. */
typedef struct {
    unsigned magic;
    double time;
    double x[SV_NX];
    double p[SV_NP];
    double u;
    double h;       /* last step size of the Co-Simulation integrator */
    double rtol, atol;
    int mode;
} SvState;

typedef struct SvInstance SvInstance;
typedef void (*sv_logger)(SvInstance *inst, int level, const char *category, const char *message);

struct SvInstance {
    SvState s;
    int is_cosim;
    int logging_on;
    long steps, rejected;               /* integrator statistics */
    double xdot[SV_NX], y[SV_NY];       /* cache, valid while !dirty */
    int dirty;
    char *name;
    sv_logger log;
    void *fmi_env;                      /* the importer's environment/callbacks */
    void *fmi_logger;
    /* CasADi work memory */
    const double *arg[SV_SZ_ARG];
    double *res[SV_SZ_RES];
    long long iw[SV_SZ_IW + 1];
    double w[SV_SZ_W + 1];
};

extern const double sv_p_start[SV_NP];   /* parameter start values */
extern const double sv_x_nominal[SV_NX]; /* state nominal values */

#include "core_api.h"

enum sv_kind sv_classify(unsigned vr, int *index);
/* 0 ok; -1 unknown reference; -2 not settable in this mode; -3 not finite; -4 outside the plant file's rules */
int sv_get(SvInstance *inst, unsigned vr, double *value);
int sv_set(SvInstance *inst, unsigned vr, double value);
/* Integrate from s.time to t_end with the adaptive RODAS4 method; 0 ok, -1 failure (logged). */
int sv_integrate(SvInstance *inst, double t_end);

#endif
