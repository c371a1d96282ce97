/* local_model.c — the BRDFs and direct light (R1) of lecture 1. */
#include "local_model.h"

#include <string.h>

local_model local_model_defaults(void)
{
    return (local_model){
        .model = SPECULAR_BLINN,
        .normalised = false,
        .ambient = v3_splat(0.0),
        .light_samples = 16,
        .shadows = true,
        .transmittance = NULL,
        .transmittance_context = NULL,
    };
}

int local_model_parse_option(local_model *lm, int argc, char **argv, int *i, char *err, size_t err_size)
{
    const char *a = argv[*i];
    if (!strcmp(a, "--model")) {
        const char *v = *i + 1 < argc ? argv[++*i] : "";
        if (!strcmp(v, "phong"))
            lm->model = SPECULAR_PHONG;
        else if (!strcmp(v, "blinn"))
            lm->model = SPECULAR_BLINN;
        else {
            snprintf(err, err_size, "argv:%d: --model wants phong or blinn, not '%s'", *i, v);
            return 2;
        }
        return 1;
    }
    if (!strcmp(a, "--normalised") || !strcmp(a, "--normalized")) {
        lm->normalised = true;
        return 1;
    }
    if (!strcmp(a, "--no-shadows")) {
        lm->shadows = false;
        return 1;
    }
    if (!strcmp(a, "--ambient")) {
        double la = 0.0;
        int status = parse_double_option(argc, argv, i, 0.0, 1e6, &la, err, err_size);
        lm->ambient = v3_splat(la);
        return status;
    }
    if (!strcmp(a, "--light-samples"))
        return parse_int_option(argc, argv, i, 1, 1 << 20, &lm->light_samples, err, err_size);
    return 0;
}

/* ---- the BRDFs ---------------------------------------------------------------------- */

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
 * which is what a physically based renderer needs. */
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

/* ---- direct light (R1) ---------------------------------------------------------------- */

/* V(x, y) of (R9) for opaque occluders: one shadow ray. */
static vec3 visibility(const local_model *lm, const scene *s, vec3 x, vec3 y, render_counters *counters)
{
    if (!lm->shadows)
        return v3_splat(1.0);
    if (lm->transmittance)
        return lm->transmittance(lm->transmittance_context, s, x, y, counters);
    counters->value[COUNT_SHADOW_RAYS]++;
    return v3_splat(scene_occluded(s, x, y) ? 0.0 : 1.0);
}

vec3 direct_light(const local_model *lm, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m,
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
        vec3 visible = visibility(lm, s, x, light->position, counters);
        if (v3_max_component(visible) <= 0.0)
            continue;
        vec3 factor = m ? reflected_fraction(lm, m, n, w_i, w_o) : v3_splat(cos_i);
        total = v3_add(total, v3_mul(v3_mul(factor, visible), v3_scale(light->intensity, 1.0 / r2))); /* (R1) */
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
            vec3 visible = visibility(lm, s, x, y, counters);
            if (v3_max_component(visible) <= 0.0)
                continue;
            vec3 factor = m ? reflected_fraction(lm, m, n, w_i, w_o) : v3_splat(cos_i);
            /* geometry term without cos_i (it is inside factor): cos_y / r^2 (R8);
             * dividing by the pdf 1/A multiplies by the emitter's area. */
            sum = v3_add(sum, v3_scale(v3_mul(factor, visible), cos_y / r2 * emitter->area));
        }
        total = v3_add(total, v3_mul(radiance, v3_scale(sum, 1.0 / samples_per_emitter)));
    }
    return total;
}
