/* Private to src/bem: quadrature points on a triangle for one collocation point. */
#ifndef DR_BEM_INTERNAL_H
#define DR_BEM_INTERNAL_H

#include "bem/bem.h"

/* One quadrature point: position y, weight (the point's share of the triangle's area, m², Jacobian
 * included) and the three linear shape functions of the triangle's vertices at y. */
typedef struct BemQuadPoint {
    double y[3];
    double w;
    double phi[3];
} BemQuadPoint;

/* Largest number of points either rule below writes for the given settings. */
int bem_quad_capacity(int levels, int max_levels, int singular_order);

/* A triangle (a, b, c) that does not contain x: the 9-point degree-5 rule on each subtriangle after
 * `levels` 4-way subdivisions, and subtriangles whose centroid lies closer to x than near_factor times their
 * diameter subdivided further, down to max_levels. Returns the point count (≤ cap). */
int bem_quad_regular(const double a[3], const double b[3], const double c[3], const double x[3], int levels,
                     int max_levels, double near_factor, BemQuadPoint *out, int cap);

/* A triangle whose vertex a is the collocation point: polar (Duffy) coordinates about a, order × order
 * Gauss–Legendre points; the Jacobian 2·area·ρ cancels a 1/r singularity. phi is for (a, b, c). */
int bem_quad_singular(const double a[3], const double b[3], const double c[3], int order, BemQuadPoint *out,
                      int cap);

/* Gauss–Legendre nodes and weights on [0, 1], n ≤ 64. */
void bem_gauss_legendre01(int n, double *x, double *w);

/* The Laplace-domain matrices Ĥ(s), Ĝ(s) (ns × n × n) and the integrals of d̂*, q̂* (ns × n × 3, may be NULL)
 * for arbitrary Laplace variables, with the quadrature of dr_bem_matrices_build (validation and benchmarks). */
DR_NODISCARD DrStatus bem_laplace_matrices(const DrTriMesh *mesh, const DrBemDesc *d, int ns, const double complex *s,
                                           double complex *H, double complex *G, double complex *D,
                                           double complex *Q, DrError *err);

#endif
