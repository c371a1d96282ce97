/* 03_radiosity_hierarchical.h — hierarchical radiosity (Hanrahan, Salesin &
 * Aupperle 1991) for chapter 3's --solver hierarchical.
 *
 * Part of lecture 3, kept in its own file because the chapter is at its
 * length limit: read it after solve_jacobi() in chapters/03_radiosity.c
 * (the bookkeeping is in 03_radiosity_hierarchical_store.[ch]).  Each input
 * surface is the root of a quadtree of elements (the cells of the patch
 * mesh, split in four by patch_mesh_split).  Instead of a form factor for
 * every pair of patches, a link joins two elements at the level where
 * their form factor is small: the refinement oracle splits the larger of
 * the pair (seen from the other) until both F estimates are below --eps, no
 * shadow edge crosses the pair, or --levels is reached.  A second pass
 * (--eps-spread) solves on those links and refines again where the
 * solution says a link is too coarse: a bright source (F B, Hanrahan et
 * al.'s BF refinement), a source whose radiance varies, a shadow of the
 * light.  Memory is O(elements + links).  The solve is the Neumann series
 * (R6) term by term as in Jacobi: gather (each element receives
 * rho Sum_links F L over its links, at its corners: each link's F shaped
 * linearly across the receiver) then push-pull (what an element gathers is
 * pushed down to its leaves, interpolated, and each element's radiance is
 * the mean of its children's, pulled up), over the part of each element
 * that is not buried inside a solid (the floor under a box).  The leaves
 * are the patches that the image, the probes and the PLY use. */
#ifndef CHAPTERS_RADIOSITY_HIERARCHICAL_H
#define CHAPTERS_RADIOSITY_HIERARCHICAL_H

#include "03_radiosity_support.h"
#include "patch_mesh.h"

enum { COVERED_PART = 1, COVERED_ALL = 2 };

typedef struct {
    int element_count, root_count, capacity;
    patch *element;         /* per cell of the mesh: its geometry, albedo and emission */
    unsigned char *level;   /* depth below its root */
    int *parent;            /* -1 for a root */
    float *exposure;        /* the fraction of its area outside every solid (not buried) */
    unsigned char *covered; /* 0, COVERED_PART or COVERED_ALL: something close above (hierarchy_track_new_cells) */
    int exposure_count;     /* elements whose exposure is known (hierarchy_exposure) */
    vec3 *gathered;         /* per element, at each of its 4 (or 3) corners: rho Sum_links F L (one Neumann term) */
    vec3 *term;             /* per element: the term, pulled up from the leaves */
    long link_count;
    long *link_start; /* links of receiver e: link_start[e] .. link_start[e + 1] - 1 */
    int *link_source;
    float *link_F;
    float *link_shape; /* per link, at the receiver's 4 (or 3) corners: F there over F (link_shapes) */
} hierarchy;

/* Refine the roots (the mesh's top-level cells, albedo and emission given
 * by radiosity_material) by the oracle, compute each link's form factor
 * (R10) with visibility, and collect the leaves as the mesh's patches.
 * Refuses, before allocating, a --levels that could exceed the chapter's
 * element limit.  Returns 0, or 2 with a message. */
int hierarchy_build(hierarchy *h, patch_mesh *m, const scene *s, const radiosity_options *o, radiosity_stats *r,
                    point_to_polygon_fn point_to_polygon, char *err, size_t err_size);

/* The Neumann terms first..last (R6) by gather and push-pull, summed into
 * L per patch (leaf); first_shot: the point lights' light reflected once
 * per patch (part of term 1).  Stops at --tol (the next term's power over
 * source_norm, as Jacobi) or --iterations.  0, or -1 when out of memory. */
int hierarchy_solve(hierarchy *h, const patch_mesh *m, const vec3 *first_shot, int first, int last,
                    const radiosity_options *o, radiosity_stats *r, double source_norm, vec3 *L);

void hierarchy_free(hierarchy *h);

#endif
