/* patch_mesh.c — the scene's surfaces cut into patches (see patch_mesh.h). */
#include "patch_mesh.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "rng.h"

/* Point location on one surface: how the top-level grid of cells is laid out. */
struct quad_grid {
    int first_cell; /* first top-level cell */
    int nu, nv;     /* quads: nu x nv cells, cell (a, b) = first_cell + b * nu + a; spheres: longitude x latitude */
    bool sphere;    /* a sphere cut along meridians and parallels: its cells' points are lifted onto it */
    vec3 center;
    double radius;
};
struct triangle_grid {
    int first_slot; /* into triangle_slots: 2 m^2 entries, (a, b, up/down) -> cell or -1 */
    int m;          /* the triangle is cut into m^2 similar triangles */
};
struct edge_entry {
    int a, b, midpoint;
};

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

static int add_vertex(patch_mesh *m, vec3 p)
{
    if (grow((void **)&m->vertices, &m->vertex_capacity, m->vertex_count + 1, sizeof *m->vertices))
        return -1;
    m->vertices[m->vertex_count] = p;
    return m->vertex_count++;
}

static int add_cell(patch_mesh *m, int surface, const int *vertex, int vertex_count)
{
    if (grow((void **)&m->cells, &m->cell_capacity, m->cell_count + 1, sizeof *m->cells))
        return -1;
    mesh_cell *c = &m->cells[m->cell_count];
    *c = (mesh_cell){.vertex_count = vertex_count, .surface = surface, .first_child = -1, .patch = -1};
    memcpy(c->vertex, vertex, (size_t)vertex_count * sizeof *vertex);
    return m->cell_count++;
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

static int mesh_quad(patch_mesh *m, const scene *s, int surface_index, double patch_size)
{
    const surface *surf = &s->surfaces[surface_index];
    const vec3 *q = surf->vertex;
    int nu = cells_along(fmax(v3_length(v3_sub(q[1], q[0])), v3_length(v3_sub(q[2], q[3]))), patch_size);
    int nv = cells_along(fmax(v3_length(v3_sub(q[3], q[0])), v3_length(v3_sub(q[2], q[1]))), patch_size);
    int first_vertex = m->vertex_count;
    for (int b = 0; b <= nv; b++)
        for (int a = 0; a <= nu; a++)
            if (add_vertex(m, bilinear(q, (double)a / nu, (double)b / nv)) < 0)
                return -1;
    m->quad_grids[surface_index] = (struct quad_grid){.first_cell = m->cell_count, .nu = nu, .nv = nv};
    for (int b = 0; b < nv; b++)
        for (int a = 0; a < nu; a++) {
            int corner = first_vertex + b * (nu + 1) + a;
            int v[4] = {corner, corner + 1, corner + nu + 2, corner + nu + 1};
            if (add_cell(m, surface_index, v, 4) < 0)
                return -1;
        }
    return 0;
}

/* A triangle (p0, p0 + e1, p0 + e2) cut into m^2 similar triangles: the grid
 * points p0 + (a e1 + b e2) / m with a + b <= m; "up" cells (a, b), (a+1, b),
 * (a, b+1) and "down" cells (a+1, b), (a+1, b+1), (a, b+1), both with the
 * triangle's orientation. */
static int mesh_triangle(patch_mesh *mesh, int surface_index, int triangle_index, const triangle *t, double patch_size)
{
    /* Equal area to a square of side patch_size cut in two: A / m^2 = size^2 / 2. */
    int m = cells_along(sqrt(2.0 * t->area), patch_size);
    int *index = malloc((size_t)(m + 1) * (size_t)(m + 1) * sizeof *index);
    if (!index)
        return -1;
    for (int a = 0; a <= m; a++)
        for (int b = 0; a + b <= m; b++) {
            vec3 p = v3_add(t->p0, v3_add(v3_scale(t->e1, (double)a / m), v3_scale(t->e2, (double)b / m)));
            if ((index[a * (m + 1) + b] = add_vertex(mesh, p)) < 0) {
                free(index);
                return -1;
            }
        }
    struct triangle_grid *grid = &mesh->triangle_grids[triangle_index];
    *grid = (struct triangle_grid){.first_slot = mesh->triangle_slot_count, .m = m};
    int needed = mesh->triangle_slot_count + 2 * m * m;
    int *slots = realloc(mesh->triangle_slots, (size_t)needed * sizeof *slots);
    if (!slots) {
        free(index);
        return -1;
    }
    mesh->triangle_slots = slots;
    mesh->triangle_slot_count = needed;
    int status = 0;
    for (int a = 0; a < m && status == 0; a++)
        for (int b = 0; b < m && status == 0; b++) {
            int *slot = &slots[grid->first_slot + 2 * (a * m + b)];
            slot[0] = slot[1] = -1;
            if (a + b <= m - 1) {
                int v[3] = {index[a * (m + 1) + b], index[(a + 1) * (m + 1) + b], index[a * (m + 1) + b + 1]};
                if ((slot[0] = add_cell(mesh, surface_index, v, 3)) < 0)
                    status = -1;
            }
            if (a + b <= m - 2 && status == 0) {
                int v[3] = {index[(a + 1) * (m + 1) + b], index[(a + 1) * (m + 1) + b + 1], index[a * (m + 1) + b + 1]};
                if ((slot[1] = add_cell(mesh, surface_index, v, 3)) < 0)
                    status = -1;
            }
        }
    free(index);
    return status;
}

/* The point of a sphere at polar angle theta (from +y) and azimuth phi. */
static vec3 sphere_point(vec3 center, double radius, double theta, double phi)
{
    return v3_add(center, v3_scale(v3(sin(theta) * cos(phi), cos(theta), sin(theta) * sin(phi)), radius));
}

/* A sphere cut along nu meridians and nv parallels (latitude-longitude):
 * band b, column a is the cell first_cell + b * nu + a, a quad between two
 * parallels (an isosceles trapezoid, so planar) or a triangle at a pole.
 * The cells are flat facets inside the sphere; their points are lifted onto
 * it (patch_mesh_cell_geometry).  Counter-clockwise seen from outside. */
static int mesh_sphere(patch_mesh *m, const surface *surf, int surface_index, double patch_size)
{
    int nu = cells_along(2.0 * M_PI * surf->radius, patch_size), nv = cells_along(M_PI * surf->radius, patch_size);
    nu = nu < 8 ? 8 : nu, nv = nv < 4 ? 4 : nv;
    int top = add_vertex(m, sphere_point(surf->center, surf->radius, 0.0, 0.0)), first_ring = m->vertex_count;
    for (int b = 1; b < nv && top >= 0; b++)
        for (int a = 0; a < nu; a++)
            if (add_vertex(m, sphere_point(surf->center, surf->radius, M_PI * b / nv, 2.0 * M_PI * a / nu)) < 0)
                return -1;
    int bottom = add_vertex(m, sphere_point(surf->center, surf->radius, M_PI, 0.0));
    if (top < 0 || bottom < 0)
        return -1;
    m->quad_grids[surface_index] = (struct quad_grid){.first_cell = m->cell_count,
                                                      .nu = nu,
                                                      .nv = nv,
                                                      .sphere = true,
                                                      .center = surf->center,
                                                      .radius = surf->radius};
    for (int b = 0; b < nv; b++)
        for (int a = 0; a < nu; a++) {
            int ring = first_ring + (b - 1) * nu, next = first_ring + b * nu, a1 = (a + 1) % nu;
            int v[4], count = 0; /* seen from outside: east along the upper parallel, then south, west */
            v[count++] = b == 0 ? top : ring + a;
            if (b > 0)
                v[count++] = ring + a1;
            if (b < nv - 1)
                v[count++] = next + a1;
            v[count++] = b == nv - 1 ? bottom : next + a;
            if (add_cell(m, surface_index, v, count) < 0)
                return -1;
        }
    return 0;
}

double patch_mesh_estimate(const scene *s, double patch_size, const bool *mesh_spheres)
{
    double estimate = 0.0;
    for (int i = 0; i < s->surface_count; i++)
        if (s->surfaces[i].kind != SURFACE_SPHERE)
            estimate += s->surfaces[i].area / (patch_size * patch_size) + s->surfaces[i].triangle_count;
        else if (mesh_spheres && mesh_spheres[i])
            estimate += s->surfaces[i].area / (patch_size * patch_size) + 72.0;
    return estimate;
}

int patch_mesh_build(patch_mesh *m, const scene *s, double patch_size, const bool *mesh_spheres)
{
    m->quad_grids = calloc((size_t)s->surface_count + 1, sizeof *m->quad_grids);
    m->triangle_grids = calloc((size_t)s->triangle_count + 1, sizeof *m->triangle_grids);
    if (!m->quad_grids || !m->triangle_grids)
        return -1;
    for (int i = 0; i < s->surface_count; i++) {
        const surface *surf = &s->surfaces[i];
        m->quad_grids[i].first_cell = -1;
        if (surf->kind == SURFACE_QUAD) {
            if (mesh_quad(m, s, i, patch_size))
                return -1;
        } else if (surf->kind == SURFACE_SPHERE) {
            if (mesh_spheres && mesh_spheres[i] && mesh_sphere(m, surf, i, patch_size))
                return -1;
        } else {
            for (int t = surf->first_triangle; t < surf->first_triangle + surf->triangle_count; t++)
                if (mesh_triangle(m, i, t, &s->triangles[t], patch_size))
                    return -1;
        }
    }
    return 0;
}

/* A point of a cell on its surface: itself on a flat one, lifted along the
 * radius onto a sphere (the facet lies inside it, where rays would start
 * inside the sphere). */
vec3 patch_mesh_on_surface(const patch_mesh *m, int surface, vec3 p)
{
    const struct quad_grid *g = &m->quad_grids[surface];
    if (!g->sphere)
        return p;
    return v3_add(g->center, v3_scale(v3_normalize(v3_sub(p, g->center)), g->radius));
}

/* ---- refinement ----------------------------------------------------------------------- */

/* The midpoint vertex of edge (a, b), shared by the two cells on either side
 * (open-addressing hash table keyed by the edge). */
static int edge_midpoint(patch_mesh *m, int a, int b)
{
    if (a > b) {
        int t = a;
        a = b, b = t;
    }
    if (2 * (m->midpoint_count + 1) > m->midpoint_capacity) {
        int capacity = m->midpoint_capacity ? 2 * m->midpoint_capacity : 1024;
        struct edge_entry *table = malloc((size_t)capacity * sizeof *table);
        if (!table)
            return -1;
        for (int k = 0; k < capacity; k++)
            table[k].a = -1;
        for (int k = 0; k < m->midpoint_capacity; k++) {
            if (m->midpoints[k].a < 0)
                continue;
            uint64_t h = hash64(((uint64_t)m->midpoints[k].a << 32) | (uint64_t)m->midpoints[k].b);
            for (int slot = (int)(h & (uint64_t)(capacity - 1));; slot = (slot + 1) & (capacity - 1))
                if (table[slot].a < 0) {
                    table[slot] = m->midpoints[k];
                    break;
                }
        }
        free(m->midpoints);
        m->midpoints = table, m->midpoint_capacity = capacity;
    }
    uint64_t h = hash64(((uint64_t)a << 32) | (uint64_t)b);
    int mask = m->midpoint_capacity - 1;
    for (int slot = (int)(h & (uint64_t)mask);; slot = (slot + 1) & mask) {
        struct edge_entry *e = &m->midpoints[slot];
        if (e->a == a && e->b == b)
            return e->midpoint;
        if (e->a < 0) {
            int mid = add_vertex(m, v3_scale(v3_add(m->vertices[a], m->vertices[b]), 0.5));
            if (mid < 0)
                return -1;
            *e = (struct edge_entry){a, b, mid};
            m->midpoint_count++;
            return mid;
        }
    }
}

/* Split a leaf cell into four: quads at the edge midpoints and the centre
 * (which is the bilinear midpoint), triangles at the edge midpoints. */
static int split_cell(patch_mesh *m, int cell_index)
{
    mesh_cell c = m->cells[cell_index];
    int mid[4];
    for (int k = 0; k < c.vertex_count; k++) {
        if ((mid[k] = edge_midpoint(m, c.vertex[k], c.vertex[(k + 1) % c.vertex_count])) < 0)
            return -1;
        m->vertices[mid[k]] = patch_mesh_on_surface(m, c.surface, m->vertices[mid[k]]); /* spheres: onto it */
    }
    int first = m->cell_count;
    if (c.vertex_count == 4) {
        vec3 centre = v3_splat(0.0);
        for (int k = 0; k < 4; k++)
            centre = v3_add(centre, v3_scale(m->vertices[c.vertex[k]], 0.25));
        int middle = add_vertex(m, patch_mesh_on_surface(m, c.surface, centre));
        if (middle < 0)
            return -1;
        int children[4][4] = {{c.vertex[0], mid[0], middle, mid[3]},
                              {mid[0], c.vertex[1], mid[1], middle},
                              {middle, mid[1], c.vertex[2], mid[2]},
                              {mid[3], middle, mid[2], c.vertex[3]}};
        for (int k = 0; k < 4; k++)
            if (add_cell(m, c.surface, children[k], 4) < 0)
                return -1;
    } else {
        int children[4][3] = {{c.vertex[0], mid[0], mid[2]},
                              {mid[0], c.vertex[1], mid[1]},
                              {mid[2], mid[1], c.vertex[2]},
                              {mid[0], mid[1], mid[2]}};
        for (int k = 0; k < 4; k++)
            if (add_cell(m, c.surface, children[k], 3) < 0)
                return -1;
    }
    m->cells[cell_index].first_child = first;
    return 0;
}

void patch_mesh_child_values(int vertex_count, const vec3 *parent, int child, vec3 *out)
{
    vec3 mid[4], centre = v3_splat(0.0); /* the values at split_cell's midpoints and centre */
    for (int k = 0; k < vertex_count; k++) {
        mid[k] = v3_scale(v3_add(parent[k], parent[(k + 1) % vertex_count]), 0.5);
        centre = v3_madd(centre, parent[k], 1.0 / vertex_count);
    }
    if (vertex_count == 4) {
        const vec3 children[4][4] = {{parent[0], mid[0], centre, mid[3]},
                                     {mid[0], parent[1], mid[1], centre},
                                     {centre, mid[1], parent[2], mid[2]},
                                     {mid[3], centre, mid[2], parent[3]}};
        memcpy(out, children[child], sizeof children[child]);
    } else {
        const vec3 children[4][3] = {{parent[0], mid[0], mid[2]},
                                     {mid[0], parent[1], mid[1]},
                                     {mid[2], mid[1], parent[2]},
                                     {mid[0], mid[1], mid[2]}};
        memcpy(out, children[child], sizeof children[child]);
    }
}

int patch_mesh_split(patch_mesh *m, int cell)
{
    if (split_cell(m, cell))
        return -1;
    return m->cells[cell].first_child;
}

int patch_mesh_refine(patch_mesh *m, const vec3 *radiance, double relative_threshold)
{
    if (patch_mesh_vertex_radiance(m, radiance))
        return -1;
    double area = 0.0, sum = 0.0; /* mean reflected radiance: the light sources' own glow would swamp it */
    for (int p = 0; p < m->patch_count; p++) {
        area += m->patches[p].area;
        sum += m->patches[p].area * v3_luminance(v3_sub(radiance[p], m->patches[p].emission));
    }
    double threshold = relative_threshold * sum / area;
    int split = 0, patches = m->patch_count;
    for (int p = 0; p < patches; p++) {
        const mesh_cell *c = &m->cells[m->patches[p].cell];
        double corners = 0.0;
        for (int k = 0; k < c->vertex_count; k++)
            corners += v3_luminance(m->vertex_radiance[c->vertex[k]]) / c->vertex_count;
        if (fabs(corners - v3_luminance(radiance[p])) > threshold) {
            if (split_cell(m, m->patches[p].cell))
                return -1;
            split++;
        }
    }
    return split;
}

/* ---- patches ------------------------------------------------------------------------- */

static double triangle_area_of(vec3 a, vec3 b, vec3 c) { return 0.5 * v3_length(v3_cross(v3_sub(b, a), v3_sub(c, a))); }

/* Quadrature points of a patch for the outer integral of a form factor:
 * each triangle of the patch (a quad is the fan (0,1,2), (0,2,3)) is cut
 * into M^2 equal sub-triangles whose centroids get equal weight. */
static int add_quadrature_points(patch_mesh *m, patch *p, int M)
{
    p->first_point = m->point_count;
    p->point_count = 0;
    for (int t = 1; t + 1 < p->corner_count; t++) {
        vec3 a = p->corner[0], e1 = v3_sub(p->corner[t], a), e2 = v3_sub(p->corner[t + 1], a);
        double weight = triangle_area_of(p->corner[0], p->corner[t], p->corner[t + 1]) / p->area / (M * M);
        for (int i = 0; i < M; i++)
            for (int j = 0; i + j < M; j++)
                for (int down = 0; down < 2; down++) {
                    if (down && i + j > M - 2)
                        continue;
                    double u = (3.0 * i + 1.0 + down) / (3.0 * M), v = (3.0 * j + 1.0 + down) / (3.0 * M);
                    if (grow((void **)&m->points, &m->point_capacity, m->point_count + 1, sizeof *m->points) ||
                        grow((void **)&m->weights, &m->weight_capacity, m->point_count + 1, sizeof *m->weights))
                        return -1;
                    m->points[m->point_count] =
                        patch_mesh_on_surface(m, p->surface, v3_add(a, v3_add(v3_scale(e1, u), v3_scale(e2, v))));
                    m->weights[m->point_count++] = weight;
                    p->point_count++;
                }
    }
    return 0;
}

bool patch_in_front(const patch *p, vec3 origin, vec3 n, double epsilon)
{
    for (int k = 0; k < p->corner_count; k++)
        if (v3_dot(n, v3_sub(p->corner[k], origin)) > epsilon)
            return true;
    return false;
}

bool patches_facing(const patch *a, const patch *b, double epsilon)
{
    return patch_in_front(b, a->centroid, a->normal, epsilon) && patch_in_front(a, b->centroid, b->normal, epsilon);
}

double form_factor_kernel(vec3 x, vec3 nx, vec3 y, vec3 ny)
{
    vec3 d = v3_sub(y, x);
    double r2 = v3_dot(d, d);
    return r2 > 0.0 ? fmax(0.0, v3_dot(nx, d)) * fmax(0.0, -v3_dot(ny, d)) / (r2 * r2) : 0.0;
}

void patch_mesh_cell_geometry(const patch_mesh *m, int c, patch *p)
{
    const mesh_cell *cell = &m->cells[c];
    *p = (patch){.cell = c, .surface = cell->surface, .corner_count = cell->vertex_count};
    for (int k = 0; k < cell->vertex_count; k++)
        p->corner[k] = m->vertices[cell->vertex[k]];
    vec3 twice_area = v3_splat(0.0), centroid = v3_splat(0.0);
    for (int t = 1; t + 1 < p->corner_count; t++) {
        vec3 cross = v3_cross(v3_sub(p->corner[t], p->corner[0]), v3_sub(p->corner[t + 1], p->corner[0]));
        double area = 0.5 * v3_length(cross);
        twice_area = v3_add(twice_area, cross);
        p->area += area;
        centroid = v3_add(centroid, v3_scale(v3_add(p->corner[0], v3_add(p->corner[t], p->corner[t + 1])), area / 3.0));
    }
    p->normal = v3_normalize(twice_area);
    p->centroid = v3_scale(centroid, 1.0 / p->area);
    for (int k = 0; k < p->corner_count; k++)
        p->radius = fmax(p->radius, v3_length(v3_sub(p->corner[k], p->centroid)));
    p->centroid = patch_mesh_on_surface(m, p->surface, p->centroid);
}

int patch_mesh_collect(patch_mesh *m, int quadrature)
{
    free(m->patches);
    m->patches = NULL;
    m->patch_count = 0;
    m->point_count = 0;
    int leaves = 0;
    for (int c = 0; c < m->cell_count; c++)
        leaves += m->cells[c].first_child < 0;
    m->patches = calloc((size_t)leaves + 1, sizeof *m->patches);
    if (!m->patches)
        return -1;
    for (int c = 0; c < m->cell_count; c++) {
        mesh_cell *cell = &m->cells[c];
        cell->patch = -1;
        if (cell->first_child >= 0)
            continue;
        patch *p = &m->patches[m->patch_count];
        patch_mesh_cell_geometry(m, c, p);
        p->unburied = 1.0;
        if (add_quadrature_points(m, p, quadrature))
            return -1;
        cell->patch = m->patch_count++;
    }
    return 0;
}

/* ---- the image ------------------------------------------------------------------------- */

int patch_mesh_vertex_radiance(patch_mesh *m, const vec3 *radiance)
{
    free(m->vertex_radiance);
    m->vertex_radiance = calloc((size_t)m->vertex_count + 1, sizeof *m->vertex_radiance);
    double *weight = calloc((size_t)m->vertex_count + 1, sizeof *weight);
    if (!m->vertex_radiance || !weight) {
        free(weight);
        return -1;
    }
    for (int p = 0; p < m->patch_count; p++) {
        const mesh_cell *c = &m->cells[m->patches[p].cell];
        for (int k = 0; k < c->vertex_count; k++) {
            m->vertex_radiance[c->vertex[k]] =
                v3_madd(m->vertex_radiance[c->vertex[k]], radiance[p], m->patches[p].area);
            weight[c->vertex[k]] += m->patches[p].area;
        }
    }
    for (int v = 0; v < m->vertex_count; v++)
        if (weight[v] > 0.0)
            m->vertex_radiance[v] = v3_scale(m->vertex_radiance[v], 1.0 / weight[v]);
    free(weight);
    return 0;
}

/* Is edge (a, b) an edge of a leaf cell?  An open-addressing set of the
 * leaves' edges, both ends in ascending order. */
static long edge_slot(const int64_t *set, long mask, int a, int b)
{
    int64_t key = ((int64_t)(a < b ? a : b) << 32) | (int64_t)(a < b ? b : a);
    long slot = (long)(hash64((uint64_t)key) & (uint64_t)mask);
    while (set[slot] >= 0 && set[slot] != key)
        slot = (slot + 1) & mask;
    return slot;
}

/* Is (a, b) half of an edge whole on one side: a the midpoint of (b, x) or (x, b)? */
static bool half_of_whole(const int *midpoint_of, const unsigned char *whole, int a, int b)
{
    return midpoint_of[2 * a] >= 0 && whole[a] && (midpoint_of[2 * a] == b || midpoint_of[2 * a + 1] == b);
}

int patch_mesh_smooth_radiance(patch_mesh *m, const vec3 *radiance)
{
    if (patch_mesh_vertex_radiance(m, radiance))
        return -1;
    if (m->midpoint_count == 0)
        return 0; /* never split: no vertex lies inside an edge */
    long capacity = 1;
    while (capacity < 8L * m->patch_count + 16)
        capacity *= 2;
    int64_t *set = malloc((size_t)capacity * sizeof *set);
    int *midpoint_of = malloc((size_t)m->vertex_count * 2 * sizeof *midpoint_of + 1);
    if (!set || !midpoint_of) {
        free(set), free(midpoint_of);
        return -1;
    }
    memset(set, 0xff, (size_t)capacity * sizeof *set);
    for (int p = 0; p < m->patch_count; p++) {
        const mesh_cell *c = &m->cells[m->patches[p].cell];
        for (int k = 0; k < c->vertex_count; k++) {
            int a = c->vertex[k], b = c->vertex[(k + 1) % c->vertex_count];
            set[edge_slot(set, capacity - 1, a, b)] = ((int64_t)(a < b ? a : b) << 32) | (int64_t)(a < b ? b : a);
        }
    }
    /* A midpoint on a leaf's edge is a T-vertex: the leaf interpolates linearly
     * along that edge, so the vertex takes the mean of the edge's ends.  So is
     * a midpoint of half of such an edge (split again on the other side), and
     * so on: an edge is "whole on one side" if a leaf has it or it is half of
     * one that is.  A midpoint is made after its edge's ends, so in the order
     * of the vertices every end is settled before the midpoints that use it. */
    for (int v = 0; v < m->vertex_count; v++)
        midpoint_of[2 * v] = midpoint_of[2 * v + 1] = -1;
    for (int k = 0; k < m->midpoint_capacity; k++)
        if (m->midpoints[k].a >= 0)
            midpoint_of[2 * m->midpoints[k].midpoint] = m->midpoints[k].a,
                            midpoint_of[2 * m->midpoints[k].midpoint + 1] = m->midpoints[k].b;
    unsigned char *whole = calloc((size_t)m->vertex_count + 1, 1); /* per midpoint: its edge is whole on one side */
    if (!whole) {
        free(set), free(midpoint_of);
        return -1;
    }
    for (int v = 0; v < m->vertex_count; v++) {
        int a = midpoint_of[2 * v], b = midpoint_of[2 * v + 1];
        if (a < 0)
            continue;
        whole[v] = set[edge_slot(set, capacity - 1, a, b)] >= 0 || half_of_whole(midpoint_of, whole, a, b) ||
                   half_of_whole(midpoint_of, whole, b, a);
        if (whole[v])
            m->vertex_radiance[v] = v3_scale(v3_add(m->vertex_radiance[a], m->vertex_radiance[b]), 0.5);
    }
    free(whole);
    free(set), free(midpoint_of);
    return 0;
}

/* Is p inside the convex cell (in its plane)?  The signed areas of p with
 * every edge must agree with the normal. */
static bool cell_contains(const patch_mesh *m, const mesh_cell *c, vec3 normal, vec3 p)
{
    for (int k = 0; k < c->vertex_count; k++) {
        vec3 a = m->vertices[c->vertex[k]], b = m->vertices[c->vertex[(k + 1) % c->vertex_count]];
        if (v3_dot(v3_cross(v3_sub(b, a), v3_sub(p, a)), normal) < -1e-9 * v3_dot(v3_sub(b, a), v3_sub(b, a)))
            return false;
    }
    return true;
}

/* The top-level cell under a hit, then down the refinement tree to its leaf. */
int patch_mesh_locate(const patch_mesh *m, const scene *s, const hit *h)
{
    const surface *surf = &s->surfaces[h->surface];
    int cell;
    if (surf->kind == SURFACE_QUAD) {
        const struct quad_grid *g = &m->quad_grids[h->surface];
        double u, v;
        inverse_bilinear(surf->vertex, s->triangles[surf->first_triangle].normal, h->point, &u, &v);
        int a = (int)fmin(g->nu - 1, u * g->nu), b = (int)fmin(g->nv - 1, v * g->nv);
        cell = g->first_cell + b * g->nu + a;
    } else if (surf->kind == SURFACE_SPHERE) { /* latitude and longitude of the hit */
        const struct quad_grid *g = &m->quad_grids[h->surface];
        vec3 d = v3_normalize(v3_sub(h->point, g->center));
        double theta = acos(fmin(1.0, fmax(-1.0, d.y))), phi = atan2(d.z, d.x);
        phi = phi < 0.0 ? phi + 2.0 * M_PI : phi;
        int a = (int)fmin(g->nu - 1, phi / (2.0 * M_PI) * g->nu), b = (int)fmin(g->nv - 1, theta / M_PI * g->nv);
        cell = g->first_cell + b * g->nu + a;
    } else {
        const triangle *t = &s->triangles[h->primitive];
        const struct triangle_grid *g = &m->triangle_grids[h->primitive];
        vec3 d = v3_sub(h->point, t->p0);
        double d11 = v3_dot(t->e1, t->e1), d12 = v3_dot(t->e1, t->e2), d22 = v3_dot(t->e2, t->e2);
        double p1 = v3_dot(d, t->e1), p2 = v3_dot(d, t->e2), det = d11 * d22 - d12 * d12;
        double u = fmax(0.0, (d22 * p1 - d12 * p2) / det) * g->m, v = fmax(0.0, (d11 * p2 - d12 * p1) / det) * g->m;
        int a = (int)fmin(g->m - 1, floor(u)), b = (int)fmin(g->m - 1 - a, floor(v));
        bool down = u - a + v - b > 1.0 && a + b <= g->m - 2;
        cell = m->triangle_slots[g->first_slot + 2 * (a * g->m + b) + down];
    }
    vec3 normal = h->normal;
    while (m->cells[cell].first_child >= 0) {
        int first = m->cells[cell].first_child, next = first + 3; /* rounding: the last child by default */
        for (int k = 0; k < 4; k++)
            if (cell_contains(m, &m->cells[first + k], normal, h->point)) {
                next = first + k;
                break;
            }
        cell = next;
    }
    return cell;
}

vec3 patch_mesh_interpolate(const patch_mesh *m, int cell, vec3 normal, vec3 p)
{
    const mesh_cell *c = &m->cells[cell];
    const vec3 *R = m->vertex_radiance;
    if (c->vertex_count == 4) {
        vec3 q[4];
        for (int k = 0; k < 4; k++)
            q[k] = m->vertices[c->vertex[k]];
        double u, v;
        inverse_bilinear(q, normal, p, &u, &v);
        return v3_add(v3_add(v3_scale(R[c->vertex[0]], (1 - u) * (1 - v)), v3_scale(R[c->vertex[1]], u * (1 - v))),
                      v3_add(v3_scale(R[c->vertex[2]], u * v), v3_scale(R[c->vertex[3]], (1 - u) * v)));
    }
    vec3 a = m->vertices[c->vertex[0]], b = m->vertices[c->vertex[1]], cc = m->vertices[c->vertex[2]];
    double area = v3_dot(v3_cross(v3_sub(b, a), v3_sub(cc, a)), normal);
    double wa = v3_dot(v3_cross(v3_sub(b, p), v3_sub(cc, p)), normal) / area;
    double wb = v3_dot(v3_cross(v3_sub(cc, p), v3_sub(a, p)), normal) / area;
    double wc = 1.0 - wa - wb;
    return v3_add(v3_add(v3_scale(R[c->vertex[0]], wa), v3_scale(R[c->vertex[1]], wb)), v3_scale(R[c->vertex[2]], wc));
}

vec3 patch_mesh_seen(const patch_mesh *m, const scene *s, ray r, const vec3 *radiance, bool smooth, bool *back)
{
    hit h;
    if (!scene_intersect(s, r, INFINITY, &h))
        return s->background;
    if ((s->surfaces[h.surface].kind == SURFACE_SPHERE && m->quad_grids[h.surface].first_cell < 0) || !radiance)
        return v3_splat(0.0); /* an unmeshed sphere */
    if (v3_dot(h.normal, r.direction) >= 0.0) {
        *back = true;
        return v3_splat(0.0);
    }
    int cell = patch_mesh_locate(m, s, &h);
    return smooth ? patch_mesh_interpolate(m, cell, h.normal, h.point) : radiance[m->cells[cell].patch];
}

double patch_mesh_power(const patch_mesh *m, const vec3 *x)
{
    double sum = 0.0;
    for (int i = 0; i < m->patch_count; i++)
        sum += m->patches[i].area * (fabs(x[i].x) + fabs(x[i].y) + fabs(x[i].z));
    return sum;
}

void patch_mesh_add_ambient(const patch_mesh *m, const vec3 *unshot, vec3 *L)
{
    double area = 0.0, rho_area = 0.0;
    vec3 unshot_area = v3_splat(0.0);
    for (int i = 0; i < m->patch_count; i++) {
        area += m->patches[i].area;
        rho_area += m->patches[i].area * v3_average(m->patches[i].albedo);
        unshot_area = v3_madd(unshot_area, unshot[i], m->patches[i].area);
    }
    double rho_average = rho_area / area;
    vec3 ambient = v3_scale(unshot_area, 1.0 / (area * (1.0 - rho_average)));
    for (int i = 0; i < m->patch_count; i++)
        L[i] = v3_add(L[i], v3_add(unshot[i], v3_mul(m->patches[i].albedo, ambient)));
}

uint64_t patch_mesh_point_lights(const patch_mesh *m, const scene *s, vec3 *irradiance_out)
{
    uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : rays)
    for (int i = 0; i < m->patch_count; i++) {
        const patch *p = &m->patches[i];
        vec3 irradiance = v3_splat(0.0);
        for (int l = 0; l < s->light_count; l++)
            for (int k = 0; k < p->point_count; k++) {
                vec3 x = m->points[p->first_point + k];
                vec3 to_light = v3_sub(s->lights[l].position, x);
                double r2 = v3_dot(to_light, to_light), cos_theta = v3_dot(p->normal, to_light) / sqrt(r2);
                if (cos_theta <= 0.0)
                    continue;
                rays++;
                if (!scene_occluded(s, x, s->lights[l].position))
                    irradiance = v3_add(
                        irradiance, v3_scale(s->lights[l].intensity, m->weights[p->first_point + k] * cos_theta / r2));
            }
        irradiance_out[i] = irradiance;
    }
    return rays;
}

vec3 patch_mesh_irradiance(const patch_mesh *m, const scene *s, const vec3 *radiance, vec3 x, vec3 n, bool point_lights,
                           point_to_polygon_fn point_to_polygon)
{
    vec3 total = v3_splat(0.0);
    if (point_lights)
        for (int l = 0; l < s->light_count; l++) {
            vec3 d = v3_sub(s->lights[l].position, x);
            double r2 = v3_dot(d, d), cos_theta = v3_dot(n, d) / sqrt(r2);
            if (cos_theta > 0.0 && !scene_occluded(s, x, s->lights[l].position))
                total = v3_madd(total, s->lights[l].intensity, cos_theta / r2);
        }
    for (int j = 0; j < m->patch_count; j++) {
        const patch *p = &m->patches[j];
        if (v3_dot(p->normal, v3_sub(x, p->centroid)) <= s->epsilon)
            continue; /* behind the one-sided patch */
        double f = point_to_polygon(x, n, p->corner, p->corner_count);
        if (f <= 0.0)
            continue;
        /* Visibility by rays to the points of j in front of x, the part f counts
         * (a ray to the part clipped away, behind the probe, meets the probe's own
         * solid: a probe on a box's side 1 mm above the floor read 15 % low).
         * Each ray counts with the kernel it carries, sum w G V / sum w G, as the
         * form factors do: through a slit the rays that pass graze, and a plain
         * fraction of rays would count them as if they carried their share. */
        double carried = 0.0, visible = 0.0;
        int in_front = 0, passed = 0;
        for (int k = 0; k < p->point_count; k++) {
            vec3 y = m->points[p->first_point + k];
            if (v3_dot(n, v3_sub(y, x)) <= s->epsilon)
                continue;
            double g = m->weights[p->first_point + k] * form_factor_kernel(x, n, y, p->normal);
            bool open = !scene_occluded(s, x, y);
            in_front++;
            passed += open;
            carried += g;
            visible += open ? g : 0.0;
        }
        if (in_front == 0)
            continue;
        /* the plain fraction only where no ray carries any kernel */
        double visible_part = carried > 0.0 ? visible / carried : (double)passed / in_front;
        total = v3_madd(total, radiance[j], M_PI * f * visible_part);
    }
    return total;
}

void patch_mesh_free(patch_mesh *m)
{
    free(m->vertices), free(m->cells), free(m->patches), free(m->points), free(m->weights);
    free(m->vertex_radiance), free(m->quad_grids), free(m->triangle_grids), free(m->triangle_slots);
    free(m->midpoints);
    *m = (patch_mesh){0};
}
