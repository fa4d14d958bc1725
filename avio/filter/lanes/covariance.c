/* The covariance phases of the filter's update frame in C (benchmarks/native/bench_native.py), each per
 * filter with the operations of the kernel's numba code in their order, and for L filters in lock-step
 * (every array lanes-last, the lane loop innermost, L a compile-time constant). Compiled with
 * -ffp-contract=off and without fast-math, so every variant gives the kernel's bits. Arrays are row-major
 * doubles. A lane's zero of a sparse factor (C, Phi) keeps its sum through a select.
 *
 * pred:  P <- F P F^T + Q, F = blockdiag(Phi, I_12) (avio.filter.kernels.propagate_covariance, Eq. 18):
 *        P (27, 27), Phi (15, 15), Qd (15, 15) shared by the lanes, scratch T (15, 27), U (15, 15).
 * proj:  CP = C P, PCt its transpose, Sig = C P C^T symmetrised (avio.filter.update.update, Eq. 37).
 * gain:  K = PCt X[:, :12], P -= K CP, lower triangle mirrored (avio.filter.update.update, Eq. 42):
 *        P (27, 27), PCt (27, 12), X (12, 13), CP (12, 27), scratch K (27, 12).
 * Each *_calls function repeats its phase n times on the same arrays (the timing loop). */
#include <string.h>

/* each phase is inlined into both its callers: the kernel's entry (lanes_*) and the benchmark's loop (*_calls) */
#define INLINE static inline __attribute__((always_inline))

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

INLINE void pred_one(double *restrict P, const double *restrict Phi, const double *restrict Qd,
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

INLINE void gain_one(double *restrict P, const double *restrict PCt, const double *restrict X,
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

/* proj:  CP = C P (C's zeros skipped, as avio.filter._linalg.matmul), PCt its transpose, Sig = C PCt
 *        symmetrised (avio.filter.update.update, Eq. 37): C (12, 27), P (27, 27); out CP (12, 27),
 *        PCt (27, 12), Sig (12, 12). A lane's zero of C keeps its sum through a select; a column of C
 *        that is zero in every lane is skipped. */
static void matmul_skip(const double *restrict A, const double *restrict B, double *restrict out, int ncols) {
    /* out (12, ncols) = A (12, 27) B (27, ncols), A's zeros skipped (avio.filter._linalg.matmul) */
    for (int i = 0; i < 12; i++) {
        for (int j = 0; j < ncols; j++) out[i * ncols + j] = 0.0;
        for (int k = 0; k < 27; k++) {
            double a = A[i * 27 + k];
            if (a != 0.0)
                for (int j = 0; j < ncols; j++) out[i * ncols + j] += a * B[k * ncols + j];
        }
    }
}

INLINE void proj_one(const double *restrict C, const double *restrict P, double *restrict CP,
                     double *restrict PCt, double *restrict Sig) {
    matmul_skip(C, P, CP, 27);
    for (int a = 0; a < 27; a++)
        for (int b = 0; b < 12; b++) PCt[a * 12 + b] = CP[b * 27 + a];
    matmul_skip(C, PCt, Sig, 12);
    for (int a = 0; a < 12; a++)
        for (int b = 0; b < a; b++) {
            double s = 0.5 * (Sig[a * 12 + b] + Sig[b * 12 + a]);
            Sig[a * 12 + b] = s;
            Sig[b * 12 + a] = s;
        }
}

void proj_calls(const double *C, const double *P, double *CP, double *PCt, double *Sig, long n) {
    for (long k = 0; k < n; k++) proj_one(C, P, CP, PCt, Sig);
}

/* L filters in lock-step. */
#define COV_LANES(L)                                                                                             \
INLINE void pred_lanes_##L(double *restrict P, const double *restrict Phi, const double *restrict Qd,        \
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
void lanes_pred_##L(double *P, const double *Phi, const double *Qd, double *T, double *U) {                  \
    pred_lanes_##L(P, Phi, Qd, T, U);  /* the kernel's entry (avio/filter/lanes/block.py) */                 \
}                                                                                                            \
INLINE void gain_lanes_##L(double *restrict P, const double *restrict PCt, const double *restrict X,         \
                           const double *restrict CP, double *restrict K) {                                  \
    for (int a = 0; a < 27; a++) {                                                                           \
        for (int b = 0; b < 12; b++)                                                                         \
            for (int l = 0; l < L; l++) K[(a * 12 + b) * L + l] = 0.0;                                       \
        for (int c = 0; c < 12; c++)                                                                         \
            for (int b = 0; b < 12; b++)                                                                     \
                for (int l = 0; l < L; l++)                                                          \
                    K[(a * 12 + b) * L + l] += PCt[(a * 12 + c) * L + l] * X[(c * 13 + b) * L + l];    \
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
void lanes_gain_##L(double *P, const double *PCt, const double *X, const double *CP, double *K) {            \
    gain_lanes_##L(P, PCt, X, CP, K);                                                                        \
}

#define PHIL(a, c) Phi[((a) * 15 + (c)) * NL + l]
#define PL_AT(a, b) P[((a) * 27 + (b)) * NL + l]
#define TL_AT(a, b) T[((a) * 27 + (b)) * NL + l]
#define UL_AT(a, b) U[((a) * 15 + (b)) * NL + l]

COV_LANES(2)
COV_LANES(4)
COV_LANES(8)

#define PROJ_LANES(L)                                                                                        \
static void matmul_lanes_##L(const double *restrict A, const double *restrict B, double *restrict out,       \
                             int ncols) {                                                                    \
    for (int i = 0; i < 12; i++) {                                                                           \
        for (int j = 0; j < ncols * L; j++) out[i * ncols * L + j] = 0.0;                                    \
        for (int k = 0; k < 27; k++) {                                                                       \
            int nz = 0;                                                                                      \
            double w[L];                                                                                     \
            for (int l = 0; l < L; l++) { w[l] = A[(i * 27 + k) * L + l]; nz |= w[l] != 0.0; }               \
            if (!nz) continue;  /* a column zero in every lane */                                            \
            for (int j = 0; j < ncols; j++)                                                                  \
                for (int l = 0; l < L; l++) {                                                                \
                    double old = out[(i * ncols + j) * L + l], t = old + w[l] * B[(k * ncols + j) * L + l];  \
                    out[(i * ncols + j) * L + l] = w[l] != 0.0 ? t : old;                                    \
                }                                                                                            \
        }                                                                                                    \
    }                                                                                                        \
}                                                                                                            \
INLINE void proj_lanes_##L(const double *restrict C, const double *restrict P, double *restrict CP,          \
                           double *restrict PCt, double *restrict Sig) {                                     \
    matmul_lanes_##L(C, P, CP, 27);                                                                          \
    for (int a = 0; a < 27; a++)                                                                             \
        for (int b = 0; b < 12; b++)                                                                         \
            for (int l = 0; l < L; l++) PCt[(a * 12 + b) * L + l] = CP[(b * 27 + a) * L + l];                \
    matmul_lanes_##L(C, PCt, Sig, 12);                                                                       \
    for (int a = 0; a < 12; a++)                                                                             \
        for (int b = 0; b < a; b++)                                                                          \
            for (int l = 0; l < L; l++) {                                                                    \
                double s = 0.5 * (Sig[(a * 12 + b) * L + l] + Sig[(b * 12 + a) * L + l]);                    \
                Sig[(a * 12 + b) * L + l] = s;                                                               \
                Sig[(b * 12 + a) * L + l] = s;                                                               \
            }                                                                                                \
}                                                                                                            \
void proj_lanes_calls_##L(const double *C, const double *P, double *CP, double *PCt, double *Sig, long n) {  \
    for (long k = 0; k < n; k++) proj_lanes_##L(C, P, CP, PCt, Sig);                                         \
}                                                                                                            \
void lanes_proj_##L(const double *C, const double *P, double *CP, double *PCt, double *Sig) {                \
    proj_lanes_##L(C, P, CP, PCt, Sig);                                                                      \
}

PROJ_LANES(2)
PROJ_LANES(4)
PROJ_LANES(8)

/* The kernel's lock-step phases that have no per-filter benchmark variant (avio/filter/lanes/block.py):
 * slide:  the window's move of L filters (avio.filter.kernels.slide, Eq. 50), P (27, 27) in place from J
 *         (6, 15) the new clone's Jacobian; scratch NR (6, 27). A lane's zero of J keeps its sum (a select).
 * finite: bad[l] = 1 where lane l's P has a non-finite entry (the first test of avio.filter.kernels._bad). */
#define SLIDE_LANES(L)                                                                                           \
void lanes_slide_##L(double *restrict P, const double *restrict J, double *restrict NR) {                      \
    for (int a = 0; a < 6; a++) {                                                                            \
        for (int b = 0; b < 27 * L; b++) NR[a * 27 * L + b] = 0.0;                                           \
        for (int c = 0; c < 15; c++) {                                                                       \
            int nz = 0;                                                                                      \
            double f[L];                                                                                     \
            for (int l = 0; l < L; l++) { f[l] = J[(a * 15 + c) * L + l]; nz |= f[l] != 0.0; }               \
            if (!nz) continue;  /* a column zero in every lane */                                            \
            for (int b = 0; b < 27; b++)                                                                     \
                for (int l = 0; l < L; l++) {                                                                \
                    double old = NR[(a * 27 + b) * L + l], t = old + f[l] * P[(c * 27 + b) * L + l];         \
                    NR[(a * 27 + b) * L + l] = f[l] != 0.0 ? t : old;                                        \
                }                                                                                            \
        }                                                                                                    \
        for (int b = 15; b < 21; b++)                                                                        \
            for (int l = 0; l < L; l++) NR[(a * 27 + b) * L + l] = NR[(a * 27 + b + 6) * L + l];             \
    }                                                                                                        \
    /* clone k-1 (rows and columns 21:27) moves to 15:21, each entry read before it is written */            \
    for (int a = 0; a < 15; a++)                                                                             \
        for (int b = 15; b < 21; b++)                                                                        \
            for (int l = 0; l < L; l++) P[(a * 27 + b) * L + l] = P[(a * 27 + b + 6) * L + l];               \
    for (int a = 15; a < 21; a++) {                                                                          \
        for (int b = 0; b < 15; b++)                                                                         \
            for (int l = 0; l < L; l++) P[(a * 27 + b) * L + l] = P[((a + 6) * 27 + b) * L + l];             \
        for (int b = 15; b < 21; b++)                                                                        \
            for (int l = 0; l < L; l++) P[(a * 27 + b) * L + l] = P[((a + 6) * 27 + b + 6) * L + l];         \
    }                                                                                                        \
    for (int a = 0; a < 6; a++) {                                                                            \
        for (int b = 0; b < 21; b++)                                                                         \
            for (int l = 0; l < L; l++) {                                                                    \
                P[((21 + a) * 27 + b) * L + l] = NR[(a * 27 + b) * L + l];                                   \
                P[(b * 27 + 21 + a) * L + l] = NR[(a * 27 + b) * L + l];                                     \
            }                                                                                                \
        for (int b = 0; b < 6; b++) {                                                                        \
            double acc[L];                                                                                   \
            for (int l = 0; l < L; l++) acc[l] = 0.0;                                                        \
            for (int c = 0; c < 15; c++)                                                                     \
                for (int l = 0; l < L; l++) acc[l] += NR[(a * 27 + c) * L + l] * J[(b * 15 + c) * L + l];    \
            for (int l = 0; l < L; l++) P[((21 + a) * 27 + 21 + b) * L + l] = acc[l];                        \
        }                                                                                                    \
    }                                                                                                        \
}                                                                                                            \
void lanes_finite_##L(const double *restrict P, unsigned char *restrict bad) {                                 \
    unsigned char nf[L] = {0};                                                                               \
    for (int e = 0; e < 27 * 27; e++)  /* x - x is NaN exactly for inf and NaN */                            \
        for (int l = 0; l < L; l++) nf[l] |= (P[e * L + l] - P[e * L + l]) != 0.0;                           \
    for (int l = 0; l < L; l++) bad[l] = nf[l];                                                              \
}

SLIDE_LANES(2)
SLIDE_LANES(4)
SLIDE_LANES(8)
