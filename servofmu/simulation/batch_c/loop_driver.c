/* servofmu closed-loop batch simulator: the batch simulator's plant integration (batch_driver.c) with the drive's
 * controller law (controller_law.h) at every sample, for many plant parameter sets on POSIX threads.
 *
 * Sample k at t_k = t[k] (uniform, the controller's sample time): the plant's position x(t_k) goes to the law with
 * the reference r[k]; the force applied on [t_k, t_k+1) is the one the law released at sample k − 1 (its command
 * of `delay` samples before, plus actuator noise if any) — the Jacobi exchange of a co-simulation stepped with the
 * sample time, where a command computed at t_k reaches the plant at t_k+1.  A known disturbance d[k] (a test signal
 * the drive injects after its output limit; optional) is added to the force applied on [t_k, t_k+1).  Outputs per
 * sample: the position and the velocity at t_k and the total command applied on [t_k, t_k+1) (as the drive logs
 * it: the law's command plus d[k]).  An encoder error e[k] (optional) is added to the position the law reads at t_k:
 * the closed-loop identification's model of a quantised encoder's error (servofmu.identification.closed_loop). */
#include "batch_driver.c"
#include "controller_law.h"

/* The loop's reference and controller and the integration's settings (sb_loop). */
typedef struct {
    long n_samples;
    const double *t, *r, *cp;  /* sample times, reference positions, the controller's CP_COUNT parameters */
    const double *d;           /* the disturbance added after the output limit (N), or NULL for none */
    const double *e;           /* the error added to the position the law reads (m), or NULL for none */
    double rtol, h_start;
    long max_steps;
} LoopInput;

/* The loop of one plant (params) at the samples: out[0..n) = position, out[n..2n) = velocity, out[2n..3n) = the
 * command applied from each sample on. */
static void loop_task(const void *input, const double *params, int n_plant, double *out) {
    const LoopInput *in = input;
    const double *t = in->t, *r = in->r, *cp = in->cp, *d = in->d, *e = in->e;
    long n = in->n_samples, k;
    Eval ev;
    Problem pb;
    CtrlState law;
    double y[NY] = {0}, h = in->h_start * (t[1] - t[0]), *x = out, *v = out + n, *command = out + 2 * n;
    problem_init(&pb, &ev, params, n_plant, in->rtol, in->max_steps);
    pb.nq = 1;                    /* the position is error-controlled like a state */
    pb.q_time = t[n - 1] - t[0];
    ctrl_reset(&law, cp);
    for (k = 0; k < n; ++k) {
        x[k] = y[NS];
        v[k] = y[0];
        ctrl_inject(&law, d ? d[k] : 0.0); /* before the first sample the law's command is 0 (ctrl_reset) */
        command[k] = law.total_command;
        pb.u0 = law.total_applied;
        pb.slope = 0.0;
        ctrl_sample(&law, cp, r[k], e ? y[NS] + e[k] : y[NS]);
        if (k + 1 < n && integrate(&ev, &pb, y, 0.0, t[k + 1] - t[k], &h) != 0) {
            for (++k; k < n; ++k) x[k] = v[k] = command[k] = NAN;
            break;
        }
    }
}

/* out has 3*n_samples doubles per set: position, velocity, command.  cp: the controller's CP_COUNT parameters;
 * d: n_samples disturbance forces, or NULL; e: n_samples encoder errors, or NULL. */
int sb_loop(long n_sets, int n_plant, const double *params, const unsigned char *valid, long n_samples,
            const double *t, const double *r, const double *d, const double *e, const double *cp, double rtol,
            double h_start, long max_steps, int n_threads, double *out) {
    LoopInput input = {.n_samples = n_samples, .t = t, .r = r, .cp = cp, .d = d, .e = e, .rtol = rtol,
                       .h_start = h_start, .max_steps = max_steps};
    if (n_plant != SB_NP || n_samples < 2) return -1;
    run_sets(n_sets, n_plant, params, valid, loop_task, &input, 3 * n_samples, n_threads, out);
    return 0;
}
