/* Quadrature on flat triangles for the boundary integrals of BEM eq. (8) (BEM §4, "Spatial quadrature").
 *
 * Regular pairs: a 9-point rule exact for polynomials of degree 5 on each subtriangle of a 4-way split. The
 * rule is the conical product of 3-point Gauss–Jacobi (weight 1−u) and 3-point Gauss–Legendre on the
 * collapsed square u ∈ [0,1], v ∈ [0,1] → (u, (1−u)v): its nodes lie inside the triangle and its weights are
 * positive. Triangles near the collocation point are split further (the kernels vary on the scale of the
 * distance, not of the triangle).
 *
 * Singular pairs (the collocation point is a vertex of the triangle): polar coordinates about that vertex in
 * Duffy's form y = a + ρ[(b − a) + θ(c − b)], whose Jacobian 2·area·ρ cancels the 1/r singularity of û*, d̂*,
 * l̂*, of p̂*(s) − p*_static, and of p*·Φ_j for the other two vertices (Φ_j vanishes at a). */
#include "bem_internal.h"

#include <math.h>

/* 3-point Gauss–Jacobi on [0,1] for the weight (1−u): nodes are the roots of the cubic orthogonal to 1, u, u²
   under that weight; exact for degree 5 (weights sum to 1/2). */
static const double gj_x[3] = {0.08858795951270394655, 0.40946686444073470882, 0.78765946176084705488};
static const double gj_w[3] = {0.20093191373895962932, 0.22924110635958624746, 0.06982697990145412323};
/* 3-point Gauss–Legendre on [0,1]. */
static const double gl3_x[3] = {0.11270166537925831148, 0.5, 0.88729833462074168852};
static const double gl3_w[3] = {5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0};

int bem_quad_capacity(int levels, int max_levels, int singular_order)
{
    (void)levels;
    int sub = 1;
    for (int l = 0; l < max_levels; l++) sub *= 4;
    int reg = 9 * sub;
    int sing = singular_order * singular_order;
    return reg > sing ? reg : sing;
}

static double dist2(const double *p, const double *q)
{
    double dx = p[0] - q[0], dy = p[1] - q[1], dz = p[2] - q[2];
    return dx * dx + dy * dy + dz * dz;
}

static double tri_area(const double *a, const double *b, const double *c)
{
    double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
    return 0.5 * sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
}

/* A subtriangle in barycentric coordinates of the parent (rows: its three corners as (λa, λb, λc)). */
typedef struct Sub {
    double l[3][3];
} Sub;

typedef struct Ctx {
    const double *a, *b, *c, *x;
    double area;
    int max_levels, levels;
    double near2; /* near_factor² */
    BemQuadPoint *out;
    int n, cap;
} Ctx;

static void bary_to_xyz(const Ctx *q, const double l[3], double y[3])
{
    for (int k = 0; k < 3; k++) y[k] = l[0] * q->a[k] + l[1] * q->b[k] + l[2] * q->c[k];
}

static void emit9(Ctx *q, const Sub *s, double sub_area)
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double u = gj_x[i], v = (1.0 - gj_x[i]) * gl3_x[j];
            double w = 2.0 * gj_w[i] * gl3_w[j] * sub_area; /* the weights sum to 1/2 on the unit triangle */
            double l[3];
            for (int k = 0; k < 3; k++) l[k] = (1.0 - u - v) * s->l[0][k] + u * s->l[1][k] + v * s->l[2][k];
            assert(q->n < q->cap);
            BemQuadPoint *p = &q->out[q->n++];
            bary_to_xyz(q, l, p->y);
            p->w = w;
            p->phi[0] = l[0];
            p->phi[1] = l[1];
            p->phi[2] = l[2];
        }
}

static void refine(Ctx *q, const Sub *s, int depth, double sub_area)
{
    bool split = depth < q->levels;
    if (!split && depth < q->max_levels) {
        double p[3][3], cen[3] = {0, 0, 0};
        for (int i = 0; i < 3; i++) {
            bary_to_xyz(q, s->l[i], p[i]);
            for (int k = 0; k < 3; k++) cen[k] += p[i][k] / 3.0;
        }
        double diam2 = fmax(dist2(p[0], p[1]), fmax(dist2(p[1], p[2]), dist2(p[2], p[0])));
        split = dist2(cen, q->x) < q->near2 * diam2;
    }
    if (!split) {
        emit9(q, s, sub_area);
        return;
    }
    double m[3][3]; /* edge midpoints: 01, 12, 20 */
    for (int k = 0; k < 3; k++) {
        m[0][k] = 0.5 * (s->l[0][k] + s->l[1][k]);
        m[1][k] = 0.5 * (s->l[1][k] + s->l[2][k]);
        m[2][k] = 0.5 * (s->l[2][k] + s->l[0][k]);
    }
    Sub c4[4];
    const double *corner[4][3] = {{s->l[0], m[0], m[2]}, {m[0], s->l[1], m[1]}, {m[2], m[1], s->l[2]}, {m[0], m[1], m[2]}};
    for (int t = 0; t < 4; t++)
        for (int i = 0; i < 3; i++)
            for (int k = 0; k < 3; k++) c4[t].l[i][k] = corner[t][i][k];
    for (int t = 0; t < 4; t++) refine(q, &c4[t], depth + 1, 0.25 * sub_area);
}

int bem_quad_regular(const double a[3], const double b[3], const double c[3], const double x[3], int levels,
                     int max_levels, double near_factor, BemQuadPoint *out, int cap)
{
    assert(levels >= 0 && max_levels >= levels);
    Ctx q = {.a = a, .b = b, .c = c, .x = x, .area = tri_area(a, b, c), .max_levels = max_levels,
             .levels = levels, .near2 = near_factor * near_factor, .out = out, .n = 0, .cap = cap};
    Sub s = {{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
    refine(&q, &s, 0, q.area);
    return q.n;
}

int bem_quad_singular(const double a[3], const double b[3], const double c[3], int order, BemQuadPoint *out, int cap)
{
    assert(order >= 1 && order <= 64 && order * order <= cap);
    double x[64], w[64];
    bem_gauss_legendre01(order, x, w);
    double two_area = 2.0 * tri_area(a, b, c);
    int n = 0;
    for (int i = 0; i < order; i++) {
        double rho = x[i];
        for (int j = 0; j < order; j++) {
            double th = x[j];
            BemQuadPoint *p = &out[n++];
            /* y = a + ρ(b − a) + ρθ(c − b): barycentric (1 − ρ, ρ(1 − θ), ρθ), Jacobian 2·area·ρ */
            p->phi[0] = 1.0 - rho;
            p->phi[1] = rho * (1.0 - th);
            p->phi[2] = rho * th;
            for (int k = 0; k < 3; k++) p->y[k] = p->phi[0] * a[k] + p->phi[1] * b[k] + p->phi[2] * c[k];
            p->w = w[i] * w[j] * two_area * rho;
        }
    }
    return n;
}

void bem_gauss_legendre01(int n, double *x, double *w)
{
    assert(n >= 1 && n <= 64);
    /* Newton on the Legendre polynomial P_n from the Chebyshev-like first guesses; converges to round-off in
       a few steps for every n ≤ 64. */
    for (int i = 0; i < n; i++) {
        double z = cos(M_PI * (i + 0.75) / (n + 0.5)), dp = 1.0;
        for (int it = 0; it < 100; it++) {
            double p0 = 1.0, p1 = z;
            for (int k = 2; k <= n; k++) {
                double p2 = ((2.0 * k - 1.0) * z * p1 - (k - 1.0) * p0) / k;
                p0 = p1;
                p1 = p2;
            }
            double pn = n == 1 ? z : p1, pm = n == 1 ? 1.0 : p0;
            dp = n * (z * pn - pm) / (z * z - 1.0);
            double dz = pn / dp;
            z -= dz;
            if (fabs(dz) < 1e-16) break;
        }
        {
            double p0 = 1.0, p1 = z;
            for (int k = 2; k <= n; k++) {
                double p2 = ((2.0 * k - 1.0) * z * p1 - (k - 1.0) * p0) / k;
                p0 = p1;
                p1 = p2;
            }
            double pn = n == 1 ? z : p1, pm = n == 1 ? 1.0 : p0;
            dp = n * (z * pn - pm) / (z * z - 1.0);
        }
        x[i] = 0.5 * (1.0 - z);
        w[i] = 1.0 / ((1.0 - z * z) * dp * dp); /* 2/((1−z²)P'²) on [−1,1], halved on [0,1] */
    }
}
