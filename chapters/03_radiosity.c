/* 03_radiosity.c — Lecture 3: the rendering equation as a linear system; radiosity.
 *
 * For diffuse (Lambertian) surfaces the exitant radiance does not depend on
 * direction.  Split the surfaces into patches i, assume the radiance L_i is
 * constant on each, and the area form of the rendering equation (R9) becomes
 * the radiosity system
 *
 *   L_i = Le_i + rho_i * Sum_j F_ij L_j          i.e.  L = E + K L   (R4)
 *
 * with K = diag(rho) F and the form factors (R10)
 *
 *   F_ij = 1/A_i Int_{A_i} Int_{A_j} cos(theta) cos(theta') / (pi r^2) V dA' dA
 *
 * (in radiance units: the classical radiosity B_i = pi L_i; pi cancels).
 * Top to bottom: the form factors (R10); the Neumann series (R6) term by
 * term, which is Jacobi's iteration L <- E + K L; Gauss-Seidel, shooting
 * (progressive refinement) and the direct solve of (I - K) L = E (R5); then
 * prepare(), named steps like DoRad in Chen's rad.c (Graphics Gems II).
 *
 * Hierarchical radiosity (quadtrees, links by a refinement oracle, gather
 * and push-pull) is the lecture's third part: chapters/03c_hierarchical.c,
 * which uses point_to_polygon() from here (chapters/radiosity_model.h).
 * Around the lecture, in common/: the patch mesh, adaptive splitting, the
 * image lookup and the probes in patch_mesh.[ch]; the PLY mesh, the
 * form-factor table, per-surface stats in mesh_io.[ch]; Gaussian
 * elimination in dense_solve.[ch]; options, meshing steps, stats in
 * radiosity_setup.[ch].  Modelling choices (said once
 * on stderr): one-sided patches (backs black); mirror and glass spheres
 * unmeshed (they block light, carry none); mirrors, glass and Phong diffuse;
 * background seen only by camera rays; point lights shoot once (R1). */
#include <omp.h>
#include <stdlib.h>
#include <string.h>

#include "dense_solve.h"
#include "mesh_io.h"
#include "patch_mesh.h"
#include "radiosity_model.h"
#include "radiosity_setup.h"
#include "render.h"

typedef struct {
    radiosity_view view;        /* first: what the driver reads once solved (radiosity_setup.h) */
    radiosity_options opt;      /* the command line fills it (RADIOSITY_OPTIONS) */
    int bounce_min, bounce_max; /* --bounces: the Neumann terms kept (R6) */
    bool quiet;
    const scene *scene;  /* for F_ij computed on the spot (form_factor_at) */
    patch_mesh mesh;     /* the patches i: corners, normal, area A_i, albedo rho_i, emission Le_i */
    float *form_factors; /* F_ij at [i * n + j], or NULL (shooting computes them per shot) */
    vec3 *first_shot;    /* light from point lights reflected once: part of term 1 of (R6) */
    vec3 *source;        /* Le + first_shot: the right-hand side E of (R4), and its size as power */
    double source_norm;
    vec3 *radiance; /* L: the solution shown (the --bounces window) */
    radiosity_stats stats;
} radiosity_state;

/* ---- form factors (R10) ------------------------------------------------------------------ */

/* The inner integral of (R10) in closed form: the form factor from a
 * differential area at x (unit normal n) to a polygon, by Lambert's contour
 * formula (1760; Cohen & Wallace eq. 4.18, Baum et al. 1989):

 *   F_dA->P = 1/(2 pi) Sum_k  gamma_k  n . (r_k x r_k+1) / |r_k x r_k+1|,
 *
 * r_k the vectors from x to the corners, gamma_k the angle between r_k and
 * r_k+1.  Only the part of the polygon in front of x counts, so the polygon
 * is first clipped to the half-space n . (y - x) > 0.  Exact, however close
 * the polygon: the 1/r^2 of the kernel is integrated analytically, which is
 * what keeps patches that share an edge accurate (a centre-to-centre
 * cos cos A / (pi r^2) would be far off there). [exercise 3.1] */
double point_to_polygon(vec3 x, vec3 n, const vec3 *polygon, int count)
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

/* Pairs closer than this many radii get every quadrature point, others the centroid. */
static const double NEAR_FACTOR = 6.0;

/* F_ij (R10): unoccluded F times its visible part.  Unoccluded: the outer
 * integral over patch i by its quadrature points x_k (weights w_k), the inner
 * one by point_to_polygon.  Visible part: one ray from each x_k to a point
 * y_k of j (pairing shifted by a hash of (i, j)), weighted by the light it
 * carries, G_k = cos cos / r^2 (form_factor_kernel): sum w G V / sum w G.
 * Unweighted, the rays through a 1 mm slit under a box would pass for typical
 * ones; they run to the walls' feet, grazing the floor (16 % of the rays,
 * 3.5 % of F).  Deterministic. [exercise 3.2] */
static double form_factor_estimate(const radiosity_state *st, const scene *s, int i, int j, uint64_t *rays)
{
    if (i == j)
        return 0.0; /* a flat patch does not see itself */
    const patch_mesh *m = &st->mesh;
    const patch *pi = &m->patches[i], *pj = &m->patches[j];
    /* One-sided patches: j must be in front of i and i in front of j. */
    if (!patches_facing(pi, pj, s->epsilon))
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
    double unoccluded = 0.0, carried = 0.0, visible = 0.0;
    for (int k = 0; k < pi->point_count; k++) {
        vec3 x = m->points[pi->first_point + k];
        /* x must be in front of j too (one-sided j); its own clip handles j's part behind x. */
        if (v3_dot(pj->normal, v3_sub(x, pj->centroid)) <= s->epsilon)
            continue;
        double f = point_to_polygon(x, pi->normal, pj->corner, pj->corner_count);
        if (f <= 0.0)
            continue;
        vec3 y = m->points[pj->first_point + (int)((shift + (uint64_t)k) % (uint64_t)pj->point_count)];
        double weight = m->weights[pi->first_point + k], g = weight * form_factor_kernel(x, pi->normal, y, pj->normal);
        ++*rays;
        unoccluded += weight * f;
        carried += g;
        visible += scene_occluded(s, x, y) ? 0.0 : g;
    }
    return carried > 0.0 ? unoccluded * visible / carried : unoccluded; /* no ray carries any: j's points behind x */
}

/* The F_ij the solvers use: the estimate (reciprocity checked in the stats),
 * or with --reciprocity enforce the mean of A_i F_ij and A_j F_ji over A_i. */
static double form_factor(const radiosity_state *st, const scene *s, int i, int j, uint64_t *rays)
{
    double f = form_factor_estimate(st, s, i, j, rays);
    if (!st->opt.enforce_reciprocity)
        return f;
    double g = form_factor_estimate(st, s, j, i, rays);
    return 0.5 * (st->mesh.patches[i].area * f + st->mesh.patches[j].area * g) / st->mesh.patches[i].area;
}

/* F_ij from the matrix when there is one, otherwise computed on the spot. */
static double form_factor_at(const void *state_pointer, int i, int j, uint64_t *rays)
{
    const radiosity_state *st = state_pointer;
    if (st->form_factors)
        return st->form_factors[(size_t)i * (size_t)st->mesh.patch_count + (size_t)j];
    return form_factor(st, st->scene, i, j, rays);
}

/* ---- the Neumann series (R6) and the solvers (R5) ----------------------------------------- */

/* out = K x, i.e. out_i = rho_i Sum_j F_ij x_j: one more bounce. */
static void apply_transport(radiosity_state *st, const vec3 *x, vec3 *out)
{
    int n = st->mesh.patch_count;
    uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : rays)
    for (int i = 0; i < n; i++) {
        vec3 sum = v3_splat(0.0);
        for (int j = 0; j < n; j++)
            sum = v3_madd(sum, x[j], form_factor_at(st, i, j, &rays));
        out[i] = v3_mul(st->mesh.patches[i].albedo, sum);
    }
    st->stats.visibility_rays += rays;
}

/* The Neumann series (R6) term by term, adding term k to L for k in
 * [first, last]:  term 0 = E,  term 1 = K E + the point lights' first shot,
 * term k = K term k-1.  The next term is exactly the residual E + K L - L
 * of the sum so far: its size as power is recorded (patch_mesh_power;
 * ||K|| <= max rho < 1 in that norm, so residuals fall monotonically), and
 * the sum stops when it is below --tol or after --iterations terms.  This
 * is Jacobi's iteration L <- E + K L started from L = 0: after k
 * iterations L holds the first k terms.  0, or -1: OOM. [exercise 3.3] */
static int neumann_terms(radiosity_state *st, int first, int last, vec3 *L)
{
    int n = st->mesh.patch_count;
    vec3 *term = malloc((size_t)n * sizeof *term + 1), *next = malloc((size_t)n * sizeof *next + 1);
    for (int i = 0; term && next && i < n; i++)
        term[i] = st->mesh.patches[i].emission;
    for (int k = 0; term && next; k++) {
        for (int i = 0; i < n && k >= first; i++)
            L[i] = v3_add(L[i], term[i]);
        apply_transport(st, term, next); /* (R6): the next term, one more bounce */
        for (int i = 0; i < n && k == 0; i++)
            next[i] = v3_add(next[i], st->first_shot[i]);
        vec3 *swap = term;
        term = next;
        next = swap;
        st->stats.iterations = k + 1;
        record_residual(&st->stats, patch_mesh_power(&st->mesh, term) / st->source_norm);
        st->stats.converged = k >= last || st->stats.residual <= st->opt.tolerance;
        if (st->stats.converged || st->stats.iterations >= st->opt.max_iterations)
            break;
    }
    int failed = !term || !next;
    free(term);
    free(next);
    return failed ? -1 : 0;
}

/* Residual r = E + K L - L of the full system, as a fraction of the source power. */
static double full_residual(radiosity_state *st, const vec3 *L)
{
    int n = st->mesh.patch_count;
    vec3 *r = malloc((size_t)n * sizeof *r + 1);
    if (!r)
        return INFINITY; /* out of memory: reported as not converged */
    apply_transport(st, L, r);
    for (int i = 0; i < n; i++)
        r[i] = v3_sub(v3_add(st->source[i], r[i]), L[i]);
    double norm = patch_mesh_power(&st->mesh, r) / st->source_norm;
    free(r);
    return norm;
}

/* Gauss-Seidel: the Jacobi update, but each L_i uses the values already
 * updated in this sweep.  Each update zeroes r_i and moves at most rho of it
 * to the others, so the residual falls every sweep. [exercise 3.4] */
static int solve_gauss_seidel(radiosity_state *st, vec3 *L)
{
    int n = st->mesh.patch_count;
    for (st->stats.iterations = 1;; st->stats.iterations++) {
        for (int i = 0; i < n; i++) {
            vec3 gathered = v3_splat(0.0);
            for (int j = 0; j < n; j++)
                gathered = v3_madd(gathered, L[j], form_factor_at(st, i, j, NULL));
            L[i] = v3_add(st->source[i], v3_mul(st->mesh.patches[i].albedo, gathered));
        }
        record_residual(&st->stats, full_residual(st, L));
        st->stats.converged = st->stats.residual <= st->opt.tolerance;
        if (st->stats.converged || st->stats.iterations >= st->opt.max_iterations)
            return 0;
    }
}

/* Progressive refinement (Cohen et al. 1988) as Southwell relaxation: keep
 * the residual r = E + K L - L, exactly the light received but not yet shot.
 * Start with L = 0, r = source.  A shot from patch j moves r_j into L_j and
 * sends it on: r_i += rho_i F_ij r_j for every i, with the column F_.j
 * computed for the shot and thrown away (memory O(n), not O(n^2)). [exercise 3.5] */
static int solve_shooting(radiosity_state *st, const scene *s, vec3 *L)
{
    int n = st->mesh.patch_count;
    vec3 *unshot = malloc((size_t)n * sizeof *unshot + 1);
    double *column = malloc((size_t)n * sizeof *column + 1);
    if (!unshot || !column) {
        free(unshot);
        free(column);
        return -1;
    }
    memcpy(unshot, st->source, (size_t)n * sizeof *unshot);
    long max_shots = (long)st->opt.max_iterations * n, shot = 0;
    double residual = patch_mesh_power(&st->mesh, unshot) / st->source_norm;
    while (residual > st->opt.tolerance && shot < max_shots) {
        int j = 0; /* the patch with the most unshot power shoots (Chen's FindShootPatch) */
        for (int i = 0; i < n; i++)
            if (st->mesh.patches[i].area * (unshot[i].x + unshot[i].y + unshot[i].z) >
                st->mesh.patches[j].area * (unshot[j].x + unshot[j].y + unshot[j].z))
                j = i;
        vec3 shooting = unshot[j];
        L[j] = v3_add(L[j], shooting);
        unshot[j] = v3_splat(0.0);
        uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 64) reduction(+ : rays)
        for (int i = 0; i < n; i++)
            column[i] = form_factor(st, s, i, j, &rays);
        st->stats.visibility_rays += rays;
        for (int i = 0; i < n; i++)
            unshot[i] = v3_add(unshot[i], v3_scale(v3_mul(st->mesh.patches[i].albedo, shooting), column[i]));
        residual = patch_mesh_power(&st->mesh, unshot) / st->source_norm;
        shot++;
        if (shot % n == 0)
            record_residual(&st->stats, residual);
    }
    if (shot % n != 0 || shot == 0)
        record_residual(&st->stats, residual);
    st->stats.shots = (int)shot;
    st->stats.iterations = (int)((shot + n - 1) / n);
    st->stats.converged = residual <= st->opt.tolerance;
    /* For display, the unshot light is radiance of its patch already, and the light
     * still to come is guessed by Cohen et al.'s ambient term (patch_mesh.h). */
    patch_mesh_add_ambient(&st->mesh, unshot, L);
    free(unshot);
    free(column);
    return 0;
}

/* (R5) directly: (I - K) L = source, one channel at a time, by Gaussian
 * elimination (dense_solve.h; O(n^3): the reference for small n). */
static int solve_direct(radiosity_state *st, vec3 *L)
{
    size_t n = (size_t)st->mesh.patch_count;
    if (n > 4000 && !st->quiet)
        fprintf(stderr, "03_radiosity: direct solve of %zu patches: O(n^3) = %.2g operations per channel\n", n,
                (double)n * n * n / 3.0);
    double *a = malloc(n * n * sizeof *a + 1), *b = malloc(n * sizeof *b + 1);
    for (int channel = 0; a && b && channel < 3; channel++) {
        for (size_t i = 0; i < n; i++) {
            double rho = v3_get(st->mesh.patches[i].albedo, channel);
            for (size_t j = 0; j < n; j++)
                a[i * n + j] = (i == j) - rho * st->form_factors[i * n + j];
            b[i] = v3_get(st->source[i], channel);
        }
        dense_solve(a, b, n); /* b <- (I - K)^-1 b */
        for (size_t i = 0; i < n; i++)
            L[i] = v3(channel == 0 ? b[i] : L[i].x, channel == 1 ? b[i] : L[i].y, channel == 2 ? b[i] : L[i].z);
    }
    int failed = !a || !b;
    free(a);
    free(b);
    st->stats.iterations = 1;
    record_residual(&st->stats, failed ? INFINITY : full_residual(st, L));
    st->stats.converged = st->stats.residual <= fmax(st->opt.tolerance, 1e-9);
    return failed ? -1 : 0;
}

/* ---- prepare: Chen's DoRad, four named steps --------------------------------------------- */

/* The arrays of step 2, one per meaning, for the current mesh (--adaptive
 * remeshes and comes back).  0, or 2 with a message. */
static int allocate_patch_arrays(radiosity_state *st, char *err, size_t err_size)
{
    size_t n = (size_t)st->mesh.patch_count;
    free(st->form_factors);
    free(st->first_shot);
    free(st->source);
    free(st->radiance);
    st->form_factors = NULL;
    st->first_shot = calloc(n + 1, sizeof *st->first_shot);
    st->source = calloc(n + 1, sizeof *st->source);
    st->radiance = calloc(n + 1, sizeof *st->radiance);
    if (st->first_shot && st->source && st->radiance)
        return 0;
    snprintf(err, err_size, "argv:0: out of memory for %zu patches", n);
    return 2;
}

/* Step 2: the sources and the form factors.  Point lights shoot first: each
 * patch reflects rho E / pi of their irradiance E = I cos / r^2 (R1), light
 * bounced once (part of K E).  Then F_ij (R10), unless the solver shoots. */
static int compute_form_factors(radiosity_state *st, const scene *s, char *err, size_t err_size)
{
    int n = st->mesh.patch_count;
    if (radiosity_check_matrix_size(&st->opt, n, err, err_size) || allocate_patch_arrays(st, err, err_size))
        return 2;
    double start = omp_get_wtime();
    st->stats.visibility_rays += patch_mesh_point_lights(&st->mesh, s, st->first_shot);
    for (int i = 0; i < n; i++)
        st->first_shot[i] = v3_mul(st->mesh.patches[i].albedo, v3_scale(st->first_shot[i], 1.0 / M_PI));
    if (st->opt.solver != SOLVER_SHOOTING) { /* F_ij for every pair, in parallel */
        st->form_factors = malloc((size_t)n * (size_t)n * sizeof *st->form_factors + 1);
        if (!st->form_factors) {
            snprintf(err, err_size, "argv:0: out of memory for the %d x %d form-factor matrix", n, n);
            return 2;
        }
        uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 8) reduction(+ : rays)
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++)
                st->form_factors[(size_t)i * (size_t)n + (size_t)j] = (float)form_factor(st, s, i, j, &rays);
        radiosity_stats *r = &st->stats; /* and the checks: row sums, reciprocity (mesh_io.h) */
        r->visibility_rays += rays;
        r->have_matrix_checks = true;
        form_factor_checks(st->form_factors, &st->mesh, &r->reciprocity_error, &r->row_sum_min, &r->row_sum_max);
        radiosity_warn_row_sums(st->form_factors, &st->mesh, s, &st->opt);
    }
    st->stats.formfactor_s += omp_get_wtime() - start;
    return 0;
}

/* The full solution by the chosen solver; with --bounces A (no upper end)
 * the terms 0 .. A-1 are computed first and taken away from it. */
static int solve_full(radiosity_state *st, const scene *s)
{
    int n = st->mesh.patch_count, failed = 0;
    vec3 *head = calloc((size_t)n + 1, sizeof *head);
    if (!head)
        return -1;
    if (st->bounce_min > 0) {
        failed = neumann_terms(st, 0, st->bounce_min - 1, head);
        st->stats.history_count = 0; /* the solver's residuals are the ones reported */
    }
    if (!failed && st->opt.solver == SOLVER_GAUSS_SEIDEL)
        failed = solve_gauss_seidel(st, st->radiance);
    else if (!failed && st->opt.solver == SOLVER_SHOOTING)
        failed = solve_shooting(st, s, st->radiance);
    else if (!failed)
        failed = solve_direct(st, st->radiance);
    for (int i = 0; i < n; i++)
        st->radiance[i] = v3_sub(st->radiance[i], head[i]);
    free(head);
    return failed;
}

/* Step 3: solve L = E + K L; st->radiance gets the --bounces window. */
static int solve(radiosity_state *st, const scene *s, char *err, size_t err_size)
{
    int n = st->mesh.patch_count, failed = 0;
    double start = omp_get_wtime();
    for (int i = 0; i < n; i++)
        st->source[i] = v3_add(st->mesh.patches[i].emission, st->first_shot[i]);
    st->source_norm = patch_mesh_power(&st->mesh, st->source);
    radiosity_stats *r = &st->stats;
    r->history_count = 0;
    r->converged = false;
    r->shots = 0;
    r->no_light = !(st->source_norm > 0.0);
    r->solver_used = solver_names[st->opt.solver];
    if (r->no_light) { /* nothing emits: L = 0 solves L = E + K L exactly */
        r->iterations = 0;
        r->converged = true;
        record_residual(r, 0.0);
    } else if (st->opt.solver == SOLVER_JACOBI || st->bounce_max < RENDER_BOUNCES_UNLIMITED) {
        /* A window with an upper end is a finite sum of Neumann terms: computed
         * as such whatever the solver (the other solvers do not separate bounces). */
        r->solver_used = "jacobi";
        failed = neumann_terms(st, st->bounce_min, st->bounce_max, st->radiance);
    } else
        failed = solve_full(st, s);
    r->solve_s += omp_get_wtime() - start;
    if (failed)
        snprintf(err, err_size, "argv:0: out of memory while solving for %d patches", n);
    return failed ? 2 : 0;
}

/* Chen's DoRad: 1. mesh, 2. sources and form factors, 3. solve (again on a
 * finer mesh with --adaptive), 4. the image lookup. */
static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    radiosity_state *st = state_pointer;
    st->bounce_min = o->bounce_min;
    st->bounce_max = o->bounce_max;
    st->quiet = o->quiet;
    st->scene = s;
    st->opt.program = "03_radiosity";
    if (radiosity_mesh_scene(&st->mesh, s, &st->opt, err, err_size)) /* 1. the surfaces cut into patches */
        return 2;
    for (int split = 1; split > 0;) {
        if (compute_form_factors(st, s, err, err_size)) /* 2. the sources and F_ij (R10) */
            return 2;
        if (solve(st, s, err, err_size)) /* 3. L = E + K L (R4-R6) */
            return 2;
        split = radiosity_refine(&st->mesh, s, &st->opt, &st->stats, st->radiance, st->quiet, err, err_size);
        if (split < 0) /* --adaptive: patches split where the radiance jumps, back to 2 */
            return 2;
    }
    if (patch_mesh_smooth_radiance(&st->mesh, st->radiance)) { /* 4. the image lookup (smooth shading) */
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    if (write_surface_form_factors(st->opt.formfactors_path, s, &st->mesh, form_factor_at, st,
                                   &st->stats.visibility_rays, err, err_size)) /* --formfactors F.csv */
        return 2;
    radiosity_report(&st->opt, &st->stats, st->mesh.patch_count, st->quiet);
    radiosity_view_set(&st->view, &st->opt, &st->stats, s, &st->mesh, st->radiance, o, st->form_factors != NULL,
                       point_to_polygon);
    return 0;
}

static void finish(void *state_pointer)
{
    radiosity_state *st = state_pointer;
    patch_mesh_free(&st->mesh);
    free(st->form_factors);
    free(st->first_shot);
    free(st->source);
    free(st->radiance);
    free(st->stats.history);
}

int main(int argc, char **argv)
{
    radiosity_state state = {0};
    const chapter radiosity = {
        .name = "03_radiosity",
        .description = "radiosity: patches, form factors (R10), L = E + KL solved by Jacobi (= Neumann series R6), "
                       "Gauss-Seidel, shooting or directly (R5); --out MESH.ply writes the patch mesh",
        .options = {{RADIOSITY_OPTIONS, &state.opt}},
        .default_spp = 1,
        .prepare = prepare,
        RADIOSITY_VIEW_FUNCTIONS, /* the patches seen, probed, their stats and mesh (radiosity_setup.h) */
        .finish = finish,
    };
    return render_main(argc, argv, &radiosity, &state);
}
