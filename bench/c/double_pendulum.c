/*
 * Peer for bench/bench_engine.py: classical RK4 on the point-mass double pendulum,
 * written the way a careful C programmer would, compiled with plain -O3 (no -ffast-math,
 * no -march), so the comparison with the Rust core is like for like.
 *
 * State (theta1, theta2, omega1, omega2): absolute angles from the downward vertical,
 * counter-clockwise positive. Accelerations are the closed-form solution of the 2x2 system
 *     (m1+m2) l1 a1 + m2 l2 cos(d) a2 = -m2 l2 w2^2 sin(d) - (m1+m2) g sin(th1)
 *     l1 cos(d) a1  + l2 a2           =  l1 w1^2 sin(d)    - g sin(th2)
 * with d = th1 - th2; its determinant is l1 l2 (m1 + m2 sin^2 d). One sin/cos of d per
 * evaluation (GCC fuses them into sincos), plus sin(th1) and sin(th2).
 *
 * Usage: double_pendulum STEPS DT th1 th2 w1 w2 l1 l2 m1 m2 g [REPEATS]
 * Prints {"ns_per_step": median over REPEATS (default 5), "final": [...], ...}.
 * Every repeat starts from the same initial state, so "final" is the state after STEPS steps.
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

typedef struct {
    double l1, l2, m1, m2, g;
} params;

static inline void deriv(const params *p, const double y[4], double dy[4])
{
    const double d = y[0] - y[1];
    const double s = sin(d), c = cos(d);
    const double s1 = sin(y[0]), s2 = sin(y[1]);
    const double w1sq = y[2] * y[2], w2sq = y[3] * y[3];
    const double msum = p->m1 + p->m2;
    const double den = p->m1 + p->m2 * s * s;

    dy[0] = y[2];
    dy[1] = y[3];
    dy[2] = (-p->m2 * p->l2 * w2sq * s - msum * p->g * s1
             - p->m2 * c * (p->l1 * w1sq * s - p->g * s2))
            / (p->l1 * den);
    dy[3] = (msum * (p->l1 * w1sq * s - p->g * s2 + p->g * s1 * c)
             + p->m2 * p->l2 * w2sq * s * c)
            / (p->l2 * den);
}

static inline void rk4_step(const params *p, double y[4], double h)
{
    double k1[4], k2[4], k3[4], k4[4], tmp[4];
    const double h2 = 0.5 * h, h6 = h / 6.0;
    int i;

    deriv(p, y, k1);
    for (i = 0; i < 4; i++) tmp[i] = y[i] + h2 * k1[i];
    deriv(p, tmp, k2);
    for (i = 0; i < 4; i++) tmp[i] = y[i] + h2 * k2[i];
    deriv(p, tmp, k3);
    for (i = 0; i < 4; i++) tmp[i] = y[i] + h * k3[i];
    deriv(p, tmp, k4);
    for (i = 0; i < 4; i++) y[i] += h6 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
}

static double now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

static int cmp_double(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double parse(const char *s, const char *name)
{
    char *end;
    double v = strtod(s, &end);
    if (end == s || *end != '\0' || !isfinite(v)) {
        fprintf(stderr, "double_pendulum: %s must be a finite number, got '%s'\n", name, s);
        exit(2);
    }
    return v;
}

int main(int argc, char **argv)
{
    static const char *names[] = {"STEPS", "DT", "th1", "th2", "w1", "w2",
                                  "l1", "l2", "m1", "m2", "g", "REPEATS"};
    double a[12];
    int i;

    if (argc != 12 && argc != 13) {
        fprintf(stderr, "usage: %s STEPS DT th1 th2 w1 w2 l1 l2 m1 m2 g [REPEATS]\n", argv[0]);
        return 2;
    }
    for (i = 1; i < argc; i++) a[i - 1] = parse(argv[i], names[i - 1]);
    if (argc == 12) a[11] = 5;

    const long steps = (long)a[0];
    const int repeats = (int)a[11];
    if (steps < 1 || repeats < 1 || repeats > 1000) {
        fprintf(stderr, "double_pendulum: STEPS and REPEATS must be >= 1\n");
        return 2;
    }
    const double h = a[1];
    const params p = {a[6], a[7], a[8], a[9], a[10]};

    double *times = malloc(sizeof(double) * (size_t)repeats);
    double y[4];
    if (!times) return 1;

    for (int r = 0; r < repeats; r++) {
        for (i = 0; i < 4; i++) y[i] = a[2 + i];
        const double t0 = now_ns();
        for (long n = 0; n < steps; n++) rk4_step(&p, y, h);
        const double t1 = now_ns();
        times[r] = (t1 - t0) / (double)steps;
    }
    qsort(times, (size_t)repeats, sizeof(double), cmp_double);
    const double median = (repeats % 2) ? times[repeats / 2]
                                        : 0.5 * (times[repeats / 2 - 1] + times[repeats / 2]);

    printf("{\"ns_per_step\": %.6g, \"min_ns_per_step\": %.6g, \"repeats\": %d, \"steps\": %ld, "
           "\"final\": [%.17g, %.17g, %.17g, %.17g]}\n",
           median, times[0], repeats, steps, y[0], y[1], y[2], y[3]);
    free(times);
    return 0;
}
