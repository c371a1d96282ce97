/* 04_pathtrace.c — Lectures 5 and 6: path tracing.
 *
 * The rendering equation in its angular form,
 *
 *   (R2)  L_r(x, w_r) = L_e(x, w_r) + Int_Omega L_r(x', -w_i) f(x, w_i, w_r) cos(theta_i) dw_i,
 *
 * is L = E + KL (R4), and its solution is the Neumann series (R6)
 * L = E + KE + K^2 E + ...  Kajiya's path tracer (1986) estimates every term
 * at once by a random walk: from the camera, hit a surface, pick one
 * direction w_i at random, follow it, and repeat.  A walk that has scattered
 * k times and then finds light contributes to the term K^k E.  Dividing each
 * step by the probability density of the direction it took makes the
 * expected value exactly (R2), whichever density we choose, as long as it is
 * positive wherever the integrand is.  The density decides the noise.
 *
 * The file climbs a ladder of four estimators (--estimator), each rung
 * adding one idea to the rung before:
 *   1. hemisphere  (R2) as written: every direction equally likely.
 *   2. cosine      directions drawn like f cos: only the density changes.
 *   3. light       next-event estimation (R9): at every vertex also a point
 *                  on a light, and a shadow ray to it.
 *   4. mis         both, weighted by the power heuristic.  The default.
 * All four give the same image in expectation (the tests check this); only
 * the noise differs.
 */
#include <stdlib.h>
#include <string.h>

#include "optics.h"
#include "render.h"
#include "sampling.h"
#include "sphere_light.h"

/* ---- state and options ------------------------------------------------------------------------- */

typedef enum { ESTIMATOR_HEMISPHERE, ESTIMATOR_COSINE, ESTIMATOR_LIGHT, ESTIMATOR_MIS } estimator_kind;
static const char *const estimator_names[] = {"hemisphere", "cosine", "light", "mis"};

typedef struct { /* area-averaged exitant radiance of one surface (--surface-samples) */
    int surface;
    vec3 radiance, standard_error;
} surface_average;

typedef struct {
    estimator_kind estimator;
    int rr_depth;        /* Russian roulette from this many bounces on */
    int max_depth;       /* hard cap on bounces (biased when it cuts) */
    int probe_samples;   /* walks per probe */
    int surface_samples; /* walks per surface for the "surfaces" stats (0 = off) */
    /* Filled by prepare from the command line and the scene. */
    int bounce_min, bounce_max; /* --bounces A:B: keep the terms K^A E .. K^B E (R6) */
    uint64_t seed;
    double total_power; /* of all lights, for picking one */
    surface_average *surface_averages;
    int surface_average_count;
    uint64_t surface_rays;
    const scene *scene; /* for the surface names in the stats */
} pathtrace_state;

enum { COUNT_BOUNCE_RAYS, COUNT_SHADOW_RAYS, COUNT_PROBE_RAYS };

/* Walks cut by --max-depth (shared by all threads: rare, so an atomic add). */
static uint64_t truncated_walks;
static int warned_truncation;

static int parse_option(void *state_pointer, int argc, char **argv, int *i, char *err, size_t err_size)
{
    pathtrace_state *state = state_pointer;
    const char *a = argv[*i];
    if (!strcmp(a, "--estimator")) {
        if (*i + 1 >= argc) {
            snprintf(err, err_size, "argv:%d: --estimator needs a value (hemisphere, cosine, light or mis)", *i);
            return 2;
        }
        const char *v = argv[++*i];
        for (int e = 0; e < 4; e++)
            if (!strcmp(v, estimator_names[e])) {
                state->estimator = (estimator_kind)e;
                return 1;
            }
        snprintf(err, err_size, "argv:%d: --estimator wants hemisphere, cosine, light or mis, not '%s'", *i, v);
        return 2;
    }
    if (!strcmp(a, "--rr-depth"))
        return parse_int_option(argc, argv, i, 0, RENDER_BOUNCES_UNLIMITED, &state->rr_depth, err, err_size);
    if (!strcmp(a, "--max-depth"))
        return parse_int_option(argc, argv, i, 0, RENDER_BOUNCES_UNLIMITED, &state->max_depth, err, err_size);
    if (!strcmp(a, "--probe-samples"))
        return parse_int_option(argc, argv, i, 32, 1 << 28, &state->probe_samples, err, err_size);
    if (!strcmp(a, "--surface-samples"))
        return parse_int_option(argc, argv, i, 0, 1 << 28, &state->surface_samples, err, err_size);
    return 0;
}

/* ---- materials --------------------------------------------------------------------------------- */

/* A vertex of a walk: light leaves the point x toward w_o (unit: toward the
 * eye or the previous vertex).  Surfaces are two-sided: n is the unit normal
 * on the side of w_o; `front` says if that is the side the scene file faces. */
typedef struct {
    vec3 x, n, w_o;
    bool front;
    const material *m;
} vertex;

static vertex vertex_at(vec3 x, vec3 n_geometric, vec3 w_o, const material *m)
{
    bool front = v3_dot(n_geometric, w_o) > 0.0;
    return (vertex){.x = x, .n = front ? n_geometric : v3_neg(n_geometric), .w_o = w_o, .front = front, .m = m};
}

static const material *material_hit(const scene *s, const hit *h)
{
    return &s->materials[s->surfaces[h->surface].material];
}

/* Unit mirror direction of w about n: 2 (n.w) n - w. */
static vec3 mirror_of(vec3 w, vec3 n) { return v3_reflect(v3_neg(w), n); }

/* f(w_i, w_o): a Lambertian term plus, for Phong, the energy-normalised
 * (modified) Phong lobe of Lafortune & Willems (1994),
 *   f(w_i, w_o) = rho / pi  +  ks (n + 2) / (2 pi) cos^n(alpha),
 * alpha the angle between w_i and the mirror direction of w_o.  The factor
 * (n + 2)/(2 pi) makes the lobe reflect at most ks of the incident energy,
 * so rho + ks <= 1 conserves energy (the classic Phong lobe does not). */
static vec3 bsdf_f(const vertex *v, vec3 w_i)
{
    const material *m = v->m;
    vec3 f = v3_scale(m->albedo, 1.0 / M_PI);
    if (m->kind == MATERIAL_PHONG) {
        double cos_alpha = v3_dot(w_i, mirror_of(v->w_o, v->n));
        if (cos_alpha > 0.0)
            f = v3_add(f, v3_scale(m->specular, (m->exponent + 2.0) / (2.0 * M_PI) * pow(cos_alpha, m->exponent)));
    }
    return f;
}

/* Mirror and glass send light into one direction only: f is a delta, which
 * no density over directions can find, so every estimator follows that one
 * direction w_i and the walk's weight f cos / p is the reflectance.  Glass
 * is a dielectric in air: reflect with probability F (exact Fresnel,
 * optics.h), refract otherwise; the choice itself is the weight.  Radiance
 * crossing into a medium changes by (n_i / n_t)^2 (its solid angle is
 * squeezed); on a closed path through the glass the two factors cancel.
 * The tint colours the transmitted light. */
static bool is_specular(const material *m) { return m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS; }

static vec3 specular_scatter(const vertex *v, rng *g, vec3 *w_i)
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

/* Light that leaves an emitter and is reflected k times before it reaches
 * the eye (or the probe) is the Neumann term K^k E (R6): the emitter seen
 * directly is k = 0, its light reflected once toward the eye k = 1.
 * --bounces A:B keeps a contribution only if A <= k <= B. */
static bool keep(const pathtrace_state *st, int k) { return k >= st->bounce_min && k <= st->bounce_max; }

/* May a walk scatter for the k-th time?  Not beyond B (nothing would be
 * kept), nor beyond --max-depth: a cap that biases the image low, so a walk
 * it cuts is counted and reported. */
static bool may_scatter(const pathtrace_state *st, int k)
{
    if (k <= st->max_depth && k <= st->bounce_max)
        return true;
    if (k > st->max_depth && st->max_depth < st->bounce_max) {
#pragma omp atomic
        truncated_walks++;
        warn_once(&warned_truncation,
                  "04_pathtrace: a path reached --max-depth %d and was cut there, so the image misses the "
                  "terms beyond K^%d E and is biased low (count in stats)",
                  st->max_depth, st->max_depth);
    }
    return false;
}

/* Russian roulette (from --rr-depth bounces on): go on with probability p,
 * and weight by 1/p if we do; the expectation is unchanged.  p follows the
 * throughput, so a dim walk ends early and a bright one (a furnace with
 * rho = 0.99) keeps going as long as its light matters. */
static bool survives_roulette(const pathtrace_state *st, int k, rng *g, vec3 *throughput)
{
    if (k < st->rr_depth)
        return true;
    double p = min_ignoring_nan(1.0, v3_max_component(*throughput));
    if (!(p > 0.0) || rng_uniform(g) >= p)
        return false;
    *throughput = v3_scale(*throughput, 1.0 / p);
    return true;
}

/* L_e of the surface a ray along w hits: emitters shine from their front only. */
static vec3 emitted(const scene *s, const hit *h, vec3 w)
{
    const material *m = material_hit(s, h);
    return m->kind == MATERIAL_EMITTER && v3_dot(h->normal, w) < 0.0 ? m->emission : v3_splat(0.0);
}

/* A density over directions draws w_i at v and returns its pdf per
 * steradian.  Rung 1's: every direction above the surface alike, 1/(2 pi). */
typedef double direction_sampler(const vertex *v, rng *g, vec3 *w_i);

static double sample_uniform(const vertex *v, rng *g, vec3 *w_i)
{
    double u1 = rng_uniform(g), u2 = rng_uniform(g);
    *w_i = onb_to_world(onb_from_normal(v->n), uniform_sample_hemisphere(u1, u2));
    return uniform_hemisphere_pdf();
}

/* Scatter: choose the next direction w_i at v (its pdf in *pdf, 0 for a
 * delta) and return the factor of the walk's throughput, f cos(theta_i) / p. */
static vec3 scatter(const vertex *v, direction_sampler *sample, rng *g, vec3 *w_i, double *pdf)
{
    *pdf = 0.0;
    if (is_specular(v->m))
        return specular_scatter(v, g, w_i);
    *pdf = sample(v, g, w_i);
    double cos_i = v3_dot(v->n, *w_i);
    if (!(*pdf > 0.0 && cos_i > 0.0))
        return v3_splat(0.0);
    return v3_scale(bsdf_f(v, *w_i), cos_i / *pdf); /* (R2) */
}

/* The radiance reflected (not emitted) at v toward w_o, the integral of (R2),
 * by one random walk whose k-th scattering is at v: scatter, follow w_i to
 * the next surface, add the light it emits toward us, and go on from there. */
static vec3 walk(const pathtrace_state *st, const scene *s, vertex v, int k, direction_sampler *sample, rng *g,
                 render_counters *counters)
{
    vec3 L = v3_splat(0.0), throughput = v3_splat(1.0); /* throughput: product of f cos / p so far */
    for (; may_scatter(st, k); k++) {
        vec3 w_i;
        double pdf;
        throughput = v3_mul(throughput, scatter(&v, sample, g, &w_i, &pdf));
        if (!(v3_max_component(throughput) > 0.0) || !survives_roulette(st, k, g, &throughput))
            break;
        counters->value[COUNT_BOUNCE_RAYS]++;
        hit h;
        if (!scene_intersect(s, (ray){scene_offset_origin(s, v.x, v.n, w_i), w_i}, INFINITY, &h)) {
            if (keep(st, k))
                L = v3_add(L, v3_mul(throughput, s->background));
            break;
        }
        if (keep(st, k)) /* light emitted there and reflected k times on its way: K^k E */
            L = v3_add(L, v3_mul(throughput, emitted(s, &h, w_i)));
        v = vertex_at(h.point, h.normal, v3_neg(w_i), material_hit(s, &h));
    }
    return L;
}

/* ---- 2. importance sampling: directions drawn like f cos ----------------------------------------- */

/* The walk stays; only the density changes.  Cosine-weighted directions,
 * pdf cos(theta)/pi, cancel the cosine of (R2): on a Lambertian surface
 * f cos / p = rho for every direction.  The glossy lobe has its own density
 * around the mirror direction, (n + 1)/(2 pi) cos^n(alpha).  A Phong
 * material draws from the lobe with probability `share` (the lobe's part of
 * the albedo), else by the cosine; the pdf is the mixture of the two, since
 * either could have drawn any w_i. */
static double glossy_share(const material *m)
{
    double d = v3_average(m->albedo), s = v3_average(m->specular);
    return m->kind == MATERIAL_PHONG && d + s > 0.0 ? s / (d + s) : 0.0;
}

static double bsdf_pdf(const vertex *v, vec3 w_i)
{
    double share = glossy_share(v->m), pdf = (1.0 - share) * cosine_hemisphere_pdf(v3_dot(v->n, w_i));
    if (share > 0.0) {
        double cos_alpha = v3_dot(w_i, mirror_of(v->w_o, v->n));
        if (cos_alpha > 0.0)
            pdf += share * (v->m->exponent + 1.0) / (2.0 * M_PI) * pow(cos_alpha, v->m->exponent);
    }
    return pdf;
}

static double sample_bsdf(const vertex *v, rng *g, vec3 *w_i)
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
 *   L_direct(x, w_o) = Int_lights L_e(y) f(x, w_i, w_o) G(x, y) V(x, y) dA_y     (R8, R9)
 * estimated with one point y: f L_e cos(theta_i) V / p(w_i), p(w_i) being the
 * density of y converted to solid angle times the chance of picking its
 * light.  Lights are picked in proportion to their power: Phi = pi L_e A for
 * a Lambertian emitter, 4 pi I for an isotropic point light.  Light i is
 * emitting surface i of the scene, or point light i - emitter_count. */
static double emitter_power(const scene *s, int surface)
{
    return M_PI * v3_average(s->materials[s->surfaces[surface].material].emission) * s->surfaces[surface].area;
}

static double light_power(const scene *s, int i)
{
    return i < s->emitter_count ? emitter_power(s, s->emitters[i])
                                : 4.0 * M_PI * v3_average(s->lights[i - s->emitter_count].intensity);
}

typedef struct {
    vec3 point, w_i; /* y, and the unit direction from x toward it */
    vec3 radiance;   /* L_e(y); for a point light I / (r^2 pick), the irradiance it gives head-on (R1) */
    double pdf;      /* per steradian, including the pick; 0 for a point light (a delta) */
} light_sample;

static bool sample_light(const pathtrace_state *st, const scene *s, vec3 x, rng *g, light_sample *out)
{
    if (!(st->total_power > 0.0))
        return false; /* no light shines */
    int i = 0, last = s->emitter_count + s->light_count - 1; /* pick light i with probability power / total */
    for (double u = rng_uniform(g) * st->total_power; i < last && u >= light_power(s, i); i++)
        u -= light_power(s, i);
    double pick = light_power(s, i) / st->total_power;
    if (!(pick > 0.0))
        return false; /* a dark last light, reached by rounding */
    if (i >= s->emitter_count) {
        const point_light *p = &s->lights[i - s->emitter_count];
        vec3 to_light = v3_sub(p->position, x);
        double r2 = v3_dot(to_light, to_light);
        *out = (light_sample){p->position, v3_scale(to_light, 1.0 / sqrt(r2)), v3_scale(p->intensity, 1.0 / (r2 * pick)),
                              0.0};
        return r2 > 0.0;
    }
    const surface *surf = &s->surfaces[s->emitters[i]];
    double u1 = rng_uniform(g), u2 = rng_uniform(g), pdf;
    vec3 y, n_y;
    if (surf->kind == SURFACE_SPHERE) { /* uniformly in the cone the sphere subtends (sphere_light.h) */
        if (!sphere_light_sample(surf->center, surf->radius, x, u1, u2, &y, &n_y, &pdf))
            return false;
    } else { /* uniformly by area, p_A = 1 / A */
        surface_sample_point(s, s->emitters[i], u1, u2, rng_uniform(g), &y, &n_y);
        pdf = area_pdf_to_solid_angle(1.0 / surf->area, x, y, n_y);
    }
    vec3 w_i = v3_normalize(v3_sub(y, x));
    *out = (light_sample){y, w_i, s->materials[surf->material].emission, pdf * pick};
    return pdf > 0.0 && v3_dot(n_y, w_i) < 0.0; /* emitters shine from their front only */
}

/* The density with which sample_light at x picks the emitter point that a
 * ray hit (h): what MIS needs when a direction drawn like f cos finds a light. */
static double light_pdf(const pathtrace_state *st, const scene *s, const hit *h, vec3 x)
{
    const surface *surf = &s->surfaces[h->surface];
    double pick = emitter_power(s, h->surface) / st->total_power;
    if (surf->kind == SURFACE_SPHERE)
        return pick * sphere_light_pdf(surf->center, surf->radius, x, h->point, h->normal);
    return pick * area_pdf_to_solid_angle(1.0 / surf->area, x, h->point, h->normal);
}

/* How much of a path to a light the light sample counts, given the
 * densities of the two ways of finding it: next-event estimation, all of it.
 * When the walk finds the same light by itself it counts the rest, 0 here. */
typedef double light_share(double pdf_light, double pdf_bsdf);

static double light_sample_only(double pdf_light, double pdf_bsdf)
{
    (void)pdf_light, (void)pdf_bsdf;
    return 1.0;
}

/* One light sample's contribution to the radiance reflected at v toward w_o:
 * f L_e cos(theta_i) V / p (R9), times the light sample's share. */
static vec3 next_event(const pathtrace_state *st, const scene *s, const vertex *v, light_share *share, rng *g,
                       render_counters *counters)
{
    light_sample ls;
    if (!sample_light(st, s, v->x, g, &ls))
        return v3_splat(0.0);
    double cos_i = v3_dot(v->n, ls.w_i);
    if (!(cos_i > 0.0))
        return v3_splat(0.0);
    vec3 f = bsdf_f(v, ls.w_i);
    if (!(v3_max_component(f) > 0.0)) /* nothing reflected: no need to look */
        return v3_splat(0.0);
    counters->value[COUNT_SHADOW_RAYS]++;
    if (scene_occluded(s, v->x, ls.point)) /* V(x, y) */
        return v3_splat(0.0);
    if (ls.pdf == 0.0) /* a point light: nothing else can find it */
        return v3_scale(v3_mul(f, ls.radiance), cos_i);
    return v3_scale(v3_mul(f, ls.radiance), cos_i * share(ls.pdf, bsdf_pdf(v, ls.w_i)) / ls.pdf);
}

/* Rung 1's walk with rung 2's directions, plus a light sample at every vertex
 * that is not specular (a delta reflects no sampled light point).  Light the
 * walk then finds by itself counts 1 - share: fully after a specular vertex. */
static vec3 walk_with_light_samples(const pathtrace_state *st, const scene *s, vertex v, int k, light_share *share,
                                    rng *g, render_counters *counters)
{
    vec3 L = v3_splat(0.0), throughput = v3_splat(1.0);
    for (; may_scatter(st, k); k++) {
        if (!is_specular(v.m) && keep(st, k))
            L = v3_add(L, v3_mul(throughput, next_event(st, s, &v, share, g, counters)));
        vec3 w_i;
        double pdf_bsdf;
        throughput = v3_mul(throughput, scatter(&v, sample_bsdf, g, &w_i, &pdf_bsdf));
        if (!(v3_max_component(throughput) > 0.0) || !survives_roulette(st, k, g, &throughput))
            break;
        counters->value[COUNT_BOUNCE_RAYS]++;
        hit h;
        if (!scene_intersect(s, (ray){scene_offset_origin(s, v.x, v.n, w_i), w_i}, INFINITY, &h)) {
            if (keep(st, k))
                L = v3_add(L, v3_mul(throughput, s->background));
            break;
        }
        vec3 Le = emitted(s, &h, w_i);
        if (keep(st, k) && v3_max_component(Le) > 0.0) {
            double counted = is_specular(v.m) ? 1.0 : 1.0 - share(light_pdf(st, s, &h, v.x), pdf_bsdf);
            L = v3_add(L, v3_mul(throughput, v3_scale(Le, counted)));
        }
        v = vertex_at(h.point, h.normal, v3_neg(w_i), material_hit(s, &h));
    }
    return L;
}

/* ---- 4. multiple importance sampling ------------------------------------------------------------- */

/* Light samples find small lights; directions drawn like f cos find a big
 * light in a sharp glossy lobe.  MIS (Veach 1997) counts a path to a light
 * found either way, each with a share, and the shares of one path add up to
 * one, so the sum stays unbiased.  The power heuristic gives the light
 * sample the share p_light^2 / (p_light^2 + p_bsdf^2): the way more likely to
 * find the path counts most of it.  Rung 3's walk with these shares is MIS. */
static double power_heuristic(double pdf_light, double pdf_bsdf)
{
    double a = pdf_light * pdf_light, b = pdf_bsdf * pdf_bsdf;
    return a + b > 0.0 ? a / (a + b) : 0.0;
}

/* ---- radiance along a camera ray ----------------------------------------------------------------- */

/* The radiance reflected at v toward w_o, whose k-th scattering v is, by
 * the estimator --estimator names. */
static vec3 reflected(const pathtrace_state *st, const scene *s, vertex v, int k, rng *g, render_counters *c)
{
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
    vec3 L = keep(st, 0) ? emitted(s, &h, r.direction) : v3_splat(0.0); /* E: the light seen directly (R6) */
    vertex v = vertex_at(h.point, h.normal, v3_neg(r.direction), material_hit(s, &h));
    return v3_add(L, reflected(st, s, v, 1, g, counters));
}

/* ---- probes and surface averages ----------------------------------------------------------------- */

/* A probe's irradiance E = Int L cos dw by the image's estimator: pi times
 * what a white Lambertian surface there reflects.  The probe only receives
 * (its walk starts at k = 0): --bounces 0:0 gives the direct irradiance.
 * A surface average, for the comparison with radiosity (R10), is a diffuse
 * surface's exitant radiance averaged over its area,
 *   L_avg = 1/A Int_A ( L_e(y) + rho/pi E(y) ) dA_y,
 * from points y drawn uniformly on it, leaving along the normal (Lambertian:
 * the same in every direction). */
static const material probe_material = {.name = "probe", .kind = MATERIAL_DIFFUSE, .albedo = {1.0, 1.0, 1.0}};

static vec3 one_sample(const pathtrace_state *st, const scene *s, const probe *p, int surface, rng *g,
                       render_counters *c)
{
    if (p)
        return v3_scale(reflected(st, s, vertex_at(p->position, p->normal, p->normal, &probe_material), 0, g, c), M_PI);
    const material *m = &s->materials[s->surfaces[surface].material];
    double u1 = rng_uniform(g), u2 = rng_uniform(g), u3 = rng_uniform(g);
    vec3 y, n;
    surface_sample_point(s, surface, u1, u2, u3, &y, &n);
    vec3 L = reflected(st, s, vertex_at(y, n, n, m), 1, g, c);
    return m->kind == MATERIAL_EMITTER && keep(st, 0) ? v3_add(L, m->emission) : L;
}

enum { BATCHES = 32 };

/* Mean and standard error of BATCHES batch means of n samples each: the
 * batches are independent, so the spread of their means estimates the error
 * of the overall mean without assuming anything about the walks'
 * distribution.  Returns the number of rays traced. */
static uint64_t batch_mean(const pathtrace_state *st, const scene *s, const probe *p, int surface, uint64_t seed,
                           int n, vec3 *mean, vec3 *standard_error)
{
    uint64_t index = p ? (uint64_t)(p - s->probes) : (uint64_t)surface, rays = 0;
    vec3 batch[BATCHES], sum = v3_splat(0.0), sum_squares = v3_splat(0.0);
    render_counters counters[BATCHES] = {{{0}}};
#pragma omp parallel for schedule(dynamic, 1)
    for (int b = 0; b < BATCHES; b++) {
        vec3 batch_sum = v3_splat(0.0);
        for (int k = 0; k < n; k++) {
            rng g = rng_for(seed, index, (uint64_t)b * (uint64_t)n + (uint64_t)k);
            vec3 L = one_sample(st, s, p, surface, &g, &counters[b]);
            if (v3_is_finite(L))
                batch_sum = v3_add(batch_sum, L);
        }
        batch[b] = v3_scale(batch_sum, 1.0 / n);
    }
    for (int b = 0; b < BATCHES; b++) {
        sum = v3_add(sum, batch[b]);
        sum_squares = v3_add(sum_squares, v3_mul(batch[b], batch[b]));
        rays += counters[b].value[COUNT_BOUNCE_RAYS] + counters[b].value[COUNT_SHADOW_RAYS];
    }
    *mean = v3_scale(sum, 1.0 / BATCHES);
    vec3 variance = v3_max(v3_sub(v3_scale(sum_squares, 1.0 / BATCHES), v3_mul(*mean, *mean)), v3_splat(0.0));
    *standard_error = v3(sqrt(variance.x / (BATCHES - 1)), sqrt(variance.y / (BATCHES - 1)),
                         sqrt(variance.z / (BATCHES - 1)));
    return rays;
}

static probe_result probe_irradiance(const void *state_pointer, const scene *s, const probe *p, uint64_t seed,
                                     render_counters *counters)
{
    const pathtrace_state *st = state_pointer;
    probe_result r;
    counters->value[COUNT_PROBE_RAYS] += batch_mean(st, s, p, -1, seed ^ 0x70726f6265ull, st->probe_samples / BATCHES,
                                                    &r.irradiance, &r.standard_error);
    return r;
}

/* ---- main ---------------------------------------------------------------------------------------- */

/* The lights' total power; warnings; the surface averages. */
static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    pathtrace_state *st = state_pointer;
    st->bounce_min = o->bounce_min, st->bounce_max = o->bounce_max, st->seed = o->seed, st->scene = s;
    truncated_walks = 0;
    for (int i = 0; i < s->emitter_count + s->light_count; i++)
        st->total_power += light_power(s, i);
    if (s->light_count > 0 && (st->estimator == ESTIMATOR_HEMISPHERE || st->estimator == ESTIMATOR_COSINE)) {
        bool only = s->emitter_count == 0;
        fprintf(stderr,
                "warning: 04_pathtrace: --estimator %s follows random directions, which never hit a point light: "
                "the image will miss the light of %s%s (use --estimator light or mis)\n",
                estimator_names[st->estimator], only ? "all lights in this scene" : "the point light(s) in this scene",
                only && v3_max_component(s->background) <= 0.0 ? " and come out black" : "");
    }
    if (st->surface_samples == 0)
        return 0;
    st->surface_averages = calloc((size_t)s->surface_count + 1, sizeof *st->surface_averages);
    if (!st->surface_averages) {
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    int per_batch = st->surface_samples / BATCHES > 0 ? st->surface_samples / BATCHES : 1;
    for (int i = 0; i < s->surface_count; i++) {
        material_kind kind = s->materials[s->surfaces[i].material].kind;
        if (kind != MATERIAL_DIFFUSE && kind != MATERIAL_EMITTER)
            continue; /* the same radiance in every direction only on these */
        surface_average *a = &st->surface_averages[st->surface_average_count++];
        a->surface = i;
        st->surface_rays += batch_mean(st, s, NULL, i, st->seed ^ 0x73757266616365ull, per_batch, &a->radiance,
                                       &a->standard_error);
    }
    return 0;
}

static void write_stats(const void *state_pointer, FILE *json)
{
    const pathtrace_state *st = state_pointer;
    fprintf(json, ",\n  \"estimator\": \"%s\",\n  \"rr_depth\": %d,\n  \"max_depth\": %d", estimator_names[st->estimator],
            st->rr_depth, st->max_depth);
    fprintf(json, ",\n  \"truncated_paths\": %llu,\n  \"biased_by_max_depth\": %s", (unsigned long long)truncated_walks,
            truncated_walks ? "true" : "false");
    fprintf(json, ",\n  \"probe_samples\": %d,\n  \"surface_samples\": %d,\n  \"surface_rays\": %llu",
            st->probe_samples, st->surface_samples, (unsigned long long)st->surface_rays);
    fprintf(json, ",\n  \"surfaces\": [");
    for (int j = 0; j < st->surface_average_count; j++) {
        const surface_average *a = &st->surface_averages[j];
        const surface *surf = &st->scene->surfaces[a->surface];
        fprintf(json, "%s\n    {\"name\": ", j ? "," : "");
        json_string(json, surf->name);
        fprintf(json, ", \"area\": ");
        json_number(json, surf->area);
        fprintf(json, ", \"radiance\": ");
        json_vec3(json, a->radiance);
        fprintf(json, ", \"standard_error\": ");
        json_vec3(json, a->standard_error);
        fputc('}', json);
    }
    fprintf(json, "%s]", st->surface_average_count ? "\n  " : "");
}

static void finish(void *state_pointer)
{
    pathtrace_state *st = state_pointer;
    free(st->surface_averages);
    st->surface_averages = NULL;
}

int main(int argc, char **argv)
{
    pathtrace_state state = {
        .estimator = ESTIMATOR_MIS,
        .rr_depth = 3,
        .max_depth = 1000,
        .probe_samples = 1 << 16,
        .surface_samples = 0,
    };
    const chapter path_tracing = {
        .name = "04_pathtrace",
        .description = "path tracing: random walks estimate every term of the Neumann series (R2, R6, R9)",
        .options_help =
            "  --estimator E          hemisphere | cosine | light | mis (default mis):\n"
            "                         uniform directions (R2 as written), cosine-weighted directions,\n"
            "                         next-event estimation on the lights (R9), or both by MIS\n"
            "  --rr-depth N           Russian roulette from N bounces on (default 3; unbiased)\n"
            "  --max-depth N          cut paths after N bounces (default 1000; biased if it cuts: see stats)\n"
            "  --probe-samples N      walks per probe for its irradiance, in 32 batches (default 65536)\n"
            "  --surface-samples N    walks per surface for the stats key \"surfaces\" (default 0 = off)\n",
        .default_spp = 16,
        .counter_names = {"bounce_rays", "shadow_rays", "probe_rays", NULL},
        .parse_option = parse_option,
        .prepare = prepare,
        .radiance = radiance,
        .probe = probe_irradiance,
        .write_stats = write_stats,
        .finish = finish,
    };
    return render_main(argc, argv, &path_tracing, &state);
}
