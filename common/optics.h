/* optics.h — reflection and refraction at a smooth dielectric interface.
 *
 * Used by every chapter that follows specular paths (Whitted ray tracing and
 * path tracing).  Conventions: d is the unit direction of the incoming ray
 * (pointing toward the surface), n the unit normal on the side d comes from
 * (dot(d, n) < 0), eta = n_incident / n_transmitted.
 */
#ifndef COMMON_OPTICS_H
#define COMMON_OPTICS_H

#include <stdbool.h>

#include "vec.h"

/* Snell's law, n_i sin(theta_i) = n_t sin(theta_t), solved for the
 * refracted direction.  Returns false on total internal reflection
 * (sin(theta_t) > 1), when there is no transmitted ray. [exercise 2.1] */
static inline bool refract_direction(vec3 d, vec3 n, double eta, vec3 *refracted)
{
    double cos_i = -v3_dot(d, n);
    double sin2_t = eta * eta * fmax(0.0, 1.0 - cos_i * cos_i);
    if (sin2_t > 1.0)
        return false;
    double cos_t = sqrt(1.0 - sin2_t);
    *refracted = v3_add(v3_scale(d, eta), v3_scale(n, eta * cos_i - cos_t));
    return true;
}

/* The exact Fresnel reflectance of unpolarised light (the mean of the s and
 * p polarisations) for a wave arriving at cos_i = cos(theta_i) > 0 on the
 * side of index n_i, going into index n_t:
 *   r_s = (n_i cos_i - n_t cos_t) / (n_i cos_i + n_t cos_t)
 *   r_p = (n_t cos_i - n_i cos_t) / (n_t cos_i + n_i cos_t)
 *   R   = (r_s^2 + r_p^2) / 2,     T = 1 - R  (energy is conserved)
 * Returns 1 beyond the critical angle (total internal reflection).
 * The polarised parts are returned too when rs2 / rp2 are not NULL. [exercise 2.2] */
static inline double fresnel_dielectric(double cos_i, double n_i, double n_t, double *rs2, double *rp2)
{
    cos_i = fmin(fmax(cos_i, 0.0), 1.0);
    double sin_t = n_i / n_t * sqrt(fmax(0.0, 1.0 - cos_i * cos_i));
    if (sin_t >= 1.0) {
        if (rs2)
            *rs2 = 1.0;
        if (rp2)
            *rp2 = 1.0;
        return 1.0;
    }
    double cos_t = sqrt(fmax(0.0, 1.0 - sin_t * sin_t));
    double r_s = (n_i * cos_i - n_t * cos_t) / (n_i * cos_i + n_t * cos_t);
    double r_p = (n_t * cos_i - n_i * cos_t) / (n_t * cos_i + n_i * cos_t);
    if (rs2)
        *rs2 = r_s * r_s;
    if (rp2)
        *rp2 = r_p * r_p;
    return 0.5 * (r_s * r_s + r_p * r_p);
}

/* Schlick's approximation, R0 + (1 - R0)(1 - cos)^5 with cos taken on the
 * optically thinner side; offered only to compare against the exact form. */
static inline double fresnel_schlick(double cos_i, double n_i, double n_t)
{
    double r0 = (n_i - n_t) / (n_i + n_t);
    r0 *= r0;
    double c = cos_i;
    if (n_i > n_t) { /* inside the denser medium: use the transmitted angle */
        double sin_t = n_i / n_t * sqrt(fmax(0.0, 1.0 - cos_i * cos_i));
        if (sin_t >= 1.0)
            return 1.0;
        c = sqrt(fmax(0.0, 1.0 - sin_t * sin_t));
    }
    return r0 + (1.0 - r0) * pow(1.0 - c, 5.0);
}

#endif
