/* hierarchy_links.c — what makes chapter 03c's links accurate, and cheap
 * enough: their form factors, their shapes across the receiver, the
 * shadow-edge test, the second pass's measures, the limits (hierarchy.h).
 * Nothing here is the lecture: chapters/03c_hierarchical.c is. */
#include "hierarchy.h"

#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>

/* Pairs closer than this many radii are integrated at quadrature points (as chapter 3's NEAR_FACTOR). */
static const double NEAR_FACTOR = 6.0;


/* The second pass weighs F by a source's radiance over the scene's mean
 * reflected radiance, at most this much.  The Cornell box's light is about
 * 165 times the mean; a light a hundredth its size and a hundred times as
 * bright (scenes/cornell-small-light.scene) 16,500 times, and weighing its
 * links by that split every receiver and the light to --levels (over 40 M
 * links at --eps 2e-2), though its form factors are accurate long before. */
static const double BRIGHTNESS_CAP = 256.0;


/* Where a pair's visibility points are drawn (element_stratified_points):
 * from the pair alone, so the same at any --threads. */
static uint64_t pair_salt(int p, int q) { return hash64((uint64_t)(unsigned)p << 32 | (unsigned)q); }

/* The visible part of F_pq from up to four rays between the two elements,
 * each weighted by the kernel cos cos / r^2 it carries (form_factor_kernel):
 * the plain fraction of rays not blocked would take the rays that pass for
 * typical ones.  Through the 1 mm slit under a floating box only the rays to
 * the walls' feet pass, grazing the floor: the plain fraction put 4.6 times
 * the walls' light into the cavity (16 % of the rays pass, 3.5 % of F).
 * Only pairs of sample points in front of each other's element count: a ray
 * to a point behind the receiver's plane would run into the receiver's own
 * solid, which Lambert's clipped formula has already left out.  No such
 * pair: 1 (the pair hardly exchanges light). */
static double visible_fraction(const patch_mesh *m, const scene *s, const patch *ep, const patch *eq, uint64_t salt,
                               uint64_t *rays)
{
    vec3 a[4], b[4];
    int na = element_stratified_points(m, ep, salt, a), nb = element_stratified_points(m, eq, ~salt, b);
    int tested = 0;
    double visible = 0.0, all = 0.0;
    for (int k = 0; k < na * nb && tested < 4; k++) {
        vec3 x = a[k % na], y = b[(k + k / na) % nb]; /* the diagonal pairs first, then shifted */
        if (v3_dot(ep->normal, v3_sub(y, ep->centroid)) <= s->epsilon ||
            v3_dot(eq->normal, v3_sub(x, eq->centroid)) <= s->epsilon)
            continue;
        tested++;
        double weight = form_factor_kernel(x, ep->normal, y, eq->normal);
        all += weight;
        if (!scene_occluded(s, x, y))
            visible += weight;
    }
    *rays += (uint64_t)tested;
    return all > 0.0 ? visible / all : 1.0;
}

/* Where shadow_edge's rays start: near the corners, so that a shadow along
 * an element's edge (a box's own shadow at its base) is seen. */
static const double EDGE_INSET = 0.9;

/* Count the ray from x on element a to y on element b as visible or blocked,
 * if each end is in front of the other's element (see visible_fraction). */
static void count_ray(const scene *s, const patch *a, vec3 x, const patch *b, vec3 y, int *visible, int *blocked)
{
    if (v3_dot(b->normal, v3_sub(x, b->centroid)) <= s->epsilon ||
        v3_dot(a->normal, v3_sub(y, a->centroid)) <= s->epsilon)
        return;
    scene_occluded(s, x, y) ? ++*blocked : ++*visible;
}

/* Where does a shadow edge cross the pair?  Across the receiver when its
 * corners (EDGE_INSET of the way from its centre) see different numbers of
 * q's four stratified points: what its links' linear shapes cannot follow
 * (a box's shadow on the floor beside it).  Else across the source when,
 * of the rays from q's corners to p's centroid and between the centroids,
 * some are blocked and some not.  At most 21 rays. */
enum shadow_side shadow_edge(const refiner *r, int p, int q)
{
    const patch *ep = &r->h->element[p], *eq = &r->h->element[q];
    vec3 b[4], mean = element_corner_mean(ep);
    int nb = element_stratified_points(r->m, eq, pair_salt(p, q), b), first_count = -1;
    for (int k = 0; k < ep->corner_count; k++) {
        vec3 x = element_toward_corner(r->m, ep, mean, k, EDGE_INSET);
        int visible = 0, blocked = 0;
        for (int j = 0; j < nb; j++)
            count_ray(r->s, ep, x, eq, b[j], &visible, &blocked);
        if (first_count < 0)
            first_count = visible;
        else if (visible != first_count)
            return SHADOW_ACROSS_RECEIVER;
    }
    int visible = 0, blocked = 0;
    count_ray(r->s, ep, ep->centroid, eq, eq->centroid, &visible, &blocked);
    vec3 source_mean = element_corner_mean(eq);
    for (int k = 0; k < eq->corner_count && !(visible && blocked); k++)
        count_ray(r->s, eq, element_toward_corner(r->m, eq, source_mean, k, EDGE_INSET), ep, ep->centroid, &visible,
                  &blocked);
    return visible && blocked ? SHADOW_ACROSS_SOURCE : NO_SHADOW_EDGE;
}

/* ---- the second pass's tests: the oracle with the first pass's solution B ---------------- */

/* Is the pair worth a shadow test?  The first pass knows no radiance: where
 * F is at least its eps / 8 (its eps: FIRST_PASS_COARSER x --eps).  A
 * shadow edge across a link can make its whole transfer F_pq B_q wrong, so
 * the second pass tests where F_pq times q's
 * radiance over the scene's mean (q's emission, or the B of q or of its
 * nearest ancestor the first pass made, at most BRIGHTNESS_CAP) is at
 * least --eps: the light's shadows are followed down to F of about
 * eps / 165, a dim wall's hardly at all (the first pass tested those). */
bool shadow_test_worthwhile(const refiner *r, int p, int q, const patch *eq, double f)
{
    if (r->h->covered[p] == COVERED_ALL)
        return false; /* under a cover p sees the rest through a slit, all of it alike */
    if (!r->radiance)
        return f >= r->eps / 8.0;
    int known = q;
    while (known >= r->known)
        known = r->h->parent[known];
    double radiance = fmax(v3_average(r->radiance[known]), v3_average(eq->emission));
    return f * fmin(radiance / r->mean_radiance, BRIGHTNESS_CAP) >= r->eps;
}

/* Second pass: how many times brighter than the scene's mean q is, at
 * least 1.  A link's error grows with F times its source's radiance
 * (Hanrahan et al.'s BF refinement), so the light's links are made finer. */
double source_brightness(const refiner *r, int q)
{
    if (!r->radiance || q >= r->known)
        return 1.0;
    return fmin(fmax(1.0, v3_average(r->radiance[q]) / r->mean_radiance), BRIGHTNESS_CAP);
}

/* spread_bound's errors are relative to p's radiance; for a receiver the
 * second pass made (which takes its first-pass ancestor's B), to no less
 * than this fraction of the scene's mean.  Without the floor such receivers
 * in the dark link to every first-pass leaf of a source with a shadow on it:
 * the Cornell box at the defaults passes the 40 M link limit (11.1 M with
 * it; 10.9 M when they were not refined at all).  First-pass elements keep
 * their own B, however dark: under a box 1 mm above a lit floor, the same
 * floor on them (0.03 or 0.1 of the mean) let 2 and 6.4 times the light
 * its slit lets in through (grade_03_furnace's contact-line test). */
static const double DARKEST_RECEIVER = 0.03;

/* Second pass: a link takes its source's radiance as constant.  Where the
 * source's leaves differ by spread_q, what p gathers may be off by up to
 * rho_p F_pq spread_q: this bound as a fraction of p's radiance (the worst
 * channel; see DARKEST_RECEIVER).  An element the second pass made takes its
 * nearest first-pass ancestor's B and spread: a first-pass leaf's spread is
 * 0 (one B), and a receiver the second pass made is still refined for its
 * sources' spread (it was not: the faces of the Cornell box's blocks lit
 * only by other surfaces gathered the floor's shadow edges through coarse
 * links, the short block's front face +3 % at --eps 8e-2, +1.4 % now).  0
 * before the first pass's solution is known. */
double spread_bound(const refiner *r, int p, int q, const patch *ep, double fpq)
{
    if (!r->radiance)
        return 0.0;
    double darkest = 0.0;
    for (; p >= r->known; p = r->h->parent[p])
        darkest = DARKEST_RECEIVER * r->mean_radiance;
    while (q >= r->known)
        q = r->h->parent[q];
    vec3 bound = v3_scale(v3_mul(ep->albedo, r->spread[q]), fpq);
    vec3 b = v3_max(r->radiance[p], v3_splat(darkest));
    double worst = 0.0;
    for (int c = 0; c < 3; c++)
        if (v3_get(b, c) > 0.0)
            worst = fmax(worst, v3_get(bound, c) / v3_get(b, c));
    return worst;
}

/* F_pq (R10) for a near pair, or one whose p may be partly inside a solid:
 * the outer integral over M x M sub-triangle centroids x of each triangle of
 * p (--quadrature M) that are outside (a ray along the normal from each),
 * Lambert's formula at each, times the visible part of the whole: rays from
 * each x to a point of q, weighted as in visible_fraction (a plain
 * fraction at each x put the walls' light into the cavity under a box). */
static double quadrature_form_factor(const hierarchy *h, const patch_mesh *m, const scene *s, point_to_polygon_fn F,
                                     int M, int p, int q, uint64_t *rays)
{
    const patch *ep = &h->element[p], *eq = &h->element[q];
    vec3 b[4], in_front = element_point_in_front(eq, ep->centroid, ep->normal, 4.0 * s->epsilon);
    int nb = element_stratified_points(m, eq, pair_salt(p, q), b), point = 0, passed = 0, tested = 0;
    double unoccluded = 0.0, exposed = 0.0, visible = 0.0, all = 0.0;
    for (int t = 1; t + 1 < ep->corner_count; t++) {
        vec3 o = ep->corner[0], e1 = v3_sub(ep->corner[t], o), e2 = v3_sub(ep->corner[t + 1], o);
        double weight = 0.5 * v3_length(v3_cross(e1, e2)) / ep->area / (M * M);
        for (int i = 0; i < M; i++)
            for (int j = 0; i + j < M; j++)
                for (int down = 0; down < 2 && !(down && i + j > M - 2); down++) {
                    double u = (3.0 * i + 1.0 + down) / (3.0 * M), v = (3.0 * j + 1.0 + down) / (3.0 * M);
                    vec3 x = patch_mesh_on_surface(m, ep->surface, v3_add(o, v3_add(v3_scale(e1, u), v3_scale(e2, v))));
                    if (h->covered[p] && element_point_buried(s, x, ep->normal))
                        continue;
                    exposed += weight;
                    if (v3_dot(eq->normal, v3_sub(x, eq->centroid)) <= s->epsilon)
                        continue;
                    double f = F(x, ep->normal, eq->corner, eq->corner_count);
                    if (f <= 0.0)
                        continue;
                    int k = 0; /* a point of q in front of p (see visible_fraction) */
                    while (k < nb && v3_dot(ep->normal, v3_sub(b[(point + k) % nb], ep->centroid)) <= s->epsilon)
                        k++;
                    vec3 y = k < nb ? b[(point++ + k) % nb] : in_front;
                    double g = weight * form_factor_kernel(x, ep->normal, y, eq->normal);
                    bool seen = !scene_occluded(s, x, y);
                    unoccluded += weight * f;
                    all += g;
                    visible += seen ? g : 0.0;
                    passed += seen;
                    tested++;
                }
    }
    *rays += (uint64_t)tested;
    if (exposed <= 0.0 || tested == 0)
        return 0.0;
    return unoccluded / exposed * (all > 0.0 ? visible / all : (double)passed / tested); /* no kernel: plain */
}

/* A link's form factor F_pq (R10) over the part of p outside every solid
 * (its mean there: what push_pull hands to that part).  Far apart: Lambert's
 * formula at four points of p times the visible part (visible_fraction).
 * Near, or when p may be partly inside a solid: quadrature_form_factor. */
static double link_form_factor(const hierarchy *h, const patch_mesh *m, const scene *s, point_to_polygon_fn F, int M,
                               int p, int q, uint64_t *rays)
{
    const patch *ep = &h->element[p], *eq = &h->element[q];
    if (h->covered[p] || v3_length(v3_sub(eq->centroid, ep->centroid)) <= NEAR_FACTOR * (ep->radius + eq->radius))
        return quadrature_form_factor(h, m, s, F, M, p, q, rays);
    /* The outer integral by the points 1/sqrt(3) of the way from the centroid
     * to the corners (Gauss's 2 x 2 rule on a parallelogram): the centroid
     * alone would miss the curvature of the 1/r^2 kernel, always low. */
    vec3 mean = element_corner_mean(ep);
    double f = 0.0;
    for (int k = 0; k < ep->corner_count; k++) {
        vec3 x = element_toward_corner(m, ep, mean, k, 1.0 / sqrt(3.0));
        if (v3_dot(eq->normal, v3_sub(x, eq->centroid)) > s->epsilon) /* x in front of q (one-sided q) */
            f += F(x, ep->normal, eq->corner, eq->corner_count);
    }
    if (f <= 0.0)
        return 0.0;
    return f / ep->corner_count * visible_fraction(m, s, ep, eq, pair_salt(p, q), rays);
}

/* The visible part of the light from q at x (rays to q's sample points in
 * front of e's plane, weighted as in visible_fraction; to y, q's part in
 * front of e, when none is). */
static double visible_from(const patch_mesh *m, const scene *s, vec3 x, const patch *ep, const patch *eq, vec3 y,
                           uint64_t salt)
{
    vec3 b[4];
    int nb = element_stratified_points(m, eq, salt, b);
    double visible = 0.0, all = 0.0;
    for (int k = 0; k < nb; k++)
        if (v3_dot(ep->normal, v3_sub(b[k], ep->centroid)) > s->epsilon) {
            double weight = form_factor_kernel(x, ep->normal, b[k], eq->normal);
            all += weight;
            if (!scene_occluded(s, x, b[k]))
                visible += weight;
        }
    return all > 0.0 ? visible / all : !scene_occluded(s, x, y);
}

/* The shape of link e <- q across the receiver e: its point form factor
 * times its visible part (visible_from: rays to q's sample points) at e's corners, from points
 * EDGE_INSET of the way out extrapolated to the corners (a ray from a corner
 * itself would start on the next surface's edge), as multiples of their
 * mean; constant where no corner sees q or e is partly inside
 * a solid (its light then steps to 0 at the solid's edge, which a ramp across
 * e would spread: a floor element across a resting box's edge).  A leaf then receives
 * from its ancestors' links what their linear interpolation gives at its
 * corners instead of their mean: at a concave corner, where F grows from 0
 * at the other wall's plane, an inherited constant gave the leaves along the
 * corner twice their share (row sums to 1.4, the corner 20 % bright). */
static void shape_link(const hierarchy *h, const patch_mesh *m, const scene *s, point_to_polygon_fn F, int e, long k)
{
    const patch *ep = &h->element[e], *eq = &h->element[h->link_source[k]];
    vec3 mean_corner = element_corner_mean(ep);
    double g[4] = {0.0, 0.0, 0.0, 0.0}, mean = 0.0, shaped = 0.0;
    vec3 y = element_point_in_front(eq, ep->centroid, ep->normal, 4.0 * s->epsilon); /* not behind e's plane */
    for (int j = 0; j < ep->corner_count; j++) {
        vec3 x = element_toward_corner(m, ep, mean_corner, j, EDGE_INSET);
        if (v3_dot(eq->normal, v3_sub(x, eq->centroid)) > s->epsilon)
            g[j] = F(x, ep->normal, eq->corner, eq->corner_count) *
                   visible_from(m, s, x, ep, eq, y, pair_salt(e, h->link_source[k]) + (uint64_t)j);
        mean += g[j] / ep->corner_count;
    }
    for (int j = 0; j < ep->corner_count; j++) {
        g[j] = fmax(0.0, mean + (g[j] - mean) / EDGE_INSET); /* out to the corner */
        shaped += g[j] / ep->corner_count;
    }
    double exposure = h->unburied[e];
    bool linear = shaped > 0.0 && exposure >= 1.0; /* partly inside a solid: a step, not a ramp */
    float *shape = &h->link_shape[4 * (h->shape_start[e] + k - h->link_start[e])];
    for (int j = 0; j < 4; j++)
        shape[j] = (float)(linear ? g[j] / shaped : exposure > 0.0);
}

/* Shapes only for the links of receivers with children: a leaf keeps the
 * mean over its corners (push_pull), whatever the shape (on the Cornell box
 * at the defaults most links are a leaf's: 16 bytes each saved). */
int hierarchy_shape_links(hierarchy *h, const patch_mesh *m, const scene *s, point_to_polygon_fn F)
{
    free(h->link_shape);
    free(h->shape_start);
    h->link_shape = NULL;
    if (!(h->shape_start = malloc((size_t)h->element_count * sizeof *h->shape_start + 1)))
        return -1;
    long shaped = 0;
    for (int e = 0; e < h->element_count; e++) {
        bool split = m->cells[e].first_child >= 0;
        h->shape_start[e] = split ? shaped : -1;
        shaped += split ? h->link_start[e + 1] - h->link_start[e] : 0;
    }
    if (!(h->link_shape = malloc(4 * (size_t)shaped * sizeof *h->link_shape + 1)))
        return -1;
#pragma omp parallel for schedule(dynamic, 64)
    for (int e = 0; e < h->element_count; e++)
        if (h->shape_start[e] >= 0)
            for (long k = h->link_start[e]; k < h->link_start[e + 1]; k++)
                shape_link(h, m, s, F, e, k);
    return 0;
}

/* The links grouped by receiver (a counting sort, stable) with their form
 * factors: computed, unless the first pass has one for the pair. */
int hierarchy_store_links(hierarchy *h, refiner *r, const radiosity_options *o, radiosity_stats *stats)
{
    if (hierarchy_group_links(h, r))
        return -1;
    uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 64) reduction(+ : rays)
    for (int e = 0; e < h->element_count; e++)
        for (long k = h->link_start[e]; k < h->link_start[e + 1]; k++)
            if (h->link_F[k] < 0.0f)
                h->link_F[k] = (float)link_form_factor(h, r->m, r->s, r->point_to_polygon, o->quadrature, e,
                                                       h->link_source[k], &rays);
    stats->visibility_rays += rays;
    return 0;
}


/* Elements when every one of the roots is split to the last level. */
static double worst_case_elements(int roots, int levels) { return roots * (pow(4.0, levels + 1) - 1.0) / 3.0; }

int hierarchy_levels(const patch_mesh *m, const radiosity_options *o, int *levels, char *err, size_t err_size)
{
    *levels = o->levels; /* the default: as deep as the limit allows for this many roots */
    while (o->levels_argv == 0 && *levels > 1 && worst_case_elements(m->cell_count, *levels) > WORST_CASE_LIMIT)
        --*levels;
    double bound = worst_case_elements(m->cell_count, *levels);
    if (bound <= WORST_CASE_LIMIT)
        return 0;
    snprintf(err, err_size,
             "argv:%d: --levels %d allows up to %.3g elements (%d roots), more than the limit %d; lower --levels",
             o->levels_argv, *levels, bound, m->cell_count, WORST_CASE_LIMIT);
    return 2;
}

pair *hierarchy_root_pairs(hierarchy *h, const patch_mesh *m, const scene *s, long *count)
{
    h->root_count = m->cell_count;
    pair *todo = malloc((size_t)h->root_count * (size_t)h->root_count * sizeof *todo + 1);
    *count = 0;
    if (!todo || hierarchy_track_new_cells(h, m, s)) {
        free(todo);
        return NULL;
    }
    for (int p = 0; p < h->root_count; p++)
        for (int q = 0; q < h->root_count; q++)
            if (p != q)
                todo[(*count)++] = (pair){p, q, -1.0f};
    return todo;
}

pair *hierarchy_links_as_pairs(hierarchy *h, long *count)
{
    pair *todo = malloc((size_t)h->link_count * sizeof *todo + 1);
    *count = 0;
    if (!todo)
        return NULL;
    for (int e = 0; e < h->element_count; e++)
        for (long k = h->link_start[e]; k < h->link_start[e + 1]; k++)
            todo[(*count)++] = (pair){e, h->link_source[k], h->link_F[k]};
    free(h->link_start);
    free(h->link_source);
    free(h->link_F);
    free(h->link_shape);
    free(h->shape_start);
    h->link_start = NULL;
    h->link_source = NULL;
    h->link_F = NULL;
    h->link_shape = NULL;
    h->shape_start = NULL;
    return todo;
}

void hierarchy_leaf_spread(const hierarchy *h, const patch_mesh *m, const vec3 *B, vec3 *lowest, vec3 *spread)
{
    vec3 *highest = spread;                           /* first the largest B below each element, then the spread */
    for (int e = h->element_count - 1; e >= 0; e--) { /* children come after their parent; buried leaves do not count */
        int child = m->cells[e].first_child;
        bool counted = child < 0 && h->unburied[e] > 0.0;
        lowest[e] = counted ? B[e] : v3_splat(INFINITY);
        highest[e] = counted ? B[e] : v3_splat(-INFINITY);
        for (int k = child; k >= 0 && k < child + 4; k++) {
            lowest[e] = v3_min(lowest[e], lowest[k]);
            highest[e] = v3_max(highest[e], highest[k]);
        }
    }
    for (int e = 0; e < h->element_count; e++)
        spread[e] = h->unburied[e] > 0.0 ? v3_sub(highest[e], lowest[e]) : v3_splat(0.0);
}

double hierarchy_mean_reflected(const hierarchy *h, const patch_mesh *m, const vec3 *B)
{
    double area = 0.0, reflected = 0.0;
    for (int e = 0; e < h->element_count; e++)
        if (m->cells[e].first_child < 0) {
            double unburied = h->element[e].area * h->unburied[e];
            area += unburied;
            reflected += unburied * v3_average(v3_sub(B[e], h->element[e].emission));
        }
    return area > 0.0 ? reflected / area : 0.0;
}

void refiner_free(refiner *r)
{
    free(r->receiver);
    free(r->source);
    free(r->known_F);
    r->receiver = r->source = NULL;
    r->known_F = NULL;
}

int hierarchy_complete(const refiner *r, const radiosity_options *o, radiosity_stats *stats, char *err, size_t err_size)
{
    hierarchy *h = r->h;
    patch_mesh *m = r->m;
    const scene *s = r->s;
    int failed = r->failed;
    if (failed == 3)
        return snprintf(err, err_size, "argv:%d: --eps %g needs more than %d elements (the limit); raise --eps",
                        o->eps_argv, o->eps, ELEMENT_LIMIT),
               2;
    if (failed == 2)
        return snprintf(err, err_size, "argv:%d: --eps %g needs more than %d links (the limit); raise --eps",
                        o->eps_argv, o->eps, LINK_LIMIT),
               2;
    if (!failed && hierarchy_shape_links(h, m, s, r->point_to_polygon))
        failed = 1;
    if (failed || !(h->gathered = calloc(5 * (size_t)h->element_count + 1, sizeof *h->gathered)))
        return snprintf(err, err_size, "argv:0: out of memory for the hierarchy"), 2;
    h->term = h->gathered + 4 * (size_t)h->element_count;
    hierarchy_report(h, m, stats);
    if (radiosity_collect_patches(m, s, o, err, err_size)) /* the leaves become the patches */
        return 2;
    for (int i = 0; i < m->patch_count; i++)
        m->patches[i].unburied = h->unburied[m->patches[i].cell];
    return 0;
}
