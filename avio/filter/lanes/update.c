/* The update's own phases in C (benchmarks/native/bench_native.py), per filter with the operations of the
 * kernel's numba code in their order, and for L filters in lock-step where that is a layout (every array
 * lanes-last, the lane loop innermost, L a compile-time constant). Compiled with -ffp-contract=off and
 * without fast-math, so every variant gives the kernel's bits. Arrays are row-major doubles.
 *
 * solve: A X = B by elimination with partial pivoting, a pivot per lane (avio.filter._linalg.solve):
 *        A (12, 12), B (12, 13), solved in place from fresh copies A0, B0 on every call.
 * info:  the information sum over a frame's inliers (Eq. 40).
 * innov: the feature innovations (Eq. 37), per filter only: they run across a frame's features already.
 * Each *_calls function repeats its phase n times on the same arrays (the timing loop). */
#include <math.h>
#include <string.h>

/* each phase is inlined into both its callers: the kernel's entry (lanes_*) and the benchmark's loop (*_calls) */
#define INLINE static inline __attribute__((always_inline))

INLINE void solve_one(double *restrict A, double *restrict B) {
    const int m = 12, k = 13;
    for (int c = 0; c < m; c++) {
        int piv = c;
        double big = fabs(A[c * m + c]);
        for (int i = c + 1; i < m; i++)
            if (fabs(A[i * m + c]) > big) { piv = i; big = fabs(A[i * m + c]); }
        if (piv != c) {
            for (int j = 0; j < m; j++) { double t = A[c * m + j]; A[c * m + j] = A[piv * m + j]; A[piv * m + j] = t; }
            for (int j = 0; j < k; j++) { double t = B[c * k + j]; B[c * k + j] = B[piv * k + j]; B[piv * k + j] = t; }
        }
        double inv = 1.0 / A[c * m + c];
        for (int i = c + 1; i < m; i++) {
            double f = A[i * m + c] * inv;
            if (f != 0.0) {
                for (int j = c + 1; j < m; j++) A[i * m + j] -= f * A[c * m + j];
                for (int j = 0; j < k; j++) B[i * k + j] -= f * B[c * k + j];
            }
        }
    }
    for (int c = m - 1; c >= 0; c--) {
        for (int i = c + 1; i < m; i++) {
            double f = A[c * m + i];
            for (int j = 0; j < k; j++) B[c * k + j] -= f * B[i * k + j];
        }
        double inv = 1.0 / A[c * m + c];
        for (int j = 0; j < k; j++) B[c * k + j] *= inv;
    }
}

void solve_calls(const double *A0, const double *B0, double *A, double *B, long n) {
    for (long r = 0; r < n; r++) {
        memcpy(A, A0, 12 * 12 * sizeof(double));
        memcpy(B, B0, 12 * 13 * sizeof(double));
        solve_one(A, B);
    }
}

/* info: the information sum over a frame's inliers (avio.filter.update.update, Eq. 40): A (12, 12) and
 *       beta = X[:, 12] from the whitened residuals rw (3, F) and Jacobians Jw (3, 12, F) of the features
 *       with inl[f] != 0 (uint8), in feature order; scratch jw_f (3, 12); stats (3,) = the inliers,
 *       sum rw^2 and sum ldR[f] over them. A lane that is not an inlier keeps its sums through a select. */
static void info_one(double *restrict A, double *restrict beta, double *restrict X, const double *restrict rw,
                     const double *restrict Jw, double *restrict jw_f, const unsigned char *restrict inl,
                     const double *restrict ldR, double *restrict stats, int F) {
    for (int i = 0; i < 144; i++) A[i] = 0.0;
    for (int b = 0; b < 12; b++) beta[b] = 0.0;
    long used = 0;
    double rr = 0.0, log_det_R = 0.0;
    for (int f = 0; f < F; f++) {
        if (!inl[f]) continue;
        used += 1;
        log_det_R += ldR[f];
        for (int a = 0; a < 3; a++) {
            rr += rw[a * F + f] * rw[a * F + f];
            for (int b = 0; b < 12; b++) jw_f[a * 12 + b] = Jw[(a * 12 + b) * F + f];
        }
        for (int a = 0; a < 3; a++) {
            double rwa = rw[a * F + f];
            for (int b = 0; b < 12; b++) beta[b] += jw_f[a * 12 + b] * rwa;
            for (int b = 0; b < 12; b++) {
                double jb = jw_f[a * 12 + b];
                for (int c = 0; c < 12; c++) A[b * 12 + c] += jb * jw_f[a * 12 + c];
            }
        }
    }
    for (int b = 0; b < 12; b++) {
        X[b * 13 + 12] = beta[b];
        for (int c = 0; c < b; c++) A[b * 12 + c] = A[c * 12 + b];
    }
    stats[0] = (double)used;
    stats[1] = rr;
    stats[2] = log_det_R;
}

void info_calls(double *A, double *beta, double *X, const double *rw, const double *Jw, double *jw_f,
                const unsigned char *inl, const double *ldR, double *stats, long F, long n) {
    for (long k = 0; k < n; k++) info_one(A, beta, X, rw, Jw, jw_f, inl, ldR, stats, (int)F);
}

/* L filters in lock-step. */
#define SOLVE_LANES(L)                                                                                             \
INLINE void solve_lanes_##L(double *restrict A, double *restrict B, double *restrict ra, double *restrict rb) { \
    const int m = 12, k = 13;                                                                                \
    for (int c = 0; c < m; c++) {                                                                            \
        int piv[L]; double big[L], inv[L], f[L];                                                             \
        for (int l = 0; l < L; l++) { piv[l] = c; big[l] = fabs(A[(c * m + c) * L + l]); }                  \
        for (int i = c + 1; i < m; i++)                                                                      \
            for (int l = 0; l < L; l++) {                                                                    \
                double v = fabs(A[(i * m + c) * L + l]);                                                     \
                piv[l] = v > big[l] ? i : piv[l];                                                            \
                big[l] = v > big[l] ? v : big[l];                                                            \
            }                                                                                                \
        for (int l = 0; l < L; l++)  /* each lane swaps its own rows */                                      \
            if (piv[l] != c) {                                                                               \
                for (int j = 0; j < m; j++) {                                                                \
                    double t = A[(c * m + j) * L + l];                                                       \
                    A[(c * m + j) * L + l] = A[(piv[l] * m + j) * L + l]; A[(piv[l] * m + j) * L + l] = t;   \
                }                                                                                            \
                for (int j = 0; j < k; j++) {                                                                \
                    double t = B[(c * k + j) * L + l];                                                       \
                    B[(c * k + j) * L + l] = B[(piv[l] * k + j) * L + l]; B[(piv[l] * k + j) * L + l] = t;   \
                }                                                                                            \
            }                                                                                                \
        /* the pivot row to scratch: its reads cannot alias the rows written below */                        \
        for (int j = 0; j < m * L; j++) ra[j] = A[c * m * L + j];                                            \
        for (int j = 0; j < k * L; j++) rb[j] = B[c * k * L + j];                                            \
        for (int l = 0; l < L; l++) inv[l] = 1.0 / ra[c * L + l];                                            \
        for (int i = c + 1; i < m; i++) {                                                                    \
            for (int l = 0; l < L; l++) f[l] = A[(i * m + c) * L + l] * inv[l];                              \
            for (int j = c + 1; j < m; j++)  /* a lane whose factor is 0 keeps its row: a select */          \
                for (int l = 0; l < L; l++) {                                                                \
                    double t = A[(i * m + j) * L + l] - f[l] * ra[j * L + l];                                \
                    A[(i * m + j) * L + l] = f[l] != 0.0 ? t : A[(i * m + j) * L + l];                       \
                }                                                                                            \
            for (int j = 0; j < k; j++)                                                                      \
                for (int l = 0; l < L; l++) {                                                                \
                    double t = B[(i * k + j) * L + l] - f[l] * rb[j * L + l];                                \
                    B[(i * k + j) * L + l] = f[l] != 0.0 ? t : B[(i * k + j) * L + l];                       \
                }                                                                                            \
        }                                                                                                    \
    }                                                                                                        \
    for (int c = m - 1; c >= 0; c--) {                                                                       \
        for (int i = c + 1; i < m; i++)                                                                      \
            for (int j = 0; j < k; j++)                                                                      \
                for (int l = 0; l < L; l++) B[(c * k + j) * L + l] -= A[(c * m + i) * L + l] * B[(i * k + j) * L + l]; \
        for (int j = 0; j < k; j++)                                                                          \
            for (int l = 0; l < L; l++) B[(c * k + j) * L + l] *= 1.0 / A[(c * m + c) * L + l];             \
    }                                                                                                        \
}                                                                                                            \
void solve_lanes_calls_##L(const double *A0, const double *B0, double *A, double *B, double *ra, double *rb, long n) { \
    for (long r = 0; r < n; r++) {                                                                           \
        memcpy(A, A0, 12 * 12 * L * sizeof(double));                                                         \
        memcpy(B, B0, 12 * 13 * L * sizeof(double));                                                         \
        solve_lanes_##L(A, B, ra, rb);                                                                       \
    }                                                                                                        \
}                                                                                                            \
void lanes_solve_##L(double *A, double *B, double *ra, double *rb) { solve_lanes_##L(A, B, ra, rb); }

SOLVE_LANES(2)
SOLVE_LANES(4)
SOLVE_LANES(8)

#define INFO_LANES(L)                                                                                              \
static void info_lanes_##L(double *restrict A, double *restrict beta, double *restrict X,                    \
                           const double *restrict rw, const double *restrict Jw, double *restrict jw_f,      \
                           const unsigned char *restrict inl, const double *restrict ldR,                    \
                           double *restrict stats, int F) {                                                  \
    double used[L], rr[L], ldr[L];                                                                           \
    for (int i = 0; i < 144 * L; i++) A[i] = 0.0;                                                            \
    for (int i = 0; i < 12 * L; i++) beta[i] = 0.0;                                                          \
    for (int l = 0; l < L; l++) { used[l] = 0.0; rr[l] = 0.0; ldr[l] = 0.0; }                                \
    for (int f = 0; f < F; f++) {                                                                            \
        int any = 0;                                                                                         \
        for (int l = 0; l < L; l++) any |= inl[f * L + l];                                                   \
        if (!any) continue;                                                                                  \
        for (int l = 0; l < L; l++) {                                                                        \
            int m = inl[f * L + l] != 0;                                                                     \
            used[l] += m;                                                                                    \
            ldr[l] = m ? ldr[l] + ldR[f * L + l] : ldr[l];                                                   \
        }                                                                                                    \
        for (int a = 0; a < 3; a++) {                                                                        \
            for (int l = 0; l < L; l++) {                                                                    \
                double r = rw[(a * F + f) * L + l], t = rr[l] + r * r;                                       \
                rr[l] = inl[f * L + l] ? t : rr[l];                                                          \
            }                                                                                                \
            for (int b = 0; b < 12; b++)                                                                     \
                for (int l = 0; l < L; l++) jw_f[(a * 12 + b) * L + l] = Jw[((a * 12 + b) * F + f) * L + l]; \
        }                                                                                                    \
        for (int a = 0; a < 3; a++) {                                                                        \
            for (int b = 0; b < 12; b++)                                                                     \
                for (int l = 0; l < L; l++) {                                                                \
                    double t = beta[b * L + l] + jw_f[(a * 12 + b) * L + l] * rw[(a * F + f) * L + l];       \
                    beta[b * L + l] = inl[f * L + l] ? t : beta[b * L + l];                                  \
                }                                                                                            \
            for (int b = 0; b < 12; b++)                                                                     \
                for (int c = 0; c < 12; c++)                                                                 \
                    for (int l = 0; l < L; l++) {                                                            \
                        double t = A[(b * 12 + c) * L + l] + jw_f[(a * 12 + b) * L + l] * jw_f[(a * 12 + c) * L + l]; \
                        A[(b * 12 + c) * L + l] = inl[f * L + l] ? t : A[(b * 12 + c) * L + l];              \
                    }                                                                                        \
        }                                                                                                    \
    }                                                                                                        \
    for (int b = 0; b < 12; b++) {                                                                           \
        for (int l = 0; l < L; l++) X[(b * 13 + 12) * L + l] = beta[b * L + l];                              \
        for (int c = 0; c < b; c++)                                                                          \
            for (int l = 0; l < L; l++) A[(b * 12 + c) * L + l] = A[(c * 12 + b) * L + l];                  \
    }                                                                                                        \
    for (int l = 0; l < L; l++) { stats[l] = used[l]; stats[L + l] = rr[l]; stats[2 * L + l] = ldr[l]; }      \
}                                                                                                            \
void info_lanes_calls_##L(double *A, double *beta, double *X, const double *rw, const double *Jw, double *jw_f, \
                          const unsigned char *inl, const double *ldR, double *stats, long F, long n) {      \
    for (long k = 0; k < n; k++) info_lanes_##L(A, beta, X, rw, Jw, jw_f, inl, ldR, stats, (int)F);         \
}

INFO_LANES(2)
INFO_LANES(4)
INFO_LANES(8)

/* innov: per feature B = H Lp (P = Lp Lp^T), S = B B^T + Rm, its Cholesky factor, log det S and
 * z = S^-1 r (avio.filter.outliers.feature_innovations_into, Eq. 37), features last: r (3, F),
 * H (3, 12, F), P (12, 12), Rm (3, 3, F); out B (3, 12, F), z (3, F), logdet (F,); scratch Lp (12, 12),
 * S, L (3, 3, F), y (3, F). Per filter only: it already runs across a frame's F features. */
static void cholesky_one(const double *restrict S, double *restrict L, int m) {
    for (int j = 0; j < m; j++) {
        double s = S[j * m + j];
        for (int k = 0; k < j; k++) s -= L[j * m + k] * L[j * m + k];
        L[j * m + j] = sqrt(s > 1e-300 ? s : 1e-300);
        double inv = 1.0 / L[j * m + j];
        for (int i = j + 1; i < m; i++) {
            s = S[i * m + j];
            for (int k = 0; k < j; k++) s -= L[i * m + k] * L[j * m + k];
            L[i * m + j] = s * inv;
        }
        for (int i = 0; i < j; i++) L[i * m + j] = 0.0;
    }
}

static void innov_one(const double *restrict r, const double *restrict H, const double *restrict P,
                      const double *restrict Rm, double *restrict B, double *restrict z, double *restrict logdet,
                      double *restrict Lp, double *restrict S, double *restrict L, double *restrict y, int F) {
    const int m = 3, d = 12;
#define F3(A, a, b, f) A[((a) * 3 + (b)) * F + (f)]
    cholesky_one(P, Lp, d);
    for (int a = 0; a < m; a++) {
        for (int c = 0; c < d; c++)
            for (int f = 0; f < F; f++) B[(a * d + c) * F + f] = 0.0;
        for (int b = 0; b < d; b++)
            for (int c = 0; c <= b; c++) {
                double lbc = Lp[b * d + c];
                for (int f = 0; f < F; f++) B[(a * d + c) * F + f] += H[(a * d + b) * F + f] * lbc;
            }
        for (int b = 0; b <= a; b++) {
            for (int f = 0; f < F; f++) F3(S, a, b, f) = 0.0;
            for (int c = 0; c < d; c++)
                for (int f = 0; f < F; f++) F3(S, a, b, f) += B[(a * d + c) * F + f] * B[(b * d + c) * F + f];
            for (int f = 0; f < F; f++) F3(S, a, b, f) += F3(Rm, a, b, f);
        }
    }
    for (int j = 0; j < m; j++) {  /* cholesky_lanes */
        for (int f = 0; f < F; f++) {
            double s = F3(S, j, j, f);
            for (int k = 0; k < j; k++) s -= F3(L, j, k, f) * F3(L, j, k, f);
            F3(L, j, j, f) = sqrt(s > 1e-300 ? s : 1e-300);
        }
        for (int i = j + 1; i < m; i++)
            for (int f = 0; f < F; f++) {
                double s = F3(S, i, j, f);
                for (int k = 0; k < j; k++) s -= F3(L, i, k, f) * F3(L, j, k, f);
                F3(L, i, j, f) = s * (1.0 / F3(L, j, j, f));
            }
    }
    for (int f = 0; f < F; f++) logdet[f] = 0.0;  /* log_det_lanes */
    for (int i = 0; i < m; i++)
        for (int f = 0; f < F; f++) logdet[f] += log(F3(L, i, i, f));
    for (int f = 0; f < F; f++) logdet[f] *= 2.0;
    for (int i = 0; i < m; i++)  /* forward_lanes */
        for (int f = 0; f < F; f++) {
            double s = r[i * F + f];
            for (int k = 0; k < i; k++) s -= F3(L, i, k, f) * y[k * F + f];
            y[i * F + f] = s / F3(L, i, i, f);
        }
    for (int i = m - 1; i >= 0; i--)
        for (int f = 0; f < F; f++) {
            double s = y[i * F + f];
            for (int k = i + 1; k < m; k++) s -= F3(L, k, i, f) * z[k * F + f];
            z[i * F + f] = s / F3(L, i, i, f);
        }
#undef F3
}

void innov_calls(const double *r, const double *H, const double *P, const double *Rm, double *B, double *z,
                 double *logdet, double *Lp, double *S, double *L, double *y, long F, long n) {
    for (long k = 0; k < n; k++) innov_one(r, H, P, Rm, B, z, logdet, Lp, S, L, y, (int)F);
}

/* stats: after the solve, the update's NIS and pose trace and its correction for L filters (avio.filter.
 *        update.update_statistics, Eqs. 41, 44, 55b): Sig (12, 12), X (12, 13), PCt (27, 12) lanes last,
 *        beta (L, 12) and sums (L, 3) (r^T R^-1 r first) lanes first; out dx (27, L) and res (L, 2): NIS, the
 *        pose trace. (log det S stays in numba: a log per pivot.) */
#define STATS_LANES(L)                                                                                         \
void lanes_stats_##L(const double *restrict Sig, const double *restrict X, const double *restrict PCt,         \
                     const double *restrict beta, const double *restrict sums, double *restrict dx,          \
                     double *restrict res) {                                                                 \
    double nis[L], tr[L], acc[L];                                                                            \
    for (int l = 0; l < L; l++) { nis[l] = sums[l * 3]; tr[l] = 0.0; }                                       \
    for (int a = 0; a < 12; a++) {                                                                           \
        for (int l = 0; l < L; l++) acc[l] = 0.0;                                                            \
        for (int b = 0; b < 12; b++)                                                                         \
            for (int l = 0; l < L; l++) acc[l] += Sig[(a * 12 + b) * L + l] * X[(b * 13 + 12) * L + l];     \
        for (int l = 0; l < L; l++) nis[l] -= beta[l * 12 + a] * acc[l];                                     \
    }                                                                                                        \
    for (int a = 0; a < 12; a++)                                                                             \
        for (int b = 0; b < 12; b++)                                                                         \
            for (int l = 0; l < L; l++) tr[l] += X[(a * 13 + b) * L + l] * Sig[(b * 12 + a) * L + l];       \
    for (int a = 0; a < 27; a++) {                                                                           \
        for (int l = 0; l < L; l++) acc[l] = 0.0;                                                            \
        for (int b = 0; b < 12; b++)                                                                         \
            for (int l = 0; l < L; l++) acc[l] += PCt[(a * 12 + b) * L + l] * X[(b * 13 + 12) * L + l];     \
        for (int l = 0; l < L; l++) dx[a * L + l] = acc[l];                                                  \
    }                                                                                                        \
    for (int l = 0; l < L; l++) { res[l * 2] = nis[l]; res[l * 2 + 1] = tr[l]; }                             \
}

STATS_LANES(2)
STATS_LANES(4)
STATS_LANES(8)
