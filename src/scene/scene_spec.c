/* The scene schema: every section, element type, component and field, in one set of tables that the
 * parser, the validator, the canonical writer and the printed reference all read (DESIGN §3). Adding a
 * field here is the whole job for a new parameter; a cross-field rule goes in scene.c's checks. */
#include "scene_internal.h"

#include <ctype.h>
#include <string.h>

#define RANGE(a, b) .ranged = true, .lo = (a), .hi = (b)
#define RANGE_LO_OPEN(a, b) RANGE(a, b), .lo_open = true
#define RANGE_OPEN(a, b) RANGE(a, b), .lo_open = true, .hi_open = true
#define RANGE_HI_OPEN(a, b) RANGE(a, b), .hi_open = true
#define COUNT(arr) ((int)(sizeof(arr) / sizeof((arr)[0])))
#define INT_MAX_31 2147483647.0
/* Generous bounds for positions: a typo like 1e9 is caught, any real set fits. */
#define POS_RANGE RANGE(-1e6, 1e6)

/* ---- sections ------------------------------------------------------------------------------------------- */

static const DrFieldSpec shot_fields[] = {
    {.name = "name", .kind = DR_FIELD_NAME, .unit = "", .def_str = "shot",
     .doc = "shot name; outputs go to out/<name>/"},
    {.name = "fps", .kind = DR_FIELD_NUMBER, .unit = "1/s", .def = {24}, RANGE_LO_OPEN(0, 1000),
     .doc = "frames per second", .hint = "use a frame rate such as 24"},
    {.name = "frames", .kind = DR_FIELD_INT2, .unit = "", .def = {1, 48}, RANGE(0, 1000000),
     .doc = "first and last frame, inclusive; first <= last"},
    {.name = "gravity", .kind = DR_FIELD_VEC3, .unit = "m/s^2", .def = {0, -9.81, 0}, RANGE(-1000, 1000),
     .doc = "gravitational acceleration (y is up)"},
    {.name = "seed", .kind = DR_FIELD_INT, .unit = "", .def = {1}, RANGE(0, INT_MAX_31),
     .doc = "seed of every random choice in the shot"},
};

static const DrFieldSpec solver_fields[] = {
    {.name = "cfl", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1.0}, RANGE(0.05, 10),
     .doc = "CFL number: the largest distance a particle moves in one substep, in grid cells"},
    {.name = "max_substeps", .kind = DR_FIELD_INT, .unit = "", .def = {64}, RANGE(1, 100000),
     .doc = "upper bound on substeps per frame"},
    {.name = "pressure_tolerance", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1e-6}, RANGE(1e-14, 0.1),
     .doc = "relative residual at which the pressure solve stops"},
    {.name = "pressure_preconditioner", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "multigrid",
     .choices = "multigrid|mic0",
     .doc = "preconditioner of the liquid's pressure solve: multigrid (a geometric multigrid V-cycle; iterations "
            "nearly flat in resolution, parallel) or mic0 (modified incomplete Cholesky; iterations grow ~1.8x per "
            "doubling of the resolution, one thread)"},
    {.name = "pressure_max_iterations", .kind = DR_FIELD_INT, .unit = "", .def = {2000}, RANGE(1, 1000000),
     .doc = "iteration limit of the pressure solve (reaching it is a warning)"},
    {.name = "coupling_iterations", .kind = DR_FIELD_INT, .unit = "", .def = {3}, RANGE(1, 100),
     .doc = "most iterations of the coupled solid-fluid loop per step (hair with a Drag component in a liquid): 1 is "
            "the staggered step (solid with drag from the fluid, reaction, pressure); more converge to the monolithic "
            "solution"},
    {.name = "coupling_tolerance", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1e-2}, RANGE_LO_OPEN(0, 1),
     .doc = "relative change of the solids' velocities and of the fluid's velocity and pressure at them below which "
            "the coupled loop stops before coupling_iterations"},
    {.name = "checkpoint_every", .kind = DR_FIELD_INT, .unit = "", .def = {1}, RANGE(1, 100000),
     .doc = "frames between checkpoints"},
    {.name = "on_instability", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "warn", .choices = "warn|fail",
     .doc = "what bake does when a solver's energy grows beyond the work done on it, or a liquid loses volume "
            "(README, \"Stability watch\"): warn (log a warning naming element, frame and fix, and go on) or fail "
            "(stop with exit code 1 after the frames before it)"},
};

static const DrFieldSpec mesh_fields[] = {
    {.name = "voxel_size", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {0}, RANGE(0, 10),
     .doc = "voxel size of liquid and MPM solid surfaces; 0 = automatic (liquid: half its grid spacing; MPM solid: "
            "its particle radius / 1.5, at most half its grid spacing)"},
    {.name = "radius_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.8}, RANGE(0.1, 10),
     .doc = "particle radius in particle spacings; 0.8 reproduces the seeded volume of jittered particles "
            "within 2 %"},
    {.name = "smoothing", .kind = DR_FIELD_INT, .unit = "", .def = {1}, RANGE(0, 50),
     .doc = "mean-curvature smoothing passes of the level set"},
    {.name = "adaptivity", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0}, RANGE(0, 1),
     .doc = "mesh adaptivity: 0 uniform triangles, 1 fewest triangles"},
    {.name = "write_vdb", .kind = DR_FIELD_BOOL, .unit = "", .def = {1}, .doc = "write <element>.NNNN.vdb"},
    {.name = "write_obj", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "write <element>.NNNN.obj of liquid and MPM solids (hair polylines and bem_solid surfaces are always "
            "written)"},
    {.name = "hair_ribbons", .kind = DR_FIELD_BOOL, .unit = "", .def = {0},
     .doc = "also write each hair element's strands as triangle strips 2 radii wide, <element>_ribbons.NNNN.obj "
            "(for tools that do not draw OBJ polylines); its <element>.NNNN.obj polylines are always written"},
    {.name = "wet_tubes", .kind = DR_FIELD_BOOL, .unit = "", .def = {0},
     .doc = "in a scene with wet hair (a Wetting component), also write each hair element's strands as closed "
            "triangle tubes of the liquid film's outer radius H = sqrt(r^2 + A/pi) (r where dry), "
            "<element>_wet.NNNN.obj"},
    {.name = "wet_tube_sides", .kind = DR_FIELD_INT, .unit = "", .def = {8}, RANGE(3, 64),
     .doc = "sides of each ring of the wet tubes (mesh.wet_tubes): 2 x sides triangles per strand vertex"},
    {.name = "write_points", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "write <element>.NNNN.points.vdb: the particles of liquid and MPM solids and the vertices of hair as "
            "OpenVDB point data (P, v, id and per kind volume, J, strain, strand, width, and wet_width in a scene "
            "with wet hair)"},
    {.name = "velocity_interior", .kind = DR_FIELD_BOOL, .unit = "", .def = {0},
     .doc = "the \"vel\" grid of <element>.NNNN.vdb covers the whole liquid or solid (every voxel inside the "
            "surface); false: the narrow band of the surface only"},
};

static const DrFieldSpec render_fields[] = {
    {.name = "resolution", .kind = DR_FIELD_INT2, .unit = "px", .def = {960, 540}, RANGE(16, 16384),
     .doc = "image width and height"},
    {.name = "contact_every", .kind = DR_FIELD_INT, .unit = "", .def = {4}, RANGE(1, 10000),
     .doc = "every n-th frame goes on the contact sheet (and the last frame)"},
    {.name = "samples", .kind = DR_FIELD_INT, .unit = "", .def = {3}, RANGE(1, 8),
     .doc = "antialiasing: supersamples per pixel side (3 = 9 per pixel)"},
    {.name = "ground", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "draw a ground plane under the lowest liquid or MPM domain floor or collider"},
};

static const DrFieldSpec camera_fields[] = {
    {.name = "eye", .kind = DR_FIELD_VEC3, .unit = "m", .def = {0.6, 0.4, 0.8}, POS_RANGE,
     .doc = "camera position"},
    {.name = "target", .kind = DR_FIELD_VEC3, .unit = "m", .def = {0, 0.1, 0}, POS_RANGE,
     .doc = "point the camera looks at"},
    {.name = "up", .kind = DR_FIELD_VEC3, .unit = "1", .def = {0, 1, 0}, RANGE(-1e6, 1e6),
     .doc = "up direction (need not be unit length; not parallel to the view direction)"},
    {.name = "fov_deg", .kind = DR_FIELD_NUMBER, .unit = "deg", .def = {40}, RANGE_OPEN(1, 170),
     .doc = "vertical field of view", .hint = "use a field of view such as 40"},
};

const DrComponentSpec dr_scene_sections_[] = {
    {"shot", "name, frame range, frame rate, gravity and seed of the shot", shot_fields, COUNT(shot_fields)},
    {"solver", "time stepping and linear solver controls", solver_fields, COUNT(solver_fields)},
    {"mesh", "liquid and MPM solid surface extraction (the mesh stage)", mesh_fields, COUNT(mesh_fields)},
    {"render", "images and contact sheet (the render stage); holds \"camera\"", render_fields,
     COUNT(render_fields)},
    {"render.camera", "the render camera (a pinhole looking from eye to target)", camera_fields,
     COUNT(camera_fields)},
};
const int dr_scene_section_count_ = COUNT(dr_scene_sections_);

/* ---- components ---------------------------------------------------------------------------------------- */

static const DrFieldSpec domain_fields[] = {
    {.name = "box", .kind = DR_FIELD_BOX, .unit = "m", .required = true, POS_RANGE,
     .doc = "simulation grid bounds; walls at its faces"},
    {.name = "voxel_size", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {0.02}, RANGE(1e-4, 10),
     .doc = "grid cell size", .hint = "use a cell size such as 0.02 (a 1 m box gets 50 cells a side)"},
    {.name = "wall_boundary", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "slip", .choices = "slip|no_slip",
     .doc = "velocity condition at the domain walls"},
};

static const DrFieldSpec liquid_source_fields[] = {
    {.name = "box", .kind = DR_FIELD_BOX, .unit = "m", .no_default = true, POS_RANGE,
     .doc = "box filled with liquid at t=0"},
    {.name = "mesh", .kind = DR_FIELD_PATH, .unit = "", .doc = "closed mesh whose volume is filled at t=0"},
    {.name = "velocity", .kind = DR_FIELD_VEC3, .unit = "m/s", .def = {0, 0, 0}, RANGE(-1e4, 1e4),
     .doc = "initial velocity"},
};

static const DrFieldSpec emitter_fields[] = {
    {.name = "box", .kind = DR_FIELD_BOX, .unit = "m", .required = true, POS_RANGE,
     .doc = "region kept full of liquid while the emitter is on"},
    {.name = "velocity", .kind = DR_FIELD_VEC3, .unit = "m/s", .def = {0, 0, 0}, RANGE(-1e4, 1e4),
     .doc = "velocity of emitted liquid"},
    {.name = "start", .kind = DR_FIELD_NUMBER, .unit = "s", .def = {0}, RANGE(0, 1e6),
     .doc = "time the emitter turns on"},
    {.name = "end", .kind = DR_FIELD_NUMBER, .unit = "s", .def = {1e6}, RANGE(0, 1e6),
     .doc = "time the emitter turns off (start <= end)"},
};

static const DrFieldSpec kill_box_fields[] = {
    {.name = "box", .kind = DR_FIELD_BOX, .unit = "m", .required = true, POS_RANGE,
     .doc = "particles entering this box are removed"},
};

static const DrFieldSpec liquid_material_fields[] = {
    {.name = "density", .kind = DR_FIELD_NUMBER, .unit = "kg/m^3", .def = {1000}, RANGE(1, 1e5),
     .doc = "mass density", .hint = "use a positive density such as 1000 for water"},
    {.name = "viscosity", .kind = DR_FIELD_NUMBER, .unit = "Pa*s", .def = {0.001}, RANGE(0, 1e4),
     .doc = "dynamic viscosity", .hint = "water is 0.001, honey about 10"},
};

static const DrFieldSpec transfer_fields[] = {
    {.name = "scheme", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "apic", .choices = "apic|flip|pic|rpic",
     .doc = "particle-grid transfer; rpic (rotational: only the skew part of the affine matrix) is for "
            "mpm_solid only"},
    {.name = "kernel", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "quadratic", .choices = "linear|quadratic|cubic",
     .doc = "B-spline interpolation kernel of the transfers; linear and cubic are for mpm_solid only (the "
            "liquid's MAC grid is quadratic)"},
    {.name = "flip_blend", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.97}, RANGE(0, 1),
     .doc = "fraction of FLIP in the FLIP/PIC blend (scheme flip only)"},
};

static const DrFieldSpec pressure_fields[] = {
    {.name = "formulation", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "ghost_fluid",
     .choices = "ghost_fluid|mass_weighted",
     .doc = "ghost_fluid: uniform density and a ghost-fluid free surface (still water stays exactly still); "
            "mass_weighted: kinetic-energy projection with the particles' face masses (conserves linear and "
            "angular momentum exactly with APIC)"},
    {.name = "volume_correction", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {4}, RANGE(0, 100),
     .doc = "rate at which liquid compressed by more than 4 % over its seeded density is expanded back, as the "
            "rate of excess removed per frame (the excess decays like exp(-k t/frame)); 0 turns it off"},
};

static const DrFieldSpec particles_fields[] = {
    {.name = "per_cell", .kind = DR_FIELD_INT, .unit = "", .def = {8}, RANGE(1, 64),
     .doc = "particles seeded per grid cell"},
    {.name = "jitter", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1),
     .doc = "random offset of seeded particles, as a fraction of the sub-cell size"},
    {.name = "seed", .kind = DR_FIELD_INT, .unit = "", .def = {1}, RANGE(0, INT_MAX_31),
     .doc = "seed of the particle jitter (combined with shot.seed)"},
};

static const DrFieldSpec mpm_material_fields[] = {
    {.name = "model", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "fixed_corotated",
     .choices = "neo_hookean|fixed_corotated",
     .doc = "hyperelastic energy: fixed_corotated stays defined when an element is inverted; neo_hookean "
            "stiffens under compression and fails on inversion"},
    {.name = "density", .kind = DR_FIELD_NUMBER, .unit = "kg/m^3", .def = {1000}, RANGE(1, 1e5),
     .doc = "mass density", .hint = "use a positive density such as 1000 for a jelly"},
    {.name = "youngs_modulus", .kind = DR_FIELD_NUMBER, .unit = "Pa", .def = {1e5}, RANGE_LO_OPEN(0, 1e12),
     .doc = "Young's modulus E (stiffness)", .hint = "use a positive stiffness such as 1e5 for a jelly, 1e7 for rubber"},
    {.name = "poisson", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.3}, RANGE_HI_OPEN(0, 0.5),
     .doc = "Poisson's ratio nu (0.5 would be incompressible)",
     .hint = "use a ratio below 0.5 such as 0.3 (0.45 for a nearly incompressible jelly)"},
};

static const DrFieldSpec mpm_shape_fields[] = {
    {.name = "box", .kind = DR_FIELD_BOX, .unit = "m", .no_default = true, POS_RANGE,
     .doc = "a box filled with particles"},
    {.name = "centre", .kind = DR_FIELD_VEC3, .unit = "m", .no_default = true, POS_RANGE,
     .doc = "centre of a sphere filled with particles (with radius)"},
    {.name = "radius", .kind = DR_FIELD_NUMBER, .unit = "m", .no_default = true, RANGE_LO_OPEN(0, 1e6),
     .doc = "radius of that sphere (with centre)", .hint = "use a positive radius"},
    {.name = "mesh", .kind = DR_FIELD_PATH, .unit = "",
     .doc = "closed triangle mesh whose volume is filled with particles"},
    {.name = "particles_per_axis", .kind = DR_FIELD_INT, .unit = "", .def = {2}, RANGE(1, 8),
     .doc = "particles per grid cell along each axis, on a lattice aligned with the grid (2 = 8 per cell)"},
};

static const DrFieldSpec initial_velocity_fields[] = {
    {.name = "velocity", .kind = DR_FIELD_VEC3, .unit = "m/s", .def = {0, 0, 0}, RANGE(-1e4, 1e4),
     .doc = "initial velocity of the body"},
    {.name = "angular_velocity", .kind = DR_FIELD_VEC3, .unit = "deg/s", .def = {0, 0, 0}, RANGE(-1e6, 1e6),
     .doc = "initial spin about the body's centre (box or sphere centre, a mesh's volume centroid; a bem_solid's "
            "centre of mass), about x, y, z"},
};

static const DrFieldSpec integrator_fields[] = {
    {.name = "type", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "midpoint",
     .choices = "midpoint|symplectic_euler|backward_euler",
     .doc = "time integrator: midpoint (implicit, conserves momentum and angular momentum), symplectic_euler "
            "(explicit: needs small steps on stiff materials), backward_euler (implicit, damped)"},
    {.name = "newton_tolerance", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1e-5}, RANGE(1e-14, 0.1),
     .doc = "implicit integrators: relative residual at which the Newton iteration stops"},
    {.name = "newton_max_iterations", .kind = DR_FIELD_INT, .unit = "", .def = {50}, RANGE(1, 10000),
     .doc = "iteration limit of Newton (reaching it is a warning; the step is kept)"},
    {.name = "cg_tolerance", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1e-5}, RANGE(1e-14, 0.1),
     .doc = "relative residual at which each Newton step's conjugate-gradient solve stops"},
    {.name = "cg_max_iterations", .kind = DR_FIELD_INT, .unit = "", .def = {1000}, RANGE(1, 1000000),
     .doc = "iteration limit of each conjugate-gradient solve"},
    {.name = "f_update_order", .kind = DR_FIELD_INT, .unit = "", .def = {1}, RANGE(1, 2),
     .doc = "deformation gradient update: 1 first order (F <- (I + dt grad v) F), 2 second order"},
    {.name = "liquid_coupling", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "two_way", .choices = "two_way|none",
     .doc = "with a liquid in the scene: two_way, the bodies and the liquid push each other (buoyancy, drag, splash): "
            "the bodies' particles are lumped onto the liquid's faces as a solid that its pressure moves, within the "
            "pressure solve, at every liquid substep, and the liquid is kept out of them; none, they pass through each "
            "other. The same for every mpm_solid of a scene"},
};

static const DrFieldSpec mesh_file_fields[] = {
    {.name = "file", .kind = DR_FIELD_PATH, .unit = "", .required = true,
     .doc = "triangle mesh file (OBJ, PLY, STL, ... anything assimp reads)"},
};

static const DrFieldSpec collider_fields[] = {
    {.name = "friction", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0}, RANGE(0, 10),
     .doc = "Coulomb friction coefficient (hair or cloth against a collider: the larger of the two elements' values)"},
    {.name = "boundary", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "slip", .choices = "slip|no_slip",
     .doc = "velocity condition of liquid at the surface (collider elements only)"},
    {.name = "thickness", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {0}, RANGE(0, 1),
     .doc = "extra thickness added around the surface (on hair: around each strand, beyond its radius; on a "
            "bem_solid: the contact offset its vertices keep from colliders and other bodies; on cloth: the distance "
            "its vertices keep from colliders and bodies, default 0 taken as 1 mm)"},
    {.name = "body_contact", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "bem_solid only: the body's vertices are kept outside the other bem_solid bodies stepped with it (the "
            "same BemSolver.time_step), with its friction"},
};

static const DrFieldSpec fixed_vertices_fields[] = {
    {.name = "box", .kind = DR_FIELD_BOX, .unit = "m", .required = true, POS_RANGE,
     .doc = "every vertex inside this box in the placed rest pose (after Transform) is held at its position at t=0 "
            "(a bem_solid's, or a cloth's: pinned); the box must hold at least one vertex"},
};

static const DrFieldSpec slide_vertices_fields[] = {
    {.name = "box", .kind = DR_FIELD_BOX, .unit = "m", .required = true, POS_RANGE,
     .doc = "every vertex inside this box in the placed rest pose (after Transform) slides on the curve: held on it, free "
            "to move along it (a curtain on its rail); the box must hold at least one vertex"},
    {.name = "curve", .kind = DR_FIELD_TABLE, .unit = "m", .arity = 3, POS_RANGE,
     .doc = "the curve, a polyline [[x, y, z], ...] of 2 points or more, in world space (not moved by Transform)"},
};

/* An attachment element: vertices of hair or cloth held by a pin, on a curve, or rigidly to a collider or a body. */
static const DrFieldSpec attachment_fields[] = {
    {.name = "members", .kind = DR_FIELD_NAMES, .unit = "", .required = true,
     .doc = "the cloth or hair elements it holds, by name"},
    {.name = "method", .kind = DR_FIELD_ENUM, .unit = "", .required = true, .choices = "pin|slide|rigid",
     .doc = "pin: held where they are (moved by the member's Motion, as FixedVertices); slide: held on the curve, free "
            "to move along it (as SlideVertices); rigid: carried by the target's rigid motion (a cloth's vertices in "
            "the box, or a hair's roots in place of its Motion)"},
    {.name = "box", .kind = DR_FIELD_BOX, .unit = "m", .no_default = true, POS_RANGE,
     .doc = "a cloth member's vertices inside this box in the placed rest pose are held (required for cloth; a hair "
            "member is held by its roots, Groom.roots)"},
    {.name = "curve", .kind = DR_FIELD_TABLE, .unit = "m", .arity = 3, POS_RANGE,
     .doc = "slide: the curve, a polyline [[x, y, z], ...] of 2 points or more, in world space"},
    {.name = "target", .kind = DR_FIELD_NAME, .unit = "", .no_default = true,
     .doc = "rigid: the collider or bem_solid element that carries the vertices (a collider by its Motion, a body by "
            "its rigid frame)"},
};

static const DrFieldSpec joint_fields[] = {
    {.name = "body_a", .kind = DR_FIELD_NAME, .unit = "", .required = true,
     .doc = "name of a bem_solid element"},
    {.name = "body_b", .kind = DR_FIELD_NAME, .unit = "", .required = true,
     .doc = "name of another bem_solid element with the same BemSolver.time_step"},
    {.name = "mode", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "coincident", .choices = "coincident|point",
     .doc = "coincident: join every pair of vertices of the two bodies within tolerance of each other in the placed "
            "rest pose (a body split into parts, BEM 3.4); point: join the vertex of each body nearest to point"},
    {.name = "point", .kind = DR_FIELD_VEC3, .unit = "m", .no_default = true, POS_RANGE,
     .doc = "mode point: where the bodies are joined, in the placed rest pose (required with point)"},
    {.name = "tolerance", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {1e-6}, RANGE_LO_OPEN(0, 1),
     .doc = "mode coincident: the largest distance between two vertices that are joined"},
};

static const DrFieldSpec transform_fields[] = {
    {.name = "translate", .kind = DR_FIELD_VEC3, .unit = "m", .def = {0, 0, 0}, POS_RANGE,
     .doc = "translation, applied last"},
    {.name = "rotate_deg", .kind = DR_FIELD_VEC3, .unit = "deg", .def = {0, 0, 0}, RANGE(-36000, 36000),
     .doc = "XYZ Euler angles (x applied first), applied after scale"},
    {.name = "scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE_LO_OPEN(0, 1e6),
     .doc = "uniform scale, applied first"},
};

static const DrFieldSpec groom_fields[] = {
    {.name = "scalp", .kind = DR_FIELD_PATH, .unit = "",
     .doc = "triangle mesh the strands grow from: roots uniform by area, each strand along the interpolated "
            "area-weighted vertex normal (exactly one of scalp and curves)"},
    {.name = "curves", .kind = DR_FIELD_PATH, .unit = "",
     .doc = "OBJ file of polylines: each 'l' record is one strand, root first (exactly one of scalp and curves; "
            "the fields below, but for roots, are for scalp only)"},
    {.name = "count", .kind = DR_FIELD_INT, .unit = "", .def = {100}, RANGE(1, 1000000),
     .doc = "strands grown from the scalp"},
    {.name = "length", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {0.05}, RANGE_LO_OPEN(0, 100),
     .doc = "strand length (for a curled strand: along the helix)", .hint = "use a positive length such as 0.05"},
    {.name = "segments", .kind = DR_FIELD_INT, .unit = "", .def = {12}, RANGE(1, 1000),
     .doc = "edges per strand, equal in arc length (segments + 1 vertices)"},
    {.name = "curl_radius", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {0}, RANGE(0, 1),
     .doc = "radius of the right-handed helix each strand winds along, its axis parallel to the scalp normal; "
            "0 = straight along the normal"},
    {.name = "curl_pitch", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {0.01}, RANGE_LO_OPEN(0, 10),
     .doc = "rise of the helix along the normal per turn (curl_radius > 0 only)",
     .hint = "use a positive rise per turn such as 0.01"},
    {.name = "length_jitter", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0}, RANGE_HI_OPEN(0, 1),
     .doc = "random spread of strand lengths: each is length * (1 + length_jitter * u), u uniform in [-1, 1)"},
    {.name = "seed", .kind = DR_FIELD_INT, .unit = "", .def = {1}, RANGE(0, INT_MAX_31),
     .doc = "seed of the root placement, curl phases and length jitter (roots depend on scalp, count and seed only)"},
    {.name = "roots", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "clamped", .choices = "clamped|pinned|free",
     .doc = "how the strands hold to the scalp (scalp or curves): clamped (the first two vertices and the first edge's "
            "twist follow the scalp and its Motion), pinned (the first vertex only: the strand swivels about it) or "
            "free (loose strands: nothing holds them, Motion moves nothing, and no scalp pushes the hair, so strands, "
            "film and liquid keep their momentum but for gravity)"},
};

/* Human hair by default (r = 50 um, keratin): dr_rod_material_default in src/hair. */
static const DrFieldSpec rod_material_fields[] = {
    {.name = "radius", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {5e-5}, RANGE_LO_OPEN(0, 0.1),
     .doc = "strand radius r", .hint = "use a positive radius such as 5e-5 (human hair)"},
    {.name = "density", .kind = DR_FIELD_NUMBER, .unit = "kg/m^3", .def = {1300}, RANGE(1, 1e5),
     .doc = "mass density of the strand", .hint = "use a positive density such as 1300 for hair"},
    {.name = "youngs_modulus", .kind = DR_FIELD_NUMBER, .unit = "Pa", .def = {3.9e9}, RANGE_LO_OPEN(0, 1e12),
     .doc = "Young's modulus E: stretching E pi r^2, bending E pi r^4 / 4",
     .hint = "use a positive stiffness such as 3.9e9 for hair"},
    {.name = "shear_modulus", .kind = DR_FIELD_NUMBER, .unit = "Pa", .def = {1.3e9}, RANGE_LO_OPEN(0, 1e12),
     .doc = "shear modulus G: twisting G pi r^4 / 2 (default E / (2 (1 + 0.5)))",
     .hint = "use a positive stiffness such as 1.3e9 for hair"},
    {.name = "damping", .kind = DR_FIELD_NUMBER, .unit = "s", .def = {0}, RANGE(0, 10),
     .doc = "internal viscosity as a Kelvin-Voigt time constant: viscous force = damping * stiffness * strain "
            "rate on stretching, bending and twisting; 0 = none"},
    {.name = "tip_radius", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {0}, RANGE(0, 0.1),
     .doc = "radius at the tip of a tapered strand: the radius falls linearly along the strand from radius at the "
            "root to this (masses, stiffnesses and contact follow); 0 = radius all along"},
};

/* Box2D's collision filter (category and mask bits), with the category written as a group index. */
static const DrFieldSpec collision_group_fields[] = {
    {.name = "group", .kind = DR_FIELD_INT, .unit = "", .def = {0}, RANGE(0, 30),
     .doc = "collision group of this hair element, 0 to 30"},
    {.name = "collides_with", .kind = DR_FIELD_INT, .unit = "", .def = {INT_MAX_31}, RANGE(0, INT_MAX_31),
     .doc = "bitmask of the groups it collides with: bit k (value 2^k) for group k, default all (2^31 - 1). Two "
            "hair elements collide when each one's mask has the other's group; 0 = no contact with other hair"},
    {.name = "self_collision", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "contact between strands of this element (the masks do not apply to it)"},
};

/* 10 N/m: 30 times a default segment's bending stiffness (~0.3 N/m), so strands bend round each other
   instead of passing through, and the weight of ten default strands (5e-5 N) on one contact sinks it by 5 um,
   a tenth of a strand radius. Stiffer contacts cost solver iterations: each couples two strands as h²k/m, and
   the block preconditioner only sees the strands (1e3 N/m needs 4-10x the iterations of 10 N/m at 1e-3 s,
   tests/bench/bench_hair). */
static const DrFieldSpec collision_response_fields[] = {
    {.name = "stiffness", .kind = DR_FIELD_NUMBER, .unit = "N/m", .def = {10}, RANGE_LO_OPEN(0, 1e9),
     .doc = "stiffness of a strand-strand contact (between two elements: the smaller of their values)",
     .hint = "use a positive stiffness such as 10"},
    {.name = "friction", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.2}, RANGE(0, 10),
     .doc = "Coulomb friction of strand-strand contact, 0.2 for dry hair (between two elements: the larger of "
            "their values)"},
    {.name = "thickness", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {0}, RANGE(0, 1),
     .doc = "extra thickness around each strand for strand-strand contact: two strands touch at r_a + t_a + r_b "
            "+ t_b"},
    {.name = "damping", .kind = DR_FIELD_NUMBER, .unit = "s", .def = {0}, RANGE(0, 10),
     .doc = "viscous damping along the contact normal as a time constant: a contact resists its approach or "
            "separation speed with damping * stiffness * speed (between two elements: the larger of their values); "
            "0 = none"},
};

/* A collision element: which hair and cloth elements meet, by which method (its CollisionResponse: with which
   response). */
static const DrFieldSpec collision_fields[] = {
    {.name = "members", .kind = DR_FIELD_NAMES, .unit = "", .required = true,
     .doc = "the hair or cloth elements of the group, by name"},
    {.name = "method", .kind = DR_FIELD_ENUM, .unit = "", .required = true, .choices = "edge_edge|vertex_face",
     .doc = "how contacts are found: edge_edge between strand segments (hair members), vertex_face between a "
            "panel's vertices and its triangles (cloth members)"},
    {.name = "pairs", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "all", .choices = "all|self|between",
     .doc = "which members meet: all (each with itself and with every other), self (each with itself only) or "
            "between (different members only)"},
};

static const DrFieldSpec hair_solver_fields[] = {
    {.name = "preconditioner", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "block",
     .choices = "block|cluster|jacobi|none",
     .doc = "preconditioner of the conjugate-gradient solve: block (each strand's banded Cholesky factor), cluster "
            "(strands joined by contacts factored together: far fewer iterations when contacts are stiff or many, "
            "at the cost of a sparse factorisation per step), jacobi (the diagonal) or none"},
    {.name = "tolerance", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1e-6}, RANGE(1e-14, 0.1),
     .doc = "relative mass-weighted residual at which the solve stops"},
    {.name = "max_iterations", .kind = DR_FIELD_INT, .unit = "", .def = {500}, RANGE(1, 1000000),
     .doc = "iteration limit of the solve (reaching it is a warning; the step is kept)"},
    {.name = "substeps", .kind = DR_FIELD_INT, .unit = "", .def = {1}, RANGE(1, 100000),
     .doc = "hair steps per frame at least (more when the strands move fast: cfl)"},
    {.name = "cfl", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 100),
     .doc = "a hair step moves no vertex, and no film along its strand, by more than this many shortest segments of "
            "the groom: the hair takes more steps where it moves fast (0 = exactly `substeps`)"},
    {.name = "max_substeps", .kind = DR_FIELD_INT, .unit = "", .def = {1000}, RANGE(1, 1000000),
     .doc = "hair steps per frame at most that `cfl` may ask for (reaching it is a warning)"},
    {.name = "geometric_stiffness", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "include the geometric stiffness (the previous multipliers times the constraint Hessians) in the "
            "system matrix"},
};

/* Wet hair (src/wet): water on human hair by default. Fields marked precompute enter the cohesion tables that
   precompute builds (and so the precompute key). */
static const DrFieldSpec wetting_fields[] = {
    {.name = "contact_angle_deg", .kind = DR_FIELD_NUMBER, .unit = "deg", .def = {40}, RANGE(0, 80), .precompute = true,
     .doc = "contact angle of the liquid on the strands (and on colliders, for hair-solid cohesion)",
     .hint = "use an angle such as 40 (water on hair)"},
    {.name = "surface_tension", .kind = DR_FIELD_NUMBER, .unit = "N/m", .def = {0.072}, RANGE(0, 10),
     .doc = "surface tension of the liquid (water 0.072); 0 turns cohesion and the Laplace pressure off"},
    {.name = "density", .kind = DR_FIELD_NUMBER, .unit = "kg/m^3", .def = {1000}, RANGE(1, 1e5),
     .doc = "mass density of the liquid on the strands"},
    {.name = "viscosity", .kind = DR_FIELD_NUMBER, .unit = "Pa*s", .def = {0.001}, RANGE_LO_OPEN(0, 1e4),
     .doc = "dynamic viscosity of the liquid (the film's friction with its strand)",
     .hint = "use a positive viscosity such as 0.001 (water)"},
    {.name = "liquid", .kind = DR_FIELD_NAME, .unit = "", .no_default = true,
     .doc = "name of a liquid element to take density and viscosity from (its LiquidMaterial)"},
};

static const DrFieldSpec film_fields[] = {
    {.name = "initial_ratio", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(1, 100),
     .doc = "outer radius of the film at t=0 over the strand radius, H/r (1 = dry)"},
    {.name = "max_ratio", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {6}, RANGE_LO_OPEN(1, 100), .precompute = true,
     .doc = "largest H/r a strand holds; film beyond it gathers at the strand's ends (the cohesion tables cover bridges "
            "of two such films)", .hint = "use a ratio above 1 such as 6"},
    {.name = "friction", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1e6),
     .doc = "scale on the viscous friction between the film and its strand (1 = a thin viscous film's wall shear)"},
    {.name = "substeps", .kind = DR_FIELD_INT, .unit = "", .def = {1}, RANGE(1, 10000),
     .doc = "film steps per hair step at least (more when the film's CFL needs them)"},
};

static const DrFieldSpec cohesion_fields[] = {
    {.name = "scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1e6),
     .doc = "multiplies the force of every bridge between strands (0 = no cohesion)"},
    {.name = "solid_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1e6),
     .doc = "multiplies the force of every bridge between a strand and a collider"},
    {.name = "radius_multiplier", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1.6}, RANGE_LO_OPEN(1, 10),
     .doc = "rest distance of two bridged strands over their contact distance: the bridge pulls them to it and no "
            "closer", .hint = "use a multiplier above 1 such as 1.6"},
    {.name = "solid_radius_multiplier", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1.1}, RANGE_LO_OPEN(1, 10),
     .doc = "the same against a collider", .hint = "use a multiplier above 1 such as 1.1"},
    {.name = "table_resolution", .kind = DR_FIELD_INT, .unit = "", .def = {256}, RANGE(16, 4096), .precompute = true,
     .doc = "samples per axis of the cohesion tables (precompute)"},
};

static const DrFieldSpec cross_flow_fields[] = {
    {.name = "enabled", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "film flows between bridged strands"},
    {.name = "rate", .kind = DR_FIELD_NUMBER, .unit = "1/s", .def = {1}, RANGE_LO_OPEN(0, 1e6),
     .doc = "how fast the films of bridged strands even out: the fraction of their difference that flows per second",
     .hint = "use a positive rate such as 1"},
};

static const DrFieldSpec capture_fields[] = {
    {.name = "enabled", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "liquid particles touching a strand's film are absorbed into it (with a liquid in the scene)"},
    {.name = "rate", .kind = DR_FIELD_NUMBER, .unit = "1/s", .def = {10}, RANGE(0, 1e6),
     .doc = "how fast: a particle within reach gives the film the share 1 - exp(-rate dt) of its volume per step of dt"},
    {.name = "capacity", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1),
     .doc = "capture fills a strand up to this share of the largest film it holds (Film.max_ratio)"},
    {.name = "reach", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 10),
     .doc = "how far beyond the film's surface a particle is within reach, in particle radii"},
};

static const DrFieldSpec dripping_fields[] = {
    {.name = "enabled", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "film beyond what a strand holds leaves it as liquid particles (with a liquid in the scene)"},
    {.name = "radius_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.5}, RANGE_LO_OPEN(0, 100),
     .doc = "c in the largest drop a strand holds per cell, V_max = 4 pi r c^2 sigma / (rho a_n), a_n the strand's "
            "acceleration across itself (gravity included)", .hint = "use a positive scale such as 0.5"},
    {.name = "middle", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "drip along the strands where a cell holds more than V_max"},
    {.name = "root", .kind = DR_FIELD_BOOL, .unit = "", .def = {0},
     .doc = "release the liquid gathered at the roots"},
    {.name = "tip", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "release the liquid gathered at the tips"},
    {.name = "min_drop", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.5}, RANGE(0, 100),
     .doc = "a cell drips once its excess reaches this many liquid particles' volume"},
    {.name = "pool_release", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE_LO_OPEN(0, 1e6),
     .doc = "an end's pool is released once it holds this many liquid particles' volume",
     .hint = "use a positive number such as 1"},
    {.name = "budget", .kind = DR_FIELD_INT, .unit = "", .def = {20000}, RANGE(1, 100000000),
     .doc = "most drops made per step; film beyond it stays on the strands (with a warning), so a blow-up cannot "
            "flood the bake with particles"},
};

static const DrFieldSpec motion_fields[] = {
    {.name = "keys", .kind = DR_FIELD_TABLE, .unit = "frame, m, deg", .arity = 7, POS_RANGE,
     .doc = "rows [frame, tx, ty, tz, rx_deg, ry_deg, rz_deg]: rigid motion applied after Transform, "
            "linear between keys; frames strictly increasing"},
};

/* A soft jelly by default: c₂ = √(μ/ρ) = 10 m/s, so a body 0.2 m across keeps n_max = ⌊0.2/(10/240) + 2⌋ = 6
   history steps at the default 1/240 s. */
static const DrFieldSpec linear_elastic_fields[] = {
    {.name = "density", .kind = DR_FIELD_NUMBER, .unit = "kg/m^3", .def = {1000}, RANGE_LO_OPEN(0, 1e5),
     .doc = "mass density rho", .hint = "use a positive density such as 1000 for a jelly"},
    {.name = "shear_modulus", .kind = DR_FIELD_NUMBER, .unit = "Pa", .def = {1e5}, RANGE_LO_OPEN(0, 1e12),
     .doc = "shear modulus mu (Lame's second parameter; E = 2 mu (1 + nu))",
     .hint = "use a positive stiffness such as 1e5 for a jelly, 1e6 for rubber"},
    {.name = "poisson", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.4}, RANGE(-0.99, 0.49),
     .doc = "Poisson's ratio nu (0.5, incompressible, would make the longitudinal wave speed infinite)",
     .hint = "use a ratio such as 0.4 (at most 0.49)"},
};

static const DrFieldSpec compression_fields[] = {
    {.name = "ratio", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {32}, RANGE(1, 4096),
     .doc = "fraction of Haar coefficients kept is 1/ratio; 1 stores dense matrices",
     .hint = "use 32 (the paper's choice) or 1 for dense matrices"},
    {.name = "ordering", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "vertex_xyz", .choices = "vertex_xyz|xyz|none",
     .doc = "unknown ordering before the Haar transform: vertex_xyz (vertices along a Hilbert curve, coordinates in "
            "x, y, z blocks: the full scheme), xyz (coordinate blocks in the mesh's vertex order), none (interleaved, "
            "mesh order; for comparison)"},
};

static const DrFieldSpec bem_solver_fields[] = {
    {.name = "time_step", .kind = DR_FIELD_NUMBER, .unit = "s", .def = {1.0 / 240.0}, RANGE_LO_OPEN(0, 1),
     .doc = "dt the matrices are built for; the body advances at this step, a whole number of steps per frame (1/fps "
            "must be a multiple of it: 1/240 s is 10 steps at 24 fps)",
     .hint = "use a positive step such as 0.004166666666666667 (1/240 s)"},
    {.name = "history_margin", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {2}, RANGE(0, 1000),
     .doc = "history steps beyond r_max/(c2 dt): n_max = floor(r_max/(c2 dt) + margin), with r_max the body's "
            "largest vertex distance and c2 its shear wave speed"},
    {.name = "quadrature_levels", .kind = DR_FIELD_INT, .unit = "", .def = {1}, RANGE(1, 4),
     .doc = "4-way subdivisions of each triangle for the regular 9-point rule (1 = the paper's)"},
    /* How the body moves in a bake; the matrices do not depend on these, so they are not in the cache key. */
    {.name = "frame_update", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "move a rigid frame with the body (BEM eqs. 10-11); false keeps the frame fixed and linear elasticity "
            "carries all motion"},
    {.name = "error_correction", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "move the drift left in the displacement into the frame each step (BEM 3.2.1)"},
    {.name = "liquid_coupling", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "two_way", .choices = "two_way|one_way",
     .doc = "with a liquid in the scene: two_way, the liquid's pressure pushes the body (buoyancy, drag, splash) and the "
            "body pushes the liquid, its rigid motion solved with the liquid's pressure at every liquid substep and "
            "the pressure's traction loading its elastic step; one_way, the body moves the liquid and feels nothing "
            "of it. Bodies with one time_step move together, so they share one choice"},
};

static const DrFieldSpec drag_fields[] = {
    {.name = "model", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "scales", .choices = "scales|permeability",
     .doc = "scales: inverse permeabilities from the drag scales (relative to the slender-body Stokes drag, see "
            "reference); permeability: Drummond-Tahir permeabilities of a fibre array of the local solid fraction, "
            "times the scales"},
    {.name = "reference", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "stokes", .choices = "stokes|literal",
     .doc = "what the scales of model scales multiply: stokes (with every scale 1 a strand moving across itself feels "
            "the low-Reynolds drag per unit length 4 pi mu |dv| / (ln(2 L/D) + 1/2)) or literal (the published "
            "1e-4, about 1e4 times weaker)"},
    {.name = "global_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1e6),
     .doc = "xi_D: scales the drag in every direction (0: none)"},
    {.name = "normal_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1e6),
     .doc = "xi_perp: drag across the strand"},
    {.name = "tangent_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.5}, RANGE(0, 1e6),
     .doc = "xi_par: drag along the strand (slender-body theory: about half the drag across)"},
    {.name = "nonlinear_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1e6),
     .doc = "xi_N: the inertial (Ergun) part of the drag, growing with the Reynolds number of the strand"},
    {.name = "degree", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 3),
     .doc = "c: the power of the Reynolds number in the inertial part"},
    {.name = "lift_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0}, RANGE(0, 100),
     .doc = "xi_L: lift orthogonal to the relative velocity, strongest at 45 degrees between strand and flow "
            "(explicit: it limits the step)"},
    {.name = "buoyancy", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "the fluid's pressure gradient pushes on the strands' volume (Archimedes)"},
};

/* Cloth (src/cloth): a light cotton-like fabric by default (0.2 kg/m², E h = 500 N/m). */
static const DrFieldSpec cloth_material_fields[] = {
    {.name = "density", .kind = DR_FIELD_NUMBER, .unit = "kg/m^3", .def = {400}, RANGE(1, 1e5),
     .doc = "mass density of the fabric (its areal density is density * thickness)",
     .hint = "use a positive density such as 400 (0.2 kg/m^2 at 0.5 mm)"},
    {.name = "thickness", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {5e-4}, RANGE_LO_OPEN(0, 0.1),
     .doc = "shell thickness h: membrane stiffness E h / (1 - nu^2), bending E h^3 / (12 (1 - nu^2)); also the "
            "diameter of its drag law", .hint = "use a positive thickness such as 5e-4"},
    {.name = "youngs_modulus", .kind = DR_FIELD_NUMBER, .unit = "Pa", .def = {1e6}, RANGE_LO_OPEN(0, 1e12),
     .doc = "Young's modulus E of the fabric (StVK membrane in plane stress)", .hint = "use a positive stiffness such as 1e6"},
    {.name = "poisson", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.3}, RANGE_HI_OPEN(0, 0.5),
     .doc = "Poisson's ratio nu"},
    {.name = "bend_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1e6),
     .doc = "multiplies the plate's bending stiffness (woven fabric bends more easily than a plate of its membrane "
            "stiffness: values well below 1 are common); 0 = no bending"},
    {.name = "damping", .kind = DR_FIELD_NUMBER, .unit = "s", .def = {0}, RANGE(0, 10),
     .doc = "internal viscosity as a Kelvin-Voigt time constant on stretching and bending; 0 = none"},
    {.name = "self_contact", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "the panel's layers keep Collider.thickness (default 1 mm) apart: vertex-triangle contacts within the panel, "
            "with Collider.friction (a fold, a sheet landing on itself); the shorthand of a vertex_face collision "
            "element: in a scene that has collision elements they decide, and a written value must agree"},
    {.name = "bending", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "shape_operator", .choices = "shape_operator|hinge",
     .doc = "bending discretisation: shape_operator (each triangle's discrete shape operator from its edges' "
            "dihedral angles: Kirchhoff's plate energy with the material's nu on regular meshes) or hinge (one term "
            "per interior edge: cheaper, but its stiffness depends on how the mesh is cut)"},
};

static const DrFieldSpec cloth_solver_fields[] = {
    {.name = "substeps", .kind = DR_FIELD_INT, .unit = "", .def = {16}, RANGE(1, 100000),
     .doc = "cloth steps per frame at least (more when the cloth moves fast: cfl). Each step is one linearised "
            "implicit solve: a 1 m sheet of 33 x 33 vertices draped on a faceted sphere collider at 24 fps gains "
            "energy in a frame at 8 steps a frame and none at 16; on an analytic sphere, none at 8"},
    {.name = "cfl", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0.5}, RANGE(0, 100),
     .doc = "a cloth step moves no vertex by more than this many shortest edges of the panel (0 = exactly substeps)"},
    {.name = "max_substeps", .kind = DR_FIELD_INT, .unit = "", .def = {1000}, RANGE(1, 1000000),
     .doc = "cloth steps per frame at most that cfl may ask for (reaching it is a warning)"},
    {.name = "tolerance", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1e-8}, RANGE(1e-14, 0.1),
     .doc = "relative mass-weighted residual at which the solve stops"},
    {.name = "max_iterations", .kind = DR_FIELD_INT, .unit = "", .def = {1000}, RANGE(1, 1000000),
     .doc = "iteration limit of the solve (reaching it is a warning; the step is kept)"},
    {.name = "collider_stiffness", .kind = DR_FIELD_NUMBER, .unit = "N/m", .def = {1e4}, RANGE_LO_OPEN(0, 1e9),
     .doc = "stiffness of a vertex's contact with a collider, a bem_solid or an MPM solid"},
};

/* The face law of src/couple: C = diag(C_perp, C_par, C_par) in the frame of the surface's normal, 1/k = scale. */
static const DrFieldSpec cloth_drag_fields[] = {
    {.name = "normal", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1000}, RANGE(0, 1e9),
     .doc = "xi_perp: drag across the fabric, the inverse of its permeability in units of thickness^2 (h^2/k: a "
            "tight weave of 0.5 mm has k about 1e-10 m^2, so about 2500); the pressure a flow U loses through it is "
            "mu U normal / h"},
    {.name = "tangent", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {10}, RANGE(0, 1e9),
     .doc = "xi_par: drag of flow along the fabric, per thickness^2 as normal"},
    {.name = "nonlinear_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 1e6),
     .doc = "xi_N: the inertial (Ergun) part of the drag, growing with the Reynolds number of the thickness"},
    {.name = "degree", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {1}, RANGE(0, 3),
     .doc = "c: the power of the Reynolds number in the inertial part"},
    {.name = "lift_scale", .kind = DR_FIELD_NUMBER, .unit = "1", .def = {0}, RANGE(0, 100),
     .doc = "xi_L: lift of a panel at an angle to the flow, orthogonal to the relative velocity (explicit: it "
            "limits the step)"},
    {.name = "buoyancy", .kind = DR_FIELD_BOOL, .unit = "", .def = {1},
     .doc = "the fluid's pressure gradient pushes on the fabric's volume (Archimedes)"},
};

/* The air (liquid.h, "air"): air at sea level by default. */
static const DrFieldSpec air_domain_fields[] = {
    {.name = "box", .kind = DR_FIELD_BOX, .unit = "m", .required = true, POS_RANGE,
     .doc = "the box the air fills: the wind enters through one face (Wind.face), leaves through the opposite one "
            "(open, p = 0), and the other four are slip walls"},
    {.name = "voxel_size", .kind = DR_FIELD_NUMBER, .unit = "m", .def = {0.02}, RANGE(1e-4, 10),
     .doc = "grid cell size", .hint = "use a cell size such as 0.02 (a 1 m box gets 50 cells a side)"},
};

static const DrFieldSpec air_material_fields[] = {
    {.name = "density", .kind = DR_FIELD_NUMBER, .unit = "kg/m^3", .def = {1.2}, RANGE_LO_OPEN(0, 1000),
     .doc = "mass density", .hint = "use a positive density such as 1.2 for air"},
    {.name = "viscosity", .kind = DR_FIELD_NUMBER, .unit = "Pa*s", .def = {1.8e-5}, RANGE(0, 10),
     .doc = "dynamic viscosity", .hint = "air is 1.8e-5"},
};

static const DrFieldSpec wind_fields[] = {
    {.name = "face", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "-x", .choices = "-x|+x|-y|+y|-z|+z",
     .doc = "the face of the AirDomain box the wind enters through (-x: the low x face); it leaves through the "
            "opposite face"},
    {.name = "velocity", .kind = DR_FIELD_VEC3, .unit = "m/s", .def = {0, 0, 0}, RANGE(-1e3, 1e3),
     .doc = "wind velocity at the inflow face; its component normal to the face points into the box; [0, 0, 0] "
            "closes the box (six walls, still air unless colliders move it)"},
    {.name = "ramp", .kind = DR_FIELD_NUMBER, .unit = "s", .def = {0}, RANGE(0, 1e6),
     .doc = "time over which the wind grows linearly from 0 to velocity; 0 = at once"},
    {.name = "initial", .kind = DR_FIELD_ENUM, .unit = "", .def_str = "rest", .choices = "rest|stream",
     .doc = "the air at t=0: at rest, or moving with the full wind velocity everywhere"},
};

const DrComponentSpec dr_scene_components_[] = {
    {"Domain", "the simulation grid", domain_fields, COUNT(domain_fields)},
    {"LiquidSource", "liquid present at t=0 (needs box or mesh)", liquid_source_fields,
     COUNT(liquid_source_fields)},
    {"Emitter", "a box that keeps emitting liquid between start and end", emitter_fields, COUNT(emitter_fields)},
    {"KillBox", "a box that removes liquid", kill_box_fields, COUNT(kill_box_fields)},
    {"LiquidMaterial", "material of the liquid", liquid_material_fields, COUNT(liquid_material_fields)},
    {"Transfer", "particle-grid transfer scheme and kernel", transfer_fields, COUNT(transfer_fields)},
    {"Particles", "particle seeding", particles_fields, COUNT(particles_fields)},
    {"Pressure", "pressure projection", pressure_fields, COUNT(pressure_fields)},
    {"Mesh", "the element's surface mesh", mesh_file_fields, COUNT(mesh_file_fields)},
    {"Collider", "contact with collider surfaces: on a collider, how liquid, solids and hair meet its surface; on "
                 "hair, how its strands meet every collider; on a bem_solid, how its vertices meet every collider "
                 "(friction: the larger of the two elements' values) and the other bodies",
     collider_fields, COUNT(collider_fields)},
    {"FixedVertices", "vertices of a boundary-element body or a cloth held where they start (of a cloth: the shorthand "
                      "of a pin attachment element)",
     fixed_vertices_fields, COUNT(fixed_vertices_fields)},
    {"Joint", "two boundary-element bodies held together at vertices", joint_fields, COUNT(joint_fields)},
    {"SlideVertices", "vertices of a cloth held on a curve, free to slide along it (a curtain on its rail; the shorthand "
                      "of a slide attachment element)",
     slide_vertices_fields, COUNT(slide_vertices_fields)},
    {"Transform", "rest placement of the mesh (of an mpm_solid: of its MpmShape; of hair: of its scalp or curves; of a "
                  "bem_solid: its pose at t=0, scale 1 only): scale, then rotate, then translate",
     transform_fields, COUNT(transform_fields)},
    {"Motion", "keyframed rigid motion (of hair: of its scalp, which the roots follow; of cloth: of its FixedVertices, "
               "which move rigidly from where the placed rest pose has them)", motion_fields,
     COUNT(motion_fields)},
    {"MpmMaterial", "hyperelastic material of an MPM solid", mpm_material_fields, COUNT(mpm_material_fields)},
    {"MpmShape", "the body's shape at t=0, filled with particles: exactly one of box, centre and radius (a sphere), "
                 "or mesh", mpm_shape_fields, COUNT(mpm_shape_fields)},
    {"InitialVelocity", "rigid motion of the body at t=0", initial_velocity_fields, COUNT(initial_velocity_fields)},
    {"Integrator", "MPM time integration and its Newton and conjugate-gradient solves", integrator_fields,
     COUNT(integrator_fields)},
    {"Groom", "the strands: grown from a scalp mesh or read from OBJ polylines (exactly one of scalp and curves)",
     groom_fields, COUNT(groom_fields)},
    {"RodMaterial", "elastic rod material of the strands (human hair by default)", rod_material_fields,
     COUNT(rod_material_fields)},
    {"CollisionGroup", "which hair elements this one's strands collide with, and whether they collide with each "
                       "other; colliders meet every hair element",
     collision_group_fields, COUNT(collision_group_fields)},
    {"CollisionResponse", "contact response: stiffness, damping, friction and thickness (of a hair element's "
                          "strand-strand contacts, or of a collision element's contacts)",
     collision_response_fields, COUNT(collision_response_fields)},
    {"Collision", "the members of a collision element and the method that finds their contacts",
     collision_fields, COUNT(collision_fields)},
    {"Attachment", "what an attachment element holds (members, and a cloth's vertices in box) and how: pin, slide "
                   "or rigid", attachment_fields, COUNT(attachment_fields)},
    {"HairSolver", "the linear solve of a hair step (the same for every hair element: they are solved together)",
     hair_solver_fields, COUNT(hair_solver_fields)},
    {"Wetting", "makes a hair element wet: the liquid its strands carry (the same on every wet hair element)",
     wetting_fields, COUNT(wetting_fields)},
    {"Film", "the film of liquid on each strand (the same on every wet hair element but initial_ratio); needs "
             "Wetting", film_fields, COUNT(film_fields)},
    {"Cohesion", "capillary bridges between wet strands and between wet strands and colliders (the same on every wet "
                 "hair element); needs Wetting", cohesion_fields, COUNT(cohesion_fields)},
    {"CrossFlow", "film flowing between bridged strands (the same on every wet hair element); needs Wetting",
     cross_flow_fields, COUNT(cross_flow_fields)},
    {"Capture", "bulk liquid absorbed into the film of the strands it touches (the same on every wet hair element); "
                "needs Wetting", capture_fields, COUNT(capture_fields)},
    {"Dripping", "film a strand cannot hold released as liquid particles, along the strands and from their ends (the "
                 "same on every wet hair element); needs Wetting", dripping_fields, COUNT(dripping_fields)},
    {"Drag", "couples a hair element two ways with the liquid: anisotropic porous drag, lift and buoyancy in the "
             "coupled loop (solver.coupling_iterations); hair without it does not feel the liquid",
     drag_fields, COUNT(drag_fields)},
    {"LinearElastic", "isotropic linear elastic material of a boundary-element body", linear_elastic_fields,
     COUNT(linear_elastic_fields)},
    {"Compression", "wavelet compression of the boundary-element matrices (Haar transform, largest coefficients kept)",
     compression_fields, COUNT(compression_fields)},
    {"AirDomain", "the box and grid of an air element", air_domain_fields, COUNT(air_domain_fields)},
    {"AirMaterial", "material of the air", air_material_fields, COUNT(air_material_fields)},
    {"Wind", "the wind blowing into the air's box through one face", wind_fields, COUNT(wind_fields)},
    {"ClothMaterial", "the fabric of a cloth element: discrete shells (StVK membrane, plate bending)",
     cloth_material_fields, COUNT(cloth_material_fields)},
    {"ClothSolver", "the steps of a cloth element and their linear solve", cloth_solver_fields,
     COUNT(cloth_solver_fields)},
    {"ClothDrag", "couples a cloth element two ways with the scene's fluid (liquid or air): porous drag across and "
                  "along the fabric, lift and buoyancy in the coupled loop",
     cloth_drag_fields, COUNT(cloth_drag_fields)},
    {"BemSolver", "time discretisation of a boundary-element body: the step its matrices are built for, the history "
                  "length and the spatial quadrature; and how the body's frame moves in a bake",
     bem_solver_fields, COUNT(bem_solver_fields)},
};
const int dr_scene_component_count_ = COUNT(dr_scene_components_);

/* ---- element types --------------------------------------------------------------------------------------- */

static const char *const liquid_components[] = {"Domain",         "LiquidSource", "Emitter",   "KillBox",
                                                "LiquidMaterial", "Transfer",     "Particles", "Pressure"};
static const char *const liquid_required[] = {"Domain"};
static const char *const collider_components[] = {"Mesh", "Collider", "Transform", "Motion"};
static const char *const collider_required[] = {"Mesh"};
static const char *const mpm_solid_components[] = {"Domain",     "MpmShape", "MpmMaterial", "InitialVelocity",
                                                   "Transform", "Transfer", "Integrator"};
static const char *const mpm_solid_required[] = {"Domain", "MpmShape"};
static const char *const hair_components[] = {"Groom",          "RodMaterial",       "Collider",   "Transform",
                                              "Motion",         "CollisionGroup",    "CollisionResponse", "HairSolver",
                                              "Wetting",        "Film",              "Cohesion",   "CrossFlow",
                                              "Capture",        "Dripping",          "Drag"};
static const char *const hair_required[] = {"Groom"};
static const char *const bem_solid_components[] = {"Mesh",      "LinearElastic",   "Compression", "BemSolver",
                                                   "Transform", "InitialVelocity", "Collider",    "FixedVertices"};
static const char *const bem_solid_required[] = {"Mesh"};
static const char *const bem_joint_components[] = {"Joint"};
static const char *const air_components[] = {"AirDomain", "AirMaterial", "Wind"};
static const char *const cloth_components[] = {"Mesh",     "Transform", "ClothMaterial", "ClothSolver",  "ClothDrag",
                                               "Collider", "FixedVertices", "SlideVertices", "Motion"};
static const char *const cloth_required[] = {"Mesh"};
static const char *const air_required[] = {"AirDomain"};
static const char *const collision_components[] = {"Collision", "CollisionResponse"};
static const char *const collision_required[] = {"Collision"};
static const char *const attachment_components[] = {"Attachment"};

const DrElementSpec dr_scene_types_[] = {
    {"liquid", "a body of incompressible liquid (APIC/FLIP/PIC particles on a MAC grid inside its Domain)",
     liquid_components, COUNT(liquid_components), liquid_required, COUNT(liquid_required), false, DR_ELEMENT_LIQUID},
    {"collider", "a rigid obstacle given by a closed triangle mesh, optionally moving", collider_components,
     COUNT(collider_components), collider_required, COUNT(collider_required), false, DR_ELEMENT_COLLIDER},
    {"mpm_solid",
     "an elastic solid on the material point method; every mpm_solid of a scene shares one grid (the bounding box "
     "of their Domain boxes, one voxel_size), so the bodies collide with each other",
     mpm_solid_components, COUNT(mpm_solid_components), mpm_solid_required, COUNT(mpm_solid_required), false, DR_ELEMENT_MPM_SOLID},
    {"hair",
     "strands of hair or fur as discrete elastic rods, grown from a scalp mesh or read from OBJ polylines; the roots "
     "are held to the scalp and follow its Transform and Motion (Groom.roots: or left free)",
     hair_components, COUNT(hair_components), hair_required, COUNT(hair_required), false, DR_ELEMENT_HAIR},
    {"bem_solid",
     "an elastic body simulated on its surface only by the boundary element method; its matrices are computed by "
     "precompute and cached under cache/bem, and bake moves it from the pose of its Transform with its "
     "InitialVelocity under gravity",
     bem_solid_components, COUNT(bem_solid_components), bem_solid_required, COUNT(bem_solid_required), true, DR_ELEMENT_BEM_SOLID},
    {"bem_joint", "a joint between two bem_solid bodies: their vertices held together in a bake",
     bem_joint_components, COUNT(bem_joint_components), bem_joint_components, COUNT(bem_joint_components), false, DR_ELEMENT_BEM_JOINT},
    {"air",
     "incompressible air filling its AirDomain box on a MAC grid, blown by a Wind through one face; colliders move "
     "it; at most one per scene, and not yet together with a liquid",
     air_components, COUNT(air_components), air_required, COUNT(air_required), false, DR_ELEMENT_AIR},
    {"cloth",
     "a panel of cloth from a triangle mesh (its rest shape, placed by Transform) as discrete shells on the "
     "Lagrangian solver; FixedVertices pins it, colliders, bem_solid and MPM bodies hold it up, ClothDrag couples it "
     "with the liquid or the air",
     cloth_components, COUNT(cloth_components), cloth_required, COUNT(cloth_required), false, DR_ELEMENT_CLOTH},
    {"collision",
     "a collision group: its members (hair or cloth elements) meet each other or themselves by one method with the "
     "response of its CollisionResponse; several give several methods or responses. Once a scene has one, collision "
     "elements alone say which strands and panels touch (a hair's CollisionGroup and CollisionResponse and a cloth's "
     "ClothMaterial.self_contact are their shorthand, for scenes without them)",
     collision_components, COUNT(collision_components), collision_required, COUNT(collision_required), false,
     DR_ELEMENT_COLLISION},
    {"attachment",
     "an attachment: vertices of its members held by a pin, on a curve (slide) or rigidly to a collider or a bem_solid "
     "body; a cloth's FixedVertices and SlideVertices are its shorthand",
     attachment_components, COUNT(attachment_components), attachment_components, COUNT(attachment_components), false,
     DR_ELEMENT_ATTACHMENT},
};
const int dr_scene_type_count_ = COUNT(dr_scene_types_);
_Static_assert(COUNT(dr_scene_types_) == DR_ELEMENT_ATTACHMENT + 1, "one DrElementKind per element type");

/* ---- lookups ---------------------------------------------------------------------------------------------- */

int dr_scene_section_index_(const char *name)
{
    for (int i = 0; i < dr_scene_section_count_; i++)
        if (strcmp(dr_scene_sections_[i].name, name) == 0) return i;
    return -1;
}

const DrComponentSpec *dr_scene_section_spec(const char *name)
{
    int i = dr_scene_section_index_(name);
    return i < 0 ? NULL : &dr_scene_sections_[i];
}

const DrComponentSpec *dr_scene_component_spec(const char *name)
{
    for (int i = 0; i < dr_scene_component_count_; i++)
        if (strcmp(dr_scene_components_[i].name, name) == 0) return &dr_scene_components_[i];
    return NULL;
}

const DrElementSpec *dr_scene_element_spec(const char *type)
{
    for (int i = 0; i < dr_scene_type_count_; i++)
        if (strcmp(dr_scene_types_[i].type, type) == 0) return &dr_scene_types_[i];
    return NULL;
}

int dr_scene_field_index_(const DrComponentSpec *c, const char *field)
{
    for (int i = 0; i < c->field_count; i++)
        if (strcmp(c->fields[i].name, field) == 0) return i;
    return -1;
}

int dr_scene_kind_width_(const DrFieldSpec *f)
{
    switch (f->kind) {
    case DR_FIELD_NUMBER:
    case DR_FIELD_INT:
    case DR_FIELD_BOOL: return 1;
    case DR_FIELD_VEC3: return 3;
    case DR_FIELD_INT2: return 2;
    case DR_FIELD_BOX: return 6;
    case DR_FIELD_TABLE: return f->arity;
    case DR_FIELD_ENUM:
    case DR_FIELD_NAME:
    case DR_FIELD_NAMES:
    case DR_FIELD_PATH: return 0;
    }
    return 0;
}

int dr_scene_split_choices_(const char *choices, char *buf, size_t size, const char **names, int max)
{
    snprintf(buf, size, "%s", choices);
    int n = 0;
    for (char *p = buf; n < max;) {
        names[n++] = p;
        char *bar = strchr(p, '|');
        if (!bar) break;
        *bar = '\0';
        p = bar + 1;
    }
    return n;
}

void dr_scene_join_names_(const char *const *names, int n, char *buf, size_t size)
{
    size_t used = 0;
    if (size) buf[0] = '\0';
    for (int i = 0; i < n && used < size; i++) used += (size_t)snprintf(buf + used, size - used, "%s%s", i ? ", " : "", names[i]);
}

static bool choice_ok(const char *choices, const char *s)
{
    char buf[256];
    const char *names[16];
    int n = dr_scene_split_choices_(choices, buf, sizeof buf, names, 16);
    for (int i = 0; i < n; i++)
        if (strcmp(names[i], s) == 0) return true;
    return false;
}

static void check_component_spec(const DrComponentSpec *c)
{
    assert(c->name && c->doc && c->field_count > 0);
    for (int i = 0; i < c->field_count; i++) {
        const DrFieldSpec *f = &c->fields[i];
        assert(f->name && f->unit && f->doc);
        assert(dr_scene_field_index_(c, f->name) == i && "duplicate field name");
        int w = dr_scene_kind_width_(f);
        bool has_def = !f->required && !f->no_default;
        if (f->kind == DR_FIELD_TABLE) assert(f->arity >= 1 && !f->required);
        if (f->kind == DR_FIELD_NAMES) assert(f->required && "a list of names is always required");
        if (f->kind == DR_FIELD_ENUM) assert(f->choices && (!has_def || choice_ok(f->choices, f->def_str)));
        if (f->kind == DR_FIELD_ENUM || f->kind == DR_FIELD_NAME) assert(!has_def || f->def_str);
        if (f->kind == DR_FIELD_INT || f->kind == DR_FIELD_INT2)
            assert(f->ranged && f->lo >= -INT_MAX_31 && f->hi <= INT_MAX_31 && "an INT needs a range that fits an int");
        if (f->kind == DR_FIELD_PATH) assert(!f->def_str && "an asset path has no default");
        if (!has_def || f->kind == DR_FIELD_TABLE) continue;
        for (int k = 0; k < w; k++) {
            double v = f->def[k];
            if (f->kind == DR_FIELD_INT || f->kind == DR_FIELD_INT2) assert(v == floor(v));
            if (f->ranged)
                assert((f->lo_open ? v > f->lo : v >= f->lo) && (f->hi_open ? v < f->hi : v <= f->hi) &&
                       "default outside its range");
        }
    }
}

void dr_scene_check_tables_(void)
{
    for (int i = 0; i < dr_scene_section_count_; i++) {
        const DrComponentSpec *c = &dr_scene_sections_[i];
        check_component_spec(c);
        assert(dr_scene_section_index_(c->name) == i);
        const char *dot = strrchr(c->name, '.');
        if (dot) { /* a nested section follows its parent */
            int parent = -1;
            for (int j = 0; j < i; j++)
                if (strlen(dr_scene_sections_[j].name) == (size_t)(dot - c->name) &&
                    strncmp(dr_scene_sections_[j].name, c->name, (size_t)(dot - c->name)) == 0)
                    parent = j;
            assert(parent >= 0 && "nested section without a parent before it");
            assert(dr_scene_field_index_(&dr_scene_sections_[parent], dot + 1) < 0);
        }
    }
    for (int i = 0; i < dr_scene_component_count_; i++) {
        check_component_spec(&dr_scene_components_[i]);
        assert(dr_scene_component_spec(dr_scene_components_[i].name) == &dr_scene_components_[i]);
    }
    for (int i = 0; i < dr_scene_type_count_; i++) {
        const DrElementSpec *t = &dr_scene_types_[i];
        assert(dr_scene_element_spec(t->type) == t);
        for (int j = 0; j < t->component_count; j++) assert(dr_scene_component_spec(t->components[j]));
        for (int j = 0; j < t->required_count; j++) {
            bool listed = false;
            for (int k = 0; k < t->component_count; k++) listed |= strcmp(t->components[k], t->required_components[j]) == 0;
            assert(listed);
        }
    }
}

/* ---- text helpers --------------------------------------------------------------------------------------- */

#define EDIT_MAX 64 /* longer words get no suggestion; no schema name is this long */

int dr_scene_edit_distance_(const char *a, const char *b)
{
    size_t n = strlen(a), m = strlen(b);
    if (n > EDIT_MAX || m > EDIT_MAX) return 1 << 20;
    int prev[EDIT_MAX + 1], cur[EDIT_MAX + 1];
    for (size_t j = 0; j <= m; j++) prev[j] = (int)j;
    for (size_t i = 1; i <= n; i++) {
        cur[0] = (int)i;
        for (size_t j = 1; j <= m; j++) {
            int cost = tolower((unsigned char)a[i - 1]) != tolower((unsigned char)b[j - 1]);
            int best = prev[j - 1] + cost;
            if (prev[j] + 1 < best) best = prev[j] + 1;
            if (cur[j - 1] + 1 < best) best = cur[j - 1] + 1;
            cur[j] = best;
        }
        memcpy(prev, cur, sizeof(int) * (m + 1));
    }
    return prev[m];
}

const char *dr_scene_suggest_(const char *word, const char *const *names, int n)
{
    const char *best = NULL;
    int best_d = 1 << 30;
    size_t wlen = strlen(word);
    for (int i = 0; i < n; i++) {
        /* a third of the longer name: "viscoy" still finds "viscosity", "fps" never becomes "seed" */
        size_t len = strlen(names[i]) > wlen ? strlen(names[i]) : wlen;
        int limit = (int)(len / 3) < 2 ? 2 : (int)(len / 3);
        int d = dr_scene_edit_distance_(word, names[i]);
        if (d <= limit && d < best_d) { best_d = d; best = names[i]; }
    }
    return best;
}

void dr_scene_fmt_num_(double v, char *buf, size_t size) { snprintf(buf, size, "%.15g", v == 0.0 ? 0.0 : v); }

void dr_scene_fmt_range_(const DrFieldSpec *f, char *buf, size_t size)
{
    if (!f->ranged) {
        if (size) buf[0] = '\0';
        return;
    }
    char lo[32], hi[32];
    dr_scene_fmt_num_(f->lo, lo, sizeof lo);
    dr_scene_fmt_num_(f->hi, hi, sizeof hi);
    snprintf(buf, size, "%c%s, %s%c", f->lo_open ? '(' : '[', lo, hi, f->hi_open ? ')' : ']');
}

/* ---- the printed reference -------------------------------------------------------------------------------- */

static void kind_text(const DrFieldSpec *f, char *buf, size_t size)
{
    switch (f->kind) {
    case DR_FIELD_NUMBER: snprintf(buf, size, "number"); return;
    case DR_FIELD_INT: snprintf(buf, size, "integer"); return;
    case DR_FIELD_BOOL: snprintf(buf, size, "bool"); return;
    case DR_FIELD_NAME: snprintf(buf, size, "name"); return;
    case DR_FIELD_PATH: snprintf(buf, size, "path"); return;
    case DR_FIELD_VEC3: snprintf(buf, size, "[x, y, z]"); return;
    case DR_FIELD_INT2: snprintf(buf, size, "[int, int]"); return;
    case DR_FIELD_BOX: snprintf(buf, size, "box [lo, hi]"); return;
    case DR_FIELD_TABLE: snprintf(buf, size, "rows of %d", f->arity); return;
    case DR_FIELD_NAMES: snprintf(buf, size, "names"); return;
    case DR_FIELD_ENUM: {
        char split[256], list[256];
        const char *names[16];
        int n = dr_scene_split_choices_(f->choices, split, sizeof split, names, 16);
        dr_scene_join_names_(names, n, list, sizeof list);
        snprintf(buf, size, "one of %s", list);
        return;
    }
    }
}

void dr_scene_default_text_(const DrFieldSpec *f, char *buf, size_t size)
{
    char a[32], b[32], c[32], d[32], e[32], g[32];
    if (f->required) { snprintf(buf, size, "required"); return; }
    if (f->kind == DR_FIELD_TABLE) { snprintf(buf, size, "[]"); return; }
    if (f->no_default || f->kind == DR_FIELD_PATH) { snprintf(buf, size, "unset"); return; }
    dr_scene_fmt_num_(f->def[0], a, sizeof a);
    dr_scene_fmt_num_(f->def[1], b, sizeof b);
    dr_scene_fmt_num_(f->def[2], c, sizeof c);
    dr_scene_fmt_num_(f->def[3], d, sizeof d);
    dr_scene_fmt_num_(f->def[4], e, sizeof e);
    dr_scene_fmt_num_(f->def[5], g, sizeof g);
    switch (f->kind) {
    case DR_FIELD_NUMBER:
    case DR_FIELD_INT: snprintf(buf, size, "%s", a); return;
    case DR_FIELD_BOOL: snprintf(buf, size, "%s", f->def[0] != 0.0 ? "true" : "false"); return;
    case DR_FIELD_ENUM:
    case DR_FIELD_NAME: snprintf(buf, size, "\"%s\"", f->def_str); return;
    case DR_FIELD_VEC3: snprintf(buf, size, "[%s, %s, %s]", a, b, c); return;
    case DR_FIELD_INT2: snprintf(buf, size, "[%s, %s]", a, b); return;
    case DR_FIELD_BOX: snprintf(buf, size, "[[%s, %s, %s], [%s, %s, %s]]", a, b, c, d, e, g); return;
    case DR_FIELD_PATH:
    case DR_FIELD_TABLE:
    case DR_FIELD_NAMES: return;
    }
}

/* Markdown table cell text: '|' would end the cell, '<' and '>' would read as HTML. */
static void put_md(FILE *f, const char *s)
{
    for (; *s; s++) {
        if (*s == '|') fputs("\\|", f);
        else if (*s == '<') fputs("&lt;", f);
        else if (*s == '>') fputs("&gt;", f);
        else fputc(*s, f);
    }
}

/* ---- plain text: columns measured over every table, descriptions wrapped at DR_REFERENCE_COLUMNS ---- */

typedef struct Columns {
    int name, kind, unit, def; /* widths; range is the last column */
} Columns;

static void plain_kind(const DrFieldSpec *f, char *buf, size_t size)
{
    if (f->kind == DR_FIELD_ENUM) snprintf(buf, size, "choice");
    else kind_text(f, buf, size);
}

static void measure_fields(const DrComponentSpec *c, Columns *w)
{
    for (int i = 0; i < c->field_count; i++) {
        const DrFieldSpec *fs = &c->fields[i];
        char kind[288], def[256];
        plain_kind(fs, kind, sizeof kind);
        dr_scene_default_text_(fs, def, sizeof def);
        int n = (int)strlen(fs->name), k = (int)strlen(kind), u = (int)strlen(fs->unit), d = (int)strlen(def);
        if (n > w->name) w->name = n;
        if (k > w->kind) w->kind = k;
        if (u > w->unit) w->unit = u;
        if (d > w->def) w->def = d;
    }
}

static Columns measure_columns(void)
{
    Columns w = {(int)strlen("field"), (int)strlen("type"), (int)strlen("unit"), (int)strlen("default")};
    for (int i = 0; i < dr_scene_section_count_; i++) measure_fields(&dr_scene_sections_[i], &w);
    for (int i = 0; i < dr_scene_component_count_; i++) measure_fields(&dr_scene_components_[i], &w);
    return w;
}

/* Prints `first` then `text`, wrapped at word boundaries so no line passes DR_REFERENCE_COLUMNS; lines
   after the first start with `indent` spaces. A word longer than a line stands alone on its line. */
static void put_wrapped(FILE *f, const char *first, int indent, const char *text)
{
    int col = (int)strlen(first);
    fputs(first, f);
    bool line_empty = col == 0 || first[col - 1] == ' '; /* else a space before the first word */
    for (const char *p = text; *p;) {
        while (*p == ' ') p++;
        if (!*p) break;
        int len = (int)strcspn(p, " ");
        if (!line_empty && col + 1 + len > DR_REFERENCE_COLUMNS) {
            fprintf(f, "\n%*s", indent, "");
            col = indent;
            line_empty = true;
        }
        if (!line_empty) {
            fputc(' ', f);
            col++;
        }
        fwrite(p, 1, (size_t)len, f);
        col += len;
        line_empty = false;
        p += len;
    }
    fputc('\n', f);
}

static void print_fields(FILE *f, const DrComponentSpec *c, bool md, const Columns *w)
{
    if (md) {
        fprintf(f, "| field | type | unit | default | range | description |\n");
        fprintf(f, "| --- | --- | --- | --- | --- | --- |\n");
    }
    for (int i = 0; i < c->field_count; i++) {
        const DrFieldSpec *fs = &c->fields[i];
        char kind[288], def[256], range[96];
        dr_scene_default_text_(fs, def, sizeof def);
        dr_scene_fmt_range_(fs, range, sizeof range);
        const char *unit = strcmp(fs->unit, "") == 0 ? "-" : fs->unit;
        if (md) {
            kind_text(fs, kind, sizeof kind);
            fprintf(f, "| `%s` | %s | %s | %s%s%s | %s | ", fs->name, kind, unit, fs->required ? "**" : "`", def,
                    fs->required ? "**" : "`", range[0] ? range : "-");
            put_md(f, fs->doc);
            fprintf(f, " |\n");
            continue;
        }
        /* one aligned row, then the description (an enum's choices first) wrapped under it */
        plain_kind(fs, kind, sizeof kind);
        char row[512], doc[1024];
        int len = snprintf(row, sizeof row, "    %-*s  %-*s  %-*s  %-*s  %s", w->name, fs->name, w->kind, kind, w->unit,
                           unit, w->def, def, range[0] ? range : "-");
        size_t end = len < (int)sizeof row ? (size_t)len : sizeof row - 1; /* the widths are the tables' own */
        while (end > 0 && row[end - 1] == ' ') row[--end] = 0;
        fprintf(f, "%s\n", row);
        if (fs->kind == DR_FIELD_ENUM) {
            char split[256], list[256];
            const char *names[16];
            int n = dr_scene_split_choices_(fs->choices, split, sizeof split, names, 16);
            dr_scene_join_names_(names, n, list, sizeof list);
            snprintf(doc, sizeof doc, "one of %s: %s", list, fs->doc);
        } else {
            snprintf(doc, sizeof doc, "%s", fs->doc);
        }
        put_wrapped(f, "        ", 8, doc);
    }
    if (md) fprintf(f, "\n");
}

/* `required`: a component the element type must have (marked in the heading). */
static void print_component(FILE *f, const char *heading, const DrComponentSpec *c, bool required, bool md,
                            const Columns *w)
{
    if (md) {
        fprintf(f, "%s `%s`%s\n\n", heading, c->name, required ? " (required)" : "");
        put_md(f, c->doc);
        fprintf(f, ".\n\n");
    } else {
        char first[160];
        snprintf(first, sizeof first, "  %s%s:", c->name, required ? " (required)" : "");
        put_wrapped(f, first, 6, c->doc);
    }
    print_fields(f, c, md, w);
}

static bool is_required(const DrElementSpec *t, const char *component)
{
    for (int k = 0; k < t->required_count; k++)
        if (strcmp(t->required_components[k], component) == 0) return true;
    return false;
}

void dr_scene_print_reference(FILE *f, bool md)
{
    Columns w = measure_columns();
    char header[256];
    snprintf(header, sizeof header, "    %-*s  %-*s  %-*s  %-*s  %s", w.name, "field", w.kind, "type", w.unit, "unit",
             w.def, "default", "range");
    if (md)
        fprintf(f, "# Scene reference\n\nGenerated from the tables the scene parser uses. Units are SI; angles "
                   "in degrees. A range applies to every number of a field. Absent sections, components "
                   "and fields take the defaults below.\n\n## Sections\n\nTop-level keys of the scene "
                   "object, all optional; `render.camera` is the object `camera` inside `render`.\n\n");
    else
        fprintf(f, "drench scene reference (units SI, angles in degrees; a range applies to every number of a "
                   "field;\nabsent sections, components and fields take the defaults; each field's description is "
                   "under it)\n\nSections (top-level keys, all optional):\n%s\n", header);
    for (int i = 0; i < dr_scene_section_count_; i++) print_component(f, "###", &dr_scene_sections_[i], false, md, &w);

    if (md)
        fprintf(f, "## Elements\n\n`\"elements\"` is an array of objects `{\"name\": ..., \"type\": ..., "
                   "\"components\": {...}}`; names are unique identifiers ([A-Za-z0-9_.-]).\n\n");
    else
        fprintf(f, "\nElements: \"elements\": [{\"name\": NAME, \"type\": TYPE, \"components\": {COMPONENT: "
                   "{FIELD: VALUE}}}],\nnames unique; a component marked (required) must be written, an absent one "
                   "reads as its defaults\n");
    for (int i = 0; i < dr_scene_type_count_; i++) {
        const DrElementSpec *t = &dr_scene_types_[i];
        char list[1024] = "";
        size_t used = 0;
        for (int j = 0; j < t->component_count && used < sizeof list; j++)
            used += (size_t)snprintf(list + used, sizeof list - used, "%s %s%s", j ? "," : "", t->components[j],
                                     is_required(t, t->components[j]) ? " (required)" : "");
        if (md) {
            fprintf(f, "### Element type `%s`\n\n%s.\n\nComponents:%s.\n\n", t->type, t->doc, list);
        } else {
            char first[160];
            snprintf(first, sizeof first, "Element type %s:", t->type);
            fputc('\n', f);
            put_wrapped(f, first, 2, t->doc);
            put_wrapped(f, "  components:", 4, list);
            fprintf(f, "%s\n", header);
        }
        for (int j = 0; j < t->component_count; j++)
            print_component(f, "####", dr_scene_component_spec(t->components[j]), is_required(t, t->components[j]), md,
                            &w);
    }
}
