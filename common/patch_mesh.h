/* patch_mesh.h — the scene's surfaces cut into patches (radiosity's mesh).
 *
 * Chapter 3 solves for one radiance per patch; this is where the patches
 * come from and how the image finds them again.  Nothing here is the
 * lecture: it is the bookkeeping around it (what Chen's `room.c` and
 * `draw.c` are to his `rad.c`, Graphics Gems II).
 *
 *   - meshing: each quad of the scene becomes a grid of cells (the bilinear
 *     map of the quad cut into u, v squares), each triangle m^2 similar
 *     triangles, every cell at most about patch_size across; the spheres the
 *     caller asks for cut along meridians and parallels (flat facets whose
 *     points are lifted onto the sphere), the others not meshed;
 *   - refinement: a leaf cell splits into four at its edge midpoints (an
 *     edge hash shares each midpoint with the neighbour across the edge);
 *   - patches: the leaves, numbered, with their geometry and quadrature
 *     points (M^2 sub-triangle centroids per triangle of the patch);
 *   - lookup: the leaf cell under a hit point (inverse bilinear map by
 *     Newton's method, then down the refinement tree), and smooth shading:
 *     per-vertex radiance interpolated over the cell, with the vertices that
 *     lie inside a neighbour's edge (T-vertices) anchored to that edge so the
 *     shading has no step there.
 */
#ifndef COMMON_PATCH_MESH_H
#define COMMON_PATCH_MESH_H

#include <stdbool.h>
#include <stdint.h>

#include "scene.h"
#include "vec.h"

/* A cell of the mesh.  Cells form a forest: the top-level cells are a
 * regular grid on each surface; patch_mesh_split() gives a cell four
 * children.  The leaves are the patches. */
typedef struct {
    int vertex[4];    /* indices into the vertex array, counter-clockwise seen from the front */
    int vertex_count; /* 4 (quad cell) or 3 (triangle cell) */
    int surface;
    int first_child; /* the four children are first_child .. first_child + 3; -1 for a leaf */
    int patch;       /* index of the leaf among the patches; -1 when split */
} mesh_cell;

/* A patch: a leaf cell with its geometry. */
typedef struct {
    int cell;
    int surface;
    vec3 corner[4];
    int corner_count;
    vec3 normal, centroid;
    double area;
    double radius;                /* largest distance from the centroid to a corner */
    vec3 albedo, emission;        /* rho_i and Le_i: zero here, the caller's model of the material */
    double unburied;              /* the fraction of it outside every solid: 1 here, the caller's to set */
    int first_point, point_count; /* its quadrature points in points[] and weights[] */
} patch;

typedef struct patch_mesh {
    vec3 *vertices;
    int vertex_count;
    mesh_cell *cells;
    int cell_count;
    patch *patches; /* the leaves, after patch_mesh_collect() */
    int patch_count;
    vec3 *points;    /* quadrature points of all patches */
    double *weights; /* their weights (fractions of the patch area, summing to 1 per patch) */
    int point_count;
    vec3 *vertex_radiance; /* after patch_mesh_vertex_radiance() */

    /* bookkeeping */
    int vertex_capacity, cell_capacity, point_capacity, weight_capacity;
    struct quad_grid *quad_grids;         /* per surface (quads only) */
    struct triangle_grid *triangle_grids; /* per scene triangle (triangles and meshes) */
    int *triangle_slots;
    int triangle_slot_count;
    struct edge_entry *midpoints; /* edge -> midpoint vertex, for splitting cells */
    int midpoint_capacity, midpoint_count;
} patch_mesh;

/* About how many top-level cells patch_mesh_build() would make (to refuse
 * a tiny patch size before running out of memory). */
double patch_mesh_estimate(const scene *s, double patch_size, const bool *mesh_spheres);

/* The top-level cells of every quad and triangle surface, and of the
 * spheres i with mesh_spheres[i] (NULL: none; at least 8 x 4 cells each; the
 * vertices that splitting adds are put on the sphere, so refined cells
 * follow it).
 * All functions returning int give 0, or -1 when out of memory. */
int patch_mesh_build(patch_mesh *m, const scene *s, double patch_size, const bool *mesh_spheres);

/* Split a leaf cell into four (the children share the edge midpoints with
 * the neighbours).  Returns the index of its first child, or -1.  The cells
 * array may move: hold indices, not pointers, across calls. */
int patch_mesh_split(patch_mesh *m, int cell);

/* A function known at a cell's corners (parent: vertex_count values in the
 * order of its vertices), interpolated (linearly along the edges, the mean of
 * the corners at a quad's centre) at the corners of its child number `child`
 * as patch_mesh_split makes them, into out. */
void patch_mesh_child_values(int vertex_count, const vec3 *parent, int child, vec3 *out);

/* A point of one of the mesh's cells put on its surface: itself on a flat
 * surface, lifted along the radius onto a sphere. */
vec3 patch_mesh_on_surface(const patch_mesh *m, int surface, vec3 p);

/* Is a corner of p in front of the plane (origin, n)?  epsilon: rounding. */
bool patch_in_front(const patch *p, vec3 origin, vec3 n, double epsilon);

/* Can one-sided patches a and b exchange light: is each in front of the
 * other's centroid plane (patch_in_front both ways)? */
bool patches_facing(const patch *a, const patch *b, double epsilon);

/* The form factor's kernel (R10) between x (normal nx) and y (normal ny)
 * without its 1/pi: cos cos / r^2, 0 where either faces away.  How much
 * light a visibility ray x -> y carries, to weigh it by. */
double form_factor_kernel(vec3 x, vec3 nx, vec3 y, vec3 ny);

/* A cell's geometry as a patch (corners, normal, area, centroid, radius;
 * no quadrature points): on a sphere the centroid is lifted onto it. */
void patch_mesh_cell_geometry(const patch_mesh *m, int cell, patch *p);

/* Number the leaves as patches and fill in their geometry and their
 * quadrature points (M x M sub-triangles per triangle of the patch). */
int patch_mesh_collect(patch_mesh *m, int quadrature);

/* Adaptive refinement: split the patches where the solution is poorly
 * represented, where a patch's radiance differs from the mean of its
 * corners' smooth-shading values (luminance) by more than `threshold` times
 * the mean reflected radiance (radiance - emission, area-weighted) of the
 * scene.  A smooth gradient (the 1/r^2 falloff) leaves that difference
 * small, a jump (a shadow edge, light leaking into a corner) does not.
 * Returns the number of patches split, or -1; call patch_mesh_collect()
 * afterwards. */
int patch_mesh_refine(patch_mesh *m, const vec3 *radiance, double threshold);

/* Per-vertex radiance for smooth shading: the area-weighted mean of the
 * patches around each vertex, on the same surface only. */
int patch_mesh_vertex_radiance(patch_mesh *m, const vec3 *radiance);

/* The same, then every T-vertex (the midpoint of an edge that a leaf still
 * has whole, split only on the other side) set to the mean of that edge's
 * ends: the leaf interpolates linearly along the edge, so do the smaller
 * cells across it, and the smooth shading is continuous (no crack). */
int patch_mesh_smooth_radiance(patch_mesh *m, const vec3 *radiance);

/* The leaf cell under a hit on a meshed surface. */
int patch_mesh_locate(const patch_mesh *m, const scene *s, const hit *h);

/* Smooth shading: the vertex radiance interpolated over a cell at p
 * (bilinear on quads, barycentric on triangles). */
vec3 patch_mesh_interpolate(const patch_mesh *m, int cell, vec3 normal, vec3 p);

/* What a camera ray sees: the background when it escapes, black on an
 * unmeshed sphere, on the back of a surface (*back set) or before a solution, else
 * radiance[patch] under the hit, or with smooth the interpolated vertex
 * radiance. */
vec3 patch_mesh_seen(const patch_mesh *m, const scene *s, ray r, const vec3 *radiance, bool smooth, bool *back);

/* The size of a per-patch radiance vector x as power: Sum_i A_i (|r| + |g| + |b|). */
double patch_mesh_power(const patch_mesh *m, const vec3 *x);

/* For display during progressive radiosity (Cohen et al. 1988): L_i +=
 * unshot_i + rho_i ambient, the ambient term being the area-weighted mean
 * unshot radiance reflected 1/(1 - rho_avg) times (rho_avg the area-weighted
 * mean albedo). */
void patch_mesh_add_ambient(const patch_mesh *m, const vec3 *unshot, vec3 *L);

/* The irradiance each patch receives from the scene's point lights,
 * E = I cos(theta) / r^2 (R1) at its quadrature points (a shadow ray each),
 * averaged over the patch, into irradiance[patch].  Returns the rays cast. */
uint64_t patch_mesh_point_lights(const patch_mesh *m, const scene *s, vec3 *irradiance);

/* Irradiance at x (unit normal n) from the patches' radiance, as a probe
 * measures it: E = Sum_j L_j pi F_dA->j, the point-to-polygon form factor
 * given by the caller, visibility by rays to j's quadrature points; plus,
 * with point_lights, the scene's point lights' I cos / r^2 (R1). */
typedef double (*point_to_polygon_fn)(vec3 x, vec3 n, const vec3 *polygon, int count);
vec3 patch_mesh_irradiance(const patch_mesh *m, const scene *s, const vec3 *radiance, vec3 x, vec3 n, bool point_lights,
                           point_to_polygon_fn point_to_polygon);

void patch_mesh_free(patch_mesh *m);

#endif
