/* servofmu closed-loop batch simulator: the batch simulator's plant integration (batch_driver.c) with the drive's
 * controller law (controller_law.h) at every sample, for many plant parameter sets on POSIX threads.
 *
 * Sample k at t_k = t[k] (uniform, the controller's sample time): the plant's position x(t_k) goes to the law with
 * the reference r[k]; the force applied on [t_k, t_k+1) is the one the law released at sample k − 1 (its command
 * of `delay` samples before, plus actuator noise if any) — the Jacobi exchange of a co-simulation stepped with the
 * sample time, where a command computed at t_k reaches the plant at t_k+1.  Outputs per sample: the position and
 * the velocity at t_k and the command applied on [t_k, t_k+1) (as the drive logs it). */
#include "batch_driver.c"
#include "controller_law.h"

static void loop_task(const double *params, int n_plant, long n, const double *t, const double *r, const double *cp,
                      double rtol, double h_start, long max_steps, double *out) {
    Eval ev;
    Problem pb;
    CtrlState law;
    double y[NY] = {0}, h = h_start * (t[1] - t[0]), *x = out, *v = out + n, *command = out + 2 * n;
    long k;
    problem_init(&pb, &ev, params, n_plant, rtol, max_steps);
    pb.nq = 1;                    /* the position is error-controlled like a state */
    pb.q_time = t[n - 1] - t[0];
    ctrl_reset(&law, cp);
    for (k = 0; k < n; ++k) {
        x[k] = y[NS];
        v[k] = y[0];
        command[k] = k == 0 ? 0.0 : law.command_out;
        pb.u0 = k == 0 ? 0.0 : law.applied;
        pb.slope = 0.0;
        ctrl_sample(&law, cp, r[k], y[NS]);
        if (k + 1 < n && integrate(&ev, &pb, y, 0.0, t[k + 1] - t[k], &h) != 0) {
            for (++k; k < n; ++k) x[k] = v[k] = command[k] = NAN;
            break;
        }
    }
}

typedef struct {
    long n_tasks, next, n_samples;
    int n_plant;
    const double *params, *t, *r, *cp;
    const unsigned char *valid;
    double rtol, h_start;
    long max_steps;
    double *out;
} LoopJob;

static void *loop_worker(void *arg) {
    LoopJob *job = (LoopJob *)arg;
    long set;
    while ((set = __atomic_fetch_add(&job->next, 1, __ATOMIC_RELAXED)) < job->n_tasks) {
        double *out = job->out + set * 3 * job->n_samples;
        if (!job->valid[set]) {
            long i;
            for (i = 0; i < 3 * job->n_samples; ++i) out[i] = NAN;
            continue;
        }
        loop_task(job->params + set * job->n_plant, job->n_plant, job->n_samples, job->t, job->r, job->cp,
                  job->rtol, job->h_start, job->max_steps, out);
    }
    return NULL;
}

/* out has 3*n_samples doubles per set: position, velocity, command.  cp: the controller's CP_COUNT parameters. */
int sb_loop(long n_sets, int n_plant, const double *params, const unsigned char *valid, long n_samples,
            const double *t, const double *r, const double *cp, double rtol, double h_start, long max_steps,
            int n_threads, double *out) {
    LoopJob job;
    pthread_t threads[64];
    int i, started = 0;
    if (n_plant != SB_NP || n_samples < 2) return -1;
    memset(&job, 0, sizeof job);
    job.n_tasks = n_sets;
    job.n_samples = n_samples;
    job.n_plant = n_plant;
    job.params = params;
    job.valid = valid;
    job.t = t;
    job.r = r;
    job.cp = cp;
    job.rtol = rtol;
    job.h_start = h_start;
    job.max_steps = max_steps;
    job.out = out;
    if (n_threads > 64) n_threads = 64;
    if (n_threads > n_sets) n_threads = (int)n_sets;
    for (i = 1; i < n_threads; ++i)
        if (pthread_create(&threads[started], NULL, loop_worker, &job) == 0) started++;
    loop_worker(&job);
    for (i = 0; i < started; ++i) pthread_join(threads[i], NULL);
    return 0;
}
