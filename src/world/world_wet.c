/* Capture and dripping between the first liquid and the wet hair (DESIGN §8 step 4): the liquid's particles and the
 * hair's film meet here as src/wet's neutral batches (wet never includes the liquid).
 *
 * The exchange runs at the start of every step of the liquid (it and the hair step at every clock step when it is on),
 * when both stand at the same time t and the liquid's particle indices are valid:
 *   1. capture over the time since the last exchange: particles within reach of a strand's film give it their share
 *      (their volume lowered in place, their velocity kept, so the bulk loses exactly the momentum the film and
 *      strands gain); particles left with no volume are removed;
 *   2. dripping: film beyond what a cell of strands holds, and full pools, leave as new particles with exactly that
 *      volume and momentum, added to the liquid before its step's P2G;
 *   3. how far each strand vertex lies under the liquid's surface, which switches cohesion off smoothly there (the
 *      bridges of the hair's next step).
 * Nothing is rescaled: bulk + film + pools + removed − emitted (removed: by kill boxes; emitted: by emitters) stays
 * the initial volume to round-off, which every frame's diagnostics show. */
#include "world_adapter.h"

#include <math.h>
#include <string.h>

#include "liquid/liquid.h"
#include "wet/wet.h"

/* The bulk liquid as src/wet takes it, now. */
static DrBulk bulk_of(const WorldWetLink *w)
{
    DrLiquidState *st = dr_liquid_state_mut(w->liquid);
    const DrMacGrid *g = dr_liquid_grid(w->liquid);
    DrVec3 hi = dr_v3_add(g->origin, dr_v3(g->nx * g->dx, g->ny * g->dx, g->nz * g->dx));
    return (DrBulk){st->n, st->x, st->v, st->vol, dr_liquid_nominal_volume(w->liquid), g->dx, g->origin, hi};
}

DrStatus world_wet_start(WorldWetLink *w, double t, DrError *err)
{
    double b, f, p;
    world_wet_volumes(w, &b, &f, &p);
    w->initial = b + f + p;
    w->emitted = w->removed = 0.0;
    w->t_last = t;
    DrBulk bk = bulk_of(w);
    return dr_exchange_submersion(w->exchange, w->x, w->nverts, &bk, w->submerged, err);
}

void world_wet_volumes(const WorldWetLink *w, double *bulk, double *film, double *pools)
{
    *bulk = *film = *pools = 0.0;
    if (w->liquid) {
        const DrLiquidState *st = dr_liquid_state(w->liquid);
        for (long p = 0; p < st->n; p++) *bulk += st->vol[p];
    }
    if (w->film) {
        DrFilmState fs = dr_film_state(w->film);
        for (int i = 0; i < fs.nverts; i++) *film += fs.volume[i];
        for (int k = 0; k < 2 * fs.nstrands; k++) *pools += fs.pool[k];
    }
}

DrStatus world_wet_exchange(WorldWetLink *w, double t, DrError *err)
{
    if (!w->on || !w->liquid || !w->film) return DR_OK;
    double t_start = dr_time_now();
    double h = t - w->t_last;
    w->t_last = t;
    DrBulk b = bulk_of(w);
    DrWetStrands s = {w->x, w->v, w->accel, w->mass};
    DrExchangeStats es = {0};
    if (h > 0) {
        DR_TRY(dr_exchange_capture(w->exchange, w->film, &s, &b, h, &es, err));
        if (es.captured_particles > 0) dr_liquid_remove_empty(w->liquid);
    }
    DrDrops d;
    DR_TRY(dr_exchange_drip(w->exchange, w->film, &s, &b, &d, &es, err));
    if (d.n > 0) DR_TRY(dr_liquid_add_particles(w->liquid, d.n, d.x, d.v, d.vol, err));
    /* where the strands stand under the surface now: the bridges of the hair's next step */
    b = bulk_of(w);
    DR_TRY(dr_exchange_submersion(w->exchange, w->x, w->nverts, &b, w->submerged, err));
    w->captured += es.captured;
    w->captured_particles += es.captured_particles;
    w->dripped += es.dripped;
    w->drops += es.drops;
    w->held += es.held;
    w->captured_momentum = dr_v3_add(w->captured_momentum, es.captured_momentum);
    w->dripped_momentum = dr_v3_add(w->dripped_momentum, es.dripped_momentum);
    w->liquid_work += es.dripped_energy - es.captured_energy;
    w->seconds += dr_time_now() - t_start;
    return DR_OK;
}
