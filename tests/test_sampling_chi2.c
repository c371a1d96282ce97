/* test_sampling_chi2.c — chi-square goodness-of-fit tests of the samplers a
 * path tracer divides by (common/sampling.h, common/sphere_light.h, and
 * surface_sample_point in common/scene.c).
 *
 * A Monte Carlo estimator is unbiased only if the samples really follow the
 * pdf it divides by.  Each test draws N samples, sorts them into bins, and
 * compares the counts n_i with the expected counts e_i = N * P_i, where P_i
 * is the pdf integrated over bin i — computed here from the pdf function
 * (or from areas and solid angles), never from the sampler.  Then
 *   X^2 = sum_i (n_i - e_i)^2 / e_i
 * follows a chi-square distribution with (bins - 1) degrees of freedom if
 * the sampler is right.  We fail when X^2 exceeds the critical value at
 * significance alpha = 1e-3 (Wilson-Hilferty approximation of the quantile,
 * accurate to well under 1 % for these degrees of freedom).  Every bin
 * expects at least 100 samples, far above the usual rule of 5.  The seeds are
 * fixed, so a run is reproducible; CHI2_VERBOSE=1 prints every X^2 on stderr.
 */
#include <stdlib.h>
#include <unistd.h>

#include "check.h"
#include "rng.h"
#include "sampling.h"
#include "scene.h"
#include "sphere_light.h"

enum { SAMPLES = 400000 };

/* Upper alpha = 1e-3 quantile of chi-square(df): Wilson & Hilferty (1931),
 * df (1 - 2/(9 df) + z sqrt(2/(9 df)))^3 with z = 3.0902 the standard normal
 * 1e-3 upper quantile. */
static double chi2_critical(int df)
{
    double z = 3.090232, a = 2.0 / (9.0 * df);
    double c = 1.0 - a + z * sqrt(a);
    return df * c * c * c;
}

/* X^2 of observed counts against expected probabilities; also checks the
 * expected probabilities sum to 1 and each bin expects enough samples. */
static void check_chi2(const char *what, const long *observed, const double *probability, int bins, long total)
{
    double x2 = 0.0, sum_p = 0.0, smallest = INFINITY;
    for (int i = 0; i < bins; i++) {
        double e = probability[i] * (double)total;
        sum_p += probability[i];
        smallest = fmin(smallest, e);
        x2 += (observed[i] - e) * (observed[i] - e) / e;
    }
    CHECK(fabs(sum_p - 1.0) < 1e-9, "%s: bin probabilities sum to %.12g, not 1", what, sum_p);
    CHECK(smallest >= 100.0, "%s: a bin expects only %.1f samples", what, smallest);
    double critical = chi2_critical(bins - 1);
    if (getenv("CHI2_VERBOSE"))
        fprintf(stderr, "%s: X2 %.1f crit %.1f df %d\n", what, x2, critical, bins - 1);
    CHECK(x2 <= critical, "%s: X^2 = %.1f > %.1f (df %d, alpha 1e-3)", what, x2, critical, bins - 1);
}

/* --- directions: bins in (cos theta, phi) ----------------------------------------------- */

enum { COS_BINS = 10, PHI_BINS = 8 };

/* Bin a unit direction (local frame, z = axis) with cos theta in [z_lo, 1]. */
static int direction_bin(vec3 d, double z_lo)
{
    int i = (int)((d.z - z_lo) / (1.0 - z_lo) * COS_BINS);
    double phi = atan2(d.y, d.x);
    if (phi < 0.0)
        phi += 2.0 * M_PI;
    int j = (int)(phi / (2.0 * M_PI) * PHI_BINS);
    if (i < 0 || i >= COS_BINS || j < 0 || j >= PHI_BINS)
        return -1;
    return i * PHI_BINS + j;
}

/* P(bin) = Int pdf dw over the bin, with dw = d(cos theta) dphi; the pdfs
 * here depend on theta only, so a fine midpoint rule in cos theta (exact for
 * the linear cosine pdf) times the bin's phi width. */
static void direction_bin_probabilities(double (*pdf_of_cos)(double), double z_lo, double *p)
{
    const int steps = 4000;
    for (int i = 0; i < COS_BINS; i++) {
        double lo = z_lo + (1.0 - z_lo) * i / COS_BINS, hi = z_lo + (1.0 - z_lo) * (i + 1) / COS_BINS;
        double integral = 0.0;
        for (int k = 0; k < steps; k++)
            integral += pdf_of_cos(lo + (hi - lo) * (k + 0.5) / steps) * (hi - lo) / steps;
        for (int j = 0; j < PHI_BINS; j++)
            p[i * PHI_BINS + j] = integral * 2.0 * M_PI / PHI_BINS;
    }
}

static double cone_cos_max; /* the cone under test */
static double pdf_cosine(double c) { return cosine_hemisphere_pdf(c); }
static double pdf_uniform_hemisphere(double c)
{
    (void)c;
    return uniform_hemisphere_pdf();
}
static double pdf_uniform_sphere(double c)
{
    (void)c;
    return uniform_sphere_pdf();
}
static double pdf_cone(double c) { return c >= cone_cos_max ? uniform_cone_pdf(cone_cos_max) : 0.0; }

static void check_direction_sampler(const char *what, vec3 (*sample)(double, double, double), double parameter,
                                    double (*pdf_of_cos)(double), double z_lo, uint64_t seed)
{
    long observed[COS_BINS * PHI_BINS] = {0};
    double probability[COS_BINS * PHI_BINS];
    direction_bin_probabilities(pdf_of_cos, z_lo, probability);
    long outside = 0;
    for (long k = 0; k < SAMPLES; k++) {
        rng g = rng_for(seed, 0, (uint64_t)k);
        double u1 = rng_uniform(&g), u2 = rng_uniform(&g);
        vec3 d = sample(u1, u2, parameter);
        int bin = direction_bin(d, z_lo);
        CHECK(fabs(v3_length(d) - 1.0) < 1e-12, "%s: direction not unit", what);
        if (bin < 0)
            outside++;
        else
            observed[bin]++;
    }
    CHECK(outside == 0, "%s: %ld samples outside the sampled domain", what, outside);
    check_chi2(what, observed, probability, COS_BINS * PHI_BINS, SAMPLES);
}

static vec3 cosine_sampler(double u1, double u2, double unused)
{
    (void)unused;
    return cosine_sample_hemisphere(u1, u2);
}
static vec3 hemisphere_sampler(double u1, double u2, double unused)
{
    (void)unused;
    return uniform_sample_hemisphere(u1, u2);
}
static vec3 sphere_sampler(double u1, double u2, double unused)
{
    (void)unused;
    return uniform_sample_sphere(u1, u2);
}
static vec3 cone_sampler(double u1, double u2, double cos_max) { return uniform_sample_cone(u1, u2, cos_max); }

static void test_cosine_hemisphere_chi2(void)
{
    check_direction_sampler("cosine hemisphere", cosine_sampler, 0.0, pdf_cosine, 0.0, 101);
}

static void test_uniform_hemisphere_chi2(void)
{
    check_direction_sampler("uniform hemisphere", hemisphere_sampler, 0.0, pdf_uniform_hemisphere, 0.0, 102);
}

static void test_uniform_sphere_chi2(void)
{
    check_direction_sampler("uniform sphere", sphere_sampler, 0.0, pdf_uniform_sphere, -1.0, 103);
}

static void test_cone_chi2(void)
{
    cone_cos_max = 0.8;
    check_direction_sampler("cone cos_max 0.8", cone_sampler, cone_cos_max, pdf_cone, cone_cos_max, 104);
    cone_cos_max = 0.999;
    check_direction_sampler("cone cos_max 0.999", cone_sampler, cone_cos_max, pdf_cone, cone_cos_max, 105);
}

/* --- sphere lights: the cone a sphere subtends ------------------------------------------ */

/* From a point outside a sphere, sphere_light_sample must give points on the
 * near side of the sphere whose directions are uniform over the subtended
 * cone (sin theta_max = r / d, computed here from the geometry), with the pdf
 * sphere_light_pdf reports.  From inside, points uniform over the sphere's
 * area (bins of equal area: equal steps in z and phi, Archimedes). */
static void test_sphere_light_cone_chi2(void)
{
    vec3 center = v3(1.0, 2.0, -0.5), x = v3(4.0, -1.0, 2.0);
    double radius = 1.3;
    double d = v3_length(v3_sub(center, x));
    double cos_max = sqrt(1.0 - radius * radius / (d * d));
    onb frame = onb_from_normal(v3_normalize(v3_sub(center, x)));
    cone_cos_max = cos_max;
    long observed[COS_BINS * PHI_BINS] = {0};
    double probability[COS_BINS * PHI_BINS];
    direction_bin_probabilities(pdf_cone, cos_max, probability);
    long bad = 0;
    double expected_pdf = 1.0 / (2.0 * M_PI * (1.0 - cos_max));
    for (long k = 0; k < SAMPLES; k++) {
        rng g = rng_for(106, 0, (uint64_t)k);
        double u1 = rng_uniform(&g), u2 = rng_uniform(&g);
        vec3 y, n;
        double pdf;
        if (!sphere_light_sample(center, radius, x, u1, u2, &y, &n, &pdf)) {
            bad++;
            continue;
        }
        vec3 w = v3_normalize(v3_sub(y, x));
        bool on_sphere = fabs(v3_length(v3_sub(y, center)) - radius) < 1e-9;
        bool near_side = v3_dot(n, w) <= 1e-9; /* the normal faces x */
        bool pdf_ok = fabs(pdf - expected_pdf) < 1e-9 * expected_pdf &&
                      fabs(sphere_light_pdf(center, radius, x, y, n) - pdf) < 1e-9 * pdf;
        int bin = direction_bin(onb_to_local(frame, w), cos_max);
        if (!on_sphere || !near_side || !pdf_ok || bin < 0)
            bad++;
        else
            observed[bin]++;
    }
    CHECK(bad == 0, "sphere cone: %ld samples off the sphere, on its far side, outside the cone or with a wrong pdf",
          bad);
    check_chi2("sphere light from outside", observed, probability, COS_BINS * PHI_BINS, SAMPLES);
}

static void test_sphere_light_inside_chi2(void)
{
    vec3 center = v3(0.0, 0.0, 0.0), x = v3(0.2, -0.3, 0.1);
    double radius = 2.0;
    long observed[COS_BINS * PHI_BINS] = {0};
    double probability[COS_BINS * PHI_BINS];
    for (int i = 0; i < COS_BINS * PHI_BINS; i++)
        probability[i] = 1.0 / (COS_BINS * PHI_BINS); /* equal-area bins */
    long bad = 0;
    /* E[1/pdf] over directions = the solid angle covered = 4 pi from inside:
     * checks the pdf's normalisation, with a 5-standard-error tolerance from
     * the sample variance. */
    double sum = 0.0, sum_squares = 0.0;
    for (long k = 0; k < SAMPLES; k++) {
        rng g = rng_for(107, 0, (uint64_t)k);
        double u1 = rng_uniform(&g), u2 = rng_uniform(&g);
        vec3 y, n;
        double pdf;
        if (!sphere_light_sample(center, radius, x, u1, u2, &y, &n, &pdf)) {
            bad++;
            continue;
        }
        sum += 1.0 / pdf, sum_squares += 1.0 / (pdf * pdf);
        int bin = direction_bin(v3_scale(v3_sub(y, center), 1.0 / radius), -1.0);
        if (bin < 0 || fabs(sphere_light_pdf(center, radius, x, y, n) - pdf) > 1e-9 * pdf)
            bad++;
        else
            observed[bin]++;
    }
    CHECK(bad == 0, "sphere from inside: %ld bad samples", bad);
    check_chi2("sphere light from inside", observed, probability, COS_BINS * PHI_BINS, SAMPLES);
    double mean = sum / SAMPLES, se = sqrt((sum_squares / SAMPLES - mean * mean) / (SAMPLES - 1));
    CHECK_NEAR(mean, 4.0 * M_PI, 5.0 * se, "E[1/pdf] from inside the sphere (4 pi)");
}

/* --- points on triangles and quads --------------------------------------------------------- */

/* A triangle cut into n^2 congruent small triangles by lines parallel to its
 * sides: each has 1/n^2 of the area, so a uniform sampler puts 1/n^2 of
 * its samples in each.  Bin of barycentric coordinates (b1, b2) of a point:
 * cell (i, j) = floor(n b1), floor(n b2), "upper" or "lower" half by the
 * fractional parts. */
enum { TRIANGLE_SPLIT = 8, TRIANGLE_BINS = TRIANGLE_SPLIT * TRIANGLE_SPLIT };

static int barycentric_bin(double b1, double b2)
{
    const double tolerance = 1e-9;
    if (b1 < -tolerance || b2 < -tolerance || b1 + b2 > 1.0 + tolerance)
        return -1;
    double s1 = fmin(fmax(b1, 0.0), 1.0) * TRIANGLE_SPLIT, s2 = fmin(fmax(b2, 0.0), 1.0) * TRIANGLE_SPLIT;
    int i = (int)fmin(s1, TRIANGLE_SPLIT - 1), j = (int)fmin(s2, TRIANGLE_SPLIT - 1);
    if (i + j > TRIANGLE_SPLIT - 1) /* rounding at the long edge */
        j = TRIANGLE_SPLIT - 1 - i;
    bool upper = (s1 - i) + (s2 - j) > 1.0 && i + j < TRIANGLE_SPLIT - 1;
    /* Number the cells: the "lower" cells (i + j <= n - 1) then the "upper" ones (i + j <= n - 2). */
    int lower_index = 0, upper_index = 0;
    for (int a = 0; a < i; a++)
        lower_index += TRIANGLE_SPLIT - a, upper_index += TRIANGLE_SPLIT - 1 - a;
    if (!upper)
        return lower_index + j;
    return TRIANGLE_SPLIT * (TRIANGLE_SPLIT + 1) / 2 + upper_index + j;
}

/* Barycentric coordinates of p in triangle (a, b, c): p = a + b1 (b - a) + b2 (c - a);
 * also how far p is from the triangle's plane. */
static void barycentric(vec3 a, vec3 b, vec3 c, vec3 p, double *b1, double *b2, double *off_plane)
{
    vec3 e1 = v3_sub(b, a), e2 = v3_sub(c, a), q = v3_sub(p, a);
    double d11 = v3_dot(e1, e1), d12 = v3_dot(e1, e2), d22 = v3_dot(e2, e2);
    double q1 = v3_dot(q, e1), q2 = v3_dot(q, e2), det = d11 * d22 - d12 * d12;
    *b1 = (d22 * q1 - d12 * q2) / det;
    *b2 = (d11 * q2 - d12 * q1) / det;
    vec3 n = v3_normalize(v3_cross(e1, e2));
    *off_plane = fabs(v3_dot(q, n));
}

static void test_triangle_points_chi2(void)
{
    vec3 a = v3(0.3, -1.0, 2.0), b = v3(2.5, 0.4, 1.0), c = v3(-0.7, 1.9, 0.2);
    long observed[TRIANGLE_BINS] = {0};
    double probability[TRIANGLE_BINS];
    for (int i = 0; i < TRIANGLE_BINS; i++)
        probability[i] = 1.0 / TRIANGLE_BINS;
    long bad = 0;
    for (long k = 0; k < SAMPLES; k++) {
        rng g = rng_for(108, 0, (uint64_t)k);
        double u1 = rng_uniform(&g), u2 = rng_uniform(&g);
        vec3 p = uniform_sample_triangle(a, b, c, u1, u2);
        double b1, b2, off;
        barycentric(a, b, c, p, &b1, &b2, &off);
        int bin = barycentric_bin(b1, b2);
        if (bin < 0 || off > 1e-9)
            bad++;
        else
            observed[bin]++;
    }
    CHECK(bad == 0, "triangle: %ld samples off the triangle", bad);
    check_chi2("triangle points", observed, probability, TRIANGLE_BINS, SAMPLES);
}

static char temp_dir[] = "/tmp/test_chi2_XXXXXX";

/* Points on whole surfaces (surface_sample_point): a trapezoid quad, which
 * the scene stores as two triangles of areas 2 and 1, must be hit in
 * proportion to area (bins: each triangle's n^2 cells, probability
 * (A_t / A) / n^2, the areas computed here from the file's vertices), and a
 * sphere uniformly (equal-area bins in z and phi). */
static void test_surface_points_chi2(void)
{
    CHECK(mkdtemp(temp_dir) != NULL, "cannot make a temporary directory");
    char path[256];
    snprintf(path, sizeof path, "%s/surfaces.scene", temp_dir);
    FILE *f = fopen(path, "w");
    CHECK(f != NULL, "cannot write %s", path);
    if (!f)
        return;
    fputs("camera eye 0 0 10  look 0 0 0  up 0 1 0  fov 40\n"
          "material m diffuse 0.5 0.5 0.5\n"
          "quad trapezoid m  0 0 0  4 0 0  3 1 0  1 1 0\n"
          "triangle tri m  0 0 1  2 0 1.5  0.5 3 1\n"
          "sphere ball m  5 5 5  0.75\n",
          f);
    fclose(f);
    scene s;
    char err[512];
    int status = scene_load(path, &s, err, sizeof err);
    remove(path);
    rmdir(temp_dir);
    CHECK(status == 0, "scene_load: %.200s", err);
    if (status)
        return;

    const char *names[] = {"trapezoid", "tri"};
    for (int q = 0; q < 2; q++) {
        int index = scene_find_surface(&s, names[q]);
        const surface *surf = &s.surfaces[index];
        int triangles = surf->triangle_count;
        CHECK(triangles >= 1 && triangles <= 2, "%s: %d triangles", names[q], triangles);
        double area[2] = {0, 0}, total = 0.0;
        for (int t = 0; t < triangles; t++) {
            const triangle *tri = &s.triangles[surf->first_triangle + t];
            area[t] = triangle_area(tri->p0, v3_add(tri->p0, tri->e1), v3_add(tri->p0, tri->e2));
            total += area[t];
        }
        if (q == 0)
            CHECK_NEAR(total, 3.0, 1e-12, "trapezoid area (bases 4 and 2, height 1)");
        long observed[2 * TRIANGLE_BINS] = {0};
        double probability[2 * TRIANGLE_BINS];
        for (int t = 0; t < 2; t++)
            for (int i = 0; i < TRIANGLE_BINS; i++)
                probability[t * TRIANGLE_BINS + i] = area[t] / total / TRIANGLE_BINS;
        long bad = 0;
        for (long k = 0; k < SAMPLES; k++) {
            rng g = rng_for(109 + (uint64_t)q, 0, (uint64_t)k);
            double u1 = rng_uniform(&g), u2 = rng_uniform(&g), u3 = rng_uniform(&g);
            vec3 p, n;
            surface_sample_point(&s, index, u1, u2, u3, &p, &n);
            int bin = -1;
            for (int t = 0; t < triangles && bin < 0; t++) {
                const triangle *tri = &s.triangles[surf->first_triangle + t];
                double b1, b2, off;
                barycentric(tri->p0, v3_add(tri->p0, tri->e1), v3_add(tri->p0, tri->e2), p, &b1, &b2, &off);
                int cell = off < 1e-9 ? barycentric_bin(b1, b2) : -1;
                if (cell >= 0)
                    bin = t * TRIANGLE_BINS + cell;
            }
            if (bin < 0)
                bad++;
            else
                observed[bin]++;
        }
        CHECK(bad == 0, "%s: %ld samples off the surface", names[q], bad);
        check_chi2(names[q], observed, probability, triangles * TRIANGLE_BINS, SAMPLES);
    }

    int ball = scene_find_surface(&s, "ball");
    long observed[COS_BINS * PHI_BINS] = {0};
    double probability[COS_BINS * PHI_BINS];
    for (int i = 0; i < COS_BINS * PHI_BINS; i++)
        probability[i] = 1.0 / (COS_BINS * PHI_BINS);
    long bad = 0;
    for (long k = 0; k < SAMPLES; k++) {
        rng g = rng_for(111, 0, (uint64_t)k);
        double u1 = rng_uniform(&g), u2 = rng_uniform(&g), u3 = rng_uniform(&g);
        vec3 p, n;
        surface_sample_point(&s, ball, u1, u2, u3, &p, &n);
        vec3 d = v3_scale(v3_sub(p, v3(5, 5, 5)), 1.0 / 0.75);
        int bin = direction_bin(d, -1.0);
        if (bin < 0 || fabs(v3_length(d) - 1.0) > 1e-9 || v3_length(v3_sub(n, d)) > 1e-9)
            bad++;
        else
            observed[bin]++;
    }
    CHECK(bad == 0, "ball: %ld samples off the sphere or with a wrong normal", bad);
    check_chi2("sphere surface points", observed, probability, COS_BINS * PHI_BINS, SAMPLES);
    scene_free(&s);
}

/* The harness must be able to fail: a sampler that is off by a little (the
 * cosine sampler with sqrt(u) replaced by u^0.55, a 10 % change of the
 * exponent) must give X^2 far beyond the critical value. */
static vec3 skewed_cosine_sampler(double u1, double u2, double unused)
{
    (void)unused;
    double r = pow(u1, 0.55), phi = 2.0 * M_PI * u2;
    return v3(r * cos(phi), r * sin(phi), sqrt(fmax(0.0, 1.0 - r * r)));
}

static void test_chi2_detects_a_wrong_sampler(void)
{
    long observed[COS_BINS * PHI_BINS] = {0};
    double probability[COS_BINS * PHI_BINS];
    direction_bin_probabilities(pdf_cosine, 0.0, probability);
    for (long k = 0; k < SAMPLES; k++) {
        rng g = rng_for(112, 0, (uint64_t)k);
        double u1 = rng_uniform(&g), u2 = rng_uniform(&g);
        int bin = direction_bin(skewed_cosine_sampler(u1, u2, 0.0), 0.0);
        if (bin >= 0)
            observed[bin]++;
    }
    double x2 = 0.0;
    for (int i = 0; i < COS_BINS * PHI_BINS; i++) {
        double e = probability[i] * SAMPLES;
        x2 += (observed[i] - e) * (observed[i] - e) / e;
    }
    CHECK(x2 > 10.0 * chi2_critical(COS_BINS * PHI_BINS - 1), "a skewed sampler passed: X^2 = %.1f", x2);
    /* And the critical value itself: chi-square(80) at 1e-3 is 124.839 (tables). */
    CHECK_NEAR(chi2_critical(80), 124.839, 0.3, "Wilson-Hilferty quantile, df 80");
}

int main(void)
{
    RUN_TEST(test_cosine_hemisphere_chi2);
    RUN_TEST(test_uniform_hemisphere_chi2);
    RUN_TEST(test_uniform_sphere_chi2);
    RUN_TEST(test_cone_chi2);
    RUN_TEST(test_sphere_light_cone_chi2);
    RUN_TEST(test_sphere_light_inside_chi2);
    RUN_TEST(test_triangle_points_chi2);
    RUN_TEST(test_surface_points_chi2);
    RUN_TEST(test_chi2_detects_a_wrong_sampler);
    return CHECK_EXIT_STATUS();
}
