/* 03_radiosity.c — Lectures 3-5: the rendering equation as a linear system.
 *
 * For diffuse (Lambertian) surfaces the exitant radiance does not depend on
 * direction, and the rendering equation in its area form (R9) becomes an
 * equation for one number per point.  Split the surfaces into patches i,
 * assume the radiance L_i is constant on each, and (R9) becomes the
 * radiosity system of Lecture 5,
 *
 *   L_i = Le_i + rho_i * Sum_j F_ij L_j          i.e.  L = E + K L   (R4)
 *
 * with K = diag(rho) F and the form factors (R10)
 *
 *   F_ij = 1/A_i Int_{A_i} Int_{A_j} cos(theta) cos(theta') / (pi r^2) V dA' dA.
 *
 * We work in radiance units throughout: the scene gives emitted radiance,
 * and L_i is exitant radiance (the classical radiosity B_i = pi L_i; the
 * factor pi cancels on both sides, so the system is the same).
 *
 * The solvers make the operator view tangible:
 *   - Jacobi, L <- E + K L from L = 0: after k iterations L is the Neumann
 *     series (R6) cut after k terms, E + KE + ... + K^(k-1) E, and each
 *     iteration computes the next term, K^k E, which is exactly the residual;
 *   - Gauss-Seidel: the same update using the newest values as soon as known;
 *   - shooting (progressive refinement, Southwell): the residual is light
 *     not yet distributed ("unshot"); the patch with the most unshot power
 *     shoots it to every other patch.  Form factors are computed per shot,
 *     so no n x n matrix is stored;
 *   - direct: (I - K) L = E (R5) by Gaussian elimination, the reference.
 *
 * Sections: state and options · meshing · form factors (R10) · sources ·
 * the solvers (R5, R6) · adaptive refinement · the image · probes ·
 * outputs (PLY, form factors, stats) · main.
 *
 * Modelling choices (each said once on stderr where it matters):
 *   - patches are one-sided: they receive and send light on the side their
 *     normal points to (the file's vertex order); the back of a surface
 *     renders black;
 *   - spheres are not meshed: they still block light, but carry no
 *     radiance (black in the image);
 *   - mirrors and glass are diffuse with their colour as albedo; Phong
 *     surfaces keep only kd;
 *   - the background lights camera rays only; point lights light the patches
 *     by a first shot (I cos / r^2, R1) but are invisible to the camera.
 */
#include <float.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "render.h"
#include "sampling.h"

/* ---- state and options ------------------------------------------------------------ */

typedef enum { SOLVER_JACOBI, SOLVER_GAUSS_SEIDEL, SOLVER_SHOOTING, SOLVER_DIRECT } solver_kind;
static const char *const solver_names[] = {"jacobi", "gauss-seidel", "shooting", "direct"};

/* A cell of the mesh.  Cells form a forest: the top-level cells are a
 * regular grid on each surface; --adaptive splits a cell into four children.
 * The leaves are the patches, the unknowns of the linear system. */
typedef struct {
    int vertex[4];    /* indices into the vertex array, counter-clockwise seen from the front */
    int vertex_count; /* 4 (quad cell) or 3 (triangle cell) */
    int surface;
    int first_child;  /* the four children are first_child .. first_child + 3; -1 for a leaf */
    int patch;        /* index of the leaf among the patches; -1 when split */
} mesh_cell;

/* A patch: one unknown L_i of (R4). */
typedef struct {
    int cell;
    int surface;
    vec3 corner[4];
    int corner_count;
    vec3 normal, centroid;
    double area;
    double radius;          /* largest distance from the centroid to a corner */
    vec3 albedo, emission;  /* rho_i and Le_i */
    int first_point, point_count; /* quadrature points for the outer integral of (R10) */
} patch;

/* Point location on one surface: how the top-level grid of cells is laid out. */
typedef struct {
    int first_cell; /* first top-level cell */
    int nu, nv;     /* quads: nu x nv cells, cell (a, b) = first_cell + b * nu + a */
} quad_grid;
typedef struct {
    int first_slot; /* into triangle_slots: 2 m^2 entries, (a, b, up/down) -> cell or -1 */
    int m;          /* the triangle is cut into m^2 similar triangles */
} triangle_grid;

typedef struct {
    /* options */
    double patch_size;
    bool adaptive;
    int adaptive_levels;
    double adaptive_threshold;
    solver_kind solver;
    double tolerance;
    int max_iterations;
    int max_patches;
    int quadrature;    /* M: each patch triangle is sampled at the centroids of M x M sub-triangles */
    bool smooth;       /* --shading smooth: interpolate per-vertex radiance */
    bool enforce_reciprocity;
    const char *formfactors_path;
    int patch_size_argv; /* where --patch-size was given, for error messages */

    /* copied from the driver's options in prepare() */
    int bounce_min, bounce_max;
    double exposure;
    bool quiet;
    const scene *scene; /* for the stats (valid from prepare() to finish()) */

    /* the mesh */
    vec3 *vertices;
    int vertex_count, vertex_capacity;
    mesh_cell *cells;
    int cell_count, cell_capacity;
    quad_grid *quad_grids;         /* per surface (quads only) */
    triangle_grid *triangle_grids; /* per scene triangle (triangles and meshes) */
    int *triangle_slots;
    int triangle_slot_count;
    struct edge_entry *midpoints; /* edge -> midpoint vertex, for splitting cells */
    int midpoint_capacity, midpoint_count;

    /* the linear system */
    patch *patches;
    int patch_count;
    vec3 *points;       /* quadrature points of all patches */
    double *weights;    /* their weights (fractions of the patch area, summing to 1 per patch) */
    int point_count, point_capacity, weight_capacity;
    float *form_factors; /* F_ij at [i * n + j], or NULL (shooting) */
    vec3 *emitted;      /* Le_i: term 0 of (R6) */
    vec3 *first_shot;   /* light from point lights reflected once: part of term 1 */
    vec3 *radiance;     /* the solution shown (the --bounces window) */
    vec3 *vertex_radiance;

    /* statistics */
    int iterations, shots, refinements;
    double residual;
    double *history;
    int history_count, history_capacity;
    bool converged, no_light;
    double formfactor_s, solve_s;
    double reciprocity_error, row_sum_min, row_sum_max;
    bool have_matrix_checks;
    uint64_t visibility_rays;
    const char *solver_used;
} radiosity_state;

struct edge_entry { int a, b, midpoint; };

static int warned_specular, warned_phong, warned_spheres, warned_back;

static double now_seconds(void) { return omp_get_wtime(); }

static int parse_option(void *state_pointer, int argc, char **argv, int *i, char *err, size_t err_size)
{
    radiosity_state *st = state_pointer;
    const char *a = argv[*i];
    if (!strcmp(a, "--patch-size")) {
        st->patch_size_argv = *i;
        int status = parse_double_option(argc, argv, i, -1e300, 1e300, &st->patch_size, err, err_size);
        if (status == 1 && !(st->patch_size > 0.0)) {
            snprintf(err, err_size, "argv:%d: --patch-size must be positive (scene units), not '%s'", *i, argv[*i]);
            return 2;
        }
        return status;
    }
    if (!strcmp(a, "--adaptive")) {
        st->adaptive = true;
        return 1;
    }
    if (!strcmp(a, "--adaptive-levels")) {
        st->adaptive = true;
        return parse_int_option(argc, argv, i, 1, 8, &st->adaptive_levels, err, err_size);
    }
    if (!strcmp(a, "--adaptive-threshold"))
        return parse_double_option(argc, argv, i, 1e-6, 1e6, &st->adaptive_threshold, err, err_size);
    if (!strcmp(a, "--solver") || !strcmp(a, "--shading") || !strcmp(a, "--reciprocity")) {
        const char *v = *i + 1 < argc ? argv[++*i] : "";
        if (!strcmp(a, "--solver")) {
            for (int k = 0; k < 4; k++)
                if (!strcmp(v, solver_names[k])) {
                    st->solver = (solver_kind)k;
                    return 1;
                }
            snprintf(err, err_size, "argv:%d: --solver wants jacobi, gauss-seidel, shooting or direct, not '%s'", *i, v);
        } else if (!strcmp(a, "--shading")) {
            if (!strcmp(v, "flat") || !strcmp(v, "smooth")) {
                st->smooth = !strcmp(v, "smooth");
                return 1;
            }
            snprintf(err, err_size, "argv:%d: --shading wants flat or smooth, not '%s'", *i, v);
        } else {
            if (!strcmp(v, "check") || !strcmp(v, "enforce")) {
                st->enforce_reciprocity = !strcmp(v, "enforce");
                return 1;
            }
            snprintf(err, err_size, "argv:%d: --reciprocity wants check or enforce, not '%s'", *i, v);
        }
        return 2;
    }
    if (!strcmp(a, "--smooth")) {
        st->smooth = true;
        return 1;
    }
    if (!strcmp(a, "--tol"))
        return parse_double_option(argc, argv, i, 0.0, 1.0, &st->tolerance, err, err_size);
    if (!strcmp(a, "--iterations"))
        return parse_int_option(argc, argv, i, 1, 100000000, &st->max_iterations, err, err_size);
    if (!strcmp(a, "--max-patches"))
        return parse_int_option(argc, argv, i, 1, 1 << 30, &st->max_patches, err, err_size);
    if (!strcmp(a, "--quadrature"))
        return parse_int_option(argc, argv, i, 1, 16, &st->quadrature, err, err_size);
    if (!strcmp(a, "--formfactors")) {
        if (*i + 1 >= argc) {
            snprintf(err, err_size, "argv:%d: --formfactors needs a file name", *i);
            return 2;
        }
        st->formfactors_path = argv[++*i];
        return 1;
    }
    return 0;
}

/* Growable arrays: double the capacity when full.  Returns 0, or -1 when out of memory. */
static int grow(void **array, int *capacity, int needed, size_t element_size)
{
    if (needed <= *capacity)
        return 0;
    int next = *capacity ? *capacity : 64;
    while (next < needed)
        next *= 2;
    void *p = realloc(*array, (size_t)next * element_size);
    if (!p)
        return -1;
    *array = p;
    *capacity = next;
    return 0;
}

static int add_vertex(radiosity_state *st, vec3 p)
{
    if (grow((void **)&st->vertices, &st->vertex_capacity, st->vertex_count + 1, sizeof *st->vertices))
        return -1;
    st->vertices[st->vertex_count] = p;
    return st->vertex_count++;
}

static int add_cell(radiosity_state *st, int surface, const int *vertex, int vertex_count)
{
    if (grow((void **)&st->cells, &st->cell_capacity, st->cell_count + 1, sizeof *st->cells))
        return -1;
    mesh_cell *c = &st->cells[st->cell_count];
    *c = (mesh_cell){.vertex_count = vertex_count, .surface = surface, .first_child = -1, .patch = -1};
    memcpy(c->vertex, vertex, (size_t)vertex_count * sizeof *vertex);
    return st->cell_count++;
}

/* ---- meshing ------------------------------------------------------------------------ */

/* Point (u, v) of the bilinear patch through quad corners q[0..3]:
 * u runs from q0 to q1, v from q0 to q3.  A planar quad maps to itself,
 * and its iso-lines are straight, so a grid of (u, v) cells tiles it with
 * planar convex quads. */
static vec3 bilinear(const vec3 *q, double u, double v)
{
    vec3 bottom = v3_add(v3_scale(q[0], 1.0 - u), v3_scale(q[1], u));
    vec3 top = v3_add(v3_scale(q[3], 1.0 - u), v3_scale(q[2], u));
    return v3_add(v3_scale(bottom, 1.0 - v), v3_scale(top, v));
}

/* Inverse of bilinear() for a point p in the plane of the quad, by Newton's
 * method on the 2x2 system (three or four steps suffice for convex quads). */
static void inverse_bilinear(const vec3 *q, vec3 normal, vec3 p, double *u_out, double *v_out)
{
    double u = 0.5, v = 0.5;
    for (int step = 0; step < 12; step++) {
        vec3 r = v3_sub(bilinear(q, u, v), p);
        vec3 du = v3_add(v3_scale(v3_sub(q[1], q[0]), 1.0 - v), v3_scale(v3_sub(q[2], q[3]), v));
        vec3 dv = v3_add(v3_scale(v3_sub(q[3], q[0]), 1.0 - u), v3_scale(v3_sub(q[2], q[1]), u));
        /* Solve [du dv] (delta_u, delta_v) = r in the plane by Cramer's rule with the normal. */
        double det = v3_dot(v3_cross(du, dv), normal);
        if (det == 0.0)
            break;
        double delta_u = v3_dot(v3_cross(r, dv), normal) / det;
        double delta_v = v3_dot(v3_cross(du, r), normal) / det;
        u -= delta_u, v -= delta_v;
        if (fabs(delta_u) + fabs(delta_v) < 1e-12)
            break;
    }
    *u_out = fmin(1.0, fmax(0.0, u)), *v_out = fmin(1.0, fmax(0.0, v));
}

/* How many cells along a length: at least one, each at most patch_size long. */
static int cells_along(double length, double size) { return (int)fmax(1.0, ceil(length / size - 1e-9)); }

enum { MESH_CELL_LIMIT = 4000000 }; /* beyond this even shooting would take hours */

static int mesh_quad(radiosity_state *st, const scene *s, int surface_index)
{
    const surface *surf = &s->surfaces[surface_index];
    const vec3 *q = surf->vertex;
    int nu = cells_along(fmax(v3_length(v3_sub(q[1], q[0])), v3_length(v3_sub(q[2], q[3]))), st->patch_size);
    int nv = cells_along(fmax(v3_length(v3_sub(q[3], q[0])), v3_length(v3_sub(q[2], q[1]))), st->patch_size);
    int first_vertex = st->vertex_count;
    for (int b = 0; b <= nv; b++)
        for (int a = 0; a <= nu; a++)
            if (add_vertex(st, bilinear(q, (double)a / nu, (double)b / nv)) < 0)
                return -1;
    st->quad_grids[surface_index] = (quad_grid){.first_cell = st->cell_count, .nu = nu, .nv = nv};
    for (int b = 0; b < nv; b++)
        for (int a = 0; a < nu; a++) {
            int corner = first_vertex + b * (nu + 1) + a;
            int v[4] = {corner, corner + 1, corner + nu + 2, corner + nu + 1};
            if (add_cell(st, surface_index, v, 4) < 0)
                return -1;
        }
    return 0;
}

/* A triangle (p0, p0 + e1, p0 + e2) cut into m^2 similar triangles: the grid
 * points p0 + (a e1 + b e2) / m with a + b <= m; "up" cells (a, b), (a+1, b),
 * (a, b+1) and "down" cells (a+1, b), (a+1, b+1), (a, b+1), both with the
 * triangle's orientation. */
static int mesh_triangle(radiosity_state *st, int surface_index, int triangle_index, const triangle *t)
{
    /* Equal area to a square of side patch_size cut in two: A / m^2 = size^2 / 2. */
    int m = cells_along(sqrt(2.0 * t->area), st->patch_size);
    int *index = malloc((size_t)(m + 1) * (size_t)(m + 1) * sizeof *index);
    if (!index)
        return -1;
    for (int a = 0; a <= m; a++)
        for (int b = 0; a + b <= m; b++) {
            vec3 p = v3_add(t->p0, v3_add(v3_scale(t->e1, (double)a / m), v3_scale(t->e2, (double)b / m)));
            if ((index[a * (m + 1) + b] = add_vertex(st, p)) < 0) {
                free(index);
                return -1;
            }
        }
    triangle_grid *grid = &st->triangle_grids[triangle_index];
    *grid = (triangle_grid){.first_slot = st->triangle_slot_count, .m = m};
    int needed = st->triangle_slot_count + 2 * m * m;
    int *slots = realloc(st->triangle_slots, (size_t)needed * sizeof *slots);
    if (!slots) {
        free(index);
        return -1;
    }
    st->triangle_slots = slots;
    st->triangle_slot_count = needed;
    for (int a = 0; a < m; a++)
        for (int b = 0; b < m; b++) {
            int *slot = &slots[grid->first_slot + 2 * (a * m + b)];
            slot[0] = slot[1] = -1;
            if (a + b <= m - 1) {
                int v[3] = {index[a * (m + 1) + b], index[(a + 1) * (m + 1) + b], index[a * (m + 1) + b + 1]};
                if ((slot[0] = add_cell(st, surface_index, v, 3)) < 0)
                    break;
            }
            if (a + b <= m - 2) {
                int v[3] = {index[(a + 1) * (m + 1) + b], index[(a + 1) * (m + 1) + b + 1], index[a * (m + 1) + b + 1]};
                if ((slot[1] = add_cell(st, surface_index, v, 3)) < 0)
                    break;
            }
        }
    free(index);
    return 0;
}

/* The top-level cells of every surface.  Returns 0, or 2 with a message. */
static int build_mesh(radiosity_state *st, const scene *s, char *err, size_t err_size)
{
    /* Count first, so a tiny --patch-size fails at once instead of exhausting memory. */
    double estimate = 0.0;
    for (int i = 0; i < s->surface_count; i++)
        if (s->surfaces[i].kind != SURFACE_SPHERE)
            estimate += s->surfaces[i].area / (st->patch_size * st->patch_size) + s->surfaces[i].triangle_count;
    if (estimate > MESH_CELL_LIMIT) {
        snprintf(err, err_size, "argv:%d: --patch-size %g gives about %.3g patches, more than this chapter meshes (%d)",
                 st->patch_size_argv, st->patch_size, estimate, MESH_CELL_LIMIT);
        return 2;
    }
    st->quad_grids = calloc((size_t)s->surface_count + 1, sizeof *st->quad_grids);
    st->triangle_grids = calloc((size_t)s->triangle_count + 1, sizeof *st->triangle_grids);
    if (!st->quad_grids || !st->triangle_grids)
        goto out_of_memory;
    for (int i = 0; i < s->surface_count; i++) {
        const surface *surf = &s->surfaces[i];
        st->quad_grids[i].first_cell = -1;
        if (surf->kind == SURFACE_SPHERE) {
            warn_once(&warned_spheres, "03_radiosity: spheres are not meshed into patches; they block light "
                                       "but carry no radiance (black in the image)");
        } else if (surf->kind == SURFACE_QUAD) {
            if (mesh_quad(st, s, i))
                goto out_of_memory;
        } else {
            for (int t = surf->first_triangle; t < surf->first_triangle + surf->triangle_count; t++)
                if (mesh_triangle(st, i, t, &s->triangles[t]))
                    goto out_of_memory;
        }
    }
    return 0;
out_of_memory:
    snprintf(err, err_size, "argv:0: out of memory while meshing");
    return 2;
}

/* The midpoint vertex of edge (a, b), shared by the two cells on either side
 * (open-addressing hash table keyed by the edge). */
static int edge_midpoint(radiosity_state *st, int a, int b)
{
    if (a > b) {
        int t = a;
        a = b, b = t;
    }
    if (2 * (st->midpoint_count + 1) > st->midpoint_capacity) {
        int capacity = st->midpoint_capacity ? 2 * st->midpoint_capacity : 1024;
        struct edge_entry *table = malloc((size_t)capacity * sizeof *table);
        if (!table)
            return -1;
        for (int k = 0; k < capacity; k++)
            table[k].a = -1;
        for (int k = 0; k < st->midpoint_capacity; k++) {
            if (st->midpoints[k].a < 0)
                continue;
            uint64_t h = hash64(((uint64_t)st->midpoints[k].a << 32) | (uint64_t)st->midpoints[k].b);
            for (int slot = (int)(h & (uint64_t)(capacity - 1));; slot = (slot + 1) & (capacity - 1))
                if (table[slot].a < 0) {
                    table[slot] = st->midpoints[k];
                    break;
                }
        }
        free(st->midpoints);
        st->midpoints = table, st->midpoint_capacity = capacity;
    }
    uint64_t h = hash64(((uint64_t)a << 32) | (uint64_t)b);
    int mask = st->midpoint_capacity - 1;
    for (int slot = (int)(h & (uint64_t)mask);; slot = (slot + 1) & mask) {
        struct edge_entry *e = &st->midpoints[slot];
        if (e->a == a && e->b == b)
            return e->midpoint;
        if (e->a < 0) {
            int m = add_vertex(st, v3_scale(v3_add(st->vertices[a], st->vertices[b]), 0.5));
            if (m < 0)
                return -1;
            *e = (struct edge_entry){a, b, m};
            st->midpoint_count++;
            return m;
        }
    }
}

/* Split a leaf cell into four: quads at the edge midpoints and the centre
 * (which is the bilinear midpoint), triangles at the edge midpoints. */
static int split_cell(radiosity_state *st, int cell_index)
{
    mesh_cell c = st->cells[cell_index];
    int mid[4];
    for (int k = 0; k < c.vertex_count; k++)
        if ((mid[k] = edge_midpoint(st, c.vertex[k], c.vertex[(k + 1) % c.vertex_count])) < 0)
            return -1;
    int first = st->cell_count;
    if (c.vertex_count == 4) {
        vec3 centre = v3_splat(0.0);
        for (int k = 0; k < 4; k++)
            centre = v3_add(centre, v3_scale(st->vertices[c.vertex[k]], 0.25));
        int m = add_vertex(st, centre);
        if (m < 0)
            return -1;
        int children[4][4] = {{c.vertex[0], mid[0], m, mid[3]}, {mid[0], c.vertex[1], mid[1], m},
                              {m, mid[1], c.vertex[2], mid[2]}, {mid[3], m, mid[2], c.vertex[3]}};
        for (int k = 0; k < 4; k++)
            if (add_cell(st, c.surface, children[k], 4) < 0)
                return -1;
    } else {
        int children[4][3] = {{c.vertex[0], mid[0], mid[2]}, {mid[0], c.vertex[1], mid[1]},
                              {mid[2], mid[1], c.vertex[2]}, {mid[0], mid[1], mid[2]}};
        for (int k = 0; k < 4; k++)
            if (add_cell(st, c.surface, children[k], 3) < 0)
                return -1;
    }
    st->cells[cell_index].first_child = first;
    return 0;
}

/* The surface's reflectance and emission as this chapter models them. */
static void patch_material(const scene *s, int surface_index, vec3 *albedo, vec3 *emission)
{
    const material *m = &s->materials[s->surfaces[surface_index].material];
    *albedo = m->albedo;
    *emission = m->kind == MATERIAL_EMITTER ? m->emission : v3_splat(0.0);
    if (m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS) {
        warn_once(&warned_specular, "03_radiosity: radiosity models diffuse reflection only; mirrors and glass "
                                    "are treated as diffuse surfaces with their colour as albedo");
        *albedo = m->specular;
    } else if (m->kind == MATERIAL_PHONG) {
        warn_once(&warned_phong, "03_radiosity: Phong surfaces are treated as diffuse with albedo kd (ks dropped)");
    }
}

/* Quadrature points of a patch for the outer integral of (R10): each
 * triangle of the patch (a quad is the fan (0,1,2), (0,2,3)) is cut into
 * M^2 equal sub-triangles whose centroids get equal weight.  Returns -1 when
 * out of memory. */
static int add_quadrature_points(radiosity_state *st, patch *p)
{
    int M = st->quadrature;
    p->first_point = st->point_count;
    p->point_count = 0;
    for (int t = 1; t + 1 < p->corner_count; t++) {
        vec3 a = p->corner[0], e1 = v3_sub(p->corner[t], a), e2 = v3_sub(p->corner[t + 1], a);
        double weight = triangle_area(p->corner[0], p->corner[t], p->corner[t + 1]) / p->area / (M * M);
        for (int i = 0; i < M; i++)
            for (int j = 0; i + j < M; j++)
                for (int down = 0; down < 2; down++) {
                    if (down && i + j > M - 2)
                        continue;
                    double u = (3.0 * i + 1.0 + down) / (3.0 * M), v = (3.0 * j + 1.0 + down) / (3.0 * M);
                    if (grow((void **)&st->points, &st->point_capacity, st->point_count + 1, sizeof *st->points) ||
                        grow((void **)&st->weights, &st->weight_capacity, st->point_count + 1, sizeof *st->weights))
                        return -1;
                    st->points[st->point_count] = v3_add(a, v3_add(v3_scale(e1, u), v3_scale(e2, v)));
                    st->weights[st->point_count++] = weight;
                    p->point_count++;
                }
    }
    return 0;
}

/* Number the leaves and fill in their geometry: the patches of the system. */
static int collect_patches(radiosity_state *st, const scene *s)
{
    free(st->patches);
    st->patches = NULL;
    st->patch_count = 0;
    st->point_count = 0;
    int leaves = 0;
    for (int c = 0; c < st->cell_count; c++)
        leaves += st->cells[c].first_child < 0;
    st->patches = calloc((size_t)leaves + 1, sizeof *st->patches);
    if (!st->patches)
        return -1;
    for (int c = 0; c < st->cell_count; c++) {
        mesh_cell *cell = &st->cells[c];
        cell->patch = -1;
        if (cell->first_child >= 0)
            continue;
        patch *p = &st->patches[st->patch_count];
        *p = (patch){.cell = c, .surface = cell->surface, .corner_count = cell->vertex_count};
        for (int k = 0; k < cell->vertex_count; k++)
            p->corner[k] = st->vertices[cell->vertex[k]];
        vec3 twice_area = v3_splat(0.0), centroid = v3_splat(0.0);
        for (int t = 1; t + 1 < p->corner_count; t++) {
            vec3 cross = v3_cross(v3_sub(p->corner[t], p->corner[0]), v3_sub(p->corner[t + 1], p->corner[0]));
            double area = 0.5 * v3_length(cross);
            twice_area = v3_add(twice_area, cross);
            p->area += area;
            centroid = v3_add(centroid, v3_scale(v3_add(p->corner[0], v3_add(p->corner[t], p->corner[t + 1])),
                                                 area / 3.0));
        }
        p->normal = v3_normalize(twice_area);
        p->centroid = v3_scale(centroid, 1.0 / p->area);
        for (int k = 0; k < p->corner_count; k++)
            p->radius = fmax(p->radius, v3_length(v3_sub(p->corner[k], p->centroid)));
        patch_material(s, p->surface, &p->albedo, &p->emission);
        if (add_quadrature_points(st, p))
            return -1;
        cell->patch = st->patch_count++;
    }
    return 0;
}

/* ---- form factors (R10) ------------------------------------------------------------------ */

/* The inner integral of (R10) in closed form: the form factor from a
 * differential area at x (unit normal n) to a polygon, by Lambert's contour
 * formula (1760; Cohen & Wallace eq. 4.18, Baum et al. 1989)
 *
 *   F_dA->P = 1/(2 pi) Sum_k  gamma_k  n . (r_k x r_k+1) / |r_k x r_k+1|,
 *
 * r_k the vectors from x to the corners, gamma_k the angle between r_k and
 * r_k+1.  Only the part of the polygon in front of x counts, so the polygon
 * is first clipped to the half-space n . (y - x) > 0.  Exact, however close
 * the polygon: the 1/r^2 of the kernel is integrated analytically, which is
 * what keeps patches that share an edge accurate (a centre-to-centre
 * cos cos A / (pi r^2) would be far off there). */
static double point_to_polygon(vec3 x, vec3 n, const vec3 *polygon, int count)
{
    vec3 clipped[8];
    int kept = 0;
    for (int k = 0; k < count; k++) {
        vec3 a = polygon[k], b = polygon[(k + 1) % count];
        double ha = v3_dot(n, v3_sub(a, x)), hb = v3_dot(n, v3_sub(b, x));
        if (ha > 0.0)
            clipped[kept++] = a;
        if ((ha > 0.0) != (hb > 0.0))
            clipped[kept++] = v3_add(a, v3_scale(v3_sub(b, a), ha / (ha - hb)));
    }
    if (kept < 3)
        return 0.0;
    double sum = 0.0;
    for (int k = 0; k < kept; k++) {
        vec3 a = v3_sub(clipped[k], x), b = v3_sub(clipped[(k + 1) % kept], x);
        vec3 c = v3_cross(a, b);
        double length = v3_length(c);
        if (length > 0.0)
            sum += atan2(length, v3_dot(a, b)) * v3_dot(n, c) / length;
    }
    return fabs(sum) / (2.0 * M_PI);
}

/* Is any corner of p strictly in front of the plane through `origin` with
 * normal n?  (scene.epsilon absorbs rounding for coplanar patches.) */
static bool any_corner_in_front(const patch *p, vec3 origin, vec3 n, double epsilon)
{
    for (int k = 0; k < p->corner_count; k++)
        if (v3_dot(n, v3_sub(p->corner[k], origin)) > epsilon)
            return true;
    return false;
}

/* Patches closer than this many radii get every quadrature point; farther
 * ones the centroid only (the integrand is smooth there). */
static const double NEAR_FACTOR = 6.0;

/* F_ij (R10): the outer integral over patch i by its quadrature points x_k,
 * the inner one by point_to_polygon, and visibility V by one ray from each
 * x_k to a quadrature point of j (the pairing is shifted by a hash of
 * (i, j) so that neighbouring pairs do not all test the same line).
 * Deterministic: the same (i, j) always gives the same number, so the
 * matrix, the per-shot columns and the probes all agree. */
static double form_factor_estimate(const radiosity_state *st, const scene *s, int i, int j, uint64_t *rays)
{
    if (i == j)
        return 0.0; /* a flat patch does not see itself */
    const patch *pi = &st->patches[i], *pj = &st->patches[j];
    /* One-sided patches: j must be in front of i and i in front of j. */
    if (!any_corner_in_front(pj, pi->centroid, pi->normal, s->epsilon) ||
        !any_corner_in_front(pi, pj->centroid, pj->normal, s->epsilon))
        return 0.0;
    double distance = v3_length(v3_sub(pj->centroid, pi->centroid));
    if (distance > NEAR_FACTOR * (pi->radius + pj->radius)) {
        double f = point_to_polygon(pi->centroid, pi->normal, pj->corner, pj->corner_count);
        if (f <= 0.0)
            return 0.0;
        ++*rays;
        return scene_occluded(s, pi->centroid, pj->centroid) ? 0.0 : f;
    }
    uint64_t shift = hash64(((uint64_t)i << 32) ^ (uint64_t)j);
    double total = 0.0;
    for (int k = 0; k < pi->point_count; k++) {
        vec3 x = st->points[pi->first_point + k];
        /* x must be in front of j too (one-sided j); its own clip handles j's part behind x. */
        if (v3_dot(pj->normal, v3_sub(x, pj->centroid)) <= s->epsilon)
            continue;
        double f = point_to_polygon(x, pi->normal, pj->corner, pj->corner_count);
        if (f <= 0.0)
            continue;
        vec3 y = st->points[pj->first_point + (int)((shift + (uint64_t)k) % (uint64_t)pj->point_count)];
        ++*rays;
        if (!scene_occluded(s, x, y))
            total += st->weights[pi->first_point + k] * f;
    }
    return total;
}

/* The F_ij the solvers use: the estimate as it is (reciprocity checked in
 * the stats), or with --reciprocity enforce the mean of the two estimates of
 * A_i F_ij = A_j F_ji divided by A_i. */
static double form_factor(const radiosity_state *st, const scene *s, int i, int j, uint64_t *rays)
{
    double f = form_factor_estimate(st, s, i, j, rays);
    if (!st->enforce_reciprocity)
        return f;
    double g = form_factor_estimate(st, s, j, i, rays);
    return 0.5 * (st->patches[i].area * f + st->patches[j].area * g) / st->patches[i].area;
}

/* The n x n matrix, row by row in parallel. */
static int compute_form_factor_matrix(radiosity_state *st, const scene *s)
{
    size_t n = (size_t)st->patch_count;
    st->form_factors = malloc(n * n * sizeof *st->form_factors + 1);
    if (!st->form_factors)
        return -1;
    uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 8) reduction(+ : rays)
    for (int i = 0; i < (int)n; i++)
        for (int j = 0; j < (int)n; j++)
            st->form_factors[(size_t)i * n + (size_t)j] = (float)form_factor(st, s, i, j, &rays);
    st->visibility_rays += rays;

    /* Checks the solution depends on: row sums (1 in a closed scene, R10 is
     * a fraction of the light leaving i) and reciprocity A_i F_ij = A_j F_ji. */
    double asymmetric = 0.0, symmetric = 0.0, row_min = INFINITY, row_max = 0.0;
#pragma omp parallel for schedule(dynamic, 8) reduction(+ : asymmetric, symmetric) reduction(min : row_min) \
    reduction(max : row_max)
    for (int i = 0; i < (int)n; i++) {
        double row = 0.0;
        for (size_t j = 0; j < n; j++) {
            double fij = st->form_factors[(size_t)i * n + j], fji = st->form_factors[j * n + (size_t)i];
            row += fij;
            if (j > (size_t)i) {
                double gij = st->patches[i].area * fij, gji = st->patches[j].area * fji;
                asymmetric += fabs(gij - gji);
                symmetric += 0.5 * (gij + gji);
            }
        }
        row_min = fmin(row_min, row), row_max = fmax(row_max, row);
    }
    st->reciprocity_error = symmetric > 0.0 ? asymmetric / symmetric : 0.0;
    st->row_sum_min = row_min, st->row_sum_max = row_max;
    st->have_matrix_checks = true;
    return 0;
}

/* ---- sources ------------------------------------------------------------------------------- */

/* Point lights shoot first: each patch receives E = I cos(theta) / r^2 (R1)
 * at its quadrature points (with a shadow ray each) and reflects rho E / pi
 * as radiance.  This is light that has bounced once, part of the term K E
 * of (R6). */
static void shoot_point_lights(radiosity_state *st, const scene *s)
{
    uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : rays)
    for (int i = 0; i < st->patch_count; i++) {
        const patch *p = &st->patches[i];
        vec3 irradiance = v3_splat(0.0);
        for (int l = 0; l < s->light_count; l++)
            for (int k = 0; k < p->point_count; k++) {
                vec3 x = st->points[p->first_point + k];
                vec3 to_light = v3_sub(s->lights[l].position, x);
                double r2 = v3_dot(to_light, to_light), cos_theta = v3_dot(p->normal, to_light) / sqrt(r2);
                if (cos_theta <= 0.0)
                    continue;
                rays++;
                if (!scene_occluded(s, x, s->lights[l].position))
                    irradiance = v3_add(irradiance, v3_scale(s->lights[l].intensity,
                                                             st->weights[p->first_point + k] * cos_theta / r2));
            }
        st->first_shot[i] = v3_mul(p->albedo, v3_scale(irradiance, 1.0 / M_PI));
    }
    st->visibility_rays += rays;
}

/* ---- the solvers (R5, R6) ------------------------------------------------------------------ */

/* out = K x, i.e. out_i = rho_i Sum_j F_ij x_j: one application of the
 * transport operator (one more bounce).  From the matrix when there is one,
 * otherwise computing each F_ij on the spot. */
static void apply_transport(radiosity_state *st, const scene *s, const vec3 *x, vec3 *out)
{
    int n = st->patch_count;
    uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : rays)
    for (int i = 0; i < n; i++) {
        vec3 sum = v3_splat(0.0);
        for (int j = 0; j < n; j++) {
            double f = st->form_factors ? st->form_factors[(size_t)i * (size_t)n + (size_t)j]
                                        : form_factor(st, s, i, j, &rays);
            if (f != 0.0)
                sum = v3_madd(sum, x[j], f);
        }
        out[i] = v3_mul(st->patches[i].albedo, sum);
    }
    st->visibility_rays += rays;
}

/* The size of a radiance vector as power: Sum_i A_i (|r| + |g| + |b|).  In
 * this norm ||K|| <= max rho < 1 (a patch cannot send out more than it
 * receives), so Jacobi, Gauss-Seidel and shooting residuals all fall
 * monotonically in it. */
static double power_norm(const radiosity_state *st, const vec3 *x)
{
    double sum = 0.0;
    for (int i = 0; i < st->patch_count; i++)
        sum += st->patches[i].area * (fabs(x[i].x) + fabs(x[i].y) + fabs(x[i].z));
    return sum;
}

static void record_residual(radiosity_state *st, double residual)
{
    st->residual = residual;
    if (grow((void **)&st->history, &st->history_capacity, st->history_count + 1, sizeof *st->history) == 0)
        st->history[st->history_count++] = residual;
}

/* The Neumann series (R6) term by term:
 *   term 0 = E, term 1 = K E + (first shot of the point lights), term k = K term k-1,
 * summing the terms inside the --bounces window into L.  Started from L = 0
 * this is Jacobi's iteration L <- E + K L: after k iterations L holds k
 * terms, and the next term is exactly its residual E + K L - L. */
static int solve_jacobi(radiosity_state *st, const scene *s, vec3 *L, double source_norm)
{
    int n = st->patch_count;
    vec3 *term = malloc((size_t)n * sizeof *term + 1), *next = malloc((size_t)n * sizeof *next + 1);
    if (!term || !next) {
        free(term), free(next);
        return -1;
    }
    memcpy(term, st->emitted, (size_t)n * sizeof *term);
    for (int i = 0; i < n; i++)
        L[i] = v3_splat(0.0);
    for (int k = 0;; k++) {
        if (k >= st->bounce_min)
            for (int i = 0; i < n; i++)
                L[i] = v3_add(L[i], term[i]);
        st->iterations = k + 1;
        apply_transport(st, s, term, next); /* (R6): the next term, one more bounce */
        if (k == 0)
            for (int i = 0; i < n; i++)
                next[i] = v3_add(next[i], st->first_shot[i]);
        record_residual(st, power_norm(st, next) / source_norm);
        vec3 *swap = term;
        term = next, next = swap;
        if (k + 1 > st->bounce_max || st->residual <= st->tolerance) {
            st->converged = true;
            break;
        }
        if (st->iterations >= st->max_iterations)
            break;
    }
    free(term);
    free(next);
    return 0;
}

/* Residual r = E + K L - L of the full system, as a fraction of the source power. */
static double full_residual(radiosity_state *st, const scene *s, const vec3 *source, const vec3 *L,
                            double source_norm)
{
    int n = st->patch_count;
    vec3 *r = malloc((size_t)n * sizeof *r + 1);
    if (!r)
        return INFINITY; /* out of memory: reported as not converged */
    apply_transport(st, s, L, r);
    for (int i = 0; i < n; i++)
        r[i] = v3_sub(v3_add(source[i], r[i]), L[i]);
    double norm = power_norm(st, r) / source_norm;
    free(r);
    return norm;
}

/* Gauss-Seidel: the Jacobi update, but each L_i uses the values already
 * updated in this sweep.  Each update zeroes r_i and moves at most rho of
 * it to the others, so the residual falls every sweep. */
static void solve_gauss_seidel(radiosity_state *st, const scene *s, const vec3 *source, vec3 *L, double source_norm)
{
    int n = st->patch_count;
    float *row = st->form_factors;
    for (int i = 0; i < n; i++)
        L[i] = v3_splat(0.0);
    for (st->iterations = 1;; st->iterations++) {
        for (int i = 0; i < n; i++) {
            const float *f = row + (size_t)i * (size_t)n;
            vec3 gathered = v3_splat(0.0);
            for (int j = 0; j < n; j++)
                if (f[j] != 0.0f)
                    gathered = v3_madd(gathered, L[j], f[j]);
            L[i] = v3_add(source[i], v3_mul(st->patches[i].albedo, gathered));
        }
        record_residual(st, full_residual(st, s, source, L, source_norm));
        if (st->residual <= st->tolerance) {
            st->converged = true;
            break;
        }
        if (st->iterations >= st->max_iterations)
            break;
    }
}

/* Progressive refinement (Cohen et al. 1988) as Southwell relaxation: keep
 * the residual r = E + K L - L, which is exactly the light received but not
 * yet shot.  Start with L = 0, r = source.  A shot from patch j moves r_j
 * into L_j and sends it on: r_i += rho_i F_ij r_j for every i.  The column
 * F_.j is computed for the shot and thrown away: memory O(n), not O(n^2).
 * One "iteration" is n shots, the work of one Jacobi step. */
static int solve_shooting(radiosity_state *st, const scene *s, const vec3 *source, vec3 *L, double source_norm)
{
    int n = st->patch_count;
    vec3 *unshot = malloc((size_t)n * sizeof *unshot + 1);
    double *column = malloc((size_t)n * sizeof *column + 1);
    if (!unshot || !column) {
        free(unshot), free(column);
        return -1;
    }
    memcpy(unshot, source, (size_t)n * sizeof *unshot);
    for (int i = 0; i < n; i++)
        L[i] = v3_splat(0.0);
    long max_shots = (long)st->max_iterations * n;
    double residual = power_norm(st, unshot) / source_norm;
    long shot = 0;
    while (residual > st->tolerance && shot < max_shots) {
        int j = 0;
        double most = -1.0;
        for (int i = 0; i < n; i++) {
            double power = st->patches[i].area * (unshot[i].x + unshot[i].y + unshot[i].z);
            if (power > most)
                most = power, j = i;
        }
        vec3 shooting = unshot[j];
        L[j] = v3_add(L[j], shooting);
        unshot[j] = v3_splat(0.0);
        uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 64) reduction(+ : rays)
        for (int i = 0; i < n; i++)
            column[i] = form_factor(st, s, i, j, &rays);
        st->visibility_rays += rays;
        for (int i = 0; i < n; i++)
            if (column[i] != 0.0)
                unshot[i] = v3_add(unshot[i], v3_scale(v3_mul(st->patches[i].albedo, shooting), column[i]));
        residual = power_norm(st, unshot) / source_norm;
        shot++;
        if (shot % n == 0)
            record_residual(st, residual);
    }
    if (shot % n != 0 || shot == 0)
        record_residual(st, residual);
    st->shots = (int)shot;
    st->iterations = (int)((shot + n - 1) / n);
    st->converged = residual <= st->tolerance;

    /* For display, the received-but-unshot light is already radiance of its
     * patch, and the light still to come is guessed by the ambient term of
     * Cohen et al.: the mean unshot radiance, reflected 1/(1 - rho_avg) times. */
    double area = 0.0, rho_area = 0.0;
    vec3 unshot_area = v3_splat(0.0);
    for (int i = 0; i < n; i++) {
        area += st->patches[i].area;
        rho_area += st->patches[i].area * v3_average(st->patches[i].albedo);
        unshot_area = v3_madd(unshot_area, unshot[i], st->patches[i].area);
    }
    double rho_average = rho_area / area;
    vec3 ambient = v3_scale(unshot_area, 1.0 / (area * (1.0 - rho_average)));
    for (int i = 0; i < n; i++)
        L[i] = v3_add(L[i], v3_add(unshot[i], v3_mul(st->patches[i].albedo, ambient)));
    free(unshot);
    free(column);
    return 0;
}

/* (R5) directly: (I - K) L = source, one channel at a time, by Gaussian
 * elimination with partial pivoting (O(n^3): the reference for small n). */
static int solve_direct(radiosity_state *st, const scene *s, const vec3 *source, vec3 *L, double source_norm)
{
    size_t n = (size_t)st->patch_count;
    if (n > 4000 && !st->quiet)
        fprintf(stderr, "03_radiosity: direct solve of %zu patches: O(n^3) = %.2g operations per channel; "
                        "this will take a while\n", n, (double)n * n * n / 3.0);
    double *a = malloc(n * n * sizeof *a + 1), *b = malloc(n * sizeof *b + 1);
    if (!a || !b) {
        free(a), free(b);
        return -1;
    }
    for (int channel = 0; channel < 3; channel++) {
        for (size_t i = 0; i < n; i++) {
            double rho = v3_get(st->patches[i].albedo, channel);
            for (size_t j = 0; j < n; j++)
                a[i * n + j] = (i == j) - rho * st->form_factors[i * n + j];
            b[i] = v3_get(source[i], channel);
        }
        for (size_t col = 0; col < n; col++) {
            size_t pivot = col;
            for (size_t r = col + 1; r < n; r++)
                if (fabs(a[r * n + col]) > fabs(a[pivot * n + col]))
                    pivot = r;
            if (pivot != col) {
                for (size_t k = 0; k < n; k++) {
                    double t = a[col * n + k];
                    a[col * n + k] = a[pivot * n + k], a[pivot * n + k] = t;
                }
                double t = b[col];
                b[col] = b[pivot], b[pivot] = t;
            }
            /* I - K is strictly diagonally dominant by columns (column sums of
             * rho F are below 1 in the power norm), so the pivot is never 0. */
#pragma omp parallel for schedule(static)
            for (size_t r = col + 1; r < n; r++) {
                double factor = a[r * n + col] / a[col * n + col];
                if (factor == 0.0)
                    continue;
                for (size_t k = col; k < n; k++)
                    a[r * n + k] -= factor * a[col * n + k];
                b[r] -= factor * b[col];
            }
        }
        for (size_t i = n; i-- > 0;) {
            double sum = b[i];
            for (size_t k = i + 1; k < n; k++)
                sum -= a[i * n + k] * b[k];
            b[i] = sum / a[i * n + i];
        }
        for (size_t i = 0; i < n; i++) {
            if (channel == 0)
                L[i].x = b[i];
            else if (channel == 1)
                L[i].y = b[i];
            else
                L[i].z = b[i];
        }
    }
    free(a);
    free(b);
    st->iterations = 1;
    record_residual(st, full_residual(st, s, source, L, source_norm));
    st->converged = st->residual <= fmax(st->tolerance, 1e-9);
    return 0;
}

/* Solve for the current mesh; st->radiance gets the --bounces window.
 * Returns 0, or 2 with a message. */
static int solve(radiosity_state *st, const scene *s, char *err, size_t err_size)
{
    int n = st->patch_count;
    bool need_matrix = st->solver != SOLVER_SHOOTING;
    if (need_matrix && n > st->max_patches) {
        snprintf(err, err_size, "argv:0: %d patches need a %d x %d matrix (%.2f GiB as doubles), over the limit "
                 "--max-patches %d (2 GiB); use --solver shooting, a larger --patch-size, or raise --max-patches",
                 n, n, n, (double)n * n * 8.0 / 1073741824.0, st->max_patches);
        return 2;
    }
    free(st->form_factors), free(st->emitted), free(st->first_shot), free(st->radiance);
    st->form_factors = NULL;
    st->emitted = calloc((size_t)n + 1, sizeof *st->emitted);
    st->first_shot = calloc((size_t)n + 1, sizeof *st->first_shot);
    st->radiance = calloc((size_t)n + 1, sizeof *st->radiance);
    vec3 *source = calloc((size_t)n + 1, sizeof *source);
    if (!st->emitted || !st->first_shot || !st->radiance || !source) {
        free(source);
        snprintf(err, err_size, "argv:0: out of memory for %d patches", n);
        return 2;
    }
    double start = now_seconds();
    for (int i = 0; i < n; i++)
        st->emitted[i] = st->patches[i].emission;
    shoot_point_lights(st, s);
    if (need_matrix && compute_form_factor_matrix(st, s)) {
        free(source);
        snprintf(err, err_size, "argv:0: out of memory for the %d x %d form-factor matrix", n, n);
        return 2;
    }
    double matrix_done = now_seconds();
    st->formfactor_s += matrix_done - start;

    for (int i = 0; i < n; i++)
        source[i] = v3_add(st->emitted[i], st->first_shot[i]);
    double source_norm = power_norm(st, source);
    st->history_count = 0;
    st->converged = false;
    st->shots = 0;
    st->no_light = !(source_norm > 0.0);
    if (st->no_light) {
        /* Nothing emits: L = 0 solves L = E + K L exactly. */
        st->iterations = 0;
        st->converged = true;
        record_residual(st, 0.0);
        st->solver_used = solver_names[st->solver];
        free(source);
        return 0;
    }
    vec3 *L = st->radiance;
    int failed = 0;
    bool finite_window = st->bounce_max < RENDER_BOUNCES_UNLIMITED;
    if (st->solver == SOLVER_JACOBI || finite_window) {
        /* A window with an upper end is a finite sum of Neumann terms: computed
         * as such whatever the solver (the other solvers do not separate bounces). */
        st->solver_used = "jacobi";
        failed = solve_jacobi(st, s, L, source_norm);
    } else {
        st->solver_used = solver_names[st->solver];
        if (st->solver == SOLVER_GAUSS_SEIDEL)
            solve_gauss_seidel(st, s, source, L, source_norm);
        else if (st->solver == SOLVER_SHOOTING)
            failed = solve_shooting(st, s, source, L, source_norm);
        else
            failed = solve_direct(st, s, source, L, source_norm);
        vec3 *term = NULL, *next = NULL;
        if (!failed && st->bounce_min > 0) {
            /* --bounces A: (no upper end): the full solution minus terms 0 .. A-1. */
            term = malloc((size_t)n * sizeof *term + 1), next = malloc((size_t)n * sizeof *next + 1);
            failed = !term || !next;
        }
        if (!failed && st->bounce_min > 0) {
            memcpy(term, st->emitted, (size_t)n * sizeof *term);
            for (int k = 0; k < st->bounce_min; k++) {
                for (int i = 0; i < n; i++)
                    L[i] = v3_sub(L[i], term[i]);
                apply_transport(st, s, term, next);
                if (k == 0)
                    for (int i = 0; i < n; i++)
                        next[i] = v3_add(next[i], st->first_shot[i]);
                vec3 *swap = term;
                term = next, next = swap;
            }
        }
        free(term);
        free(next);
    }
    st->solve_s += now_seconds() - matrix_done;
    free(source);
    if (failed) {
        snprintf(err, err_size, "argv:0: out of memory while solving for %d patches", n);
        return 2;
    }
    return 0;
}

/* ---- the image ------------------------------------------------------------------------------- */

/* Per-vertex radiance for smooth shading: the area-weighted mean of the
 * patches around each vertex, on the same surface only (radiance jumps
 * across a corner between two walls, and must). */
static int compute_vertex_radiance(radiosity_state *st)
{
    free(st->vertex_radiance);
    st->vertex_radiance = calloc((size_t)st->vertex_count + 1, sizeof *st->vertex_radiance);
    double *weight = calloc((size_t)st->vertex_count + 1, sizeof *weight);
    if (!st->vertex_radiance || !weight) {
        free(weight);
        return -1;
    }
    for (int p = 0; p < st->patch_count; p++) {
        const mesh_cell *c = &st->cells[st->patches[p].cell];
        for (int k = 0; k < c->vertex_count; k++) {
            st->vertex_radiance[c->vertex[k]] =
                v3_madd(st->vertex_radiance[c->vertex[k]], st->radiance[p], st->patches[p].area);
            weight[c->vertex[k]] += st->patches[p].area;
        }
    }
    for (int v = 0; v < st->vertex_count; v++)
        if (weight[v] > 0.0)
            st->vertex_radiance[v] = v3_scale(st->vertex_radiance[v], 1.0 / weight[v]);
    free(weight);
    return 0;
}

/* Is p inside the convex cell (in its plane)?  The signed areas of p with
 * every edge must agree with the normal. */
static bool cell_contains(const radiosity_state *st, const mesh_cell *c, vec3 normal, vec3 p)
{
    for (int k = 0; k < c->vertex_count; k++) {
        vec3 a = st->vertices[c->vertex[k]], b = st->vertices[c->vertex[(k + 1) % c->vertex_count]];
        if (v3_dot(v3_cross(v3_sub(b, a), v3_sub(p, a)), normal) < -1e-9 * v3_dot(v3_sub(b, a), v3_sub(b, a)))
            return false;
    }
    return true;
}

/* The top-level cell under a hit, then down the refinement tree to its leaf. */
static int locate_cell(const radiosity_state *st, const scene *s, const hit *h)
{
    const surface *surf = &s->surfaces[h->surface];
    int cell;
    if (surf->kind == SURFACE_QUAD) {
        const quad_grid *g = &st->quad_grids[h->surface];
        double u, v;
        inverse_bilinear(surf->vertex, s->triangles[surf->first_triangle].normal, h->point, &u, &v);
        int a = (int)fmin(g->nu - 1, u * g->nu), b = (int)fmin(g->nv - 1, v * g->nv);
        cell = g->first_cell + b * g->nu + a;
    } else {
        const triangle *t = &s->triangles[h->primitive];
        const triangle_grid *g = &st->triangle_grids[h->primitive];
        vec3 d = v3_sub(h->point, t->p0);
        double d11 = v3_dot(t->e1, t->e1), d12 = v3_dot(t->e1, t->e2), d22 = v3_dot(t->e2, t->e2);
        double p1 = v3_dot(d, t->e1), p2 = v3_dot(d, t->e2), det = d11 * d22 - d12 * d12;
        double u = fmax(0.0, (d22 * p1 - d12 * p2) / det) * g->m, v = fmax(0.0, (d11 * p2 - d12 * p1) / det) * g->m;
        int a = (int)fmin(g->m - 1, floor(u)), b = (int)fmin(g->m - 1 - a, floor(v));
        bool down = u - a + v - b > 1.0 && a + b <= g->m - 2;
        cell = st->triangle_slots[g->first_slot + 2 * (a * g->m + b) + down];
    }
    vec3 normal = h->normal;
    while (st->cells[cell].first_child >= 0) {
        int first = st->cells[cell].first_child, next = first + 3; /* rounding: the last child by default */
        for (int k = 0; k < 4; k++)
            if (cell_contains(st, &st->cells[first + k], normal, h->point)) {
                next = first + k;
                break;
            }
        cell = next;
    }
    return cell;
}

/* Smooth shading: interpolate the vertex radiances over the leaf (bilinear
 * on quads, barycentric on triangles). */
static vec3 interpolate(const radiosity_state *st, const mesh_cell *c, vec3 normal, vec3 p)
{
    const vec3 *R = st->vertex_radiance;
    if (c->vertex_count == 4) {
        vec3 q[4];
        for (int k = 0; k < 4; k++)
            q[k] = st->vertices[c->vertex[k]];
        double u, v;
        inverse_bilinear(q, normal, p, &u, &v);
        return v3_add(v3_add(v3_scale(R[c->vertex[0]], (1 - u) * (1 - v)), v3_scale(R[c->vertex[1]], u * (1 - v))),
                      v3_add(v3_scale(R[c->vertex[2]], u * v), v3_scale(R[c->vertex[3]], (1 - u) * v)));
    }
    vec3 a = st->vertices[c->vertex[0]], b = st->vertices[c->vertex[1]], cc = st->vertices[c->vertex[2]];
    double area = v3_dot(v3_cross(v3_sub(b, a), v3_sub(cc, a)), normal);
    double wa = v3_dot(v3_cross(v3_sub(b, p), v3_sub(cc, p)), normal) / area;
    double wb = v3_dot(v3_cross(v3_sub(cc, p), v3_sub(a, p)), normal) / area;
    double wc = 1.0 - wa - wb;
    return v3_add(v3_add(v3_scale(R[c->vertex[0]], wa), v3_scale(R[c->vertex[1]], wb)), v3_scale(R[c->vertex[2]], wc));
}

static vec3 radiance(const void *state_pointer, const scene *s, ray r, rng *g, render_counters *counters)
{
    const radiosity_state *st = state_pointer;
    (void)g, (void)counters;
    hit h;
    if (!scene_intersect(s, r, INFINITY, &h))
        return s->background;
    if (s->surfaces[h.surface].kind == SURFACE_SPHERE || !st->radiance)
        return v3_splat(0.0);
    if (v3_dot(h.normal, r.direction) >= 0.0) {
        warn_once(&warned_back, "03_radiosity: the camera sees the back of a surface; patches are one-sided "
                                "(front = right-hand rule), backs render black");
        return v3_splat(0.0);
    }
    const mesh_cell *c = &st->cells[locate_cell(st, s, &h)];
    return st->smooth ? interpolate(st, c, h.normal, h.point) : st->radiance[c->patch];
}

/* ---- adaptive refinement ------------------------------------------------------------------- */

/* Split the patches where the solution is poorly represented: where a
 * patch's radiance differs from the mean of its corners' smooth-shading
 * values (each the average of the patches around the corner) by more than
 * --adaptive-threshold times the mean reflected radiance of the scene.  A
 * smooth gradient (the 1/r^2 falloff) leaves that difference small, a jump
 * (a shadow edge, light leaking into a corner) does not.  Returns the
 * number of patches split, or -1 when out of memory. */
static int refine(radiosity_state *st)
{
    if (compute_vertex_radiance(st))
        return -1;
    double area = 0.0, sum = 0.0; /* mean reflected radiance: the light sources' own glow would swamp it */
    for (int p = 0; p < st->patch_count; p++) {
        area += st->patches[p].area;
        sum += st->patches[p].area * v3_luminance(v3_sub(st->radiance[p], st->emitted[p]));
    }
    double threshold = st->adaptive_threshold * sum / area;
    int split = 0, patches = st->patch_count;
    for (int p = 0; p < patches; p++) {
        const mesh_cell *c = &st->cells[st->patches[p].cell];
        double corners = 0.0;
        for (int k = 0; k < c->vertex_count; k++)
            corners += v3_luminance(st->vertex_radiance[c->vertex[k]]) / c->vertex_count;
        if (fabs(corners - v3_luminance(st->radiance[p])) > threshold) {
            if (split_cell(st, st->patches[p].cell))
                return -1;
            split++;
        }
    }
    return split;
}

static int write_formfactors(radiosity_state *st, const scene *s, char *err, size_t err_size);

/* ---- prepare: mesh, form factors, solve ------------------------------------------------------ */

static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    radiosity_state *st = state_pointer;
    st->bounce_min = o->bounce_min, st->bounce_max = o->bounce_max;
    st->exposure = o->exposure, st->quiet = o->quiet;
    st->scene = s;
    if (build_mesh(st, s, err, err_size))
        return 2;
    for (int level = 0;; level++) {
        if (collect_patches(st, s)) {
            snprintf(err, err_size, "argv:0: out of memory for the patches");
            return 2;
        }
        if (solve(st, s, err, err_size))
            return 2;
        if (!st->adaptive || level == st->adaptive_levels || st->no_light)
            break;
        int split = refine(st);
        if (split < 0) {
            snprintf(err, err_size, "argv:0: out of memory while refining the mesh");
            return 2;
        }
        if (split == 0)
            break;
        st->refinements++;
        if (!st->quiet)
            fprintf(stderr, "03_radiosity: refinement %d split %d of %d patches\n", level + 1, split, st->patch_count);
    }
    if (compute_vertex_radiance(st)) {
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    if (st->formfactors_path && write_formfactors(st, s, err, err_size))
        return 2;
    if (st->no_light)
        fprintf(stderr, "03_radiosity: nothing in the scene emits light (no emitter, no point light): "
                        "the solution is zero and the image black\n");
    else if (!st->converged)
        fprintf(stderr, "03_radiosity: %s stopped at the iteration cap (%d iterations) with residual %.3g "
                        "above --tol %.3g; raise --iterations\n", st->solver_used, st->iterations, st->residual,
                st->tolerance);
    if (!st->quiet)
        fprintf(stderr, "03_radiosity: %d patches, form factors %.2f s, %s %d iterations %.2f s, residual %.3g\n",
                st->patch_count, st->formfactor_s, st->solver_used, st->iterations, st->solve_s, st->residual);
    return 0;
}

/* ---- probes -------------------------------------------------------------------------------- */

/* Irradiance at a probe from the solution: E = Sum_j L_j pi F_dA->j (the
 * contour formula again, visibility by rays to j's quadrature points) plus
 * the point lights' I cos / r^2 (R1).  The patches' radiance is the window
 * shown in the image; point lights count as term 0, like an emitter.
 * Deterministic, so the standard error is 0; its error is the
 * discretisation's. */
static probe_result probe_irradiance(const void *state_pointer, const scene *s, const probe *pr, uint64_t seed,
                                     render_counters *counters)
{
    const radiosity_state *st = state_pointer;
    (void)seed, (void)counters;
    vec3 x = pr->position, n = pr->normal;
    vec3 total = v3_splat(0.0);
    if (st->bounce_min == 0)
        for (int l = 0; l < s->light_count; l++) {
            vec3 d = v3_sub(s->lights[l].position, x);
            double r2 = v3_dot(d, d), cos_theta = v3_dot(n, d) / sqrt(r2);
            if (cos_theta > 0.0 && !scene_occluded(s, x, s->lights[l].position))
                total = v3_madd(total, s->lights[l].intensity, cos_theta / r2);
        }
    for (int j = 0; j < st->patch_count; j++) {
        const patch *p = &st->patches[j];
        if (v3_dot(p->normal, v3_sub(x, p->centroid)) <= s->epsilon)
            continue; /* behind the one-sided patch */
        double f = point_to_polygon(x, n, p->corner, p->corner_count);
        if (f <= 0.0)
            continue;
        int visible = 0;
        for (int k = 0; k < p->point_count; k++)
            visible += !scene_occluded(s, x, st->points[p->first_point + k]);
        total = v3_madd(total, st->radiance[j], M_PI * f * visible / p->point_count);
    }
    return (probe_result){.irradiance = total, .standard_error = v3_splat(0.0)};
}

/* ---- outputs: PLY mesh, form-factor table, stats --------------------------------------------- */

/* ASCII PLY of the patches with per-vertex radiance: float properties
 * radiance_r/g/b (linear) and uchar red/green/blue (tone-mapped sRGB, what
 * MeshLab and Blender display).  Flat shading writes each patch with its own
 * corners so its colour stays flat; smooth shares the vertices. */
static int write_ply(const radiosity_state *st, const char *path, char *err, size_t err_size)
{
    atomic_file out; /* written through a temporary and renamed, like the driver's outputs */
    if (atomic_file_open(&out, path, err, err_size))
        return 2;
    FILE *f = out.file;
    int corners = 0;
    for (int p = 0; p < st->patch_count; p++)
        corners += st->patches[p].corner_count;
    int vertices = st->smooth ? st->vertex_count : corners;
    fprintf(f, "ply\nformat ascii 1.0\ncomment 03_radiosity: radiance per vertex (%s shading)\n"
               "element vertex %d\nproperty float x\nproperty float y\nproperty float z\n"
               "property float radiance_r\nproperty float radiance_g\nproperty float radiance_b\n"
               "property uchar red\nproperty uchar green\nproperty uchar blue\n"
               "element face %d\nproperty list uchar int vertex_indices\nend_header\n",
            st->smooth ? "smooth" : "flat", vertices, st->patch_count);
    for (int v = 0; v < vertices; v++) {
        vec3 p, L;
        if (st->smooth) {
            p = st->vertices[v], L = st->vertex_radiance[v];
        } else {
            int patch_index = 0, k = v;
            while (k >= st->patches[patch_index].corner_count)
                k -= st->patches[patch_index++].corner_count;
            p = st->patches[patch_index].corner[k], L = st->radiance[patch_index];
        }
        fprintf(f, "%.9g %.9g %.9g %.9g %.9g %.9g %u %u %u\n", p.x, p.y, p.z, L.x, L.y, L.z,
                tonemap_srgb8(L.x, st->exposure), tonemap_srgb8(L.y, st->exposure), tonemap_srgb8(L.z, st->exposure));
    }
    int next = 0;
    for (int p = 0; p < st->patch_count; p++) {
        const mesh_cell *c = &st->cells[st->patches[p].cell];
        fprintf(f, "%d", c->vertex_count);
        for (int k = 0; k < c->vertex_count; k++)
            fprintf(f, " %d", st->smooth ? c->vertex[k] : next++);
        fputc('\n', f);
    }
    return atomic_file_commit(&out, 0, err, err_size);
}

/* --formfactors FILE.csv: surface-to-surface form factors
 *   F(S -> T) = 1/A_S Sum_{i in S} Sum_{j in T} A_i F_ij,
 * for every ordered pair of meshed surfaces. */
static int write_formfactors(radiosity_state *st, const scene *s, char *err, size_t err_size)
{
    int m = s->surface_count, n = st->patch_count;
    double *sums = calloc((size_t)m * (size_t)m + 1, sizeof *sums);
    if (!sums) {
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    uint64_t rays = 0;
#pragma omp parallel reduction(+ : rays)
    {
        double *local = calloc((size_t)m * (size_t)m + 1, sizeof *local);
#pragma omp for schedule(dynamic, 8)
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++) {
                double f = st->form_factors ? st->form_factors[(size_t)i * (size_t)n + (size_t)j]
                                            : form_factor(st, s, i, j, &rays);
                if (local)
                    local[st->patches[i].surface * m + st->patches[j].surface] += st->patches[i].area * f;
            }
#pragma omp critical
        for (int k = 0; local && k < m * m; k++)
            sums[k] += local[k];
        free(local);
    }
    st->visibility_rays += rays;
    double *area = calloc((size_t)m + 1, sizeof *area);
    for (int i = 0; area && i < n; i++)
        area[st->patches[i].surface] += st->patches[i].area;
    atomic_file out;
    int status = 2;
    if (area && atomic_file_open(&out, st->formfactors_path, err, err_size) == 0) {
        FILE *f = out.file;
        fprintf(f, "from,to,F\n");
        for (int a = 0; a < m; a++)
            for (int b = 0; b < m; b++)
                if (area[a] > 0.0 && area[b] > 0.0)
                    fprintf(f, "%s,%s,%.10g\n", s->surfaces[a].name, s->surfaces[b].name, sums[a * m + b] / area[a]);
        status = atomic_file_commit(&out, 0, err, err_size);
    } else if (!area) {
        snprintf(err, err_size, "argv:0: out of memory");
    }
    free(area);
    free(sums);
    return status;
}

static int write_output(const void *state_pointer, const scene *s, const char *path, char *err, size_t err_size)
{
    (void)s;
    if (!path_has_extension(path, ".ply"))
        return 0;
    return write_ply(state_pointer, path, err, err_size) ? 2 : 1;
}

static void write_stats(const void *state_pointer, FILE *json)
{
    const radiosity_state *st = state_pointer;
    fprintf(json, ",\n  \"solver\": \"%s\",\n  \"solver_used\": \"%s\",\n  \"patch_size\": ", solver_names[st->solver],
            st->solver_used ? st->solver_used : "none");
    json_number(json, st->patch_size);
    fprintf(json, ",\n  \"patches\": %d,\n  \"refinements\": %d,\n  \"iterations\": %d,\n  \"shots\": %d",
            st->patch_count, st->refinements, st->iterations, st->shots);
    json_field_number(json, "residual", st->residual);
    json_field_number(json, "tolerance", st->tolerance);
    fprintf(json, ",\n  \"converged\": %s,\n  \"no_light\": %s,\n  \"residual_history\": [",
            st->converged ? "true" : "false", st->no_light ? "true" : "false");
    for (int k = 0; k < st->history_count; k++) {
        if (k)
            fputs(", ", json);
        json_number(json, st->history[k]);
    }
    fprintf(json, "],\n  \"formfactor_s\": ");
    json_number(json, st->formfactor_s);
    json_field_number(json, "solve_s", st->solve_s);
    fprintf(json, ",\n  \"visibility_rays\": %llu,\n  \"reciprocity\": \"%s\"", (unsigned long long)st->visibility_rays,
            st->enforce_reciprocity ? "enforce" : "check");
    if (st->have_matrix_checks) {
        json_field_number(json, "reciprocity_error", st->reciprocity_error);
        json_field_number(json, "row_sum_min", st->row_sum_min);
        json_field_number(json, "row_sum_max", st->row_sum_max);
    }
    fprintf(json, ",\n  \"matrix_bytes\": %.0f", st->form_factors ? (double)st->patch_count * st->patch_count * 4.0 : 0.0);

    /* Each surface's area-weighted mean exitant radiance (emission included),
     * the same key the path tracer reports, for comparing the two methods. */
    fprintf(json, ",\n  \"surfaces\": [");
    int written = 0;
    for (int surface_index = 0; st->radiance && surface_index < st->scene->surface_count; surface_index++) {
        double area = 0.0;
        vec3 sum = v3_splat(0.0);
        for (int p = 0; p < st->patch_count; p++)
            if (st->patches[p].surface == surface_index) {
                area += st->patches[p].area;
                sum = v3_madd(sum, st->radiance[p], st->patches[p].area);
            }
        if (area <= 0.0)
            continue;
        fprintf(json, "%s\n    {\"name\": ", written++ ? "," : "");
        json_string(json, st->scene->surfaces[surface_index].name);
        fprintf(json, ", \"area\": ");
        json_number(json, area);
        fprintf(json, ", \"radiance\": ");
        json_vec3(json, v3_scale(sum, 1.0 / area));
        fputc('}', json);
    }
    fprintf(json, "%s]", written ? "\n  " : "");
}

static void finish(void *state_pointer)
{
    radiosity_state *st = state_pointer;
    free(st->vertices), free(st->cells), free(st->quad_grids), free(st->triangle_grids), free(st->triangle_slots);
    free(st->midpoints), free(st->patches), free(st->points), free(st->weights), free(st->form_factors);
    free(st->emitted), free(st->first_shot), free(st->radiance), free(st->vertex_radiance), free(st->history);
}

/* ---- main ---------------------------------------------------------------------------------- */

int main(int argc, char **argv)
{
    radiosity_state state = {
        .patch_size = 50.0,
        .adaptive = false,
        .adaptive_levels = 2,
        .adaptive_threshold = 0.1,
        .solver = SOLVER_JACOBI,
        .tolerance = 1e-4,
        .max_iterations = 1000,
        .max_patches = 16384, /* 16384^2 doubles = 2 GiB (the direct solve's matrix; F itself is float) */
        .quadrature = 4,
        .smooth = false,
    };
    const chapter radiosity = {
        .name = "03_radiosity",
        .description = "radiosity: patches, form factors (R10), L = E + KL solved by Jacobi (= Neumann series R6), "
                       "Gauss-Seidel, shooting, or directly (R5)",
        .options_help =
            "  --patch-size S         target patch edge in scene units (default 50, for the Cornell box in mm)\n"
            "  --adaptive             refine patches where the radiance changes fast (shadow edges)\n"
            "  --adaptive-levels N    refinement rounds, each splitting patches in four (default 2)\n"
            "  --adaptive-threshold T split where a patch and the mean of its corners differ by T x the mean radiance (default 0.1)\n"
            "  --solver NAME          jacobi | gauss-seidel | shooting | direct (default jacobi)\n"
            "  --tol T                stop when the residual falls below T (fraction of source power; default 1e-4)\n"
            "  --iterations N         at most N iterations (shooting: N x patches shots; default 1000)\n"
            "  --max-patches N        refuse matrix solvers above N patches (default 16384: 2 GiB of doubles)\n"
            "  --quadrature M         M x M points per patch triangle for near form factors (default 4)\n"
            "  --reciprocity check|enforce  report A_i F_ij vs A_j F_ji, or average them (default check)\n"
            "  --shading flat|smooth  patch colours, or interpolated vertex radiance (default flat)\n"
            "  --smooth               same as --shading smooth\n"
            "  --formfactors FILE.csv write surface-to-surface form factors (from,to,F)\n"
            "  --out FILE.ply         also write the mesh with per-vertex radiance (PLY)\n",
        .default_spp = 1,
        .counter_names = {NULL},
        .parse_option = parse_option,
        .prepare = prepare,
        .radiance = radiance,
        .probe = probe_irradiance,
        .write_stats = write_stats,
        .write_output = write_output,
        .finish = finish,
    };
    return render_main(argc, argv, &radiosity, &state);
}
