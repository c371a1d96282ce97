/* radiosity_setup.h — what chapter 3 (03_radiosity.c) and chapter 03c
 * (03c_hierarchical.c) need around their lectures: their options
 * (--patch-size, --solver, --eps ...), defaults and help text; the steps
 * that build and refine the patch mesh (patch_mesh.h) with the chapters'
 * limits, material model and warnings; the solve's statistics and the
 * radiosity members of the --stats JSON.  Nothing here is the lecture; the
 * driver's common options are in render.h. */
#ifndef COMMON_RADIOSITY_SETUP_H
#define COMMON_RADIOSITY_SETUP_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "options.h"
#include "patch_mesh.h"
#include "render.h"
#include "scene.h"

/* The order of --solver's choices. */
typedef enum { SOLVER_JACOBI, SOLVER_GAUSS_SEIDEL, SOLVER_SHOOTING, SOLVER_DIRECT } solver_kind;
extern const char *const solver_names[4]; /* "jacobi", "gauss-seidel", "shooting", "direct" */

typedef struct {
    const char *program; /* "03_radiosity" or "03c_hierarchical": the messages' prefix */
    bool hierarchical;   /* chapter 03c: the mesh's cells are the roots of quadtrees */
    double patch_size;
    bool adaptive;
    int adaptive_levels;
    double adaptive_threshold;
    int solver; /* solver_kind (chapter 3) */
    double tolerance;
    int max_iterations;
    int max_patches;
    int quadrature;          /* M: each patch triangle is sampled at the centroids of M x M sub-triangles */
    int smooth;              /* --shading flat|smooth: 1 interpolates per-vertex radiance */
    int enforce_reciprocity; /* --reciprocity check|enforce: 1 averages A_i F_ij and A_j F_ji */
    const char *formfactors_path;
    int patch_size_argv; /* where --patch-size was given, for error messages */
    double eps;          /* chapter 03c: link when both form-factor estimates are below eps */
    double eps_spread;   /* chapter 03c: second pass, a link's bound on its source's variation (0: off) */
    int levels;          /* chapter 03c: deepest split below a root */
    int eps_argv, levels_argv;
} radiosity_options;

/* What a solve reports. */
typedef struct {
    const char *solver_used;
    int refinements, iterations, shots;
    double residual; /* the last one recorded */
    double *history; /* every residual recorded */
    int history_count, history_capacity;
    bool converged, no_light;
    double formfactor_s, solve_s;
    uint64_t visibility_rays;
    bool have_matrix_checks;
    double reciprocity_error, row_sum_min, row_sum_max;
    long elements, links;  /* chapter 03c: quadtree cells (all levels), links */
    long first_pass_links; /* chapter 03c: links before the second pass (--eps-spread) */
    int levels;            /* the deepest level reached */
    double hierarchy_bytes;
} radiosity_stats;

/* The chapters' options, their ranges, defaults and help (options.h):
 * offsets into a radiosity_options.  Chapter 3's and chapter 03c's. */
extern const option RADIOSITY_OPTIONS[], HIERARCHICAL_OPTIONS[];

/* stats->residual = residual, and append it to the history. */
void record_residual(radiosity_stats *stats, double residual);

/* The chapter's members of the stats JSON, ending with each surface's mean
 * radiance (json_surface_radiance, mesh_io.h). */
void write_radiosity_stats(FILE *json, const radiosity_options *o, const radiosity_stats *r, const scene *s,
                           const patch_mesh *m, const vec3 *radiance, bool have_matrix);

/* Mesh the scene into patches of about --patch-size (refusing over
 * 4,000,000; diffuse spheres meshed by latitude and longitude, mirror and
 * glass spheres not, said once on stderr; the default size, 0, becomes a
 * tenth of the scene's largest extent) and collect them
 * (radiosity_collect_patches).  chapter 03c: the roots, one cell
 * per surface (per triangle, 12 x 6 per sphere) unless --patch-size is given.  Returns 0, or 2 with a message. */
int radiosity_mesh_scene(patch_mesh *m, const scene *s, radiosity_options *o, char *err, size_t err_size);

/* A surface's albedo rho and emission Le as radiosity models its material:
 * diffuse only, so mirrors and glass become diffuse with their colour as
 * albedo, Phong surfaces keep kd. */
void radiosity_material(const scene *s, int surface, vec3 *albedo, vec3 *emission);

/* Number the patches (patch_mesh_collect) and give each the albedo rho_i
 * and emission Le_i of its material as radiosity models it: diffuse only,
 * so mirrors and glass become diffuse with their colour as albedo, Phong
 * surfaces keep kd (each said once on stderr).  Returns 0, or 2. */
int radiosity_collect_patches(patch_mesh *m, const scene *s, const radiosity_options *o, char *err, size_t err_size);

/* --adaptive: unless the rounds are used up (or nothing emits), split the
 * patches where the radiance jumps (patch_mesh_refine) and collect them
 * again.  Returns how many were split (0: done), or -1 with a message. */
int radiosity_refine(patch_mesh *m, const scene *s, const radiosity_options *o, radiosity_stats *r,
                     const vec3 *radiance, bool quiet, char *err, size_t err_size);

/* A warning naming the enclosed surfaces (a few fixed rays from each of
 * their patches all hit the scene) whose area-weighted form-factor row sum
 * falls short of 1 by more than would bias a furnace's L = Le / (1 - rho)
 * by 1 % at the scene's largest albedo rho: rho (1 - S) / (1 - rho) > 1 %. */
void radiosity_warn_row_sums(const float *F, const patch_mesh *m, const scene *s, const radiosity_options *o);

/* Refuse a matrix solver (all but shooting) over --max-patches before
 * trying.  Returns 0, or 2 with the message. */
int radiosity_check_matrix_size(const radiosity_options *o, int patches, char *err, size_t err_size);

/* After the solve, on stderr: a warning when nothing emits or the solver
 * stopped at its iteration cap, and (unless quiet) a one-line summary. */
void radiosity_report(const radiosity_options *o, const radiosity_stats *r, int patches, bool quiet);

/* What the driver's callbacks read of a solved radiosity chapter (chapters
 * 3 and 03c): the first member of the chapter's state, set by the last step
 * of its prepare(), so that the functions below can be its .radiance,
 * .probe, .write_output and .write_stats (render.h). */
typedef struct {
    const radiosity_options *opt;
    const radiosity_stats *stats;
    const scene *scene;
    const patch_mesh *mesh;
    const vec3 *radiance; /* per patch: L, the --bounces window */
    double exposure;      /* --exposure: the PLY's colours */
    bool point_lights;    /* term 0 kept: a probe adds the point lights' direct light */
    bool have_matrix;     /* the n x n form factors were stored (stats: matrix_bytes) */
    point_to_polygon_fn point_to_polygon;
} radiosity_view;

/* *v for a solved chapter: its options, stats, scene, mesh and L per patch;
 * --exposure and the --bounces window from o; have_matrix: the n x n form
 * factors were stored. */
void radiosity_view_set(radiosity_view *v, const radiosity_options *opt, const radiosity_stats *stats, const scene *s,
                        const patch_mesh *m, const vec3 *radiance, const render_options *o, bool have_matrix,
                        point_to_polygon_fn point_to_polygon);

/* What the camera sees: the radiance of the patch under the hit
 * (patch_mesh_seen), with a warning once when it is a patch's back. */
vec3 radiosity_view_radiance(const void *view, const scene *s, ray r, rng *g, render_counters *counters);

/* A probe: E = Sum_j L_j pi F_dA->j by Lambert's formula, plus the point
 * lights when term 0 is kept (patch_mesh_irradiance); deterministic, its
 * error is the discretisation's. */
probe_result radiosity_view_probe(const void *view, const scene *s, const probe *pr, uint64_t seed,
                                  render_counters *counters);

/* --out MESH.ply: the patches with their radiance (write_patch_ply). */
int radiosity_view_write_output(const void *view, const scene *s, const char *path, char *err, size_t err_size);

/* The radiosity members of the --stats JSON (write_radiosity_stats). */
void radiosity_view_write_stats(const void *view, FILE *json);

/* A radiosity chapter's view, in its struct chapter: the four functions above,
 * the same for chapters 3 and 03c (a solved mesh is shown the same way). */
#define RADIOSITY_VIEW_FUNCTIONS                                                                                       \
    .radiance = radiosity_view_radiance, .probe = radiosity_view_probe, .write_stats = radiosity_view_write_stats,     \
    .write_output = radiosity_view_write_output

#endif
