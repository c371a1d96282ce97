/* local_model.h — the local illumination model of lecture 1, shared.
 *
 * Chapter 1 renders with nothing else; chapter 2 (Whitted) shades every
 * non-specular hit with it.  One copy, so both chapters show the same
 * picture where they should.
 *
 *   (R1)  L_r(x, w_r) = L_e(x, w_r) + f(x, w_i, w_r) * I / r^2 * cos(theta_i)
 *
 * for point lights; emitting surfaces by sampling points on them with the
 * area form (R7-R9); Lambert + Phong or Blinn-Phong lobes (classic or
 * energy-normalised); a constant ambient radiance standing in for every
 * other bounce.
 */
#ifndef COMMON_LOCAL_MODEL_H
#define COMMON_LOCAL_MODEL_H

#include <stdbool.h>
#include <stddef.h>

#include "render.h"
#include "rng.h"
#include "scene.h"
#include "vec.h"

typedef enum { SPECULAR_PHONG, SPECULAR_BLINN } specular_model;

/* Counters direct_light() increments.  A chapter that uses it names these
 * first in its counter_names ("shadow_rays", "point_light_samples",
 * "area_light_samples") and numbers its own from LOCAL_MODEL_COUNTERS. */
enum { COUNT_SHADOW_RAYS, COUNT_POINT_LIGHT_SAMPLES, COUNT_AREA_LIGHT_SAMPLES, LOCAL_MODEL_COUNTERS };

/* How much of the light leaving y arrives at x along the straight segment
 * (RGB, each in [0, 1]).  It counts the rays it casts in counters. */
typedef vec3 (*light_transmittance_function)(const void *context, const scene *s, vec3 x, vec3 y,
                                             render_counters *counters);

typedef struct {
    specular_model model;
    bool normalised;   /* energy-normalised lobes instead of the classic ones */
    vec3 ambient;      /* La: constant incident radiance standing in for all other bounces */
    int light_samples; /* points per emitter per call of direct_light() */
    bool shadows;      /* false: every light is visible (no shadow rays) */
    /* Visibility V(x, y) of (R9).  NULL: opaque occluders, one shadow ray
     * (scene_occluded).  Chapter 2 lets light through glass. */
    light_transmittance_function transmittance;
    const void *transmittance_context;
} local_model;

/* The defaults of chapter 1: classic Blinn-Phong, no ambient, 16 points per
 * emitter, shadows on, opaque occluders. */
local_model local_model_defaults(void);

/* The model's command-line options (--model, --normalised, --ambient,
 * --light-samples, --no-shadows), in the chapter.parse_option convention:
 * 1 consumed, 0 not one of them, 2 bad value (message in err). */
int local_model_parse_option(local_model *m, int argc, char **argv, int *i, char *err, size_t err_size);
#define LOCAL_MODEL_OPTIONS_HELP                                                                          \
    "  --model phong|blinn    specular lobe (default blinn)\n"                                            \
    "  --normalised           energy-normalised lobes instead of the classic ones\n"                      \
    "  --ambient LA           constant ambient radiance standing in for indirect light (default 0)\n"     \
    "  --light-samples N      points sampled per emitter per pixel sample (default 16)\n"                 \
    "  --no-shadows           skip the shadow rays (every light visible)\n"

/* f(w_i, w_o) * cos(theta_i) of the local model at a surface of material m
 * with unit normal n, w_i toward the light, w_o toward the viewer: the
 * factor that multiplies the perpendicular irradiance I / r^2 in (R1). */
vec3 reflected_fraction(const local_model *lm, const material *m, vec3 n, vec3 w_i, vec3 w_o);

/* Radiance reflected at x (unit normal n, facing the viewer) toward w_o
 * from every point light (R1) and every emitter (area form, samples_per_emitter
 * points each).  With m = NULL it returns the irradiance instead (probes):
 * the same sums with f cos(theta_i) replaced by cos(theta_i). */
vec3 direct_light(const local_model *lm, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m,
                  int samples_per_emitter, rng *g, render_counters *counters);

/* The ambient term: a Lambertian surface under uniform radiance La reflects
 * rho * La (its albedo integrates to rho over the hemisphere). */
static inline vec3 ambient_light(const local_model *lm, const material *m) { return v3_mul(m->albedo, lm->ambient); }

#endif
