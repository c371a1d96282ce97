/* 01_local.c — Lecture 1: local illumination.
 *
 * Light goes from the light sources straight to a surface and from there to
 * the eye; every other path is replaced by one constant, the ambient term.
 * For a point light of intensity I at distance r the reflected radiance is
 *
 *   (R1)  L_r(x, w_r) = L_e(x, w_r) + f(x, w_i, w_r) * I / r^2 * cos(theta_i)
 *
 * summed over the lights.  An area light is the same sum taken over points
 * y on the emitter, written with the geometry term of the area form (R8):
 *
 *   L_r = L_e + Int_{emitters} L_e(y) f(x, w_i, w_r) cos(theta_i) cos(theta_y) / |x - y|^2 V(x, y) dA_y
 *
 * estimated by sampling --light-samples points per emitter (soft shadows).
 *
 * In the Neumann series (R6) of the rendering equation, emission seen
 * directly is E, this sum over the lights is KE, and the ambient term is
 * the stand-in for K^2 E + K^3 E + ...: --bounces 0:0 shows E, 1:1 the
 * direct light, 2: the ambient term alone (it is kept only when the window
 * keeps all of K^2 E, K^3 E, ..., as in chapter 2; 2:2 shows nothing).
 *
 * Chapter 2 shades its non-specular hits with the same BRDFs and the same
 * sum (declared in local_model.h; the Makefile links this file into it).
 *
 * Sections: the BRDFs · the sum over the lights (R1) · radiance along a
 * camera ray · probes · options and main.
 */
#include <stddef.h>

#include "local_model.h"
#include "render.h"

/* ---- the BRDFs ------------------------------------------------------------------------ */

/* Returned as f(w_i, w_o) * cos(theta_i) (all directions pointing away from
 * the surface):
 *
 *  Lambert:              f = kd / pi
 *  Phong, classic:       ks (R.V)^n          per unit perpendicular irradiance
 *  Blinn-Phong, classic: ks (N.H)^n          (the textbook I = ks (R.V)^n I_light)
 *  Phong, normalised:    f = ks (n + 2) / (2 pi) (R.V)^n       (Lafortune & Willems 1994)
 *  Blinn, normalised:    f = ks (n + 8) / (8 pi) (N.H)^n       (Akenine-Moller et al., RTR)
 *
 * The classic forms are what OpenGL's fixed pipeline computed: their
 * highlight does not fade with cos(theta_i) and they can reflect more
 * light than arrives.  The normalised forms conserve energy (for ks <= 1),
 * which is what a physically based renderer needs. [exercise 1.1] */
vec3 reflected_fraction(const local_model *lm, const material *m, vec3 n, vec3 w_i, vec3 w_o)
{
    double cos_i = v3_dot(n, w_i);
    if (cos_i <= 0.0 || v3_dot(n, w_o) <= 0.0)
        return v3_splat(0.0);
    vec3 result = v3_scale(m->albedo, cos_i / M_PI);
    if (m->kind != MATERIAL_PHONG)
        return result;

    double cos_lobe, normalisation;
    if (lm->model == SPECULAR_PHONG) {
        vec3 mirrored = v3_reflect(v3_neg(w_i), n); /* R: w_i mirrored about n */
        cos_lobe = v3_dot(mirrored, w_o);
        normalisation = (m->exponent + 2.0) / (2.0 * M_PI);
    } else {
        vec3 halfway = v3_normalize(v3_add(w_i, w_o)); /* H */
        cos_lobe = v3_dot(n, halfway);
        normalisation = (m->exponent + 8.0) / (8.0 * M_PI);
    }
    if (cos_lobe <= 0.0)
        return result;
    double lobe = pow(cos_lobe, m->exponent);
    double specular = lm->normalised ? normalisation * lobe * cos_i : lobe;
    return v3_add(result, v3_scale(m->specular, specular));
}

/* ---- the sum over the lights (R1) ---------------------------------------------------------- */

/* V(x, y) of (R9) for opaque occluders: one shadow ray. */
static vec3 visibility(const local_model *lm, const scene *s, vec3 x, vec3 y, render_counters *counters)
{
    if (lm->no_shadows)
        return v3_splat(1.0);
    if (lm->transmittance)
        return lm->transmittance(lm->transmittance_context, s, x, y, counters);
    counters->value[COUNT_SHADOW_RAYS]++;
    return v3_splat(scene_occluded(s, x, y) ? 0.0 : 1.0);
}

/* (R1) for every point light: f cos(theta_i) I / r^2, where the light is visible. [exercise 1.2] */
static vec3 point_lights(const local_model *lm, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m,
                         render_counters *counters)
{
    vec3 total = v3_splat(0.0);
    for (int l = 0; l < s->light_count; l++) {
        const point_light *light = &s->lights[l];
        vec3 to_light = v3_sub(light->position, x);
        double r2 = v3_dot(to_light, to_light);
        vec3 w_i = v3_scale(to_light, 1.0 / sqrt(r2));
        double cos_i = v3_dot(n, w_i);
        if (cos_i <= 0.0)
            continue;
        counters->value[COUNT_POINT_LIGHT_SAMPLES]++;
        vec3 visible = visibility(lm, s, x, light->position, counters);
        if (v3_max_component(visible) <= 0.0)
            continue;
        vec3 factor = m ? reflected_fraction(lm, m, n, w_i, w_o) : v3_splat(cos_i);
        total = v3_add(total, v3_mul(v3_mul(factor, visible), v3_scale(light->intensity, 1.0 / r2))); /* (R1) */
    }
    return total;
}

/* The area form for one emitter: the mean over `samples` points y, uniform
 * on its area A (pdf 1/A), of L_e f cos(theta_i) cos(theta_y) / r^2 V. [exercise 1.3] */
static vec3 area_light(const local_model *lm, const scene *s, int emitter_surface, vec3 x, vec3 n, vec3 w_o,
                       const material *m, int samples, rng *g, render_counters *counters)
{
    const surface *emitter = &s->surfaces[emitter_surface];
    vec3 sum = v3_splat(0.0);
    for (int k = 0; k < samples; k++) {
        vec3 y, n_y;
        double u1 = rng_uniform(g), u2 = rng_uniform(g), u3 = rng_uniform(g);
        surface_sample_point(s, emitter_surface, u1, u2, u3, &y, &n_y);
        counters->value[COUNT_AREA_LIGHT_SAMPLES]++;
        vec3 to_light = v3_sub(y, x);
        double r2 = v3_dot(to_light, to_light);
        if (r2 <= 0.0)
            continue;
        vec3 w_i = v3_scale(to_light, 1.0 / sqrt(r2));
        double cos_i = v3_dot(n, w_i), cos_y = -v3_dot(n_y, w_i); /* emitters shine from their front */
        if (cos_i <= 0.0 || cos_y <= 0.0)
            continue;
        vec3 visible = visibility(lm, s, x, y, counters);
        if (v3_max_component(visible) <= 0.0)
            continue;
        vec3 factor = m ? reflected_fraction(lm, m, n, w_i, w_o) : v3_splat(cos_i);
        /* geometry term without cos_i (it is inside factor): cos_y / r^2 (R8);
         * dividing by the pdf 1/A multiplies by the emitter's area. */
        sum = v3_add(sum, v3_scale(v3_mul(factor, visible), cos_y / r2 * emitter->area));
    }
    vec3 radiance = s->materials[emitter->material].emission;
    return v3_mul(radiance, v3_scale(sum, 1.0 / samples));
}

vec3 direct_light(const local_model *lm, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m,
                  int samples_per_emitter, rng *g, render_counters *counters)
{
    vec3 total = point_lights(lm, s, x, n, w_o, m, counters);
    for (int e = 0; e < s->emitter_count; e++)
        total = v3_add(total, area_light(lm, s, s->emitters[e], x, n, w_o, m, samples_per_emitter, g, counters));
    return total;
}

vec3 direct_irradiance(const local_model *lm, const scene *s, vec3 x, vec3 n, int samples_per_emitter, rng *g,
                       render_counters *counters)
{
    return direct_light(lm, s, x, n, n, NULL, samples_per_emitter, g, counters); /* no material: cos(theta_i) */
}

/* ---- radiance along a camera ray ---------------------------------------------------------- */

typedef struct {
    local_model local;     /* --model --normalised --ambient --light-samples --no-shadows */
    int probe_samples;     /* points per emitter for a probe's irradiance */
    bounce_window bounces; /* --bounces A:B, copied from the driver in prepare() */
} local_state;

static int warned_specular_materials, warned_no_light; /* warn_once flags */

/* Is Neumann term k (R6) inside the --bounces window? */
static bool keep(const local_state *state, int k) { return bounces_keep(state->bounces, k); }

/* Emission seen directly (E), plus the light of every source reflected once
 * (R1, the term KE), plus the ambient stand-in for all the other bounces
 * (K^2 E and beyond). */
static vec3 radiance(const void *state_pointer, const scene *s, ray r, rng *g, render_counters *counters)
{
    const local_state *state = state_pointer;
    hit h;
    if (!scene_intersect(s, r, INFINITY, &h))
        return keep(state, 0) ? s->background : v3_splat(0.0);

    const material *m = &s->materials[s->surfaces[h.surface].material];
    vec3 w_o = v3_neg(r.direction);
    bool front = v3_dot(h.normal, w_o) > 0.0;
    material shaded = *m;
    if (m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS) {
        warn_once(&warned_specular_materials,
                  "01_local: mirrors and glass need reflected and refracted rays (chapter 2); "
                  "here they are shaded as diffuse surfaces of their colour");
        shaded.albedo = m->specular;
    }
    vec3 n = front ? h.normal : v3_neg(h.normal); /* shade both sides: the normal toward the viewer */

    vec3 zero = v3_splat(0.0);
    vec3 emitted = keep(state, 0) && m->kind == MATERIAL_EMITTER && front ? m->emission : zero; /* E */
    vec3 direct = keep(state, 1) ? direct_light(&state->local, s, h.point, n, w_o, &shaded, state->local.light_samples,
                                                g, counters)
                                 : zero; /* KE (R1) */
    vec3 ambient = bounces_keep_all_from(state->bounces, 2) ? ambient_light(&state->local, &shaded) : zero; /* rho La */
    return v3_add(emitted, v3_add(ambient, direct));
}

static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    local_state *state = state_pointer;
    (void)err, (void)err_size;
    state->bounces = bounce_window_of(o);
    if (s->light_count == 0 && s->emitter_count == 0)
        warn_once(&warned_no_light, "01_local: the scene has no light (no point light, no emitter): "
                                    "only the ambient term and the background are seen");
    return 0;
}

/* ---- probes ------------------------------------------------------------------------------- */

/* Direct irradiance E = sum_lights I cos / r^2 + Int_emitters L cos cos' / r^2 V dA,
 * the latter by probe_samples points per emitter; the standard error is
 * estimated from PROBE_BATCHES independent batches of the samples. */
static probe_result probe_irradiance(const void *state_pointer, const scene *s, const probe *p, uint64_t seed,
                                     render_counters *counters)
{
    const local_state *state = state_pointer;
    int per_batch = state->probe_samples / PROBE_BATCHES > 0 ? state->probe_samples / PROBE_BATCHES : 1;
    vec3 batch[PROBE_BATCHES];
    uint64_t probe_index = (uint64_t)(p - s->probes);
#pragma omp parallel for schedule(dynamic, 1)
    for (int b = 0; b < PROBE_BATCHES; b++) {
        rng g = rng_for(probe_seed(seed), probe_index, (uint64_t)b);
        render_counters ignored = {{0}};
        batch[b] = direct_irradiance(&state->local, s, p->position, p->normal, per_batch, &g, &ignored);
    }
    (void)counters;
    probe_result result = batch_mean_and_error(batch, PROBE_BATCHES);
    if (s->emitter_count == 0)
        result.standard_error = v3_splat(0.0); /* point lights alone are exact */
    return result;
}

/* ---- options and main --------------------------------------------------------------------- */

void local_model_write_stats(const local_model *lm, FILE *json)
{
    fprintf(json, ",\n  \"model\": \"%s\",\n  \"normalised\": %s,\n  \"shadows\": %s,\n  \"light_samples\": %d",
            lm->model == SPECULAR_PHONG ? "phong" : "blinn", lm->normalised ? "true" : "false",
            lm->no_shadows ? "false" : "true", lm->light_samples);
    fprintf(json, ",\n  \"ambient\": ");
    json_vec3(json, v3_splat(lm->ambient));
}

static void write_stats(const void *state_pointer, FILE *json)
{
    const local_state *state = state_pointer;
    local_model_write_stats(&state->local, json);
}

#define MODEL(field) offsetof(local_model, field)
const option LOCAL_MODEL_OPTIONS[] = {
    {"--model", NULL, OPTION_CHOICE, MODEL(model), .choices = "phong|blinn", .default_text = "blinn",
     .help = "specular lobe"},
    {"--normalised", NULL, OPTION_FLAG, MODEL(normalised),
     .help = "energy-normalised lobes instead of the classic ones"},
    {"--normalized", NULL, OPTION_FLAG, 0, .alias_of = "--normalised"},
    {"--ambient", "LA", OPTION_DOUBLE, MODEL(ambient), .min = 0.0, .max = 1e6, .default_text = "0",
     .help = "constant ambient radiance standing in for K^2 E and beyond"},
    {"--light-samples", "N", OPTION_INT, MODEL(light_samples), .min = 1, .max = 1 << 20, .default_text = "16",
     .help = "points sampled per emitter per pixel sample"},
    {"--no-shadows", NULL, OPTION_FLAG, MODEL(no_shadows), .help = "skip the shadow rays (every light visible)"},
    {0},
};
#undef MODEL

static const option LOCAL_OPTIONS[] = {
    {"--probe-samples", "N", OPTION_INT, offsetof(local_state, probe_samples), .min = 1, .max = 1 << 26,
     .default_text = "65536", .help = "points per emitter for probe irradiance"},
    {0},
};

int main(int argc, char **argv)
{
    local_state state = {0};
    const chapter local_illumination = {
        .name = "01_local",
        .description = "local illumination: point and area lights (R1), Phong / Blinn-Phong, ambient, shadows",
        .options = {{LOCAL_MODEL_OPTIONS, &state.local}, {LOCAL_OPTIONS, &state}},
        .default_spp = 1,
        .counter_names = {"shadow_rays", "point_light_samples", "area_light_samples", NULL},
        .prepare = prepare,
        .radiance = radiance,
        .probe = probe_irradiance,
        .write_stats = write_stats,
    };
    return render_main(argc, argv, &local_illumination, &state);
}
