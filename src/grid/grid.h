/* drench grid: the staggered (MAC) grid of the liquid, the interpolation kernels shared by the
 * particle–grid transfers (quadratic B-spline, linear), and rigid colliders given as dense signed
 * distance fields moving by keyed transforms.
 *
 * Units: metres, seconds. Thread safety: a DrMacGrid or DrCollider may be read from several threads
 * at once; nothing here mutates shared state after creation. */
#ifndef DR_GRID_H
#define DR_GRID_H

#include "core/core.h"

/* ---- MAC grid ---------------------------------------------------------------------------------- */

/* nx·ny·nz cubic cells of edge dx; cell (i,j,k) spans origin + dx·[i,i+1]×[j,j+1]×[k,k+1].
 * Face component a (0 = u, 1 = v, 2 = w) lives on the faces normal to axis a: u(i,j,k) at
 * origin + dx·(i, j+½, k+½), i in [0, nx], and likewise for v and w. Arrays are x fastest:
 * u index i + (nx+1)·(j + ny·k), v index i + nx·(j + (ny+1)·k), w index i + nx·(j + ny·k).
 * The grid owns its arrays (dr_mac_grid_create/destroy). */
typedef struct DrMacGrid {
    int nx, ny, nz;
    double dx;
    DrVec3 origin;
    int fdim[3][3]; /* fdim[a] = face counts of component a along x, y, z */
    long nfaces[3]; /* fdim[a][0]·fdim[a][1]·fdim[a][2] */
    union {
        struct { double *u, *v, *w; };
        double *f[3]; /* f[a] == u, v, w: face velocities, m/s */
    };
} DrMacGrid;

/* DR_ERR_INPUT for non-positive sizes or dx, DR_ERR_NOMEM on exhaustion or size overflow. */
DR_NODISCARD DrStatus dr_mac_grid_create(int nx, int ny, int nz, double dx, DrVec3 origin,
                                         DrMacGrid **out, DrError *err);
void dr_mac_grid_destroy(DrMacGrid **g);

static inline long dr_mac_cell_index(const DrMacGrid *g, int i, int j, int k)
{
    return (long)i + (long)g->nx * ((long)j + (long)g->ny * (long)k);
}
static inline long dr_mac_face_index(const DrMacGrid *g, int a, int i, int j, int k)
{
    return (long)i + (long)g->fdim[a][0] * ((long)j + (long)g->fdim[a][1] * (long)k);
}
/* Offset (in cells) of face component a's node lattice: 0 along axis a, ½ along the others. */
static inline double dr_mac_face_offset(int a, int axis) { return a == axis ? 0.0 : 0.5; }
/* World position of face (a; i,j,k). */
DrVec3 dr_mac_face_position(const DrMacGrid *g, int a, int i, int j, int k);
DrVec3 dr_mac_cell_center(const DrMacGrid *g, int i, int j, int k);

/* ---- face coupling ------------------------------------------------------------------------------- */

/* What solids impose on the liquid at the MAC faces: one value per face of each component, each array
 * sized like the grid's faces (nfaces[a], the grid's face order). The liquid keeps one of these for its
 * colliders (their variational face weights and velocities, liquid.h); another participant fills one of
 * its own and hands it to the liquid's projection (dr_liquid_project), which adds it to the colliders'.
 *   open[a][f]      fraction of the face open to the liquid, in [0, 1]: 1 − the solids' share of its
 *                   area (the variational weight; an open fraction rather than the solid share, so the
 *                   colliders' weights are stored exactly as the projection uses them)
 *   velocity[a][f]  component a of the solids' velocity over the blocked part of the face, m/s (read
 *                   only where open < 1, and on faces no liquid reaches)
 *   impulse[a][f]   momentum added to the liquid through the face along e_a, N·s (kg·m/s; not per area):
 *                   the liquid turns it into the velocity increment J/m_f with its own face mass m_f.
 *                   May be NULL for none (the colliders' instance has none).
 *   drag[a][f]      implicit drag mass β_f, kg (≥ 0; NULL for none): a porous solid on the face pulls the
 *                   liquid towards velocity[a][f] within the projection, m_f u_f = m_f u*_f + J_f
 *                   + β_f (velocity_f − u_f) − (pressure impulse), so the face's velocity is
 *                   (m_f u*_f + J_f + β_f velocity_f)/(m_f + β_f) and its pressure coefficient is scaled by
 *                   m_f/(m_f + β_f) (a porous face). The momentum it gives the liquid, β_f (velocity_f − u_f)
 *                   with the projected u_f, is not part of the impulse sum (the liquid reports it apart).
 *   solid_mass[a][f] kg (≥ 0; NULL for none; the liquid reads it, the air ignores it): the blocked share
 *                   σ_f = 1 − open of the face is a solid that moves with the pressure, a point mass m^s_f
 *                   along e_a at velocity[a][f] before the projection (a deformable solid lumped onto the faces
 *                   it covers). 0 keeps the face's solid velocity prescribed, as without the array.
 * A participant writing into one owns its arrays; nothing here is thread-safe against a concurrent writer. */
typedef struct DrFaceCoupling {
    long nfaces[3];
    double *open[3];
    double *velocity[3];
    double *impulse[3];
    double *drag[3];
    double *solid_mass[3];
} DrFaceCoupling;
/* Allocates the four arrays for grid g (solid_mass stays NULL: dr_face_coupling_add_solid_mass) and clears them
   (dr_face_coupling_clear). DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_face_coupling_create(const DrMacGrid *g, DrFaceCoupling **out, DrError *err);
void dr_face_coupling_destroy(DrFaceCoupling **fc);
/* Allocates solid_mass (zeroed) when it is NULL. DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_face_coupling_add_solid_mass(DrFaceCoupling *fc, DrError *err);
/* No solid: open 1, velocity 0, impulse 0, drag 0, solid mass 0 on every face. */
void dr_face_coupling_clear(DrFaceCoupling *fc);
/* One face of two disjoint solids' couplings together (the colliders' own and another participant's): the solid shares
   add, open = 1 − (1 − w_own) − (1 − w_extra) (at least 0), and the solid velocity is their share-weighted mean. A face
   the extra coupling leaves open (w_extra ≥ 1, or not a number) keeps the own values exactly. */
static inline void dr_face_mix(double w_own, double v_own, double w_extra, double v_extra, double *w_out, double *v_out)
{
    if (w_extra >= 1.0 || !(w_extra >= 0.0)) {
        *w_out = w_own;
        *v_out = v_own;
        return;
    }
    double so = 1.0 - w_own, se = 1.0 - w_extra, sum = so + se;
    *w_out = sum < 1.0 ? 1.0 - sum : 0.0;
    *v_out = (so * v_own + se * v_extra) / sum;
}
/* The z-slices per chunk of a parallel loop over the faces of component a: at least min_items faces a chunk. */
static inline long dr_mac_slice_grain(const DrMacGrid *g, int a, long min_items)
{
    long per = (long)g->fdim[a][0] * g->fdim[a][1];
    long grain = (min_items + per - 1) / per;
    return grain < 1 ? 1 : grain;
}

/* ---- kernels --------------------------------------------------------------------------------------- */

/* One axis of a quadratic B-spline stencil: nodes base, base+1, base+2 with weights w[] (sum 1) and
 * derivatives dw[] (per grid unit). `s` is the sample position in grid units relative to node 0.
 * The kernel reproduces linear functions exactly and Σ w (node − s)² = ¼ (so D = Δx²/4·I, APIC §5.9). */
typedef struct DrStencil3 { int base; double w[3]; double dw[3]; } DrStencil3;
static inline DrStencil3 dr_kernel_quadratic(double s)
{
    DrStencil3 st;
    double fb = floor(s - 0.5);
    st.base = (int)fb;
    double fx = s - fb; /* in [0.5, 1.5) */
    double a = 1.5 - fx, b = fx - 1.0, c = fx - 0.5;
    st.w[0] = 0.5 * a * a;
    st.w[1] = 0.75 - b * b;
    st.w[2] = 0.5 * c * c;
    st.dw[0] = -a;
    st.dw[1] = -2.0 * b;
    st.dw[2] = c;
    return st;
}
/* One axis of a linear (tent) stencil: nodes base, base+1 with weights w[0], w[1]. */
typedef struct DrStencil2 { int base; double w[2]; } DrStencil2;
static inline DrStencil2 dr_kernel_linear(double s)
{
    DrStencil2 st;
    double fb = floor(s);
    st.base = (int)fb;
    double f = s - fb;
    st.w[0] = 1.0 - f;
    st.w[1] = f;
    return st;
}

/* Trilinear interpolation of face component a at world position x (clamped to the face lattice). */
double dr_mac_sample_face(const DrMacGrid *g, int a, DrVec3 x);

/* ---- colliders ----------------------------------------------------------------------------------- */

typedef struct DrColliderDesc {
    const float *phi; int nx, ny, nz; DrVec3 origin; double dx; /* dense SDF in the collider's rest frame,
                                              negative inside, node (i,j,k) at origin + dx*(i,j,k), x fastest;
                                              copied; nx, ny, nz >= 2 */
    double friction;   /* Coulomb coefficient, >= 0 */
    bool no_slip;      /* no-slip: the liquid takes the collider's velocity at contact; slip: only the normal */
    double thickness;  /* m, added to the surface (phi - thickness) */
    int nkeys; const double *keys; /* rows of 7: [time_s, tx, ty, tz, rx, ry, rz (radians, XYZ Euler as
                                      dr_m3_from_euler_xyz)], strictly increasing time; 0 rows = static
                                      identity; linear interpolation between keys, constant outside; copied */
} DrColliderDesc;
typedef struct DrCollider DrCollider;
/* DR_ERR_INPUT (naming the field) for a missing/too small SDF, non-positive dx, negative friction,
 * non-finite values or keys not strictly increasing in time; DR_ERR_NOMEM. */
DR_NODISCARD DrStatus dr_collider_create(const DrColliderDesc *desc, DrCollider **out, DrError *err);
/* Replaces the motion keys (checked and copied as dr_collider_create's; the SDF stays), for a collider whose motion
 * is known one step at a time. The collider gets a new dr_collider_id, as a new collider would. */
DR_NODISCARD DrStatus dr_collider_set_keys(DrCollider *c, const double *keys, int nkeys, DrError *err);
void dr_collider_destroy(DrCollider **c);
DrXform dr_collider_pose(const DrCollider *c, double t); /* rest frame -> world at time t */
/* Signed distance (world, minus thickness) at x and time t; outside the SDF box it is the distance to the
   box plus the boundary value (positive = outside). Trilinear inside the box. grad may be NULL; grad is
   the world-space unit gradient (central differences of half an SDF cell, rotated to world). */
double dr_collider_phi(const DrCollider *c, double t, DrVec3 x, DrVec3 *grad);
/* Rigid velocity of the collider point at x (m/s): zero outside the key range (the pose is constant
   there); inside a key interval the derivative of the interpolated pose. */
DrVec3 dr_collider_velocity(const DrCollider *c, double t, DrVec3 x);
double dr_collider_friction(const DrCollider *c);
bool dr_collider_no_slip(const DrCollider *c);
/* True when the collider never moves (at most one key): its pose and SDF are the same at every time. */
bool dr_collider_static(const DrCollider *c);
/* A number no other collider created by this process has had (thread-safe), so that something computed
   from a collider can be recognised as its own even when a later collider reuses its memory. */
uint64_t dr_collider_id(const DrCollider *c);

/* Rigid motion from key rows as DrColliderDesc.keys describe them (also the scalp motion of hair): the pose at
   time t (identity without keys; linear between keys, constant outside). */
DrXform dr_motion_pose(const double *keys, int nkeys, double t);

/* Per-substep form: the pose and rigid motion evaluated once at time t, then queried many times. */
typedef struct DrColliderFrame {
    const DrCollider *c;
    DrXform pose;     /* rest -> world */
    DrVec3 lin_vel;   /* velocity of the world origin's image: v(x) = lin_vel + omega × (x - pose.t) */
    DrVec3 omega;     /* world angular velocity, rad/s */
} DrColliderFrame;
DrColliderFrame dr_collider_frame(const DrCollider *c, double t);
double dr_collider_frame_phi(const DrColliderFrame *f, DrVec3 x, DrVec3 *grad);
DrVec3 dr_collider_frame_velocity(const DrColliderFrame *f, DrVec3 x);
/* World-space axis-aligned bounds of the collider's SDF box at the frame's pose. */
void dr_collider_frame_bounds(const DrColliderFrame *f, DrVec3 *lo, DrVec3 *hi);

/* Fraction of the axis-aligned square face (corners c00, c10, c11, c01 in order around it) that lies
   where phi >= 0 (outside solids), from the four corner values: the face is split into four triangles
   around its centre (centre value = mean of corners), each clipped linearly. In [0, 1]. */
double dr_face_fraction_outside(double p00, double p10, double p11, double p01);

#endif
