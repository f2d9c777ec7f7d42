/* The normal equations of a term's samples, summed in one pass over the samples (the
 * compiled counterpart of torch_dq/fitting/_normal.py's _window_normal and _Normal.add,
 * called from _Normal.add_samples through ctypes).
 *
 * Sample s has k rows: J_c (k, w, 6) with respect to the steps of the w control points
 * f .. f + w - 1 of its window f, J_n (k, Mt) with respect to the term's nuisance columns,
 * the whitened residual r (k) and the robust weight wt. Its rows Y = sqrt(wt) [J_c | J_n'
 * | r] (J_n' the M columns its window u uses: the term's local[u], the problem's gcol[u],
 * -1 where none) add Y^T Y to the normal equations of its window, summed in an
 * accumulator (the upper triangle of q x q, q = 6 w + M + 1) while consecutive samples
 * share the window, then added to each destination set (the sum's blocks, and a term's
 * own where it has them) as
 *   band (G, w, 6, 6): block (a, a + d) of the window at (f + a, d), d = 0 .. w - 1 - a
 *   gc   (G, 6):       Y_a^T r at control point f + a
 *   cn   (G, 6, m):    Y_a^T Y_n at row f + a, problem column gcol
 *   nn   (B, m, m), gn (B, m): the nuisance blocks of the window's batch row
 * G = B (n + w) windows; sample s's window is f = win[s] + lo, its batch row f / (n + w).
 * Arrays are float64 (int64 indices); the inputs' element strides are given (the span
 * products' rows are component-major), the outputs are dense. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define BLOCK 32 /* samples whose rows are read at once: in the component-major layout each
                  * input component of a block of samples is one run of memory */

struct dims {
    int64_t S, k, w, M, m, nw, lo;
    int64_t q, p; /* columns of a row, and its stride (q rounded up to 4: whole vectors) */
};

/* Add the window's accumulated upper triangle A (q x p) to one destination set
 * out = {band, gc, cn, nn, gn}. */
static void flush(const struct dims *d, const double *A, int64_t f, const int64_t *gcol,
                  double *const *out)
{
    const int64_t w = d->w, M = d->M, m = d->m, q = d->q, p = d->p, nc = 6 * w;
    double *band = out[0], *gc = out[1], *cn = out[2];
    for (int64_t a = 0; a < w; a++) {
        double *row = band + (f + a) * w * 36;
        for (int64_t e = a; e < w; e++) {
            double *dst = row + (e - a) * 36;
            for (int64_t c1 = 0; c1 < 6; c1++)
                for (int64_t c2 = 0; c2 < 6; c2++) {
                    const int64_t i = 6 * a + c1, j = 6 * e + c2;
                    dst[6 * c1 + c2] += i <= j ? A[i * p + j] : A[j * p + i];
                }
        }
        for (int64_t c = 0; c < 6; c++) {
            const double *Ai = A + (6 * a + c) * p;
            gc[(f + a) * 6 + c] += Ai[q - 1];
            for (int64_t j = 0; j < M; j++)
                if (gcol[j] >= 0)
                    cn[((f + a) * 6 + c) * m + gcol[j]] += Ai[nc + j];
        }
    }
    double *nn = out[3] + (f / d->nw) * m * m, *gn = out[4] + (f / d->nw) * m;
    for (int64_t j1 = 0; j1 < M; j1++) {
        if (gcol[j1] < 0)
            continue;
        const double *Aj = A + (nc + j1) * p;
        gn[gcol[j1]] += Aj[q - 1];
        for (int64_t j2 = 0; j2 < M; j2++)
            if (gcol[j2] >= 0)
                nn[gcol[j1] * m + gcol[j2]] += j1 <= j2 ? Aj[nc + j2]
                                                        : A[(nc + j2) * p + nc + j1];
    }
}

/* The weighted rows Y (k x p each, dense, zero past q) of samples s0 .. s0 + B - 1. */
static void rows(const struct dims *d, int64_t s0, int64_t B, const int64_t *st,
                 const double *jc, const double *jn, const double *r, const double *wt,
                 const int64_t *win, const int64_t *local, const int64_t *gcol, double *Y)
{
    const int64_t w = d->w, M = d->M, q = d->q, p = d->p, k = d->k, nc = 6 * w, kp = k * p;
    const int64_t s_jc = st[0];
    double sw[BLOCK];
    for (int64_t b = 0; b < B; b++)
        sw[b] = sqrt(wt[(s0 + b) * st[9]]);
    for (int64_t i = 0; i < k; i++) {
        for (int64_t a = 0; a < w; a++)
            for (int64_t c = 0; c < 6; c++) {
                const double *x = jc + s0 * s_jc + i * st[1] + a * st[2] + c * st[3];
                double *y = Y + i * p + 6 * a + c;
                for (int64_t b = 0; b < B; b++)
                    y[b * kp] = x[b * s_jc] * sw[b];
            }
        for (int64_t b = 0; b < B; b++) {
            const int64_t u = win[s0 + b], *loc = local + u * M, *g = gcol + u * M;
            const double *ni = jn + (s0 + b) * st[4] + i * st[5];
            double *y = Y + b * kp + i * p;
            for (int64_t j = 0; j < M; j++)
                y[nc + j] = g[j] < 0 ? 0.0 : ni[loc[j] * st[6]] * sw[b];
            y[q - 1] = r[(s0 + b) * st[7] + i * st[8]] * sw[b];
            for (int64_t j = q; j < p; j++)
                y[j] = 0.0;
        }
    }
}

/* A (q x p; its upper triangle, and some entries below it) += Y^T Y of n rows Y (n x p),
 * four columns at a time from the diagonal's vector on (n constant where inlined: the
 * rows' sum in registers, a row of A read and written once per n rows). */
static inline __attribute__((always_inline)) void
rank_update(int n, int64_t q, int64_t p, const double *restrict Y, double *restrict A)
{
    for (int64_t i = 0; i < q; i++) {
        double *restrict Ai = A + i * p;
        double a[6];
        for (int l = 0; l < n; l++)
            a[l] = Y[l * p + i];
        for (int64_t j = i & ~(int64_t)3; j < p; j += 4)
            for (int t = 0; t < 4; t++) {
                double sum = Ai[j + t];
                for (int l = 0; l < n; l++)
                    sum += a[l] * Y[l * p + j + t];
                Ai[j + t] = sum;
            }
    }
}

/* A += Y^T Y of the R rows Y (R x p): six rows at a time, then the rest. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__GLIBC__)
/* a clone for AVX and FMA, chosen at load time where the processor has them (the build's
 * flags target the baseline x86-64; GCC's ifunc dispatch, glibc's loader) */
__attribute__((target_clones("fma", "default")))
#endif
static void gram(int64_t q, int64_t p, int64_t R, const double *restrict Y,
                 double *restrict A)
{
    int64_t l = 0;
    for (; l + 6 <= R; l += 6)
        rank_update(6, q, p, Y + l * p, A);
    if (R - l >= 3) {
        rank_update(3, q, p, Y + l * p, A);
        l += 3;
    }
    if (R - l == 2)
        rank_update(2, q, p, Y + l * p, A);
    else if (R - l == 1)
        rank_update(1, q, p, Y + l * p, A);
}

/* flush of window rel + lo's sum A to the destination sets out (one or two). */
static void add(const struct dims *d, const double *A, int64_t rel, const int64_t *gcol,
                double *const *out)
{
    for (int o = 0; o < 2 && out[5 * o] != NULL; o++)
        flush(d, A, rel + d->lo, gcol + rel * d->M, out + 5 * o);
}

/* dims: S, k, w, M, m, nw (= n + w), lo, then the element strides of jc (4), jn (3),
 * r (2) and wt (1). win (S), local and gcol (windows, M): dense. out: {band, gc, cn, nn,
 * gn} of the sum, then those of the term's own blocks or five NULL. Returns 0, or -1
 * where its buffers could not be allocated. */
int tdq_normal_add(const int64_t *dims, const int64_t *win, const int64_t *local,
                   const int64_t *gcol, double *const *out, const double *jc,
                   const double *jn, const double *r, const double *wt)
{
    struct dims d = {dims[0], dims[1], dims[2], dims[3], dims[4], dims[5], dims[6], 0, 0};
    d.q = 6 * d.w + d.M + 1;
    d.p = (d.q + 3) & ~(int64_t)3;
    const int64_t q = d.q, p = d.p, k = d.k, *st = dims + 7;
    double *A = malloc(sizeof(double) * (size_t)(q * p + BLOCK * k * p));
    if (A == NULL)
        return -1;
    double *Y = A + q * p;
    int64_t cur = -1; /* the window being summed */
    for (int64_t s0 = 0; s0 < d.S; s0 += BLOCK) {
        const int64_t B = d.S - s0 < BLOCK ? d.S - s0 : BLOCK;
        rows(&d, s0, B, st, jc, jn, r, wt, win, local, gcol, Y);
        for (int64_t b = 0, e; b < B; b = e) { /* a run of samples of one window */
            if (win[s0 + b] != cur) {
                if (cur >= 0)
                    add(&d, A, cur, gcol, out);
                memset(A, 0, sizeof(double) * (size_t)(q * p));
                cur = win[s0 + b];
            }
            for (e = b + 1; e < B && win[s0 + e] == cur; e++)
                ;
            gram(q, p, (e - b) * k, Y + b * k * p, A);
        }
    }
    if (cur >= 0)
        add(&d, A, cur, gcol, out);
    free(A);
    return 0;
}
