/* The wet hair elements of a scene as src/wet takes them (stage.h): the liquid on the strands, the film, the bridges
 * and the two cohesion tables precompute builds and the world reads. In a file of its own so that only the stages
 * that need wet hair link src/wet's tables. */
#include "stage/stage.h"

#include <math.h>
#include <string.h>

#include "wet/wet.h"

DrStatus dr_stage_wet_settings(const DrScene *scene, DrStageWet *out, DrError *err)
{
    (void)err;
    memset(out, 0, sizeof *out);
    const DrElement *first = NULL;
    for (int i = 0; i < dr_scene_element_count(scene); i++) {
        const DrElement *e = dr_scene_element(scene, i);
        if (e->kind != DR_ELEMENT_HAIR || !dr_component_present(dr_element_component(e, "Wetting"))) continue;
        out->elements++;
        if (!first) first = e;
    }
    if (!first) return DR_OK; /* the scene's rules made every wet element agree with the first */
    out->wet = true;
    out->element = first;
    const DrComponent *w = dr_element_component(first, "Wetting");
    const DrComponent *f = dr_element_component(first, "Film");
    const DrComponent *c = dr_element_component(first, "Cohesion");
    const DrComponent *x = dr_element_component(first, "CrossFlow");
    double theta = dr_component_num(w, "contact_angle_deg") * DR_PI / 180.0;
    dr_film_desc_default(&out->film);
    out->film.density = dr_component_num(w, "density");
    out->film.viscosity = dr_component_num(w, "viscosity");
    if (dr_component_is_set(w, "liquid")) {
        const DrElement *l = dr_scene_find(scene, dr_component_str(w, "liquid"));
        const DrComponent *lm = dr_element_component(l, "LiquidMaterial");
        out->film.density = dr_component_num(lm, "density");
        out->film.viscosity = dr_component_num(lm, "viscosity");
        if (!(out->film.viscosity > 0)) out->film.viscosity = dr_component_num(w, "viscosity");
    }
    out->film.surface_tension = dr_component_num(w, "surface_tension");
    out->film.max_ratio = dr_component_num(f, "max_ratio");
    out->film.friction = dr_component_num(f, "friction");
    out->film.substeps = dr_component_int(f, "substeps");
    dr_bridge_desc_default(&out->bridges);
    out->bridges.contact_angle = theta;
    out->bridges.surface_tension = out->film.surface_tension;
    out->bridges.scale = dr_component_num(c, "scale");
    out->bridges.solid_scale = dr_component_num(c, "solid_scale");
    out->bridges.radius_multiplier = dr_component_num(c, "radius_multiplier");
    out->bridges.solid_radius_multiplier = dr_component_num(c, "solid_radius_multiplier");
    out->bridges.cross_flow = dr_component_bool(x, "enabled");
    out->bridges.cross_flow_rate = dr_component_num(x, "rate");
    const DrComponent *cap = dr_element_component(first, "Capture"), *dr = dr_element_component(first, "Dripping");
    out->capture = dr_component_bool(cap, "enabled");
    dr_capture_desc_default(&out->capture_desc);
    out->capture_desc.rate = dr_component_num(cap, "rate");
    out->capture_desc.capacity = dr_component_num(cap, "capacity");
    out->capture_desc.reach = dr_component_num(cap, "reach");
    out->dripping = dr_component_bool(dr, "enabled");
    dr_drip_desc_default(&out->drip_desc);
    out->drip_desc.radius_scale = dr_component_num(dr, "radius_scale");
    out->drip_desc.middle = dr_component_bool(dr, "middle");
    out->drip_desc.root = dr_component_bool(dr, "root");
    out->drip_desc.tip = dr_component_bool(dr, "tip");
    out->drip_desc.min_drop = dr_component_num(dr, "min_drop");
    out->drip_desc.pool_release = dr_component_num(dr, "pool_release");
    out->drip_desc.budget = dr_component_int(dr, "budget");
    for (int k = 0; k < 2; k++) {
        DrCohesionDesc *d = &out->tables[k];
        dr_cohesion_desc_default(d);
        d->shape = k == 0 ? DR_COHESION_CYLINDERS : DR_COHESION_PLANE;
        d->contact_angle = theta;
        d->resolution = dr_component_int(c, "table_resolution");
        double m = out->film.max_ratio;
        /* two films at the largest ratio between strands; one against a solid */
        d->max_area = (k == 0 ? 2.0 : 1.0) * DR_PI * (m * m - 1.0);
        d->max_gap = (1.0 + 0.5 * theta) * sqrt(d->max_area);
    }
    return DR_OK;
}
