/* test_optics.c — unit tests of common/optics.h against closed forms.
 *
 * Truth comes from textbook optics, not from the code: Fresnel's sine and
 * tangent laws (a different algebraic form of the same physics), the
 * amplitude transmission coefficients t_s, t_p for T (so R + T = 1 is a
 * real check of energy conservation), Brewster's and the critical angle,
 * Snell's law in vector form, and the lateral shift of a ray through a
 * parallel slab, d sin(theta - theta_t) / cos(theta_t). */
#include <stdio.h>

#include "check.h"
#include "optics.h"

static double degrees(double radians) { return radians * 180.0 / M_PI; }
static double radians(double deg) { return deg * M_PI / 180.0; }

static void test_normal_incidence_is_4_percent(void)
{
    /* ((n - 1) / (n + 1))^2 = (0.5 / 2.5)^2 = 0.04, from either side */
    CHECK_NEAR(fresnel_dielectric(1.0, 1.0, 1.5, NULL, NULL), 0.04, 1e-15, "R air->glass at 0 deg");
    CHECK_NEAR(fresnel_dielectric(1.0, 1.5, 1.0, NULL, NULL), 0.04, 1e-15, "R glass->air at 0 deg");
    CHECK_NEAR(fresnel_schlick(1.0, 1.0, 1.5), 0.04, 1e-15, "Schlick at 0 deg is R0");
    /* water: (0.33 / 2.33)^2 */
    CHECK_NEAR(fresnel_dielectric(1.0, 1.0, 1.33, NULL, NULL), (0.33 / 2.33) * (0.33 / 2.33), 1e-15, "water");
}

static void test_brewster_angle_has_no_p_reflection(void)
{
    double brewster = atan(1.5); /* tan(theta_B) = n_t / n_i */
    CHECK_NEAR(degrees(brewster), 56.30993, 1e-5, "Brewster angle for n = 1.5");
    double rs2, rp2;
    double R = fresnel_dielectric(cos(brewster), 1.0, 1.5, &rs2, &rp2);
    CHECK_NEAR(rp2, 0.0, 1e-28, "R_p at Brewster's angle");
    /* At Brewster's angle theta_i + theta_t = 90 deg, so the sine law gives
     * r_s = -sin(theta_i - theta_t) = -cos(2 theta_B). */
    double rs = cos(2.0 * brewster);
    CHECK_NEAR(rs2, rs * rs, 1e-15, "R_s at Brewster's angle");
    CHECK_NEAR(R, 0.5 * rs * rs, 1e-15, "R unpolarised at Brewster's angle");
    /* From inside the glass Brewster's angle is atan(1 / 1.5) */
    fresnel_dielectric(cos(atan(1.0 / 1.5)), 1.5, 1.0, NULL, &rp2);
    CHECK_NEAR(rp2, 0.0, 1e-28, "R_p at the inside Brewster angle");
}

static void test_critical_angle_total_internal_reflection(void)
{
    double critical = asin(1.0 / 1.5);
    CHECK_NEAR(degrees(critical), 41.81031, 1e-5, "critical angle for n = 1.5");
    for (double extra = 1e-6; extra < radians(48.0); extra *= 3.0) {
        double theta = critical + extra;
        CHECK(fresnel_dielectric(cos(theta), 1.5, 1.0, NULL, NULL) == 1.0, "R = 1 at %.8f deg from inside",
              degrees(theta));
        CHECK(fresnel_schlick(cos(theta), 1.5, 1.0) == 1.0, "Schlick R = 1 at %.8f deg from inside", degrees(theta));
        vec3 t = {0};
        vec3 d = v3(sin(theta), -cos(theta), 0.0);
        CHECK(!refract_direction(d, v3(0, 1, 0), 1.5, &t), "no refracted ray at %.6f deg", degrees(theta));
    }
    /* Just below it the reflectance is below one and climbs to it continuously. */
    double below = fresnel_dielectric(cos(critical - 1e-3), 1.5, 1.0, NULL, NULL);
    double further = fresnel_dielectric(cos(critical - 1e-2), 1.5, 1.0, NULL, NULL);
    CHECK(further < below && below < 1.0, "R below the critical angle: %g at -0.01 rad, %g at -0.001 rad", further,
          below);
    vec3 t = {0};
    CHECK(refract_direction(v3(sin(critical - 1e-6), -cos(critical - 1e-6), 0), v3(0, 1, 0), 1.5, &t),
          "a refracted ray just below the critical angle");
    /* From the thin side there is never total reflection. */
    CHECK(fresnel_dielectric(cos(radians(89.999)), 1.0, 1.5, NULL, NULL) < 1.0, "air->glass at grazing incidence");
}

/* Fresnel's sine and tangent laws (Born & Wolf 1.5.(21a)):
 *   r_s = -sin(i - t) / sin(i + t),   r_p = tan(i - t) / tan(i + t) */
static void test_agrees_with_sine_and_tangent_laws(void)
{
    const double pairs[][2] = {{1.0, 1.5}, {1.5, 1.0}, {1.0, 1.33}, {1.33, 1.0}, {1.0, 2.4}};
    for (size_t k = 0; k < sizeof pairs / sizeof pairs[0]; k++) {
        double n_i = pairs[k][0], n_t = pairs[k][1];
        for (double deg = 0.5; deg < 90.0; deg += 0.5) {
            double i = radians(deg);
            double sin_t = n_i / n_t * sin(i);
            if (sin_t >= 1.0)
                break;
            double t = asin(sin_t);
            double rs = -sin(i - t) / sin(i + t), rp = tan(i - t) / tan(i + t);
            double rs2, rp2;
            double R = fresnel_dielectric(cos(i), n_i, n_t, &rs2, &rp2);
            CHECK_NEAR(rs2, rs * rs, 1e-12, "R_s vs the sine law");
            CHECK_NEAR(rp2, rp * rp, 1e-12, "R_p vs the tangent law");
            CHECK_NEAR(R, 0.5 * (rs * rs + rp * rp), 1e-12, "R unpolarised");
        }
    }
}

/* Energy: T from the transmission amplitudes
 *   t_s = 2 n_i cos_i / (n_i cos_i + n_t cos_t),  t_p = 2 n_i cos_i / (n_t cos_i + n_i cos_t),
 *   T_s,p = (n_t cos_t) / (n_i cos_i) t_s,p^2   (power through the interface),
 * must make R_s + T_s = 1 and R_p + T_p = 1 separately. */
static void test_reflected_plus_transmitted_is_one(void)
{
    const double pairs[][2] = {{1.0, 1.5}, {1.5, 1.0}, {1.0, 1.33}, {1.33, 1.0}, {1.0, 2.4}};
    double worst = 0.0;
    for (size_t k = 0; k < sizeof pairs / sizeof pairs[0]; k++) {
        double n_i = pairs[k][0], n_t = pairs[k][1];
        for (double deg = 0.0; deg < 89.95; deg += 0.25) {
            double cos_i = cos(radians(deg));
            double sin_t = n_i / n_t * sqrt(1.0 - cos_i * cos_i);
            if (sin_t >= 1.0)
                break;
            double cos_t = sqrt(1.0 - sin_t * sin_t);
            double t_s = 2.0 * n_i * cos_i / (n_i * cos_i + n_t * cos_t);
            double t_p = 2.0 * n_i * cos_i / (n_t * cos_i + n_i * cos_t);
            double power = n_t * cos_t / (n_i * cos_i);
            double T_s = power * t_s * t_s, T_p = power * t_p * t_p;
            double rs2, rp2;
            double R = fresnel_dielectric(cos_i, n_i, n_t, &rs2, &rp2);
            worst = fmax(worst, fabs(rs2 + T_s - 1.0));
            worst = fmax(worst, fabs(rp2 + T_p - 1.0));
            worst = fmax(worst, fabs(R + 0.5 * (T_s + T_p) - 1.0));
        }
    }
    CHECK(worst < 1e-12, "largest |R + T - 1| = %g", worst);
}

static void test_schlick_is_exact_at_the_ends(void)
{
    CHECK_NEAR(fresnel_schlick(0.0, 1.0, 1.5), 1.0, 1e-15, "Schlick at grazing incidence");
    CHECK_NEAR(fresnel_dielectric(0.0, 1.0, 1.5, NULL, NULL), 1.0, 1e-15, "exact at grazing incidence");
    /* In between it only approximates; both must rise with the angle. */
    double previous_exact = 0.0, previous_schlick = 0.0;
    for (double deg = 0.0; deg <= 90.0; deg += 1.0) {
        double c = cos(radians(deg));
        double exact = fresnel_dielectric(c, 1.0, 1.5, NULL, NULL), schlick = fresnel_schlick(c, 1.0, 1.5);
        CHECK(exact >= previous_exact - 1e-15 && schlick >= previous_schlick - 1e-15, "reflectance falls at %g deg",
              deg);
        previous_exact = exact, previous_schlick = schlick;
    }
}

/* Snell's law in vector form: the refracted ray is unit, lies in the plane
 * of incidence on the far side, and n_i sin(theta_i) = n_t sin(theta_t). */
static void test_refracted_direction_obeys_snell(void)
{
    vec3 n = v3_normalize(v3(0.2, 1.0, -0.3));
    onb frame = onb_from_normal(n);
    for (double deg = 0.0; deg < 90.0; deg += 7.5)
        for (double phi = 0.0; phi < 6.2; phi += 1.1) {
            double th = radians(deg);
            vec3 d = onb_to_world(frame, v3(sin(th) * cos(phi), sin(th) * sin(phi), -cos(th)));
            for (int side = 0; side < 2; side++) {
                double n_i = side ? 1.5 : 1.0, n_t = side ? 1.0 : 1.5;
                vec3 t = {0};
                bool ok = refract_direction(d, n, n_i / n_t, &t);
                bool expected = n_i / n_t * sin(th) < 1.0;
                CHECK(ok == expected, "refraction exists at %g deg, %g -> %g: %d", deg, n_i, n_t, ok);
                if (!ok)
                    continue;
                CHECK_NEAR(v3_length(t), 1.0, 1e-12, "unit refracted direction");
                CHECK(v3_dot(t, n) < 0.0, "refracted ray goes through the surface");
                CHECK_NEAR(v3_dot(t, v3_cross(d, n)), 0.0, 1e-12, "in the plane of incidence");
                double sin_i = v3_length(v3_cross(d, n)), sin_t = v3_length(v3_cross(t, n));
                CHECK_NEAR(n_i * sin_i, n_t * sin_t, 1e-12, "n_i sin_i = n_t sin_t");
            }
        }
}

/* A ray through a parallel slab of thickness d leaves parallel to itself,
 * shifted sideways by d sin(theta - theta_t) / cos(theta_t).  Traced here
 * with refract_direction twice and plane intersections. */
static void test_slab_shifts_ray_sideways(void)
{
    const double thickness = 2.0, n_glass = 1.5;
    vec3 up = v3(0, 1, 0);
    for (double deg = 0.0; deg < 89.0; deg += 4.0) {
        double theta = radians(deg);
        vec3 d = v3(sin(theta), -cos(theta), 0.0);
        vec3 origin = v3(0.0, 1.0, 0.0); /* slab between y = 0 and y = -thickness */
        vec3 entry = v3_madd(origin, d, 1.0 / cos(theta));
        vec3 inside = {0}, outside = {0};
        CHECK(refract_direction(d, up, 1.0 / n_glass, &inside), "enters the slab");
        vec3 exit_point = v3_madd(entry, inside, thickness / -inside.y);
        CHECK(refract_direction(inside, up, n_glass, &outside), "leaves the slab at %g deg", deg);
        CHECK_NEAR(v3_length(v3_sub(outside, d)), 0.0, 1e-12, "leaves parallel to the incoming ray");
        /* perpendicular distance between the incoming line and the outgoing line */
        vec3 offset = v3_sub(exit_point, origin);
        double shift = v3_length(v3_sub(offset, v3_scale(d, v3_dot(offset, d))));
        double theta_t = asin(sin(theta) / n_glass);
        CHECK_NEAR(shift, thickness * sin(theta - theta_t) / cos(theta_t), 1e-12, "lateral displacement");
    }
}

int main(void)
{
    RUN_TEST(test_normal_incidence_is_4_percent);
    RUN_TEST(test_brewster_angle_has_no_p_reflection);
    RUN_TEST(test_critical_angle_total_internal_reflection);
    RUN_TEST(test_agrees_with_sine_and_tangent_laws);
    RUN_TEST(test_reflected_plus_transmitted_is_one);
    RUN_TEST(test_schlick_is_exact_at_the_ends);
    RUN_TEST(test_refracted_direction_obeys_snell);
    RUN_TEST(test_slab_shifts_ray_sideways);
    return CHECK_EXIT_STATUS();
}
