/* First-flip times of an ensemble of point-mass double pendulums released from rest: the peer of
 * multipendulum's flip-map kernel in bench/bench_flip.py.
 *
 * The same step as multipendulum: classical RK4 on the Lagrangian form, the 2x2 mass matrix
 * solved in closed form; a trajectory stops at the first step after which |theta_1| or
 * |theta_2| >= pi, and the crossing is located by 60 bisections on the step's cubic Hermite
 * interpolant (theta' = omega at both ends). Never: +inf; a start beyond pi: 0.
 *
 * Two builds of this file (bench_flip.py compiles both into bench/build/):
 *   scalar: cc -O3 -march=native -fopenmp              one trajectory per loop iteration
 *   SIMD:   cc -O3 -march=native -fopenmp -ffast-math -fno-builtin-sin -fno-builtin-cos -DFLIP_SIMD
 *           blocks of W trajectories (structure of arrays) advanced together, stage by stage,
 *           under `#pragma omp simd`; sin and cos become glibc libmvec's vector variants, which
 *           GCC only uses under -ffast-math (-fno-builtin-sin/cos stop it from merging the two
 *           into a scalar sincos call, which it cannot vectorise).
 *           A block runs until all its lanes have flipped (flipped lanes compute on, unrecorded).
 *
 * Usage: flip_omp IN.bin OUT.bin STEPS DT L1 L2 M1 M2 G
 *   IN.bin: B x 2 float64 (theta1, theta2); OUT.bin: B float64 flip times.
 *   Prints the seconds spent integrating (omp_get_wtime, I/O excluded). Threads: OMP_NUM_THREADS.
 */
#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>

static const double PI = 3.14159265358979323846;

typedef struct {
    double gh1, gh2, k, d1, d2, d1d2;
} Coef;

static inline void accel(const Coef *c, double th1, double th2, double w1, double w2, double *a1, double *a2) {
    double s1 = sin(th1), c1 = cos(th1), s2 = sin(th2), c2 = cos(th2);
    double s12 = s1 * c2 - c1 * s2, c12 = c1 * c2 + s1 * s2;
    double r1 = -c->gh1 * s1 - c->k * s12 * w2 * w2;
    double r2 = -c->gh2 * s2 + c->k * s12 * w1 * w1;
    double kc = c->k * c12;
    double inv = 1.0 / (c->d1d2 - kc * kc);
    *a1 = (c->d2 * r1 - kc * r2) * inv;
    *a2 = (c->d1 * r2 - kc * r1) * inv;
}

static inline void rk4(const Coef *c, double h, double *th1, double *th2, double *w1, double *w2) {
    double half = 0.5 * h, y1 = *th1, y2 = *th2, y3 = *w1, y4 = *w2;
    double a1, a2, b1, b2, c1, c2, d1, d2;
    accel(c, y1, y2, y3, y4, &a1, &a2);
    double t1 = y1 + half * y3, t2 = y2 + half * y4, t3 = y3 + half * a1, t4 = y4 + half * a2;
    accel(c, t1, t2, t3, t4, &b1, &b2);
    double u1 = y1 + half * t3, u2 = y2 + half * t4, u3 = y3 + half * b1, u4 = y4 + half * b2;
    accel(c, u1, u2, u3, u4, &c1, &c2);
    double v1 = y1 + h * u3, v2 = y2 + h * u4, v3 = y3 + h * c1, v4 = y4 + h * c2;
    accel(c, v1, v2, v3, v4, &d1, &d2);
    double sixth = h / 6.0;
    *th1 = y1 + sixth * (y3 + 2.0 * (t3 + u3) + v3);
    *th2 = y2 + sixth * (y4 + 2.0 * (t4 + u4) + v4);
    *w1 = y3 + sixth * (a1 + 2.0 * (b1 + c1) + d1);
    *w2 = y4 + sixth * (a2 + 2.0 * (b2 + c2) + d2);
}

/* The flip time inside step `step` from (theta, omega) of link k at both ends. */
static double locate(double th0, double om0, double th1, double om1, long step, double h) {
    double target = copysign(PI, th1), lo = 0.0, hi = 1.0, t = step * h;
    for (int i = 0; i < 60; i++) {
        double x = 0.5 * (lo + hi), x2 = x * x, x3 = x2 * x;
        double at = (2 * x3 - 3 * x2 + 1) * th0 + (x3 - 2 * x2 + x) * h * om0 + (-2 * x3 + 3 * x2) * th1 + (x3 - x2) * h * om1;
        if ((at - target) * copysign(1.0, target) >= 0.0) hi = x; else lo = x;
    }
    return fmin(t + hi * h, t + h);
}

static int flipped(double a, double b) { return fabs(a) >= PI || fabs(b) >= PI; }

static double locate_either(const double p[4], const double q[4], long step, double h) {
    int k = fabs(q[0]) >= PI ? 0 : 1;
    return locate(p[k], p[2 + k], q[k], q[2 + k], step, h);
}

#ifndef FLIP_SIMD
static void run(const Coef *c, const double *in, double *out, long b, long steps, double h) {
#pragma omp parallel for schedule(dynamic, 64)
    for (long j = 0; j < b; j++) {
        double y[4] = {in[2 * j], in[2 * j + 1], 0.0, 0.0}, p[4];
        out[j] = INFINITY;
        if (flipped(y[0], y[1])) { out[j] = 0.0; continue; }
        for (long s = 0; s < steps; s++) {
            for (int m = 0; m < 4; m++) p[m] = y[m];
            rk4(c, h, &y[0], &y[1], &y[2], &y[3]);
            if (flipped(y[0], y[1])) { out[j] = locate_either(p, y, s, h); break; }
        }
    }
}
#else
#define W 8
/* theta_ddot of W lanes: the same arithmetic as accel(), one stage of the structure-of-arrays step. */
static inline void accel_lanes(const Coef *c, const double *th1, const double *th2, const double *w1, const double *w2,
                               double *a1, double *a2) {
    double s1[W], c1[W], s2[W], c2[W];
#pragma omp simd
    for (int l = 0; l < W; l++) s1[l] = sin(th1[l]), c1[l] = cos(th1[l]), s2[l] = sin(th2[l]), c2[l] = cos(th2[l]);
#pragma omp simd
    for (int l = 0; l < W; l++) {
        double s12 = s1[l] * c2[l] - c1[l] * s2[l], c12 = c1[l] * c2[l] + s1[l] * s2[l];
        double r1 = -c->gh1 * s1[l] - c->k * s12 * w2[l] * w2[l];
        double r2 = -c->gh2 * s2[l] + c->k * s12 * w1[l] * w1[l];
        double kc = c->k * c12, inv = 1.0 / (c->d1d2 - kc * kc);
        a1[l] = (c->d2 * r1 - kc * r2) * inv;
        a2[l] = (c->d1 * r2 - kc * r1) * inv;
    }
}

static void run(const Coef *c, const double *in, double *out, long b, long steps, double h) {
#pragma omp parallel for schedule(dynamic, 4)
    for (long j0 = 0; j0 < b; j0 += W) {
        /* y[m][l]: component m (theta1, theta2, omega1, omega2) of lane l; k[i]: stage i's slopes. */
        double y[4][W], p[4][W], t[4][W], k[4][4][W], pf[4][W], qf[4][W];
        long at[W];
        int done[W];
        for (int l = 0; l < W; l++) {
            long j = j0 + l < b ? j0 + l : b - 1;
            y[0][l] = in[2 * j], y[1][l] = in[2 * j + 1], y[2][l] = y[3][l] = 0.0;
            done[l] = j0 + l >= b || flipped(y[0][l], y[1][l]);
            at[l] = -1;
        }
        double half = 0.5 * h, sixth = h / 6.0;
        for (long s = 0; s < steps; s++) {
            for (int m = 0; m < 4; m++)
                for (int l = 0; l < W; l++) p[m][l] = t[m][l] = y[m][l];
            for (int i = 0; i < 4; i++) {
                accel_lanes(c, t[0], t[1], t[2], t[3], k[i][2], k[i][3]);
                double f = i < 2 ? half : h;
#pragma omp simd
                for (int l = 0; l < W; l++) {
                    k[i][0][l] = t[2][l], k[i][1][l] = t[3][l];
                    for (int m = 0; m < 4; m++) t[m][l] = y[m][l] + f * k[i][m][l];
                }
            }
            int all = 1;
#pragma omp simd reduction(& : all)
            for (int l = 0; l < W; l++) {
                for (int m = 0; m < 4; m++) y[m][l] += sixth * (k[0][m][l] + 2.0 * (k[1][m][l] + k[2][m][l]) + k[3][m][l]);
                int hit = !done[l] & ((fabs(y[0][l]) >= PI) | (fabs(y[1][l]) >= PI));
                at[l] = hit ? s : at[l];
                done[l] |= hit;
                all &= done[l];
            }
            /* Keep the states around each lane's flip step (once per lane). */
            for (int l = 0; l < W; l++)
                if (at[l] == s)
                    for (int m = 0; m < 4; m++) pf[m][l] = p[m][l], qf[m][l] = y[m][l];
            if (all) break;
        }
        for (int l = 0; l < W && j0 + l < b; l++) {
            double pp[4], qq[4];
            for (int m = 0; m < 4; m++) pp[m] = pf[m][l], qq[m] = qf[m][l];
            out[j0 + l] = flipped(in[2 * (j0 + l)], in[2 * (j0 + l) + 1]) ? 0.0
                          : at[l] < 0                                     ? INFINITY
                                                                          : locate_either(pp, qq, at[l], h);
        }
    }
}
#endif

int main(int argc, char **argv) {
    if (argc != 10) {
        fprintf(stderr, "usage: %s IN.bin OUT.bin STEPS DT L1 L2 M1 M2 G\n", argv[0]);
        return 2;
    }
    long steps = atol(argv[3]);
    double h = atof(argv[4]), l1 = atof(argv[5]), l2 = atof(argv[6]), m1 = atof(argv[7]), m2 = atof(argv[8]), g = atof(argv[9]);
    FILE *f = fopen(argv[1], "rb");
    if (!f) { perror(argv[1]); return 1; }
    fseek(f, 0, SEEK_END);
    long b = ftell(f) / (2 * (long)sizeof(double));
    fseek(f, 0, SEEK_SET);
    double *in = malloc(2 * b * sizeof(double)), *out = malloc(b * sizeof(double));
    if (fread(in, sizeof(double), 2 * b, f) != (size_t)(2 * b)) { fprintf(stderr, "short read\n"); return 1; }
    fclose(f);
    /* Point masses at the link ends: h_1 = (m1 + m2) l1, h_2 = m2 l2, K_12 = l1 h_2. */
    Coef c = {g * (m1 + m2) * l1, g * m2 * l2, l1 * m2 * l2, (m1 + m2) * l1 * l1, m2 * l2 * l2, 0.0};
    c.d1d2 = c.d1 * c.d2;
    double t0 = omp_get_wtime();
    run(&c, in, out, b, steps, h);
    double t1 = omp_get_wtime();
    f = fopen(argv[2], "wb");
    if (!f) { perror(argv[2]); return 1; }
    fwrite(out, sizeof(double), b, f);
    fclose(f);
    printf("%.9f\n", t1 - t0);
    free(in), free(out);
    return 0;
}
