/* 03c_hierarchical.c — Lecture 3, part 3: hierarchical radiosity
 * (Hanrahan, Salesin & Aupperle 1991).
 *
 * Chapter 3 (03_radiosity.c) solves the radiosity system
 *
 *   L_i = Le_i + rho_i * Sum_j F_ij L_j          i.e.  L = E + K L   (R4)
 *
 * on a uniform mesh: n patches, n^2 form factors (R10).  Most of those
 * numbers are tiny.  Two groups of patches far from each other exchange
 * light through one number about as well as through all the products of
 * their patches: what matters is how large F is, not how many patches
 * there are.  Hierarchical radiosity keeps one form factor, a *link*, per
 * pair of elements at the level where F is small, so the work grows with
 * the links (about linear in the elements), not with n^2.  Read top to
 * bottom, in the paper's order:
 *
 *   the quadtree   each surface is the root of a quadtree of elements (the
 *                  cells of the patch mesh, split in four);
 *   the oracle     judge(): link p <- q here, or split the larger of the two;
 *   refine         refine_rounds(): the oracle over every pair of roots, down;
 *   gather         gather(): every element receives rho Sum_links F_pq L_q,
 *                  one product K L of (R4) over the links;
 *   push-pull      push_pull(): what an element gathered goes down to its
 *                  leaves, and each element's radiance is its children's
 *                  mean, pulled up;
 *   the solve      solve(): gather then push-pull is one more term of the
 *                  Neumann series (R6), term by term as chapter 3's Jacobi.
 *
 * Then Hanrahan et al.'s BF refinement as a second pass (refine_again):
 * solve once, then refine where F times the source's radiance is large.
 * Around the lecture, in common/ (nothing there is the lecture): the
 * elements' arrays, link lists and unburied fractions in hierarchy.[ch];
 * each link's form factor (R10) over its receiver's unburied part, its
 * shape across the receiver, the shadow-edge test and the second pass's
 * measures in hierarchy_links.c; meshing, options and stats shared with
 * chapter 3 in radiosity_setup.[ch].  Lambert's point-to-polygon formula
 * is chapter 3's (exercise 3.1, chapters/radiosity_model.h). */
#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>

#include "hierarchy.h"
#include "mesh_io.h"
#include "radiosity_model.h"
#include "render.h"

typedef struct {
    radiosity_view view;        /* first: what the driver reads once solved (radiosity_setup.h) */
    radiosity_options opt;      /* the command line fills it (HIERARCHICAL_OPTIONS) */
    int bounce_min, bounce_max; /* --bounces: the Neumann terms kept (R6) */
    bool quiet;
    patch_mesh mesh;  /* its cells are the elements, its patches the leaves */
    hierarchy tree;   /* the elements' quadtrees and their links (common/hierarchy.h) */
    vec3 *first_shot; /* per leaf: light from point lights reflected once (part of term 1) */
    vec3 *radiance;   /* per leaf: L, the --bounces window */
    radiosity_stats stats;
} hierarchical_state;

/* ---- the quadtree ----------------------------------------------------------------------- */

/* No element smaller than the scene's diagonal over this (1.9 mm in the
 * Cornell box): two faces 1 mm apart (a box just above the floor) see each
 * other at F ~ 1 at every level, and would split to --levels whatever the
 * scene's size. */
static const double SMALLEST_PART = 512.0;

/* An element e is split into four children (refiner_children, the mesh's
 * patch_mesh_split) below --levels, while its children would be at least
 * the smallest size across: the same hierarchy in metres as in millimetres. */
static bool can_split(const refiner *r, int e)
{
    return r->h->level[e] < r->levels && sqrt(r->h->element[e].area / 4.0) >= r->smallest;
}

/* ---- the oracle --------------------------------------------------------------------------- */

/* Beyond this many radii the oracle estimates F by the disc approximation
 * (measured on the Cornell box: 4 gives the error of Lambert's formula
 * everywhere, 2 does not). */
static const double DISC_FACTOR = 4.0;

/* The point form factor F_dx->q at x on the receiver ep: Lambert's formula
 * near, far the disc approximation A cos cos / (pi r^2 + A) (the oracle is
 * asked millions of times); 0 when x is behind the one-sided q. */
static double point_form_factor(const refiner *r, vec3 x, const patch *ep, const patch *eq, bool far)
{
    vec3 d = v3_sub(eq->centroid, x);
    double distance = v3_length(d);
    double cos_p = v3_dot(ep->normal, d) / distance, cos_q = -v3_dot(eq->normal, d) / distance;
    if (!far && cos_q * distance <= r->s->epsilon)
        return 0.0;
    if (!far)
        return r->point_to_polygon(x, ep->normal, eq->corner, eq->corner_count);
    if (cos_p <= 0.0 || cos_q <= 0.0)
        return 0.0;
    return eq->area * cos_p * cos_q / (M_PI * distance * distance + eq->area);
}

/* The oracle's estimate of F_pq: the largest point form factor at p's
 * centroid and, when near, its corners.  At the centroid alone a pair that
 * nearly touches (a box 1 mm above the floor) reads F ~ 0 while a corner of
 * p sees q at F ~ 1/2, and a link there would give all of p what only its
 * corner receives. [exercise 3c.1] */
static double largest_form_factor(const refiner *r, const patch *ep, const patch *eq)
{
    bool far = v3_length(v3_sub(eq->centroid, ep->centroid)) > DISC_FACTOR * (ep->radius + eq->radius);
    double largest = point_form_factor(r, ep->centroid, ep, eq, far);
    for (int k = 0; k < ep->corner_count && !far; k++)
        largest = fmax(largest, point_form_factor(r, ep->corner[k], ep, eq, far));
    return largest;
}

enum verdict { NO_LINK, LINK, SPLIT_RECEIVER, SPLIT_SOURCE };

/* A shadow across the receiver p splits p (not the larger element) while q
 * sees p at F_qp of at least this: p's links are linear across it and
 * cannot follow the shadow's step, and a floor beside a box gets the same
 * step from every source behind the box.  A fixed F, about eps/32 at the
 * default --eps (2e-2 in the first pass, over 64): as a fraction of --eps a
 * finer --eps split receivers without end (over 40 M links on the Cornell
 * box at --eps 5e-3). */
static const double RECEIVER_SHADOW_F = 3e-4;

/* A receiver split already (for other sources) follows a shadow across it
 * to its children on links of F_pq >= eps / this: links, not elements.  The
 * parent's linear shape put half the light of the walls behind a box on the
 * floor leaves beside its corners, in its shadow (row sums 0.97-1.04 at the
 * defaults, now within 1.1 %); with no bound on F the Cornell box had 3 times
 * the links at --eps 1.1e-1, at 16 a leaf there stays 2.1 % off at 2e-2. */
static const double FOLLOW_SHADOW_DIV = 32.0;

/* The refinement oracle (Hanrahan et al.'s Refine): p receives from q.
 * Link here when both form-factor estimates are below eps (times q's
 * brightness in the second pass), the source's spread is within
 * --eps-spread, and no shadow edge crosses the pair where a test is worth
 * it (always where p is split already); otherwise split p when the shadow
 * edge crosses p, else the element that looks larger from the other (q when
 * F_pq > F_qp).  An element partly covered (a box resting on part of it) is
 * split first, so that its parts get their own links: the light steps there,
 * and no link's shape follows a step. [exercise 3c.2] */
static enum verdict judge(const refiner *r, int p, int q)
{
    const patch *ep = &r->h->element[p], *eq = &r->h->element[q];
    if (!patches_facing(ep, eq, r->s->epsilon))
        return NO_LINK; /* one-sided: they cannot exchange light */
    bool can_p = can_split(r, p), can_q = can_split(r, q);
    if (r->h->covered[p] == COVERED_PART && can_p)
        return SPLIT_RECEIVER;
    double fpq = largest_form_factor(r, ep, eq), fqp = largest_form_factor(r, eq, ep);
    double bright = source_brightness(r, q);
    bool small = fpq * bright < r->eps && fqp * bright < r->eps && spread_bound(r, p, q, ep, fpq) <= r->eps_spread;
    bool split_already =
        r->m->cells[p].first_child >= 0 && r->h->covered[p] != COVERED_ALL && fpq >= r->eps / FOLLOW_SHADOW_DIV;
    enum shadow_side shadow = NO_SHADOW_EDGE;
    if (small && (split_already || shadow_test_worthwhile(r, p, q, eq, fmax(fpq, fqp))))
        shadow = shadow_edge(r, p, q);
    if ((small && shadow == NO_SHADOW_EDGE) || (!can_p && !can_q))
        return LINK;
    bool receiver_shadowed = shadow == SHADOW_ACROSS_RECEIVER && can_p;
    if (receiver_shadowed && (fqp >= RECEIVER_SHADOW_F || split_already))
        return SPLIT_RECEIVER; /* a link's shape is linear across p: it cannot follow the shadow's step */
    if (can_q && (fpq > fqp || !can_p))
        return SPLIT_SOURCE;
    return SPLIT_RECEIVER;
}

/* ---- refine ------------------------------------------------------------------------------- */

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
            bool split_source = verdict[k] == SPLIT_SOURCE;
            if (verdict[k] == LINK)
                refiner_add_link(r, t.p, t.q, t.F);
            if (verdict[k] == LINK || verdict[k] == NO_LINK)
                continue;
            int first = refiner_children(r, split_source ? t.q : t.p); /* the quadtree grows */
            if (first < 0 || pairs_push_children(&next, &next_count, &next_capacity, t, split_source, first))
                r->failed = r->failed ? r->failed : 1;
        }
        free(verdict);
        free(todo);
        todo = next;
        count = next_count;
    }
    free(todo);
}

/* ---- gather and push-pull --------------------------------------------------------------- */

/* Gather: every element receives rho Sum_links F_pq term_q (one more
 * bounce, R6), at each of its corners: F times the link's shape there
 * (linear across the receiver, hierarchy_shape_links). [exercise 3c.3] */
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

/* What a leaf adds of its own to term 0 (its emission) or term 1 (the
 * point lights' first shot, all of it on its unburied part). */
typedef enum { ADD_EMISSION, ADD_FIRST_SHOT, ADD_NOTHING } leaf_source;

/* Push-pull.  What e and its ancestors gathered (down, at e's corners) is
 * pushed to e's children interpolated at theirs (patch_mesh_child_values);
 * a leaf receives the mean over its corners (the mean of a bilinear or
 * linear function over the cell) and adds its source.  e's term is its
 * children's mean over their unburied area, pulled up. [exercise 3c.4] */
static vec3 push_pull(hierarchy *h, const patch_mesh *m, int e, const vec3 *down, leaf_source add,
                      const vec3 *first_shot)
{
    const mesh_cell *c = &m->cells[e];
    vec3 here[4], up = v3_splat(0.0);
    for (int k = 0; k < c->vertex_count; k++)
        here[k] = v3_add(down[k], h->gathered[4 * (size_t)e + (size_t)k]);
    if (c->first_child < 0) { /* a leaf */
        for (int k = 0; k < c->vertex_count; k++)
            up = v3_madd(up, here[k], 1.0 / c->vertex_count);
        if (add == ADD_EMISSION)
            up = v3_add(up, h->element[e].emission);
        if (add == ADD_FIRST_SHOT && h->unburied[e] > 0.0)
            up = v3_madd(up, first_shot[c->patch], 1.0 / h->unburied[e]);
        h->term[e] = up;
        return up;
    }
    double unburied_area = 0.0;
    for (int k = 0; k < 4; k++) {
        int child = c->first_child + k;
        vec3 child_down[4];
        patch_mesh_child_values(c->vertex_count, here, k, child_down);
        double weight = h->element[child].area * h->unburied[child];
        up = v3_madd(up, push_pull(h, m, child, child_down, add, first_shot), weight);
        unburied_area += weight;
    }
    h->term[e] = v3_scale(up, unburied_area > 0.0 ? 1.0 / unburied_area : 0.0);
    return h->term[e];
}

/* Push-pull from every root (nothing gathered above a root). */
static void push_pull_all(hierarchy *h, const patch_mesh *m, leaf_source add, const vec3 *first_shot)
{
    const vec3 nothing_above[4] = {{0}};
#pragma omp parallel for schedule(dynamic, 1)
    for (int root = 0; root < h->root_count; root++)
        push_pull(h, m, root, nothing_above, add, first_shot);
}

/* ---- the solve ---------------------------------------------------------------------------- */

/* The Neumann terms (R6) first..last summed into L per leaf: term 0 = E
 * pulled up, then term k + 1 = gather and push-pull of term k (plus the
 * point lights' first shot in term 1).  As chapter 3's Jacobi it records
 * the next term's power as the residual and stops at --tol or
 * --iterations. [exercise 3c.5] */
static void solve(hierarchical_state *st, double source_norm)
{
    hierarchy *h = &st->tree;
    const patch_mesh *m = &st->mesh;
    radiosity_stats *r = &st->stats;
    memset(h->gathered, 0, 4 * (size_t)h->element_count * sizeof *h->gathered);
    push_pull_all(h, m, ADD_EMISSION, st->first_shot); /* term 0 */
    for (int k = 0;; k++) {
        double power = 0.0;
        for (int i = 0; i < m->patch_count && k >= st->bounce_min; i++)
            if (m->patches[i].unburied > 0.0) /* the image and the probes see no buried leaf */
                st->radiance[i] = v3_add(st->radiance[i], h->term[m->patches[i].cell]);
        gather(h, m);
        push_pull_all(h, m, k == 0 ? ADD_FIRST_SHOT : ADD_NOTHING, st->first_shot); /* term k + 1 */
        for (int i = 0; i < m->patch_count; i++) { /* its power, on each leaf's unburied part */
            vec3 t = h->term[m->patches[i].cell];
            power += m->patches[i].area * m->patches[i].unburied * (fabs(t.x) + fabs(t.y) + fabs(t.z));
        }
        r->iterations = k + 1;
        record_residual(r, power / source_norm);
        r->converged = k >= st->bounce_max || r->residual <= st->opt.tolerance;
        if (r->converged || r->iterations >= st->opt.max_iterations)
            return;
    }
}

/* ---- the second pass: BF refinement ------------------------------------------------------- */

/* With a second pass, the first runs at this times --eps: it only has to
 * show where the light goes, and the second refines its links anyway
 * (measured on the Cornell box: the same error in 70 % of the time). */
static const double FIRST_PASS_COARSER = 2.0;

/* B per element from the first pass's links: every bounce of the
 * emission, summed until a term's power is below 1e-3 of the emission's. */
static void first_pass_solution(hierarchy *h, const patch_mesh *m, vec3 *B)
{
    memset(h->gathered, 0, 4 * (size_t)h->element_count * sizeof *h->gathered);
    memset(B, 0, (size_t)h->element_count * sizeof *B);
    push_pull_all(h, m, ADD_EMISSION, NULL);
    double first_power = 0.0;
    for (int k = 0; k < 1000; k++) {
        double power = 0.0;
        for (int e = 0; e < h->element_count; e++) {
            B[e] = v3_add(B[e], h->term[e]);
            if (m->cells[e].first_child < 0)
                power += h->element[e].area * h->unburied[e] * v3_average(h->term[e]);
        }
        first_power = k == 0 ? power : first_power;
        if (!(power > 1e-3 * first_power))
            return;
        gather(h, m);
        push_pull_all(h, m, ADD_NOTHING, NULL);
    }
}

/* The second pass (--eps-spread): solve on the first pass's links, then
 * judge them again with B known (source_brightness, spread_bound,
 * shadow_test_worthwhile) and --eps itself.  What the first pass split
 * stays split, and a link kept keeps its form factor.  B holds the
 * emission's light only: lit only by point lights, the second pass refines
 * by F alone. */
static int refine_again(hierarchical_state *st, refiner *r)
{
    hierarchy *h = &st->tree;
    size_t n = (size_t)h->element_count;
    vec3 *B = malloc(n * sizeof *B + 1), *lowest = malloc(n * sizeof *lowest + 1);
    vec3 *spread = malloc(n * sizeof *spread + 1);
    h->gathered = calloc(5 * n + 1, sizeof *h->gathered);
    long count = 0;
    pair *todo = NULL;
    if (B && lowest && spread && h->gathered) {
        h->term = h->gathered + 4 * n;
        first_pass_solution(h, r->m, B);
        hierarchy_leaf_spread(h, r->m, B, lowest, spread);
        todo = hierarchy_links_as_pairs(h, &count);
    }
    free(h->gathered);
    h->gathered = h->term = NULL;
    double mean = todo ? hierarchy_mean_reflected(h, r->m, B) : 0.0;
    r->count = 0;
    r->eps = st->opt.eps;
    if (mean > 0.0) {
        r->radiance = B;
        r->spread = spread;
        r->known = (int)n;
        r->mean_radiance = mean;
    }
    if (todo)
        refine_rounds(r, todo, count);
    free(B);
    free(lowest);
    free(spread);
    r->radiance = r->spread = NULL;
    return !todo || r->failed || hierarchy_store_links(h, r, &st->opt, &st->stats) ? -1 : 0;
}

/* ---- prepare: the hierarchy, the solve, the image ------------------------------------------- */

/* Steps 1-2: the roots, refined by the oracle from every pair of roots;
 * each link's form factor (R10); the second pass; the leaves become the
 * mesh's patches.  Refuses a --levels whose worst case passes the element
 * limit before allocating (hierarchy_levels). */
static int build(hierarchical_state *st, const scene *s, char *err, size_t err_size)
{
    hierarchy *h = &st->tree;
    const radiosity_options *o = &st->opt;
    int levels;
    if (hierarchy_levels(&st->mesh, o, &levels, err, err_size))
        return 2;
    double start = omp_get_wtime();
    refiner r = {.h = h,
                 .m = &st->mesh,
                 .s = s,
                 .point_to_polygon = point_to_polygon,
                 .eps = o->eps_spread > 0.0 ? FIRST_PASS_COARSER * o->eps : o->eps,
                 .eps_spread = o->eps_spread,
                 .levels = levels,
                 .smallest = v3_length(v3_sub(s->bounds.hi, s->bounds.lo)) / SMALLEST_PART};
    long count = 0;
    pair *todo = hierarchy_root_pairs(h, &st->mesh, s, &count);
    if (!todo)
        r.failed = 1;
    refine_rounds(&r, todo, count);
    if (!r.failed && hierarchy_store_links(h, &r, o, &st->stats))
        r.failed = 1;
    st->stats.first_pass_links = h->link_count;
    bool second = o->eps_spread > 0.0;
    if (!r.failed && second && (hierarchy_measure_unburied(h, &st->mesh, s) || refine_again(st, &r)))
        r.failed = r.failed ? r.failed : 1;
    if (!r.failed && hierarchy_measure_unburied(h, &st->mesh, s))
        r.failed = 1;
    refiner_free(&r);
    int status = hierarchy_complete(&r, o, &st->stats, err, err_size); /* with the links' shapes */
    st->stats.formfactor_s += omp_get_wtime() - start; /* refinement, the links' form factors and shapes */
    return status;
}

/* Step 3: the sources (point lights shoot once, R1, as in chapter 3) and
 * the solve; the leaves' radiance is the --bounces window. */
static int solve_step(hierarchical_state *st, const scene *s, char *err, size_t err_size)
{
    int n = st->mesh.patch_count;
    st->first_shot = calloc((size_t)n + 1, sizeof *st->first_shot);
    st->radiance = calloc((size_t)n + 1, sizeof *st->radiance);
    vec3 *source = calloc((size_t)n + 1, sizeof *source);
    if (!st->first_shot || !st->radiance || !source) {
        free(source);
        snprintf(err, err_size, "argv:0: out of memory for %d patches", n);
        return 2;
    }
    double start = omp_get_wtime();
    st->stats.visibility_rays += patch_mesh_point_lights(&st->mesh, s, st->first_shot);
    for (int i = 0; i < n; i++) {
        st->first_shot[i] = v3_mul(st->mesh.patches[i].albedo, v3_scale(st->first_shot[i], 1.0 / M_PI));
        source[i] = v3_add(st->mesh.patches[i].emission, st->first_shot[i]);
    }
    double source_norm = patch_mesh_power(&st->mesh, source);
    free(source);
    st->stats.solver_used = "hierarchical";
    st->stats.no_light = !(source_norm > 0.0);
    if (st->stats.no_light) { /* nothing emits: L = 0 solves L = E + K L exactly */
        st->stats.converged = true;
        record_residual(&st->stats, 0.0);
    } else
        solve(st, source_norm);
    st->stats.solve_s += omp_get_wtime() - start;
    return 0;
}

static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    hierarchical_state *st = state_pointer;
    st->bounce_min = o->bounce_min;
    st->bounce_max = o->bounce_max;
    st->quiet = o->quiet;
    st->opt.program = "03c_hierarchical";
    st->opt.hierarchical = true;
    if (radiosity_mesh_scene(&st->mesh, s, &st->opt, err, err_size)) /* 1. the roots */
        return 2;
    if (build(st, s, err, err_size)) /* 2. refine: elements and links */
        return 2;
    if (solve_step(st, s, err, err_size)) /* 3. L = E + K L over the links (R4-R6) */
        return 2;
    if (patch_mesh_smooth_radiance(&st->mesh, st->radiance)) { /* 4. the image lookup */
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    radiosity_report(&st->opt, &st->stats, st->mesh.patch_count, st->quiet);
    radiosity_view_set(&st->view, &st->opt, &st->stats, s, &st->mesh, st->radiance, o, false, point_to_polygon);
    return 0;
}

static void finish(void *state_pointer)
{
    hierarchical_state *st = state_pointer;
    patch_mesh_free(&st->mesh);
    hierarchy_free(&st->tree);
    free(st->first_shot);
    free(st->radiance);
    free(st->stats.history);
}

int main(int argc, char **argv)
{
    hierarchical_state state = {0};
    const chapter hierarchical = {
        .name = "03c_hierarchical",
        .description = "hierarchical radiosity: quadtrees of elements, links where the form factor (R10) is small, "
                       "L = E + KL by gather and push-pull (Neumann series R6); --out MESH.ply writes the leaves",
        .options = {{HIERARCHICAL_OPTIONS, &state.opt}},
        .default_spp = 1,
        .prepare = prepare,
        RADIOSITY_VIEW_FUNCTIONS, /* the patches seen, probed, their stats and mesh (radiosity_setup.h) */
        .finish = finish,
    };
    return render_main(argc, argv, &hierarchical, &state);
}
