/* 01_local.c — Lecture 1: local illumination.
 *
 * Light goes from the light sources straight to a surface and from there to
 * the eye; every other path is replaced by one constant, the ambient term.
 * For a point light of intensity I at distance r the reflected radiance is
 *
 *   (R1)  L_r(x, w_r) = L_e(x, w_r) + f(x, w_i, w_r) * I / r^2 * cos(theta_i)
 *
 * and an area light is the same sum taken over points y on the emitter,
 * written with the geometry term of the area form (R7, R8):
 *
 *   L_r = L_e + Int_{emitters} L_e(y) f(x, w_i, w_r) cos(theta_i) cos(theta_y) / |x - y|^2 V(x, y) dA_y
 *
 * estimated by sampling --light-samples points per emitter (soft shadows).
 *
 * The BRDFs (Lambert, Phong, Blinn-Phong, classic and energy-normalised)
 * and the sum over the lights are in common/local_model.c (chapter 2 uses
 * them too).
 *
 * Sections: state and options · radiance along a camera ray (R1) · probes · main.
 */
#include <stdlib.h>
#include <string.h>

#include "local_model.h"
#include "render.h"

/* ---- state and options ------------------------------------------------------------ */

/* The local model itself (the BRDFs and the sum over lights of (R1)) lives
 * in common/local_model.c, because chapter 2 shades its diffuse and glossy
 * hits with exactly the same model.  Read it next to this file:
 *   reflected_fraction()  f(w_i, w_o) cos(theta_i): Lambert, Phong, Blinn-Phong
 *   direct_light()        (R1) for point lights, the area form for emitters */
typedef struct {
    local_model local;  /* --model --normalised --ambient --light-samples --no-shadows */
    int probe_samples;  /* points per emitter for a probe's irradiance */
} local_state;

static int warned_specular_materials; /* warn_once flag */

static int parse_option(void *state_pointer, int argc, char **argv, int *i, char *err, size_t err_size)
{
    local_state *state = state_pointer;
    if (!strcmp(argv[*i], "--probe-samples"))
        return parse_int_option(argc, argv, i, 1, 1 << 26, &state->probe_samples, err, err_size);
    return local_model_parse_option(&state->local, argc, argv, i, err, err_size);
}

/* ---- radiance along a camera ray (R1) -------------------------------------------------------- */

/* Emission seen directly, plus the light of every source reflected once
 * (R1), plus the ambient stand-in for all the other bounces. */
static vec3 radiance(const void *state_pointer, const scene *s, ray r, rng *g, render_counters *counters)
{
    const local_state *state = state_pointer;
    hit h;
    if (!scene_intersect(s, r, INFINITY, &h))
        return s->background;

    const material *m = &s->materials[s->surfaces[h.surface].material];
    vec3 w_o = v3_neg(r.direction);
    bool front = v3_dot(h.normal, w_o) > 0.0;
    vec3 emitted = m->kind == MATERIAL_EMITTER && front ? m->emission : v3_splat(0.0);

    if (m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS)
        warn_once(&warned_specular_materials,
                  "01_local: mirrors and glass need reflected and refracted rays (chapter 2); "
                  "here they are shaded as diffuse surfaces of their colour");
    material shaded = *m;
    if (m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS)
        shaded.albedo = m->specular;

    /* Shade both sides: turn the normal toward the viewer. */
    vec3 n = front ? h.normal : v3_neg(h.normal);
    vec3 ambient = ambient_light(&state->local, &shaded); /* rho * La */
    vec3 direct = direct_light(&state->local, s, h.point, n, w_o, &shaded, state->local.light_samples, g,
                               counters); /* (R1) */
    return v3_add(emitted, v3_add(ambient, direct));
}

/* ---- probes ------------------------------------------------------------------------------- */

/* Direct irradiance E = sum_lights I cos / r^2 + Int_emitters L cos cos' / r^2 V dA,
 * the latter by probe_samples points per emitter; the standard error is
 * estimated from 32 independent batches of the samples. */
static probe_result probe_irradiance(const void *state_pointer, const scene *s, const probe *p, uint64_t seed,
                          render_counters *counters)
{
    const local_state *state = state_pointer;
    enum { BATCHES = 32 };
    int per_batch = state->probe_samples / BATCHES > 0 ? state->probe_samples / BATCHES : 1;
    vec3 batch[BATCHES];
    uint64_t probe_index = (uint64_t)(p - s->probes);
#pragma omp parallel for schedule(dynamic, 1)
    for (int b = 0; b < BATCHES; b++) {
        rng g = rng_for(seed ^ 0x70726f6265ull, probe_index, (uint64_t)b);
        render_counters ignored = {{0}};
        batch[b] = direct_light(&state->local, s, p->position, p->normal, p->normal, NULL, per_batch, &g, &ignored);
    }
    vec3 sum = v3_splat(0.0), sum_squares = v3_splat(0.0);
    for (int b = 0; b < BATCHES; b++) {
        sum = v3_add(sum, batch[b]);
        sum_squares = v3_add(sum_squares, v3_mul(batch[b], batch[b]));
    }
    (void)counters;
    vec3 mean = v3_scale(sum, 1.0 / BATCHES);
    vec3 variance = v3_sub(v3_scale(sum_squares, 1.0 / BATCHES), v3_mul(mean, mean));
    vec3 standard_error = v3(sqrt(fmax(0.0, variance.x) / (BATCHES - 1)), sqrt(fmax(0.0, variance.y) / (BATCHES - 1)),
                             sqrt(fmax(0.0, variance.z) / (BATCHES - 1)));
    if (s->emitter_count == 0)
        standard_error = v3_splat(0.0); /* point lights alone are exact */
    return (probe_result){.irradiance = mean, .standard_error = standard_error};
}

/* ---- main --------------------------------------------------------------------------------- */

static void write_stats(const void *state_pointer, FILE *json)
{
    const local_state *state = state_pointer;
    fprintf(json, ",\n  \"model\": \"%s\",\n  \"normalised\": %s,\n  \"shadows\": %s,\n  \"light_samples\": %d",
            state->local.model == SPECULAR_PHONG ? "phong" : "blinn", state->local.normalised ? "true" : "false",
            state->local.shadows ? "true" : "false", state->local.light_samples);
    fprintf(json, ",\n  \"ambient\": ");
    json_vec3(json, state->local.ambient);
}

int main(int argc, char **argv)
{
    local_state state = {
        .local = local_model_defaults(), /* classic Blinn-Phong, no ambient, 16 light samples, shadows */
        .probe_samples = 1 << 16,
    };
    const chapter local_illumination = {
        .name = "01_local",
        .description = "local illumination: point and area lights (R1), Phong / Blinn-Phong, ambient, shadows",
        .options_help = LOCAL_MODEL_OPTIONS_HELP
                        "  --probe-samples N      points per emitter for probe irradiance (default 65536)\n",
        .default_spp = 1,
        .counter_names = {"shadow_rays", "point_light_samples", "area_light_samples", NULL},
        .parse_option = parse_option,
        .radiance = radiance,
        .probe = probe_irradiance,
        .write_stats = write_stats,
    };
    return render_main(argc, argv, &local_illumination, &state);
}
