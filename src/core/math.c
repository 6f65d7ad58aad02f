/* Small 3×3 math, rigid transforms and triangle-mesh measures. */
#include "core.h"

#include <stdlib.h>
#include <string.h>

DrMat3 dr_m3_identity(void)
{
    DrMat3 r = {{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};
    return r;
}

DrMat3 dr_m3_mul(DrMat3 a, DrMat3 b)
{
    DrMat3 r;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) r.m[i][j] = a.m[i][0] * b.m[0][j] + a.m[i][1] * b.m[1][j] + a.m[i][2] * b.m[2][j];
    return r;
}

DrMat3 dr_m3_transpose(DrMat3 a)
{
    DrMat3 r;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) r.m[i][j] = a.m[j][i];
    return r;
}

DrVec3 dr_m3_apply(DrMat3 a, DrVec3 v)
{
    return dr_v3(a.m[0][0] * v.x + a.m[0][1] * v.y + a.m[0][2] * v.z,
                 a.m[1][0] * v.x + a.m[1][1] * v.y + a.m[1][2] * v.z,
                 a.m[2][0] * v.x + a.m[2][1] * v.y + a.m[2][2] * v.z);
}

DrMat3 dr_m3_from_euler_xyz(DrVec3 r)
{
    double cx = cos(r.x), sx = sin(r.x), cy = cos(r.y), sy = sin(r.y), cz = cos(r.z), sz = sin(r.z);
    DrMat3 rx = {{{1, 0, 0}, {0, cx, -sx}, {0, sx, cx}}};
    DrMat3 ry = {{{cy, 0, sy}, {0, 1, 0}, {-sy, 0, cy}}};
    DrMat3 rz = {{{cz, -sz, 0}, {sz, cz, 0}, {0, 0, 1}}};
    return dr_m3_mul(rz, dr_m3_mul(ry, rx));
}

DrMat3 dr_m3_rotation_exp(DrVec3 w)
{
    double th = dr_v3_norm(w);
    double a = th > 1e-8 ? sin(th) / th : 1.0 - th * th / 6.0;
    double b = th > 1e-8 ? (1.0 - cos(th)) / (th * th) : 0.5 - th * th / 24.0;
    DrMat3 K = {{{0, -w.z, w.y}, {w.z, 0, -w.x}, {-w.y, w.x, 0}}}; /* [w]× */
    DrMat3 K2 = dr_m3_mul(K, K), R;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) R.m[i][j] = (i == j ? 1.0 : 0.0) + a * K.m[i][j] + b * K2.m[i][j];
    return R;
}

DrVec3 dr_m3_rotation_log(DrMat3 R)
{
    double c = 0.5 * (R.m[0][0] + R.m[1][1] + R.m[2][2] - 1.0); /* cos θ */
    c = c > 1.0 ? 1.0 : (c < -1.0 ? -1.0 : c);
    DrVec3 v = dr_v3(R.m[2][1] - R.m[1][2], R.m[0][2] - R.m[2][0], R.m[1][0] - R.m[0][1]); /* 2 sin θ · axis */
    if (c >= 0.0) {
        /* θ ≤ π/2: w = v θ/(2 sin θ). acos loses digits as θ → 0 (δθ ≈ ε/sin θ), but θ enters only through
           θ/sin θ, which that moves by θ δθ/3 ≈ ε/3: w keeps the round-off of v. Below θ = 1e-6, θ/sin θ is 1 to
           within θ²/6 < 2e-13. */
        double th = acos(c);
        if (th < 1e-6) return dr_v3_scale(v, 0.5);
        return dr_v3_scale(v, th / (2.0 * sin(th)));
    }
    /* θ > π/2: as sin θ → 0 near a half turn, v/|v| and acos(c) lose digits (ε/sin θ each). The angle from
       atan2(sin θ, cos θ), right to a few ε; the axis a from the symmetric part
       (R + Rᵀ)/2 − cos θ I = (1 − cos θ) a aᵀ, its column with the largest diagonal normalised (1 − cos θ > 1, so a
       keeps the round-off of R), its sign from v (at θ = π either sign is the same rotation). */
    double th = atan2(0.5 * dr_v3_norm(v), c);
    int k = 0;
    for (int i = 1; i < 3; i++)
        if (R.m[i][i] > R.m[k][k]) k = i;
    double col[3];
    for (int i = 0; i < 3; i++) col[i] = 0.5 * (R.m[i][k] + R.m[k][i]) - (i == k ? c : 0.0);
    DrVec3 a = dr_v3_normalize(dr_v3(col[0], col[1], col[2]));
    if (dr_v3_dot(a, v) < 0.0) a = dr_v3_scale(a, -1.0);
    return dr_v3_scale(a, th);
}

DrXform dr_xform_identity(void)
{
    DrXform x = {dr_m3_identity(), {0, 0, 0}};
    return x;
}

DrVec3 dr_xform_apply(DrXform x, DrVec3 p) { return dr_v3_add(dr_m3_apply(x.R, p), x.t); }

DrVec3 dr_xform_apply_inverse(DrXform x, DrVec3 p)
{
    return dr_m3_apply(dr_m3_transpose(x.R), dr_v3_sub(p, x.t));
}

void dr_trimesh_free(DrTriMesh *m)
{
    if (!m) return;
    free(m->v);
    free(m->tri);
    free(m->n);
    free(m->uv);
    memset(m, 0, sizeof *m);
}

double dr_trimesh_volume(const DrTriMesh *m)
{
    double vol = 0.0;
    for (int t = 0; t < m->nt; t++) {
        const double *a = m->v + 3 * m->tri[3 * t], *b = m->v + 3 * m->tri[3 * t + 1], *c = m->v + 3 * m->tri[3 * t + 2];
        DrVec3 A = dr_v3(a[0], a[1], a[2]), B = dr_v3(b[0], b[1], b[2]), C = dr_v3(c[0], c[1], c[2]);
        vol += dr_v3_dot(A, dr_v3_cross(B, C)) / 6.0;
    }
    return vol;
}

bool dr_trimesh_bounds(const DrTriMesh *m, DrVec3 *lo, DrVec3 *hi)
{
    if (m->nv <= 0) return false;
    *lo = *hi = dr_v3(m->v[0], m->v[1], m->v[2]);
    for (int i = 1; i < m->nv; i++) {
        DrVec3 p = dr_v3(m->v[3 * i], m->v[3 * i + 1], m->v[3 * i + 2]);
        *lo = dr_v3_min(*lo, p);
        *hi = dr_v3_max(*hi, p);
    }
    return true;
}

static int edge_cmp(const void *a, const void *b)
{
    const int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

bool dr_trimesh_is_closed(const DrTriMesh *m)
{
    if (m->nt <= 0) return false;
    /* Each directed edge (a,b) must appear once and its reverse (b,a) once. */
    size_t ne = 3 * (size_t)m->nt;
    int64_t *e = malloc(ne * sizeof *e);
    if (!e) return false;
    for (int t = 0; t < m->nt; t++)
        for (int k = 0; k < 3; k++) {
            int64_t a = m->tri[3 * t + k], b = m->tri[3 * t + (k + 1) % 3];
            e[3 * t + k] = a * (int64_t)m->nv + b;
        }
    qsort(e, ne, sizeof *e, edge_cmp);
    bool ok = true;
    for (size_t i = 0; i < ne && ok; i++) {
        if (i + 1 < ne && e[i] == e[i + 1]) ok = false; /* duplicated directed edge */
        int64_t a = e[i] / m->nv, b = e[i] % m->nv;
        int64_t rev = b * (int64_t)m->nv + a;
        if (!bsearch(&rev, e, ne, sizeof *e, edge_cmp)) ok = false;
    }
    free(e);
    return ok;
}

void dr_m3a_sym_eigen(const double Ain[9], double e[3], double V[9])
{
    double A[9];
    memcpy(A, Ain, sizeof A);
    for (int k = 0; k < 9; k++) V[k] = (k % 4 == 0) ? 1.0 : 0.0;
    for (int sweep = 0; sweep < 30; sweep++) {
        double off = A[1] * A[1] + A[2] * A[2] + A[5] * A[5];
        double diag = A[0] * A[0] + A[4] * A[4] + A[8] * A[8];
        if (off <= 1e-32 * diag || off == 0.0) break;
        static const int PQ[3][2] = {{0, 1}, {0, 2}, {1, 2}};
        for (int r = 0; r < 3; r++) {
            int p = PQ[r][0], q = PQ[r][1];
            double apq = A[3 * p + q];
            if (apq == 0.0) continue;
            double theta = (A[3 * q + q] - A[3 * p + p]) / (2.0 * apq);
            double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
            double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
            /* A ← Jᵀ A J, J the rotation in the (p, q) plane */
            for (int k = 0; k < 3; k++) {
                double akp = A[3 * k + p], akq = A[3 * k + q];
                A[3 * k + p] = c * akp - s * akq;
                A[3 * k + q] = s * akp + c * akq;
            }
            for (int k = 0; k < 3; k++) {
                double apk = A[3 * p + k], aqk = A[3 * q + k];
                A[3 * p + k] = c * apk - s * aqk;
                A[3 * q + k] = s * apk + c * aqk;
            }
            for (int k = 0; k < 3; k++) {
                double vkp = V[3 * k + p], vkq = V[3 * k + q];
                V[3 * k + p] = c * vkp - s * vkq;
                V[3 * k + q] = s * vkp + c * vkq;
            }
        }
    }
    e[0] = A[0], e[1] = A[4], e[2] = A[8];
}
