/* 05_photonmap.c — Lecture 5: photon mapping.
 *
 * A path tracer (chapter 4) walks from the eye and finds the light by
 * chance.  Light that reaches a diffuse floor through a glass ball (a
 * caustic: light -> specular -> diffuse -> eye, "L S+ D E") can only be found
 * by a walk that leaves the floor in exactly the direction the ball focuses
 * the light from: the noisiest part of chapter 4's image.  Photon mapping
 * (Jensen 1996) turns the walk around:
 *
 *   1. photon pass: shoot photons from the lights, each carrying a share of
 *      the emitted power (flux), bounce them through mirrors, glass and
 *      diffuse surfaces (Russian roulette decides when they are absorbed)
 *      and store where they land on non-specular surfaces;
 *   2. eye pass: follow camera rays through mirrors and glass to the first
 *      non-specular point x and estimate the light reflected there from the
 *      photons near x, by density estimation:
 *
 *   (R11)  L_r(x, w_o) ~= sum over photons p within r of x of f(x, w_p, w_o) Phi_p / (pi r^2)
 *
 * The estimate is biased (it blurs the light over a disc of radius r) but
 * consistent: with more photons and a smaller radius it converges to (R2).
 *
 *   --maps global    the naive method: every photon in one map, (R11) at the
 *                    first diffuse point does all the work (direct light too);
 *   --maps caustic   a path tracer (next-event estimation, R9) whose caustic
 *                    paths L S+ D come from a caustic map instead of chance;
 *   --maps both      Jensen's split: direct light by light sampling, caustics
 *                    from the caustic map, the rest from the global map, at x
 *                    or after one more bounce (--gather N: final gathering).
 *
 * Progressive photon mapping (Hachisuka, Ogaki & Jensen 2008; in the
 * memoryless form of Knaus & Zwicker 2011): every pass shoots a new photon
 * map and shrinks the radius,
 *
 *   (R12)  r_{i+1}^2 = r_i^2 (i + alpha) / (i + 1),   0 < alpha < 1,
 *
 * slowly enough that the photons per disc still grow, fast enough that the
 * blur vanishes: the average of the passes converges to the true image.
 * (alpha = 1 keeps the radius: classic photon mapping, whose bias stays.)
 *
 * Sections: state and options · scattering · lights and photon emission ·
 * the photon pass · density estimation (R11) · direct light (R9) · the eye
 * pass · probes · passes (R12), stats and main.
 */
#include <stdlib.h>
#include <string.h>

#include "optics.h"
#include "photon_grid.h"
#include "render.h"
#include "sampling.h"

/* ---- state and options ------------------------------------------------------------ */

typedef enum { MAPS_GLOBAL, MAPS_CAUSTIC, MAPS_BOTH } maps_kind;
static const char *const maps_names[] = {"global", "caustic", "both"};
enum { BATCHES = 32, CHUNK = 4096, MAX_BOUNCES = 1000, MAX_NEAREST = 4096 };

/* A photon where it landed: a packet of flux Phi_p arriving from w_p. */
typedef struct {
    vec3 position;
    vec3 from;    /* w_p: unit, toward where the photon came from */
    vec3 normal;  /* the surface's unit normal on the side the photon arrived */
    vec3 power;   /* Phi_p (W per channel), already divided by the photons of the pass */
    int bounces;  /* scatterings before it landed: 0 = straight from a light */
    bool caustic; /* every scattering was specular (the path L S+ D) */
    bool front;   /* it arrived on the side the surface's normal points to */
    int surface;
    uint32_t path; /* which emitted photon it is (for batch statistics) */
} photon;

typedef struct {
    photon *photons;
    size_t count, capacity;
    photon_grid grid;
} photon_map;

/* A light, picked for emission with probability proportional to its power. */
typedef struct {
    int surface, point_light; /* one of them is -1 */
    double probability;
    vec3 power;               /* pi L_e A for a Lambertian emitter, 4 pi I for a point light */
} light_source;

typedef struct {
    int photons, maps, gather, nearest, probe_photons; /* options */
    double radius, alpha;
    /* From prepare and begin_pass. */
    const scene *scene;
    int bounce_min, bounce_max, passes;
    uint64_t seed;
    light_source *lights;
    int light_count;
    double initial_radius, current_radius, *radius_per_pass;
    photon_map global, caustic;
    uint64_t photon_rays, stored[2];
    vec3 emitted_power, power_batch[2][BATCHES]; /* stored power, global and caustic map */
    vec3 *surface_batch;                         /* per surface x BATCHES: power landing on its front */
} photonmap_state;

enum { COUNT_LOOKUPS, COUNT_PHOTONS_USED, COUNT_SHADOW_RAYS, COUNT_WALK_RAYS };

#define STATE(field) offsetof(photonmap_state, field)
static const option PHOTONMAP_OPTIONS[] = {
    {"--photons", "N", OPTION_INT, STATE(photons), .min = 1, .max = 1 << 26, .default_text = "100000",
     .help = "photons emitted per pass"},
    {"--radius", "R", OPTION_DOUBLE, STATE(radius), .min = 0.0, .min_exclusive = true, .max = 1e300,
     .help = "first pass's search radius (default: 1/100 of the scene's bounding-box diagonal)"},
    {"--alpha", "A", OPTION_DOUBLE, STATE(alpha), .min = 0.0, .min_exclusive = true, .max = 1.0,
     .default_text = "0.666667", .help = "radius shrink per pass (R12); 1 keeps the radius (no convergence)"},
    {"--maps", NULL, OPTION_CHOICE, STATE(maps), .choices = "global|caustic|both", .default_text = "both",
     .help = "which photon maps estimate what (see the file's header)"},
    {"--gather", "N", OPTION_INT, STATE(gather), .min = 0, .max = 1 << 16, .default_text = "0",
     .help = "final-gather rays per eye sample (0: read the global map at the first diffuse point)"},
    {"--nearest", "K", OPTION_INT, STATE(nearest), .min = 0, .max = MAX_NEAREST, .default_text = "0",
     .help = "use the K nearest photons within the radius (0: all photons within it)"},
    {"--probe-photons", "N", OPTION_INT, STATE(probe_photons), .min = BATCHES, .max = 1 << 28,
     .default_text = "1048576", .help = "photons per probe estimate, in 32 batches"},
    {0},
};
#undef STATE

/* Is the Neumann term K^k E (R6) inside the --bounces window? */
static bool keeps(const photonmap_state *st, int k) { return k >= st->bounce_min && k <= st->bounce_max; }

/* ---- scattering -------------------------------------------------------------------------- */

/* Non-specular materials (diffuse, Phong, emitters that reflect) get photons
 * and the density estimate; mirrors and glass only pass light on. */
static bool is_specular(const material *m) { return m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS; }

/* f(w_i, w_o) of chapter 4: Lambert plus the normalised Phong lobe around the
 * mirror direction of w_o (symmetric in w_i and w_o, so photons and eye
 * paths share it).  n is the normal on the side of w_o; 0 below the surface. */
static vec3 bsdf(const material *m, vec3 n, vec3 w_i, vec3 w_o)
{
    if (v3_dot(n, w_i) <= 0.0 || v3_dot(n, w_o) <= 0.0)
        return v3_splat(0.0);
    vec3 f = v3_scale(m->albedo, 1.0 / M_PI);
    double cos_alpha = v3_dot(w_i, v3_reflect(v3_neg(w_o), n));
    if (m->kind == MATERIAL_PHONG && cos_alpha > 0.0)
        f = v3_add(f, v3_scale(m->specular, (m->exponent + 2.0) / (2.0 * M_PI) * pow(cos_alpha, m->exponent)));
    return f;
}

/* Draw w_i at a non-specular point: cosine-weighted, or (for Phong, with
 * the lobe's share of the albedo) around the mirror direction; the weight
 * f cos / pdf uses the pdf of the whole mixture.  False: absorbed. */
static bool sample_bsdf(const material *m, vec3 n, vec3 w_o, rng *g, vec3 *w_i, vec3 *weight)
{
    double kd = v3_average(m->albedo), ks = m->kind == MATERIAL_PHONG ? v3_average(m->specular) : 0.0;
    double share = kd + ks > 0.0 ? ks / (kd + ks) : 0.0, u1 = rng_uniform(g), u2 = rng_uniform(g);
    vec3 mirror = v3_reflect(v3_neg(w_o), n);
    if (rng_uniform(g) >= share) {
        *w_i = onb_to_world(onb_from_normal(n), cosine_sample_hemisphere(u1, u2));
    } else {
        double c = pow(u1, 1.0 / (m->exponent + 1.0)), sin_phi, cos_phi;
        sincos_turns(u2, &sin_phi, &cos_phi);
        vec3 local = v3(sqrt_one_minus_square(c) * cos_phi, sqrt_one_minus_square(c) * sin_phi, c);
        *w_i = onb_to_world(onb_from_normal(mirror), local);
    }
    double cos_i = v3_dot(n, *w_i), cos_alpha = fmax(0.0, v3_dot(*w_i, mirror));
    double pdf = (1.0 - share) * cos_i / M_PI + share * (m->exponent + 1.0) / (2.0 * M_PI) * pow(cos_alpha, m->exponent);
    if (!(cos_i > 0.0) || !(pdf > 0.0))
        return false;
    *weight = v3_scale(bsdf(m, n, *w_i, w_o), cos_i / pdf);
    return v3_max_component(*weight) > 0.0;
}

/* A mirror or glass: the next direction and its weight.  Glass reflects
 * with probability F (exact Fresnel) and refracts otherwise.  Radiance
 * crossing into glass is squeezed into a smaller solid angle, times
 * (n_i / n_t)^2; flux is not (a photon's power is the same on both sides):
 * `carries_radiance` says which of the two is being carried. */
static vec3 scatter_specular(const material *m, vec3 n_geometric, vec3 w_o, bool carries_radiance, rng *g, vec3 *w_i)
{
    bool entering = v3_dot(n_geometric, w_o) > 0.0;
    vec3 n = entering ? n_geometric : v3_neg(n_geometric);
    if (m->kind == MATERIAL_MIRROR) {
        *w_i = v3_reflect(v3_neg(w_o), n);
        return m->specular;
    }
    double n_i = entering ? 1.0 : m->ior, n_t = entering ? m->ior : 1.0;
    double fresnel = fresnel_dielectric(v3_dot(n, w_o), n_i, n_t, NULL, NULL);
    if (rng_uniform(g) < fresnel || !refract_direction(v3_neg(w_o), n, n_i / n_t, w_i)) {
        *w_i = v3_reflect(v3_neg(w_o), n);
        return v3_splat(1.0);
    }
    double eta = n_i / n_t;
    return carries_radiance ? v3_scale(m->specular, eta * eta) : m->specular;
}

/* Russian roulette on a path's weight: go on with probability p = its
 * largest channel (at most 1) and divide by p; the expectation is unchanged. */
static bool survives_roulette(vec3 *weight, rng *g)
{
    double p = fmin(1.0, v3_max_component(*weight));
    if (!(p > 0.0) || rng_uniform(g) >= p)
        return false;
    *weight = v3_scale(*weight, 1.0 / p);
    return true;
}

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

/* A photon leaving a light: a point and a direction drawn in proportion to
 * the emitted power (uniform over the sphere for a point light; uniform over
 * the area and cosine-weighted for a Lambertian emitter), so every photon
 * carries the same share Phi_light / (probability * photons). */
static ray emit_photon(const photonmap_state *st, const scene *s, rng *g, int photons, vec3 *power)
{
    const light_source *light = pick_light(st, g);
    *power = v3_scale(light->power, 1.0 / (light->probability * photons));
    double u1 = rng_uniform(g), u2 = rng_uniform(g);
    if (light->point_light >= 0)
        return (ray){s->lights[light->point_light].position, uniform_sample_sphere(u1, u2)};
    vec3 y, n;
    surface_sample_point(s, light->surface, u1, u2, rng_uniform(g), &y, &n);
    vec3 w = onb_to_world(onb_from_normal(n), cosine_sample_hemisphere(rng_uniform(g), rng_uniform(g)));
    return (ray){scene_offset_origin(s, y, n, w), w};
}

/* ---- the photon pass -------------------------------------------------------------------------- */

static int map_add(photon_map *map, const photon *p)
{
    if (map->count == map->capacity) {
        size_t capacity = 2 * map->capacity + 256;
        photon *grown = realloc(map->photons, capacity * sizeof *grown);
        if (!grown)
            return 2;
        map->photons = grown, map->capacity = capacity;
    }
    map->photons[map->count++] = *p;
    return 0;
}

/* Follow one photon from a light until it is absorbed or leaves the scene,
 * storing it at every non-specular surface it lands on.  Returns rays traced. */
static int trace_photon(const photonmap_state *st, const scene *s, uint32_t path, rng *g, photon_map *out)
{
    vec3 power;
    ray r = emit_photon(st, s, g, st->photons, &power);
    bool caustic = true;
    int rays = 0;
    for (int bounces = 0; bounces < MAX_BOUNCES; bounces++) {
        hit h;
        rays++;
        if (!scene_intersect(s, r, INFINITY, &h))
            break;
        const material *m = &s->materials[s->surfaces[h.surface].material];
        vec3 from = v3_neg(r.direction), w_i, weight;
        vec3 n = v3_dot(h.normal, from) > 0.0 ? h.normal : v3_neg(h.normal);
        if (is_specular(m)) {
            weight = scatter_specular(m, h.normal, from, false, g, &w_i);
        } else {
            photon p = {h.point, from, n, power, bounces, caustic && bounces > 0, n.x == h.normal.x && n.y == h.normal.y && n.z == h.normal.z, h.surface, path};
            if (map_add(out, &p))
                return -1;
            if (!sample_bsdf(m, n, from, g, &w_i, &weight))
                break; /* absorbed */
            caustic = false;
        }
        if (!survives_roulette(&weight, g))
            break;
        power = v3_mul(power, weight);
        r = (ray){scene_offset_origin(s, h.point, h.normal, w_i), w_i};
    }
    return rays;
}

/* Shoot the pass's photons in parallel.  Each chunk of CHUNK photons has
 * its own list, and each photon its own random stream, so the concatenated
 * map is the same for any number of threads. */
static int photon_pass(photonmap_state *st, const scene *s, int pass)
{
    int chunks = (st->photons + CHUNK - 1) / CHUNK, failed = 0;
    photon_map *lists = calloc((size_t)chunks, sizeof *lists);
    uint64_t rays = 0;
    if (!lists)
        return 2;
#pragma omp parallel for schedule(dynamic, 1) reduction(+ : rays, failed)
    for (int c = 0; c < chunks; c++)
        for (int k = c * CHUNK; k < st->photons && k < (c + 1) * CHUNK && !failed; k++) {
            rng g = rng_for(st->seed ^ 0x70686f746f6eull, (uint64_t)pass, (uint64_t)k);
            int traced = trace_photon(st, s, (uint32_t)k, &g, &lists[c]);
            failed += traced < 0, rays += (uint64_t)(traced > 0 ? traced : 0);
        }
    st->photon_rays += rays;
    st->global.count = st->caustic.count = 0;
    for (int c = 0; c < chunks; c++) {
        for (size_t i = 0; i < lists[c].count && !failed; i++) {
            const photon *p = &lists[c].photons[i];
            failed |= map_add(&st->global, p) || (p->caustic && map_add(&st->caustic, p));
        }
        free(lists[c].photons);
    }
    free(lists);
    return failed ? 2 : 0;
}

/* Statistics of a pass's photons: stored power per map and per surface, in
 * BATCHES batches of emitted photons (independent, so their spread gives
 * the standard error). */
static void tally_pass(photonmap_state *st)
{
    for (size_t i = 0; i < st->global.count; i++) {
        const photon *p = &st->global.photons[i];
        int b = (int)(p->path % BATCHES);
        st->power_batch[0][b] = v3_add(st->power_batch[0][b], p->power);
        if (p->caustic)
            st->power_batch[1][b] = v3_add(st->power_batch[1][b], p->power);
        if (p->front && keeps(st, p->bounces + 1))
            st->surface_batch[(size_t)p->surface * BATCHES + (size_t)b] =
                v3_add(st->surface_batch[(size_t)p->surface * BATCHES + (size_t)b], p->power);
    }
    st->stored[0] += st->global.count, st->stored[1] += st->caustic.count;
}

/* ---- density estimation (R11) ---------------------------------------------------------------- */

typedef enum { ALL_PHOTONS, INDIRECT_PHOTONS } photon_filter;

/* Does photon p count at x (unit normal n on the side of w_o)?  It must have
 * landed on a surface facing the same way (not the wall round the corner,
 * not the back of a thin panel), and its light must be a term of (R6) the
 * --bounces window keeps: it scattered p->bounces times, then once more at x
 * after `before` scatterings on the way to the eye. */
static bool photon_counts(const photonmap_state *st, const photon *p, vec3 n, int before, photon_filter filter)
{
    if (v3_dot(p->normal, n) < 0.9)
        return false;
    if (filter == INDIRECT_PHOTONS && (p->bounces == 0 || p->caustic))
        return false; /* direct light and caustics are counted elsewhere */
    return keeps(st, before + p->bounces + 1);
}

/* (R11): the sum of f Phi_p over the photons in a disc of radius r around x,
 * divided by the disc's area pi r^2.  With --nearest K the disc is the
 * smallest one holding the K nearest photons (at most the pass's radius). */
static vec3 photon_estimate(const photonmap_state *st, const photon_map *map, vec3 x, vec3 n, vec3 w_o,
                            const material *m, int before, photon_filter filter, render_counters *counters)
{
    double r2 = st->current_radius * st->current_radius, d2;
    vec3 sum = v3_splat(0.0);
    uint32_t i;
    counters->value[COUNT_LOOKUPS]++;
    if (st->nearest > 0) {
        uint32_t found[MAX_NEAREST];
        double scratch[MAX_NEAREST];
        int count = photon_grid_nearest(&map->grid, x, st->current_radius, st->nearest, found, scratch, &r2);
        for (int j = 0; j < count; j++) {
            const photon *p = &map->photons[found[j]];
            if (photon_counts(st, p, n, before, filter))
                sum = v3_add(sum, v3_mul(bsdf(m, n, p->from, w_o), p->power));
        }
        counters->value[COUNT_PHOTONS_USED] += (uint64_t)count;
    } else {
        photon_grid_cursor c;
        for (photon_grid_search(&map->grid, x, st->current_radius, &c); photon_grid_next(&map->grid, &c, &i, &d2);) {
            const photon *p = &map->photons[i];
            if (photon_counts(st, p, n, before, filter))
                sum = v3_add(sum, v3_mul(bsdf(m, n, p->from, w_o), p->power));
            counters->value[COUNT_PHOTONS_USED]++;
        }
    }
    return v3_scale(sum, 1.0 / (M_PI * r2)); /* (R11) */
}

/* ---- direct light by light sampling (R9) ---------------------------------------------------- */

/* One point y on a light picked by power, as in chapter 4's next-event
 * estimation: L_e f cos(theta_i) cos(theta_y) / |x - y|^2 V / (p_A p_pick)  (R8, R9),
 * or f I cos(theta_i) / r^2 V / p_pick for a point light (R1). */
static vec3 direct_light(const photonmap_state *st, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m,
                         rng *g, render_counters *counters)
{
    if (st->light_count == 0)
        return v3_splat(0.0);
    const light_source *light = pick_light(st, g);
    vec3 y, n_y = v3_splat(0.0), intensity;
    double u1 = rng_uniform(g), u2 = rng_uniform(g), u3 = rng_uniform(g);
    if (light->point_light >= 0) {
        y = s->lights[light->point_light].position;
        intensity = s->lights[light->point_light].intensity;
    } else {
        surface_sample_point(s, light->surface, u1, u2, u3, &y, &n_y);
        intensity = v3_scale(light->power, 1.0 / M_PI); /* L_e A: pi L_e A / pi */
    }
    vec3 to_y = v3_sub(y, x);
    double r2 = v3_dot(to_y, to_y);
    vec3 w_i = v3_scale(to_y, 1.0 / sqrt(r2));
    double cos_y = light->point_light >= 0 ? 1.0 : -v3_dot(n_y, w_i); /* the emitter's front faces x */
    vec3 f = bsdf(m, n, w_i, w_o);
    if (!(cos_y > 0.0) || !(r2 > 0.0) || v3_max_component(f) <= 0.0)
        return v3_splat(0.0);
    counters->value[COUNT_SHADOW_RAYS]++;
    if (scene_occluded(s, x, y)) /* V(x, y) */
        return v3_splat(0.0);
    return v3_scale(v3_mul(f, intensity), v3_dot(n, w_i) * cos_y / (r2 * light->probability)); /* (R9) */
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
        const material *m = &s->materials[s->surfaces[h->surface].material];
        if (!is_specular(m))
            return true;
        vec3 w_i;
        *weight = v3_mul(*weight, scatter_specular(m, h->normal, v3_neg(r->direction), true, g, &w_i));
        if (!survives_roulette(weight, g))
            return false;
        *r = (ray){scene_offset_origin(s, h->point, h->normal, w_i), w_i};
    }
    return false;
}

/* The light reflected at the non-specular point x toward w_o, after `before`
 * scatterings on the way to the eye.  --maps global: (R11) on the global map,
 * nothing else.  Otherwise direct light (R9) plus the caustic map (R11), and
 * for the rest: the global map without its direct and caustic photons, or
 * walks from x (--gather N of them): --maps both reads the global map where
 * a walk next lands (final gathering), --maps caustic goes on as a path
 * tracer.  Light a walk finds on an emitter is direct or caustic light at
 * the vertex before, counted there already: walks never add it again. */
static vec3 reflected_radiance(const photonmap_state *st, const scene *s, hit x, vec3 w_o, int before, rng *g,
                               render_counters *counters)
{
    const material *m = &s->materials[s->surfaces[x.surface].material];
    vec3 n = v3_dot(x.normal, w_o) > 0.0 ? x.normal : v3_neg(x.normal);
    if (st->maps == MAPS_GLOBAL)
        return photon_estimate(st, &st->global, x.point, n, w_o, m, before, ALL_PHOTONS, counters);
    vec3 L = photon_estimate(st, &st->caustic, x.point, n, w_o, m, before, ALL_PHOTONS, counters);
    if (keeps(st, before + 1))
        L = v3_add(L, direct_light(st, s, x.point, n, w_o, m, g, counters));
    if (st->maps == MAPS_BOTH && st->gather == 0)
        return v3_add(L, photon_estimate(st, &st->global, x.point, n, w_o, m, before, INDIRECT_PHOTONS, counters));
    int walks = st->gather > 0 ? st->gather : 1;
    for (int w = 0; w < walks; w++) {
        vec3 weight = v3_splat(1.0 / walks), out = w_o, normal = n, w_i, scatter;
        const material *at_material = m;
        hit at = x;
        for (int k = before; k < st->bounce_max;) {
            if (!sample_bsdf(at_material, normal, out, g, &w_i, &scatter))
                break;
            weight = v3_mul(weight, scatter); /* f cos / p (R2) */
            ray r = {scene_offset_origin(s, at.point, at.normal, w_i), w_i};
            bool escaped;
            k++;
            if (!survives_roulette(&weight, g) || !next_diffuse_hit(s, &r, &weight, &k, g, counters, &at, &escaped)) {
                if (escaped && keeps(st, k)) /* the background lights x: not a photon source */
                    L = v3_add(L, v3_mul(weight, s->background));
                break;
            }
            out = v3_neg(r.direction);
            normal = v3_dot(at.normal, out) > 0.0 ? at.normal : v3_neg(at.normal);
            at_material = &s->materials[s->surfaces[at.surface].material];
            if (st->maps == MAPS_BOTH) { /* final gathering: the global map one bounce on */
                L = v3_add(L, v3_mul(weight, photon_estimate(st, &st->global, at.point, normal, out, at_material, k,
                                                             ALL_PHOTONS, counters)));
                break;
            }
            vec3 here = photon_estimate(st, &st->caustic, at.point, normal, out, at_material, k, ALL_PHOTONS, counters);
            if (keeps(st, k + 1))
                here = v3_add(here, direct_light(st, s, at.point, normal, out, at_material, g, counters));
            L = v3_add(L, v3_mul(weight, here));
        }
    }
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
    const material *m = &s->materials[s->surfaces[x.surface].material];
    vec3 w_o = v3_neg(r.direction), L = v3_splat(0.0);
    if (m->kind == MATERIAL_EMITTER && v3_dot(x.normal, w_o) > 0.0 && keeps(st, k))
        L = m->emission;
    return v3_mul(weight, v3_add(L, reflected_radiance(st, s, x, w_o, k, g, counters)));
}

/* ---- probes -------------------------------------------------------------------------------------- */

/* A probe is a sensor, not a surface: photons fly through it.  Its
 * irradiance is the flux crossing a disc of radius r around it (from the
 * side its normal faces) over the disc's area: (R11) with f = 1/pi
 * times pi.  Each of BATCHES batches shoots its own photons; the spread of
 * the batch estimates is the standard error.  (The estimate is the mean
 * irradiance over the disc: the tests compare it with exactly that.) */
static double crossing_distance(const probe *p, double radius, ray r, double t_max)
{
    double facing = -v3_dot(r.direction, p->normal);
    if (!(facing > 0.0))
        return INFINITY;
    double t = v3_dot(v3_sub(r.origin, p->position), p->normal) / facing;
    vec3 offset = v3_sub(v3_madd(r.origin, r.direction, t), p->position);
    return t >= 0.0 && t <= t_max && v3_dot(offset, offset) <= radius * radius ? t : INFINITY;
}

static vec3 probe_batch(const photonmap_state *st, const scene *s, const probe *p, uint64_t seed, int batch, int count)
{
    vec3 flux = v3_splat(0.0);
    for (int k = 0; k < count; k++) {
        rng g = rng_for(seed ^ 0x70726f6265ull, (uint64_t)(p - s->probes), (uint64_t)batch * (uint64_t)count + (uint64_t)k);
        vec3 power;
        ray r = emit_photon(st, s, &g, count, &power);
        for (int bounces = 0; bounces < MAX_BOUNCES; bounces++) {
            hit h;
            bool found = scene_intersect(s, r, INFINITY, &h);
            if (keeps(st, bounces) && isfinite(crossing_distance(p, st->initial_radius, r, found ? h.t + s->epsilon : INFINITY)))
                flux = v3_add(flux, power);
            if (!found)
                break;
            const material *m = &s->materials[s->surfaces[h.surface].material];
            vec3 from = v3_neg(r.direction), w_i, weight;
            vec3 n = v3_dot(h.normal, from) > 0.0 ? h.normal : v3_neg(h.normal);
            if (is_specular(m))
                weight = scatter_specular(m, h.normal, from, false, &g, &w_i);
            else if (!sample_bsdf(m, n, from, &g, &w_i, &weight))
                break;
            if (!survives_roulette(&weight, &g))
                break;
            power = v3_mul(power, weight);
            r = (ray){scene_offset_origin(s, h.point, h.normal, w_i), w_i};
        }
    }
    return v3_scale(flux, 1.0 / (M_PI * st->initial_radius * st->initial_radius));
}

static probe_result probe_irradiance(const void *state_pointer, const scene *s, const probe *p, uint64_t seed,
                                     render_counters *counters)
{
    const photonmap_state *st = state_pointer;
    vec3 batch[BATCHES];
    (void)counters;
    if (st->light_count == 0)
        return (probe_result){v3_splat(0.0), v3_splat(0.0)};
#pragma omp parallel for schedule(dynamic, 1)
    for (int b = 0; b < BATCHES; b++)
        batch[b] = probe_batch(st, s, p, seed, b, st->probe_photons / BATCHES);
    return batch_mean_and_error(batch, BATCHES);
}

/* ---- passes (R12), stats and main ----------------------------------------------------------------- */

/* The lights, each with its power and its chance of emitting a photon. */
static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    photonmap_state *st = state_pointer;
    st->scene = s, st->seed = o->seed, st->bounce_min = o->bounce_min, st->bounce_max = o->bounce_max;
    st->lights = calloc((size_t)(s->emitter_count + s->light_count) + 1, sizeof *st->lights);
    st->surface_batch = calloc((size_t)s->surface_count * BATCHES + 1, sizeof *st->surface_batch);
    st->radius_per_pass = calloc(1, sizeof *st->radius_per_pass);
    if (!st->lights || !st->surface_batch || !st->radius_per_pass) {
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    double total = 0.0;
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
    for (int l = 0; l < st->light_count; l++)
        total += st->lights[l].probability, st->emitted_power = v3_add(st->emitted_power, st->lights[l].power);
    for (int l = 0; l < st->light_count; l++)
        st->lights[l].probability /= total;
    if (st->light_count == 0)
        fprintf(stderr, "warning: 05_photonmap: the scene has no light to shoot photons from: the image is black\n");
    vec3 diagonal = v3_sub(s->bounds.hi, s->bounds.lo);
    st->initial_radius = st->radius > 0.0 ? st->radius : 0.01 * v3_length(diagonal);
    if (!(st->initial_radius > 0.0))
        st->initial_radius = 1.0; /* a scene without extent: nothing to look up anyway */
    st->current_radius = st->initial_radius;
    return 0;
}

/* Before pass i (from 1): a new photon map, and the radius of (R12). */
static int begin_pass(void *state_pointer, const scene *s, const render_options *o, int pass, char *err,
                      size_t err_size)
{
    photonmap_state *st = state_pointer;
    (void)o;
    if (pass > 1) {
        double r2 = st->current_radius * st->current_radius * (pass - 1 + st->alpha) / pass; /* (R12) */
        st->current_radius = sqrt(r2);
    }
    double *grown = realloc(st->radius_per_pass, (size_t)pass * sizeof *grown);
    if (!grown || (st->light_count > 0 && photon_pass(st, s, pass))) {
        st->radius_per_pass = grown ? grown : st->radius_per_pass;
        snprintf(err, err_size, "argv:0: out of memory for the photons of pass %d", pass);
        return 2;
    }
    st->radius_per_pass = grown, grown[pass - 1] = st->current_radius, st->passes = pass;
    tally_pass(st);
    photon_grid_free(&st->global.grid);
    photon_grid_free(&st->caustic.grid);
    if (photon_grid_build(&st->global.grid, &st->global.photons[0].position, sizeof(photon), st->global.count,
                          st->current_radius) ||
        photon_grid_build(&st->caustic.grid, &st->caustic.photons[0].position, sizeof(photon), st->caustic.count,
                          st->current_radius)) {
        snprintf(err, err_size, "argv:0: out of memory for the photon grid of pass %d", pass);
        return 2;
    }
    return 0;
}

static void json_batches(FILE *json, const char *key, const vec3 *batch, int passes)
{
    vec3 scaled[BATCHES]; /* a batch's share of the photons stands for all of them: times BATCHES, per pass */
    for (int b = 0; b < BATCHES; b++)
        scaled[b] = v3_scale(batch[b], (double)BATCHES / (passes > 0 ? passes : 1));
    probe_result r = batch_mean_and_error(scaled, BATCHES);
    fprintf(json, "\"%s\": ", key);
    json_vec3(json, r.irradiance);
    fprintf(json, ", \"%s_standard_error\": ", key);
    json_vec3(json, r.standard_error);
}

static void write_stats(const void *state_pointer, FILE *json)
{
    const photonmap_state *st = state_pointer;
    const scene *s = st->scene;
    fprintf(json, ",\n  \"maps\": \"%s\",\n  \"photons_per_pass\": %d,\n  \"gather\": %d,\n  \"nearest\": %d",
            maps_names[st->maps], st->photons, st->gather, st->nearest);
    json_field_number(json, "alpha", st->alpha);
    fprintf(json, ",\n  \"photons_stored\": {\"global\": %llu, \"caustic\": %llu},\n  \"photon_rays\": %llu",
            (unsigned long long)st->stored[0], (unsigned long long)st->stored[1], (unsigned long long)st->photon_rays);
    fprintf(json, ",\n  \"radius_per_pass\": [");
    for (int i = 0; i < st->passes; i++)
        fprintf(json, "%s%.17g", i ? ", " : "", st->radius_per_pass[i]);
    fprintf(json, "],\n  \"emitted_power\": ");
    json_vec3(json, st->emitted_power);
    fprintf(json, ",\n  \"stored_power\": {");
    json_batches(json, "global", st->power_batch[0], st->passes);
    fputs(", ", json);
    json_batches(json, "caustic", st->power_batch[1], st->passes);
    fprintf(json, "},\n  \"surfaces\": [");
    /* A Lambertian surface's mean exitant radiance from the power landing on
     * its front: L = L_e + rho / pi * Phi / A (no radius: no blur). */
    int written = 0;
    for (int i = 0; i < s->surface_count; i++) {
        const material *m = &s->materials[s->surfaces[i].material];
        if (m->kind != MATERIAL_DIFFUSE && m->kind != MATERIAL_EMITTER)
            continue;
        vec3 batch[BATCHES];
        for (int b = 0; b < BATCHES; b++) {
            vec3 landed = v3_scale(st->surface_batch[(size_t)i * BATCHES + (size_t)b], (double)BATCHES / st->passes);
            batch[b] = v3_scale(v3_mul(m->albedo, landed), 1.0 / (M_PI * s->surfaces[i].area));
            if (m->kind == MATERIAL_EMITTER && keeps(st, 0))
                batch[b] = v3_add(batch[b], m->emission);
        }
        probe_result r = batch_mean_and_error(batch, BATCHES);
        fprintf(json, "%s\n    {\"name\": ", written++ ? "," : "");
        json_string(json, s->surfaces[i].name);
        fprintf(json, ", \"area\": ");
        json_number(json, s->surfaces[i].area);
        fprintf(json, ", \"radiance\": ");
        json_vec3(json, r.irradiance);
        fprintf(json, ", \"standard_error\": ");
        json_vec3(json, r.standard_error);
        fputc('}', json);
    }
    fprintf(json, "%s]", written ? "\n  " : "");
}

static void finish(void *state_pointer)
{
    photonmap_state *st = state_pointer;
    photon_map *maps[2] = {&st->global, &st->caustic};
    for (int k = 0; k < 2; k++) {
        photon_grid_free(&maps[k]->grid);
        free(maps[k]->photons);
        *maps[k] = (photon_map){0};
    }
    free(st->lights), free(st->surface_batch), free(st->radius_per_pass);
    st->lights = NULL, st->surface_batch = NULL, st->radius_per_pass = NULL;
}

int main(int argc, char **argv)
{
    photonmap_state state = {0};
    const chapter photon_mapping = {
        .name = "05_photonmap",
        .description = "photon mapping: density estimation (R11) of photons shot from the lights; progressive (R12)",
        .options = {{PHOTONMAP_OPTIONS, &state}},
        .default_spp = 16,
        .counter_names = {"photon_lookups", "photons_visited", "shadow_rays", "walk_rays", NULL},
        .prepare = prepare,
        .begin_pass = begin_pass,
        .radiance = radiance,
        .probe = probe_irradiance,
        .write_stats = write_stats,
        .finish = finish,
    };
    return render_main(argc, argv, &photon_mapping, &state);
}
