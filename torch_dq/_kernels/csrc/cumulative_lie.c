/* The cumulative B-spline form in its Lie algebra, one loop over samples (the readable
 * reference, the same mathematics: torch_dq/_cumulative_lie.py, its functions named below).
 *
 * Twists xi = (omega, v) are double[6]; a dual 3 x 3 matrix A + eps B acting on twists as
 * [[A, 0], [B, A]] is a `dmat` (row-major A, B); dual quaternions are double[8] (real, dual
 * half, scalar first). The even functions of torch_dq._numerics (sinc, se3_c1, se3_c2 and cos)
 * come with their series coefficients and switch points from the caller (`even`: per function
 * 8 coefficients c_0..c_7 and the switch in x2 = theta^2), so both paths take the same branch
 * with the same series. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#define EVEN_TERMS 8
#define EVEN_STRIDE (EVEN_TERMS + 1)
#define MAXP 8 /* steps per span (degree): the wrapper takes the torch path beyond */

enum { EV_COS, EV_SINC, EV_C1, EV_C2 }; /* rows of the caller's table */

typedef struct { double a[9], b[9]; } dmat;

/* The closed forms of _numerics._EVEN at theta = sqrt(x2) (above the switch). */
static double even_closed(int f, double th) {
    switch (f) {
    case EV_COS: return cos(th);
    case EV_SINC: return sin(th) / th;
    case EV_C1: return (1.0 - cos(th)) / (th * th);
    default: return (th - sin(th)) / (th * th * th);
    }
}

/* d f / d x2 in closed form, _numerics._EVEN_SLOPES (f' = (df / dtheta) / (2 theta)). */
static double even_closed_slope(int f, double th) {
    double sinc_slope = (cos(th) - sin(th) / th) / (2.0 * th * th);
    switch (f) {
    case EV_SINC: return sinc_slope;
    case EV_C1: return (sin(th) / th - 2.0 * (1.0 - cos(th)) / (th * th)) / (2.0 * th * th);
    default: return -(sinc_slope + (th - sin(th)) / (th * th * th)) / (th * th);
    }
}

/* f(x2) and (slope != NULL) f'(x2) of the even function f: Horner's series and its
 * term-by-term derivative below the switch, the closed forms above (_numerics.even_slopes). */
static double even_value(const double *even, int f, double x2, double *slope) {
    const double *c = even + f * EVEN_STRIDE;
    if (x2 < c[EVEN_TERMS]) {
        double s = c[7] * x2 + c[6];
        for (int i = 5; i >= 0; i--) s = s * x2 + c[i];
        if (slope) {
            double d = 7.0 * c[7] * x2 + 6.0 * c[6];
            for (int i = 5; i >= 1; i--) d = d * x2 + (double)i * c[i];
            *slope = d;
        }
        return s;
    }
    double th = sqrt(x2);
    if (slope) *slope = even_closed_slope(f, th);
    return even_closed(f, th);
}

/* out = a x b */
static void cross(const double *a, const double *b, double *out) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* out += a x b */
static void cross_acc(const double *a, const double *b, double *out) {
    double c[3];
    cross(a, b, c);
    for (int i = 0; i < 3; i++) out[i] += c[i];
}

/* [a, b] = ad_a b = (a_w x b_w, a_w x b_v + a_v x b_w) */
static void bracket(const double *a, const double *b, double *out) {
    cross(a, b, out);
    cross(a, b + 3, out + 3);
    cross_acc(a + 3, b, out + 3);
}

/* out += rows a times ad_z: (a_w x z_w + a_v x z_v, a_v x z_w) (_row_ad) */
static void row_ad_acc(const double *a, const double *z, double *out) {
    cross_acc(a, z, out);
    cross_acc(a + 3, z + 3, out);
    cross_acc(a + 3, z, out + 3);
}

/* The dual matrix times a twist: (A x_w, A x_v + B x_w) (_apply) */
static void dmat_apply(const dmat *m, const double *x, double *out) {
    for (int r = 0; r < 3; r++) {
        double w = 0.0, v = 0.0, b = 0.0;
        for (int i = 0; i < 3; i++) {
            w += m->a[3 * r + i] * x[i];
            v += m->a[3 * r + i] * x[3 + i];
            b += m->b[3 * r + i] * x[i];
        }
        out[r] = w;
        out[3 + r] = v + b;
    }
}

/* A row times the dual matrix: (a_w A + a_v B, a_v A) (_rows), scaled by `value`, written
 * (acc 0) or added (acc 1) to out */
static void rows_dmat(const double *a, const dmat *m, double *out, int acc, double value) {
    for (int c = 0; c < 3; c++) {
        double w = 0.0, v = 0.0;
        for (int i = 0; i < 3; i++) {
            w += a[i] * m->a[3 * i + c] + a[3 + i] * m->b[3 * i + c];
            v += a[3 + i] * m->a[3 * i + c];
        }
        out[c] = (acc ? out[c] : 0.0) + value * w;
        out[3 + c] = (acc ? out[3 + c] : 0.0) + value * v;
    }
}

/* The dual matrix c0 I + c1 Phi + c2 Phi^2 (_polynomial) of Phi = W + eps V, Phi^2 = W2 + eps WV
 * (the span's powers `pw`: W, V, W2, WV row-major, then s0, s1), c1, c2 dual */
static void polynomial(const double *pw, double c0, double a1, double b1, double a2, double b2,
                       dmat *m) {
    for (int i = 0; i < 9; i++) {
        double W = pw[i], V = pw[9 + i], W2 = pw[18 + i], WV = pw[27 + i];
        m->a[i] = W2 * a2 + W * a1 + (i % 4 == 0 ? c0 : 0.0);
        m->b[i] = W * b1 + V * a1 + W2 * b2 + WV * a2;
    }
}

/* The vector part of q* u (left) or of u q* for a quaternion q = (q0, qv), u a 4-vector:
 * q0 u_v - u0 q_v +- u_v x q_v, added to out (_conj_vec) */
static void conj_vec_acc(double q0, const double *qv, const double *u, int left, double *out) {
    for (int i = 0; i < 3; i++) out[i] += q0 * u[1 + i] - u[0] * qv[i];
    if (left) cross_acc(u + 1, qv, out);
    else cross_acc(qv, u + 1, out);
}

/* L(X)^T g: (r* g_a + d* g_b, r* g_b) (_left_t) */
static void left_t(const double *X, const double *g, double *out) {
    for (int i = 0; i < 8; i++) out[i] = 0.0;
    conj_vec_acc(X[0], X + 1, g, 1, out + 1);
    conj_vec_acc(X[4], X + 5, g + 4, 1, out + 1);
    conj_vec_acc(X[0], X + 1, g + 4, 1, out + 5);
    out[0] = g[0] * X[0] + g[1] * X[1] + g[2] * X[2] + g[3] * X[3]
             + g[4] * X[4] + g[5] * X[5] + g[6] * X[6] + g[7] * X[7];
    out[4] = g[4] * X[0] + g[5] * X[1] + g[6] * X[2] + g[7] * X[3];
}

/* One sample's forward quantities (_forward): per step M_j = Ad_{Exp(-lambda_j d_j)},
 * lambda_j J_r(lambda_j d_j), z_j = M_j V_{j-1}, zd_j = M_j Vd_{j-1}, V_j; the last V, Vd. */
typedef struct {
    dmat M[MAXP], Jr[MAXP];
    double z[MAXP][6], zd[MAXP][6], V[MAXP][6], last[2][6];
} forward_t;

/* The recursions V_j = M_j V_{j-1} + lambda'_j d_j, Vd_j = M_j Vd_{j-1} + lambda''_j d_j
 * + lambda'_j [V_j, d_j] with M_j = I - lambda sigma Phi + lambda^2 alpha Phi^2 and
 * lambda J_r = lambda I - lambda^2 alpha Phi + lambda^3 beta Phi^2 (coefficients at the dual
 * square lambda^2 s); `d` the twists, `pw` their powers (38 each: _powers), lam[o][j]. */
static void forward(int64_t p, int64_t O, const double (*d)[6], const double (*pw)[38],
                    const double (*lam)[MAXP], const double *even, forward_t *fw) {
    double V[6] = {0}, Vd[6] = {0};
    for (int64_t j = 0; j < p; j++) {
        const double *pj = pw[j], *dj = d[j];
        double l1 = lam[0][j], l2 = l1 * l1, l3 = l2 * l1;
        double x2 = l2 * pj[36], dual = l2 * pj[37], sl[3], f[3];
        for (int e = 0; e < 3; e++) {
            f[e] = even_value(even, EV_SINC + e, x2, &sl[e]);
            sl[e] *= dual;
        }
        polynomial(pj, 1.0, -l1 * f[0], -l1 * sl[0], l2 * f[1], l2 * sl[1], &fw->M[j]);
        polynomial(pj, l1, -l2 * f[1], -l2 * sl[1], l3 * f[2], l3 * sl[2], &fw->Jr[j]);
        if (O > 1) {
            if (j) dmat_apply(&fw->M[j], V, fw->z[j]);
            for (int i = 0; i < 6; i++) V[i] = (j ? fw->z[j][i] : 0.0) + lam[1][j] * dj[i];
            for (int i = 0; i < 6; i++) fw->V[j][i] = V[i];
        }
        if (O > 2) {
            double b[6] = {0};
            if (j) {
                dmat_apply(&fw->M[j], Vd, fw->zd[j]);
                bracket(V, dj, b);
            }
            for (int i = 0; i < 6; i++)
                Vd[i] = (j ? fw->zd[j][i] : 0.0) + lam[2][j] * dj[i] + lam[1][j] * b[i];
        }
    }
    for (int i = 0; i < 6; i++) {
        fw->last[0][i] = V[i];
        fw->last[1][i] = Vd[i];
    }
}

/* Cotangents a[o] of the pose's right step, of V and of Vd from those g (O x 8) of X, Xd,
 * Xdd (_algebra_cotangents): pose P(u_0 + R(h(V))^T u_1 + R(h(V)^2 + h(Vd))^T u_2), V:
 * P(u_1 + (R + L)(h(V))^T u_2), Vd: P u_2, u_o = L(X)^T g_o, P the vector parts times 1/2;
 * the second order's terms only where `sec` */
static void algebra_cotangents(const double *X, const double *V, const double *Vd,
                               const double *g, int64_t O, int sec, double (*a)[6]) {
    double *pw = a[0], *pv = a[0] + 3, u[8], w[3], v[3];
    for (int i = 0; i < 6; i++) a[0][i] = 0.0;
    conj_vec_acc(X[0], X + 1, g, 1, pw);
    conj_vec_acc(X[4], X + 5, g + 4, 1, pw);
    conj_vec_acc(X[0], X + 1, g + 4, 1, pv);
    if (O > 1) {
        left_t(X, g + 8, u);
        for (int i = 0; i < 3; i++) {
            a[1][i] = u[1 + i];
            a[1][3 + i] = u[5 + i];
            w[i] = 0.5 * V[i];
            v[i] = 0.5 * V[3 + i];
        }
        conj_vec_acc(0.0, w, u, 0, pw);
        conj_vec_acc(0.0, v, u + 4, 0, pw);
        conj_vec_acc(0.0, w, u + 4, 0, pv);
    }
    if (O > 2 && sec) {
        double hr[3], hd[3];
        left_t(X, g + 16, u);
        for (int i = 0; i < 3; i++) {
            a[2][i] = u[1 + i];
            a[2][3 + i] = u[5 + i];
            hr[i] = 0.5 * Vd[i];
            hd[i] = 0.5 * Vd[3 + i];
        }
        double r0 = -(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
        double d0 = -2.0 * (w[0] * v[0] + w[1] * v[1] + w[2] * v[2]);
        conj_vec_acc(r0, hr, u, 0, pw);
        conj_vec_acc(d0, hd, u + 4, 0, pw);
        conj_vec_acc(r0, hr, u + 4, 0, pv);
        for (int i = 0; i < 3; i++) {
            a[1][i] -= u[0] * V[i] + u[4] * V[3 + i];
            a[1][3 + i] -= u[4] * V[i];
        }
    }
    for (int o = 0; o < (O > 2 && !sec ? 2 : O); o++) /* of Vd only the rows `second` */
        for (int i = 0; i < 6; i++) a[o][i] *= 0.5;
}

/* The recursions run backwards (_backward) from the rows a (O x 6, updated in place): the
 * cotangents cd[j] of every d_j and `first`, the first point's step through the pose. */
static void backward(int64_t p, int64_t O, int sec, const double (*d)[6],
                     const double (*lam)[MAXP], const forward_t *fw, double (*a)[6],
                     double (*cd)[6], double *first) {
    int two = O > 2 && sec;
    for (int64_t j = p - 1; j >= 0; j--) {
        double t[6], m[6], b[3][6];
        if (two) {
            for (int i = 0; i < 6; i++) m[i] = -lam[1][j] * d[j][i];
            row_ad_acc(a[2], m, a[1]);
        }
        for (int i = 0; i < 6; i++) t[i] = a[0][i];
        if (O > 1 && j) row_ad_acc(a[1], fw->z[j], t);
        if (two && j) row_ad_acc(a[2], fw->zd[j], t);
        rows_dmat(t, &fw->Jr[j], cd[j], 0, 1.0);
        if (O > 1)
            for (int i = 0; i < 6; i++) cd[j][i] += a[1][i] * lam[1][j];
        if (two) {
            for (int i = 0; i < 6; i++) {
                cd[j][i] += a[2][i] * lam[2][j];
                m[i] = lam[1][j] * fw->V[j][i];
            }
            row_ad_acc(a[2], m, cd[j]);
        }
        if (!j) {
            rows_dmat(a[0], &fw->M[0], first, 0, 1.0);
            break;
        }
        int orders = two ? 3 : (O > 2 ? 2 : (int)O); /* of Vd only the rows `second` */
        for (int o = 0; o < orders; o++) rows_dmat(a[o], &fw->M[j], b[o], 0, 1.0);
        for (int o = 0; o < orders; o++)
            for (int i = 0; i < 6; i++) a[o][i] = b[o][i];
    }
}

/* One sample's cotangent rows (_vjp_part's loop body): its span's parts `part` (span-major: per
 * step the 80 rows of span_parts), weights lam, cotangents g (k x O x 8), pose X, into st
 * (k x (p + 1) x 6). The last chain, d d_j = J_r^-1(d_j) (delta_{j+1} - Ad_{Exp(-d_j)}
 * delta_j): step j + 1 gets cd_j J_r^-1, step j gets -cd_j J_l^-1 (rows 44..79 of the part). */
static void vjp_sample(int64_t p, int64_t O, int64_t k, const double *part,
                       const double (*lam)[MAXP], const double *g, const double *X,
                       const uint8_t *second, const double *even, double *st) {
    double d[MAXP][6], pw[MAXP][38];
    dmat Ji[MAXP], Jl[MAXP];
    forward_t fw;
    for (int64_t j = 0; j < p; j++) {
        const double *c = part + 80 * j;
        for (int i = 0; i < 6; i++) d[j][i] = c[i];
        for (int i = 0; i < 38; i++) pw[j][i] = c[6 + i];
        for (int i = 0; i < 9; i++) {
            Ji[j].a[i] = c[44 + i];
            Ji[j].b[i] = c[53 + i];
            Jl[j].a[i] = c[62 + i];
            Jl[j].b[i] = c[71 + i];
        }
    }
    forward(p, O, (const double (*)[6])d, (const double (*)[38])pw, lam, even, &fw);
    for (int64_t r = 0; r < k; r++, st += (p + 1) * 6) {
        double a[3][6], cd[MAXP][6];
        algebra_cotangents(X, fw.last[0], fw.last[1], g + r * O * 8, O, second[r], a);
        backward(p, O, second[r], (const double (*)[6])d, lam, &fw, a, cd, st);
        for (int64_t j = 0; j < p; j++) {
            rows_dmat(cd[j], &Jl[j], st + 6 * j, 1, -1.0);
            rows_dmat(cd[j], &Ji[j], st + 6 * (j + 1), 0, 1.0);
        }
    }
}

#define BLOCK 32 /* samples whose cotangents are gathered at once (strided reads stay local) */

/* Cotangents of the control-point steps of S samples (_cumulative_lie.vjp): span parts `span`
 * (80, p, U) contiguous, inverse (S,), weights (O, S, p), cot (S, k, O, 8) of strides cs[4]
 * (the callers' are component-major views, the samples' stride 1: gathered a block of samples
 * at a time), pose (S, 8), second (k,) 0/1: the rows whose cotangents of Xdd are read; out
 * (S, k, p + 1, 6). Returns 0, or -1 where no scratch memory was had (nothing written). */
int tdq_lie_vjp(const double *span, int64_t p, int64_t U, const int64_t *inverse, int64_t S,
                const double *weights, int64_t O, const double *cot, const int64_t *cs,
                int64_t k, const double *pose, const uint8_t *second, const double *even,
                double *out) {
    int64_t P = p * U, n = k * O * 8;
    if (S == 0) return 0;
    double *parts = malloc(sizeof(double) * (size_t)(80 * P + BLOCK * n));
    if (!parts) return -1;
    double *g = parts + 80 * P;
    for (int64_t row = 0; row < 80; row++) /* span-major: a sample's parts in one stretch */
        for (int64_t j = 0; j < p; j++)
            for (int64_t u = 0; u < U; u++)
                parts[(u * p + j) * 80 + row] = span[row * P + j * U + u];
    for (int64_t s0 = 0; s0 < S; s0 += BLOCK) {
        int64_t B = S - s0 < BLOCK ? S - s0 : BLOCK;
        for (int64_t r = 0; r < k; r++)
            for (int64_t o = 0; o < O; o++)
                for (int c = 0; c < 8; c++) {
                    const double *src = cot + s0 * cs[0] + r * cs[1] + o * cs[2] + c * cs[3];
                    for (int64_t b = 0; b < B; b++) g[b * n + (r * O + o) * 8 + c] = src[b * cs[0]];
                }
        for (int64_t b = 0; b < B; b++) {
            int64_t s = s0 + b;
            double lam[3][MAXP];
            for (int64_t o = 0; o < O; o++)
                for (int64_t j = 0; j < p; j++) lam[o][j] = weights[(o * S + s) * p + j];
            vjp_sample(p, O, k, parts + inverse[s] * p * 80, (const double (*)[MAXP])lam,
                       g + b * n, pose + 8 * s, second, even, out + s * k * (p + 1) * 6);
        }
    }
    free(parts);
    return 0;
}

/* ------------------------------------------------------------------------------ evaluation */

/* The Hamilton product a b of quaternions, added to out */
static void qmul_acc(const double *a, const double *b, double *out) {
    out[0] += a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    out[1] += a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    out[2] += a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    out[3] += a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
}

/* The dual-quaternion product (r_a r_b, r_a d_b + d_a r_b) (_dq_rows) */
static void dq_mul(const double *a, const double *b, double *out) {
    for (int i = 0; i < 8; i++) out[i] = 0.0;
    qmul_acc(a, b, out);
    qmul_acc(a, b + 4, out + 4);
    qmul_acc(a + 4, b, out + 4);
}

/* Exp(xi) of a twist (_exp_rows): r = (cos(theta/2), sinc(theta/2) omega/2), t = v + c1 omega x v
 * + c2 omega x (omega x v), dual part (0, t) r / 2; x2 = theta^2, c1, c2 se3_c1, se3_c2 there */
static void exp_twist(const double *xi, double x2, double c1, double c2, const double *even,
                      double *out) {
    double wxv[3], wwv[3], t[3], txq[3];
    double sinc = even_value(even, EV_SINC, 0.25 * x2, 0);
    out[0] = even_value(even, EV_COS, 0.25 * x2, 0);
    for (int i = 0; i < 3; i++) out[1 + i] = xi[i] * (0.5 * sinc);
    cross(xi, xi + 3, wxv);
    cross(xi, wxv, wwv);
    for (int i = 0; i < 3; i++) t[i] = xi[3 + i] + c1 * wxv[i] + wwv[i] * c2;
    out[4] = -0.5 * (t[0] * out[1] + t[1] * out[2] + t[2] * out[3]);
    cross(t, out + 1, txq);
    for (int i = 0; i < 3; i++) out[5 + i] = 0.5 * (txq[i] + t[i] * out[0]);
}

/* M y = y + c1 [d, y] + c2 [d, [d, y]] (_adjoint), dual scalars c = (a, e): (a y_w, a y_v +
 * e y_w), in place */
static void adjoint(const double *d, double a1, double e1, double a2, double e2, double *y) {
    double b[6], bb[6];
    bracket(d, y, b);
    bracket(d, b, bb);
    for (int i = 0; i < 6; i++) y[i] += b[i] * a1 + bb[i] * a2;
    for (int i = 0; i < 3; i++) y[3 + i] += b[i] * e1 + bb[i] * e2;
}

/* The cumulative form and its time derivatives (_cumulative_lie.derivatives) at N times:
 * X = c_f prod_j Exp(lambda_j d_j), Xd = X h(V), Xdd = X (h(V)^2 + h(Vd)) with V, Vd by the
 * recursions (_rates); ctrl (M, 8), first (N,), twists (6, p, N), lam (O, p, N), out (O, N, 8). */
void tdq_lie_derivatives(const double *ctrl, const int64_t *first, const double *twists,
                         int64_t p, int64_t N, const double *lam, int64_t O, const double *even,
                         double *out) {
    for (int64_t n = 0; n < N; n++) {
        double X[8], R[2][6] = {{0}}, E[8], Y[8];
        for (int i = 0; i < 8; i++) X[i] = ctrl[8 * first[n] + i];
        for (int64_t j = 0; j < p; j++) {
            double d[6], xi[6], sl[3], f[3], l = lam[j * N + n];
            for (int i = 0; i < 6; i++) d[i] = twists[(i * p + j) * N + n];
            double x2 = l * l * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            for (int e = 0; e < 3; e++) f[e] = even_value(even, EV_SINC + e, x2, &sl[e]);
            for (int i = 0; i < 6; i++) xi[i] = d[i] * l;
            exp_twist(xi, x2, f[1], f[2], even, E);
            dq_mul(X, E, Y);
            for (int i = 0; i < 8; i++) X[i] = Y[i];
            for (int64_t o = 0; o + 1 < O; o++) {
                double lo = lam[((o + 1) * p + j) * N + n];
                if (j) {
                    double dual = 2.0 * l * l * (d[0] * d[3] + d[1] * d[4] + d[2] * d[5]);
                    adjoint(d, -l * f[0], -l * sl[0] * dual, l * l * f[1], l * l * sl[1] * dual,
                            R[o]);
                }
                for (int i = 0; i < 6; i++) R[o][i] += d[i] * lo;
            }
            if (O > 2 && j) {
                double b[6];
                bracket(R[0], d, b);
                for (int i = 0; i < 6; i++) R[1][i] += b[i] * lam[(p + j) * N + n];
            }
        }
        for (int i = 0; i < 8; i++) out[8 * n + i] = X[i];
        if (O > 1) {
            double h[8] = {0}, H[8] = {0};
            for (int i = 0; i < 3; i++) {
                h[1 + i] = 0.5 * R[0][i];
                h[5 + i] = 0.5 * R[0][3 + i];
                H[1 + i] = 0.5 * R[1][i];
                H[5 + i] = 0.5 * R[1][3 + i];
            }
            dq_mul(X, h, out + 8 * (N + n));
            if (O > 2) {
                H[0] = -(h[1] * h[1] + h[2] * h[2] + h[3] * h[3]);
                H[4] = -2.0 * (h[1] * h[5] + h[2] * h[6] + h[3] * h[7]);
                dq_mul(X, H, out + 8 * (2 * N + n));
            }
        }
    }
}
