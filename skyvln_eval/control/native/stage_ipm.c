/* The MPC's stage-wise QP solved by a primal-dual interior point method (Mehrotra's
 * predictor-corrector) with one Riccati factorisation per iteration (see stage_ipm.py).
 *
 * The QP (control.stage_qp, linearised at a guess), stages k = 0 .. N-1 and a terminal one:
 *
 *   min  sum_k 1/2 y_k' H_k y_k + h_k' y_k  +  1/2 z_N' Q_N z_N + q_N' z_N,   y_k = [v_k; z_k]
 *   s.t. x_{k+1} = Fx_k x_k + Fu_k u_k + f_k        (the model, linearised)
 *        p_{k+1} = u_k                              (the input memory)
 *        lv_k <= v_k <= uv_k                        (a side whose bound is not finite is absent)
 *        lg_k <= D_k v_k + C_k z_k <= ug_k
 *        z_0 = the measured state and applied input (fixed)
 *
 * with the augmented state z = [x (SX), p (SU): the previous input] and the stage controls
 * v = [u (SU), s (SS): slacks]. Together "z_{k+1} = M_k y_k + f_k" with M = [Fu 0 Fx 0; I 0 0 0];
 * only the model's blocks Fx, Fu are ever multiplied, never M's zeros and identity.
 *
 * Each stage works in vectors of LY numbers (y padded with zeros to a multiple of 4) and
 * matrices of LY x LY, column-major, so that the loops, which all have compile-time trip
 * counts (-D SN, SX, SU, SS, SG), run on whole SIMD registers. The Riccati recursion keeps
 * each stage's matrix W = H + M' P_{k+1} M + barrier terms in one array: a Cholesky of its
 * control columns, then their Schur complement, which is the cost-to-go P_k, in its state
 * block. No globals, no allocation: the caller passes the work area, so calls with distinct
 * work areas may run in parallel (Python calls it with the interpreter's lock released).
 */
#include <math.h>
#include <stddef.h>
#include <string.h>

#if !defined(SN) || !defined(SX) || !defined(SU) || !defined(SS) || !defined(SG)
#error "compile with -DSN=<horizon> -DSX=<states> -DSU=<inputs> -DSS=<slacks> -DSG=<rows>"
#endif

#define NV (SU + SS)             /* stage controls */
#define NZ (SX + SU)             /* augmented state */
#define PAD4(n) (((n) + 3) / 4 * 4)
#define ZOFF PAD4(NV)            /* where z starts in a stage vector y = [v; 0; z; 0] */
#define LZ PAD4(NZ)              /* a state vector's padded length */
#define LY (ZOFF + LZ)           /* a stage vector's padded length */
#define LM PAD4(ZOFF + SX)       /* the rows of a stage vector the model map can touch */
#define LX PAD4(SX)              /* a model state's padded length */
#define INLINE static inline __attribute__((always_inline))
/* vec4 helpers are always inlined, so no vec4 crosses a call: the ABI note does not apply */
#pragma GCC diagnostic ignored "-Wpsabi"
/* Four doubles, loaded and stored without an alignment requirement. */
typedef double vec4 __attribute__((vector_size(32)));
#define VMAX(a, b) ((a) > (b) ? (a) : (b))
#define VMIN(a, b) ((a) < (b) ? (a) : (b))
/* x86-64: the entry point (and everything inlined into it) built for AVX2 + FMA and for the
 * baseline; the loader picks one for the CPU. Elsewhere, the compiler's default. */
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define CPU_VARIANTS __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define CPU_VARIANTS
#endif

/* One stage's data, laid out as the QP data function writes it (column-major). */
typedef struct {
    double Fx[SX * SX], Fu[SX * SU], f[SX];
    double C[SG * NZ], D[SG * NV], lg[SG], ug[SG];
    double lv[NV], uv[NV], r[NV], q[NZ];
} Stage;

typedef struct {
    Stage stage[SN];
    double qN[NZ];
} Problem;

/* The constant Hessian: [R S; S' Q] on [v; z] per stage, then Q_N. */
typedef struct {
    struct {
        double R[NV * NV], S[NV * NZ], Q[NZ * NZ];
    } stage[SN];
    double QN[NZ * NZ];
} Hessian;

/* One family of one-sided inequalities of a stage: slacks t, multipliers lam, residuals
 * c(y) - t, barrier weights lam / t, right-hand sides and steps; m is 1 where the bound
 * exists (an absent one keeps t = 1, lam = 0 and takes no part). */
#define SIDE(n)                                                                         \
    struct {                                                                            \
        double t[n], lam[n], m[n], rc[n], sigma[n], g[n], dt[n], dlam[n];               \
    }

/* Apply M(side, length) to each family of inequalities of a stage. */
#define EACH_SIDE(M) M(lv, NV) M(uv, NV) M(lg, SG) M(ug, SG)

typedef struct {
    double H[LY * LY];       /* the stage's Hessian, padded */
    double G[SG][LY];        /* the general rows [D C] as stage vectors */
    double MT[SX][LY];       /* rows of the model map [Fu 0 Fx 0] as stage vectors */
    double Fx[SX][LX], Fu[SU][LX]; /* the model's columns, padded */
    double h[LY];            /* [r; q] */
    double W[LY * LY];       /* Newton matrix; factorised: L11 | L21 in the control columns,
                              * the cost-to-go P in the state block */
    double y[LY], pi[LZ];    /* iterate: stage variables, multipliers of z_{k+1} = M y + f */
    double ry[LY], rb[LZ];   /* residuals: stationarity, dynamics */
    double gy[LY];           /* right-hand side of the Riccati pass */
    double p[LZ];            /* cost-to-go's linear term, for this stage's state */
    double ly[NV];           /* L11^{-1} (control part of the right-hand side + future) */
    double dy[LY], dpi[LZ];  /* step */
    SIDE(NV) lv, uv;
    SIDE(SG) lg, ug;
} StageWork;

typedef struct {
    StageWork s[SN + 1]; /* s[SN]: the terminal state (its z in y, P in W) */
    double count;        /* inequalities present */
} Work;

/* ---- vectors of fixed length ---- */

INLINE vec4 load4(const double *p) {
    vec4 v;
    memcpy(&v, p, sizeof v);
    return v;
}

INLINE void store4(double *p, vec4 v) { memcpy(p, &v, sizeof v); }

INLINE double dot_y(const double *restrict a, const double *restrict b) {
    vec4 acc = {0.0, 0.0, 0.0, 0.0};
    for (int i = 0; i < LY; i += 4) acc += load4(a + i) * load4(b + i);
    return (acc[0] + acc[1]) + (acc[2] + acc[3]);
}

/* y += sum_{l < n} a[l * a_stride] * X[l * x_stride + i], i < LY (gemv_y) or LZ (gemv_z):
 * y stays in registers across the sum (an axpy per term would store and reload it). */
#define GEMV(name, LEN)                                                                  \
    INLINE void name(double *restrict y, const double *restrict X, int x_stride,        \
                     const double *restrict a, int a_stride, int n) {                    \
        vec4 acc[LEN / 4];                                                               \
        for (int i = 0; i < LEN / 4; ++i) acc[i] = load4(y + 4 * i);                     \
        for (int l = 0; l < n; ++l) {                                                    \
            const double al = a[l * a_stride];                                           \
            for (int i = 0; i < LEN / 4; ++i) acc[i] += al * load4(X + l * x_stride + 4 * i); \
        }                                                                                \
        for (int i = 0; i < LEN / 4; ++i) store4(y + 4 * i, acc[i]);                     \
    }
GEMV(gemv_y, LY)
GEMV(gemv_z, LZ)
GEMV(gemv_m, LM) /* M' times a vector: M's rows have nothing past the states x */
GEMV(gemv_x, LX) /* the model's x part: Fx and Fu columns */

/* P's column j (the state block of W). */
#define PCOL(W, j) ((W) + ZOFF + (ZOFF + (j)) * LY)

/* x = L^{-1} x, x = L^{-T} x with L the lower NV x NV block of W (leading dimension LY). */
INLINE void lower_solve(const double *L, double *x) {
    for (int i = 0; i < NV; ++i) {
        double a = x[i];
        for (int k = 0; k < i; ++k) a -= L[i + k * LY] * x[k];
        x[i] = a / L[i + i * LY];
    }
}

INLINE void upper_solve(const double *L, double *x) {
    for (int i = NV - 1; i >= 0; --i) {
        double a = x[i];
        for (int k = i + 1; k < NV; ++k) a -= L[k + i * LY] * x[k];
        x[i] = a / L[i + i * LY];
    }
}

/* ---- set-up: the stage data in padded form ---- */

INLINE void pack(const Problem *pb, const Hessian *H, Work *w) {
    for (int k = 0; k <= SN; ++k) {
        StageWork *s = &w->s[k];
        memset(s->H, 0, sizeof s->H);
        memset(s->h, 0, sizeof s->h);
        if (k == SN) {
            for (int j = 0; j < NZ; ++j)
                for (int i = 0; i < NZ; ++i) s->H[ZOFF + i + (ZOFF + j) * LY] = H->QN[i + j * NZ];
            for (int i = 0; i < NZ; ++i) s->h[ZOFF + i] = pb->qN[i];
            break;
        }
        const Stage *st = &pb->stage[k];
        for (int j = 0; j < NV; ++j)
            for (int i = 0; i < NV; ++i) s->H[i + j * LY] = H->stage[k].R[i + j * NV];
        for (int j = 0; j < NZ; ++j)
            for (int i = 0; i < NV; ++i) {
                double a = H->stage[k].S[i + j * NV];
                s->H[i + (ZOFF + j) * LY] = a;
                s->H[ZOFF + j + i * LY] = a;
            }
        for (int j = 0; j < NZ; ++j)
            for (int i = 0; i < NZ; ++i) s->H[ZOFF + i + (ZOFF + j) * LY] = H->stage[k].Q[i + j * NZ];
        for (int i = 0; i < NV; ++i) s->h[i] = st->r[i];
        for (int i = 0; i < NZ; ++i) s->h[ZOFF + i] = st->q[i];
        memset(s->G, 0, sizeof s->G);
        for (int l = 0; l < SG; ++l) {
            for (int j = 0; j < NV; ++j) s->G[l][j] = st->D[l + j * SG];
            for (int j = 0; j < NZ; ++j) s->G[l][ZOFF + j] = st->C[l + j * SG];
        }
        memset(s->Fx, 0, sizeof s->Fx);
        memset(s->Fu, 0, sizeof s->Fu);
        for (int j = 0; j < SX; ++j) memcpy(s->Fx[j], st->Fx + j * SX, sizeof(double) * SX);
        for (int j = 0; j < SU; ++j) memcpy(s->Fu[j], st->Fu + j * SX, sizeof(double) * SX);
        memset(s->MT, 0, sizeof s->MT);
        for (int l = 0; l < SX; ++l) {
            for (int j = 0; j < SU; ++j) s->MT[l][j] = st->Fu[l + j * SX];
            for (int j = 0; j < SX; ++j) s->MT[l][ZOFF + j] = st->Fx[l + j * SX];
        }
    }
}

/* ---- the interior point method ---- */

/* The residuals c(y) - t of a row's lower and upper sides (value g, bounds st->low and
 * st->up), their complementarity products, folded into ri, rm and sum. */
#define PAIR_RESIDUALS(low, up, i, value)                                                  \
    {                                                                                      \
        const double g = (value);                                                          \
        double a = s->low.m[i] != 0.0 ? g - st->low[i] - s->low.t[i] : 0.0;               \
        double b = s->up.m[i] != 0.0 ? st->up[i] - g - s->up.t[i] : 0.0;                  \
        s->low.rc[i] = a;                                                                  \
        s->up.rc[i] = b;                                                                   \
        ri = VMAX(ri, VMAX(fabs(a), fabs(b)));                                             \
        double ca = s->low.t[i] * s->low.lam[i], cb = s->up.t[i] * s->up.lam[i];          \
        rm = VMAX(rm, VMAX(ca, cb));                                                       \
        sum += ca + cb;                                                                    \
    }

/* Residuals at the iterate; res = [stationarity, dynamics, inequalities, max t lam, a sum
 * that is not finite if any residual is not];
 * *mu = mean t lam. */
INLINE void residuals(const Problem *pb, Work *w, double *res, double *mu) {
    double rs = 0.0, re = 0.0, ri = 0.0, rm = 0.0, sum = 0.0, nan_check = 0.0;
    for (int k = 0; k < SN; ++k) {
        const Stage *st = &pb->stage[k];
        StageWork *s = &w->s[k], *next = &w->s[k + 1];
        /* H y + h + M' pi - [0; pi_{k-1}] - box and row multipliers */
        double *ry = s->ry;
        memcpy(ry, s->h, sizeof s->h);
        gemv_y(ry, s->H, LY, s->y, 1, LY);
        gemv_m(ry, s->MT[0], LY, s->pi, 1, SX);
        for (int i = 0; i < SU; ++i) ry[i] += s->pi[SX + i];
        if (k > 0)
            for (int i = 0; i < NZ; ++i) ry[ZOFF + i] -= w->s[k - 1].pi[i];
        for (int i = 0; i < NV; ++i) ry[i] -= s->lv.lam[i] - s->uv.lam[i];
        double dlam[SG];
        for (int l = 0; l < SG; ++l) dlam[l] = s->ug.lam[l] - s->lg.lam[l];
        gemv_y(ry, s->G[0], LY, dlam, 1, SG);
        const int stationary = k > 0 ? LY : NV; /* stage 0's state is fixed */
        for (int i = 0; i < stationary; ++i) rs = VMAX(rs, fabs(ry[i]));
        nan_check += ry[0];
        /* z_{k+1} residual: [Fx x + Fu u + f - x+; u - p+] */
        double *rb = s->rb;
        for (int i = 0; i < SX; ++i) rb[i] = st->f[i] - next->y[ZOFF + i];
        gemv_x(rb, s->Fx[0], LX, s->y + ZOFF, 1, SX);
        gemv_x(rb, s->Fu[0], LX, s->y, 1, SU);
        for (int i = 0; i < SU; ++i) rb[SX + i] = s->y[i] - next->y[ZOFF + SX + i];
        for (int i = 0; i < NZ; ++i) re = VMAX(re, fabs(rb[i]));
        /* inequalities c(y) - t and complementarity */
        for (int i = 0; i < NV; ++i) PAIR_RESIDUALS(lv, uv, i, s->y[i])
        for (int l = 0; l < SG; ++l) PAIR_RESIDUALS(lg, ug, l, dot_y(s->G[l], s->y))
    }
    StageWork *last = &w->s[SN];
    double *ry = last->ry;
    memcpy(ry, last->h, sizeof last->h);
    gemv_y(ry, last->H + ZOFF * LY, LY, last->y + ZOFF, 1, NZ);
    for (int i = 0; i < NZ; ++i) {
        ry[ZOFF + i] -= w->s[SN - 1].pi[i];
        rs = VMAX(rs, fabs(ry[ZOFF + i]));
    }
    res[0] = rs;
    res[1] = re;
    res[2] = ri;
    res[3] = rm;
    res[4] = nan_check + re + ri + rm + sum;
    *mu = sum / w->count;
}

/* The Riccati factorisation of the Newton matrix with barrier weights sigma = lam / t.
 * Returns 0 if a control block is not positive definite. */
INLINE int factorize(Work *w) {
    StageWork *last = &w->s[SN];
    memcpy(last->W, last->H, sizeof last->W); /* P_N = Q_N in the state block */
    for (int k = SN - 1; k >= 0; --k) {
        StageWork *s = &w->s[k];
        const double *Wn = w->s[k + 1].W;
        double *W = s->W;
        memcpy(W, s->H, sizeof s->H);
        for (int i = 0; i < NV; ++i) W[i + i * LY] += s->lv.sigma[i] + s->uv.sigma[i];
        double sg[SG];
        for (int l = 0; l < SG; ++l) sg[l] = s->lg.sigma[l] + s->ug.sigma[l];
        for (int j = 0; j < LY; ++j) {
            if (j >= NV && j < ZOFF) continue; /* padding */
            double *Wj = W + j * LY;
            /* G' diag(sg) G */
            double a[SG];
            int any = 0;
            for (int l = 0; l < SG; ++l) {
                a[l] = sg[l] * s->G[l][j];
                any |= a[l] != 0.0;
            }
            if (any) gemv_y(Wj, s->G[0], LY, a, 1, SG);
            /* M' P M on the u and x columns: T = P M_j, then M' T */
            const int u = j < SU, x = j >= ZOFF && j < ZOFF + SX;
            if (!u && !x) continue;
            double T[LZ];
            if (u)
                memcpy(T, PCOL(Wn, SX + j), sizeof T);
            else
                memset(T, 0, sizeof T);
            gemv_z(T, PCOL(Wn, 0), LY, &s->MT[0][j], LY, SX);
            gemv_m(Wj, s->MT[0], LY, T, 1, SX);
            for (int i = 0; i < SU; ++i) Wj[i] += T[SX + i];
        }
        /* Cholesky of the control columns (whole columns: entries above the diagonal are
         * overwritten and never read again) */
        for (int c = 0; c < NV; ++c) {
            double *Wc = W + c * LY;
            double a[NV];
            for (int j = 0; j < c; ++j) a[j] = -W[c + j * LY];
            gemv_y(Wc, W, LY, a, 1, c);
            double d = Wc[c];
            if (!(d > 0.0)) return 0;
            double inv = 1.0 / sqrt(d);
            for (int i = 0; i < LY; ++i) Wc[i] *= inv;
        }
        if (k == 0) break; /* z_0 is fixed: no cost-to-go needed */
        /* P_k = W_zz - L21 L21' (the state block) */
        for (int j = ZOFF; j < ZOFF + NZ; ++j) {
            double a[NV];
            for (int c = 0; c < NV; ++c) a[c] = -W[j + c * LY];
            gemv_z(W + j * LY + ZOFF, W + ZOFF, LY, a, 1, NV);
        }
    }
    return 1;
}

/* Right-hand side of one solve: (r_m + lam rc) / t per inequality with
 * r_m = t lam - sigma_mu (+ dt dlam of the predictor in the corrector), then
 * g = r_y + box terms + G' (g_lower - g_upper). */
#define SIDE_RHS(side, n)                                                                  \
    for (int i = 0; i < n; ++i) {                                                          \
        double rm = s->side.t[i] * s->side.lam[i] - sigma_mu;                               \
        if (corrector) rm += s->side.dt[i] * s->side.dlam[i];                              \
        s->side.g[i] = s->side.m[i] * (rm + s->side.lam[i] * s->side.rc[i]) / s->side.t[i]; \
    }

INLINE void right_hand_side(Work *w, double sigma_mu, int corrector) {
    for (int k = 0; k < SN; ++k) {
        StageWork *s = &w->s[k];
        EACH_SIDE(SIDE_RHS)
        memcpy(s->gy, s->ry, sizeof s->gy);
        for (int i = 0; i < NV; ++i) s->gy[i] += s->lv.g[i] - s->uv.g[i];
        double dg[SG];
        for (int l = 0; l < SG; ++l) dg[l] = s->lg.g[l] - s->ug.g[l];
        gemv_y(s->gy, s->G[0], LY, dg, 1, SG);
    }
    memcpy(w->s[SN].gy, w->s[SN].ry, sizeof w->s[SN].gy);
}

/* The Newton step: a backward pass for the cost-to-go's linear terms, a forward pass for
 * the primal step and the multipliers, then the slacks' and multipliers' steps. */
INLINE void newton_step(Work *w, int multipliers) {
    memcpy(w->s[SN].p, w->s[SN].gy + ZOFF, sizeof(double) * LZ);
    for (int k = SN - 1; k >= 0; --k) {
        StageWork *s = &w->s[k], *next = &w->s[k + 1];
        /* rho = P_{k+1} rb + p_{k+1}; then gy + M' rho */
        double rho[LZ];
        memcpy(rho, next->p, sizeof rho);
        gemv_z(rho, PCOL(next->W, 0), LY, s->rb, 1, NZ);
        double g[LY];
        memcpy(g, s->gy, sizeof g);
        gemv_m(g, s->MT[0], LY, rho, 1, SX);
        for (int i = 0; i < SU; ++i) g[i] += rho[SX + i];
        for (int i = 0; i < NV; ++i) s->ly[i] = g[i];
        lower_solve(s->W, s->ly);
        if (k == 0) break;
        /* p_k = g_z - L21 ly */
        memcpy(s->p, g + ZOFF, sizeof s->p);
        double minus_ly[NV];
        for (int c = 0; c < NV; ++c) minus_ly[c] = -s->ly[c];
        gemv_z(s->p, s->W + ZOFF, LY, minus_ly, 1, NV);
    }
    memset(w->s[0].dy + ZOFF, 0, sizeof(double) * LZ); /* z_0 is fixed */
    for (int k = 0; k < SN; ++k) {
        StageWork *s = &w->s[k], *next = &w->s[k + 1];
        /* dv = -L11^{-T} (L21' dz + ly) */
        double dv[NV];
        for (int c = 0; c < NV; ++c) {
            const double *L = s->W + c * LY + ZOFF;
            double a = s->ly[c];
            for (int i = 0; i < LZ; ++i) a += L[i] * s->dy[ZOFF + i];
            dv[c] = -a;
        }
        upper_solve(s->W, dv);
        memcpy(s->dy, dv, sizeof dv);
        /* dz_{k+1} = M dy + rb */
        double *dz = next->dy + ZOFF;
        memcpy(dz, s->rb, sizeof(double) * LZ);
        gemv_x(dz, s->Fx[0], LX, s->dy + ZOFF, 1, SX);
        gemv_x(dz, s->Fu[0], LX, s->dy, 1, SU);
        for (int i = 0; i < SU; ++i) dz[SX + i] += s->dy[i];
        /* dpi = P_{k+1} dz_{k+1} + p_{k+1} */
        if (multipliers) {
            memcpy(s->dpi, next->p, sizeof s->dpi);
            gemv_z(s->dpi, PCOL(next->W, 0), LY, dz, 1, NZ);
        }
        /* dt = +-G dy + rc, dlam = -g -+ sigma G dy */
        for (int i = 0; i < NV; ++i) {
            double gd = s->dy[i];
            s->lv.dt[i] = s->lv.m[i] * (gd + s->lv.rc[i]);
            s->lv.dlam[i] = -s->lv.g[i] - s->lv.sigma[i] * gd;
            s->uv.dt[i] = s->uv.m[i] * (s->uv.rc[i] - gd);
            s->uv.dlam[i] = -s->uv.g[i] + s->uv.sigma[i] * gd;
        }
        for (int l = 0; l < SG; ++l) {
            double gd = dot_y(s->G[l], s->dy);
            s->lg.dt[l] = s->lg.m[l] * (gd + s->lg.rc[l]);
            s->lg.dlam[l] = -s->lg.g[l] - s->lg.sigma[l] * gd;
            s->ug.dt[l] = s->ug.m[l] * (s->ug.rc[l] - gd);
            s->ug.dlam[l] = -s->ug.g[l] + s->ug.sigma[l] * gd;
        }
    }
}

/* The longest step in [0, 1] that keeps every slack and multiplier non-negative. */
#define SIDE_STEP(side, n)                                                                 \
    for (int i = 0; i < n; ++i) {                                                          \
        if (s->side.dt[i] < 0.0) alpha = VMIN(alpha, -s->side.t[i] / s->side.dt[i]);      \
        if (s->side.dlam[i] < 0.0) alpha = VMIN(alpha, -s->side.lam[i] / s->side.dlam[i]); \
    }

INLINE double max_step(Work *w) {
    double alpha = 1.0;
    for (int k = 0; k < SN; ++k) {
        StageWork *s = &w->s[k];
        EACH_SIDE(SIDE_STEP)
    }
    return alpha;
}

/* Mean complementarity after a step alpha. */
#define SIDE_MU(side, n)                                                                   \
    for (int i = 0; i < n; ++i)                                                            \
        sum += (s->side.t[i] + alpha * s->side.dt[i]) * (s->side.lam[i] + alpha * s->side.dlam[i]);

INLINE double mu_after(Work *w, double alpha) {
    double sum = 0.0;
    for (int k = 0; k < SN; ++k) {
        StageWork *s = &w->s[k];
        EACH_SIDE(SIDE_MU)
    }
    return sum / w->count;
}

#define SIDE_SIGMA(side, n) \
    for (int i = 0; i < n; ++i) s->side.sigma[i] = s->side.m[i] * s->side.lam[i] / s->side.t[i];
#define SIDE_UPDATE(side, n)                          \
    for (int i = 0; i < n; ++i) {                     \
        s->side.t[i] += alpha * s->side.dt[i];        \
        s->side.lam[i] += alpha * s->side.dlam[i];    \
    }

/* One side's slack and multiplier from the guess: t = max(c(y), t0_min), lam = mu0 / t. */
INLINE double start_side(double *t, double *lam, double *m, double bound, double c,
                         double mu0, double t0_min) {
    int present = isfinite(bound);
    *m = present ? 1.0 : 0.0;
    *t = present ? VMAX(c, t0_min) : 1.0;
    *lam = present ? mu0 / *t : 0.0;
    return *m;
}

/* The primal iterate into out = [z_0 v_0 z_1 v_1 ... z_N]. */
INLINE void keep_primal(const Work *w, double *out, const double *z0) {
    const int stride = NV + NZ;
    memcpy(out, z0, sizeof(double) * NZ);
    for (int k = 0; k < SN; ++k) {
        memcpy(out + k * stride + NZ, w->s[k].y, sizeof(double) * NV);
        memcpy(out + (k + 1) * stride, w->s[k + 1].y + ZOFF, sizeof(double) * NZ);
    }
}

/* One run of the method from the primal guess (slacks and multipliers from mu0, t0_min).
 * Returns 0 when solved, 1 at the iteration limit, 2 on a non-finite residual, 3 when a
 * factorisation failed, 4 when it stopped (1 or 3) but its best iterate has every residual
 * within the acceptable one. out holds the best iterate in every case but 2. */
INLINE int interior_point(const Problem *pb, const double *z0, const double *guess,
                          double *out, Work *w, double tol, double mu0, double t0_min,
                          int iter_max, double boundary, double acceptable, int *iterations) {
    const int stride = NV + NZ; /* guess = [z_0 v_0 z_1 v_1 ... z_N] */
    double count = 0.0;
    for (int k = 0; k <= SN; ++k) {
        StageWork *s = &w->s[k];
        memset(s->y, 0, sizeof s->y);
        memset(s->pi, 0, sizeof s->pi);
        memcpy(s->y + ZOFF, k == 0 ? z0 : guess + k * stride, sizeof(double) * NZ);
        if (k < SN) memcpy(s->y, guess + k * stride + NZ, sizeof(double) * NV);
    }
    for (int k = 0; k < SN; ++k) {
        const Stage *st = &pb->stage[k];
        StageWork *s = &w->s[k];
        for (int i = 0; i < NV; ++i) {
            count += start_side(&s->lv.t[i], &s->lv.lam[i], &s->lv.m[i], st->lv[i],
                                s->y[i] - st->lv[i], mu0, t0_min);
            count += start_side(&s->uv.t[i], &s->uv.lam[i], &s->uv.m[i], st->uv[i],
                                st->uv[i] - s->y[i], mu0, t0_min);
        }
        for (int l = 0; l < SG; ++l) {
            double g = dot_y(s->G[l], s->y);
            count += start_side(&s->lg.t[l], &s->lg.lam[l], &s->lg.m[l], st->lg[l],
                                g - st->lg[l], mu0, t0_min);
            count += start_side(&s->ug.t[l], &s->ug.lam[l], &s->ug.m[l], st->ug[l],
                                st->ug[l] - g, mu0, t0_min);
        }
    }
    w->count = count > 0.0 ? count : 1.0;
    /* The best iterate so far (the smallest largest residual), kept for when the method
     * stalls short of the tolerance: barrier weights of nearly degenerate constraints grow
     * without bound and rounding then holds the stationarity residual near 1e-6. */
    double best = INFINITY;
    int status = 1, it;
    for (it = 0;; ++it) {
        double res[5], mu;
        residuals(pb, w, res, &mu);
        if (!isfinite(res[4])) {
            status = 2;
            break;
        }
        const double worst = VMAX(VMAX(res[0], res[1]), VMAX(res[2], res[3]));
        if (worst < best) {
            best = worst;
            keep_primal(w, out, z0);
        }
        if (worst <= tol) {
            status = 0;
            break;
        }
        if (it == iter_max) break;
        for (int k = 0; k < SN; ++k) {
            StageWork *s = &w->s[k];
            EACH_SIDE(SIDE_SIGMA)
        }
        if (!factorize(w)) {
            status = 3;
            break;
        }
        /* predictor: the affine step; centring sigma = (mu_affine / mu)^3 (Mehrotra) */
        right_hand_side(w, 0.0, 0);
        newton_step(w, 0); /* the step length needs no multipliers of the dynamics */
        double alpha = max_step(w);
        double ratio = mu > 0.0 ? mu_after(w, alpha) / mu : 0.0;
        double centring = VMIN(ratio * ratio * ratio, 1.0);
        /* corrector, on the same factorisation; the fraction to the boundary tends to 1 as
         * mu does (as in IPOPT), so the last steps are not held back */
        right_hand_side(w, centring * mu, 1);
        newton_step(w, 1);
        alpha = VMIN(1.0, VMAX(boundary, 1.0 - mu) * max_step(w));
        for (int k = 0; k < SN; ++k) {
            StageWork *s = &w->s[k], *next = &w->s[k + 1];
            for (int i = 0; i < NV; ++i) s->y[i] += alpha * s->dy[i];
            for (int i = 0; i < NZ; ++i) {
                next->y[ZOFF + i] += alpha * next->dy[ZOFF + i];
                s->pi[i] += alpha * s->dpi[i];
            }
            EACH_SIDE(SIDE_UPDATE)
        }
    }
    *iterations = it;
    if (status != 0 && status != 2 && best <= acceptable) status = 4;
    return status;
}


/* Settings: [tolerance, mu0, t0_min, max iterations, least fraction to the boundary,
 * acceptable residual]. Returns interior_point's code and its iterations.
 * z0 is the fixed first state; guess (the layout of out) the primal starting point. */
CPU_VARIANTS
int stage_ipm_solve(const Hessian *H, const Problem *pb, const double *z0, const double *guess,
                    double *out, Work *w, const double *settings, int *iterations) {
    pack(pb, H, w);
    return interior_point(pb, z0, guess, out, w, settings[0], settings[1], settings[2],
                          (int)settings[3], settings[4], settings[5], iterations);
}

/* Sizes the caller allocates: the work area and the two inputs, in bytes. */
long stage_ipm_work_size(void) { return (long)sizeof(Work); }
long stage_ipm_problem_size(void) { return (long)sizeof(Problem); }
long stage_ipm_hessian_size(void) { return (long)sizeof(Hessian); }
