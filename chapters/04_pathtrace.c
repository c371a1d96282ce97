/* 04_pathtrace.c — Lecture 4: path tracing.
 *
 *   (R2)  L_r(x, w_r) = L_e(x, w_r) + Int_Omega L_r(x', -w_i) f(x, w_i, w_r) cos(theta_i) dw_i
 *
 * is L = E + KL (R4), solved by the Neumann series (R6) L = E + KE + K^2 E + ...
 * Kajiya's path tracer (1986) estimates every term at once by a random walk:
 * from the camera, hit a surface, pick a direction w_i at random, follow it,
 * repeat; a walk that has scattered k times and then finds light adds to
 * K^k E.  Dividing each step by the density of the direction it took makes
 * the expectation exactly (R2) for any density positive wherever the
 * integrand is; the density decides the noise.  The ladder of --estimator:
 *   1. hemisphere  (R2) as written: every direction equally likely;
 *   2. cosine      directions drawn like f cos: only the density changes;
 *   3. light       next-event estimation (R9): at every vertex also a point
 *                  on a light, and a shadow ray to it;
 *   4. mis         both, weighted by the power heuristic (the default).
 * All four have the same expectation (the tests check it); the noise differs. */
#include <stdlib.h>

#include "optics.h"
#include "pathtrace_model.h" /* what chapter 5 uses of this chapter: vertex, bsdf_f, ..., next_event */
#include "render.h"
#include "sampling.h"
#include "sphere_light.h"
#include "walk_stats.h"

/* ---- state and options ------------------------------------------------------------------------- */

/* --estimator, in the order of its choices */
typedef enum { ESTIMATOR_HEMISPHERE, ESTIMATOR_COSINE, ESTIMATOR_LIGHT, ESTIMATOR_MIS } estimator_kind;
static const char *const estimator_names[] = {"hemisphere", "cosine", "light", "mis"};

typedef struct {
    int estimator;                                           /* estimator_kind */
    int rr_depth, max_depth, probe_samples, surface_samples; /* the options of the same names */
    bounce_window bounces; /* from here on filled by prepare; --bounces A:B keeps K^A E .. K^B E (R6) */
    uint64_t seed;
    double total_power;                /* of all lights */
    surface_average *surface_averages; /* --surface-samples, to compare with radiosity (R10) */
    int surface_average_count;
    uint64_t surface_rays;
    const scene *scene; /* for the surface names in the stats */
} pathtrace_state;

enum { COUNT_BOUNCE_RAYS, COUNT_SHADOW_RAYS, COUNT_PROBE_RAYS };

static uint64_t truncated_walks; /* cut by --max-depth (all threads: rare, so an atomic add) */
static int warned_truncation, warned_rr_depth, warned_no_light;

/* ---- materials --------------------------------------------------------------------------------- */

/* A vertex of a walk (pathtrace_model.h): light leaves x toward w_o; n is the
 * unit normal on the side of w_o (surfaces are two-sided). */
vertex vertex_at(vec3 x, vec3 n_geometric, vec3 w_o, const material *m)
{
    bool front = v3_dot(n_geometric, w_o) > 0.0;
    return (vertex){.x = x, .n = front ? n_geometric : v3_neg(n_geometric), .w_o = w_o, .front = front, .m = m};
}

/* Unit mirror direction of w about n: 2 (n.w) n - w. */
static vec3 mirror_of(vec3 w, vec3 n) { return v3_reflect(v3_neg(w), n); }

/* f(w_i, w_o) = rho / pi  +  ks (n + 2) / (2 pi) cos^n(alpha): Lambertian,
 * plus for Phong the energy-normalised lobe of Lafortune & Willems (1994),
 * alpha the angle between w_i and the mirror direction of w_o.  (n + 2)/(2 pi)
 * makes the lobe reflect at most ks of the incident energy, so rho + ks <= 1
 * conserves energy (the classic Phong lobe does not). */
vec3 bsdf_f(const vertex *v, vec3 w_i)
{
    const material *m = v->m;
    vec3 f = v3_scale(m->albedo, 1.0 / M_PI);
    double cos_alpha = m->kind == MATERIAL_PHONG ? v3_dot(w_i, mirror_of(v->w_o, v->n)) : 0.0;
    if (cos_alpha > 0.0)
        f = v3_add(f, v3_scale(m->specular, (m->exponent + 2.0) / (2.0 * M_PI) * pow(cos_alpha, m->exponent)));
    return f;
}

/* Mirror and glass send light one way only: f is a delta that no density
 * over directions finds, so every estimator follows it, with the weight
 * f cos / p = the reflectance.  Glass reflects with probability F (exact
 * Fresnel, optics.h), else refracts (the choice is the weight); radiance
 * entering a medium changes by (n_i / n_t)^2, undone on the way out. */
bool is_specular(const material *m) { return m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS; }

vec3 specular_scatter(const vertex *v, rng *g, vec3 *w_i)
{
    *w_i = mirror_of(v->w_o, v->n);
    if (v->m->kind == MATERIAL_MIRROR)
        return v->m->specular;
    double n_i = v->front ? 1.0 : v->m->ior, n_t = v->front ? v->m->ior : 1.0;
    double fresnel = fresnel_dielectric(v3_dot(v->n, v->w_o), n_i, n_t, NULL, NULL);
    vec3 refracted;
    if (rng_uniform(g) < fresnel || !refract_direction(v3_neg(v->w_o), v->n, n_i / n_t, &refracted))
        return v3_splat(1.0);
    *w_i = refracted;
    return v3_scale(v->m->specular, (n_i / n_t) * (n_i / n_t));
}

/* ---- 1. the hemisphere estimator: (R2) as written ------------------------------------------------ */

/* Light reflected k times on its way from an emitter to the eye (or probe)
 * is the term K^k E (R6); --bounces A:B keeps it only if A <= k <= B. */
static bool keep(const pathtrace_state *st, int k) { return bounces_keep(st->bounces, k); }

/* May a walk scatter for the k-th time?  Not beyond B (nothing is kept), nor
 * beyond --max-depth, a cap that biases the image low: cuts are reported. */
static bool may_scatter(const pathtrace_state *st, int k)
{
    if (k <= st->max_depth && k <= st->bounces.last)
        return true;
    if (k > st->max_depth && st->max_depth < st->bounces.last) {
#pragma omp atomic
        truncated_walks++;
        warn_once(&warned_truncation,
                  "04_pathtrace: a path reached --max-depth %d and was cut there, so the image "
                  "misses the terms beyond K^%d E and is biased low (count in stats)",
                  st->max_depth, st->max_depth);
    }
    return false;
}

/* Russian roulette: go on with probability p, weighted by 1/p, so the
 * expectation is unchanged.  p follows the throughput: a dim walk ends early,
 * a bright one (a furnace, rho = 0.99) goes on. [exercise 4.3] */
bool survives_roulette(vec3 *throughput, rng *g)
{
    double p = min_ignoring_nan(1.0, v3_max_component(*throughput));
    if (!(p > 0.0) || rng_uniform(g) >= p)
        return false;
    *throughput = v3_scale(*throughput, 1.0 / p);
    return true;
}

/* L_e of the surface a ray along w hits: emitters shine from their front only. */
static vec3 emitted(const scene *s, const hit *h, vec3 w)
{
    const material *m = material_of(s, h->surface);
    return m->kind == MATERIAL_EMITTER && v3_dot(h->normal, w) < 0.0 ? m->emission : v3_splat(0.0);
}

/* A density over directions (direction_sampler) draws w_i at v and returns its
 * pdf per steradian.  Rung 1's: every direction above the surface alike, 1/(2 pi). */
static double sample_uniform(const vertex *v, rng *g, vec3 *w_i)
{
    double u1 = rng_uniform(g), u2 = rng_uniform(g);
    *w_i = onb_to_world(onb_from_normal(v->n), uniform_sample_hemisphere(u1, u2));
    return uniform_hemisphere_pdf();
}

/* Scatter: choose the next direction w_i at v (its pdf in *pdf, 0 for a
 * delta) and return the factor of the walk's throughput, f cos(theta_i) / p. [exercise 4.2] */
vec3 scatter(const vertex *v, direction_sampler *sample, rng *g, vec3 *w_i, double *pdf)
{
    *pdf = 0.0;
    if (is_specular(v->m))
        return specular_scatter(v, g, w_i);
    *pdf = sample(v, g, w_i);
    double cos_i = v3_dot(v->n, *w_i);
    return *pdf > 0.0 && cos_i > 0.0 ? v3_scale(bsdf_f(v, *w_i), cos_i / *pdf) : v3_splat(0.0); /* (R2) */
}

/* The radiance reflected (not emitted) at v toward w_o, the integral of (R2),
 * by one random walk whose k-th scattering is at v: scatter, follow w_i to
 * the next surface, add the light it emits toward us, and go on from there. [exercise 4.1] */
static vec3 walk(const pathtrace_state *st, const scene *s, vertex v, int k, direction_sampler *sample, rng *g,
                 render_counters *counters)
{
    vec3 L = v3_splat(0.0), throughput = v3_splat(1.0); /* throughput: product of f cos / p so far */
    for (; may_scatter(st, k); k++) {
        vec3 w_i;
        double pdf;
        throughput = v3_mul(throughput, scatter(&v, sample, g, &w_i, &pdf));
        if (!(v3_max_component(throughput) > 0.0) || (k >= st->rr_depth && !survives_roulette(&throughput, g)))
            break;
        counters->value[COUNT_BOUNCE_RAYS]++;
        hit h;
        bool escaped = !scene_intersect(s, (ray){scene_offset_origin(s, v.x, v.n, w_i), w_i}, INFINITY, &h);
        if (keep(st, k)) /* the light found there (or the background), reflected k times on its way: K^k E */
            L = v3_add(L, v3_mul(throughput, escaped ? s->background : emitted(s, &h, w_i)));
        if (escaped)
            break;
        v = vertex_at(h.point, h.normal, v3_neg(w_i), material_of(s, h.surface));
    }
    return L;
}

/* ---- 2. importance sampling: directions drawn like f cos ----------------------------------------- */

/* Rung 1's walk with another density.  Cosine-weighted directions, pdf
 * cos(theta)/pi, cancel the cosine of (R2): f cos / p = rho if Lambertian.
 * The glossy lobe gets (n + 1)/(2 pi) cos^n(alpha) around the mirror direction,
 * with probability `share` (its part of the albedo); the pdf is the mixture. */
static double glossy_share(const material *m)
{
    double d = v3_average(m->albedo), s = v3_average(m->specular);
    return m->kind == MATERIAL_PHONG && d + s > 0.0 ? s / (d + s) : 0.0;
}

/* The density per steradian of sample_bsdf: the mixture of cosine and lobe. [exercise 4.4] */
double bsdf_pdf(const vertex *v, vec3 w_i)
{
    double share = glossy_share(v->m), pdf = (1.0 - share) * cosine_hemisphere_pdf(v3_dot(v->n, w_i));
    double cos_alpha = share > 0.0 ? v3_dot(w_i, mirror_of(v->w_o, v->n)) : 0.0;
    if (cos_alpha > 0.0)
        pdf += share * (v->m->exponent + 1.0) / (2.0 * M_PI) * pow(cos_alpha, v->m->exponent);
    return pdf;
}

/* Draws w_i like f cos: the lobe with probability share, else cosine; returns its pdf. [exercise 4.5] */
double sample_bsdf(const vertex *v, rng *g, vec3 *w_i)
{
    double u1 = rng_uniform(g), u2 = rng_uniform(g), share = glossy_share(v->m);
    if (share == 0.0 || rng_uniform(g) >= share) {
        *w_i = onb_to_world(onb_from_normal(v->n), cosine_sample_hemisphere(u1, u2));
    } else { /* cos(alpha) = u1^(1/(n+1)) has the density (n + 1) cos^n(alpha) on [0, 1] */
        double cos_alpha = pow(u1, 1.0 / (v->m->exponent + 1.0)), sin_alpha = sqrt_one_minus_square(cos_alpha);
        double phi = 2.0 * M_PI * u2;
        vec3 local = v3(sin_alpha * cos(phi), sin_alpha * sin(phi), cos_alpha);
        *w_i = onb_to_world(onb_from_normal(mirror_of(v->w_o, v->n)), local);
    }
    return bsdf_pdf(v, *w_i);
}

/* ---- 3. next-event estimation (R9) --------------------------------------------------------------- */

/* Light sampling turns the integral over directions into one over the
 * lights' surfaces, dw_i = cos(theta_y) dA_y / |x - y|^2 (R7):
 *   L_direct(x, w_o) = Int_lights L_e(y) f(x, w_i, w_o) G(x, y) V(x, y) dA_y   (R8), (R9)
 * estimated with one point y: f L_e cos(theta_i) V / p(w_i), p the density of
 * y per steradian times the chance of picking its light.  Light i (emitting
 * surface i, or point light i - emitter_count) is picked by its power. */
static double emitter_power(const scene *s, int i) /* pi L_e A for a Lambertian emitter */
{
    return M_PI * v3_average(material_of(s, i)->emission) * s->surfaces[i].area;
}

static double light_power(const scene *s, int i) /* 4 pi I for a point light */
{
    return i < s->emitter_count ? emitter_power(s, s->emitters[i])
                                : 4.0 * M_PI * v3_average(s->lights[i - s->emitter_count].intensity);
}

double total_light_power(const scene *s)
{
    double total = 0.0;
    for (int i = 0; i < s->emitter_count + s->light_count; i++)
        total += light_power(s, i);
    return total;
}

/* The density per steradian of sample_light at x picking y (normal n_y) on
 * emitting surface i (also for MIS): the pick times that of y, uniform in the
 * cone a sphere subtends (sphere_light.h), else uniform by area, p_A = 1 / A
 * (a sphere cut to the cap that shines into the room: by area on the cap). */
static double light_pdf(const scene *s, double total_power, int i, vec3 x, vec3 y, vec3 n_y)
{
    const surface *surf = &s->surfaces[i];
    double pick = emitter_power(s, i) / total_power;
    if (surface_is_whole_sphere(surf))
        return pick * sphere_light_pdf(surf->center, surf->radius, x, y, n_y);
    return pick * area_pdf_to_solid_angle(1.0 / surf->area, x, y, n_y);
}

typedef struct {
    vec3 point, w_i; /* y, and the unit direction from x toward it */
    vec3 radiance;   /* L_e(y); for a point light I / (r^2 pick), the irradiance it gives head-on (R1) */
    double pdf;      /* per steradian, including the pick; 0 for a point light (a delta) */
} light_sample;

/* Picks a light by power and a point y on it (R9); false when nothing shines toward x. [exercise 4.6] */
static bool sample_light(const scene *s, double total_power, vec3 x, rng *g, light_sample *out)
{
    if (!(total_power > 0.0)) /* no light shines */
        return false;
    int i = 0, last = s->emitter_count + s->light_count - 1; /* pick light i with probability power / total */
    for (double u = rng_uniform(g) * total_power; i < last && u >= light_power(s, i); i++)
        u -= light_power(s, i);
    double pick = light_power(s, i) / total_power;
    if (i >= s->emitter_count) {
        const point_light *p = &s->lights[i - s->emitter_count];
        vec3 d = v3_sub(p->position, x);
        double r2 = v3_dot(d, d);
        *out = (light_sample){p->position, v3_scale(d, 1.0 / sqrt(r2)), v3_scale(p->intensity, 1.0 / (r2 * pick)), 0.0};
        return r2 > 0.0 && pick > 0.0;
    }
    int e = s->emitters[i];
    const surface *surf = &s->surfaces[e];
    double u1 = rng_uniform(g), u2 = rng_uniform(g), pdf_unused;
    vec3 y, n_y;
    if (!surface_is_whole_sphere(surf)) /* a sphere cut to its cap (scene.h) too */
        surface_sample_point(s, e, u1, u2, rng_uniform(g), &y, &n_y);
    else if (!sphere_light_sample(surf->center, surf->radius, x, u1, u2, &y, &n_y, &pdf_unused))
        return false;
    vec3 w_i = v3_normalize(v3_sub(y, x));
    *out = (light_sample){y, w_i, material_of(s, e)->emission, light_pdf(s, total_power, e, x, y, n_y)};
    return out->pdf > 0.0 && v3_dot(n_y, w_i) < 0.0; /* emitters shine from their front only */
}

/* The share of a path to a light that the light sample counts (light_share:
 * the walk that finds it by itself counts the rest).  Next-event estimation alone: all. */
double light_sample_only(double pdf_light, double pdf_bsdf)
{
    (void)pdf_light, (void)pdf_bsdf;
    return 1.0;
}

/* One light sample's contribution to the radiance reflected at v toward w_o:
 * f L_e cos(theta_i) V / p (R9), times the light sample's share. [exercise 4.7] */
vec3 next_event(const scene *s, double total_power, const vertex *v, light_share *share, rng *g, uint64_t *shadow_rays)
{
    light_sample ls;
    if (!sample_light(s, total_power, v->x, g, &ls))
        return v3_splat(0.0);
    double cos_i = v3_dot(v->n, ls.w_i);
    vec3 f = cos_i > 0.0 ? bsdf_f(v, ls.w_i) : v3_splat(0.0);
    if (!(v3_max_component(f) > 0.0)) /* nothing reflected toward w_o: no need to look */
        return v3_splat(0.0);
    ++*shadow_rays;
    if (scene_occluded(s, v->x, ls.point)) /* V(x, y) */
        return v3_splat(0.0);
    if (ls.pdf == 0.0) /* a point light: nothing else can find it */
        return v3_scale(v3_mul(f, ls.radiance), cos_i);
    return v3_scale(v3_mul(f, ls.radiance), cos_i * share(ls.pdf, bsdf_pdf(v, ls.w_i)) / ls.pdf);
}

/* Rung 1's walk with rung 2's directions and a light sample at every vertex
 * but specular ones (a delta reflects no sampled point); light the walk then
 * finds by itself counts 1 - share: fully after a specular vertex. [exercise 4.8] */
static vec3 walk_with_light_samples(const pathtrace_state *st, const scene *s, vertex v, int k, light_share *share,
                                    rng *g, render_counters *counters)
{
    vec3 L = v3_splat(0.0), throughput = v3_splat(1.0);
    for (; may_scatter(st, k); k++) {
        if (!is_specular(v.m) && keep(st, k))
            L = v3_add(L, v3_mul(throughput,
                                 next_event(s, st->total_power, &v, share, g, &counters->value[COUNT_SHADOW_RAYS])));
        vec3 w_i;
        double pdf_bsdf;
        throughput = v3_mul(throughput, scatter(&v, sample_bsdf, g, &w_i, &pdf_bsdf));
        if (!(v3_max_component(throughput) > 0.0) || (k >= st->rr_depth && !survives_roulette(&throughput, g)))
            break;
        counters->value[COUNT_BOUNCE_RAYS]++;
        hit h;
        bool escaped = !scene_intersect(s, (ray){scene_offset_origin(s, v.x, v.n, w_i), w_i}, INFINITY, &h);
        vec3 Le = escaped ? s->background : emitted(s, &h, w_i);
        if (keep(st, k) && v3_max_component(Le) > 0.0) {
            double counted = 1.0; /* the background, or after a specular vertex: no light sample found it */
            if (!escaped && !is_specular(v.m))
                counted -= share(light_pdf(s, st->total_power, h.surface, v.x, h.point, h.normal), pdf_bsdf);
            L = v3_add(L, v3_mul(throughput, v3_scale(Le, counted)));
        }
        if (escaped)
            break;
        v = vertex_at(h.point, h.normal, v3_neg(w_i), material_of(s, h.surface));
    }
    return L;
}

/* ---- 4. multiple importance sampling ------------------------------------------------------------- */

/* Light samples find small lights, directions drawn like f cos a big light in
 * a sharp glossy lobe.  MIS (Veach 1997) counts a path found either way with a
 * share each, adding up to one (unbiased); the power heuristic gives the light
 * sample p_light^2 / (p_light^2 + p_bsdf^2).  Rung 3's walk with it is MIS. [exercise 4.9] */
static double power_heuristic(double pdf_light, double pdf_bsdf)
{
    double a = pdf_light * pdf_light, b = pdf_bsdf * pdf_bsdf;
    return a + b > 0.0 ? a / (a + b) : 0.0;
}

/* ---- radiance along a camera ray ----------------------------------------------------------------- */

/* The radiance reflected at x (normal n, material m) toward w_o, by one walk
 * of the estimator --estimator names, whose first scattering (at x) is bounce k. */
static vec3 reflected(const void *state, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m, int k, rng *g,
                      render_counters *c)
{
    const pathtrace_state *st = state;
    vertex v = vertex_at(x, n, w_o, m);
    switch (st->estimator) {
    case ESTIMATOR_HEMISPHERE: return walk(st, s, v, k, sample_uniform, g, c);
    case ESTIMATOR_COSINE: return walk(st, s, v, k, sample_bsdf, g, c);
    case ESTIMATOR_LIGHT: return walk_with_light_samples(st, s, v, k, light_sample_only, g, c);
    default: return walk_with_light_samples(st, s, v, k, power_heuristic, g, c);
    }
}

static vec3 radiance(const void *state_pointer, const scene *s, ray r, rng *g, render_counters *counters)
{
    const pathtrace_state *st = state_pointer;
    hit h;
    if (!scene_intersect(s, r, INFINITY, &h))
        return keep(st, 0) ? s->background : v3_splat(0.0);
    vec3 E = keep(st, 0) ? emitted(s, &h, r.direction) : v3_splat(0.0); /* the light seen directly: k = 0 (R6) */
    const material *m = material_of(s, h.surface);
    return v3_add(E, reflected(st, s, h.point, h.normal, v3_neg(r.direction), m, 1, g, counters));
}

/* A probe's irradiance, by the image's estimator (walk_stats.h). */
static probe_result probe_irradiance(const void *state_pointer, const scene *s, const probe *p, uint64_t seed,
                                     render_counters *counters)
{
    const pathtrace_state *st = state_pointer;
    walk_source w = {reflected, st, s, false};
    return walk_probe(&w, p, probe_seed(seed), st->probe_samples, &counters->value[COUNT_PROBE_RAYS]);
}

/* ---- main ---------------------------------------------------------------------------------------- */

/* The lights' total power, warnings, the surface averages (walk_stats.h). */
static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    pathtrace_state *st = state_pointer;
    st->bounces = bounce_window_of(o), st->seed = o->seed, st->scene = s;
    truncated_walks = 0;
    st->total_power = total_light_power(s);
    if (s->light_count > 0 && (st->estimator == ESTIMATOR_HEMISPHERE || st->estimator == ESTIMATOR_COSINE)) {
        bool only = s->emitter_count == 0;
        fprintf(stderr,
                "warning: 04_pathtrace: --estimator %s follows random directions, which never hit a point light: "
                "the image will miss the light of %s%s (use --estimator light or mis)\n",
                estimator_names[st->estimator], only ? "all lights in this scene" : "the point light(s) in this scene",
                only && v3_max_component(s->background) <= 0.0 ? " and come out black" : "");
    }
    if (st->rr_depth == 0)
        warn_once(&warned_rr_depth, "04_pathtrace: --rr-depth 0 acts as --rr-depth 1: the first scattering is "
                                    "bounce 1, and roulette can end a walk there already");
    if (s->light_count == 0 && s->emitter_count == 0)
        warn_once(&warned_no_light, "04_pathtrace: the scene has no light (no point light, no emitter): "
                                    "only the background lights it");
    walk_source w = {reflected, st, s, keep(st, 0)};
    return st->surface_samples == 0
               ? 0
               : walk_surface_averages(&w, st->seed ^ 0x73757266616365ull, st->surface_samples, &st->surface_averages,
                                       &st->surface_average_count, &st->surface_rays, err, err_size);
}

static void write_stats(const void *state_pointer, FILE *json)
{
    const pathtrace_state *st = state_pointer;
    fprintf(json,
            ",\n  \"estimator\": \"%s\",\n  \"rr_depth\": %d,\n  \"max_depth\": %d,\n  \"truncated_paths\": %llu,"
            "\n  \"biased_by_max_depth\": %s,\n  \"probe_samples\": %d,\n  \"surface_samples\": %d,"
            "\n  \"surface_rays\": %llu",
            estimator_names[st->estimator], st->rr_depth, st->max_depth, (unsigned long long)truncated_walks,
            truncated_walks ? "true" : "false", st->probe_samples, st->surface_samples,
            (unsigned long long)st->surface_rays);
    json_surface_averages(json, st->scene, st->surface_averages, st->surface_average_count);
}

static void finish(void *state_pointer)
{
    pathtrace_state *st = state_pointer;
    free(st->surface_averages);
    st->surface_averages = NULL;
}

#define OPTION_FIELD(field) offsetof(pathtrace_state, field)
static const option PATHTRACE_OPTIONS[] = {
    {"--estimator", NULL, OPTION_CHOICE, OPTION_FIELD(estimator), .choices = "hemisphere|cosine|light|mis",
     .default_text = "mis",
     .help = "uniform directions (R2 as written), cosine-weighted directions, "
             "next-event estimation on the lights (R9), or both by MIS"},
    {"--rr-depth", "N", OPTION_INT, OPTION_FIELD(rr_depth), .min = 0, .max = RENDER_BOUNCES_UNLIMITED,
     .default_text = "3", .help = "Russian roulette from N bounces on (unbiased)"},
    {"--max-depth", "N", OPTION_INT, OPTION_FIELD(max_depth), .min = 0, .max = RENDER_BOUNCES_UNLIMITED,
     .default_text = "1000", .help = "cut paths after N bounces (biased if it cuts: see the stats)"},
    {"--probe-samples", "N", OPTION_INT, OPTION_FIELD(probe_samples), .min = 32, .max = 1 << 28,
     .default_text = "65536", .help = "walks per probe for its irradiance, in 32 batches"},
    {"--surface-samples", "N", OPTION_INT, OPTION_FIELD(surface_samples), .min = 0, .max = 1 << 28, .default_text = "0",
     .help = "walks per surface for the stats key \"surfaces\" (0: off)"},
    {0},
};
#undef OPTION_FIELD

int main(int argc, char **argv)
{
    pathtrace_state state = {0};
    const chapter path_tracing = {
        .name = "04_pathtrace",
        .description = "path tracing: random walks estimate every term of the Neumann series (R2, R6, R9)",
        .options = {{PATHTRACE_OPTIONS, &state}},
        .default_spp = 16,
        .counter_names = {"bounce_rays", "shadow_rays", "probe_rays", NULL},
        .prepare = prepare,
        .radiance = radiance,
        .probe = probe_irradiance,
        .write_stats = write_stats,
        .finish = finish,
    };
    return render_main(argc, argv, &path_tracing, &state);
}
