/* The interface of an FMU core, written against by the FMI wrappers (fmi2_api.c, fmi3_api.c): servo_core.h (a
 * plant) and sampled_core.h (a sampled component) each define SvInstance and SvState, then include this. */
#ifndef CORE_API_H
#define CORE_API_H

#include <stddef.h>

enum sv_mode { SV_INSTANTIATED, SV_INITIALIZATION, SV_EVENT, SV_CONTINUOUS, SV_STEP, SV_TERMINATED, SV_ERROR };
enum sv_level { SV_LOG_OK = 0, SV_LOG_WARNING = 1, SV_LOG_ERROR = 3 };

void sv_reset(SvInstance *inst);
char *sv_strdup(const char *text);
void sv_logf(SvInstance *inst, int level, const char *category, const char *fmt, ...);
/* Variables by value reference, failures logged: 0 ok, < 0 refused. */
int sv_set_checked(SvInstance *inst, unsigned vr, double value);
int sv_get_checked(SvInstance *inst, unsigned vr, double *value);
void sv_eval(SvInstance *inst);
/* sensitivity = d unknowns / d knowns · seed (adjoint=0) or seedᵀ · d unknowns / d knowns (adjoint=1). */
int sv_derivative(SvInstance *inst, const unsigned *unknowns, size_t n_unknowns, const unsigned *knowns,
                  size_t n_knowns, const double *seed, double *sensitivity, int adjoint);
/* The rules between parameters (the single-parameter ones are checked when a value is set); 0 ok, -1 (logged). */
int sv_check_parameters(SvInstance *inst);
/* Life cycle shared by the FMI versions; 0 ok, -1 error (logged). */
int sv_enter_initialization(SvInstance *inst, int tolerance_defined, double tolerance, double start_time);
int sv_exit_initialization(SvInstance *inst);
int sv_do_step(SvInstance *inst, double communication_point, double step_size);
/* FMU state: get allocates when *state is NULL; 0 ok, -1 error (logged). */
int sv_state_get(SvInstance *inst, void **state);
int sv_state_set(SvInstance *inst, const void *state);
int sv_state_serialize(SvInstance *inst, const void *state, unsigned char *bytes, size_t size);
int sv_state_deserialize(SvInstance *inst, const unsigned char *bytes, size_t size, void **state);
#define SV_STATE_SIZE sizeof(SvState)

#endif
