/* A bem_solid element as the boundary element method takes it (stage.h): its build parameters from the scene,
 * its mesh through dr_bem_asset_load. In a file of its own so that only the stages that prepare BEM bodies link
 * the BEM. */
#include "stage/stage.h"

#include "bem/bem.h"

static DrBemOrdering ordering_of(const char *name)
{
    DrBemOrdering o = DR_BEM_ORDER_VERTEX_XYZ;
    bool known = dr_bem_ordering_parse(name, &o);
    assert(known); /* the scene's enum admits nothing else */
    (void)known;
    return o;
}

/* The element's components as build parameters; what the scene does not set keeps dr_bem_desc_default. */
static void desc_of(const DrElement *e, DrBemDesc *d)
{
    dr_bem_desc_default(d);
    const DrComponent *mat = dr_element_component(e, "LinearElastic");
    const DrComponent *cmp = dr_element_component(e, "Compression");
    const DrComponent *sol = dr_element_component(e, "BemSolver");
    d->material.density = dr_component_num(mat, "density");
    d->material.shear_modulus = dr_component_num(mat, "shear_modulus");
    d->material.poisson = dr_component_num(mat, "poisson");
    d->compression_ratio = dr_component_num(cmp, "ratio");
    d->ordering = ordering_of(dr_component_str(cmp, "ordering"));
    d->dt = dr_component_num(sol, "time_step");
    d->history_margin = dr_component_num(sol, "history_margin");
    d->quad_levels = dr_component_int(sol, "quadrature_levels");
    d->keep_dense = false;
}

DrStatus dr_stage_load_bem_asset(const DrElement *e, DrBemAsset *out, DrError *err)
{
    DrBemDesc d;
    desc_of(e, &d);
    const char *path = dr_component_str(dr_element_component(e, "Mesh"), "file");
    return dr_error_prefix(dr_bem_asset_load(path, &d, out, err), err, "%s.Mesh.file", e->name);
}
