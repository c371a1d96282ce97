/* walk_stats.h — probes and surface averages, with error bars, for a
 * chapter that estimates by random walks (path tracing).
 *
 * The chapter supplies one function: a one-sample estimate of the radiance
 * a surface point x (unit normal n, material m) reflects toward w_o, whose
 * first scattering at x is bounce k (R6).  From it:
 *   - walk_probe: a probe's irradiance E = Int L cos dw, pi times what a
 *     white Lambertian surface at the probe reflects (k = 0: the probe only
 *     receives, so --bounces 0:0 is the direct irradiance);
 *   - walk_surface_averages: each diffuse surface's exitant radiance
 *     averaged over its area, L_avg = 1/A Int_A ( L_e(y) + rho/pi E(y) ) dA_y,
 *     from points y drawn uniformly on it, leaving along the normal (the
 *     stats key "surfaces", to compare with radiosity's patches, R10).
 * Each is the mean of PROBE_BATCHES (render.h) independent batch means, whose spread
 * gives the standard error without assuming anything about the walks'
 * distribution.  Walk j of batch b draws from rng_for(seed, index, b n + j),
 * so the results do not depend on the number of threads.
 */
#ifndef COMMON_WALK_STATS_H
#define COMMON_WALK_STATS_H

#include <stdlib.h>

#include "render.h"

typedef vec3 walk_reflected_fn(const void *state, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m, int k,
                               rng *g, render_counters *counters);

typedef struct {
    walk_reflected_fn *reflected;
    const void *state;
    const scene *scene;
    bool emission; /* surface averages: add L_e (the bounce window keeps k = 0) */
} walk_source;

typedef struct {
    int surface;
    vec3 radiance, standard_error;
} surface_average;

/* One walk: at probe p, or (p NULL) from a uniform point of surface i. */
static inline vec3 walk_stats_sample(const walk_source *w, const probe *p, int i, rng *g, render_counters *c)
{
    static const material white = {.name = "probe", .kind = MATERIAL_DIFFUSE, .albedo = {1.0, 1.0, 1.0}};
    if (p)
        return v3_scale(w->reflected(w->state, w->scene, p->position, p->normal, p->normal, &white, 0, g, c), M_PI);
    const material *m = &w->scene->materials[w->scene->surfaces[i].material];
    double u1 = rng_uniform(g), u2 = rng_uniform(g), u3 = rng_uniform(g);
    vec3 y, n;
    surface_sample_point(w->scene, i, u1, u2, u3, &y, &n);
    vec3 L = w->reflected(w->state, w->scene, y, n, n, m, 1, g, c);
    return m->kind == MATERIAL_EMITTER && w->emission ? v3_add(L, m->emission) : L;
}

/* Mean and standard error of PROBE_BATCHES batch means of n walks each (at
 * probe p, or on surface i); returns the rays traced (all counters). */
static inline uint64_t walk_batch_mean(const walk_source *w, const probe *p, int i, uint64_t seed, int n, vec3 *mean,
                                       vec3 *standard_error)
{
    uint64_t index = p ? (uint64_t)(p - w->scene->probes) : (uint64_t)i, rays = 0;
    vec3 batch[PROBE_BATCHES];
    render_counters counters[PROBE_BATCHES] = {{{0}}};
#pragma omp parallel for schedule(dynamic, 1)
    for (int b = 0; b < PROBE_BATCHES; b++) {
        vec3 batch_sum = v3_splat(0.0);
        for (int j = 0; j < n; j++) {
            rng g = rng_for(seed, index, (uint64_t)b * (uint64_t)n + (uint64_t)j);
            vec3 L = walk_stats_sample(w, p, i, &g, &counters[b]);
            if (v3_is_finite(L))
                batch_sum = v3_add(batch_sum, L);
        }
        batch[b] = v3_scale(batch_sum, 1.0 / n);
    }
    for (int b = 0; b < PROBE_BATCHES; b++)
        for (int c = 0; c < RENDER_MAX_COUNTERS; c++)
            rays += counters[b].value[c];
    probe_result r = batch_mean_and_error(batch, PROBE_BATCHES);
    *mean = r.irradiance, *standard_error = r.standard_error;
    return rays;
}

/* A probe's irradiance from `walks` walks (in PROBE_BATCHES batches); adds the rays traced to *rays. */
static inline probe_result walk_probe(const walk_source *w, const probe *p, uint64_t seed, int walks, uint64_t *rays)
{
    probe_result r;
    *rays += walk_batch_mean(w, p, -1, seed, walks / PROBE_BATCHES, &r.irradiance, &r.standard_error);
    return r;
}

/* The average radiance of every diffuse or emitting surface (the only ones
 * that leave alike in every direction), from `walks` walks each (at least one
 * per batch), into a calloc'ed array *out of *count entries (free it); adds
 * the rays traced to *rays.  Returns 0, or 2 with a message when out of memory. */
static inline int walk_surface_averages(const walk_source *w, uint64_t seed, int walks, surface_average **out,
                                        int *count, uint64_t *rays, char *err, size_t err_size)
{
    const scene *s = w->scene;
    int per_batch = walks / PROBE_BATCHES > 0 ? walks / PROBE_BATCHES : 1;
    *count = 0;
    *out = calloc((size_t)s->surface_count + 1, sizeof **out);
    if (!*out) {
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    for (int i = 0; i < s->surface_count; i++) {
        material_kind kind = s->materials[s->surfaces[i].material].kind;
        if (kind != MATERIAL_DIFFUSE && kind != MATERIAL_EMITTER)
            continue;
        surface_average *a = &(*out)[(*count)++];
        a->surface = i;
        *rays += walk_batch_mean(w, NULL, i, seed, per_batch, &a->radiance, &a->standard_error);
    }
    return 0;
}

/* The stats member `,\n  "surfaces": [{"name", "area", "radiance", "standard_error"} ...]`. */
static inline void json_surface_averages(FILE *json, const scene *s, const surface_average *a, int count)
{
    fprintf(json, ",\n  \"surfaces\": [");
    for (int j = 0; j < count; j++) {
        const surface *surf = &s->surfaces[a[j].surface];
        fprintf(json, "%s\n    {\"name\": ", j ? "," : "");
        json_string(json, surf->name);
        fprintf(json, ", \"area\": ");
        json_number(json, surf->area);
        fprintf(json, ", \"radiance\": ");
        json_vec3(json, a[j].radiance);
        fprintf(json, ", \"standard_error\": ");
        json_vec3(json, a[j].standard_error);
        fputc('}', json);
    }
    fprintf(json, "%s]", count ? "\n  " : "");
}

#endif
