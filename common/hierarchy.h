/* hierarchy.h — the bookkeeping of chapter 03c's hierarchical radiosity:
 * the elements' arrays, the refiner's link list, the pairs of a refinement
 * round, the links grouped by receiver, points on an element, the unburied
 * fraction of an element (its area outside every solid), the stats
 * (hierarchy.c); and what makes the links accurate and cheap enough: their
 * form factors and shapes, the shadow-edge test, the second pass's measures,
 * the limits (hierarchy_links.c).  Nothing here is the lecture:
 * chapters/03c_hierarchical.c is, and calls these. */
#ifndef COMMON_HIERARCHY_H
#define COMMON_HIERARCHY_H

#include "patch_mesh.h"
#include "radiosity_setup.h"

enum { COVERED_PART = 1, COVERED_ALL = 2 };

typedef struct {
    int element_count, root_count, capacity;
    patch *element;         /* per cell of the mesh: its geometry, albedo and emission */
    unsigned char *level;   /* depth below its root */
    int *parent;            /* -1 for a root */
    float *unburied;        /* the fraction of its area outside every solid */
    unsigned char *covered; /* 0, COVERED_PART or COVERED_ALL: something close above (hierarchy_track_new_cells) */
    int unburied_count;     /* elements whose unburied fraction is known (hierarchy_measure_unburied) */
    vec3 *gathered;         /* per element, at each of its 4 (or 3) corners: rho Sum_links F L (one Neumann term) */
    vec3 *term;             /* per element: the term, pulled up from the leaves */
    long link_count;
    long *link_start; /* links of receiver e: link_start[e] .. link_start[e + 1] - 1 */
    int *link_source;
    float *link_F;
    float *link_shape; /* per link, at the receiver's 4 (or 3) corners: F there over F (hierarchy_shape_links) */
    long *shape_start; /* receiver e's first link in link_shape; -1 for a leaf (its links' shapes are constant) */
} hierarchy;

/* Elements: at most 4 M (as the uniform mesh), and --levels is refused when
 * its worst case (every root split to the last level) passes 16 M; links:
 * 40 M (320 MiB). */
enum { ELEMENT_LIMIT = 4000000, WORST_CASE_LIMIT = 16000000, LINK_LIMIT = 40000000 };

/* What a refinement pass works with and makes. */
typedef struct {
    hierarchy *h;
    patch_mesh *m;
    const scene *s;
    point_to_polygon_fn point_to_polygon;
    double eps, eps_spread;
    int levels;
    double smallest;        /* no element is split into children smaller than this across */
    int *receiver, *source; /* the links, in the order the oracle makes them */
    float *known_F;         /* a form factor the first pass computed for the same pair, or -1 */
    long count, capacity;
    int failed; /* 1: out of memory, 2: over LINK_LIMIT, 3: over ELEMENT_LIMIT */
    /* The second pass (--eps-spread) knows the first pass's solution: */
    const vec3 *radiance; /* per element: B, the area-weighted mean over its leaves */
    const vec3 *spread;   /* per element: the largest minus the smallest B of its leaves */
    int known;            /* the elements 0 .. known - 1 have them (newer ones do not) */
    double mean_radiance; /* of the scene's reflecting leaves, area-weighted */
} refiner;

/* A pair the refinement has still to judge: p receives from q.  F: the
 * first pass's form factor for this link (the second pass starts from the
 * first's links), or -1. */
typedef struct {
    int p, q;
    float F;
} pair;

/* Geometry, albedo and emission of the cells the mesh gained since the last call. */
int hierarchy_track_new_cells(hierarchy *h, const patch_mesh *m, const scene *s);

/* The children of element e, splitting it first if it is a leaf; -1 when
 * out of memory (r->failed 3: over ELEMENT_LIMIT). */
int refiner_children(refiner *r, int e);

/* Append link p <- q (known_F: its form factor, or -1); r->failed 2 over LINK_LIMIT. */
void refiner_add_link(refiner *r, int p, int q, float known_F);

/* Append to next the four pairs of the children of the split element:
 * (p, child of q) when split_source, else (child of p, q).  -1 when out of memory. */
int pairs_push_children(pair **next, long *count, long *capacity, pair t, bool split_source, int first);

/* h->link_start/source/F from r's links, grouped by receiver (a counting
 * sort, stable); F is r's known_F (-1 where it is to be computed). */
int hierarchy_group_links(hierarchy *h, const refiner *r);

/* The mean of element e's corners (in its plane; the centroid of a curved element is on the surface). */
vec3 element_corner_mean(const patch *e);

/* The point a fraction t of the way from `mean` (element_corner_mean) to corner k of e, on the surface. */
vec3 element_toward_corner(const patch_mesh *m, const patch *e, vec3 mean, int k, double t);

/* A point of q in front of the plane (origin, n), epsilon off it: the mean
 * of the corners of q clipped to that half-space (q's centroid if none).  A
 * ray to q's centroid below a box's top would pass through the box. */
vec3 element_point_in_front(const patch *q, vec3 origin, vec3 n, double epsilon);

/* Points for visibility rays: the corners moved half-way to the centroid, on the surface. */
int element_sample_points(const patch_mesh *m, const patch *e, vec3 *out);

/* Points for estimating how much of a pair is visible: one in each corner's
 * kite of e (the corner, its two edges' midpoints, the centre), at a place
 * drawn from `salt`, on the surface.  The kites' centres
 * (element_sample_points) miss a shadow along e's edge every time, and an
 * edge is where a box standing on a floor or a wall's corner shadows. */
int element_stratified_points(const patch_mesh *m, const patch *e, uint64_t salt, vec3 *out);

/* Is x (on a surface of normal n) inside a solid: does a ray along the
 * normal meet the back of a surface first (the floor under a box meets the
 * underside of the box's top)? */
bool element_point_buried(const scene *s, vec3 x, vec3 n);

/* h->unburied of every element (a leaf's measured once, across calls): the fraction of its area outside every
 * solid.  A box standing on the floor buries the floor under it; an element
 * across the box's edge gathers light on one part only, and push_pull
 * gives that light to the part that is not buried.  -1 when out of memory. */
int hierarchy_measure_unburied(hierarchy *h, const patch_mesh *m, const scene *s);

/* Link k of receiver e at e's corner j: its shape (h->link_shape), or before
 * the shapes are known (the first pass) constant over e's exposed part. */
double hierarchy_link_shape(const hierarchy *h, int e, long k, int j);

/* The stats of a built hierarchy: elements, links, levels, memory, and each
 * leaf's row sum (the form factors of its links and its ancestors', 1 in a
 * closed scene, as the matrix solvers' row_sum_min/max). */
void hierarchy_report(const hierarchy *h, const patch_mesh *m, radiosity_stats *stats);

/* ---- the links (hierarchy_links.c) ---- */

/* Does a shadow edge cross the pair p <- q, and across which element?
 * Across the receiver p when its corners (near them) see different numbers
 * of q's four stratified points; else across the source q when, of the rays
 * from q's corners to p's centroid and between the centroids, some are
 * blocked and some not (at most 21 rays). */
enum shadow_side { NO_SHADOW_EDGE, SHADOW_ACROSS_RECEIVER, SHADOW_ACROSS_SOURCE };
enum shadow_side shadow_edge(const refiner *r, int p, int q);

/* Is the pair worth a shadow test?  First pass: where F >= eps / 8.  Second
 * pass: where F times q's radiance over the scene's mean (capped) >= --eps. */
bool shadow_test_worthwhile(const refiner *r, int p, int q, const patch *eq, double f);

/* Second pass: how many times brighter than the scene's mean q is, at least 1
 * (capped; 1 in the first pass).  A link's error grows with F B (Hanrahan et
 * al.'s BF refinement). */
double source_brightness(const refiner *r, int q);

/* Second pass: a link takes its source's radiance as constant; where q's
 * leaves differ by spread_q, p's gather may be off by rho_p F_pq spread_q:
 * that as a fraction of p's radiance (worst channel), with the B and spread
 * of p's and q's nearest first-pass ancestors.  0 before the first pass. */
double spread_bound(const refiner *r, int p, int q, const patch *ep, double fpq);

/* h->link_start/source/F from r's links grouped by receiver, each F (R10)
 * computed over the receiver's unburied part (Lambert's formula at points of
 * p, a ray from each to q) unless the first pass knows it.  -1: out of memory. */
int hierarchy_store_links(hierarchy *h, refiner *r, const radiosity_options *o, radiosity_stats *stats);

/* Each link's shape across its receiver: its point form factor times
 * visibility at the receiver's corners over their mean (linear across it;
 * constant where the receiver is partly buried).  -1: out of memory. */
int hierarchy_shape_links(hierarchy *h, const patch_mesh *m, const scene *s, point_to_polygon_fn F);

/* *levels: --levels, or by default as deep as the element limit allows for
 * the mesh's roots.  2 with a message when the worst case passes the limit. */
int hierarchy_levels(const patch_mesh *m, const radiosity_options *o, int *levels, char *err, size_t err_size);

/* Every ordered pair of roots (the mesh's cells, tracked): the first round's
 * todo (malloc'ed), or NULL when out of memory. */
pair *hierarchy_root_pairs(hierarchy *h, const patch_mesh *m, const scene *s, long *count);

/* h's links as pairs with their form factors (malloc'ed; the second pass
 * judges them again), the link arrays freed; NULL when out of memory. */
pair *hierarchy_links_as_pairs(hierarchy *h, long *count);

/* spread[e]: the largest minus the smallest B of e's unburied leaves
 * (lowest: scratch of element_count). */
void hierarchy_leaf_spread(const hierarchy *h, const patch_mesh *m, const vec3 *B, vec3 *lowest, vec3 *spread);

/* The area-weighted mean of B - Le over the unburied leaves. */
double hierarchy_mean_reflected(const hierarchy *h, const patch_mesh *m, const vec3 *B);

void refiner_free(refiner *r);

/* After refinement: the message for r->failed (the element or link limit,
 * out of memory), the links' shapes, the solve's arrays, the stats, and the
 * leaves collected as the mesh's patches with their unburied fractions.
 * Returns 0, or 2 with a message. */
int hierarchy_complete(const refiner *r, const radiosity_options *o, radiosity_stats *stats, char *err,
                       size_t err_size);

void hierarchy_free(hierarchy *h);

#endif
