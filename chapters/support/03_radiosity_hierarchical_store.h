/* 03_radiosity_hierarchical_store.h — the hierarchical solver's bookkeeping
 * (03_radiosity_hierarchical.c is the lecture): the elements' arrays, the
 * refiner's link list, the pairs of a refinement round, the links grouped by
 * receiver, points on an element, the exposure of an element to the scene,
 * the stats.  Private to chapter 3's hierarchical solver. */
#ifndef CHAPTERS_RADIOSITY_HIERARCHICAL_STORE_H
#define CHAPTERS_RADIOSITY_HIERARCHICAL_STORE_H

#include "03_radiosity_hierarchical.h"

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

/* Is x (on a surface of normal n) inside a solid: does a ray along the
 * normal meet the back of a surface first (the floor under a box meets the
 * underside of the box's top)? */
bool element_point_buried(const scene *s, vec3 x, vec3 n);

/* h->exposure of every element (a leaf's measured once, across calls): the fraction of its area outside every
 * solid.  A box standing on the floor buries the floor under it; an element
 * across the box's edge gathers light on one part only, and push_pull
 * gives that light to the part that is not buried.  -1 when out of memory. */
int hierarchy_exposure(hierarchy *h, const patch_mesh *m, const scene *s);

/* Link k of receiver e at e's corner j: its shape (h->link_shape), or before
 * the shapes are known (the first pass) constant over e's exposed part. */
double hierarchy_link_shape(const hierarchy *h, int e, long k, int j);

/* The stats of a built hierarchy: elements, links, levels, memory, and each
 * leaf's row sum (the form factors of its links and its ancestors', 1 in a
 * closed scene, as the matrix solvers' row_sum_min/max). */
void hierarchy_report(const hierarchy *h, const patch_mesh *m, radiosity_stats *stats);

#endif
