/* 03_radiosity_hierarchical.c — hierarchical radiosity (see 03_radiosity_hierarchical.h). */
#include "03_radiosity_hierarchical_store.h"

#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>

/* Pairs closer than this many radii are integrated at quadrature points (as chapter 3's NEAR_FACTOR). */
static const double NEAR_FACTOR = 6.0;

/* With a second pass, the first runs at this times --eps: it only has to
 * show where the light goes, and the second refines its links anyway
 * (measured on the Cornell box: the same error as 1 in 70 % of the time). */
static const double FIRST_PASS_COARSER = 2.0;

/* The second pass weighs F by a source's radiance over the scene's mean
 * reflected radiance, at most this much.  The Cornell box's light is about
 * 165 times the mean; a light a hundredth its size and a hundred times as
 * bright (scenes/cornell-small-light.scene) 16,500 times, and weighing its
 * links by that split every receiver and the light to --levels (over 40 M
 * links at --eps 2e-2), though its form factors are accurate long before. */
static const double BRIGHTNESS_CAP = 256.0;

/* The oracle estimates F by the disc approximation beyond this many radii
 * (measured on the Cornell box: 4 gives the error of Lambert's formula
 * everywhere, 2 does not). */
static const double DISC_FACTOR = 4.0;

/* No element smaller than the scene's diagonal over this (1.9 mm in the
 * Cornell box, whose floor reaches --levels 8 at 2.2 mm): two faces 1 mm
 * apart (a box just above the floor) see each other at F ~ 1 at every level,
 * and without it would split to --levels whatever the scene's size. */
static const double SMALLEST_PART = 512.0;


/* The fraction of up to four rays between the two elements that nothing
 * blocks.  Only pairs of sample points in front of each other's element
 * count: a ray to a point behind the receiver's plane would run into the
 * receiver's own solid, which Lambert's clipped formula has already left
 * out.  No such pair: 1 (the pair hardly exchanges light). */
static double visible_fraction(const patch_mesh *m, const scene *s, const patch *ep, const patch *eq, uint64_t *rays)
{
    vec3 a[4], b[4];
    int na = element_sample_points(m, ep, a), nb = element_sample_points(m, eq, b), tested = 0, visible = 0;
    for (int k = 0; k < na * nb && tested < 4; k++) {
        vec3 x = a[k % na], y = b[(k + k / na) % nb]; /* the diagonal pairs first, then shifted */
        if (v3_dot(ep->normal, v3_sub(y, ep->centroid)) <= s->epsilon ||
            v3_dot(eq->normal, v3_sub(x, eq->centroid)) <= s->epsilon)
            continue;
        tested++;
        visible += !scene_occluded(s, x, y);
    }
    *rays += (uint64_t)tested;
    return tested ? (double)visible / tested : 1.0;
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

/* Does a shadow edge cross the pair?  Of the rays from each element's
 * corners (EDGE_INSET of the way from its centre) to the other's centroid,
 * and between the centroids, some are blocked and some not (at most 9 rays,
 * stopping at the first mixed pair). */
static bool shadow_edge(const refiner *r, const patch *ep, const patch *eq)
{
    int visible = 0, blocked = 0;
    count_ray(r->s, ep, ep->centroid, eq, eq->centroid, &visible, &blocked);
    for (int side = 0; side < 2; side++) {
        const patch *e = side ? eq : ep, *other = side ? ep : eq;
        vec3 mean = element_corner_mean(e);
        for (int k = 0; k < e->corner_count && !(visible && blocked); k++)
            count_ray(r->s, e, element_toward_corner(r->m, e, mean, k, EDGE_INSET), other, other->centroid, &visible,
                      &blocked);
    }
    return visible && blocked;
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
static bool worth_shadow_test(const refiner *r, int p, int q, const patch *eq, double f)
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
static double brightness(const refiner *r, int q)
{
    if (!r->radiance || q >= r->known)
        return 1.0;
    return fmin(fmax(1.0, v3_average(r->radiance[q]) / r->mean_radiance), BRIGHTNESS_CAP);
}

/* Second pass: a link takes its source's radiance as constant.  Where the
 * source's leaves differ by spread_q, what p gathers may be off by up to
 * rho_p F_pq spread_q: this bound as a fraction of p's radiance (the worst
 * channel).  0 when unknown. */
static double spread_bound(const refiner *r, int p, int q, const patch *ep, double fpq)
{
    if (!r->radiance || p >= r->known || q >= r->known)
        return 0.0;
    vec3 bound = v3_scale(v3_mul(ep->albedo, r->spread[q]), fpq), b = r->radiance[p];
    double worst = 0.0;
    for (int c = 0; c < 3; c++)
        if (v3_get(b, c) > 0.0)
            worst = fmax(worst, v3_get(bound, c) / v3_get(b, c));
    return worst;
}

/* ---- refinement ------------------------------------------------------------------------- */

enum verdict { NO_LINK, LINK, SPLIT_RECEIVER, SPLIT_SOURCE };

/* The point form factor F_dx->q at x on the receiver ep (normal ep->normal):
 * Lambert's formula near, the disc approximation far (the oracle is asked
 * millions of times); 0 when x is behind the one-sided q. */
static double point_form_factor(const refiner *r, vec3 x, const patch *ep, const patch *eq, bool far)
{
    vec3 d = v3_sub(eq->centroid, x);
    double distance = v3_length(d);
    double cos_p = v3_dot(ep->normal, d) / distance, cos_q = -v3_dot(eq->normal, d) / distance;
    if (!far)
        return cos_q * distance <= r->s->epsilon ? 0.0
                                                 : r->point_to_polygon(x, ep->normal, eq->corner, eq->corner_count);
    return cos_p > 0.0 && cos_q > 0.0 ? eq->area * cos_p * cos_q / (M_PI * distance * distance + eq->area) : 0.0;
}

/* The oracle's F_pq: the largest point form factor at p's centroid and, if
 * near, its corners.  At the centroid alone a pair that nearly touches (a
 * box 1 mm above the floor) reads F ~ 0 while a corner of p sees q at F ~ 1/2,
 * and a link there would give all of p what only its corner receives. */
static double largest_form_factor(const refiner *r, const patch *ep, const patch *eq)
{
    bool far = v3_length(v3_sub(eq->centroid, ep->centroid)) > DISC_FACTOR * (ep->radius + eq->radius);
    double largest = point_form_factor(r, ep->centroid, ep, eq, far);
    for (int k = 0; k < ep->corner_count && !far; k++)
        largest = fmax(largest, point_form_factor(r, ep->corner[k], ep, eq, far));
    return largest;
}

/* Below --levels, and its children would be at least the refiner's smallest
 * size across (by default the scene's diagonal / SMALLEST_PART: the same
 * hierarchy in metres and in millimetres). */
static bool can_split(const refiner *r, int e)
{
    return r->h->level[e] < r->levels && sqrt(r->h->element[e].area / 4.0) >= r->smallest;
}

/* The refinement oracle (Hanrahan et al.'s Refine): p receives from q.  An
 * element partly covered (a box resting on it or just above part of it:
 * hierarchy_track_new_cells) is split, so that its parts get their own links
 * (the light steps there, which no link's shape follows).  Otherwise a link
 * at this level when both form-factor estimates are below the pass's eps (in
 * the second pass --eps, and F times q's brightness), the spread bound is
 * within --eps-spread, and no shadow edge crosses the pair where a test is
 * worth it.  Otherwise split the element that looks larger from the other
 * (q when F_pq > F_qp); an element at --levels or the smallest size is not
 * split further. */
static enum verdict judge(const refiner *r, int p, int q)
{
    const patch *ep = &r->h->element[p], *eq = &r->h->element[q];
    if (!patches_facing(ep, eq, r->s->epsilon))
        return NO_LINK; /* one-sided: they cannot exchange light */
    if (r->h->covered[p] == COVERED_PART && can_split(r, p))
        return SPLIT_RECEIVER; /* a contact shadow or a solid's edge across p, whatever the source */
    double fpq = largest_form_factor(r, ep, eq), fqp = largest_form_factor(r, eq, ep);
    double bright = brightness(r, q);
    bool link = fpq * bright < r->eps && fqp * bright < r->eps;
    link = link && spread_bound(r, p, q, ep, fpq) <= r->eps_spread;
    bool shadowed = link && worth_shadow_test(r, p, q, eq, fmax(fpq, fqp)) && shadow_edge(r, ep, eq);
    bool can_p = can_split(r, p), can_q = can_split(r, q);
    if ((link && !shadowed) || (!can_p && !can_q))
        return LINK;
    return can_q && (fpq > fqp || !can_p) ? SPLIT_SOURCE : SPLIT_RECEIVER;
}

/* Hanrahan et al.'s recursion, breadth first: judge every pair of a round
 * (in parallel: judging only reads), then link or split them one by one;
 * the children's pairs make the next round.  The same links as the
 * depth-first recursion, in another order.  Takes todo (malloc'ed). */
static void refine_rounds(refiner *r, pair *todo, long count)
{
    while (count > 0 && !r->failed) {
        unsigned char *verdict = malloc((size_t)count);
        pair *next = NULL;
        long next_count = 0, next_capacity = 0;
        if (!verdict) {
            r->failed = 1;
            break;
        }
#pragma omp parallel for schedule(dynamic, 256)
        for (long k = 0; k < count; k++)
            verdict[k] = (unsigned char)judge(r, todo[k].p, todo[k].q);
        for (long k = 0; k < count && !r->failed; k++) {
            pair t = todo[k];
            if (verdict[k] == LINK)
                refiner_add_link(r, t.p, t.q, t.F);
            else if (verdict[k] != NO_LINK) {
                bool split_source = verdict[k] == SPLIT_SOURCE;
                int first = refiner_children(r, split_source ? t.q : t.p);
                if (first < 0 || pairs_push_children(&next, &next_count, &next_capacity, t, split_source, first))
                    r->failed = r->failed ? r->failed : 1;
            }
        }
        free(verdict), free(todo);
        todo = next, count = next_count;
    }
    free(todo);
}

/* A link's form factor F_pq (R10) over the part of p outside every solid
 * (its mean there: what push_pull hands to that part).  Far apart: Lambert's
 * formula at four points of p times the fraction of rays between them not
 * blocked.  Near, or when p may be partly inside a solid: the outer integral
 * over M x M sub-triangle centroids of each triangle of p (--quadrature M)
 * that are outside (a ray along the normal from each), a ray from each to a
 * point of q. */
static double link_form_factor(const hierarchy *h, const patch_mesh *m, const scene *s, point_to_polygon_fn F, int M,
                               int p, int q, uint64_t *rays)
{
    const patch *ep = &h->element[p], *eq = &h->element[q];
    vec3 b[4];
    int nb = element_sample_points(m, eq, b);
    bool covered = h->covered[p] != 0; /* part of p may be inside a solid: integrate over the rest only */
    if (!covered && v3_length(v3_sub(eq->centroid, ep->centroid)) > NEAR_FACTOR * (ep->radius + eq->radius)) {
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
        return f / ep->corner_count * visible_fraction(m, s, ep, eq, rays);
    }
    double total = 0.0, exposed = 0.0;
    int point = 0;
    vec3 in_front = element_point_in_front(eq, ep->centroid, ep->normal, 4.0 * s->epsilon);
    for (int t = 1; t + 1 < ep->corner_count; t++) {
        vec3 o = ep->corner[0], e1 = v3_sub(ep->corner[t], o), e2 = v3_sub(ep->corner[t + 1], o);
        double weight = 0.5 * v3_length(v3_cross(e1, e2)) / ep->area / (M * M);
        for (int i = 0; i < M; i++)
            for (int j = 0; i + j < M; j++)
                for (int down = 0; down < 2 && !(down && i + j > M - 2); down++) {
                    double u = (3.0 * i + 1.0 + down) / (3.0 * M), v = (3.0 * j + 1.0 + down) / (3.0 * M);
                    vec3 x = patch_mesh_on_surface(m, ep->surface, v3_add(o, v3_add(v3_scale(e1, u), v3_scale(e2, v))));
                    if (covered && element_point_buried(s, x, ep->normal))
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
                    ++*rays;
                    if (!scene_occluded(s, x, y))
                        total += weight * f;
                }
    }
    return exposed > 0.0 ? total / exposed : 0.0;
}

/* The shape of link e <- q across the receiver e: its point form factor
 * times visibility (one ray to q's part in front of e) at e's corners, from points
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
        if (v3_dot(eq->normal, v3_sub(x, eq->centroid)) > s->epsilon && !scene_occluded(s, x, y))
            g[j] = F(x, ep->normal, eq->corner, eq->corner_count);
        mean += g[j] / ep->corner_count;
    }
    for (int j = 0; j < ep->corner_count; j++) {
        g[j] = fmax(0.0, mean + (g[j] - mean) / EDGE_INSET); /* out to the corner */
        shaped += g[j] / ep->corner_count;
    }
    double exposure = h->exposure[e];
    bool linear = shaped > 0.0 && exposure >= 1.0; /* partly inside a solid: a step, not a ramp */
    for (int j = 0; j < 4; j++)
        h->link_shape[4 * k + j] = (float)(linear ? g[j] / shaped : exposure > 0.0);
}

static int link_shapes(hierarchy *h, const patch_mesh *m, const scene *s, point_to_polygon_fn F)
{
    free(h->link_shape);
    if (!(h->link_shape = malloc(4 * (size_t)h->link_count * sizeof *h->link_shape + 1)))
        return -1;
#pragma omp parallel for schedule(dynamic, 64)
    for (int e = 0; e < h->element_count; e++)
        for (long k = h->link_start[e]; k < h->link_start[e + 1]; k++)
            shape_link(h, m, s, F, e, k);
    return 0;
}

/* The links grouped by receiver (a counting sort, stable) with their form
 * factors: computed, unless the first pass has one for the pair. */
static int store_links(hierarchy *h, refiner *r, const radiosity_options *o, radiosity_stats *stats)
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

/* Push-pull.  What an element gathers is known at its corners (each link's
 * F shaped by link_shapes: linear across the element, not constant), so
 * what e and its ancestors gathered (down, at e's corners) is pushed to
 * e's children interpolated at theirs (patch_mesh_child_values), and a leaf
 * receives the mean of its corners' values (the mean of a bilinear or linear
 * function over the cell) and adds its source.  e's term is the mean of its
 * children's over their exposed area, pulled up.  source: 0 emission,
 * 1 first_shot, 2 none. */
static vec3 push_pull(hierarchy *h, const patch_mesh *m, int e, const vec3 *down, int source, const vec3 *first_shot)
{
    const mesh_cell *c = &m->cells[e];
    vec3 here[4], up = v3_splat(0.0);
    for (int k = 0; k < c->vertex_count; k++)
        here[k] = v3_add(down[k], h->gathered[4 * (size_t)e + (size_t)k]);
    if (c->first_child < 0) {
        double exposure = h->exposure[e];
        vec3 received = v3_splat(0.0);
        for (int k = 0; k < c->vertex_count; k++)
            received = v3_madd(received, here[k], 1.0 / c->vertex_count);
        up = source == 0   ? v3_add(received, h->element[e].emission)
             : source == 1 ? v3_madd(received, first_shot[c->patch], exposure > 0.0 ? 1.0 / exposure : 0.0)
                           : received;
    } else {
        double exposed_area = 0.0;
        for (int k = 0; k < 4; k++) {
            vec3 child_down[4];
            patch_mesh_child_values(c->vertex_count, here, k, child_down);
            double weight = h->element[c->first_child + k].area * h->exposure[c->first_child + k];
            up = v3_madd(up, push_pull(h, m, c->first_child + k, child_down, source, first_shot), weight);
            exposed_area += weight;
        }
        up = v3_scale(up, exposed_area > 0.0 ? 1.0 / exposed_area : 0.0);
    }
    h->term[e] = up;
    return up;
}

/* Gather: every element receives rho Sum_links F_pq term_q (one more bounce,
 * R6) at each of its corners: F times the link's shape there. */
static void gather(hierarchy *h, const patch_mesh *m)
{
#pragma omp parallel for schedule(dynamic, 256)
    for (int e = 0; e < h->element_count; e++) {
        vec3 sum[4] = {v3_splat(0.0), v3_splat(0.0), v3_splat(0.0), v3_splat(0.0)};
        for (long k = h->link_start[e]; k < h->link_start[e + 1]; k++)
            for (int j = 0; j < 4; j++)
                sum[j] = v3_madd(sum[j], h->term[h->link_source[k]], h->link_F[k] * hierarchy_link_shape(h, e, k, j));
        for (int j = 0; j < m->cells[e].vertex_count; j++)
            h->gathered[4 * (size_t)e + (size_t)j] = v3_mul(h->element[e].albedo, sum[j]);
    }
}

static void push_pull_all(hierarchy *h, const patch_mesh *m, int source, const vec3 *first_shot)
{
#pragma omp parallel for schedule(dynamic, 1)
    for (int root = 0; root < h->root_count; root++)
        push_pull(h, m, root, (vec3[4]){{0}}, source, first_shot);
}

/* B per element (all bounces of the emission, summed until a term's power
 * is below 1e-3 of the emission's) and its spread over the element's leaves. */
static void first_pass_solution(hierarchy *h, const patch_mesh *m, vec3 *B, vec3 *spread)
{
    int n = h->element_count;
    vec3 *lowest = spread, *highest = B + n; /* B has room for 2n: the second half is scratch */
    memset(h->gathered, 0, 4 * (size_t)n * sizeof *h->gathered);
    memset(B, 0, (size_t)n * sizeof *B);
    push_pull_all(h, m, 0, NULL);
    double first_power = 0.0;
    for (int k = 0; k < 1000; k++) {
        double power = 0.0;
        for (int e = 0; e < n; e++) {
            B[e] = v3_add(B[e], h->term[e]);
            if (m->cells[e].first_child < 0)
                power += h->element[e].area * h->exposure[e] * v3_average(h->term[e]);
        }
        first_power = k == 0 ? power : first_power;
        if (!(power > 1e-3 * first_power))
            break;
        gather(h, m);
        push_pull_all(h, m, 2, NULL);
    }
    for (int e = n - 1; e >= 0; e--) { /* children come after their parent; buried leaves do not count */
        int child = m->cells[e].first_child;
        lowest[e] = child < 0 && h->exposure[e] > 0.0 ? B[e] : v3_splat(INFINITY);
        highest[e] = child < 0 && h->exposure[e] > 0.0 ? B[e] : v3_splat(-INFINITY);
        for (int k = child; k >= 0 && k < child + 4; k++)
            lowest[e] = v3_min(lowest[e], lowest[k]), highest[e] = v3_max(highest[e], highest[k]);
    }
    for (int e = 0; e < n; e++)
        spread[e] = h->exposure[e] > 0.0 ? v3_sub(highest[e], lowest[e]) : v3_splat(0.0);
}

/* The second pass (--eps-spread): solve on the first pass's links, then
 * judge them again with B known (brightness, spread_bound,
 * worth_shadow_test) and --eps itself.  It starts from the first pass's
 * links, so what the first pass split stays split, and a link kept keeps
 * its form factor.  B holds the emission's light only: in a scene lit only
 * by point lights there is none, and the second pass refines by F alone. */
static int refine_again(hierarchy *h, refiner *r, const radiosity_options *o, radiosity_stats *stats)
{
    int n = h->element_count;
    vec3 *B = malloc(3 * (size_t)n * sizeof *B), *spread = B ? B + 2 * (size_t)n : NULL;
    h->gathered = calloc(5 * (size_t)n + 1, sizeof *h->gathered);
    if (!B || !h->gathered)
        return free(B), -1;
    h->term = h->gathered + 4 * (size_t)n;
    first_pass_solution(h, r->m, B, spread);
    free(h->gathered), h->gathered = h->term = NULL;
    double area = 0.0, reflected = 0.0; /* the scene's mean reflected radiance, B - Le over the leaves */
    for (int e = 0; e < n; e++)
        if (r->m->cells[e].first_child < 0) {
            double exposed = h->element[e].area * h->exposure[e];
            area += exposed, reflected += exposed * v3_average(v3_sub(B[e], h->element[e].emission));
        }
    pair *todo = malloc((size_t)h->link_count * sizeof *todo + 1);
    if (!todo)
        return free(B), -1;
    long count = 0;
    for (int e = 0; e < n; e++)
        for (long k = h->link_start[e]; k < h->link_start[e + 1]; k++)
            todo[count++] = (pair){e, h->link_source[k], h->link_F[k]};
    free(h->link_start), free(h->link_source), free(h->link_F);
    h->link_start = NULL, h->link_source = NULL, h->link_F = NULL;
    r->count = 0, r->eps = o->eps;
    if (reflected > 0.0)
        r->radiance = B, r->spread = spread, r->known = n, r->mean_radiance = reflected / area;
    refine_rounds(r, todo, count); /* what the first pass split, the second splits too: start from its links */
    free(B);
    r->radiance = r->spread = NULL;
    return r->failed || store_links(h, r, o, stats) ? -1 : 0;
}


/* Elements when every one of the roots is split to the last level. */
static double worst_case_elements(int roots, int levels) { return roots * (pow(4.0, levels + 1) - 1.0) / 3.0; }

int hierarchy_build(hierarchy *h, patch_mesh *m, const scene *s, const radiosity_options *o, radiosity_stats *stats,
                    point_to_polygon_fn point_to_polygon, char *err, size_t err_size)
{
    int levels = o->levels; /* the default: as deep as the limit allows for this many roots */
    while (o->levels_argv == 0 && levels > 1 && worst_case_elements(m->cell_count, levels) > WORST_CASE_LIMIT)
        levels--;
    double bound = worst_case_elements(m->cell_count, levels);
    if (bound > WORST_CASE_LIMIT) /* refused before the hierarchy is allocated */
        return snprintf(err, err_size,
                        "argv:%d: --levels %d allows up to %.3g elements (%d roots), more than the limit %d; "
                        "lower --levels",
                        o->levels_argv, levels, bound, m->cell_count, WORST_CASE_LIMIT),
               2;
    hierarchy_free(h);
    double start = omp_get_wtime();
    h->root_count = m->cell_count;
    refiner r = {.h = h,
                 .m = m,
                 .s = s,
                 .point_to_polygon = point_to_polygon,
                 .eps = o->eps_spread > 0.0 ? FIRST_PASS_COARSER * o->eps : o->eps,
                 .eps_spread = o->eps_spread,
                 .levels = levels,
                 .smallest = v3_length(v3_sub(s->bounds.hi, s->bounds.lo)) / SMALLEST_PART};
    pair *todo = malloc((size_t)h->root_count * h->root_count * sizeof *todo + 1);
    long count = 0;
    if (hierarchy_track_new_cells(h, m, s) || !todo)
        r.failed = 1;
    for (int p = 0; p < h->root_count && todo; p++)
        for (int q = 0; q < h->root_count; q++)
            if (p != q)
                todo[count++] = (pair){p, q, -1.0f};
    refine_rounds(&r, todo, count);
    if (!r.failed && store_links(h, &r, o, stats))
        r.failed = 1;
    stats->first_pass_links = h->link_count;
    if (!r.failed && o->eps_spread > 0.0 && (hierarchy_exposure(h, m, s) || refine_again(h, &r, o, stats)))
        r.failed = r.failed ? r.failed : 1;
    if (!r.failed && hierarchy_exposure(h, m, s))
        r.failed = 1;
    free(r.receiver), free(r.source), free(r.known_F);
    stats->formfactor_s += omp_get_wtime() - start; /* refinement and the links' form factors */
    if (r.failed == 3)
        return snprintf(err, err_size, "argv:%d: --eps %g needs more than %d elements (the limit); raise --eps",
                        o->eps_argv, o->eps, ELEMENT_LIMIT),
               2;
    if (r.failed == 2)
        return snprintf(err, err_size, "argv:%d: --eps %g needs more than %d links (the limit); raise --eps",
                        o->eps_argv, o->eps, LINK_LIMIT),
               2;
    if (!r.failed && link_shapes(h, m, s, point_to_polygon))
        r.failed = 1;
    if (r.failed || !(h->gathered = calloc(5 * (size_t)h->element_count + 1, sizeof *h->gathered)))
        return snprintf(err, err_size, "argv:0: out of memory for the hierarchy"), 2;
    h->term = h->gathered + 4 * (size_t)h->element_count;
    hierarchy_report(h, m, stats);
    if (radiosity_collect_patches(m, s, o, err, err_size)) /* the leaves become the patches */
        return 2;
    for (int i = 0; i < m->patch_count; i++)
        m->patches[i].exposure = h->exposure[m->patches[i].cell];
    return 0;
}

int hierarchy_solve(hierarchy *h, const patch_mesh *m, const vec3 *first_shot, int first, int last,
                    const radiosity_options *o, radiosity_stats *r, double source_norm, vec3 *L)
{
    memset(h->gathered, 0, 4 * (size_t)h->element_count * sizeof *h->gathered);
    push_pull_all(h, m, 0, first_shot); /* term 0: E at the leaves, pulled up */
    for (int k = 0;; k++) {
        if (k >= first) /* a patch's radiance on its exposed part (the image and probes see no other) */
            for (int i = 0; i < m->patch_count; i++)
                if (h->exposure[m->patches[i].cell] > 0.0)
                    L[i] = v3_add(L[i], h->term[m->patches[i].cell]);
        gather(h, m);
        push_pull_all(h, m, k == 0 ? 1 : 2, first_shot); /* term k + 1 */
        double power = 0.0;
        for (int i = 0; i < m->patch_count; i++) {
            vec3 t = h->term[m->patches[i].cell];
            power += m->patches[i].area * h->exposure[m->patches[i].cell] * (fabs(t.x) + fabs(t.y) + fabs(t.z));
        }
        r->iterations = k + 1;
        record_residual(r, power / source_norm);
        r->converged = k >= last || r->residual <= o->tolerance;
        if (r->converged || r->iterations >= o->max_iterations)
            return 0;
    }
}

void hierarchy_free(hierarchy *h)
{
    free(h->element), free(h->level), free(h->covered), free(h->parent), free(h->exposure), free(h->gathered),
        free(h->link_start), free(h->link_source), free(h->link_F), free(h->link_shape);
    *h = (hierarchy){0};
}
