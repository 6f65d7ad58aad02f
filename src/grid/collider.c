/* Rigid colliders: dense rest-frame SDF + keyed pose; see grid.h. */
#include "grid/grid.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

struct DrCollider {
    float *phi;
    int nx, ny, nz;
    DrVec3 origin;
    double dx;
    double friction, thickness;
    bool no_slip;
    int nkeys, cap_keys;
    double *keys; /* nkeys rows of 7 (room for cap_keys) */
    uint64_t id;  /* unique per process (dr_collider_id) */
};

static atomic_uint_fast64_t next_id = 1;

static DrStatus check_keys(const double *keys, int nkeys, DrError *err)
{
    if (nkeys < 0 || (nkeys > 0 && !keys))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "collider keys: %d rows but no data.", nkeys);
    for (int k = 0; k < nkeys; k++) {
        for (int c = 0; c < 7; c++)
            if (!isfinite(keys[7 * k + c]))
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "collider key %d column %d is not finite.",
                                    k, c);
        if (k > 0 && !(keys[7 * k] > keys[7 * (k - 1)]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "collider key times must increase strictly (key %d at %g s after %g s).", k,
                                keys[7 * k], keys[7 * (k - 1)]);
    }
    return DR_OK;
}

DrStatus dr_collider_create(const DrColliderDesc *desc, DrCollider **out, DrError *err)
{
    *out = NULL;
    if (!desc->phi || desc->nx < 2 || desc->ny < 2 || desc->nz < 2)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "collider SDF needs at least 2 nodes per axis (got %d x %d x %d).", desc->nx,
                            desc->ny, desc->nz);
    if (!(desc->dx > 0.0) || !isfinite(desc->dx) || !dr_v3_isfinite(desc->origin))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "collider SDF voxel size must be positive (got %g).",
                            desc->dx);
    if (!(desc->friction >= 0.0) || !isfinite(desc->friction) || !isfinite(desc->thickness))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "collider friction must be finite and >= 0, thickness finite (got %g, %g).",
                            desc->friction, desc->thickness);
    DR_TRY(check_keys(desc->keys, desc->nkeys, err));
    size_t n = 0;
    if (dr_mul_overflows((size_t)desc->nx, (size_t)desc->ny, &n) || dr_mul_overflows(n, (size_t)desc->nz, &n))
        return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "collider SDF size overflows.");
    DrCollider *c = NULL;
    DR_TRY(dr_calloc(1, sizeof *c, &c, err));
    DrStatus s = dr_calloc(n, sizeof(float), &c->phi, err);
    if (s >= 0 && desc->nkeys > 0) s = dr_calloc((size_t)desc->nkeys * 7, sizeof(double), &c->keys, err);
    if (s < 0) { dr_collider_destroy(&c); return s; }
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(desc->phi[i])) {
            dr_collider_destroy(&c);
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "collider SDF value %zu is not finite.", i);
        }
    }
    memcpy(c->phi, desc->phi, n * sizeof(float));
    if (desc->nkeys > 0) memcpy(c->keys, desc->keys, (size_t)desc->nkeys * 7 * sizeof(double));
    c->nx = desc->nx; c->ny = desc->ny; c->nz = desc->nz;
    c->origin = desc->origin; c->dx = desc->dx;
    c->friction = desc->friction; c->thickness = desc->thickness; c->no_slip = desc->no_slip;
    c->nkeys = desc->nkeys;
    c->cap_keys = desc->nkeys;
    c->id = (uint64_t)atomic_fetch_add(&next_id, 1);
    *out = c;
    return DR_OK;
}

DrStatus dr_collider_set_keys(DrCollider *c, const double *keys, int nkeys, DrError *err)
{
    DR_TRY(check_keys(keys, nkeys, err));
    if (nkeys > c->cap_keys) {
        DR_TRY(dr_realloc((size_t)nkeys * 7, sizeof(double), &c->keys, err));
        c->cap_keys = nkeys;
    }
    if (nkeys > 0) memcpy(c->keys, keys, (size_t)nkeys * 7 * sizeof(double));
    c->nkeys = nkeys;
    c->id = (uint64_t)atomic_fetch_add(&next_id, 1); /* another motion: caches keyed by the id start over */
    return DR_OK;
}

void dr_collider_destroy(DrCollider **c)
{
    if (!c || !*c) return;
    free((*c)->phi);
    free((*c)->keys);
    free(*c);
    *c = NULL;
}

double dr_collider_friction(const DrCollider *c) { return c->friction; }
bool dr_collider_no_slip(const DrCollider *c) { return c->no_slip; }
bool dr_collider_static(const DrCollider *c) { return c->nkeys <= 1; }
uint64_t dr_collider_id(const DrCollider *c) { return c->id; }

/* Interpolated key row at time t (translation and Euler angles) and its time derivative. */
static void keys_state(const double *K, int nkeys, double t, double st[6], double rate[6])
{
    for (int i = 0; i < 6; i++) { st[i] = 0.0; rate[i] = 0.0; }
    if (nkeys == 0) return;
    if (t <= K[0]) { for (int i = 0; i < 6; i++) st[i] = K[1 + i]; return; }
    const double *L = K + 7 * (nkeys - 1);
    if (t >= L[0]) { for (int i = 0; i < 6; i++) st[i] = L[1 + i]; return; }
    int k = 0;
    while (K[7 * (k + 1)] <= t) k++;
    const double *a = K + 7 * k, *b = a + 7;
    double h = b[0] - a[0], s = (t - a[0]) / h;
    for (int i = 0; i < 6; i++) {
        st[i] = a[1 + i] + s * (b[1 + i] - a[1 + i]);
        rate[i] = (b[1 + i] - a[1 + i]) / h;
    }
}

static void key_state(const DrCollider *c, double t, double st[6], double rate[6])
{
    keys_state(c->keys, c->nkeys, t, st, rate);
}

DrXform dr_motion_pose(const double *keys, int nkeys, double t)
{
    double st[6], rate[6];
    keys_state(keys, nkeys, t, st, rate);
    DrXform x;
    x.R = dr_m3_from_euler_xyz(dr_v3(st[3], st[4], st[5]));
    x.t = dr_v3(st[0], st[1], st[2]);
    return x;
}

DrXform dr_collider_pose(const DrCollider *c, double t)
{
    double st[6], rate[6];
    key_state(c, t, st, rate);
    DrXform x;
    x.R = dr_m3_from_euler_xyz(dr_v3(st[3], st[4], st[5]));
    x.t = dr_v3(st[0], st[1], st[2]);
    return x;
}

DrColliderFrame dr_collider_frame(const DrCollider *c, double t)
{
    DrColliderFrame f;
    double st[6], rate[6];
    key_state(c, t, st, rate);
    f.c = c;
    f.pose.R = dr_m3_from_euler_xyz(dr_v3(st[3], st[4], st[5]));
    f.pose.t = dr_v3(st[0], st[1], st[2]);
    f.lin_vel = dr_v3(rate[0], rate[1], rate[2]);
    /* ω from Ṙ Rᵀ (skew); Ṙ by central differences along the straight line in Euler space, whose
       truncation error is O(h²) relative (h = 1e-5 rad·s per unit rate) — far below any use here. */
    double h = 1e-5;
    DrMat3 Rp = dr_m3_from_euler_xyz(dr_v3(st[3] + h * rate[3], st[4] + h * rate[4], st[5] + h * rate[5]));
    DrMat3 Rm = dr_m3_from_euler_xyz(dr_v3(st[3] - h * rate[3], st[4] - h * rate[4], st[5] - h * rate[5]));
    DrMat3 Rd;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) Rd.m[i][j] = (Rp.m[i][j] - Rm.m[i][j]) / (2.0 * h);
    DrMat3 W = dr_m3_mul(Rd, dr_m3_transpose(f.pose.R));
    f.omega = dr_v3(0.5 * (W.m[2][1] - W.m[1][2]), 0.5 * (W.m[0][2] - W.m[2][0]), 0.5 * (W.m[1][0] - W.m[0][1]));
    return f;
}

/* Rest-frame phi (without thickness): trilinear inside the box, distance to the box plus the
   boundary value outside. */
static double rest_phi(const DrCollider *c, DrVec3 p)
{
    double s[3] = {(p.x - c->origin.x) / c->dx, (p.y - c->origin.y) / c->dx, (p.z - c->origin.z) / c->dx};
    int n[3] = {c->nx, c->ny, c->nz};
    double out2 = 0.0;
    int base[3];
    double f[3];
    for (int d = 0; d < 3; d++) {
        double hi = n[d] - 1;
        double cl = s[d] < 0.0 ? 0.0 : (s[d] > hi ? hi : s[d]);
        double o = (s[d] - cl) * c->dx;
        out2 += o * o;
        int b = (int)floor(cl);
        if (b > n[d] - 2) b = n[d] - 2;
        base[d] = b;
        f[d] = cl - b;
    }
    double v = 0.0;
    for (int kk = 0; kk < 2; kk++)
        for (int jj = 0; jj < 2; jj++)
            for (int ii = 0; ii < 2; ii++) {
                double w = (ii ? f[0] : 1 - f[0]) * (jj ? f[1] : 1 - f[1]) * (kk ? f[2] : 1 - f[2]);
                long idx = (long)(base[0] + ii) + (long)c->nx * ((long)(base[1] + jj) + (long)c->ny * (base[2] + kk));
                v += w * (double)c->phi[idx];
            }
    return v + sqrt(out2);
}

double dr_collider_frame_phi(const DrColliderFrame *f, DrVec3 x, DrVec3 *grad)
{
    const DrCollider *c = f->c;
    DrVec3 p = dr_xform_apply_inverse(f->pose, x);
    double v = rest_phi(c, p) - c->thickness;
    if (grad) {
        double h = 0.5 * c->dx;
        DrVec3 g = dr_v3(rest_phi(c, dr_v3(p.x + h, p.y, p.z)) - rest_phi(c, dr_v3(p.x - h, p.y, p.z)),
                         rest_phi(c, dr_v3(p.x, p.y + h, p.z)) - rest_phi(c, dr_v3(p.x, p.y - h, p.z)),
                         rest_phi(c, dr_v3(p.x, p.y, p.z + h)) - rest_phi(c, dr_v3(p.x, p.y, p.z - h)));
        *grad = dr_m3_apply(f->pose.R, dr_v3_normalize(g));
    }
    return v;
}

DrVec3 dr_collider_frame_velocity(const DrColliderFrame *f, DrVec3 x)
{
    return dr_v3_add(f->lin_vel, dr_v3_cross(f->omega, dr_v3_sub(x, f->pose.t)));
}

void dr_collider_frame_bounds(const DrColliderFrame *f, DrVec3 *lo, DrVec3 *hi)
{
    const DrCollider *c = f->c;
    DrVec3 ext = dr_v3((c->nx - 1) * c->dx, (c->ny - 1) * c->dx, (c->nz - 1) * c->dx);
    *lo = dr_v3(INFINITY, INFINITY, INFINITY);
    *hi = dr_v3(-INFINITY, -INFINITY, -INFINITY);
    for (int m = 0; m < 8; m++) {
        DrVec3 p = dr_v3_add(c->origin, dr_v3((m & 1) ? ext.x : 0, (m & 2) ? ext.y : 0, (m & 4) ? ext.z : 0));
        DrVec3 w = dr_xform_apply(f->pose, p);
        *lo = dr_v3_min(*lo, w);
        *hi = dr_v3_max(*hi, w);
    }
}

double dr_collider_phi(const DrCollider *c, double t, DrVec3 x, DrVec3 *grad)
{
    DrColliderFrame f = dr_collider_frame(c, t);
    return dr_collider_frame_phi(&f, x, grad);
}

DrVec3 dr_collider_velocity(const DrCollider *c, double t, DrVec3 x)
{
    DrColliderFrame f = dr_collider_frame(c, t);
    return dr_collider_frame_velocity(&f, x);
}
