/* servofmu FMU core; see servo_core.h. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "servo_core.h"
#include "model_eqs.h"

#define SV_MAGIC 0x53564d31u /* "SVM1" */

const double sv_p_start[SV_NP] = SV_P_START;
/* The plant file's value rules (generated from servofmu.model.plant.parameter_rules, see model_config.h). */
static const double p_low[SV_NP] = SV_P_LOW, p_high[SV_NP] = SV_P_HIGH;
static const int p_low_open[SV_NP] = SV_P_LOW_OPEN, p_nonzero[SV_NP] = SV_P_NONZERO;
static const int p_at_least[][2] = SV_P_AT_LEAST, p_roots_not_zero[][2] = SV_P_ROOTS_NOT_ZERO;
const double sv_x_nominal[SV_NX] = SV_X_NOMINAL;

#include "core_common.c"

void sv_reset(SvInstance *inst) {
    memset(&inst->s, 0, sizeof inst->s);
    inst->s.magic = SV_MAGIC;
    memcpy(inst->s.p, sv_p_start, sizeof inst->s.p);
    inst->s.rtol = SV_DEFAULT_RTOL;
    inst->s.atol = SV_DEFAULT_RTOL;
    inst->s.h = 0.0;
    inst->s.mode = SV_INSTANTIATED;
    inst->steps = inst->rejected = 0;
    inst->dirty = 1;
}

enum sv_kind sv_classify(unsigned vr, int *index) {
    *index = 0;
    if (vr == SV_VR_TIME) return SV_TIME;
    if (vr == SV_VR_U) return SV_INPUT;
    if (vr >= SV_VR_Y0 && vr < SV_VR_Y0 + SV_NY && vr != SV_VR_Y0 + 1) {
        *index = (int)(vr - SV_VR_Y0);
        return SV_OUTPUT;
    }
    if (vr >= SV_VR_P0 && vr < SV_VR_P0 + SV_NP) { *index = (int)(vr - SV_VR_P0); return SV_PARAM; }
    /* The position state is the output `position` (VR SV_VR_Y0 + 1), not a variable of its own. */
    if (vr == SV_VR_Y0 + 1) { *index = SV_POSITION; return SV_STATE; }
    if (vr >= SV_VR_X0 && vr < SV_VR_X0 + SV_NX && vr != SV_VR_X0 + SV_POSITION) {
        *index = (int)(vr - SV_VR_X0);
        return SV_STATE;
    }
    if (vr >= SV_VR_DX0 && vr < SV_VR_DX0 + SV_NX) { *index = (int)(vr - SV_VR_DX0); return SV_DERIV; }
    return SV_UNKNOWN;
}

/* ---- model evaluation ---------------------------------------------------- */
static void call4(SvInstance *inst, int (*fn)(const double **, double **, long long *, double *, int), double t,
                  const double *x, double *out0, double *out1) {
    inst->arg[0] = &t;
    inst->arg[1] = x;
    inst->arg[2] = &inst->s.u;
    inst->arg[3] = inst->s.p;
    inst->res[0] = out0;
    if (out1) inst->res[1] = out1;
    fn(inst->arg, inst->res, inst->iw, inst->w, 0);
}

static void rhs(SvInstance *inst, double t, const double *x, double *xdot) {
    call4(inst, servo_ode, t, x, xdot, NULL);
}

void sv_eval(SvInstance *inst) {
    if (!inst->dirty) return;
    call4(inst, servo_ode, inst->s.time, inst->s.x, inst->xdot, NULL);
    call4(inst, servo_outputs, inst->s.time, inst->s.x, inst->y, NULL);
    inst->dirty = 0;
}

/* ---- variable access --------------------------------------------------------- */
int sv_get(SvInstance *inst, unsigned vr, double *value) {
    int i;
    switch (sv_classify(vr, &i)) {
    case SV_TIME: *value = inst->s.time; return 0;
    case SV_INPUT: *value = inst->s.u; return 0;
    case SV_PARAM: *value = inst->s.p[i]; return 0;
    case SV_STATE: *value = inst->s.x[i]; return 0;
    case SV_OUTPUT: sv_eval(inst); *value = inst->y[i]; return 0;
    case SV_DERIV: sv_eval(inst); *value = inst->xdot[i]; return 0;
    default: return -1;
    }
}

int sv_set(SvInstance *inst, unsigned vr, double value) {
    int i;
    enum sv_kind kind = sv_classify(vr, &i);
    int before_init = inst->s.mode == SV_INSTANTIATED || inst->s.mode == SV_INITIALIZATION;
    if (kind == SV_UNKNOWN) return -1;
    if (!isfinite(value)) return -3;
    switch (kind) {
    case SV_INPUT: inst->s.u = value; break;
    case SV_PARAM:
        if (inst->s.mode == SV_TERMINATED) return -2;
        if (value < p_low[i] || (p_low_open[i] && value == p_low[i]) || value > p_high[i] ||
            (p_nonzero[i] && value == 0.0))
            return -4;
        inst->s.p[i] = value;
        break;
    case SV_STATE: /* start values of the states, before initialisation only */
        if (!before_init) return -2;
        inst->s.x[i] = value;
        break;
    default: return -2;
    }
    inst->dirty = 1;
    return 0;
}

int sv_set_checked(SvInstance *inst, unsigned vr, double value) {
    int rc = sv_set(inst, vr, value);
    if (rc == -1) sv_logf(inst, SV_LOG_ERROR, "logStatusError", "unknown value reference %u", vr);
    if (rc == -2) sv_logf(inst, SV_LOG_ERROR, "logStatusError", "variable %u cannot be set in this mode", vr);
    if (rc == -3) sv_logf(inst, SV_LOG_ERROR, "logStatusError", "variable %u: value is not finite", vr);
    if (rc == -4)
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "parameter %u = %g refused: outside what the plant file "
                "allows (docs/plant-format.md)", vr, value);
    return rc;
}

int sv_get_checked(SvInstance *inst, unsigned vr, double *value) {
    int rc = sv_get(inst, vr, value);
    if (rc == -1) sv_logf(inst, SV_LOG_ERROR, "logStatusError", "unknown value reference %u", vr);
    return rc;
}

/* ---- dense LU with partial pivoting (n is tiny) -------------------------------- */
static int lu_factor(double *a, int *piv, int n) {
    int i, j, k;
    for (k = 0; k < n; ++k) {
        int p = k;
        double big = fabs(a[k * n + k]);
        for (i = k + 1; i < n; ++i)
            if (fabs(a[i * n + k]) > big) { big = fabs(a[i * n + k]); p = i; }
        if (big == 0.0 || !isfinite(big)) return -1;
        piv[k] = p;
        if (p != k)
            for (j = 0; j < n; ++j) { double t = a[k * n + j]; a[k * n + j] = a[p * n + j]; a[p * n + j] = t; }
        for (i = k + 1; i < n; ++i) {
            double f = a[i * n + k] /= a[k * n + k];
            for (j = k + 1; j < n; ++j) a[i * n + j] -= f * a[k * n + j];
        }
    }
    return 0;
}

static void lu_solve(const double *a, const int *piv, double *b, int n) {
    int i, j;
    for (i = 0; i < n; ++i) {
        if (piv[i] != i) { double t = b[i]; b[i] = b[piv[i]]; b[piv[i]] = t; }
        for (j = 0; j < i; ++j) b[i] -= a[i * n + j] * b[j];
    }
    for (i = n - 1; i >= 0; --i) {
        for (j = i + 1; j < n; ++j) b[i] -= a[i * n + j] * b[j];
        b[i] /= a[i * n + i];
    }
}

/* ---- RODAS4 (Hairer & Wanner, stiffly accurate Rosenbrock, order 4(3)) -------- */
static const double R_GAMMA = 0.25;
static const double R_C[6] = {0.0, 0.386, 0.21, 0.63, 1.0, 1.0};
static const double R_D[6] = {0.25, -0.1043, 0.1035, -0.3620000000000023e-01, 0.0, 0.0};
static const double R_A[6][5] = {
    {0},
    {0.1544e+01},
    {0.9466785280815826e+00, 0.2557011698983284e+00},
    {0.3314825187068521e+01, 0.2896124015972201e+01, 0.9986419139977817e+00},
    {0.1221224509226641e+01, 0.6019134481288629e+01, 0.1253708332932087e+02, -0.6878860361058950e+00},
    {0.1221224509226641e+01, 0.6019134481288629e+01, 0.1253708332932087e+02, -0.6878860361058950e+00, 1.0},
};
static const double R_CC[6][5] = {
    {0},
    {-0.56688e+01},
    {-0.2430093356833875e+01, -0.2063599157091915e+00},
    {-0.1073529058151375e+00, -0.9594562251023355e+01, -0.2047028614809616e+02},
    {0.7496443313967647e+01, -0.1024680431464352e+02, -0.3399990352819905e+02, 0.1170890893206160e+02},
    {0.8083246795921522e+01, -0.7981132988064893e+01, -0.3152159432874371e+02, 0.1631930543123136e+02,
     -0.6058818238834054e+01},
};

/* The state at RODAS4 stage s, x + sum over j < s of a_sj * k_j (k: the stages so far, rows of `stride`
 * numbers): one definition for this integrator and the batch simulator's, which includes this file. */
static void rodas_stage_state(const double *x, const double *k, int stride, int s, int n, double *xs) {
    int i, j;
    for (i = 0; i < n; ++i) {
        double acc = x[i];
        for (j = 0; j < s; ++j) acc += R_A[s][j] * k[j * stride + i];
        xs[i] = acc;
    }
}

/* One step of size h from (t, x); writes the new state and returns the scaled error norm. */
static double rodas_step(SvInstance *inst, double t, const double *x, double h, double *xnew) {
    enum { N = SV_NX };
    double jac[N * N], ft[N], m[N * N], k[6][N], xs[N], f[N];
    int piv[N], i, j, s;
    double err = 0.0;
    call4(inst, servo_ode_jacobian, t, x, jac, ft);
    /* CasADi stores dense matrices column-major: transpose into row-major while building M. */
    for (i = 0; i < N; ++i)
        for (j = 0; j < N; ++j) m[i * N + j] = -jac[j * N + i] + (i == j ? 1.0 / (h * R_GAMMA) : 0.0);
    if (lu_factor(m, piv, N) != 0) return INFINITY;
    for (s = 0; s < 6; ++s) {
        rodas_stage_state(x, &k[0][0], N, s, N, xs);
        rhs(inst, t + R_C[s] * h, xs, f);
        for (i = 0; i < N; ++i) {
            double acc = f[i] + h * R_D[s] * ft[i];
            for (j = 0; j < s; ++j) acc += R_CC[s][j] / h * k[j][i];
            k[s][i] = acc;
        }
        lu_solve(m, piv, k[s], N);
    }
    for (i = 0; i < N; ++i) {
        double sc;
        xnew[i] = xs[i] + k[5][i];
        sc = inst->s.atol * sv_x_nominal[i] + inst->s.rtol * fmax(fabs(x[i]), fabs(xnew[i]));
        err += (k[5][i] / sc) * (k[5][i] / sc);
        if (!isfinite(xnew[i])) return INFINITY;
    }
    return sqrt(err / N);
}

int sv_integrate(SvInstance *inst, double t_end) {
    double t = inst->s.time, xnew[SV_NX];
    double h = inst->s.h > 0.0 ? inst->s.h : 1e-5;
    const double span = fmax(fabs(t_end), 1.0);
    long budget = 2000000L; /* steps per call: a bounded time (seconds), however absurd the input */
    while (t < t_end) {
        double err, fac;
        int last = 0;
        if (h >= t_end - t || t_end - t - h < 1e-12 * span) { h = t_end - t; last = 1; }
        err = rodas_step(inst, t, inst->s.x, h, xnew);
        if (err <= 1.0) {
            t = last ? t_end : t + h;
            memcpy(inst->s.x, xnew, sizeof xnew);
            inst->steps++;
            fac = err > 0.0 ? 0.9 * pow(err, -0.25) : 5.0;
            fac = fmin(5.0, fmax(0.2, fac));
            /* a clipped last step says little about the step size: keep the previous one unless it shrinks */
            if (!last || fac < 1.0 || inst->s.h <= 0.0) inst->s.h = h * fac;
            h = inst->s.h;
        } else {
            inst->rejected++;
            fac = isfinite(err) ? fmax(0.2, 0.9 * pow(err, -0.25)) : 0.1;
            h *= fac;
        }
        if (t < t_end && (h < 1e-14 * span || --budget == 0)) {
            inst->s.time = t;
            inst->dirty = 1;
            sv_logf(inst, SV_LOG_ERROR, "logStatusError",
                    "integrator failed at t = %.17g (step size %.3g; rtol %.3g)", t, h, inst->s.rtol);
            return -1;
        }
    }
    inst->s.time = t_end;
    inst->dirty = 1;
    sv_logf(inst, SV_LOG_OK, "logSolver", "t = %.9g: %ld accepted, %ld rejected steps so far, h = %.3g",
            t_end, inst->steps, inst->rejected, inst->s.h);
    return 0;
}

/* ---- directional and adjoint derivatives ---------------------------------------- */
int sv_derivative(SvInstance *inst, const unsigned *unknowns, size_t n_unknowns, const unsigned *knowns,
                  size_t n_knowns, const double *seed, double *sensitivity, int adjoint) {
    enum { ROWS = SV_NX + SV_NY, COLS = SV_NX + 1 };
    double jac[ROWS * COLS];
    size_t a, b;
    int idx;
    call4(inst, servo_io_jacobian, inst->s.time, inst->s.x, jac, NULL);
    for (a = 0; a < (adjoint ? n_knowns : n_unknowns); ++a) sensitivity[a] = 0.0;
    for (a = 0; a < n_unknowns; ++a) {
        int row;
        enum sv_kind kind = sv_classify(unknowns[a], &idx);
        if (kind == SV_DERIV) row = idx;
        else if (unknowns[a] >= SV_VR_Y0 && unknowns[a] < SV_VR_Y0 + SV_NY) row = SV_NX + (int)(unknowns[a] - SV_VR_Y0);
        else {
            sv_logf(inst, SV_LOG_ERROR, "logStatusError",
                    "directional derivative: %u is not a derivative or an output", unknowns[a]);
            return -1;
        }
        for (b = 0; b < n_knowns; ++b) {
            int col;
            kind = sv_classify(knowns[b], &idx);
            if (kind == SV_STATE) col = idx;
            else if (kind == SV_INPUT) col = SV_NX;
            else {
                sv_logf(inst, SV_LOG_ERROR, "logStatusError",
                        "directional derivative: %u is not a state or the input", knowns[b]);
                return -1;
            }
            if (adjoint) sensitivity[b] += seed[a] * jac[col * ROWS + row];
            else sensitivity[a] += jac[col * ROWS + row] * seed[b];
        }
    }
    return 0;
}

/* ---- FMU state: a copy of SvState ---------------------------------------------------- */
static int sv_state_get_from(SvInstance *inst, const SvState *from, void **state) {
    if (!*state) *state = malloc(sizeof(SvState));
    if (!*state) { sv_logf(inst, SV_LOG_ERROR, "logStatusError", "out of memory"); return -1; }
    memcpy(*state, from, sizeof(SvState));
    return 0;
}

int sv_state_get(SvInstance *inst, void **state) { return sv_state_get_from(inst, &inst->s, state); }

int sv_state_set(SvInstance *inst, const void *state) {
    if (!state) { sv_logf(inst, SV_LOG_ERROR, "logStatusError", "no FMU state given"); return -1; }
    memcpy(&inst->s, state, sizeof(SvState));
    inst->dirty = 1;
    return 0;
}

int sv_state_serialize(SvInstance *inst, const void *state, unsigned char *bytes, size_t size) {
    if (!state || size < sizeof(SvState)) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "serialize FMU state: buffer of %zu bytes, need %zu", size,
                sizeof(SvState));
        return -1;
    }
    memcpy(bytes, state, sizeof(SvState));
    return 0;
}

int sv_state_deserialize(SvInstance *inst, const unsigned char *bytes, size_t size, void **state) {
    SvState probe;
    if (size != sizeof(SvState)) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "deserialize FMU state: %zu bytes is not a state of this FMU",
                size);
        return -1;
    }
    memcpy(&probe, bytes, sizeof probe);
    if (probe.magic != SV_MAGIC) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "deserialize FMU state: not a state of this FMU");
        return -1;
    }
    return sv_state_get_from(inst, &probe, state);
}

/* ---- life cycle shared by FMI 2.0 and 3.0 ------------------------------------------------ */
int sv_enter_initialization(SvInstance *inst, int tolerance_defined, double tolerance, double start_time) {
    if (inst->s.mode != SV_INSTANTIATED) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "initialization mode can only be entered after instantiation");
        return -1;
    }
    if (tolerance_defined) {
        if (!(tolerance > 0.0 && tolerance < 1.0)) {
            sv_logf(inst, SV_LOG_ERROR, "logStatusError", "tolerance %g is not in (0, 1)", tolerance);
            return -1;
        }
        inst->s.rtol = inst->s.atol = tolerance;
    }
    inst->s.time = start_time;
    inst->s.mode = SV_INITIALIZATION;
    inst->dirty = 1;
    return 0;
}

/* The rules between parameters (static friction not below Coulomb friction; with a DC gain, no root at 0): they
 * can only be judged once all are set.  0 ok, -1 violated (logged). */
int sv_check_parameters(SvInstance *inst) {
    int k;
    for (k = 0; k < SV_N_AT_LEAST; ++k)
        if (inst->s.p[p_at_least[k][0]] < inst->s.p[p_at_least[k][1]]) {
            sv_logf(inst, SV_LOG_ERROR, "logStatusError", "parameter %u (%g) is below parameter %u (%g): static "
                    "friction must not be below Coulomb friction", SV_VR_P0 + p_at_least[k][0],
                    inst->s.p[p_at_least[k][0]], SV_VR_P0 + p_at_least[k][1], inst->s.p[p_at_least[k][1]]);
            return -1;
        }
    for (k = 0; k < SV_N_ROOTS_NOT_ZERO; ++k)
        if (inst->s.p[p_roots_not_zero[k][0]] == 0.0 &&
            (p_roots_not_zero[k][1] < 0 || inst->s.p[p_roots_not_zero[k][1]] == 0.0)) {
            sv_logf(inst, SV_LOG_ERROR, "logStatusError", "parameter %u puts a root at 0: no finite DC gain",
                    SV_VR_P0 + p_roots_not_zero[k][0]);
            return -1;
        }
    return 0;
}

int sv_exit_initialization(SvInstance *inst) {
    if (inst->s.mode != SV_INITIALIZATION) {
        sv_logf(inst, SV_LOG_ERROR, "logStatusError", "exit initialization mode: not in initialization mode");
        return -1;
    }
    if (sv_check_parameters(inst) != 0) return -1;
    inst->s.mode = inst->is_cosim ? SV_STEP : SV_EVENT;
    return 0;
}

int sv_do_step(SvInstance *inst, double communication_point, double step_size) {
    if (check_step(inst, communication_point, step_size) != 0) return -1;
    if (sv_check_parameters(inst) != 0) return -1;
    inst->s.time = communication_point;
    return sv_integrate(inst, communication_point + step_size);
}
