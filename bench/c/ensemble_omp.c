/* An ensemble of N-link point-mass chains (equal links, N <= 8) run by classical RK4: the peer of
 * multipendulum's lanes (`mp.ensemble(..., method="rk4")`) in bench/bench_ensemble.py.
 *
 * Hand-vectorised as issue 14 asks: trajectories in blocks of W (structure of arrays), OpenMP
 * across blocks, `#pragma omp simd` across the W trajectories of a block; the dynamics by the
 * textbook route, the dense mass matrix M_ab = l h_max(a,b) cos(theta_a - theta_b) (with
 * h_b = m l (N - b) for equal point masses and links, 0-based b) and the right-hand side
 * -sum_b l h_max(a,b) sin(theta_a - theta_b) omega_b^2 - g h_a sin(theta_a), solved by Gaussian
 * elimination without pivoting (M is symmetric positive definite).
 *
 * Build: cc -O3 -march=native -fopenmp -ffast-math -fno-builtin-sin -fno-builtin-cos
 *        ensemble_omp.c -lm -lmvec      (libmvec's vector sin/cos under -ffast-math)
 * Usage: ensemble_omp IN.bin OUT.bin N STEPS DT L M G
 *   IN.bin: B x N float64 initial angles (from rest); OUT.bin: B x 2N float64 final (theta, omega).
 *   Prints the seconds spent integrating (omp_get_wtime, I/O excluded). Threads: OMP_NUM_THREADS.
 */
#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>

#define W 8
#define NMAX 8

typedef struct {
    int n;
    double l, g, h[NMAX], lh[NMAX][NMAX];
} Model;

/* theta_ddot of the W lanes of a block: the dense system, eliminated lane by lane in SIMD. */
static inline void accel(const Model *md, const double th[NMAX][W], const double w[NMAX][W], double out[NMAX][W]) {
    const int n = md->n;
    double A[NMAX][NMAX][W], r[NMAX][W], s[NMAX][W], c[NMAX][W];
    for (int a = 0; a < n; a++) {
#pragma omp simd
        for (int i = 0; i < W; i++) {
            s[a][i] = sin(th[a][i]);
            c[a][i] = cos(th[a][i]);
        }
    }
    for (int a = 0; a < n; a++) {
#pragma omp simd
        for (int i = 0; i < W; i++) r[a][i] = -md->g * md->h[a] * s[a][i];
        for (int b = 0; b < n; b++) {
            const double k = md->lh[a][b];
#pragma omp simd
            for (int i = 0; i < W; i++) {
                double sab = s[a][i] * c[b][i] - c[a][i] * s[b][i];
                double cab = c[a][i] * c[b][i] + s[a][i] * s[b][i];
                A[a][b][i] = k * cab;
                r[a][i] -= k * sab * w[b][i] * w[b][i];
            }
        }
    }
    for (int p = 0; p < n; p++) {
        for (int q = p + 1; q < n; q++) {
#pragma omp simd
            for (int i = 0; i < W; i++) {
                double f = A[q][p][i] / A[p][p][i];
                for (int j = p; j < n; j++) A[q][j][i] -= f * A[p][j][i];
                r[q][i] -= f * r[p][i];
            }
        }
    }
    for (int a = n - 1; a >= 0; a--) {
#pragma omp simd
        for (int i = 0; i < W; i++) {
            double x = r[a][i];
            for (int b = a + 1; b < n; b++) x -= A[a][b][i] * out[b][i];
            out[a][i] = x / A[a][a][i];
        }
    }
}

static void rk4(const Model *md, double h, double th[NMAX][W], double w[NMAX][W]) {
    const int n = md->n;
    double k1[NMAX][W], k2[NMAX][W], k3[NMAX][W], k4[NMAX][W];
    double t[NMAX][W], u[NMAX][W], v2[NMAX][W], v3[NMAX][W], v4[NMAX][W];
    double half = 0.5 * h, sixth = h / 6.0;
    accel(md, th, w, k1);
    for (int a = 0; a < n; a++)
#pragma omp simd
        for (int i = 0; i < W; i++) { t[a][i] = th[a][i] + half * w[a][i]; v2[a][i] = w[a][i] + half * k1[a][i]; }
    accel(md, t, v2, k2);
    for (int a = 0; a < n; a++)
#pragma omp simd
        for (int i = 0; i < W; i++) { u[a][i] = th[a][i] + half * v2[a][i]; v3[a][i] = w[a][i] + half * k2[a][i]; }
    accel(md, u, v3, k3);
    double x[NMAX][W];
    for (int a = 0; a < n; a++)
#pragma omp simd
        for (int i = 0; i < W; i++) { x[a][i] = th[a][i] + h * v3[a][i]; v4[a][i] = w[a][i] + h * k3[a][i]; }
    accel(md, x, v4, k4);
    for (int a = 0; a < n; a++)
#pragma omp simd
        for (int i = 0; i < W; i++) {
            th[a][i] += sixth * (w[a][i] + 2.0 * (v2[a][i] + v3[a][i]) + v4[a][i]);
            w[a][i] += sixth * (k1[a][i] + 2.0 * (k2[a][i] + k3[a][i]) + k4[a][i]);
        }
}

int main(int argc, char **argv) {
    if (argc != 9) {
        fprintf(stderr, "usage: %s IN.bin OUT.bin N STEPS DT L M G\n", argv[0]);
        return 2;
    }
    Model md;
    md.n = atoi(argv[3]);
    long steps = atol(argv[4]);
    double dt = atof(argv[5]);
    md.l = atof(argv[6]);
    double m = atof(argv[7]);
    md.g = atof(argv[8]);
    int n = md.n;
    if (n < 1 || n > NMAX) {
        fprintf(stderr, "N must be 1..%d\n", NMAX);
        return 2;
    }
    for (int a = 0; a < n; a++) md.h[a] = m * md.l * (n - a);
    for (int a = 0; a < n; a++)
        for (int b = 0; b < n; b++) md.lh[a][b] = md.l * md.h[a > b ? a : b];
    FILE *f = fopen(argv[1], "rb");
    if (!f) return 2;
    fseek(f, 0, SEEK_END);
    long bytes = ftell(f);
    fseek(f, 0, SEEK_SET);
    long rows = bytes / (8L * n);
    double *in = malloc(bytes), *out = malloc(rows * 2 * n * sizeof(double));
    if (fread(in, 1, bytes, f) != (size_t)bytes) return 2;
    fclose(f);
    long blocks = (rows + W - 1) / W;
    double t0 = omp_get_wtime();
#pragma omp parallel for schedule(static)
    for (long blk = 0; blk < blocks; blk++) {
        double th[NMAX][W] = {{0}}, w[NMAX][W] = {{0}};
        for (int i = 0; i < W; i++) {
            long r = blk * W + i;
            for (int a = 0; a < n; a++) th[a][i] = r < rows ? in[r * n + a] : 0.0;
        }
        for (long k = 0; k < steps; k++) rk4(&md, dt, th, w);
        for (int i = 0; i < W; i++) {
            long r = blk * W + i;
            if (r >= rows) break;
            for (int a = 0; a < n; a++) {
                out[r * 2 * n + a] = th[a][i];
                out[r * 2 * n + n + a] = w[a][i];
            }
        }
    }
    printf("%.9f\n", omp_get_wtime() - t0);
    f = fopen(argv[2], "wb");
    if (!f) return 2;
    fwrite(out, sizeof(double), rows * 2 * n, f);
    fclose(f);
    return 0;
}
