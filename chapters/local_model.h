/* local_model.h — the local illumination model of lecture 1, as chapter 2
 * uses it too.
 *
 * Defined in chapters/01_local.c, where lecture 1 reads it: the BRDFs
 * (reflected_fraction) and the sum over the lights of (R1) (direct_light,
 * and direct_irradiance for probes).
 * Chapter 2 (Whitted) shades every non-specular hit with exactly this
 * model; the Makefile links chapter 1's object into it (with chapter 1's
 * main renamed), so neither chapter includes the other.
 */
#ifndef CHAPTERS_LOCAL_MODEL_H
#define CHAPTERS_LOCAL_MODEL_H

#include <stdbool.h>
#include <stdio.h>

#include "options.h"
#include "render.h"
#include "rng.h"
#include "scene.h"
#include "vec.h"

typedef enum { SPECULAR_PHONG, SPECULAR_BLINN } specular_model; /* the order of --model's choices */

/* Counters direct_light() increments.  A chapter that uses it names these
 * first in its counter_names ("shadow_rays", "point_light_samples",
 * "area_light_samples") and numbers its own from LOCAL_MODEL_COUNTERS. */
enum { COUNT_SHADOW_RAYS, COUNT_POINT_LIGHT_SAMPLES, COUNT_AREA_LIGHT_SAMPLES, LOCAL_MODEL_COUNTERS };

/* How much of the light leaving y arrives at x along the straight segment
 * (RGB, each in [0, 1]).  It counts the rays it casts in counters. */
typedef vec3 (*light_transmittance_function)(const void *context, const scene *s, vec3 x, vec3 y,
                                             render_counters *counters);

typedef struct {
    int model;         /* specular_model: --model phong|blinn */
    bool normalised;   /* energy-normalised lobes instead of the classic ones */
    double ambient;    /* La: constant incident radiance standing in for all other bounces */
    int light_samples; /* points per emitter per call of direct_light() */
    bool no_shadows;   /* every light is visible (no shadow rays) */
    /* Visibility V(x, y) of (R9).  NULL: opaque occluders, one shadow ray
     * (scene_occluded).  Chapter 2 lets light through glass. */
    light_transmittance_function transmittance;
    const void *transmittance_context;
} local_model;

/* The model's options (--model, --normalised, --ambient, --light-samples,
 * --no-shadows), their defaults and help: offsets into a local_model. */
extern const option LOCAL_MODEL_OPTIONS[];

/* f(w_i, w_o) cos(theta_i) at a surface of material m with unit normal n,
 * w_i toward the light, w_o toward the viewer: the factor that multiplies
 * the perpendicular irradiance I / r^2 in (R1). */
vec3 reflected_fraction(const local_model *lm, const material *m, vec3 n, vec3 w_i, vec3 w_o);

/* Radiance reflected at x (unit normal n, facing the viewer) toward w_o
 * from every point light (R1) and every emitter (area form, samples_per_emitter
 * points each). */
vec3 direct_light(const local_model *lm, const scene *s, vec3 x, vec3 n, vec3 w_o, const material *m,
                  int samples_per_emitter, rng *g, render_counters *counters);

/* The irradiance at x (unit normal n) from the same lights (probes): the
 * sums of direct_light() with f cos(theta_i) replaced by cos(theta_i). */
vec3 direct_irradiance(const local_model *lm, const scene *s, vec3 x, vec3 n, int samples_per_emitter, rng *g,
                       render_counters *counters);

/* The model's members of the stats object (model, normalised, shadows,
 * light_samples, ambient), each preceded by ",\n  ": chapters 1 and 2 write the same. */
void local_model_write_stats(const local_model *lm, FILE *json);

/* The ambient term: a Lambertian surface under uniform radiance La reflects
 * rho La (its albedo integrates to rho over the hemisphere). */
static inline vec3 ambient_light(const local_model *lm, const material *m)
{
    return v3_mul(m->albedo, v3_splat(lm->ambient));
}

#endif
