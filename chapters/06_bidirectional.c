/* 06_bidirectional.c — Lecture 6: bidirectional methods.
 *
 * Path tracing (chapter 4) builds paths from the eye, photon mapping (chapter 5) from the lights.  A path x_0 (a
 * light) ... x_k (the eye) of k edges carries the term K^(k-1) E (R6); a pixel is the path integral ((R9) unrolled)
 *
 *   (R13)  I_j = sum_k Int L_e(x_0) G(x_0,x_1) f(x_1) G(x_1,x_2) ... f(x_(k-1)) G(x_(k-1),x_k) W_e(x_k) dA_0 .. dA_k
 *
 * One path can be drawn in k + 2 ways (strategies): s vertices from a light, t = k + 1 - s from the eye, joined by
 * a shadow ray.  Each has its density (R14); their power heuristic weights (R15) add to 1 on every path.  --method:
 *   1. light  light tracing: every vertex of a light subpath joined to the camera (t = 1), in the pixel it is seen;
 *   2. bdpt   every (s, t), weighted by (R15) computed plainly from the path's densities (R14);
 *   3. vcm    (the default) also chapter 5's estimate (R11) as one more strategy (R16) at eye vertices seen in a
 *             mirror or glass, radius (R12).  --merge off is bdpt; --connect off progressive photon mapping.
 * --strategy S,T: one strategy, unweighted.  --check N: weights and densities tested on random paths.  Probes and
 * surface means (walk_stats.h) put a sensor in the camera's place: sensor_sample.  Each pass traces one light subpath
 * per pixel (begin_pass: light tracing, the photon grid); pixel p's camera ray makes one eye subpath, joined to p's. */
#include <string.h>

#include "render.h"
#include "sampling.h"
#include "bidir_store.h" /* bookkeeping: the state, options, storage of light subpaths, stats */
#include "bidir_model.h" /* what chapter 7 uses of this one; chapter 5's as_flux, chapter 4's f, pdfs, scattering */

/* A path x_0 .. x_k of k edges is the term K^(k-1) E (R6): does --bounces A:B keep it?  At a sensor (probes,
 * surface means: sensor_sample) x_(k-1) is the sensor's point, whose reflection is bounce x_k.surface (0 or 1). */
bool keeps_length(const bidir_state *st, const path_vertex *x, int k)
{
    return bounces_keep(st->bounces, k - 1 - (x[k].kind == AT_SENSOR ? 1 - x[k].surface : 0));
}

static vec3 unit(vec3 from, vec3 to) { return v3_normalize(v3_sub(to, from)); }
static bool at_specular(const path_vertex *p) { return p->specular; } /* is_specular(m) where it was made */

/* |cos| between the normal at p and w; 1 at the camera and a point light (they have no surface). */
static double cos_at(const path_vertex *p, vec3 w) { return p->kind == AT_SURFACE ? fabs(v3_dot(p->n, w)) : 1.0; }

/* (R8) G(a, b) = cos cos / |a - b|^2. */
static double geometry(const path_vertex *a, const path_vertex *b)
{
    double d = v3_length(v3_sub(b->x, a->x));
    vec3 w = unit(a->x, b->x);
    return cos_at(a, w) * cos_at(b, w) / (d * d);
}

/* ---- the camera: W_e (R13) ---------------------------------------------------------------------- */

/* Pixel j measures the mean radiance over its square (area A_pix) on the image plane at distance 1.  A point there
 * at the angle theta off the axis is seen in the solid angle dw = cos^3(theta) dA, so the importance of (R13) is
 * W_e = 1 / (A_pix cos^3 theta) per steradian inside the pixel (0 outside): also the density of the eye ray through
 * the pixel, so an eye subpath starts with weight W_e / p = 1.  No light path hits the pinhole. [exercise 6.1] */
static double camera_importance(const pinhole *c, double cos_theta)
{
    return 1.0 / (c->pixel_area * cos_theta * cos_theta * cos_theta);
}

/* ---- subpaths ----------------------------------------------------------------------------------- */

/* Extend subpath p (count vertices, the last one left toward w with weight alpha) by a random walk as chapter 4's
 * (R2), up to `cap` vertices; a light subpath carries flux (chapter 5's as_flux).  Returns the new count. */
int extend(const scene *s, path_vertex *p, int count, int cap, vec3 alpha, vec3 w, bool roulette, bool flux, rng *g,
           uint64_t *rays)
{
    for (; count < cap; count++) {
        hit h;
        ++*rays;
        if (!scene_intersect(s, (ray){scene_offset_origin(s, p[count - 1].x, p[count - 1].n, w), w}, INFINITY, &h))
            return count;
        const material *m = material_of(s, h.surface);
        p[count] = (path_vertex){h.point, h.normal, alpha, m, AT_SURFACE, h.surface, count, is_specular(m)};
        vertex v = vertex_at(h.point, h.normal, v3_neg(w), m);
        vec3 w_i = {0}; /* set: a handout's stub of scatter returns zero without writing it */
        double pdf;
        vec3 weight = scatter(&v, sample_bsdf, g, &w_i, &pdf); /* f cos / p (R2) */
        if (flux)
            weight = as_flux(&v, weight, w_i);
        if (!(v3_max_component(weight) > 0.0) || (roulette && !survives_roulette(&weight, g)))
            return count + 1;
        alpha = v3_mul(alpha, weight);
        w = w_i;
    }
    if (cap == MAX_VERTICES)
        note_truncated_walk();
    return count;
}

/* x_0's density per unit area: the light's pick by power over its area (a point light: the pick; x_0 is given). */
static double light_point_pdf(const bidir_state *st, const scene *s, const path_vertex *x0)
{
    return x0->kind == AT_POINT_LIGHT ? st->light_probability[s->surface_count + x0->surface]
                                      : st->light_probability[x0->surface] / s->surfaces[x0->surface].area;
}

/* A light subpath: a light picked by power, a point on it, a direction drawn like the emitted power (cosine; a
 * point light: the sphere), then a walk.  y_0's weight is 1 / its density, y_1's L_e cos / p(w) more. */
int light_subpath(const bidir_state *st, const scene *s, rng *g, path_vertex *y, uint64_t *rays, bool roulette)
{
    int i = pick_light(st, s, rng_uniform(g));
    double u1 = rng_uniform(g), u2 = rng_uniform(g);
    vec3 w, power;
    if (i >= s->surface_count) {
        const point_light *l = &s->lights[i - s->surface_count];
        y[0] = (path_vertex){.x = l->position, .kind = AT_POINT_LIGHT, .surface = i - s->surface_count};
        w = uniform_sample_sphere(u1, u2);
        power = v3_scale(l->intensity, 4.0 * M_PI); /* I / (1 / 4 pi) */
    } else {
        y[0] = (path_vertex){.m = material_of(s, i), .kind = AT_SURFACE, .surface = i};
        surface_sample_point(s, i, u1, u2, rng_uniform(g), &y[0].x, &y[0].n);
        w = onb_to_world(onb_from_normal(y[0].n), cosine_sample_hemisphere(rng_uniform(g), rng_uniform(g)));
        power = v3_scale(y[0].m->emission, M_PI); /* L_e cos / (cos / pi) */
    }
    double pdf = light_point_pdf(st, s, &y[0]);
    if (!(pdf > 0.0))
        return 0;
    y[0].alpha = v3_splat(1.0 / pdf);
    return extend(s, y, 1, st->light_cap, v3_scale(power, 1.0 / pdf), w, roulette, true, g, rays);
}

/* What vertex i of subpath p sends toward w of what reached it from vertex i - 1: at a light's own point its L_e (a
 * point light: I), elsewhere f (R2); nothing through a surface, nothing off a mirror or glass (a delta). */
static vec3 vertex_f(const scene *s, const path_vertex *p, int i, vec3 w)
{
    if (i == 0 && p[0].kind == AT_POINT_LIGHT)
        return s->lights[p[0].surface].intensity;
    if (i == 0)
        return p[0].m->kind == MATERIAL_EMITTER && v3_dot(p[0].n, w) > 0.0 ? p[0].m->emission : v3_splat(0.0);
    vertex v = vertex_at(p[i].x, p[i].n, unit(p[i].x, p[i - 1].x), p[i].m);
    return v3_dot(v.n, w) > 0.0 && !is_specular(v.m) ? bsdf_f(&v, w) : v3_splat(0.0);
}

/* ---- 1. light tracing: strategies (s, 1) -------------------------------------------------------- */

/* Light subpath vertex y_{s-1} joined to the eye by a shadow ray: the pixel it is seen in gets alpha f G W_e / N
 * (R13), N light subpaths per pass. [exercise 6.2] */
static bool connect_to_camera(const bidir_state *st, const scene *s, const path_vertex *y, int s_count, int *pixel,
                              vec3 *value, uint64_t *rays)
{
    const path_vertex *last = &y[s_count - 1];
    path_vertex eye = {.x = st->camera.eye, .kind = AT_CAMERA};
    vec3 w = unit(last->x, eye.x);
    double cos_theta;
    vec3 f = vertex_f(s, y, s_count - 1, w);
    if (!pixel_seen(&st->camera, v3_neg(w), pixel, &cos_theta) || !(v3_max_component(f) > 0.0))
        return false;
    ++*rays;
    vec3 sensor; /* the eye, or camera.near from it (scene.h): where camera rays start */
    if (!pinhole_sensor_point(&st->camera, last->x, &sensor) || scene_occluded(s, last->x, sensor))
        return false;
    double G = geometry(last, &eye); /* the cosine at a pinhole is in W_e */
    *value = v3_scale(v3_mul(last->alpha, f), G * camera_importance(&st->camera, cos_theta) / st->light_paths);
    return true;
}

/* ---- 2. bidirectional path tracing: every (s, t), weighted by (R15) ---------------------------- */

/* The path x_0 .. x_k of a strategy: y_0 .. y_{s-1}, then z_{t-1} .. z_0. */
int join(const path_vertex *y, int s_count, const path_vertex *z, int t_count, path_vertex *x)
{
    memcpy(x, y, (size_t)s_count * sizeof *x);
    for (int i = 0; i < t_count; i++)
        x[s_count + i] = z[t_count - 1 - i];
    return s_count + t_count - 1;
}

/* The density per steradian of direction x_j -> x_{j+dir} as a walk from x_{j-dir} draws it (dir 1: light, -1: eye). */
static double direction_pdf(const path_vertex *x, const path_edges *e, int j, int dir, const pinhole *c)
{
    vec3 w = path_toward(e, j, dir);
    if (x[j].kind == AT_CAMERA)
        return camera_importance(c, v3_dot(w, c->forward)); /* W_e is the eye ray's density */
    if (j == 0)
        return x[0].kind == AT_POINT_LIGHT ? uniform_sphere_pdf() : cosine_hemisphere_pdf(v3_dot(x[0].n, w));
    vertex v = vertex_at(x[j].x, x[j].n, path_toward(e, j, -dir), x[j].m);
    return bsdf_pdf(&v, w);
}

/* (R14) The density per unit area of x_i as the walk in direction dir drew it: p(w) at the last non-specular vertex
 * x_j before it, times cos theta_i over the squared length D of the way from x_j (through mirrors and glass,
 * unfolded) to x_i (R7).  A light's own point: light_point_pdf; the eye: 1 (a delta in all). [exercise 6.3] */
static double area_pdf(const bidir_state *st, const scene *s, const path_vertex *x, const path_edges *e, int k, int i,
                       int dir)
{
    if (dir == 1 && i == 0)
        return light_point_pdf(st, s, &x[0]);
    if (dir == -1 && (i == k || (i == k - 1 && x[k].kind == AT_SENSOR))) /* a sensor's point is given too */
        return 1.0;
    double D = 0.0;
    int j = i;
    do {
        D += e->d[dir == 1 ? j - 1 : j]; /* |x_j - x_{j-dir}| */
        j -= dir;
    } while (at_specular(&x[j]));
    return direction_pdf(x, e, j, dir, &st->camera) * cos_at(&x[i], path_toward(e, i, -dir)) / (D * D);
}

/* Merging (R16) at vertex v, whose neighbour toward the eye is n: VCM merges only where the eye sees v in a mirror
 * or glass (L .. D S .. E): elsewhere a join makes the path as well, and a merge adds a photon search and blur. */
static bool may_merge_at(const bidir_state *st, const path_vertex *v, const path_vertex *n)
{
    return st->merge && !at_specular(v) && (!st->connect || at_specular(n));
}

/* Can the method make x_0 .. x_k by joining s light to t = k + 1 - s eye vertices (or merging at x_s)?  Not through a
 * delta: a mirror, glass, the pinhole (t = 0), a point light (s = 0). */
bool strategy_allowed(const bidir_state *st, const path_vertex *x, int k, technique how, int s)
{
    int t = k + 1 - s;
    bool sensor = x[k].kind == AT_SENSOR; /* its point is z_1, given: no (s, 1), no merging, no L_e there */
    if (s > st->light_cap || t > st->eye_cap || (sensor && (how == MERGE || t < 2 || k < 2)))
        return false;
    if (st->single_strategy)
        return how == CONNECT && s == st->strategy_s && t == st->strategy_t;
    if (how == MERGE)
        return s >= 1 && t >= 2 && may_merge_at(st, &x[s], &x[s + 1]) && (st->connect || first_from_eye(x, k) == s);
    if (t == 0 || (s == 0 && x[0].kind == AT_POINT_LIGHT) || (s >= 1 && (at_specular(&x[s - 1]) || at_specular(&x[s]))))
        return false;
    if (!st->connect && !sensor)
        return s == 0 && first_from_eye(x, k) == 0;
    return st->method != METHOD_LIGHT || t == 1 + sensor;
}

/* (R15) n_s p_s: the strategy's samples per pixel (N light subpaths for t = 1 and merging, else 1) times its density,
 * the product over the path's non-specular vertices of the light walk's pdf_light for the first s and the eye walk's
 * pdf_eye for the rest (R14); merging at x_s also needs a light vertex within r of it: pdf_light(x_s) pi r^2 (R16). */
static double strategy_density(const bidir_state *st, const path_vertex *x, int k, const double *pdf_light,
                               const double *pdf_eye, const double *merge_chance, technique how, int s)
{
    double p = how == MERGE ? st->light_paths * merge_chance[s] : k + 1 - s == 1 ? st->light_paths : 1.0;
    for (int i = 0; i <= k; i++)
        if (!at_specular(&x[i]))
            p *= i < s ? pdf_light[i] : pdf_eye[i];
    return p;
}

/* (R14) Both densities of every vertex of x_0 .. x_k, and (R16) the chance of a light vertex within r of it. */
static void path_pdfs(const bidir_state *st, const scene *s, const path_vertex *x, int k, double *pdf_light,
                      double *pdf_eye, double *merge_chance)
{
    path_edges e; /* the directions and lengths of x's edges */
    path_edges_of(x, k, &e);
    for (int i = 0; i <= k; i++) {
        pdf_light[i] = area_pdf(st, s, x, &e, k, i, 1);
        pdf_eye[i] = area_pdf(st, s, x, &e, k, i, -1);
        merge_chance[i] = pdf_light[i] * M_PI * st->current_radius * st->current_radius;
    }
}

/* (R15) The power heuristic, plainly: (n_s p_s)^2 over the sum of (n_j p_j)^2 over every strategy j the method has
 * for x_0 .. x_k.  Dividing both densities of one vertex by the same number changes no weight (every strategy takes
 * one of them), so each is divided by the larger: a long path in millimetres does not underflow.  If the strategy's
 * own density still does, the path is dropped (weight 0, counted in the stats). [exercise 6.4] */
double mis_weight(const bidir_state *st, const scene *s, const path_vertex *x, int k, technique how, int used)
{
    double pdf_light[MAX_PATH], pdf_eye[MAX_PATH], merge_chance[MAX_PATH], sum = 0.0;
    if (st->single_strategy)
        return 1.0;
    path_pdfs(st, s, x, k, pdf_light, pdf_eye, merge_chance);
    for (int i = 0; i <= k; i++) {
        double larger = fmax(pdf_light[i], pdf_eye[i]);
        pdf_light[i] /= larger > 0.0 ? larger : 1.0;
        pdf_eye[i] /= larger > 0.0 ? larger : 1.0;
    }
    double p = strategy_density(st, x, k, pdf_light, pdf_eye, merge_chance, how, used);
    for (int j = 0; j <= k + 1; j++) { /* merging at x_j (t >= 2) is joining there (n = 1) times N pi r^2 pdf_light */
        bool join = strategy_allowed(st, x, k, CONNECT, j), merge = strategy_allowed(st, x, k, MERGE, j);
        double q = join || merge ? strategy_density(st, x, k, pdf_light, pdf_eye, merge_chance, CONNECT, j) : 0.0;
        sum += (join ? q * q : 0.0) + (merge ? pow(q * st->light_paths * merge_chance[j], 2.0) : 0.0);
    }
    if (p > 0.0 && sum > 0.0 && isfinite(sum))
        return p * p / sum;
    note_dropped_path();
    return 0.0;
}

/* Strategy (s, t), s >= 1, t >= 2: y_{s-1} joined to z_{t-1} by a shadow ray: alpha_L f G f alpha_E, (R13)'s
 * integrand over the subpaths' densities. [exercise 6.5] */
static vec3 connect(const scene *s, const path_vertex *y, int s_count, const path_vertex *z, int t_count,
                    uint64_t *rays)
{
    const path_vertex *a = &y[s_count - 1], *b = &z[t_count - 1];
    vec3 w = unit(a->x, b->x);
    vec3 f = v3_mul(vertex_f(s, y, s_count - 1, w), vertex_f(s, z, t_count - 1, v3_neg(w)));
    if (!(v3_max_component(f) > 0.0))
        return v3_splat(0.0);
    ++*rays;
    if (scene_occluded(s, a->x, b->x))
        return v3_splat(0.0);
    return v3_scale(v3_mul(v3_mul(a->alpha, f), b->alpha), geometry(a, b));
}

/* The unweighted value of strategy (s, t) on subpaths y, z: (R13)'s integrand over (R14)'s density as they carry
 * it.  s = 0: the eye subpath found the light by itself; t = 1: light tracing (into *pixel); else a join. */
vec3 strategy_value(const bidir_state *st, const scene *s, const path_vertex *y, int s_count, const path_vertex *z,
                    int t, int *pixel, uint64_t *rays)
{
    vec3 C = v3_splat(0.0);
    if (s_count == 0)
        return v3_mul(z[t - 1].alpha, vertex_f(s, &z[t - 1], 0, unit(z[t - 1].x, z[t - 2].x)));
    if (t == 1)
        return connect_to_camera(st, s, y, s_count, pixel, &C, rays) ? C : v3_splat(0.0);
    return connect(s, y, s_count, z, t, rays);
}

/* Every strategy ending at eye vertex z_{t-1} (t >= 2): the light it finds (s = 0), its joins to y; weights (R15). */
static vec3 connections(const bidir_state *st, const scene *s, const path_vertex *y, int light_count,
                        const path_vertex *z, int t, uint64_t *rays)
{
    path_vertex x[MAX_PATH];
    vec3 L = v3_splat(0.0);
    for (int s_count = 0, pixel; s_count <= light_count; s_count++) {
        int k = bidir_join_step(x, y, s_count, z, t); /* join(): x held s_count - 1's path */
        if (!keeps_length(st, x, k) || !strategy_allowed(st, x, k, CONNECT, s_count))
            continue;
        vec3 C = strategy_value(st, s, y, s_count, z, t, &pixel, rays);
        if (v3_max_component(C) > 0.0)
            L = v3_add(L, v3_scale(C, mis_weight(st, s, x, k, CONNECT, s_count)));
    }
    return L;
}

/* ---- 3. vertex merging (R16) -------------------------------------------------------------------- */

/* Merging at eye vertex z = z_{t-1}: every light vertex y_j (j >= 1) of the pass within r of z counts as chapter
 * 5's photon (R11), on a surface facing the same way: alpha_L f alpha_E / (N pi r^2), weighted by (R15) against the
 * joins and the other merges. [exercise 6.6] */
static vec3 merges(const bidir_state *st, const scene *s, const path_vertex *z, int t, render_counters *counters)
{
    path_vertex x[MAX_PATH];
    vertex v = vertex_at(z[t - 1].x, z[t - 1].n, unit(z[t - 1].x, z[t - 2].x), z[t - 1].m);
    double r2 = st->current_radius * st->current_radius, d2;
    vec3 L = v3_splat(0.0);
    photon_grid_cursor c;
    uint32_t i;
    for (photon_grid_search(&st->grid, v.x, r2, &c); photon_grid_next(&st->grid, &c, &i, &d2);) {
        const path_vertex *y = &st->light_vertices[i], *first = y - y->index;
        vec3 from = y->index > 0 ? unit(y->x, y[-1].x) : v3_splat(0.0);
        vertex at_y = vertex_at(y->x, y->n, from, y->m);
        if (y->index == 0 || at_specular(y) || v3_dot(at_y.n, v.n) < 0.9 || !(v3_dot(from, v.n) > 0.0))
            continue;
        int k = join(first, y->index, z, t, x); /* only now: most light vertices found are passed over */
        if (!keeps_length(st, x, k) || !strategy_allowed(st, x, k, MERGE, y->index))
            continue;
        counters->value[COUNT_MERGES]++;
        vec3 C =
            v3_scale(v3_mul(v3_mul(y->alpha, bsdf_f(&v, from)), z[t - 1].alpha), 1.0 / (st->light_paths * M_PI * r2));
        L = v3_add(L, v3_scale(C, mis_weight(st, s, x, k, MERGE, y->index)));
    }
    return L;
}

/* ---- passes: the light subpaths, then one eye subpath per pixel ---------------------------------- */

/* Light subpath `path` into the chunk, and light tracing's strategies (s, 1), weighted by (R15), into its splats. */
static int trace_light_path(const bidir_state *st, const scene *s, int pass, int path, chunk *out)
{
    path_vertex y[MAX_VERTICES], x[MAX_PATH], eye = {.x = st->camera.eye, .kind = AT_CAMERA};
    rng g = rng_for(st->seed ^ 0x6c69676874ull, (uint64_t)pass, (uint64_t)path);
    int count = light_subpath(st, s, &g, y, &out->rays, true), failed = 0, pixel;
    st->path_first[path] = (int)out->vertex_count;
    st->path_count[path] = count;
    bidir_join_step(x, y, 0, &eye, 1);
    for (int s_count = 1; s_count <= count; s_count++) {
        vec3 value;
        int k = bidir_join_step(x, y, s_count, &eye, 1); /* join(): x held s_count - 1's path */
        if (keeps_length(st, x, k) && strategy_allowed(st, x, k, CONNECT, s_count) &&
            connect_to_camera(st, s, y, s_count, &pixel, &value, &out->rays))
            failed |= chunk_add_splat(out, pixel, v3_scale(value, mis_weight(st, s, x, k, CONNECT, s_count)));
    }
    return failed | chunk_add_vertices(out, y, count);
}

/* Before pass i: the radius of (R12), then the pass's light subpaths (trace_light_path, in parallel). */
static int begin_pass(void *state_pointer, const scene *s, const render_options *o, int pass, char *err,
                      size_t err_size)
{
    bidir_state *st = state_pointer;
    (void)o;
    if (pass > 1) /* (R12) r_{i+1}^2 = r_i^2 (i + alpha) / (i + 1) */
        st->current_radius *= sqrt((pass - 1 + st->alpha) / pass);
    return light_pass(st, s, pass, trace_light_path, err, err_size);
}

/* A camera ray of pixel p: the pass's light tracing there, and one eye subpath joined to light subpath p, merged. */
static vec3 radiance(const void *state_pointer, const scene *s, ray r, rng *g, render_counters *counters)
{
    const bidir_state *st = state_pointer;
    int pixel = pixel_of_ray(&st->camera, r.direction);
    vec3 L = st->light_image[pixel];
    if (st->single_strategy ? st->strategy_t == 1 : st->method == METHOD_LIGHT) /* light tracing only */
        return L;
    path_vertex z[MAX_VERTICES]; /* not zeroed: 6 kB a camera ray */
    z[0] = (path_vertex){.x = r.origin, .alpha = v3_splat(1.0), .kind = AT_CAMERA};
    int t_count =
        extend(s, z, 1, st->eye_cap, v3_splat(1.0), r.direction, true, false, g, &counters->value[COUNT_EYE_RAYS]);
    z[0].x = st->camera.eye; /* the pinhole: its ray began camera.near ahead of it (scene.h) */
    const path_vertex *y = &st->light_vertices[st->path_first[pixel]];
    for (int t = 2; t <= t_count; t++) {
        L = v3_add(L, connections(st, s, y, st->path_count[pixel], z, t, &counters->value[COUNT_SHADOW_RAYS]));
        if (may_merge_at(st, &z[t - 1], &z[t - 2]))
            L = v3_add(L, merges(st, s, z, t, counters));
    }
    return L;
}

/* ---- probes and surface means: the camera replaced by a sensor at a point ------------------------ */

/* walk_stats.h's one sample of the radiance x reflects toward w_o (material m; its reflection is bounce k): a light
 * subpath of its own joined to an eye subpath from x.  The sensor z_0 stands one unit up w_o, z_1 = x is given: a
 * delta in every strategy, so t >= 2, no merging (one light subpath is no density estimate), n = 1 in (R15). */
static vec3 sensor_sample(const void *state_pointer, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m, int k,
                          rng *g, render_counters *counters)
{
    const bidir_state *st = state_pointer;
    path_vertex y[MAX_VERTICES], z[MAX_VERTICES] = {{.x = v3_add(x, w_o), .kind = AT_SENSOR, .surface = k},
                                                    {x, n, v3_splat(1.0), m, AT_SURFACE, -1, 1, is_specular(m)}};
    uint64_t *rays = &counters->value[COUNT_PROBE_RAYS];
    int light_count = light_subpath(st, s, g, y, rays, true), t_count = 2;
    vertex v = vertex_at(x, n, w_o, m);
    vec3 w;
    double pdf;
    vec3 weight = scatter(&v, sample_bsdf, g, &w, &pdf); /* f cos / p (R2) */
    if (v3_max_component(weight) > 0.0)
        t_count = extend(s, z, 2, st->eye_cap, weight, w, true, false, g, rays);
    vec3 L = v3_splat(0.0);
    for (int t = 2; t <= t_count; t++)
        L = v3_add(L, connections(st, s, y, light_count, z, t, rays));
    return L;
}

/* ---- the check: (R13) over (R14) is what the subpaths carry; the weights (R15) add to 1 ---------- */

/* (R13)'s integrand: L_e, f at every inner vertex, G on every edge, W_e at the eye. */
static vec3 path_integrand(const bidir_state *st, const scene *s, const path_vertex *x, int k)
{
    vec3 F = v3_splat(camera_importance(&st->camera, v3_dot(unit(x[k].x, x[k - 1].x), st->camera.forward)));
    for (int i = 0; i < k; i++)
        F = v3_scale(v3_mul(F, vertex_f(s, x, i, unit(x[i].x, x[i + 1].x))), geometry(&x[i], &x[i + 1]));
    return F;
}

/* One join (s, t): the weights of all strategies for its path must add up to 1, and with no mirror or glass on it
 * (and no roulette on the subpaths, so alpha is exactly the product of f cos / p) its value must be f(x) / p_s(x). */
static void check_join(bidir_state *st, const scene *s, const path_vertex *y, int s_count, const path_vertex *z, int t)
{
    path_vertex x[MAX_PATH];
    double sum = 0.0, pdf_light[MAX_PATH], pdf_eye[MAX_PATH], merge_chance[MAX_PATH];
    int k = join(y, s_count, z, t, x), pixel;
    uint64_t rays = 0;
    vec3 C = strategy_allowed(st, x, k, CONNECT, s_count) ? strategy_value(st, s, y, s_count, z, t, &pixel, &rays)
                                                          : v3_splat(0.0);
    if (!(v3_max_component(C) > 0.0))
        return;
    bool specular = false;
    for (int j = 0; j <= k + 1; j++) {
        for (technique h = CONNECT; h <= MERGE; h++)
            sum += strategy_allowed(st, x, k, h, j) ? mis_weight(st, s, x, k, h, j) : 0.0;
        specular |= j <= k && at_specular(&x[j]);
    }
    path_pdfs(st, s, x, k, pdf_light, pdf_eye, merge_chance);
    double p = strategy_density(st, x, k, pdf_light, pdf_eye, merge_chance, CONNECT, s_count);
    bidir_check_record(st, sum, specular ? -1.0 : v3_average(C), p, v3_average(path_integrand(st, s, x, k)));
}

/* --check: pairs of random subpaths, without roulette, and every join of them. */
static void check_pair(bidir_state *st, const scene *s, rng *g)
{
    path_vertex y[MAX_VERTICES], z[MAX_VERTICES] = {{.x = st->camera.eye, .alpha = v3_splat(1.0)}};
    uint64_t rays = 0;
    int light_count = light_subpath(st, s, g, y, &rays, false);
    ray r = camera_frame_ray(&st->camera.frame, rng_uniform(g) * st->camera.width, rng_uniform(g) * st->camera.height);
    int eye_count = extend(s, z, 1, st->eye_cap, v3_splat(1.0), r.direction, false, false, g, &rays);
    for (int t = 1; t <= eye_count; t++)
        for (int s_count = t == 1; s_count <= light_count; s_count++)
            check_join(st, s, y, s_count, z, t);
}

int main(int argc, char **argv)
{
    bidir_state state = {.is_specular = is_specular, /* chapter 4's, as the bookkeeping needs them */
                         .total_light_power = total_light_power,
                         .sensor = sensor_sample,
                         .check = check_pair};
    const chapter bidirectional = {
        .name = "06_bidirectional",
        .description = "bidirectional methods: light tracing, BDPT and VCM, weighted by the power heuristic "
                       "over strategies (R13-R16)",
        .options = {{BIDIR_OPTIONS, &state}},
        .default_spp = 16,
        .counter_names = {"eye_rays", "shadow_rays", "merges", "probe_rays", NULL},
        .prepare = bidir_prepare,
        .begin_pass = begin_pass,
        .radiance = radiance,
        .probe = bidir_probe,
        .write_stats = bidir_write_stats,
        .finish = bidir_finish,
    };
    return render_main(argc, argv, &bidirectional, &state);
}
