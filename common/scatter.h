/* scatter.h — the materials of the scene format as a random walk meets
 * them: f of the non-specular materials, drawing a direction from it,
 * mirrors and glass, and Russian roulette.
 *
 * The same BSDFs as chapter 4 (path tracing), written once, plainly, for
 * chapters that trace light in both directions (chapter 5 follows photons
 * from the lights and paths from the eye with the same functions).
 * Conventions as in optics.h: directions point away from the surface; n is
 * the unit normal on the side of w_o.
 */
#ifndef COMMON_SCATTER_H
#define COMMON_SCATTER_H

#include <stdbool.h>

#include "optics.h"
#include "rng.h"
#include "sampling.h"
#include "scene.h"
#include "vec.h"

/* Non-specular materials (diffuse, Phong, emitters that reflect) get photons
 * and the density estimate; mirrors and glass only pass light on. */
static inline bool is_specular(const material *m) { return m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS; }

/* f(w_i, w_o) of chapter 4: Lambert plus the normalised Phong lobe around the
 * mirror direction of w_o (symmetric in w_i and w_o, so photons and eye
 * paths share it).  n is the normal on the side of w_o; 0 below the surface. */
static inline vec3 bsdf(const material *m, vec3 n, vec3 w_i, vec3 w_o)
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
static inline bool sample_bsdf(const material *m, vec3 n, vec3 w_o, rng *g, vec3 *w_i, vec3 *weight)
{
    double kd = v3_average(m->albedo), ks = m->kind == MATERIAL_PHONG ? v3_average(m->specular) : 0.0;
    double share = kd + ks > 0.0 ? ks / (kd + ks) : 0.0, u1 = rng_uniform(g), u2 = rng_uniform(g);
    vec3 mirror = v3_reflect(v3_neg(w_o), n);
    if (rng_uniform(g) >= share) {
        *w_i = onb_to_world(onb_from_normal(n), cosine_sample_hemisphere(u1, u2));
    } else {
        double c = pow(u1, 1.0 / (m->exponent + 1.0)), s = sqrt_one_minus_square(c), phi = 2.0 * M_PI * u2;
        vec3 local = v3(s * cos(phi), s * sin(phi), c); /* cos(alpha) = u1^(1/(n+1)) around the mirror direction */
        *w_i = onb_to_world(onb_from_normal(mirror), local);
    }
    double cos_i = v3_dot(n, *w_i), cos_alpha = fmax(0.0, v3_dot(*w_i, mirror));
    double pdf =
        (1.0 - share) * cos_i / M_PI + share * (m->exponent + 1.0) / (2.0 * M_PI) * pow(cos_alpha, m->exponent);
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
static inline vec3 scatter_specular(const material *m, vec3 n_geometric, vec3 w_o, bool carries_radiance, rng *g,
                                    vec3 *w_i)
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
static inline bool survives_roulette(vec3 *weight, rng *g)
{
    double p = fmin(1.0, v3_max_component(*weight));
    if (!(p > 0.0) || rng_uniform(g) >= p)
        return false;
    *weight = v3_scale(*weight, 1.0 / p);
    return true;
}

#endif
