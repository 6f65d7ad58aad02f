/* Fluids for tests of the coupled loop (src/couple) without a world: the air solver as a single-phase fluid, and a
 * mock fluid at rest on a grid (every face coupled, no pressure, takes nothing back). */
#ifndef DR_TESTS_COUPLE_FLUIDS_H
#define DR_TESTS_COUPLE_FLUIDS_H

#include <stdlib.h>
#include <string.h>

#include "couple/couple.h"
#include "liquid/liquid.h"

static inline DrStatus air_project_cb(void *ctx, const DrFaceCoupling *extra, DrError *err)
{
    DrAirStats st;
    memset(&st, 0, sizeof st);
    return dr_air_project(ctx, extra, &st, err);
}
static inline void air_pressure_cb(void *ctx, long n, const double *pts, double *p, double *wet)
{
    dr_air_sample(ctx, n, pts, NULL, p);
    for (long i = 0; i < n; i++) wet[i] = 1.0;
}
static inline const unsigned char *air_faces_cb(void *ctx, int a) { return dr_air_coupled_faces(ctx, a); }
static inline const double *air_mass_cb(void *ctx, int a) { return dr_air_face_mass(ctx, a); }

typedef struct Still { DrMacGrid *g; unsigned char *take[3]; int projects; } Still;

static inline DrStatus still_project(void *ctx, const DrFaceCoupling *extra, DrError *err)
{
    (void)extra, (void)err;
    ((Still *)ctx)->projects++;
    return DR_OK;
}
static inline void still_pressure(void *ctx, long n, const double *pts, double *p, double *wet)
{
    (void)ctx, (void)pts;
    for (long i = 0; i < n; i++) p[i] = 0.0, wet[i] = 1.0;
}
static inline const unsigned char *still_faces(void *ctx, int a) { return ((Still *)ctx)->take[a]; }

/* A 16 × 64 × 16 grid of 2.5 cm cells from (−0.2, −1.5, −0.2), every face coupled. */
static inline DrStatus still_make(Still *s, DrError *err)
{
    memset(s, 0, sizeof *s);
    DR_TRY(dr_mac_grid_create(16, 64, 16, 0.025, dr_v3(-0.2, -1.5, -0.2), &s->g, err));
    for (int a = 0; a < 3; a++) {
        s->take[a] = malloc((size_t)s->g->nfaces[a]);
        if (!s->take[a]) return dr_error_set(err, DR_ERR_NOMEM, NULL, 0, 0, "out of memory");
        memset(s->take[a], 1, (size_t)s->g->nfaces[a]);
    }
    return DR_OK;
}
static inline void still_free(Still *s)
{
    for (int a = 0; a < 3; a++) free(s->take[a]);
    dr_mac_grid_destroy(&s->g);
}

#endif
