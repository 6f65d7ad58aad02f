/* The stability watch every adapter runs at the end of a frame (world_adapter.h, README "Stability watch"): a
 * solver's energy against the work done on it, and what happens when it grows beyond that: a warning naming the
 * element, the frame and the fix, or with solver.on_instability "fail" a runtime error (bake exits 1). */
#include "world_adapter.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

void world_watch_init(WorldWatch *w, const DrScene *scene)
{
    memset(w, 0, sizeof *w);
    w->fail = strcmp(dr_component_str(dr_scene_section(scene, "solver"), "on_instability"), "fail") == 0;
}

DrStatus world_watch_alarm(const WorldWatch *w, const char *message, DrError *err)
{
    if (w->fail) return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0, "%s (solver.on_instability is \"fail\")", message);
    dr_log_warn("%s", message);
    return DR_OK;
}

/* The margins. A solver that is stable at its step keeps its energy or loses it (the transfers, contacts, the
   pressure projection and BDF1 dissipate) up to errors of the time integration that fall with the step: the
   midpoint MPM's contacts at the CFL step gave up to 6 % of the available energy in a frame (a brick sliding off a
   post in assets/scenes/jelly_drop.json) and 3 % over a shot. An unstable one gains a fixed factor per step or per
   frame (×1.3 to ×8 in four frames in the cases the stress tests keep). So the per-frame margin is 10 % of the
   energy available at the frame's start and the cumulative one 10 % of the first frame's, on top of the work. */
#define FRAME_MARGIN 0.10
#define TOTAL_MARGIN 0.10

DrStatus world_watch_energy(WorldWatch *w, const WorldCtx *c, const WorldEnergy *e, const char *element,
                            const char *fix, DrError *err)
{
    if (!w->have) {
        /* the first frame checked (after a start or a resume): the reference is its start, the state the
           adapter measured when it was built or restored (WorldWatch.start) */
        w->have = true;
        w->first = w->start;
        w->work_total = 0.0;
    }
    double work = e->work > 0.0 ? e->work : 0.0; /* negative work takes energy away: no credit for it */
    w->work_total += work;
    double gain = e->energy - w->start.energy - work;
    double total_gain = e->energy - w->first.energy - w->work_total;
    double frame_margin = FRAME_MARGIN * w->start.available + e->floor;
    double total_margin = TOTAL_MARGIN * w->first.available + e->floor;
    WorldEnergy start = w->start;
    w->start = *e;
    w->start.work = 0.0;
    char msg[sizeof err->message];
    if (!w->cumulative_only && gain > frame_margin && isfinite(gain)) {
        snprintf(msg, sizeof msg,
                 "frame %d: %s: the energy grew by %.3g J in the frame (from %.6g J to %.6g J; %.0f %% of the %.3g J "
                 "it had available) beyond the %.3g J of work done on it: the solver is unstable at its step; %s",
                 c->frame, element, gain, start.energy, e->energy, 100.0 * gain / fmax(start.available, 1e-300),
                 start.available, work, fix);
        return world_watch_alarm(w, msg, err);
    }
    if (total_gain > total_margin && isfinite(total_gain)) {
        snprintf(msg, sizeof msg,
                 "frame %d: %s: the energy grew by %.3g J since the start of frame %d (from %.6g J to %.6g J; %.0f %% "
                 "of the %.3g J it had available) beyond the %.3g J of work done on it: the solver is unstable at its "
                 "step; %s",
                 c->frame, element, total_gain, w->first_frame, w->first.energy, e->energy,
                 100.0 * total_gain / fmax(w->first.available, 1e-300), w->first.available, w->work_total, fix);
        /* the next alarm only for a further growth from here (a warning each frame would bury the first) */
        w->first = *e;
        w->first_frame = c->frame + 1;
        w->work_total = 0.0;
        return world_watch_alarm(w, msg, err);
    }
    return DR_OK;
}

void world_watch_start(WorldWatch *w, int frame, const WorldEnergy *e)
{
    w->have = false;
    w->first_frame = frame;
    w->start = *e;
    w->start.work = 0.0;
}

DrStatus world_watch_frame_length(const WorldCtx *c, const char *element, double step, const char *why, DrError *err)
{
    const DrComponent *solver = dr_scene_section(c->scene, "solver");
    int max_substeps = dr_component_int(solver, "max_substeps");
    double frame = 1.0 / c->fps;
    if (!(step > 0.0) || !isfinite(step)) return DR_OK;
    double need = ceil(frame / step * (1.0 - 1e-9));
    if (need <= max_substeps) return DR_OK;
    double fps_min = c->fps * need / max_substeps;
    return dr_error_set(err, DR_ERR_INPUT, dr_scene_path(c->scene), 0, 0,
                        "shot.fps = %g: a frame of %g s needs at least %.0f substeps of %s (%s: %.3g s) but "
                        "solver.max_substeps is %d, and longer substeps would collapse it; raise shot.fps to at "
                        "least %.3g or solver.max_substeps to at least %.0f",
                        c->fps, frame, need, element, why, step, max_substeps, fps_min, need);
}
