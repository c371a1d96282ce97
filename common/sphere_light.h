/* sphere_light.h — points on a spherical emitter, sampled by the cone of
 * directions the sphere subtends from the shaded point.
 *
 * Seen from x outside a sphere (centre c, radius r, distance d = |c - x|)
 * the sphere covers a cone around (c - x)/d of half-angle theta_max with
 *   sin(theta_max) = r / d.
 * Sampling a direction uniformly in that cone (sampling.h) and taking the
 * first point of the sphere along it wastes no sample on the far side (which
 * uniform area sampling would: half its points face away from x), and its
 * pdf is simply 1 / (2 pi (1 - cos theta_max)) per steradian.
 * From inside the sphere (d <= r) there is no cone: we fall back to uniform
 * area sampling, pdf 1 / (4 pi r^2) per unit area.
 *
 * Header-only and shared (added for chapter 4, path tracing): any chapter
 * that samples sphere lights, and the chi-square test of the sampler.
 */
#ifndef COMMON_SPHERE_LIGHT_H
#define COMMON_SPHERE_LIGHT_H

#include <stdbool.h>

#include "sampling.h"
#include "vec.h"

/* cos(theta_max) of the cone the sphere subtends from x; returns false when x
 * is on or inside the sphere (no cone). */
static inline bool sphere_cone_cos_max(vec3 center, double radius, vec3 x, double *cos_theta_max)
{
    vec3 to_center = v3_sub(center, x);
    double d2 = v3_dot(to_center, to_center);
    if (d2 <= radius * radius)
        return false;
    *cos_theta_max = sqrt(1.0 - radius * radius / d2); /* the quotient is at most 1, even rounded */
    return true;
}

/* A point y on the sphere, its outward unit normal, and the pdf of the
 * *direction* x -> y per steradian.  Outside: cone sampling.  Inside: uniform
 * area sampling converted to solid angle, pdf_A * |x - y|^2 / |cos theta_y|
 * (R7).  Returns false if the sample is degenerate (pdf 0). */
static inline bool sphere_light_sample(vec3 center, double radius, vec3 x, double u1, double u2, vec3 *y, vec3 *normal,
                                       double *pdf_solid_angle)
{
    double cos_max;
    if (sphere_cone_cos_max(center, radius, x, &cos_max)) {
        vec3 axis = v3_normalize(v3_sub(center, x));
        vec3 w = onb_to_world(onb_from_normal(axis), uniform_sample_cone(u1, u2, cos_max));
        /* First intersection of x + t w with the sphere; at the rim (grazing)
         * rounding may make the discriminant slightly negative: clamp to the
         * tangent point. */
        vec3 oc = v3_sub(x, center);
        double b = v3_dot(oc, w);
        vec3 closest = v3_sub(oc, v3_scale(w, b)); /* centre-relative point of closest approach */
        double h2 = radius * radius - v3_dot(closest, closest);
        double t = -b - (h2 > 0.0 ? sqrt(h2) : 0.0);
        *y = v3_madd(x, w, t);
        *normal = v3_normalize(v3_sub(*y, center));
        *pdf_solid_angle = uniform_cone_pdf(cos_max);
        return true;
    }
    vec3 d = uniform_sample_sphere(u1, u2);
    *y = v3_madd(center, d, radius);
    *normal = d;
    *pdf_solid_angle = area_pdf_to_solid_angle(1.0 / (4.0 * M_PI * radius * radius), x, *y, d);
    return *pdf_solid_angle > 0.0;
}

/* The pdf per steradian with which sphere_light_sample, called at x, picks
 * the sphere point y (normal n_y): what MIS needs when a BSDF-sampled ray
 * happens to hit the sphere at y. */
static inline double sphere_light_pdf(vec3 center, double radius, vec3 x, vec3 y, vec3 n_y)
{
    double cos_max;
    if (sphere_cone_cos_max(center, radius, x, &cos_max))
        return uniform_cone_pdf(cos_max);
    return area_pdf_to_solid_angle(1.0 / (4.0 * M_PI * radius * radius), x, y, n_y);
}

#endif
