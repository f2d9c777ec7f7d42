/* The banded Cholesky factorisation, its solves and its selected inverse (the compiled
 * counterpart of torch_dq/fitting/_banded.py's block cyclic reduction, called from
 * BandedCholesky through torch_dq/_kernels/banded_native.py).
 *
 * The matrix of n block rows of size s is given by its upper band (n, w, s, s) (block
 * (k, k + d) at band[k, d], the diagonal blocks' lower triangles read) and an optional
 * shift (n, s) added to its diagonal; it is padded to N = G g s scalar rows with identity
 * rows (g = max(w - 1, 1), G = ceil(n / g): the grouping of the PyTorch path). Its scalar
 * bandwidth is p = w s - 1, and the factor A = U^T U (U = L^T upper) is stored by rows,
 * U(j, i) = U[j (p + 1) + i - j] for j <= i <= j + p (LAPACK dpbtrf's upper factor, scipy's
 * cholesky_banded's), computed in place of the matrix's rows in dpbtf2's order (factor_one).
 *
 * A batch element whose matrix is not numerically positive definite (a pivot that is not
 * > 0, NaN included: LAPACK's test) gets ok = 0 and the identity as its factor (results
 * meaningless but finite, as the PyTorch path's).
 *
 * The selected inverse is Takahashi's recursion on L = U^T: with Z = A^-1, L^T Z = L^-1
 * gives, from the last row up,
 *   Z(i, j) = -(1 / L(i, i)) sum_{k = i+1}^{i+p} L(k, i) Z(k, j),  j > i,
 *   Z(i, i) = (1 / L(i, i) - sum_k L(k, i) Z(i, k)) / L(i, i),
 * exact for every |i - j| <= P (any P >= p); P = 2 g s - 1 covers the blocks of the grouped
 * matrix's tridiagonal (diag[j]: groups (j, j), sub[j]: groups (j + 1, j)). Rows i .. i + P
 * are kept in a circular buffer of P + 1 rows, each the full width i - P .. i + P (row i's
 * entries left of the diagonal mirrored in as rows < i are computed), and a group's blocks
 * are copied out when its first row is done. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

struct shape {
    int64_t n, w, s, N, p;
};

/* Row j's entries A(j, j .. j + p) of the shifted, padded matrix into u (A(j, c) of block
 * (k, k + e) is band[k, e]'s element (j - k s, c - (k + e) s); the diagonal blocks' lower
 * triangles read, as the PyTorch path's Cholesky does; zero past N). */
static void matrix_row(const struct shape *d, const double *band, const double *shift,
                       int64_t j, double *u)
{
    const int64_t s = d->s, w = d->w, n = d->n, k = j / s, a = j % s;
    memset(u, 0, (size_t)(d->p + 1) * sizeof(double));
    if (j >= n * s) {
        u[0] = 1.0;
        return;
    }
    const double *blk = band + (k * w * s + a) * s; /* band[k, 0] row a */
    for (int64_t b = a; b < s; b++)
        u[b - a] = band[(k * w * s + b) * s + a];
    for (int64_t e = 1; e < w && k + e < n; e++)
        memcpy(u + e * s - a, blk + e * s * s, (size_t)s * sizeof(double));
    if (shift)
        u[0] += shift[j];
}

/* sum a[k] b[k], k < len, in four running sums (independent: vectorised). */
static double dot(const double *restrict a, const double *restrict b, int64_t len)
{
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int64_t k = 0;
    for (; k + 4 <= len; k += 4) {
        s0 += a[k] * b[k];
        s1 += a[k + 1] * b[k + 1];
        s2 += a[k + 2] * b[k + 2];
        s3 += a[k + 3] * b[k + 3];
    }
    for (; k < len; k++)
        s0 += a[k] * b[k];
    return (s0 + s1) + (s2 + s3);
}

/* y[k] -= c x[k], k < len. */
static void axpy(double *restrict y, double c, const double *restrict x, int64_t len)
{
    for (int64_t k = 0; k < len; k++)
        y[k] -= c * x[k];
}

/* One batch element's factor in place of its rows (LAPACK dpbtf2's order: row j's pivot,
 * the row scaled, then its rank-one update of the rows j + 1 .. j + p, each one contiguous
 * axpy, independent of the others); 0 where a pivot fails (U then the identity). */
static int factor_one(const struct shape *d, const double *band, const double *shift,
                      double *U)
{
    const int64_t N = d->N, p = d->p, q = p + 1;
    for (int64_t j = 0; j < N; j++)
        matrix_row(d, band, shift, j, U + j * q);
    for (int64_t j = 0; j < N; j++) {
        double *Uj = U + j * q; /* Uj[c - j] = U(j, c) */
        if (!(Uj[0] > 0.0)) { /* not > 0 (NaN too): the identity, flagged */
            memset(U, 0, (size_t)(N * q) * sizeof(double));
            for (int64_t k = 0; k < N; k++)
                U[k * q] = 1.0;
            return 0;
        }
        Uj[0] = sqrt(Uj[0]);
        const double inv = 1.0 / Uj[0];
        for (int64_t t = 1; t <= p; t++)
            Uj[t] *= inv;
        for (int64_t t = 1; t <= p && j + t < N; t++)
            axpy(U + (j + t) * q, Uj[t], Uj + t, q - t);
    }
    return 1;
}

/* Factor B matrices: band (B, n, w, s, s), shift (B, n, s) or NULL, U (B, N, p + 1),
 * ok (B). */
void tdq_band_factor(const double *band, const double *shift, int64_t B, int64_t n, int64_t w,
                    int64_t s, int64_t N, double *U, uint8_t *ok)
{
    const struct shape d = {n, w, s, N, w * s - 1};
    for (int64_t b = 0; b < B; b++)
        ok[b] = (uint8_t)factor_one(&d, band + b * n * w * s * s,
                                    shift ? shift + b * n * s : NULL, U + b * N * (d.p + 1));
}

/* One right-hand side x (m): L y = x by axpys along U's rows, U x = y by dots. */
static void solve_one(const double *U, int64_t p, int64_t m, double *x)
{
    const int64_t q = p + 1;
    for (int64_t j = 0; j < m; j++) {
        x[j] /= U[j * q];
        axpy(x + j + 1, x[j], U + j * q + 1, (j + p < m - 1 ? j + p : m - 1) - j);
    }
    for (int64_t i = m - 1; i >= 0; i--) {
        const int64_t len = (i + p < m - 1 ? i + p : m - 1) - i;
        x[i] = (x[i] - dot(U + i * q + 1, x + i + 1, len)) / U[i * q];
    }
}

/* r right-hand sides x (m, r) a row at a time: row j's multiple of each later row. */
static void solve_rows(const double *U, int64_t p, int64_t m, int64_t r, double *x)
{
    const int64_t q = p + 1;
    for (int64_t j = 0; j < m; j++) {
        double *xj = x + j * r;
        const double inv = 1.0 / U[j * q];
        for (int64_t c = 0; c < r; c++)
            xj[c] *= inv;
        const int64_t hi = j + p < m - 1 ? j + p : m - 1;
        for (int64_t i = j + 1; i <= hi; i++)
            axpy(x + i * r, U[j * q + i - j], xj, r);
    }
    for (int64_t i = m - 1; i >= 0; i--) {
        double *xi = x + i * r;
        const int64_t hi = i + p < m - 1 ? i + p : m - 1;
        for (int64_t k = i + 1; k <= hi; k++)
            axpy(xi, U[i * q + k - i], x + k * r, r);
        const double inv = 1.0 / U[i * q];
        for (int64_t c = 0; c < r; c++)
            xi[c] *= inv;
    }
}

/* Solve A x = rhs in place for B elements: x (B, m, r) (m <= N the rows solved: those past
 * n s are identity rows, uncoupled), U (B, N, p + 1). */
void tdq_band_solve(const double *U, int64_t B, int64_t N, int64_t p, int64_t m, int64_t r,
                    double *x)
{
    for (int64_t b = 0; b < B; b++) {
        if (r == 1)
            solve_one(U + b * N * (p + 1), p, m, x + b * m);
        else
            solve_rows(U + b * N * (p + 1), p, m, r, x + b * m * r);
    }
}

/* Row i of Z (its entries j >= i) from rows i + 1 .. i + p of the buffer Z (R rows of
 * width W = 2 P + 1, row r at slot r % R, column j at j - r + P), mirrored into the rows
 * after it; L(k, i) = U(i, k) is row i of U. */
static void inverse_row(const double *U, int64_t N, int64_t p, int64_t P, double *Z,
                        int64_t i)
{
    const int64_t q = p + 1, R = P + 1, W = 2 * P + 1;
    const int64_t kmax = i + p < N - 1 ? i + p : N - 1, jmax = i + P < N - 1 ? i + P : N - 1;
    const double *Ui = U + i * q - i; /* Ui[k] = U(i, k) */
    double *Zi = Z + (i % R) * W + P - i; /* Zi[j] = Z(i, j) */
    memset(Z + (i % R) * W, 0, (size_t)W * sizeof(double));
    for (int64_t k = i + 1; k <= kmax; k++) /* Zi[j] += U(i, k) Z(k, j) */
        axpy(Zi + i + 1, -Ui[k], Z + (k % R) * W + P - k + i + 1, jmax - i);
    const double inv = 1.0 / Ui[i];
    for (int64_t j = i + 1; j <= jmax; j++) {
        Zi[j] *= -inv;
        Z[(j % R) * W + P - j + i] = Zi[j];
    }
    Zi[i] = (inv - dot(Ui + i + 1, Zi + i + 1, kmax - i)) * inv;
}

/* Copy the blocks of A^-1 whose first row is i out of the buffer Z: where b > 0 and i % b
 * == 0 the grouped matrix's diag[i / b] and sub[i / b] (b x b each, sub zero for the last
 * group); where s > 0, i % s == 0 and i < n s the band's blocks (i / s, i / s + d), d < w
 * (w s x s, zero past the last block row). */
static void emit(const double *Z, int64_t P, int64_t N, int64_t i, int64_t b, double *diag,
                 double *sub, int64_t n, int64_t w, int64_t s, double *band)
{
    const int64_t R = P + 1, W = 2 * P + 1;
    if (b > 0 && i % b == 0) {
        const int64_t j = i / b;
        for (int64_t a = 0; a < b; a++)
            for (int64_t c = 0; c < b; c++) {
                diag[(j * b + a) * b + c] = Z[((i + a) % R) * W + c - a + P];
                sub[(j * b + a) * b + c] = i + b < N ? Z[((i + b + a) % R) * W + c - a - b + P]
                                                     : 0.0;
            }
    }
    if (s > 0 && i % s == 0 && i < n * s) {
        const int64_t k = i / s;
        for (int64_t d = 0; d < w; d++)
            for (int64_t a = 0; a < s; a++)
                for (int64_t c = 0; c < s; c++)
                    band[((k * w + d) * s + a) * s + c] =
                        k + d < n ? Z[((i + a) % R) * W + d * s + c - a + P] : 0.0;
    }
}

/* Blocks of A^-1 for B elements of the factor U (B, N, p + 1): where b > 0 those of the
 * grouped matrix (groups of b = g s rows, G = N / b): diag (B, G, b, b), sub (B, G, b, b)
 * (sub[j] groups (j + 1, j)); where s > 0 those inside the band of n block rows of s,
 * band (B, n, w, s, s) as the matrix's (block (k, k + d) at [k, d]). The recursion runs to
 * P = 2 b - 1 off the diagonal for the first, p for the second alone. Returns 0, or -1 where
 * the buffer could not be allocated. */
int tdq_band_selected_inverse(const double *U, int64_t B, int64_t N, int64_t p, int64_t b,
                              double *diag, double *sub, int64_t n, int64_t w, int64_t s,
                              double *band)
{
    const int64_t P = b > 0 ? 2 * b - 1 : p, W = 2 * P + 1;
    double *Z = malloc((size_t)((P + 1) * W) * sizeof(double));
    if (!Z)
        return -1;
    for (int64_t e = 0; e < B; e++) {
        const double *Ue = U + e * N * (p + 1);
        for (int64_t i = N - 1; i >= 0; i--) {
            inverse_row(Ue, N, p, P, Z, i);
            emit(Z, P, N, i, b, b > 0 ? diag + e * N * b : NULL, b > 0 ? sub + e * N * b : NULL,
                 n, w, s, s > 0 ? band + e * n * w * s * s : NULL);
        }
    }
    free(Z);
    return 0;
}
