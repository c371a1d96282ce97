/* hierarchy.c — the hierarchical solver's bookkeeping (hierarchy.h); nothing here is the lecture. */
#include "hierarchy.h"
#include "rng.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* How far above an element, in its radii, something covers it (COVER_REACH),
 * and where the rays start (as the oracle's EDGE_INSET). */
static const double COVER_REACH = 2.0, COVER_INSET = 0.9;

/* Is something close above e (a box resting on, or 1 mm above, part of a
 * floor element)?  Rays along the normal from its centroid and near its
 * corners: blocked within COVER_REACH radii or from inside a solid (they
 * meet a back face first).  COVERED_PART when some are blocked and some
 * not, COVERED_ALL when all are, else 0 (hierarchy.h). */
static unsigned char covered(const patch_mesh *m, const scene *s, const patch *e)
{
    vec3 mean = element_corner_mean(e);
    int blocked = 0, open = 0;
    for (int k = -1; k < e->corner_count; k++) {
        vec3 x = k < 0 ? e->centroid : element_toward_corner(m, e, mean, k, COVER_INSET);
        hit first;
        ray up = {scene_offset_origin(s, x, e->normal, e->normal), e->normal};
        if (scene_intersect(s, up, INFINITY, &first) &&
            (first.t < COVER_REACH * e->radius || v3_dot(first.normal, e->normal) > 0.0)) /* or inside a solid */
            blocked++;
        else
            open++;
    }
    return !blocked ? 0 : open ? COVERED_PART : COVERED_ALL;
}

int hierarchy_track_new_cells(hierarchy *h, const patch_mesh *m, const scene *s)
{
    if (m->cell_count > h->capacity) {
        int capacity = h->capacity ? h->capacity : 256;
        while (capacity < m->cell_count)
            capacity *= 2;
        patch *element = realloc(h->element, (size_t)capacity * sizeof *element);
        if (element)
            h->element = element;
        unsigned char *level = realloc(h->level, (size_t)capacity);
        if (level)
            h->level = level;
        unsigned char *covered = realloc(h->covered, (size_t)capacity);
        if (covered)
            h->covered = covered;
        int *parent = realloc(h->parent, (size_t)capacity * sizeof *parent);
        if (parent)
            h->parent = parent;
        if (!element || !level || !covered || !parent)
            return -1;
        h->capacity = capacity;
    }
    for (; h->element_count < m->cell_count; h->element_count++) {
        patch *e = &h->element[h->element_count];
        patch_mesh_cell_geometry(m, h->element_count, e);
        radiosity_material(s, e->surface, &e->albedo, &e->emission);
        h->covered[h->element_count] = covered(m, s, e);
        h->level[h->element_count] = 0, h->parent[h->element_count] = -1;
    }
    return 0;
}

int refiner_children(refiner *r, int e)
{
    if (r->m->cells[e].first_child >= 0)
        return r->m->cells[e].first_child;
    if (r->m->cell_count + 4 > ELEMENT_LIMIT) {
        r->failed = 3;
        return -1;
    }
    int first = patch_mesh_split(r->m, e);
    if (first < 0 || hierarchy_track_new_cells(r->h, r->m, r->s))
        return -1;
    for (int k = 0; k < 4; k++)
        r->h->level[first + k] = (unsigned char)(r->h->level[e] + 1), r->h->parent[first + k] = e;
    return first;
}

void refiner_add_link(refiner *r, int p, int q, float known_F)
{
    if (r->count == r->capacity) {
        long capacity = r->capacity ? 2 * r->capacity : 4096;
        if (capacity > LINK_LIMIT)
            capacity = LINK_LIMIT;
        if (r->count == capacity) {
            r->failed = 2;
            return;
        }
        int *receiver = realloc(r->receiver, (size_t)capacity * sizeof *receiver);
        if (receiver)
            r->receiver = receiver;
        int *source = realloc(r->source, (size_t)capacity * sizeof *source);
        if (source)
            r->source = source;
        float *known_F = realloc(r->known_F, (size_t)capacity * sizeof *known_F);
        if (known_F)
            r->known_F = known_F;
        if (!receiver || !source || !known_F) {
            r->failed = 1;
            return;
        }
        r->capacity = capacity;
    }
    r->known_F[r->count] = known_F;
    r->receiver[r->count] = p, r->source[r->count++] = q;
}

int pairs_push_children(pair **next, long *count, long *capacity, pair t, bool split_source, int first)
{
    if (*count + 4 > *capacity) {
        long grown = *capacity ? 2 * *capacity : 4096;
        pair *bigger = realloc(*next, (size_t)grown * sizeof *bigger);
        if (!bigger)
            return -1;
        *next = bigger, *capacity = grown;
    }
    for (int k = 0; k < 4; k++)
        (*next)[(*count)++] = split_source ? (pair){t.p, first + k, -1.0f} : (pair){first + k, t.q, -1.0f};
    return 0;
}

int hierarchy_group_links(hierarchy *h, const refiner *r)
{
    long n = r->count;
    h->link_start = calloc((size_t)h->element_count + 1, sizeof *h->link_start);
    h->link_source = malloc((size_t)n * sizeof *h->link_source + 1);
    h->link_F = malloc((size_t)n * sizeof *h->link_F + 1);
    long *next = malloc((size_t)h->element_count * sizeof *next + 1);
    if (!h->link_start || !h->link_source || !h->link_F || !next)
        return free(next), -1;
    for (long k = 0; k < n; k++)
        h->link_start[r->receiver[k] + 1]++;
    for (int e = 0; e < h->element_count; e++)
        h->link_start[e + 1] += h->link_start[e];
    memcpy(next, h->link_start, (size_t)h->element_count * sizeof *next);
    for (long k = 0; k < n; k++) {
        h->link_F[next[r->receiver[k]]] = r->known_F[k];
        h->link_source[next[r->receiver[k]]++] = r->source[k];
    }
    free(next);
    h->link_count = n;
    return 0;
}

vec3 element_corner_mean(const patch *e)
{
    vec3 mean = v3_splat(0.0);
    for (int k = 0; k < e->corner_count; k++)
        mean = v3_add(mean, v3_scale(e->corner[k], 1.0 / e->corner_count));
    return mean;
}

vec3 element_toward_corner(const patch_mesh *m, const patch *e, vec3 mean, int k, double t)
{
    return patch_mesh_on_surface(m, e->surface, v3_add(mean, v3_scale(v3_sub(e->corner[k], mean), t)));
}

vec3 element_point_in_front(const patch *q, vec3 origin, vec3 n, double epsilon)
{
    vec3 sum = v3_splat(0.0);
    int count = 0;
    for (int k = 0; k < q->corner_count; k++) {
        vec3 a = q->corner[k], b = q->corner[(k + 1) % q->corner_count];
        double ha = v3_dot(n, v3_sub(a, origin)), hb = v3_dot(n, v3_sub(b, origin));
        if (ha > epsilon) {
            sum = v3_add(sum, a);
            count++;
        }
        if ((ha > epsilon) != (hb > epsilon)) { /* where the edge crosses the plane */
            sum = v3_add(sum, v3_add(a, v3_scale(v3_sub(b, a), (ha - epsilon) / (ha - hb))));
            count++;
        }
    }
    return count ? v3_scale(sum, 1.0 / count) : q->centroid;
}

int element_sample_points(const patch_mesh *m, const patch *e, vec3 *out)
{
    vec3 mean = element_corner_mean(e);
    for (int k = 0; k < e->corner_count; k++)
        out[k] = element_toward_corner(m, e, mean, k, 0.5);
    return e->corner_count;
}

int element_stratified_points(const patch_mesh *m, const patch *e, uint64_t salt, vec3 *out)
{
    vec3 mean = element_corner_mean(e);
    int n = e->corner_count;
    for (int k = 0; k < n; k++) {
        uint64_t bits = hash64(salt ^ (uint64_t)k * 0x9e3779b97f4a7c15ull);
        double u = (double)(bits >> 40) / (double)(1ull << 24), v = (double)(bits & 0xffffff) / (double)(1ull << 24);
        vec3 corner = e->corner[k], next = v3_scale(v3_add(corner, e->corner[(k + 1) % n]), 0.5),
             previous = v3_scale(v3_add(corner, e->corner[(k + n - 1) % n]), 0.5);
        vec3 x = v3_add(v3_add(v3_scale(corner, (1 - u) * (1 - v)), v3_scale(next, u * (1 - v))),
                        v3_add(v3_scale(mean, u * v), v3_scale(previous, (1 - u) * v))); /* bilinear over the kite */
        out[k] = patch_mesh_on_surface(m, e->surface, x);
    }
    return n;
}

bool element_point_buried(const scene *s, vec3 x, vec3 n)
{
    hit first;
    ray along_normal = {scene_offset_origin(s, x, n, n), n};
    return scene_intersect(s, along_normal, INFINITY, &first) && v3_dot(first.normal, n) > 0.0;
}

/* Points per side of the grid on which a quad leaf's unburied fraction is measured
 * (a leaf across a box's edge by a fifth of its width was measured buried
 * from its centroid and four points). */
enum { UNBURIED_GRID = 4 };

/* The fraction of element e's area outside every solid: a leaf's from a
 * grid of points (a triangle's: its centroid and sample points), a parent's the area-weighted mean of its
 * children's. */
static double unburied_fraction(hierarchy *h, const patch_mesh *m, const scene *s, int e)
{
    const mesh_cell *c = &m->cells[e];
    const patch *element = &h->element[e];
    double unburied = 0.0;
    if (c->first_child < 0 && e < h->unburied_count)
        return h->unburied[e];                              /* a leaf measured by an earlier call, still a leaf */
    if (c->first_child < 0 && element->corner_count == 4) { /* a 4 x 4 grid over the cell */
        const vec3 *q = element->corner;
        for (int i = 0; i < UNBURIED_GRID; i++)
            for (int j = 0; j < UNBURIED_GRID; j++) {
                double u = (i + 0.5) / UNBURIED_GRID, v = (j + 0.5) / UNBURIED_GRID;
                vec3 x = v3_add(v3_scale(v3_add(v3_scale(q[0], 1 - u), v3_scale(q[1], u)), 1 - v),
                                v3_scale(v3_add(v3_scale(q[3], 1 - u), v3_scale(q[2], u)), v));
                x = patch_mesh_on_surface(m, element->surface, x);
                unburied += !element_point_buried(s, x, element->normal) / (double)(UNBURIED_GRID * UNBURIED_GRID);
            }
    } else if (c->first_child < 0) {
        vec3 point[5];
        int count = element_sample_points(m, element, point);
        point[count++] = element->centroid;
        for (int k = 0; k < count; k++)
            unburied += !element_point_buried(s, point[k], element->normal) / (double)count;
    } else {
        for (int k = c->first_child; k < c->first_child + 4; k++)
            unburied += unburied_fraction(h, m, s, k) * h->element[k].area / element->area;
    }
    h->unburied[e] = (float)unburied;
    return unburied;
}

int hierarchy_measure_unburied(hierarchy *h, const patch_mesh *m, const scene *s)
{
    float *unburied = realloc(h->unburied, (size_t)h->element_count * sizeof *unburied + 1);
    if (!unburied)
        return -1;
    h->unburied = unburied;
#pragma omp parallel for schedule(dynamic, 1)
    for (int root = 0; root < h->root_count; root++)
        unburied_fraction(h, m, s, root);
    h->unburied_count = h->element_count;
    return 0;
}

double hierarchy_link_shape(const hierarchy *h, int e, long k, int j)
{
    if (h->link_shape && h->shape_start[e] >= 0)
        return h->link_shape[4 * (h->shape_start[e] + k - h->link_start[e]) + j];
    return h->unburied[e] > 0.0; /* F is the mean over the exposed part already (link_form_factor) */
}

/* Each exposed leaf's row sum: what it gathers, as push_pull gives it,
 * when every element has radiance 1 and albedo 1 (in x). */
static void hierarchy_row_sums(const hierarchy *h, const patch_mesh *m, int e, const vec3 *above,
                               radiosity_stats *stats)
{
    const mesh_cell *c = &m->cells[e];
    vec3 here[4];
    double row = 0.0;
    for (int j = 0; j < c->vertex_count; j++) {
        here[j] = above[j];
        for (long k = h->link_start[e]; k < h->link_start[e + 1]; k++)
            here[j].x += h->link_F[k] * hierarchy_link_shape(h, e, k, j);
        row += here[j].x / c->vertex_count;
    }
    if (c->first_child < 0 && h->unburied[e] > 0.0) {
        stats->row_sum_min = fmin(stats->row_sum_min, row);
        stats->row_sum_max = fmax(stats->row_sum_max, row);
    }
    for (int k = 0; c->first_child >= 0 && k < 4; k++) {
        vec3 below[4];
        patch_mesh_child_values(c->vertex_count, here, k, below);
        hierarchy_row_sums(h, m, c->first_child + k, below, stats);
    }
}

void hierarchy_report(const hierarchy *h, const patch_mesh *m, radiosity_stats *stats)
{
    stats->elements = h->element_count, stats->links = h->link_count, stats->levels = 0;
    stats->have_matrix_checks = true, stats->row_sum_min = INFINITY, stats->row_sum_max = 0.0;
    for (int root = 0; root < h->root_count; root++)
        hierarchy_row_sums(h, m, root, (vec3[4]){{0}}, stats);
    long shaped = 0; /* links with a shape: a split receiver's (hierarchy_shape_links) */
    for (int e = 0; e < h->element_count; e++) {
        stats->levels = stats->levels > h->level[e] ? stats->levels : h->level[e];
        shaped += h->shape_start && h->shape_start[e] >= 0 ? h->link_start[e + 1] - h->link_start[e] : 0;
    }
    stats->hierarchy_bytes = (double)h->element_count * (sizeof(patch) + sizeof(mesh_cell) + 2 * sizeof(vec3) + 1 +
                                                         2 * sizeof(long) + sizeof(int) + sizeof(float)) +
                             (double)m->vertex_count * sizeof(vec3) +
                             (double)h->link_count * (sizeof(int) + sizeof(float)) + (double)shaped * 4 * sizeof(float);
}

void hierarchy_free(hierarchy *h)
{
    free(h->element);
    free(h->level);
    free(h->covered);
    free(h->parent);
    free(h->unburied);
    free(h->gathered);
    free(h->link_start);
    free(h->link_source);
    free(h->link_F);
    free(h->link_shape);
    free(h->shape_start);
    *h = (hierarchy){0};
}
