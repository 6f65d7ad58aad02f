/* MAC grid storage and sampling; see grid.h. */
#include "grid/grid.h"

#include <stdlib.h>

DrStatus dr_mac_grid_create(int nx, int ny, int nz, double dx, DrVec3 origin, DrMacGrid **out,
                            DrError *err)
{
    *out = NULL;
    if (nx <= 0 || ny <= 0 || nz <= 0 || !(dx > 0.0) || !isfinite(dx) || !dr_v3_isfinite(origin))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "MAC grid needs positive cell counts and spacing (got %d x %d x %d, dx %g).",
                            nx, ny, nz, dx);
    DrMacGrid *g = NULL;
    DR_TRY(dr_calloc(1, sizeof *g, &g, err));
    g->nx = nx; g->ny = ny; g->nz = nz; g->dx = dx; g->origin = origin;
    int n[3] = {nx, ny, nz};
    for (int a = 0; a < 3; a++) {
        size_t cnt = 1;
        for (int d = 0; d < 3; d++) {
            g->fdim[a][d] = n[d] + (a == d);
            if (dr_mul_overflows(cnt, (size_t)g->fdim[a][d], &cnt)) {
                dr_mac_grid_destroy(&g);
                return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "MAC grid size overflows; use a larger dx.");
            }
        }
        g->nfaces[a] = (long)cnt;
        DrStatus s = dr_calloc(cnt, sizeof(double), &g->f[a], err);
        if (s < 0) { dr_mac_grid_destroy(&g); return s; }
    }
    *out = g;
    return DR_OK;
}

void dr_mac_grid_destroy(DrMacGrid **g)
{
    if (!g || !*g) return;
    for (int a = 0; a < 3; a++) free((*g)->f[a]);
    free(*g);
    *g = NULL;
}

DrStatus dr_face_coupling_create(const DrMacGrid *g, DrFaceCoupling **out, DrError *err)
{
    *out = NULL;
    DrFaceCoupling *fc = NULL;
    DR_TRY(dr_calloc(1, sizeof *fc, &fc, err));
    for (int a = 0; a < 3; a++) {
        fc->nfaces[a] = g->nfaces[a];
        DrStatus s = dr_calloc((size_t)g->nfaces[a], sizeof(double), &fc->open[a], err);
        if (s >= 0) s = dr_calloc((size_t)g->nfaces[a], sizeof(double), &fc->velocity[a], err);
        if (s >= 0) s = dr_calloc((size_t)g->nfaces[a], sizeof(double), &fc->impulse[a], err);
        if (s >= 0) s = dr_calloc((size_t)g->nfaces[a], sizeof(double), &fc->drag[a], err);
        if (s < 0) { dr_face_coupling_destroy(&fc); return s; }
    }
    dr_face_coupling_clear(fc);
    *out = fc;
    return DR_OK;
}

void dr_face_coupling_destroy(DrFaceCoupling **fc)
{
    if (!fc || !*fc) return;
    for (int a = 0; a < 3; a++) {
        free((*fc)->open[a]);
        free((*fc)->velocity[a]);
        free((*fc)->impulse[a]);
        free((*fc)->drag[a]);
        free((*fc)->solid_mass[a]);
    }
    free(*fc);
    *fc = NULL;
}

void dr_face_coupling_clear(DrFaceCoupling *fc)
{
    for (int a = 0; a < 3; a++)
        for (long f = 0; f < fc->nfaces[a]; f++) {
            fc->open[a][f] = 1.0;
            fc->velocity[a][f] = 0.0;
            if (fc->impulse[a]) fc->impulse[a][f] = 0.0;
            if (fc->drag[a]) fc->drag[a][f] = 0.0;
            if (fc->solid_mass[a]) fc->solid_mass[a][f] = 0.0;
        }
}

DrStatus dr_face_coupling_add_solid_mass(DrFaceCoupling *fc, DrError *err)
{
    for (int a = 0; a < 3; a++)
        if (!fc->solid_mass[a]) DR_TRY(dr_calloc((size_t)fc->nfaces[a], sizeof(double), &fc->solid_mass[a], err));
    return DR_OK;
}

DrVec3 dr_mac_face_position(const DrMacGrid *g, int a, int i, int j, int k)
{
    return dr_v3(g->origin.x + g->dx * (i + dr_mac_face_offset(a, 0)),
                 g->origin.y + g->dx * (j + dr_mac_face_offset(a, 1)),
                 g->origin.z + g->dx * (k + dr_mac_face_offset(a, 2)));
}

DrVec3 dr_mac_cell_center(const DrMacGrid *g, int i, int j, int k)
{
    return dr_v3(g->origin.x + g->dx * (i + 0.5), g->origin.y + g->dx * (j + 0.5), g->origin.z + g->dx * (k + 0.5));
}

double dr_mac_sample_face(const DrMacGrid *g, int a, DrVec3 x)
{
    int idx[3][2];
    double w[3][2];
    for (int d = 0; d < 3; d++) {
        double s = (dr_v3_get(x, d) - dr_v3_get(g->origin, d)) / g->dx - dr_mac_face_offset(a, d);
        int hi = g->fdim[a][d] - 1;
        if (s < 0.0) s = 0.0;
        if (s > hi) s = hi;
        DrStencil2 st = dr_kernel_linear(s);
        int b0 = st.base, b1 = st.base + 1 > hi ? hi : st.base + 1;
        idx[d][0] = b0; idx[d][1] = b1;
        w[d][0] = st.w[0]; w[d][1] = st.w[1];
    }
    double sum = 0.0;
    for (int kk = 0; kk < 2; kk++)
        for (int jj = 0; jj < 2; jj++)
            for (int ii = 0; ii < 2; ii++)
                sum += w[0][ii] * w[1][jj] * w[2][kk] *
                       g->f[a][dr_mac_face_index(g, a, idx[0][ii], idx[1][jj], idx[2][kk])];
    return sum;
}

/* Fraction of a triangle with vertex values a, b, c lying where phi >= 0 (phi linear on it). */
static double tri_fraction_outside(double a, double b, double c)
{
    int nin = (a < 0) + (b < 0) + (c < 0);
    if (nin == 0) return 1.0;
    if (nin == 3) return 0.0;
    /* rotate so that the lone vertex (the one whose sign differs from the other two) is first */
    double v[3] = {a, b, c};
    bool lone_inside = (nin == 1);
    int lone = 0;
    for (int i = 0; i < 3; i++)
        if ((v[i] < 0) == lone_inside) lone = i;
    double p = v[lone], q = v[(lone + 1) % 3], r = v[(lone + 2) % 3];
    /* the corner triangle at the lone vertex covers t1·t2 of the area, t = p/(p - other) */
    double t1 = p / (p - q), t2 = p / (p - r);
    double corner = t1 * t2;
    return lone_inside ? 1.0 - corner : corner;
}

double dr_face_fraction_outside(double p00, double p10, double p11, double p01)
{
    double pc = 0.25 * (p00 + p10 + p11 + p01);
    double f = tri_fraction_outside(p00, p10, pc) + tri_fraction_outside(p10, p11, pc) +
               tri_fraction_outside(p11, p01, pc) + tri_fraction_outside(p01, p00, pc);
    f *= 0.25;
    return f < 0.0 ? 0.0 : (f > 1.0 ? 1.0 : f);
}
