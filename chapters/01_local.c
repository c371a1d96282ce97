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
 * Sections: state and options · the BRDFs (Lambert, Phong, Blinn-Phong) ·
 * direct light (R1) · radiance along a camera ray · probes · main.
 */
#include <stdlib.h>
#include <string.h>

#include "render.h"
#include "sampling.h"

/* ---- state and options ------------------------------------------------------------ */

typedef enum { SPECULAR_PHONG, SPECULAR_BLINN } specular_model;

typedef struct {
    specular_model model;
    bool normalised;    /* energy-normalised lobes instead of the classic ones */
    vec3 ambient;       /* La: the constant incident radiance standing in for all other bounces */
    int light_samples;  /* points per emitter per camera sample */
    int probe_samples;  /* points per emitter for a probe's irradiance */
    bool shadows;
} local_state;

static int warned_specular_materials; /* warn_once flag */

enum { COUNT_SHADOW_RAYS, COUNT_POINT_LIGHT_SAMPLES, COUNT_AREA_LIGHT_SAMPLES };

static int parse_option(void *state_pointer, int argc, char **argv, int *i, char *err, size_t err_size)
{
    local_state *state = state_pointer;
    const char *a = argv[*i];
    if (!strcmp(a, "--model")) {
        const char *v = *i + 1 < argc ? argv[++*i] : "";
        if (!strcmp(v, "phong"))
            state->model = SPECULAR_PHONG;
        else if (!strcmp(v, "blinn"))
            state->model = SPECULAR_BLINN;
        else {
            snprintf(err, err_size, "argv:%d: --model wants phong or blinn, not '%s'", *i, v);
            return 2;
        }
        return 1;
    }
    if (!strcmp(a, "--normalised") || !strcmp(a, "--normalized")) {
        state->normalised = true;
        return 1;
    }
    if (!strcmp(a, "--no-shadows")) {
        state->shadows = false;
        return 1;
    }
    if (!strcmp(a, "--ambient")) {
        double la;
        int status = parse_double_option(argc, argv, i, 0.0, 1e6, &la, err, err_size);
        state->ambient = v3_splat(la);
        return status;
    }
    if (!strcmp(a, "--light-samples"))
        return parse_int_option(argc, argv, i, 1, 1 << 20, &state->light_samples, err, err_size);
    if (!strcmp(a, "--probe-samples"))
        return parse_int_option(argc, argv, i, 1, 1 << 26, &state->probe_samples, err, err_size);
    return 0;
}

/* ---- the BRDFs ---------------------------------------------------------------------- */

/* The local model's reflection for light arriving from w_i and leaving
 * toward w_o at a surface with unit normal n (all pointing away from the
 * surface), returned as f(w_i, w_o) * cos(theta_i): the factor that
 * multiplies the light's perpendicular irradiance I / r^2 in (R1).
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
 * which is what a physically based renderer needs. */
static vec3 reflected_fraction(const local_state *state, const material *m, vec3 n, vec3 w_i, vec3 w_o)
{
    double cos_i = v3_dot(n, w_i);
    if (cos_i <= 0.0 || v3_dot(n, w_o) <= 0.0)
        return v3_splat(0.0);
    vec3 result = v3_scale(m->albedo, cos_i / M_PI);
    if (m->kind != MATERIAL_PHONG)
        return result;

    double cos_lobe, normalisation;
    if (state->model == SPECULAR_PHONG) {
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
    double specular = state->normalised ? normalisation * lobe * cos_i : lobe;
    return v3_add(result, v3_scale(m->specular, specular));
}

/* ---- direct light (R1) ---------------------------------------------------------------- */

/* Radiance reflected at x toward w_o from every light: point lights by
 * (R1), emitters by sampling points on them (area form, R7-R9).
 * With reflect = NULL it returns the irradiance instead (used by probes),
 * i.e. the same sums with f cos(theta_i) replaced by cos(theta_i). */
static vec3 direct_light(const local_state *state, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m,
                         int samples_per_emitter, rng *g, render_counters *counters)
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
        if (state->shadows) {
            counters->value[COUNT_SHADOW_RAYS]++;
            if (scene_occluded(s, x, light->position))
                continue;
        }
        vec3 factor = m ? reflected_fraction(state, m, n, w_i, w_o) : v3_splat(cos_i);
        total = v3_add(total, v3_mul(factor, v3_scale(light->intensity, 1.0 / r2))); /* (R1) */
    }

    for (int e = 0; e < s->emitter_count; e++) {
        const surface *emitter = &s->surfaces[s->emitters[e]];
        vec3 radiance = s->materials[emitter->material].emission;
        vec3 sum = v3_splat(0.0);
        for (int k = 0; k < samples_per_emitter; k++) {
            vec3 y, n_y;
            double u1 = rng_uniform(g), u2 = rng_uniform(g), u3 = rng_uniform(g);
            surface_sample_point(s, s->emitters[e], u1, u2, u3, &y, &n_y);
            counters->value[COUNT_AREA_LIGHT_SAMPLES]++;
            vec3 to_light = v3_sub(y, x);
            double r2 = v3_dot(to_light, to_light);
            if (r2 <= 0.0)
                continue;
            vec3 w_i = v3_scale(to_light, 1.0 / sqrt(r2));
            double cos_i = v3_dot(n, w_i), cos_y = -v3_dot(n_y, w_i); /* emitters shine from their front */
            if (cos_i <= 0.0 || cos_y <= 0.0)
                continue;
            if (state->shadows) {
                counters->value[COUNT_SHADOW_RAYS]++;
                if (scene_occluded(s, x, y))
                    continue;
            }
            vec3 factor = m ? reflected_fraction(state, m, n, w_i, w_o) : v3_splat(cos_i);
            /* geometry term without cos_i (it is inside factor): cos_y / r^2 (R8);
             * dividing by the pdf 1/A multiplies by the emitter's area. */
            sum = v3_add(sum, v3_scale(factor, cos_y / r2 * emitter->area));
        }
        total = v3_add(total, v3_mul(radiance, v3_scale(sum, 1.0 / samples_per_emitter)));
    }
    return total;
}

/* ---- radiance along a camera ray ---------------------------------------------------------- */

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
    vec3 ambient = v3_mul(shaded.albedo, state->ambient); /* Lambertian surface under uniform La reflects rho * La */
    vec3 direct = direct_light(state, s, h.point, n, w_o, &shaded, state->light_samples, g, counters);
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
        batch[b] = direct_light(state, s, p->position, p->normal, p->normal, NULL, per_batch, &g, &ignored);
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
            state->model == SPECULAR_PHONG ? "phong" : "blinn", state->normalised ? "true" : "false",
            state->shadows ? "true" : "false", state->light_samples);
    fprintf(json, ",\n  \"ambient\": ");
    json_vec3(json, state->ambient);
}

int main(int argc, char **argv)
{
    local_state state = {
        .model = SPECULAR_BLINN,
        .normalised = false,
        .ambient = v3_splat(0.0),
        .light_samples = 16,
        .probe_samples = 1 << 16,
        .shadows = true,
    };
    const chapter local_illumination = {
        .name = "01_local",
        .description = "local illumination: point and area lights (R1), Phong / Blinn-Phong, ambient, shadows",
        .options_help = "  --model phong|blinn    specular lobe (default blinn)\n"
                        "  --normalised           energy-normalised lobes instead of the classic ones\n"
                        "  --ambient LA           constant ambient radiance standing in for indirect light (default 0)\n"
                        "  --light-samples N      points sampled per emitter per pixel sample (default 16)\n"
                        "  --probe-samples N      points per emitter for probe irradiance (default 65536)\n"
                        "  --no-shadows           skip the shadow rays (every light visible)\n",
        .default_spp = 1,
        .counter_names = {"shadow_rays", "point_light_samples", "area_light_samples", NULL},
        .parse_option = parse_option,
        .radiance = radiance,
        .probe = probe_irradiance,
        .write_stats = write_stats,
    };
    return render_main(argc, argv, &local_illumination, &state);
}
