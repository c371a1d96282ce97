/* 05_photonmap.c — Lecture 5: photon mapping.
 *
 * A path tracer (chapter 4) walks from the eye and finds the light by chance.  Light that
 * reaches a diffuse floor through a glass ball (a caustic: light -> specular -> diffuse -> eye,
 * "L S+ D E") can only be found by a walk that leaves the floor in exactly the direction the
 * ball focuses the light from: the noisiest part of chapter 4's image.  Photon mapping
 * (Jensen 1996) turns the walk around:
 *
 *   1. photon pass: shoot photons from the lights, each carrying a share of the emitted
 *      power (flux), bounce them through mirrors, glass and diffuse surfaces (Russian
 *      roulette decides when they are absorbed) and store where they land on non-specular
 *      surfaces;
 *   2. eye pass: follow camera rays through mirrors and glass to the first non-specular
 *      point x and estimate the light reflected there from the photons near x, by density
 *      estimation:
 *
 *   (R11)  L_r(x, w_o) ~= sum over photons p within r of x of f(x, w_p, w_o) Phi_p / (pi r^2)
 *
 * Biased (it blurs the light over a disc of radius r) but consistent: with
 * more photons and a smaller radius it converges to (R2).
 *
 *   --maps global    the naive method: every photon in one map, (R11) at the
 *                    first diffuse point does all the work (direct light too);
 *   --maps caustic   a path tracer (next-event estimation, R9) whose caustic
 *                    paths L S+ D come from a caustic map instead of chance;
 *   --maps both      Jensen's split: direct light by light sampling, caustics
 *                    from the caustic map, the rest from the global map, at x
 *                    or after one more bounce (--gather N: final gathering).
 *
 * Progressive photon mapping (Hachisuka, Ogaki & Jensen 2008; in the memoryless form of
 * Knaus & Zwicker 2011): every pass shoots a new photon map and shrinks the radius,
 *
 *   (R12)  r_{i+1}^2 = r_i^2 (i + alpha) / (i + 1),   0 < alpha < 1,
 *
 * slowly enough that the photons per disc still grow, fast enough that the blur vanishes: the average
 * of the passes converges to the true image.  (alpha = 1 keeps the radius: classic photon mapping, whose bias stays.)
 *
 * The materials (f, drawing a direction like f cos, mirrors and glass), Russian roulette and direct
 * light by light sampling (R9) are chapter 4's, through chapters/pathtrace_model.h: written once.
 *
 * Sections: state, options · lights, photon emission · the photon pass · density
 * estimation (R11) · eye pass · probes · passes (R12), main.
 */
#include <stdlib.h>

#include "pathtrace_model.h" /* chapter 4's: vertex, bsdf_f, scatter, survives_roulette, next_event */
#include "photon_stats.h"    /* and photon_map.h: the photon, the maps, the tally */
#include "render.h"
#include "sampling.h"
#include "walk_stats.h" /* walk_probe: batches of one-sample probe estimates */

/* ---- state and options ------------------------------------------------------------ */

typedef enum { MAPS_GLOBAL, MAPS_CAUSTIC, MAPS_BOTH } maps_kind;
static const char *const maps_names[] = {"global", "caustic", "both"};
enum { CHUNK = 4096, MAX_BOUNCES = 1000 };

/* A light, picked for emission with probability proportional to its power. */
typedef struct {
    int surface, point_light; /* one of them is -1 */
    double probability;
    vec3 power; /* pi L_e A for a Lambertian emitter, 4 pi I for a point light */
} light_source;

typedef struct {
    int photons, maps, gather, nearest, probe_photons; /* options */
    double radius, alpha;
    /* From prepare and begin_pass. */
    const scene *scene;
    bounce_window bounces; /* --bounces A:B (R6) */
    int light_count;
    uint64_t seed, photon_rays;
    light_source *lights;
    vec3 emitted_power; /* of all lights; its mean channel is what next_event picks lights by */
    double initial_radius, current_radius, *radius_per_pass;
    photon_map global, caustic; /* this pass's photons (photon_map.h: what a photon holds) */
    photon_tally tally;         /* stored power over all passes, for the stats */
} photonmap_state;

enum { COUNT_LOOKUPS, COUNT_PHOTONS_VISITED, COUNT_SHADOW_RAYS, COUNT_WALK_RAYS, COUNT_PROBE_RAYS };

#define STATE(field) offsetof(photonmap_state, field)
static const option PHOTONMAP_OPTIONS[] = {
    {"--photons", "N", OPTION_INT, STATE(photons), .min = 1, .max = 1 << 26, .default_text = "100000",
     .help = "photons emitted per pass"},
    {"--radius", "R", OPTION_DOUBLE, STATE(radius), .min = 0.0, .min_exclusive = true, .max = 1e300,
     .help = "first pass's search radius (default: 1/200 of the scene's bounding-box diagonal)"},
    {"--alpha", "A", OPTION_DOUBLE, STATE(alpha), .min = 0.0, .min_exclusive = true, .max = 1.0,
     .default_text = "0.666667", .help = "radius shrink per pass (R12); 1 keeps the radius (no convergence)"},
    {"--maps", NULL, OPTION_CHOICE, STATE(maps), .choices = "global|caustic|both", .default_text = "both",
     .help = "which photon maps estimate what (see the file's header)"},
    {"--gather", "N", OPTION_INT, STATE(gather), .min = 0, .max = 1 << 16, .default_text = "0",
     .help = "final-gather rays per eye sample (0: read the global map at the first diffuse point)"},
    {"--nearest", "K", OPTION_INT, STATE(nearest), .min = 0, .max = PHOTON_GRID_MAX_NEAREST, .default_text = "0",
     .help = "use the K nearest photons within the radius (0: all photons within it)"},
    {"--probe-photons", "N", OPTION_INT, STATE(probe_photons), .min = PROBE_BATCHES, .max = 1 << 28,
     .default_text = "262144", .help = "light samples and photons per probe estimate, in 32 batches"},
    {0},
};
#undef STATE

/* Is the Neumann term K^k E (R6) inside the --bounces window? */
static bool keeps(const photonmap_state *st, int k) { return bounces_keep(st->bounces, k); }

/* ---- lights and photon emission ----------------------------------------------------------- */

/* One light, chosen with probability proportional to its power (mean channel). */
static const light_source *pick_light(const photonmap_state *st, rng *g)
{
    double u = rng_uniform(g);
    for (int l = 0; l < st->light_count - 1; l++) {
        if (u < st->lights[l].probability)
            return &st->lights[l];
        u -= st->lights[l].probability;
    }
    return &st->lights[st->light_count - 1];
}

/* A photon leaving a light: a point and a direction drawn in proportion to the emitted power (uniform
 * over the sphere for a point light; uniform over the area and cosine-weighted for a Lambertian emitter,
 * whose normal there goes to *normal), so every photon carries the same share
 * Phi_p = Phi_light / (probability * photons) of (R11). [exercise 5.1] */
static ray emit_photon(const photonmap_state *st, const scene *s, rng *g, int photons, vec3 *power, vec3 *normal)
{
    const light_source *light = pick_light(st, g);
    *power = v3_scale(light->power, 1.0 / (light->probability * photons));
    double u1 = rng_uniform(g), u2 = rng_uniform(g);
    if (light->point_light >= 0)
        return (ray){s->lights[light->point_light].position, uniform_sample_sphere(u1, u2)};
    vec3 y;
    surface_sample_point(s, light->surface, u1, u2, rng_uniform(g), &y, normal);
    vec3 w = onb_to_world(onb_from_normal(*normal), cosine_sample_hemisphere(rng_uniform(g), rng_uniform(g)));
    return (ray){scene_offset_origin(s, y, *normal, w), w};
}

/* ---- the photon pass -------------------------------------------------------------------------- */

/* A photon carries flux, not radiance.  Radiance refracted into glass is
 * squeezed into a smaller solid angle, and chapter 4's weight multiplies it
 * by (n_i / n_t)^2; the flux through the surface is not: undo that factor. */
vec3 as_flux(const vertex *v, vec3 radiance_weight, vec3 w_i)
{
    if (v->m->kind != MATERIAL_GLASS || v3_dot(w_i, v->n) > 0.0) /* not refracted */
        return radiance_weight;
    double n_t_over_n_i = v->front ? v->m->ior : 1.0 / v->m->ior;
    return v3_scale(radiance_weight, n_t_over_n_i * n_t_over_n_i);
}

/* What one photon tells a probe, a sensor at x (not a surface: photons fly past it).  Its irradiance
 * E(x) = Int L cos dw (R2), split by the last vertex x' of the light's path before x:
 *   - a light, or a non-specular surface where a photon lands: photons sample the light leaving the
 *     lights and arriving at surfaces (R11: flux per area), so the sum of f(x', w_p, x' -> x) Phi_p
 *     G(x, x') V(x, x') (R8) over them estimates (R9)'s integral over A' with no radius: no blur, no
 *     bias (a disc near a crease would pass behind the wall).  At a light (v NULL) f is the share of
 *     its power per steradian: cos / pi (Lambertian emitter), 1 / (4 pi) (point light, n zero);
 *   - a mirror or glass, a delta no shadow ray can aim at x: the photon's flux through a disc of the
 *     eye pass's radius around x (R11, f = 1), blurred like the image's caustics, shrinking by (R12). */
static vec3 light_sent_to_probe(const scene *s, const probe *p, vec3 from, vec3 n, const vertex *v, vec3 power)
{
    double d = v3_length(v3_sub(p->position, from));
    vec3 w = v3_scale(v3_sub(p->position, from), 1.0 / d);
    double cos_probe = -v3_dot(w, p->normal), cos_from = v3_dot(n, n) > 0.0 ? v3_dot(w, n) : 1.0;
    if (!(cos_probe > 0.0 && cos_from > 0.0) || scene_occluded(s, from, p->position)) /* V(x, x') */
        return v3_splat(0.0);
    vec3 f = v ? bsdf_f(v, w) : v3_splat(v3_dot(n, n) > 0.0 ? 1.0 / M_PI : 0.25 / M_PI);
    return v3_scale(v3_mul(f, power), cos_probe * cos_from / (d * d)); /* f Phi_p G (R8) */
}

/* Follow one photon from a light until Russian roulette absorbs it or it leaves the scene, storing
 * it (into `out`) at every non-specular surface it lands on, caustic while it met only mirrors and
 * glass (L S+ D); each bounce multiplies its power by f cos / p (R2).  For a probe (`sensor`) it adds
 * its irradiance from this photon to *received.  Returns the rays traced, or -1 if out of memory. [exercise 5.2] */
static int trace_photon(const photonmap_state *st, const scene *s, int photons, uint32_t path, rng *g, photon_map *out,
                        const probe *sensor, vec3 *received)
{
    vec3 power = v3_splat(0.0), normal = v3_splat(0.0); /* emit_photon sets them; zero while it is a stub */
    ray r = emit_photon(st, s, g, photons, &power, &normal);
    if (sensor && keeps(st, 0)) /* the light itself */
        *received = v3_add(*received, light_sent_to_probe(s, sensor, r.origin, normal, NULL, power));
    bool caustic = true, after_specular = false;
    int bounces;
    for (bounces = 0; bounces < MAX_BOUNCES; bounces++) {
        hit h;
        bool found = scene_intersect(s, r, INFINITY, &h);
        double t_max = found ? h.t + s->epsilon : INFINITY;   /* a probe on a wall: what lands in its disc */
        if (sensor && after_specular && keeps(st, bounces) && /* the disc, (R11) with f = 1 */
            ray_crosses_disc(r, t_max, sensor->position, sensor->normal, st->current_radius))
            *received = v3_add(*received, v3_scale(power, 1.0 / (M_PI * st->current_radius * st->current_radius)));
        if (!found)
            break;
        vertex v = vertex_at(h.point, h.normal, v3_neg(r.direction), material_of(s, h.surface));
        if (!is_specular(v.m)) {
            photon p = {v.x, v.w_o, v.n, power, bounces, caustic && bounces > 0, v.front, h.surface, path};
            if (out && photon_map_add(out, &p))
                return -1;
            if (sensor && keeps(st, bounces + 1))
                *received = v3_add(*received, light_sent_to_probe(s, sensor, v.x, v.n, &v, power));
            caustic = false;
        }
        after_specular = is_specular(v.m);
        vec3 w_i;
        double pdf;
        vec3 weight = as_flux(&v, scatter(&v, sample_bsdf, g, &w_i, &pdf), w_i); /* f cos / p (R2) */
        if (!(v3_max_component(weight) > 0.0) || !survives_roulette(&weight, g))
            break; /* absorbed */
        power = v3_mul(power, weight);
        r = (ray){scene_offset_origin(s, h.point, h.normal, w_i), w_i};
    }
    return bounces + 1;
}

/* Shoot the pass's photons in parallel.  Each chunk of CHUNK photons has
 * its own list, and each photon its own random stream, so the maps (the
 * lists joined in chunk order) are the same for any number of threads. */
static int photon_pass(photonmap_state *st, const scene *s, int pass)
{
    int chunks = (st->photons + CHUNK - 1) / CHUNK, failed = 0;
    photon_map *lists = calloc((size_t)chunks, sizeof *lists);
    uint64_t rays = 0;
    if (!lists)
        return 2;
#pragma omp parallel for schedule(dynamic, 1) reduction(+ : rays, failed)
    for (int c = 0; c < chunks; c++)
        for (int k = c * CHUNK; k < st->photons && k < (c + 1) * CHUNK; k++) {
            rng g = rng_for(st->seed ^ 0x70686f746f6eull, (uint64_t)pass, (uint64_t)k);
            int traced = trace_photon(st, s, st->photons, (uint32_t)k, &g, &lists[c], NULL, NULL);
            failed += traced < 0, rays += (uint64_t)(traced > 0 ? traced : 0);
        }
    st->photon_rays += rays;
    failed += photon_maps_merge(lists, chunks, &st->global, &st->caustic);
    free(lists);
    return failed ? 2 : 0;
}

/* ---- density estimation (R11) ---------------------------------------------------------------- */

typedef enum { ALL_PHOTONS, INDIRECT_PHOTONS } photon_filter;

/* Does photon p count at x (unit normal n on the side of w_o)?  It must have landed on a surface
 * facing the same way (not the wall round the corner, not the back of a thin panel), and its light
 * must be a term of (R6) the --bounces window keeps: it scattered p->bounces times, then once more
 * at x after `before` scatterings on the way to the eye. */
static bool photon_counts(const photonmap_state *st, const photon *p, vec3 n, int before, photon_filter filter)
{
    bool counted_elsewhere = filter == INDIRECT_PHOTONS && (p->bounces == 0 || p->caustic); /* direct, caustic */
    bool from_above = v3_dot(p->from, n) > 0.0; /* f is zero below the surface */
    return v3_dot(p->normal, n) >= 0.9 && from_above && !counted_elsewhere && keeps(st, before + p->bounces + 1);
}

/* (R11): the sum of f Phi_p over the photons in a disc of radius r around x,
 * divided by the disc's area pi r^2.  With --nearest K the disc is the
 * smallest that holds the K nearest photons (at most the pass's radius). [exercise 5.3] */
static vec3 photon_estimate(const photonmap_state *st, const photon_map *map, vec3 x, vec3 n, vec3 w_o,
                            const material *m, int before, photon_filter filter, render_counters *counters)
{
    vertex v = vertex_at(x, n, w_o, m);
    double r2 = st->current_radius * st->current_radius, d2;
    if (st->nearest > 0)
        r2 = photon_grid_nearest_radius2(&map->grid, x, st->current_radius, st->nearest);
    vec3 sum = v3_splat(0.0);
    photon_grid_cursor c;
    uint32_t i;
    counters->value[COUNT_LOOKUPS]++;
    for (photon_grid_search(&map->grid, x, r2, &c); photon_grid_next(&map->grid, &c, &i, &d2);) {
        const photon *p = &map->photons[i];
        if (photon_counts(st, p, n, before, filter))
            sum = v3_add(sum, v3_mul(bsdf_f(&v, p->from), p->power));
        counters->value[COUNT_PHOTONS_VISITED]++;
    }
    return v3_scale(sum, 1.0 / (M_PI * r2)); /* (R11) */
}

/* ---- the eye pass ------------------------------------------------------------------------------ */

/* Follow *r through mirrors and glass (each a bounce, its weight multiplied
 * in) to the first non-specular surface; *r ends as the last segment.  False
 * if the path leaves the scene (*escaped: it sees the background) or is lost. */
static bool next_diffuse_hit(const scene *s, ray *r, vec3 *weight, int *bounces, rng *g, render_counters *counters,
                             hit *h, bool *escaped)
{
    for (*escaped = false; *bounces < MAX_BOUNCES; ++*bounces) {
        counters->value[COUNT_WALK_RAYS]++;
        if (!scene_intersect(s, *r, INFINITY, h))
            return !(*escaped = true);
        vertex v = vertex_at(h->point, h->normal, v3_neg(r->direction), material_of(s, h->surface));
        if (!is_specular(v.m))
            return true;
        vec3 w_i;
        *weight = v3_mul(*weight, specular_scatter(&v, g, &w_i));
        if (!survives_roulette(weight, g))
            return false;
        *r = (ray){scene_offset_origin(s, h->point, h->normal, w_i), w_i};
    }
    return false;
}

/* At the non-specular point x (normal n on the side of w_o, `before`
 * scatterings from the eye): the light the maps need not blur, direct light
 * by light sampling (R9: chapter 4's next_event), and the caustics from the
 * caustic map (R11). */
static vec3 direct_and_caustic(const photonmap_state *st, const scene *s, hit x, vec3 n, vec3 w_o, int before, rng *g,
                               render_counters *counters)
{
    const material *m = material_of(s, x.surface);
    vec3 L = photon_estimate(st, &st->caustic, x.point, n, w_o, m, before, ALL_PHOTONS, counters);
    if (!keeps(st, before + 1))
        return L;
    vertex v = vertex_at(x.point, n, w_o, m);
    double total_power = v3_average(st->emitted_power);
    return v3_add(L, next_event(s, total_power, &v, light_sample_only, g, &counters->value[COUNT_SHADOW_RAYS]));
}

/* The rest of the light at x by one walk (weight 1/walks): --maps both reads the global map where
 * the walk lands next (final gathering), --maps caustic goes on as a path tracer.  Light a walk
 * finds on an emitter is direct or caustic light at the vertex before, counted there: not again. [exercise 5.5] */
static vec3 indirect_walk(const photonmap_state *st, const scene *s, hit at, vec3 normal, vec3 out, int k, vec3 weight,
                          rng *g, render_counters *counters)
{
    vec3 L = v3_splat(0.0), w_i;
    while (k < st->bounces.last) {
        vertex v = vertex_at(at.point, normal, out, material_of(s, at.surface));
        double pdf;
        weight = v3_mul(weight, scatter(&v, sample_bsdf, g, &w_i, &pdf)); /* f cos / p (R2) */
        if (!(v3_max_component(weight) > 0.0))
            break;
        ray r = {scene_offset_origin(s, at.point, at.normal, w_i), w_i};
        bool escaped = false;
        k++;
        if (!survives_roulette(&weight, g) || !next_diffuse_hit(s, &r, &weight, &k, g, counters, &at, &escaped)) {
            if (escaped && keeps(st, k)) /* the background lights x: it shoots no photons */
                L = v3_add(L, v3_mul(weight, s->background));
            break;
        }
        out = v3_neg(r.direction);
        normal = v3_dot(at.normal, out) > 0.0 ? at.normal : v3_neg(at.normal);
        if (st->maps == MAPS_BOTH) /* final gathering: the global map one bounce on */
            return v3_add(L, v3_mul(weight, photon_estimate(st, &st->global, at.point, normal, out,
                                                            material_of(s, at.surface), k, ALL_PHOTONS, counters)));
        L = v3_add(L, v3_mul(weight, direct_and_caustic(st, s, at, normal, out, k, g, counters)));
    }
    return L;
}

/* The light reflected at the non-specular point x toward w_o.  --maps global:
 * (R11) on the global map, nothing else.  Otherwise direct light and
 * caustics, and for the rest the global map's photons that were reflected
 * diffusely on their way (--gather 0, --maps both), or --gather N walks. [exercise 5.4] */
static vec3 reflected_radiance(const photonmap_state *st, const scene *s, hit x, vec3 w_o, int before, rng *g,
                               render_counters *counters)
{
    const material *m = material_of(s, x.surface);
    vec3 n = v3_dot(x.normal, w_o) > 0.0 ? x.normal : v3_neg(x.normal);
    if (st->maps == MAPS_GLOBAL)
        return photon_estimate(st, &st->global, x.point, n, w_o, m, before, ALL_PHOTONS, counters);
    vec3 L = direct_and_caustic(st, s, x, n, w_o, before, g, counters);
    if (st->maps == MAPS_BOTH && st->gather == 0)
        return v3_add(L, photon_estimate(st, &st->global, x.point, n, w_o, m, before, INDIRECT_PHOTONS, counters));
    int walks = st->gather > 0 ? st->gather : 1;
    for (int w = 0; w < walks; w++)
        L = v3_add(L, indirect_walk(st, s, x, n, w_o, before, v3_splat(1.0 / walks), g, counters));
    return L;
}

/* Radiance along a camera ray: through mirrors and glass to the first
 * non-specular point; its emission (seen after k specular bounces: the term
 * K^k E) and the light it reflects. */
static vec3 radiance(const void *state_pointer, const scene *s, ray r, rng *g, render_counters *counters)
{
    const photonmap_state *st = state_pointer;
    vec3 weight = v3_splat(1.0);
    int k = 0;
    hit x;
    bool escaped;
    if (!next_diffuse_hit(s, &r, &weight, &k, g, counters, &x, &escaped))
        return escaped && keeps(st, k) ? v3_mul(weight, s->background) : v3_splat(0.0);
    const material *m = material_of(s, x.surface);
    vec3 w_o = v3_neg(r.direction);
    vec3 L = m->kind == MATERIAL_EMITTER && v3_dot(x.normal, w_o) > 0.0 && keeps(st, k) ? m->emission : v3_splat(0.0);
    return v3_mul(weight, v3_add(L, reflected_radiance(st, s, x, w_o, k, g, counters)));
}

/* ---- probes -------------------------------------------------------------------------------------- */

/* One sample of E / pi, what a white Lambertian point x at a probe reflects (walk_probe, which asks
 * for k = 0, multiplies it by pi): one photon's light at x (see above). */
static vec3 probe_light(const void *state_pointer, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *white,
                        int k, rng *g, render_counters *counters)
{
    const photonmap_state *st = state_pointer;
    vec3 E = v3_splat(0.0);
    (void)w_o;
    (void)white;
    if (st->light_count > 0 && k == 0)
        counters->value[COUNT_WALK_RAYS] +=
            (uint64_t)trace_photon(st, s, 1, 0, g, NULL, &(probe){.position = x, .normal = n}, &E);
    return v3_scale(E, 1.0 / M_PI);
}

static probe_result probe_irradiance(const void *state_pointer, const scene *s, const probe *p, uint64_t seed,
                                     render_counters *counters)
{
    const photonmap_state *st = state_pointer;
    walk_source w = {probe_light, st, s, false};
    return walk_probe(&w, p, probe_seed(seed), st->probe_photons, &counters->value[COUNT_PROBE_RAYS]);
}

/* ---- passes (R12), stats and main ----------------------------------------------------------------- */

/* The lights, each with its power and its chance of emitting a photon. */
static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    photonmap_state *st = state_pointer;
    st->scene = s, st->seed = o->seed, st->bounces = bounce_window_of(o);
    st->lights = calloc((size_t)(s->emitter_count + s->light_count) + 1, sizeof *st->lights);
    st->tally.surface = calloc((size_t)s->surface_count * PROBE_BATCHES + 1, sizeof *st->tally.surface);
    if (!st->lights || !st->tally.surface) {
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    for (int e = 0; e < s->emitter_count; e++) {
        const surface *surf = &s->surfaces[s->emitters[e]];
        vec3 power = v3_scale(s->materials[surf->material].emission, M_PI * surf->area);
        if (v3_average(power) > 0.0)
            st->lights[st->light_count++] = (light_source){s->emitters[e], -1, v3_average(power), power};
    }
    for (int l = 0; l < s->light_count; l++) {
        vec3 power = v3_scale(s->lights[l].intensity, 4.0 * M_PI);
        if (v3_average(power) > 0.0)
            st->lights[st->light_count++] = (light_source){-1, l, v3_average(power), power};
    }
    for (int l = 0; l < st->light_count; l++) /* the power of all of them, then each one's share */
        st->emitted_power = v3_add(st->emitted_power, st->lights[l].power);
    for (int l = 0; l < st->light_count; l++)
        st->lights[l].probability /= v3_average(st->emitted_power);
    if (st->light_count == 0)
        fprintf(stderr, "warning: 05_photonmap: the scene has no light to shoot photons from: %s\n",
                v3_max_component(s->background) > 0.0 ? "only the background lights it" : "the image is black");
    /* A radius relative to the scene, so the scene's unit does not matter. */
    st->initial_radius = st->radius > 0.0 ? st->radius : 0.005 * scene_diagonal(s);
    st->current_radius = st->initial_radius = st->initial_radius > 0.0 ? st->initial_radius : 1.0;
    return 0;
}

/* (R12) after pass i: r_{i+1}^2 = r_i^2 (i + alpha) / (i + 1). [exercise 5.6] */
static void shrink_radius(photonmap_state *st, int i) { st->current_radius *= sqrt((i + st->alpha) / (i + 1)); }

/* Before pass i (from 1): the radius of (R12), and a new photon map. */
static int begin_pass(void *state_pointer, const scene *s, const render_options *o, int pass, char *err,
                      size_t err_size)
{
    photonmap_state *st = state_pointer;
    (void)o;
    if (pass > 1)
        shrink_radius(st, pass - 1);
    if (photon_radius_record(&st->radius_per_pass, pass, st->current_radius) ||
        (st->light_count > 0 && photon_pass(st, s, pass)) || photon_map_index(&st->global, st->current_radius) ||
        photon_map_index(&st->caustic, st->current_radius)) {
        snprintf(err, err_size, "argv:0: out of memory for the photons of pass %d", pass);
        return 2;
    }
    photon_tally_add(&st->tally, &st->global, st->bounces.first, st->bounces.last);
    return 0;
}

static void write_stats(const void *state_pointer, FILE *json)
{
    const photonmap_state *st = state_pointer;
    photon_run run = {maps_names[st->maps], st->photons,         st->gather,        st->nearest, st->alpha,
                      st->photon_rays,      st->radius_per_pass, st->emitted_power, &st->tally};
    photon_run_write(json, &run, st->scene, keeps(st, 0));
}

static void finish(void *state_pointer)
{
    photonmap_state *st = state_pointer;
    photon_map_free(&st->global);
    photon_map_free(&st->caustic);
    free(st->lights), free(st->tally.surface), free(st->radius_per_pass);
    st->lights = NULL, st->tally.surface = NULL, st->radius_per_pass = NULL;
}

int main(int argc, char **argv)
{
    photonmap_state state = {0};
    const chapter photon_mapping = {
        .name = "05_photonmap",
        .description = "photon mapping: density estimation (R11) of photons shot from the lights; progressive (R12)",
        .options = {{PHOTONMAP_OPTIONS, &state}},
        .default_spp = 16,
        .counter_names = {"photon_lookups", "photons_visited", "shadow_rays", "walk_rays", "probe_rays", NULL},
        .prepare = prepare,
        .begin_pass = begin_pass,
        .radiance = radiance,
        .probe = probe_irradiance,
        .write_stats = write_stats,
        .finish = finish,
    };
    return render_main(argc, argv, &photon_mapping, &state);
}
