/* Three phases of the filter's update frame in C (benchmarks/native/bench_native.py): each per filter,
 * with the operations of the kernel's numba code in their order, and for L filters in lock-step (every
 * array lanes-last, the lane loop innermost, L a compile-time constant). Compiled with -ffp-contract=off
 * and without fast-math, so every variant gives the kernel's bits. Arrays are row-major doubles.
 *
 * pred:  P <- F P F^T + Q, F = blockdiag(Phi, I_12) (avio.filter.kernels.propagate_covariance, Eq. 18):
 *        P (27, 27), Phi (15, 15), Qd (15, 15) shared by the lanes, scratch T (15, 27), U (15, 15).
 * gain:  K = PCt X[:, :12], P -= K CP, lower triangle mirrored (avio.filter.update.update, Eq. 42):
 *        P (27, 27), PCt (27, 12), X (12, 13), CP (12, 27), scratch K (27, 12).
 * solve: A X = B by elimination with partial pivoting, a pivot per lane (avio.filter._linalg.solve):
 *        A (12, 12), B (12, 13), solved in place from fresh copies A0, B0 on every call.
 * Each *_calls function repeats its phase n times on the same arrays (the timing loop). */
#include <math.h>
#include <string.h>

#define PHI_ROWS(I, N, Q_OF, PHI, X_AT, OUT_AT, LANE)                                                        \
    for (int i = 0; i < 3; i++)                                                                              \
        for (int b = 0; b < N; b++) {                                                                        \
            LANE { double acc = Q_OF(i, b);                                                                  \
                   acc += PHI(i, i) * X_AT(i, b);                                                            \
                   for (int c = 3; c < 6; c++) acc += PHI(i, c) * X_AT(c, b);                                \
                   acc += PHI(i, 6 + i) * X_AT(6 + i, b);                                                    \
                   for (int c = 9; c < 15; c++) acc += PHI(i, c) * X_AT(c, b);                               \
                   OUT_AT(i, b) = acc; }                                                                     \
        }                                                                                                    \
    for (int a = 3; a < 6; a++)                                                                              \
        for (int b = 0; b < N; b++) {                                                                        \
            LANE { double acc = Q_OF(a, b);                                                                  \
                   for (int c = 3; c < 6; c++) acc += PHI(a, c) * X_AT(c, b);                                \
                   for (int c = 12; c < 15; c++) acc += PHI(a, c) * X_AT(c, b);                              \
                   OUT_AT(a, b) = acc; }                                                                     \
        }                                                                                                    \
    for (int a = 6; a < 9; a++)                                                                              \
        for (int b = 0; b < N; b++) {                                                                        \
            LANE { double acc = Q_OF(a, b);                                                                  \
                   for (int c = 3; c < 6; c++) acc += PHI(a, c) * X_AT(c, b);                                \
                   acc += PHI(a, a) * X_AT(a, b);                                                            \
                   for (int c = 9; c < 15; c++) acc += PHI(a, c) * X_AT(c, b);                               \
                   OUT_AT(a, b) = acc; }                                                                     \
        }                                                                                                    \
    for (int a = 9; a < 15; a++)                                                                             \
        for (int b = 0; b < N; b++) {                                                                        \
            LANE { OUT_AT(a, b) = Q_OF(a, b) + PHI(a, a) * X_AT(a, b); }                                     \
        }

/* One filter. The lane loop of the lock-step variants below wraps the same statements. */
#define ONE
#define Q0(a, b) 0.0
#define QD(a, b) Qd[(a) * 15 + (b)]
#define PHI1(a, c) Phi[(a) * 15 + (c)]
#define P_AT(a, b) P[(a) * 27 + (b)]
#define T_AT(a, b) T[(a) * 27 + (b)]
#define U_AT(a, b) U[(a) * 15 + (b)]

static void pred_one(double *restrict P, const double *restrict Phi, const double *restrict Qd,
                     double *restrict T, double *restrict U) {
    PHI_ROWS(i, 27, Q0, PHI1, P_AT, T_AT, ONE)
    for (int a = 0; a < 15; a++)
        for (int b = 0; b < 15; b++) U[a * 15 + b] = T[b * 27 + a];
    PHI_ROWS(i, 15, QD, PHI1, U_AT, P_AT, ONE)
    for (int a = 0; a < 15; a++)
        for (int b = 15; b < 27; b++) {
            P[a * 27 + b] = T[a * 27 + b];
            P[b * 27 + a] = T[a * 27 + b];
        }
}

void pred_calls(double *P, const double *Phi, const double *Qd, double *T, double *U, long n) {
    for (long k = 0; k < n; k++) pred_one(P, Phi, Qd, T, U);
}

static void gain_one(double *restrict P, const double *restrict PCt, const double *restrict X,
                     const double *restrict CP, double *restrict K) {
    for (int a = 0; a < 27; a++) {
        for (int b = 0; b < 12; b++) K[a * 12 + b] = 0.0;
        for (int c = 0; c < 12; c++) {
            double f = PCt[a * 12 + c];
            for (int b = 0; b < 12; b++) K[a * 12 + b] += f * X[c * 13 + b];
        }
    }
    for (int a = 0; a < 27; a++) {
        int n = (a / 8 + 1) * 8 < 27 ? (a / 8 + 1) * 8 : 27;  /* the kernel's rows rounded up to 8 entries */
        for (int c = 0; c < n; c++) {
            double acc = P[a * 27 + c];
            for (int b = 0; b < 12; b++) acc -= K[a * 12 + b] * CP[b * 27 + c];
            P[a * 27 + c] = acc;
        }
        for (int c = 0; c < a; c++) P[c * 27 + a] = P[a * 27 + c];
    }
}

void gain_calls(double *P, const double *PCt, const double *X, const double *CP, double *K, long n) {
    for (long k = 0; k < n; k++) gain_one(P, PCt, X, CP, K);
}

static void solve_one(double *restrict A, double *restrict B) {
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

/* L filters in lock-step. */
#define LANES(L)                                                                                             \
static void pred_lanes_##L(double *restrict P, const double *restrict Phi, const double *restrict Qd,        \
                           double *restrict T, double *restrict U) {                                         \
    enum { NL = L };  /* the lane count in the PHI_ROWS macros' index expressions */                         \
    PHI_ROWS(i, 27, Q0, PHIL, PL_AT, TL_AT, for (int l = 0; l < L; l++))                                     \
    for (int a = 0; a < 15; a++)                                                                             \
        for (int b = 0; b < 15; b++)                                                                         \
            for (int l = 0; l < L; l++) U[(a * 15 + b) * L + l] = T[(b * 27 + a) * L + l];                  \
    PHI_ROWS(i, 15, QD, PHIL, UL_AT, PL_AT, for (int l = 0; l < L; l++))                                     \
    for (int a = 0; a < 15; a++)                                                                             \
        for (int b = 15; b < 27; b++)                                                                        \
            for (int l = 0; l < L; l++) {                                                                    \
                P[(a * 27 + b) * L + l] = T[(a * 27 + b) * L + l];                                           \
                P[(b * 27 + a) * L + l] = T[(a * 27 + b) * L + l];                                           \
            }                                                                                                \
}                                                                                                            \
void pred_lanes_calls_##L(double *P, const double *Phi, const double *Qd, double *T, double *U, long n) {    \
    for (long k = 0; k < n; k++) pred_lanes_##L(P, Phi, Qd, T, U);                                           \
}                                                                                                            \
static void gain_lanes_##L(double *restrict P, const double *restrict PCt, const double *restrict X,         \
                           const double *restrict CP, double *restrict K) {                                  \
    for (int a = 0; a < 27; a++) {                                                                           \
        for (int b = 0; b < 12; b++)                                                                         \
            for (int l = 0; l < L; l++) K[(a * 12 + b) * L + l] = 0.0;                                       \
        for (int c = 0; c < 12; c++)                                                                         \
            for (int b = 0; b < 12; b++)                                                                     \
                for (int l = 0; l < L; l++) K[(a * 12 + b) * L + l] += PCt[(a * 12 + c) * L + l] * X[(c * 13 + b) * L + l]; \
    }                                                                                                        \
    for (int a = 0; a < 27; a++) {  /* the lower triangle: the rest is the mirror's */                        \
        for (int c = 0; c <= a; c++) {                                                                       \
            double acc[L];                                                                                   \
            for (int l = 0; l < L; l++) acc[l] = P[(a * 27 + c) * L + l];                                    \
            for (int b = 0; b < 12; b++)                                                                     \
                for (int l = 0; l < L; l++) acc[l] -= K[(a * 12 + b) * L + l] * CP[(b * 27 + c) * L + l];    \
            for (int l = 0; l < L; l++) P[(a * 27 + c) * L + l] = acc[l];                                    \
        }                                                                                                    \
        for (int c = 0; c < a; c++)                                                                          \
            for (int l = 0; l < L; l++) P[(c * 27 + a) * L + l] = P[(a * 27 + c) * L + l];                  \
    }                                                                                                        \
}                                                                                                            \
void gain_lanes_calls_##L(double *P, const double *PCt, const double *X, const double *CP, double *K, long n) { \
    for (long k = 0; k < n; k++) gain_lanes_##L(P, PCt, X, CP, K);                                           \
}                                                                                                            \
static void solve_lanes_##L(double *restrict A, double *restrict B, double *restrict ra, double *restrict rb) { \
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
}

#define PHIL(a, c) Phi[((a) * 15 + (c)) * NL + l]
#define PL_AT(a, b) P[((a) * 27 + (b)) * NL + l]
#define TL_AT(a, b) T[((a) * 27 + (b)) * NL + l]
#define UL_AT(a, b) U[((a) * 15 + (b)) * NL + l]

LANES(4)
LANES(8)

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
