/* The inertial residuals' rows with respect to the span derivatives, sample by sample (the
 * compiled counterparts of torch_dq/fitting/_imu_jacobians.py's gyro_rows and accel_rows,
 * whose docstrings state the formulas; called from there through ctypes).
 *
 * Inputs per sample s: the pose x and its derivatives dx, ddx (8 each, unit stride, sample
 * stride given), gravity g (3), the rows' scales w (3, one per residual component j: the
 * whitening mask / sigma; NULL: 1). Outputs are component-major (sample fastest, S per row):
 * gyro rows (3 j, 2 order, 8) and accel rows (3 j, 3 order, 8), row j times w[j], both in
 * an array of O >= 2 (3) orders per j (the rows of a group's terms stacked; the higher
 * orders' rows not written), and the accelerometer's rows toward gravity (3 j, 3 axis). */
#include <stdint.h>
#include <string.h>

/* q e_j for the pure unit quaternions e_j: component c of row j is SIGN[j][c] q[INDEX[j][c]] */
static const int INDEX[3][4] = {{1, 0, 3, 2}, {2, 3, 0, 1}, {3, 2, 1, 0}};
static const double SIGN[3][4] = {{-1.0, 1.0, 1.0, -1.0}, {-1.0, -1.0, 1.0, 1.0},
                                  {-1.0, 1.0, -1.0, 1.0}};

#define BLOCK 32 /* samples computed into a local buffer, then written row by row */

/* Copy rows (R, B) of a block's buffer to rows (R + gap R / per, S) of the output from
 * sample s0: after every `per` rows `gap` rows are skipped (the orders of the output's j
 * beyond the builder's). */
static void store(const double *buf, int64_t R, int64_t per, int64_t gap, int64_t B,
                  double *rows, int64_t S, int64_t s0)
{
    for (int64_t k = 0; k < R; k++)
        memcpy(rows + (k + k / per * gap) * S + s0, buf + k * BLOCK, sizeof(double) * (size_t)B);
}

/* rows (3 j, O order, 8, S): -2 dr e_j (order 0, real), 2 r e_j (order 1, real), the dual
 * parts zero; times w[j] (sample stride sw) where w is given. */
void tdq_gyro_rows(int64_t S, const double *x, int64_t sx, const double *dx, int64_t sdx,
                   const double *w, int64_t sw, int64_t O, double *rows)
{
    double buf[48 * BLOCK];
    memset(buf, 0, sizeof(buf));
    for (int64_t s0 = 0; s0 < S; s0 += BLOCK) {
        const int64_t B = S - s0 < BLOCK ? S - s0 : BLOCK;
        for (int64_t t = 0; t < B; t++) {
            const double *q[2] = {dx + (s0 + t) * sdx, x + (s0 + t) * sx};
            const double scale[2] = {-2.0, 2.0};
            for (int j = 0; j < 3; j++)
                for (int o = 0; o < 2; o++)
                    for (int c = 0; c < 4; c++) {
                        const double v = q[o][INDEX[j][c]] * (scale[o] * SIGN[j][c]);
                        buf[((j * 2 + o) * 8 + c) * BLOCK + t] = w ? v * w[(s0 + t) * sw + j] : v;
                    }
        }
        store(buf, 48, 16, 8 * (O - 2), B, rows, S, s0);
    }
}

/* the vector part of a b^*: b_0 a_v - a_0 b_v - a_v x b_v (= b_v x a_v + ...) */
static void vec_conj(const double *a, const double *b, double *v)
{
    v[0] = (b[2] * a[3] - b[3] * a[2]) + a[1] * b[0] - b[1] * a[0];
    v[1] = (b[3] * a[1] - b[1] * a[3]) + a[2] * b[0] - b[2] * a[0];
    v[2] = (b[1] * a[2] - b[2] * a[1]) + a[3] * b[0] - b[3] * a[0];
}

/* Sample (r + e d, its derivatives, gravity gs)'s accelerometer rows: (3 j, 6 b, 4 c) in
 * buf[((j * 6 + b) * 4 + c) * BLOCK], then toward (3 j, 3 i) in buf[(72 + 3 j + i) BLOCK]. */
static void accel_sample(const double *r, const double *rd, const double *rdd,
                         const double *gs, const double *ws, double *buf)
{
    const double *d = r + 4, *dd = rd + 4, *ddd = rdd + 4;
    double P[4][4], h[3][3]; /* h[i][j]: component i of h_j */
    for (int a = 0; a < 4; a++)
        for (int b = 0; b < 4; b++)
            P[a][b] = r[a] * r[b];
    const double half = P[0][0] - P[1][1] - P[2][2] - P[3][3];
    for (int i = 0; i < 3; i++) {
        const int j = (i + 1) % 3, m = (i + 2) % 3;
        h[i][i] = (half + 2.0 * P[i + 1][i + 1]) * 2.0;
        h[i][j] = (P[i + 1][j + 1] - P[0][m + 1]) * 4.0;
        h[j][i] = (P[i + 1][j + 1] + P[0][m + 1]) * 4.0;
    }
    double Q[4][6];
    for (int c = 0; c < 4; c++) {
        Q[c][0] = -ddd[c];
        Q[c][1] = rdd[c];
        Q[c][2] = -2.0 * dd[c];
        Q[c][3] = 2.0 * rd[c];
        Q[c][4] = -d[c];
        Q[c][5] = r[c];
    }
    double out[3][6][4];
    for (int jj = 0; jj < 3; jj++)
        for (int b = 0; b < 6; b++) {
            out[jj][b][0] = -(h[0][jj] * Q[1][b] + h[1][jj] * Q[2][b] + h[2][jj] * Q[3][b]);
            for (int c = 0; c < 3; c++) {
                const int j = (c + 1) % 3, m = (c + 2) % 3;
                out[jj][b][1 + c] = Q[0][b] * h[c][jj] + h[j][jj] * Q[1 + m][b]
                                    - h[m][jj] * Q[1 + j][b];
            }
        }
    double u[3], v[3], p[4];
    vec_conj(ddd, r, u);
    vec_conj(dd, rd, v);
    for (int i = 0; i < 3; i++)
        u[i] += 2.0 * v[i];
    vec_conj(d, rdd, v);
    for (int i = 0; i < 3; i++)
        u[i] = (u[i] + v[i]) * 2.0 - gs[i];
    p[0] = -(u[0] * r[1] + u[1] * r[2] + u[2] * r[3]); /* U r */
    p[1] = (u[1] * r[3] - u[2] * r[2]) + u[0] * r[0];
    p[2] = (u[2] * r[1] - u[0] * r[3]) + u[1] * r[0];
    p[3] = (u[0] * r[2] - u[1] * r[1]) + u[2] * r[0];
    for (int j = 0; j < 3; j++)
        for (int c = 0; c < 4; c++)
            out[j][0][c] += p[INDEX[j][c]] * (-2.0 * SIGN[j][c]);
    for (int j = 0; j < 3; j++)
        for (int b = 0; b < 6; b++)
            for (int c = 0; c < 4; c++)
                buf[((j * 6 + b) * 4 + c) * BLOCK] = ws ? out[j][b][c] * ws[j] : out[j][b][c];
    for (int j = 0; j < 3; j++)
        for (int i = 0; i < 3; i++)
            buf[(72 + j * 3 + i) * BLOCK] = -0.5 * h[i][j];
}

/* rows (72, S): block b of (3 j, 6 b, 4 c) is H_j times Q_b, Q = (-ddd, rdd, -2 dd, 2 rd,
 * -d, r) (b = 2 order + dual), H_j = (0, h_j), h_j = 2 R e_j; the real part of order 0
 * adds -2 U r e_j, U = (0, u), u = 2 vec(ddd r^* + 2 dd rd^* + d rdd^*) - g. toward (9, S):
 * (j, i) = -h_j[i] / 2. Row j of rows times w[j] (sample stride sw) where w is given; rows
 * (3 j, O order, 8, S). */
void tdq_accel_rows(int64_t S, const double *x, int64_t sx, const double *dx, int64_t sdx,
                    const double *ddx, int64_t sddx, const double *g, int64_t sg,
                    const double *w, int64_t sw, int64_t O, double *rows, double *toward)
{
    double buf[81 * BLOCK];
    for (int64_t s0 = 0; s0 < S; s0 += BLOCK) {
        const int64_t B = S - s0 < BLOCK ? S - s0 : BLOCK;
        for (int64_t t = 0; t < B; t++)
            accel_sample(x + (s0 + t) * sx, dx + (s0 + t) * sdx, ddx + (s0 + t) * sddx,
                         g + (s0 + t) * sg, w ? w + (s0 + t) * sw : NULL, buf + t);
        store(buf, 72, 24, 8 * (O - 3), B, rows, S, s0);
        store(buf + 72 * BLOCK, 9, 9, 0, B, toward, S, s0);
    }
}

/* o = a b^* (quaternions) */
static void mul_conj(const double *a, const double *b, double *o)
{
    o[0] = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
    o[1] = -a[0] * b[1] + a[1] * b[0] - a[2] * b[3] + a[3] * b[2];
    o[2] = -a[0] * b[2] + a[1] * b[3] + a[2] * b[0] - a[3] * b[1];
    o[3] = -a[0] * b[3] - a[1] * b[2] + a[2] * b[1] + a[3] * b[0];
}

/* vec(r^* (0, u) r) = R^T u for a unit r */
static void rotate_back(const double *r, const double *u, double *f)
{
    const double w = r[0], x = r[1], y = r[2], z = r[3];
    f[0] = (1.0 - 2.0 * (y * y + z * z)) * u[0] + 2.0 * (x * y + w * z) * u[1]
           + 2.0 * (x * z - w * y) * u[2];
    f[1] = 2.0 * (x * y - w * z) * u[0] + (1.0 - 2.0 * (x * x + z * z)) * u[1]
           + 2.0 * (y * z + w * x) * u[2];
    f[2] = 2.0 * (x * z + w * y) * u[0] + 2.0 * (y * z - w * x) * u[1]
           + (1.0 - 2.0 * (x * x + y * y)) * u[2];
}

/* The inertial residuals before whitening, (S, 3) contiguous: gyroscope 2 vec(r^* dr) + b - y
 * (body rate), accelerometer (ddx given) R^T (2 vec(ddd r^* + 2 dd dr^* + d ddr^*) - g) + b - y
 * (specific force); b, y, g rows of 3 with sample strides sb, sy, sg. */
void tdq_imu_residuals(int64_t S, const double *x, int64_t sx, const double *dx, int64_t sdx,
                       const double *ddx, int64_t sddx, const double *g, int64_t sg,
                       const double *b, int64_t sb, const double *y, int64_t sy, double *out)
{
    for (int64_t s = 0; s < S; s++) {
        const double *r = x + s * sx, *rd = dx + s * sdx, *bs = b + s * sb, *ys = y + s * sy;
        double f[3];
        if (!ddx) { /* 2 vec(r^* dr) = 2 (r_0 dr_v - dr_0 r_v - r_v x dr_v) */
            f[0] = 2.0 * (r[0] * rd[1] - r[1] * rd[0] - (r[2] * rd[3] - r[3] * rd[2]));
            f[1] = 2.0 * (r[0] * rd[2] - r[2] * rd[0] - (r[3] * rd[1] - r[1] * rd[3]));
            f[2] = 2.0 * (r[0] * rd[3] - r[3] * rd[0] - (r[1] * rd[2] - r[2] * rd[1]));
        } else {
            const double *d = r + 4, *dd = rd + 4, *rdd = ddx + s * sddx, *ddd = rdd + 4;
            const double *gs = g + s * sg;
            double a[4], t[4], u[3];
            mul_conj(ddd, r, a);
            mul_conj(dd, rd, t);
            for (int i = 1; i < 4; i++) a[i] += 2.0 * t[i];
            mul_conj(d, rdd, t);
            for (int i = 0; i < 3; i++) u[i] = 2.0 * (a[i + 1] + t[i + 1]) - gs[i];
            rotate_back(r, u, f);
        }
        for (int i = 0; i < 3; i++) out[3 * s + i] = f[i] + bs[i] - ys[i];
    }
}
