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
 * k times and then finds light contributes to the term K^k E.  Dividing
 * each step by the probability density of the direction it took makes the
 * expected value exactly (R2) — whichever density we choose, as long as it
 * is positive wherever the integrand is.  The density decides the noise:
 *
 *   --estimator hemisphere  every direction equally likely, pdf 1/(2 pi):
 *                           (R2) as written.  The light is found only by
 *                           chance, so small lights give a noisy image.
 *   --estimator cosine      pdf cos(theta)/pi cancels the cosine of (R2)
 *                           (and, for Phong, part of the lobe too).
 *   --estimator light       next-event estimation: at every vertex, also
 *                           pick a point y on a light and use the area
 *                           form (R9) with G and V of (R8); a direction that
 *                           later hits a light is then not counted again.
 *   --estimator mis         both, each weighted by the power heuristic
 *                           (Veach 1997): good for small lights (light
 *                           sampling) and for glossy reflection of big
 *                           lights (BSDF sampling).  The default.
 *
 * All four are unbiased: in expectation they give the same image (the tests
 * check this), only the noise differs.  Russian roulette ends walks without
 * bias (a walk that survives with probability p is weighted by 1/p), so a
 * walk can be as long as the light needs; --max-depth is a hard cap that
 * does bias, and the statistics say when it cut a path.
 *
 * Sections: state and options · materials (BSDF value, sampling, pdf) ·
 * lights (next-event estimation, R9) · the random walk · radiance along a
 * camera ray · probes · surface averages · main.
 */
#include <stdlib.h>
#include <string.h>

#include "optics.h"
#include "render.h"
#include "sampling.h"
#include "sphere_light.h"

/* ---- state and options ------------------------------------------------------------ */

typedef enum { ESTIMATOR_HEMISPHERE, ESTIMATOR_COSINE, ESTIMATOR_LIGHT, ESTIMATOR_MIS } estimator_kind;
static const char *const estimator_names[] = {"hemisphere", "cosine", "light", "mis"};

/* A light that next-event estimation can pick: an emitting surface or a
 * point light, chosen with a probability proportional to its power. */
typedef struct {
    int surface;        /* emitting surface index, or -1 */
    int point_light;    /* index into scene.lights, or -1 */
    double probability; /* of being picked at a vertex */
    vec3 emission;      /* L_e of the emitting surface (looked up once, in prepare) */
} light_source;

/* Area-averaged exitant radiance of one surface (--surface-samples). */
typedef struct {
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
    int bounce_limit;           /* min(max_depth, bounce_max): no walk scatters more often */
    uint64_t seed;
    light_source *lights;
    int light_count;
    double *surface_pick_probability; /* per surface: probability its light is picked (0 if not a light) */
    struct reflection_lobes *material_lobes; /* per material, then probe_material's: see lobes_of */
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

static bool uses_light_sampling(const pathtrace_state *st)
{
    return st->estimator == ESTIMATOR_LIGHT || st->estimator == ESTIMATOR_MIS;
}

/* ---- materials -------------------------------------------------------------------------- */

/* The non-specular part of a material: a Lambertian term plus the
 * energy-normalised (modified) Phong lobe of Lafortune & Willems (1994),
 *
 *   f(w_i, w_o) = rho / pi  +  ks (n + 2) / (2 pi) cos^n(alpha),
 *
 * alpha the angle between w_i and the mirror direction of w_o.  The factor
 * (n + 2)/(2 pi) makes the lobe reflect at most ks of the incident energy,
 * so rho + ks <= 1 conserves energy (the classic Phong lobe does not).
 *
 * Everything here that depends on the material only, not on the directions,
 * is worked out once per material in prepare() (lobes_of), not at every
 * vertex of every walk. */
typedef struct reflection_lobes {
    vec3 albedo;         /* rho */
    vec3 lambert;        /* rho / pi: the Lambertian term of f */
    vec3 glossy;         /* ks */
    double exponent;     /* n */
    bool has_lobe;       /* ks > 0 or n > 0; otherwise f is the Lambertian term alone */
    double lobe_norm;    /* (n + 2) / (2 pi): the lobe's normalisation in f */
    /* For importance sampling (bsdf_sample, bsdf_eval): */
    double glossy_share; /* probability of drawing w_i from the lobe, see below */
    double lambert_pdf;  /* (1 - glossy_share) / pi: the Lambertian term of the pdf is this times cos(theta) */
    double lobe_pdf;     /* glossy_share (n + 1) / (2 pi): the lobe term of the pdf is this times cos^n(alpha) */
    double inverse_exponent_plus_1; /* 1 / (n + 1), for drawing cos(alpha) = u^(1/(n+1)) */
} reflection_lobes;

/* Which share of BSDF samples go to the glossy lobe: in proportion to the
 * lobes' albedos (a one-sample mixture; the pdf below is the full mixture). */
static double glossy_share(vec3 rho, vec3 ks)
{
    double d = v3_average(rho), s = v3_average(ks);
    return d + s > 0.0 ? s / (d + s) : 0.0;
}

static reflection_lobes lobes_of(const material *m)
{
    vec3 rho = m->albedo, ks = v3_splat(0.0);
    double n = 0.0;
    if (m->kind == MATERIAL_PHONG)
        ks = m->specular, n = m->exponent;
    double share = glossy_share(rho, ks);
    return (reflection_lobes){
        .albedo = rho,
        .lambert = v3_scale(rho, 1.0 / M_PI),
        .glossy = ks,
        .exponent = n,
        .has_lobe = n > 0.0 || v3_max_component(ks) > 0.0,
        .lobe_norm = (n + 2.0) / (2.0 * M_PI),
        .glossy_share = share,
        .lambert_pdf = (1.0 - share) / M_PI,
        .lobe_pdf = share * (n + 1.0) / (2.0 * M_PI),
        .inverse_exponent_plus_1 = 1.0 / (n + 1.0),
    };
}

/* A probe measures irradiance E = Int L cos dw: the radiance a white
 * Lambertian surface (rho = 1) would reflect is E / pi. */
static const material probe_material = {.name = "probe", .kind = MATERIAL_DIFFUSE, .albedo = {1.0, 1.0, 1.0}};

/* Unit mirror direction of w about n: 2 (n.w) n - w. */
static vec3 mirror_of(vec3 w, vec3 n) { return v3_reflect(v3_neg(w), n); }

/* The lobes of m, a material of the scene or the probe's. */
static const reflection_lobes *lobes_for(const pathtrace_state *st, const scene *s, const material *m)
{
    return m == &probe_material ? &st->material_lobes[s->material_count] : &st->material_lobes[m - s->materials];
}

/* Is every channel of a colour zero (or negative)?  Written out rather than
 * v3_max_component(c) <= 0: three comparisons. */
static bool is_black(vec3 c) { return !(c.x > 0.0 || c.y > 0.0 || c.z > 0.0); }

/* What the BSDF needs at one vertex of a walk, worked out once there and
 * shared by next-event estimation and by the choice of the next direction. */
typedef struct {
    const reflection_lobes *lobes;
    vec3 n;      /* unit normal on the side of w_o (surfaces are two-sided) */
    vec3 mirror; /* mirror direction of w_o, the axis of the glossy lobe (if there is one) */
} shading_point;

/* The shading point for light leaving toward w_o (unit: toward the eye or
 * the previous vertex).  Returns false when w_o lies in the surface's plane
 * (n . w_o = 0): f = 0 there, nothing is reflected toward w_o. */
static bool shading_point_at(const pathtrace_state *st, const scene *s, const material *m, vec3 n_geometric,
                             vec3 w_o, shading_point *sp)
{
    double cos_o = v3_dot(n_geometric, w_o);
    sp->lobes = lobes_for(st, s, m);
    sp->n = cos_o > 0.0 ? n_geometric : v3_neg(n_geometric);
    sp->mirror = sp->lobes->has_lobe ? mirror_of(w_o, sp->n) : sp->n; /* (unused without a lobe) */
    return cos_o != 0.0;
}

/* f(w_i, w_o), and the density per steradian with which bsdf_sample draws
 * w_i (for MIS), for a w_i above the surface (cos_i = n . w_i > 0):
 *   pdf = (1 - share) cos(theta)/pi + share (n + 1)/(2 pi) cos^n(alpha),
 * or 1/(2 pi) for --estimator hemisphere.  f and pdf share cos^n(alpha): one
 * pow for both.  (Inline: small, and called up to twice per vertex.) */
static inline vec3 bsdf_eval(const pathtrace_state *st, const shading_point *sp, vec3 w_i, double cos_i, double *pdf)
{
    const reflection_lobes *b = sp->lobes;
    bool uniform = st->estimator == ESTIMATOR_HEMISPHERE;
    vec3 f = b->lambert;
    *pdf = uniform ? uniform_hemisphere_pdf() : b->lambert_pdf * cos_i;
    if (b->has_lobe) {
        double cos_alpha = v3_dot(w_i, sp->mirror);
        if (cos_alpha > 0.0) {
            double lobe = pow(cos_alpha, b->exponent); /* cos^n(alpha) */
            f = v3_add(f, v3_scale(b->glossy, b->lobe_norm * lobe));
            if (!uniform)
                *pdf += b->lobe_pdf * lobe;
        }
    }
    return f;
}

/* A direction drawn by bsdf_sample. */
typedef struct {
    vec3 w_i;    /* unit, above the surface */
    double pdf;  /* per steradian, for MIS if w_i finds a light */
    vec3 weight; /* f cos(theta_i) / pdf: what the walk's throughput is multiplied by (R2) */
} bsdf_sample_result;

/* Draw w_i: uniformly over the hemisphere (--estimator hemisphere), or by
 * importance: cos(theta)/pi for the Lambertian term and
 * (n + 1)/(2 pi) cos^n(alpha) around the mirror direction for the lobe.
 * Returns false if f cos / p is zero, the end of the walk: a lobe sample
 * below the surface (near the horizon), or a black surface. */
static bool bsdf_sample(const pathtrace_state *st, const shading_point *sp, rng *g, bsdf_sample_result *out)
{
    const reflection_lobes *b = sp->lobes;
    double u1 = rng_uniform(g), u2 = rng_uniform(g);
    if (st->estimator != ESTIMATOR_HEMISPHERE && !b->has_lobe) {
        /* A Lambertian surface, the common case: the cosine density cancels
         * everything but the albedo, f cos / p = (rho/pi) cos / (cos/pi) = rho,
         * so there is nothing to evaluate.  cos(theta) = local.z > 0. */
        vec3 local = cosine_sample_hemisphere(u1, u2);
        *out = (bsdf_sample_result){.w_i = onb_to_world(onb_from_normal(sp->n), local),
                                    .pdf = b->lambert_pdf * local.z, .weight = b->albedo};
        return !is_black(b->albedo);
    }
    vec3 w_i;
    if (st->estimator == ESTIMATOR_HEMISPHERE) {
        w_i = onb_to_world(onb_from_normal(sp->n), uniform_sample_hemisphere(u1, u2));
    } else if (rng_uniform(g) >= b->glossy_share) {
        w_i = onb_to_world(onb_from_normal(sp->n), cosine_sample_hemisphere(u1, u2));
    } else {
        double cos_alpha = pow(u1, b->inverse_exponent_plus_1);
        double sin_alpha = sqrt_one_minus_square(cos_alpha);
        double phi = 2.0 * M_PI * u2;
        vec3 local = v3(sin_alpha * cos(phi), sin_alpha * sin(phi), cos_alpha);
        w_i = onb_to_world(onb_from_normal(sp->mirror), local);
    }
    double cos_i = v3_dot(sp->n, w_i), pdf;
    if (!(cos_i > 0.0))
        return false;
    vec3 f = bsdf_eval(st, sp, w_i, cos_i, &pdf);
    if (!(pdf > 0.0) || is_black(f))
        return false;
    *out = (bsdf_sample_result){.w_i = w_i, .pdf = pdf, .weight = v3_scale(f, cos_i / pdf)};
    return true;
}

/* ---- lights: next-event estimation (R9) --------------------------------------------------- */

/* Light sampling turns the integral over directions into one over the
 * lights' surfaces, dw_i = cos(theta_y) dA_y / |x - y|^2 (R7):
 *   L_direct(x, w_o) = Int_lights L_e(y) f(x, w_i, w_o) G(x, y) V(x, y) dA_y     (R8, R9)
 * estimated with one point y: f L_e cos(theta_i) V / p(w_i), where p(w_i) is
 * the density of y converted to solid angle, p_A(y) |x - y|^2 / cos(theta_y),
 * times the chance of having picked this light. */
typedef struct {
    vec3 point;    /* y */
    vec3 w_i;      /* unit, from x toward y */
    vec3 radiance; /* L_e(y) toward x, or I / r^2 for a point light (already the irradiance at normal incidence) */
    double pdf;    /* per steradian, including the pick probability; 0 for a point light (a delta) */
    bool delta;
} light_sample;

/* A planar emitter is sampled uniformly by area, p_A = 1 / A; per steradian
 * that is p_A |x - y|^2 / cos(theta_y) (R7), with r2 = |x - y|^2 and
 * cos(theta_y) = |n_y . w| for the unit direction w from x to y. */
static double planar_light_pdf(double area, double r2, vec3 n_y, vec3 w)
{
    double cos_y = fabs(v3_dot(n_y, w));
    return cos_y > 0.0 ? r2 / (cos_y * area) : 0.0;
}

/* The density with which next-event estimation at x would have chosen the
 * emitter point y (normal n_y): what MIS needs when a BSDF-sampled ray hits
 * a light.  Worked out from x and y exactly as sample_light does, so the
 * two MIS weights of the same path add up to one. */
static double light_pdf(const pathtrace_state *st, const scene *s, int surface_index, vec3 x, vec3 y, vec3 n_y)
{
    double pick = st->surface_pick_probability[surface_index];
    if (!(pick > 0.0))
        return 0.0;
    const surface *surf = &s->surfaces[surface_index];
    if (surf->kind == SURFACE_SPHERE)
        return pick * sphere_light_pdf(surf->center, surf->radius, x, y, n_y);
    vec3 to_y = v3_sub(y, x);
    double r2 = v3_dot(to_y, to_y);
    return pick * planar_light_pdf(surf->area, r2, n_y, v3_scale(to_y, 1.0 / sqrt(r2)));
}

static bool sample_light(const pathtrace_state *st, const scene *s, vec3 x, rng *g, light_sample *out)
{
    if (st->light_count == 0)
        return false;
    /* Pick a light by power (with one light there is nothing to draw). */
    const light_source *light = &st->lights[0];
    if (st->light_count > 1) {
        double u = rng_uniform(g);
        light = &st->lights[st->light_count - 1];
        for (int l = 0; l < st->light_count - 1; l++) {
            if (u < st->lights[l].probability) {
                light = &st->lights[l];
                break;
            }
            u -= st->lights[l].probability;
        }
    }
    if (light->point_light >= 0) {
        const point_light *p = &s->lights[light->point_light];
        vec3 to_light = v3_sub(p->position, x);
        double r2 = v3_dot(to_light, to_light);
        if (!(r2 > 0.0))
            return false;
        *out = (light_sample){.point = p->position, .w_i = v3_scale(to_light, 1.0 / sqrt(r2)),
                              .radiance = v3_scale(p->intensity, 1.0 / (r2 * light->probability)), /* (R1) */
                              .pdf = 0.0, .delta = true};
        return true;
    }
    const surface *surf = &s->surfaces[light->surface];
    double u1 = rng_uniform(g), u2 = rng_uniform(g);
    vec3 y, n_y;
    double pdf = 0.0;
    if (surf->kind == SURFACE_SPHERE) {
        if (!sphere_light_sample(surf->center, surf->radius, x, u1, u2, &y, &n_y, &pdf))
            return false;
    } else {
        surface_sample_point(s, light->surface, u1, u2, rng_uniform(g), &y, &n_y);
    }
    vec3 to_y = v3_sub(y, x);
    double r2 = v3_dot(to_y, to_y);
    if (!(r2 > 0.0))
        return false;
    vec3 w_i = v3_scale(to_y, 1.0 / sqrt(r2));
    if (v3_dot(n_y, w_i) >= 0.0)
        return false; /* the back of an emitter: emitters shine from their front only */
    if (surf->kind != SURFACE_SPHERE)
        pdf = planar_light_pdf(surf->area, r2, n_y, w_i);
    if (!(pdf > 0.0))
        return false;
    *out = (light_sample){.point = y, .w_i = w_i, .radiance = light->emission, .pdf = pdf * light->probability,
                          .delta = false};
    return true;
}

/* One light sample's contribution to the radiance reflected at x toward w_o:
 * f L_e cos(theta_i) V / p  (R9), times the MIS weight when BSDF sampling
 * could have found the same light. */
static vec3 next_event(const pathtrace_state *st, const scene *s, vec3 x, const shading_point *sp, rng *g,
                       render_counters *counters)
{
    light_sample ls;
    if (!sample_light(st, s, x, g, &ls))
        return v3_splat(0.0);
    double cos_i = v3_dot(sp->n, ls.w_i), pdf_bsdf;
    if (cos_i <= 0.0)
        return v3_splat(0.0);
    vec3 f = bsdf_eval(st, sp, ls.w_i, cos_i, &pdf_bsdf);
    if (is_black(f))
        return v3_splat(0.0);
    counters->value[COUNT_SHADOW_RAYS]++;
    if (scene_occluded(s, x, ls.point)) /* V(x, y) */
        return v3_splat(0.0);
    if (ls.delta) /* a point light: nothing else can find it */
        return v3_scale(v3_mul(f, ls.radiance), cos_i);
    double weight = st->estimator == ESTIMATOR_MIS ? power_heuristic(ls.pdf, pdf_bsdf) : 1.0;
    return v3_scale(v3_mul(f, ls.radiance), cos_i * weight / ls.pdf);
}

/* ---- the random walk ---------------------------------------------------------------------- */

/* Counting bounces: light that leaves an emitter and is reflected k times
 * before it reaches the eye (or the probe) is the Neumann term K^k E (R6).
 * The emitter seen directly is k = 0; next-event estimation at the first
 * surface the camera sees is k = 1 (direct illumination).  --bounces A:B
 * keeps a contribution only if A <= k <= B. */

/* The radiance reflected (not emitted) at surface point x toward w_o, i.e.
 * the integral of (R2), by one random walk.  `bounces` is how often the
 * light has already been scattered between x and the eye: 0 at the first
 * surface a camera ray hits, -1 at a probe (which only receives). */
static vec3 reflected_radiance(const pathtrace_state *st, const scene *s, vec3 x, vec3 n_geometric, vec3 w_o,
                               const material *m, int bounces, rng *g, render_counters *counters)
{
    const render_options window = {.bounce_min = st->bounce_min, .bounce_max = st->bounce_max};
    vec3 radiance = v3_splat(0.0);
    vec3 throughput = v3_splat(1.0); /* product of f cos / p along the walk so far */
    for (;;) {
        int k = bounces + 1; /* light scattered here toward w_o has made k bounces */
        if (k > st->bounce_limit) {
            if (k > st->max_depth && st->max_depth < st->bounce_max) {
#pragma omp atomic
                truncated_walks++;
                warn_once(&warned_truncation,
                          "04_pathtrace: a path reached --max-depth %d and was cut there, so the image misses the "
                          "terms beyond K^%d E and is biased low (count in stats)",
                          st->max_depth, st->max_depth);
            }
            break;
        }

        /* Scatter: choose the next direction w_i and update the throughput. */
        vec3 w_i;
        bool specular = true;
        double pdf_bsdf = 0.0; /* of w_i, for MIS on a light hit */
        if (m->kind == MATERIAL_MIRROR) {
            vec3 n = v3_dot(n_geometric, w_o) > 0.0 ? n_geometric : v3_neg(n_geometric);
            w_i = mirror_of(w_o, n);
            throughput = v3_mul(throughput, m->specular);
        } else if (m->kind == MATERIAL_GLASS) {
            /* A dielectric in air.  Reflect with probability F (exact Fresnel,
             * optics.h), refract otherwise: the choice itself is the weight.
             * Radiance crossing into a medium changes by (n_i / n_t)^2 (its
             * solid angle is squeezed); on a closed path through the glass the
             * two factors cancel.  The tint colours the transmitted light. */
            bool entering = v3_dot(n_geometric, w_o) > 0.0;
            vec3 n = entering ? n_geometric : v3_neg(n_geometric);
            double n_i = entering ? 1.0 : m->ior, n_t = entering ? m->ior : 1.0;
            double fresnel = fresnel_dielectric(v3_dot(n, w_o), n_i, n_t, NULL, NULL);
            if (rng_uniform(g) < fresnel || !refract_direction(v3_neg(w_o), n, n_i / n_t, &w_i)) {
                w_i = mirror_of(w_o, n);
            } else {
                double eta = n_i / n_t;
                throughput = v3_mul(throughput, v3_scale(m->specular, eta * eta));
            }
        } else {
            shading_point sp;
            if (!shading_point_at(st, s, m, n_geometric, w_o, &sp))
                break; /* w_o in the surface's plane: f = 0 */
            if (uses_light_sampling(st) && bounces_keep(&window, k))
                radiance = v3_add(radiance, v3_mul(throughput, next_event(st, s, x, &sp, g, counters)));
            bsdf_sample_result scattered;
            if (!bsdf_sample(st, &sp, g, &scattered))
                break;
            w_i = scattered.w_i, pdf_bsdf = scattered.pdf;
            throughput = v3_mul(throughput, scattered.weight); /* f cos / p (R2) */
            specular = false;
        }

        /* Russian roulette: go on with probability p, and weight by 1/p if we
         * do; the expectation is unchanged.  p follows the throughput, so a
         * dim walk ends early and a bright one (a furnace with rho = 0.99)
         * keeps going as long as its light matters. */
        if (k >= st->rr_depth) {
            double p = min_ignoring_nan(1.0, v3_max_component(throughput));
            if (!(p > 0.0) || rng_uniform(g) >= p)
                break;
            throughput = v3_scale(throughput, 1.0 / p);
        }

        ray next = {scene_offset_origin(s, x, n_geometric, w_i), w_i};
        counters->value[COUNT_BOUNCE_RAYS]++;
        hit h;
        if (!scene_intersect(s, next, INFINITY, &h)) {
            if (bounces_keep(&window, k))
                radiance = v3_add(radiance, v3_mul(throughput, s->background));
            break;
        }
        const material *hit_material = &s->materials[s->surfaces[h.surface].material];
        if (hit_material->kind == MATERIAL_EMITTER && v3_dot(h.normal, w_i) < 0.0 && bounces_keep(&window, k)) {
            /* The walk found a light by itself.  Light sampling already
             * counted this light at x unless x was specular (a mirror cannot
             * use a sampled light point); MIS shares it between the two. */
            double weight = 1.0;
            if (!specular && st->estimator == ESTIMATOR_LIGHT)
                weight = 0.0;
            else if (!specular && st->estimator == ESTIMATOR_MIS)
                weight = power_heuristic(pdf_bsdf, light_pdf(st, s, h.surface, x, h.point, h.normal));
            radiance = v3_add(radiance, v3_mul(throughput, v3_scale(hit_material->emission, weight)));
        }
        x = h.point, n_geometric = h.normal, w_o = v3_neg(w_i), m = hit_material, bounces = k;
    }
    return radiance;
}

/* ---- radiance along a camera ray ------------------------------------------------------------- */

static vec3 radiance(const void *state_pointer, const scene *s, ray r, rng *g, render_counters *counters)
{
    const pathtrace_state *st = state_pointer;
    const render_options window = {.bounce_min = st->bounce_min, .bounce_max = st->bounce_max};
    hit h;
    if (!scene_intersect(s, r, INFINITY, &h))
        return bounces_keep(&window, 0) ? s->background : v3_splat(0.0);
    const material *m = &s->materials[s->surfaces[h.surface].material];
    vec3 w_o = v3_neg(r.direction);
    vec3 L = v3_splat(0.0);
    if (m->kind == MATERIAL_EMITTER && v3_dot(h.normal, w_o) > 0.0 && bounces_keep(&window, 0))
        L = m->emission; /* E: the light seen directly (R6, k = 0) */
    return v3_add(L, reflected_radiance(st, s, h.point, h.normal, w_o, m, 0, g, counters));
}

/* ---- probes ---------------------------------------------------------------------------------- */

enum { BATCHES = 32 };

/* Mean and standard error of BATCHES batch means: the batches are
 * independent, so the spread of their means estimates the error of the
 * overall mean without assuming anything about the walks' distribution. */
static void batch_statistics(const vec3 *batch, vec3 *mean, vec3 *standard_error)
{
    vec3 sum = v3_splat(0.0), sum_squares = v3_splat(0.0);
    for (int b = 0; b < BATCHES; b++) {
        sum = v3_add(sum, batch[b]);
        sum_squares = v3_add(sum_squares, v3_mul(batch[b], batch[b]));
    }
    *mean = v3_scale(sum, 1.0 / BATCHES);
    vec3 variance = v3_sub(v3_scale(sum_squares, 1.0 / BATCHES), v3_mul(*mean, *mean));
    double scale = 1.0 / (BATCHES - 1);
    *standard_error = v3(sqrt(fmax(0.0, variance.x) * scale), sqrt(fmax(0.0, variance.y) * scale),
                         sqrt(fmax(0.0, variance.z) * scale));
}

/* Irradiance E = Int L cos dw (the integral of (R2) with f = 1) by the
 * same estimator as the image: E = pi times what a white Lambertian surface
 * at the probe would reflect.  The probe itself scatters nothing, so the
 * light it receives after k bounces is the term K^k E: --bounces 0:0 gives
 * the direct irradiance. */
static probe_result probe_irradiance(const void *state_pointer, const scene *s, const probe *p, uint64_t seed,
                                     render_counters *counters)
{
    const pathtrace_state *st = state_pointer;
    int per_batch = st->probe_samples / BATCHES;
    uint64_t probe_index = (uint64_t)(p - s->probes);
    vec3 batch[BATCHES];
    render_counters batch_counters[BATCHES] = {{{0}}};
#pragma omp parallel for schedule(dynamic, 1)
    for (int b = 0; b < BATCHES; b++) {
        vec3 sum = v3_splat(0.0);
        for (int k = 0; k < per_batch; k++) {
            rng g = rng_for(seed ^ 0x70726f6265ull, probe_index, (uint64_t)b * (uint64_t)per_batch + (uint64_t)k);
            vec3 L = reflected_radiance(st, s, p->position, p->normal, p->normal, &probe_material, -1, &g,
                                        &batch_counters[b]);
            if (v3_is_finite(L))
                sum = v3_add(sum, L);
        }
        batch[b] = v3_scale(sum, M_PI / per_batch);
    }
    for (int b = 0; b < BATCHES; b++)
        counters->value[COUNT_PROBE_RAYS] +=
            batch_counters[b].value[COUNT_BOUNCE_RAYS] + batch_counters[b].value[COUNT_SHADOW_RAYS];
    probe_result result;
    batch_statistics(batch, &result.irradiance, &result.standard_error);
    return result;
}

/* ---- surface averages ------------------------------------------------------------------------ */

/* For comparison with radiosity (R10), which computes one radiance per
 * patch: each diffuse surface's exitant radiance averaged over its area,
 *   L_avg = 1/A Int_A ( L_e(y) + rho/pi E(y) ) dA_y,
 * by walks from points y drawn uniformly on the surface (on its front
 * side).  Lambertian surfaces reflect the same radiance in every direction,
 * so leaving along the normal is as good as any direction. */
static bool has_direction_independent_radiance(const material *m)
{
    return m->kind == MATERIAL_DIFFUSE || m->kind == MATERIAL_EMITTER;
}

static int compute_surface_averages(pathtrace_state *st, const scene *s, char *err, size_t err_size)
{
    st->surface_averages = calloc((size_t)s->surface_count, sizeof *st->surface_averages);
    if (!st->surface_averages) {
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    int count = 0;
    for (int i = 0; i < s->surface_count; i++)
        if (has_direction_independent_radiance(&s->materials[s->surfaces[i].material]))
            st->surface_averages[count++].surface = i;
    st->surface_average_count = count;

    const render_options window = {.bounce_min = st->bounce_min, .bounce_max = st->bounce_max};
    int per_batch = st->surface_samples / BATCHES > 0 ? st->surface_samples / BATCHES : 1;
    vec3 *batch = calloc((size_t)count * BATCHES + 1, sizeof *batch);
    uint64_t *rays = calloc((size_t)count * BATCHES + 1, sizeof *rays);
    if (!batch || !rays) {
        free(batch), free(rays);
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
#pragma omp parallel for schedule(dynamic, 1)
    for (int task = 0; task < count * BATCHES; task++) {
        int index = st->surface_averages[task / BATCHES].surface, b = task % BATCHES;
        const material *m = &s->materials[s->surfaces[index].material];
        render_counters counters = {{0}};
        vec3 sum = v3_splat(0.0);
        for (int k = 0; k < per_batch; k++) {
            rng g = rng_for(st->seed ^ 0x73757266616365ull, (uint64_t)index,
                            (uint64_t)b * (uint64_t)per_batch + (uint64_t)k);
            double u1 = rng_uniform(&g), u2 = rng_uniform(&g), u3 = rng_uniform(&g);
            vec3 y, n;
            surface_sample_point(s, index, u1, u2, u3, &y, &n);
            vec3 L = reflected_radiance(st, s, y, n, n, m, 0, &g, &counters);
            if (m->kind == MATERIAL_EMITTER && bounces_keep(&window, 0))
                L = v3_add(L, m->emission);
            if (v3_is_finite(L))
                sum = v3_add(sum, L);
        }
        batch[task] = v3_scale(sum, 1.0 / per_batch);
        rays[task] = counters.value[COUNT_BOUNCE_RAYS] + counters.value[COUNT_SHADOW_RAYS];
    }
    for (int j = 0; j < count; j++) {
        batch_statistics(batch + (size_t)j * BATCHES, &st->surface_averages[j].radiance,
                         &st->surface_averages[j].standard_error);
        for (int b = 0; b < BATCHES; b++)
            st->surface_rays += rays[(size_t)j * BATCHES + (size_t)b];
    }
    free(batch);
    free(rays);
    return 0;
}

/* ---- main ------------------------------------------------------------------------------------ */

/* Work out every material's lobes; build the list of lights next-event
 * estimation picks from, each with a probability proportional to its power
 * (Phi = pi L A for a Lambertian emitter, 4 pi I for an isotropic point
 * light); and warn about lights the chosen estimator cannot see. */
static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    pathtrace_state *st = state_pointer;
    st->bounce_min = o->bounce_min, st->bounce_max = o->bounce_max, st->seed = o->seed, st->scene = s;
    st->bounce_limit = st->max_depth < o->bounce_max ? st->max_depth : o->bounce_max;
    truncated_walks = 0;

    st->lights = calloc((size_t)(s->emitter_count + s->light_count) + 1, sizeof *st->lights);
    st->surface_pick_probability = calloc((size_t)s->surface_count + 1, sizeof *st->surface_pick_probability);
    st->material_lobes = calloc((size_t)s->material_count + 1, sizeof *st->material_lobes);
    if (!st->lights || !st->surface_pick_probability || !st->material_lobes) {
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    /* The lobes depend on the material only: once here, not at every vertex. */
    for (int i = 0; i < s->material_count; i++)
        st->material_lobes[i] = lobes_of(&s->materials[i]);
    st->material_lobes[s->material_count] = lobes_of(&probe_material);
    double total_power = 0.0;
    for (int e = 0; e < s->emitter_count; e++) {
        const surface *surf = &s->surfaces[s->emitters[e]];
        double power = M_PI * v3_average(s->materials[surf->material].emission) * surf->area;
        if (power > 0.0)
            st->lights[st->light_count++] = (light_source){
                .surface = s->emitters[e], .point_light = -1, .probability = power,
                .emission = s->materials[surf->material].emission};
    }
    for (int l = 0; l < s->light_count; l++) {
        double power = 4.0 * M_PI * v3_average(s->lights[l].intensity);
        if (power > 0.0)
            st->lights[st->light_count++] = (light_source){.surface = -1, .point_light = l, .probability = power};
    }
    for (int l = 0; l < st->light_count; l++)
        total_power += st->lights[l].probability;
    for (int l = 0; l < st->light_count; l++) {
        st->lights[l].probability /= total_power;
        if (st->lights[l].surface >= 0)
            st->surface_pick_probability[st->lights[l].surface] = st->lights[l].probability;
    }

    if (s->light_count > 0 && !uses_light_sampling(st)) {
        bool only = s->emitter_count == 0;
        fprintf(stderr,
                "warning: 04_pathtrace: --estimator %s follows random directions, which never hit a point light: "
                "the image will miss the light of %s%s (use --estimator light or mis)\n",
                estimator_names[st->estimator], only ? "all lights in this scene" : "the point light(s) in this scene",
                only && v3_max_component(s->background) <= 0.0 ? " and come out black" : "");
    }
    if (st->surface_samples > 0)
        return compute_surface_averages(st, s, err, err_size);
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
    free(st->lights);
    free(st->surface_pick_probability);
    free(st->material_lobes);
    free(st->surface_averages);
    st->lights = NULL, st->surface_pick_probability = NULL, st->material_lobes = NULL, st->surface_averages = NULL;
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
