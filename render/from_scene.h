/* What the render stage draws from the scene alone, without the bake: the simulation domains' walls, the sizes a
 * shot's frames share (so that the ground's checker and the water's tint do not change from frame to frame), the
 * camera, how wet hair looks, and `render --preview`, the scene's initial state in one PNG. */
#ifndef DR_RENDER_FROM_SCENE_H
#define DR_RENDER_FROM_SCENE_H

#include "render/render.h"
#include "scene/scene.h"
#include "stage/stage.h"

/* The box [lo, hi] as a closed triangle mesh wound counter-clockwise seen from outside (8 vertices, 12 triangles),
 * or without its top face (y = hi.y: an open tank, 10 triangles). DR_ERR_NOMEM only. */
DR_NODISCARD DrStatus scene_box_mesh(DrVec3 lo, DrVec3 hi, bool top, DrTriMesh *out, DrError *err);

/* Adds the walls of every liquid and mpm_solid Domain (its box without the top face) to rs as DR_MATERIAL_WALL
 * panels: where the water stops at a wall, the wall is seen. */
DR_NODISCARD DrStatus scene_add_domain_walls(const DrScene *scene, DrRenderScene *rs, DrError *err);

/* Sizes every frame of the shot renders with (DrRenderDesc.scene_size and liquid_size): the largest side of the
 * box around the liquid and mpm_solid Domain boxes and the static colliders' meshes (`still`, n of them, posed;
 * empty ones are skipped), else the camera's eye-target distance; and the largest side of the liquid Domain boxes
 * (0 without liquid: the renderer then measures the liquid drawn). */
void scene_render_sizes(const DrScene *scene, const DrTriMesh *still, int n, DrRenderDesc *desc);

/* The lowest liquid or mpm_solid Domain floor or vertex of the given meshes: where the ground goes (0 if none). */
double scene_ground_height(const DrScene *scene, const DrTriMesh *meshes, int n);

/* Hair element e's strands p as the render stage draws them, in frames and in the preview alike. With the liquid
 * film's outer radius per vertex (p->outer, H) each vertex is drawn H wide (instead of the strand's radius) and
 * darkened by its wetness w = clamp((H/r − 1) / (max_ratio − 1), 0, 1): r the vertex's radius (dr_stage_vertex_radii,
 * RodMaterial.tip_radius), max_ratio the scene's Film.max_ratio, the most film a strand holds, so w grows with the
 * film from 0 (dry) to 1 (full) and a strand that drains fades back to its dry colour (render.h: the darkening of
 * a fibre under water). Without p->outer each strand is drawn as wide as its radius. Errors as
 * dr_render_scene_add_polylines, prefixed with the element's name; DR_ERR_NOMEM. */
DR_NODISCARD DrStatus scene_add_strands(const DrScene *scene, const DrElement *e, const DrPolylines *p,
                                        DrRenderScene *rs, DrError *err);

/* The scene's camera and resolution; DR_ERR_INPUT naming render.camera when dr_camera_check refuses it. */
DR_NODISCARD DrStatus scene_camera(const DrScene *scene, DrCamera *cam, DrError *err);

/* render --preview: draws the scene's initial state from the scene and its assets alone — liquid as its
 * LiquidSource (box or mesh) and Emitter boxes, colliders posed by their Motion at the shot's first frame, grooms
 * grown (dr_stage_load_groom) as strands of RodMaterial.radius (in a scene with wet hair, each with the film the
 * bake starts from, H = Film.initial_ratio · r on wet elements and none on dry ones, drawn by scene_add_strands as
 * the baked frames are), mpm_solid shapes and bem_solid meshes at rest
 * (their Transform), the Domain walls and the ground — through the scene camera at render.resolution and
 * render.samples, into <out_root>/<shot>/preview.png (atomic), and its path into `path`. Reads nothing baked or
 * meshed and writes nothing else: no stage folder, no MANIFEST. Errors as the assets' loaders (naming the
 * element and field) and dr_image_write_png. */
DR_NODISCARD DrStatus scene_preview(const DrScene *scene, const DrStageArgs *args, char *path, size_t size,
                                    DrError *err);

#endif
