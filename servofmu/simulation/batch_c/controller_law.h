/* The drive's cascade controller, one sample at a time: the single source of its arithmetic, compiled into the
 * controller FMU (controller_component.c) and the batch simulator's closed loop (batch_driver.c).
 *
 * Parameters p[] in the order of servofmu.control.controller.PARAMETERS (indices CP_* in controller_params.h).
 * At sample k (time t_k) with reference position r and measured position x:
 *   y      = encoder(x)                          q·floor(x/q + 1/2) for a resolution q > 0, else x
 *   v_ref  = (r − r_{k−1})/Ts,  a_ref = (v_ref − v_ref,k−1)/Ts       (0 at the first sample)
 *   v_hat  = velocity from the position difference: (y − y_{k−1})/Ts, its moving average over N samples
 *            (y − y_{k−N})/(N·Ts), or a first-order filter v_hat += Ts/(τ + Ts)·((y − y_{k−1})/Ts − v_hat)
 *   v_dem  = kp_position·(r − y) + velocity_feedforward·v_ref
 *   e      = v_dem − v_hat
 *   I      = I + ki_velocity·Ts·e                (not integrated while the output saturates: anti-windup)
 *   f      = kp_velocity·e + I + mass_feedforward·a_ref + friction_feedforward·F_ff(v_ref)
 *   u_k    = min(max(f, −limit), limit)
 * F_ff(v) = g+(v)·max(t, 0) + g−(v)·min(t, 0) + fv·v + fv_pos·max(v, 0) + fv_neg·min(v, 0) with
 * t = tanh(v/v_smooth), g±(v) = fc± + (fs± − fc±)·exp(−|v/vs|^δ): the steady friction of the plant model (δ = 2
 * and no direction-dependent part: the arithmetic of before they existed, to the bit).  The command u_k is applied from t_{k+delay} (delay ≥ 1:
 * the drive computes during the sample).  Actuator noise (force_noise > 0): a Gaussian sample per controller
 * sample (seeded, platform independent) added to the applied force, not to the logged command.  A known
 * disturbance d (a test signal the drive injects: force pulses, a noise burst) is added after the output limit,
 * to the force applied and to the command as the drive logs it (ctrl_inject). */
#ifndef CONTROLLER_LAW_H
#define CONTROLLER_LAW_H

#include <math.h>
#include <string.h>

#include "controller_params.h"

#define CTRL_MAX_WINDOW 64
#define CTRL_MAX_DELAY 16

typedef struct {
    long k;                              /* samples done */
    double r_prev, v_ref_prev;
    double y_hist[CTRL_MAX_WINDOW + 1];  /* ring: y_k at index k % (CTRL_MAX_WINDOW + 1) */
    double v_hat, integral;
    double queue[CTRL_MAX_DELAY];        /* commands waiting to be applied, oldest at index k % delay */
    unsigned long long rng;
    double last_y, last_v_ref;           /* of the last sample: the encoder reading and the reference velocity */
    double command_out, applied;         /* the command applied from the next sample on; with actuator noise */
    double total_command, total_applied; /* the same with the injected disturbance (ctrl_inject) */
} CtrlState;

static double ctrl_encoder(const double *p, double x) {
    double q = p[CP_ENCODER_RESOLUTION];
    return q > 0.0 ? q * floor(x / q + 0.5) : x;
}

static double ctrl_friction(const double *p, double v) {
    double th = tanh(v / p[CP_FF_V_SMOOTH]), bump, g_pos, g_neg, f;
    if (p[CP_FF_DELTA] == 2.0)
        bump = exp(-(v / p[CP_FF_VS]) * (v / p[CP_FF_VS]));
    else
        bump = exp(-pow(fabs(v / p[CP_FF_VS]), p[CP_FF_DELTA]));
    g_pos = p[CP_FF_FC_POS] + (p[CP_FF_FS_POS] - p[CP_FF_FC_POS]) * bump;
    g_neg = p[CP_FF_FC_NEG] + (p[CP_FF_FS_NEG] - p[CP_FF_FC_NEG]) * bump;
    f = g_pos * fmax(th, 0.0) + g_neg * fmin(th, 0.0) + p[CP_FF_FV] * v;
    if (p[CP_FF_FV_POS] != 0.0 || p[CP_FF_FV_NEG] != 0.0)
        f += p[CP_FF_FV_POS] * fmax(v, 0.0) + p[CP_FF_FV_NEG] * fmin(v, 0.0);
    return f;
}

/* A standard normal sample from the state's xorshift64* generator (Box–Muller, one of the pair). */
static double ctrl_gaussian(CtrlState *s) {
    double u1, u2;
    s->rng ^= s->rng >> 12; s->rng ^= s->rng << 25; s->rng ^= s->rng >> 27;
    u1 = ((s->rng * 2685821657736338717ULL) >> 11) * (1.0 / 9007199254740992.0);
    s->rng ^= s->rng >> 12; s->rng ^= s->rng << 25; s->rng ^= s->rng >> 27;
    u2 = ((s->rng * 2685821657736338717ULL) >> 11) * (1.0 / 9007199254740992.0);
    return sqrt(-2.0 * log(u1 + 1e-300)) * cos(6.283185307179586 * u2);
}

static void ctrl_reset(CtrlState *s, const double *p) {
    memset(s, 0, sizeof *s);
    s->rng = 0x9E3779B97F4A7C15ULL ^ (unsigned long long)(long long)p[CP_NOISE_SEED];
    if (s->rng == 0) s->rng = 1;
}

/* One sample: the command u_k, and the force applied from the next sample on (the delayed command plus noise). */
static double ctrl_sample(CtrlState *s, const double *p, double r, double x) {
    const double ts = p[CP_SAMPLE_TIME], limit = p[CP_FORCE_LIMIT];
    const int window = (int)p[CP_FILTER_WINDOW], delay = (int)p[CP_DELAY], filter = (int)p[CP_VELOCITY_FILTER];
    double y = ctrl_encoder(p, x), v_ref, a_ref, raw, e, integral, f, u;
    int i;
    if (s->k == 0) {
        for (i = 0; i <= CTRL_MAX_WINDOW; ++i) s->y_hist[i] = y;
        s->r_prev = r;
    }
    v_ref = (r - s->r_prev) / ts;
    a_ref = s->k == 0 ? 0.0 : (v_ref - s->v_ref_prev) / ts;
    raw = (y - s->y_hist[(s->k + CTRL_MAX_WINDOW) % (CTRL_MAX_WINDOW + 1)]) / ts;
    if (filter == 1)
        s->v_hat = (y - s->y_hist[(s->k + CTRL_MAX_WINDOW + 1 - window) % (CTRL_MAX_WINDOW + 1)]) / (window * ts);
    else if (filter == 2)
        s->v_hat += ts / (p[CP_FILTER_TIME_CONSTANT] + ts) * (raw - s->v_hat);
    else
        s->v_hat = raw;
    s->y_hist[s->k % (CTRL_MAX_WINDOW + 1)] = y;
    e = p[CP_KP_POSITION] * (r - y) + p[CP_VELOCITY_FEEDFORWARD] * v_ref - s->v_hat;
    integral = s->integral + p[CP_KI_VELOCITY] * ts * e;
    f = p[CP_KP_VELOCITY] * e + p[CP_MASS_FEEDFORWARD] * a_ref + p[CP_FRICTION_FEEDFORWARD] * ctrl_friction(p, v_ref);
    if (fabs(f + integral) > limit) integral = s->integral; /* anti-windup: hold the integral */
    u = fmin(fmax(f + integral, -limit), limit);
    s->integral = integral;
    s->r_prev = r;
    s->v_ref_prev = v_ref;
    s->last_y = y;
    s->last_v_ref = v_ref;
    /* the delay line: u_k leaves it `delay` samples later; what leaves now was computed delay - 1 samples ago */
    s->queue[s->k % delay] = u;
    s->command_out = s->queue[(s->k + 1) % delay];
    s->applied = s->command_out + (p[CP_FORCE_NOISE] > 0.0 ? p[CP_FORCE_NOISE] * ctrl_gaussian(s) : 0.0);
    s->k++;
    return u;
}

/* The disturbance d (N) injected after the output limit over the coming sample: the total command (as logged)
 * and the total force applied. */
static void ctrl_inject(CtrlState *s, double d) {
    s->total_command = s->command_out + d;
    s->total_applied = s->applied + d;
}

#endif
