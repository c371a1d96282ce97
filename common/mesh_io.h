/* mesh_io.h — what radiosity writes about its patch mesh: the mesh as PLY
 * with per-vertex radiance, the surface-to-surface form-factor table (CSV),
 * checks of a form-factor matrix, and each surface's mean radiance for the
 * stats JSON.  Output, not the lecture; chapter 3 calls these. */
#ifndef COMMON_MESH_IO_H
#define COMMON_MESH_IO_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include "patch_mesh.h"
#include "scene.h"
#include "vec.h"

/* ASCII PLY of the patches with per-vertex radiance: float properties
 * radiance_r/g/b (linear) and uchar red/green/blue (tone-mapped sRGB at
 * `exposure` stops, what MeshLab and Blender display).  Flat shading writes
 * each patch with its own corners and radiance[patch], so its colour stays
 * flat; smooth shares the vertices and their m->vertex_radiance.  `program`
 * names the writer in the header comment.  Written through a temporary and
 * renamed.  Returns 1 when written, 0 when path does not end in ".ply" (not
 * this writer's format: nothing done), 2 with a message on error. */
int write_patch_ply(const char *path, const patch_mesh *m, const vec3 *radiance, bool smooth, double exposure,
                    const char *program, char *err, size_t err_size);

/* F_ij between patches i and j; counts the visibility rays it casts. */
typedef double (*form_factor_fn)(const void *context, int i, int j, uint64_t *rays);

/* Surface-to-surface form factors
 *   F(S -> T) = 1/A_S Sum_{i in S} Sum_{j in T} A_i F_ij
 * for every ordered pair of meshed surfaces, as CSV lines "from,to,F"
 * (all pairs F(i, j) in parallel).  Adds the rays cast to *rays.  Returns
 * 0 (nothing to do when path is NULL), or 2 with a message. */
int write_surface_form_factors(const char *path, const scene *s, const patch_mesh *m, form_factor_fn form_factor,
                               const void *context, uint64_t *rays, char *err, size_t err_size);

/* Checks of an n x n form-factor matrix (n = m->patch_count, F[i * n + j]):
 * the smallest and largest row sum (1 in a closed scene: F_ij is a fraction
 * of the light leaving i) and the reciprocity error
 * Sum_{i<j} |A_i F_ij - A_j F_ji| / Sum_{i<j} (A_i F_ij + A_j F_ji) / 2. */
void form_factor_checks(const float *F, const patch_mesh *m, double *reciprocity_error, double *row_sum_min,
                        double *row_sum_max);

/* The stats member "surfaces": each meshed surface's area and area-weighted
 * mean radiance (emission included), the key the path tracer reports too.
 * radiance may be NULL (an empty list). */
void json_surface_radiance(FILE *json, const scene *s, const patch_mesh *m, const vec3 *radiance);

#endif
