/* pathtrace_model.h — the materials and the light sampling of lecture 4, as
 * chapter 5 uses them too.
 *
 * Defined in chapters/04_pathtrace.c, where lecture 4 reads them: f of the
 * scene's materials (bsdf_f), drawing a direction like f cos (sample_bsdf,
 * bsdf_pdf), mirrors and glass (specular_scatter), one scattering step
 * (scatter), Russian roulette (survives_roulette), and next-event estimation
 * (sample_light, next_event: (R9)).  Chapter 5 (photon mapping) follows
 * photons from the lights and paths from the eye with exactly these; the
 * Makefile links chapter 4's object into it (with chapter 4's main renamed),
 * so neither chapter includes the other and each is written once.
 * Conventions as in optics.h: directions point away from the surface.
 */
#ifndef CHAPTERS_PATHTRACE_MODEL_H
#define CHAPTERS_PATHTRACE_MODEL_H

#include <stdbool.h>
#include <stdint.h>

#include "rng.h"
#include "scene.h"
#include "vec.h"

/* A vertex of a walk: light leaves x toward w_o (unit, toward the eye or the
 * last vertex); n is the unit normal on the side of w_o (surfaces are
 * two-sided), `front` says if that is the side the scene file faces. */
typedef struct {
    vec3 x, n, w_o;
    bool front;
    const material *m;
} vertex;

/* The vertex at x on a surface of geometric normal n_geometric, seen from w_o. */
vertex vertex_at(vec3 x, vec3 n_geometric, vec3 w_o, const material *m);

static inline const material *material_of(const scene *s, int surface)
{
    return &s->materials[s->surfaces[surface].material];
}

/* f(w_i, w_o) of a non-specular material at v: Lambert plus the normalised
 * Phong lobe (symmetric in w_i and w_o, so photons and eye paths share it). */
vec3 bsdf_f(const vertex *v, vec3 w_i);

/* Mirrors and glass: f is a delta, followed by every estimator. */
bool is_specular(const material *m);

/* A mirror or glass at v: the next direction and its weight, for radiance
 * (glass: (n_i / n_t)^2 on the way in; a carrier of flux undoes it). */
vec3 specular_scatter(const vertex *v, rng *g, vec3 *w_i);

/* A density over directions: draws w_i at v and returns its pdf per steradian. */
typedef double direction_sampler(const vertex *v, rng *g, vec3 *w_i);

/* Directions drawn like f cos (the cosine and the Phong lobe, mixed), and
 * the density of that mixture. */
double sample_bsdf(const vertex *v, rng *g, vec3 *w_i);
double bsdf_pdf(const vertex *v, vec3 w_i);

/* One scattering at v: the next direction w_i (its pdf in *pdf, 0 for a
 * delta) and the factor of the walk's weight, f cos(theta_i) / p (R2). */
vec3 scatter(const vertex *v, direction_sampler *sample, rng *g, vec3 *w_i, double *pdf);

/* Russian roulette on a weight: go on with probability p = its largest
 * channel (at most 1) and divide it by p; false: the walk ends. */
bool survives_roulette(vec3 *weight, rng *g);

/* The lights' total power (mean channel): pi L_e A per emitter, 4 pi I per point light. */
double total_light_power(const scene *s);

/* The share of a path to a light that a light sample counts; the walk that
 * finds the light by itself counts the rest.  Next-event estimation alone
 * counts all (light_sample_only); MIS splits by the power heuristic. */
typedef double light_share(double pdf_light, double pdf_bsdf);
double light_sample_only(double pdf_light, double pdf_bsdf);

/* One light sample's contribution to the radiance reflected at v toward
 * v->w_o (R9): a light picked by power (of total_power), a point on it, a
 * shadow ray (counted in *shadow_rays); times the light sample's share. */
vec3 next_event(const scene *s, double total_power, const vertex *v, light_share *share, rng *g, uint64_t *shadow_rays);

#endif
