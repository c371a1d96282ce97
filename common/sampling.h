/* sampling.h — turning uniform random numbers into directions and points.
 *
 * Each routine maps (u1, u2) in [0,1)^2 to a sample and has a matching pdf
 * function.  Directions are in the local frame of onb (z = normal); pdfs of
 * directions are per steradian, pdfs of points per unit area.  A Monte Carlo
 * estimator divides by exactly these pdfs, so the tests check each one by a
 * chi-square test against its pdf.
 */
#ifndef COMMON_SAMPLING_H
#define COMMON_SAMPLING_H

#include "fast_math.h"
#include "vec.h"

/* sqrt(1 - z^2) for |z| <= 1, as sqrt((1 - z)(1 + z)): never the root of a
 * negative number (no clamp needed) and accurate near z = 1 too. */
static inline double sqrt_one_minus_square(double z) { return sqrt((1.0 - z) * (1.0 + z)); }

/* Uniform over the hemisphere z >= 0: pdf = 1 / (2 pi).  The angular form
 * (R2) "as written": every direction equally likely. */
static inline vec3 uniform_sample_hemisphere(double u1, double u2)
{
    double z = u1, r = sqrt_one_minus_square(z);
    circle_point phi = unit_circle(u2); /* phi.cos = cos(phi), phi.sin = sin(phi) for phi = 2 pi u2 */
    return v3(r * phi.cos, r * phi.sin, z);
}
static inline double uniform_hemisphere_pdf(void) { return 1.0 / (2.0 * M_PI); }

/* Cosine-weighted hemisphere (Malley's method: uniform disk, projected up):
 * pdf = cos(theta) / pi, which cancels the cosine of (R2).  The disk point
 * has x^2 + y^2 = r^2 = u1, so its height is z = cos(theta) = sqrt(1 - u1):
 * positive (at least 1e-8 for u1 < 1), so the direction is strictly above
 * the surface. */
static inline vec3 cosine_sample_hemisphere(double u1, double u2)
{
    double r = sqrt(u1);
    circle_point phi = unit_circle(u2); /* phi.cos = cos(phi), phi.sin = sin(phi) for phi = 2 pi u2 */
    return v3(r * phi.cos, r * phi.sin, sqrt(1.0 - u1));
}
static inline double cosine_hemisphere_pdf(double cos_theta) { return cos_theta > 0.0 ? cos_theta / M_PI : 0.0; }

/* Uniform over the whole sphere: pdf = 1 / (4 pi). */
static inline vec3 uniform_sample_sphere(double u1, double u2)
{
    double z = 1.0 - 2.0 * u1, r = sqrt_one_minus_square(z);
    circle_point phi = unit_circle(u2); /* phi.cos = cos(phi), phi.sin = sin(phi) for phi = 2 pi u2 */
    return v3(r * phi.cos, r * phi.sin, z);
}
static inline double uniform_sphere_pdf(void) { return 1.0 / (4.0 * M_PI); }

/* Uniform over the cone of directions within angle theta_max of +z
 * (cos_theta_max given): pdf = 1 / (2 pi (1 - cos_theta_max)).  A sphere seen
 * from outside subtends such a cone. */
static inline vec3 uniform_sample_cone(double u1, double u2, double cos_theta_max)
{
    double z = 1.0 - u1 * (1.0 - cos_theta_max), r = sqrt_one_minus_square(z);
    circle_point phi = unit_circle(u2); /* phi.cos = cos(phi), phi.sin = sin(phi) for phi = 2 pi u2 */
    return v3(r * phi.cos, r * phi.sin, z);
}
static inline double uniform_cone_pdf(double cos_theta_max) { return 1.0 / (2.0 * M_PI * (1.0 - cos_theta_max)); }

/* A density p_A per unit area at the point y (unit normal n_y), converted to
 * a density per steradian of the direction from x to y: dw = cos(theta_y) dA
 * / |x - y|^2 (R7), so p_w = p_A |x - y|^2 / cos(theta_y).  0 if y is seen
 * edge-on (or is x itself). */
static inline double area_pdf_to_solid_angle(double pdf_area, vec3 x, vec3 y, vec3 n_y)
{
    vec3 to_y = v3_sub(y, x);
    double r2 = v3_dot(to_y, to_y), cos_y = fabs(v3_dot(n_y, to_y)) / sqrt(r2);
    return cos_y > 0.0 ? pdf_area * r2 / cos_y : 0.0;
}

/* Uniform point on triangle (a, b, c): pdf = 1 / area.  The square-root
 * warp keeps the density constant (a naive (u1, u2) with u1 + u2 <= 1
 * rejection would waste half the samples). */
static inline vec3 uniform_sample_triangle(vec3 a, vec3 b, vec3 c, double u1, double u2)
{
    double s = sqrt(u1);
    double wb = s * (1.0 - u2), wc = s * u2;
    return v3_add(a, v3_add(v3_scale(v3_sub(b, a), wb), v3_scale(v3_sub(c, a), wc)));
}
static inline double triangle_area(vec3 a, vec3 b, vec3 c)
{
    return 0.5 * v3_length(v3_cross(v3_sub(b, a), v3_sub(c, a)));
}

#endif
