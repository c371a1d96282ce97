/* test_common.c — unit tests of vec.h, rng.h, sampling.h and image.c. */
#include <stdlib.h>
#include <unistd.h>

#include "../common/fast_math.h"
#include "../common/image.h"
#include "../common/options.h"
#include "../common/render.h"
#include "../common/rng.h"
#include "../common/sampling.h"
#include "../common/vec.h"
#include "check.h"

static void test_vector_algebra(void)
{
    vec3 a = v3(1, 2, 3), b = v3(-4, 5, 0.5);
    CHECK_NEAR(v3_dot(a, b), -4 + 10 + 1.5, 0, "dot");
    vec3 c = v3_cross(a, b);
    CHECK_NEAR(v3_dot(c, a), 0, 1e-12, "cross is orthogonal to a");
    CHECK_NEAR(v3_dot(c, b), 0, 1e-12, "cross is orthogonal to b");
    CHECK_NEAR(v3_length(v3_normalize(b)), 1, 1e-15, "normalize");
    vec3 r = v3_reflect(v3_normalize(v3(1, -1, 0)), v3(0, 1, 0));
    CHECK_NEAR(r.x, sqrt(0.5), 1e-15, "reflect x");
    CHECK_NEAR(r.y, sqrt(0.5), 1e-15, "reflect y");
}

static void test_orthonormal_basis(void)
{
    /* Including the normals where naive constructions break (n = -z, +-x). */
    vec3 normals[] = {{0, 0, 1}, {0, 0, -1}, {1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0.6, 0, -0.8}, {1e-9, 0, -1}};
    for (size_t i = 0; i < sizeof normals / sizeof normals[0]; i++) {
        vec3 n = v3_normalize(normals[i]);
        onb b = onb_from_normal(n);
        CHECK_NEAR(v3_length(b.tangent), 1, 1e-12, "tangent unit");
        CHECK_NEAR(v3_length(b.bitangent), 1, 1e-12, "bitangent unit");
        CHECK_NEAR(v3_dot(b.tangent, n), 0, 1e-12, "tangent orthogonal");
        CHECK_NEAR(v3_dot(b.bitangent, n), 0, 1e-12, "bitangent orthogonal");
        CHECK_NEAR(v3_dot(b.tangent, b.bitangent), 0, 1e-12, "tangent . bitangent");
        vec3 back = onb_to_local(b, onb_to_world(b, v3(0.3, -0.4, 0.5)));
        CHECK_NEAR(back.x, 0.3, 1e-12, "round trip");
    }
}

static void test_rng_is_deterministic_and_uniform(void)
{
    rng a = rng_for(7, 12345, 3), b = rng_for(7, 12345, 3), c = rng_for(7, 12346, 3);
    int same = 1, differs = 0;
    for (int i = 0; i < 100; i++) {
        double x = rng_uniform(&a), y = rng_uniform(&b), z = rng_uniform(&c);
        same &= x == y;
        differs += x != z;
    }
    CHECK(same, "the same (seed, index, sample) must give the same stream");
    CHECK(differs > 95, "neighbouring pixels must get different streams");
    /* Mean and variance of U(0,1) over 1e6 draws from many streams: mean
     * 1/2 with standard error sqrt(1/12 / n); tolerance 5 standard errors. */
    const int n = 1000000;
    double sum = 0, sum_squares = 0, lo = 1, hi = 0;
    for (int i = 0; i < n; i++) {
        rng g = rng_for(1, (uint64_t)i / 16, (uint64_t)i % 16);
        double u = rng_uniform(&g);
        sum += u, sum_squares += u * u;
        lo = fmin(lo, u), hi = fmax(hi, u);
    }
    CHECK_NEAR(sum / n, 0.5, 5 * sqrt(1.0 / 12.0 / n), "mean of U(0,1)");
    CHECK_NEAR(sum_squares / n, 1.0 / 3.0, 5 * sqrt(4.0 / 45.0 / n), "second moment of U(0,1)");
    CHECK(lo >= 0 && hi < 1, "range [0,1)");
}

/* The expectation of g(sample)/pdf must be the integral of g: check with
 * g = cos(theta) over the hemisphere (integral pi) for each sampler, using
 * 200k samples and a 5-standard-error tolerance from the sample variance. */
static void check_cosine_integral(const char *what, vec3 (*sample)(double, double), double (*pdf)(vec3))
{
    const int n = 200000;
    rng g = rng_for(3, 0, 0);
    double sum = 0, sum_squares = 0;
    for (int i = 0; i < n; i++) {
        vec3 d = sample(rng_uniform(&g), rng_uniform(&g));
        double value = d.z / pdf(d);
        sum += value, sum_squares += value * value;
    }
    double mean = sum / n, variance = sum_squares / n - mean * mean;
    CHECK_NEAR(mean, M_PI, 5 * sqrt(variance / n) + 1e-12, what);
}
static double uniform_pdf(vec3 d)
{
    (void)d;
    return uniform_hemisphere_pdf();
}
static double cosine_pdf(vec3 d) { return cosine_hemisphere_pdf(d.z); }

static void test_hemisphere_samplers_integrate_cosine(void)
{
    check_cosine_integral("uniform hemisphere", uniform_sample_hemisphere, uniform_pdf);
    check_cosine_integral("cosine hemisphere", cosine_sample_hemisphere, cosine_pdf);
    vec3 d = cosine_sample_hemisphere(0.3, 0.7);
    CHECK_NEAR(v3_length(d), 1, 1e-12, "unit direction");
}

static void test_triangle_sampler_is_uniform(void)
{
    /* Right triangle (0,0)-(1,0)-(0,1): the mean point is the centroid (1/3, 1/3),
     * and the fraction in the sub-triangle x + y < 1/2 is its area share 1/4. */
    const int n = 400000;
    rng g = rng_for(5, 0, 0);
    double sx = 0, sy = 0;
    int inside = 0;
    for (int i = 0; i < n; i++) {
        vec3 p = uniform_sample_triangle(v3(0, 0, 0), v3(1, 0, 0), v3(0, 1, 0), rng_uniform(&g), rng_uniform(&g));
        sx += p.x, sy += p.y;
        inside += p.x + p.y < 0.5;
        CHECK(p.x >= 0 && p.y >= 0 && p.x + p.y <= 1 + 1e-12, "point outside the triangle");
    }
    double se_mean = sqrt(1.0 / 18.0 / n); /* variance of x on this triangle is 1/18 */
    CHECK_NEAR(sx / n, 1.0 / 3.0, 5 * se_mean, "mean x");
    CHECK_NEAR(sy / n, 1.0 / 3.0, 5 * se_mean, "mean y");
    CHECK_NEAR((double)inside / n, 0.25, 5 * sqrt(0.25 * 0.75 / n), "area share");
    CHECK_NEAR(triangle_area(v3(0, 0, 0), v3(2, 0, 0), v3(0, 3, 0)), 3, 1e-15, "area");
}

static void test_cone_sampler_stays_in_cone(void)
{
    rng g = rng_for(9, 0, 0);
    double cos_max = cos(0.2), sum = 0;
    const int n = 100000;
    for (int i = 0; i < n; i++) {
        vec3 d = uniform_sample_cone(rng_uniform(&g), rng_uniform(&g), cos_max);
        CHECK(d.z >= cos_max - 1e-12, "direction outside the cone");
        sum += 1.0 / uniform_cone_pdf(cos_max);
    }
    CHECK_NEAR(sum / n, 2 * M_PI * (1 - cos_max), 1e-9, "solid angle of the cone");
}

/* fast_math.h's unit_circle against cos and sin in long double (64-bit
 * mantissa: 2 pi u rounds 2^11 times finer than in double), so the
 * difference is unit_circle's own error: within 3e-16, about an ulp of 1. */
static void test_unit_circle_matches_the_library(void)
{
    const long double two_pi = 6.283185307179586476925286766559L;
    const double special[] = {0.0, 1e-300, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 0x1.fffffffffffffp-1};
    rng g = rng_for(17, 0, 0);
    double worst = 0;
    for (int i = 0; i < 1000000; i++) {
        double u = i < 10 ? special[i] : rng_uniform(&g);
        circle_point p = unit_circle(u);
        double error_cos = fabs(p.cos - (double)cosl(two_pi * u)), error_sin = fabs(p.sin - (double)sinl(two_pi * u));
        worst = fmax(worst, fmax(error_cos, error_sin));
    }
    CHECK(worst <= 3e-16, "unit_circle differs from cos and sin by %g", worst);
    CHECK(unit_circle(0.25).cos == 0.0 && unit_circle(0.25).sin == 1.0, "a quarter turn is (0, 1) exactly");
}

static image test_pattern(int w, int h)
{
    image img = image_new(w, h);
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++)
            image_set(&img, x, y, v3(x + 0.25, y * 1e-3, -(x * y) - 1e20));
    return img;
}

static void test_pfm_round_trip_and_orientation(void)
{
    char path[256], err[256];
    snprintf(path, sizeof path, "/tmp/test_common_%ld.pfm", (long)getpid());
    image img = test_pattern(5, 3);
    CHECK(image_write_pfm(&img, path, err, sizeof err) == 0, "write: %s", err);
    image back;
    CHECK(image_read_pfm(path, &back, err, sizeof err) == 0, "read: %s", err);
    CHECK(back.width == 5 && back.height == 3, "size");
    CHECK(memcmp(back.pixels, img.pixels, sizeof(float) * 45) == 0, "pixels differ after a round trip");
    /* Standard PFM: header, then the BOTTOM row first, little-endian (scale -1). */
    FILE *f = fopen(path, "rb");
    char header[32] = {0};
    CHECK(fread(header, 1, 13, f) == 13 && !memcmp(header, "PF\n5 3\n-1.0\n", 12), "header '%s'", header);
    fseek(f, 12, SEEK_SET);
    unsigned char b[12];
    CHECK(fread(b, 1, 12, f) == 12, "data");
    float first_green;
    uint32_t bits = (uint32_t)b[4] | (uint32_t)b[5] << 8 | (uint32_t)b[6] << 16 | (uint32_t)b[7] << 24;
    memcpy(&first_green, &bits, 4);
    CHECK(first_green == (float)(2 * 1e-3), "first stored row must be the bottom row (y = 2), got %g", first_green);
    fclose(f);
    remove(path);
    image_free(&img);
    image_free(&back);
}

static void test_png_and_tone_mapping(void)
{
    CHECK(tonemap_srgb8(0.0, 0) == 0, "black");
    CHECK(tonemap_srgb8(1.0, 0) == 255, "white");
    CHECK(tonemap_srgb8(0.5, 0) == 188, "sRGB(0.5) = 0.7354 -> 188, got %d", tonemap_srgb8(0.5, 0));
    CHECK(tonemap_srgb8(0.25, 1) == 188, "one stop of exposure doubles");
    CHECK(tonemap_srgb8(NAN, 0) == 0 && tonemap_srgb8(-1, 0) == 0, "NaN and negatives map to black");
    image img = test_pattern(4, 4);
    char path[256], err[256];
    snprintf(path, sizeof path, "/tmp/test_common_%ld.png", (long)getpid());
    CHECK(image_write(&img, path, 0, err, sizeof err) == 0, "png: %s", err);
    FILE *f = fopen(path, "rb");
    unsigned char signature[8] = {0};
    CHECK(fread(signature, 1, 8, f) == 8 && !memcmp(signature, "\x89PNG\r\n\x1a\n", 8), "PNG signature");
    fclose(f);
    remove(path);
    image_free(&img);
}

static void test_failed_write_leaves_nothing(void)
{
    image img = test_pattern(2, 2);
    char err[256];
    CHECK(image_write(&img, "/nonexistent-directory/x.pfm", 0, err, sizeof err) == 2, "must fail");
    CHECK(strncmp(err, "/nonexistent-directory/x.pfm:0:", 31) == 0, "message '%s'", err);
    CHECK(image_write(&img, "/tmp/x.jpeg", 0, err, sizeof err) == 2, "unknown extension must fail");
    image_free(&img);
}

static void test_metrics(void)
{
    image a = image_new(16, 16), b = image_new(16, 16);
    for (int i = 0; i < 16 * 16 * 3; i++)
        a.pixels[i] = b.pixels[i] = (float)(0.5 + 0.4 * sin(i));
    image_metrics same = image_compare(&a, &b);
    CHECK(same.rmse == 0 && same.relmse == 0 && isinf(same.psnr), "identical images");
    CHECK_NEAR(same.ssim, 1, 1e-12, "ssim of identical images");
    for (int i = 0; i < 16 * 16 * 3; i++)
        b.pixels[i] += 0.1f;
    image_metrics shifted = image_compare(&b, &a);
    CHECK_NEAR(shifted.rmse, 0.1, 1e-6, "rmse of a constant offset");
    CHECK(shifted.ssim < 1 && shifted.ssim > 0.5, "ssim of a slightly brighter image: %g", shifted.ssim);
    image_free(&a);
    image_free(&b);
}

/* PSNR must not reward a bright light in the reference: an image whose
 * displayed pixels are all far off scores lower than one slightly off,
 * however bright the first reference's one light pixel is. */
static void test_psnr_is_not_fooled_by_a_bright_light(void)
{
    image bright_reference = image_new(16, 16), noisy = image_new(16, 16);
    image dim_reference = image_new(16, 16), close = image_new(16, 16);
    for (int i = 0; i < 16 * 16 * 3; i++) {
        bright_reference.pixels[i] = dim_reference.pixels[i] = 0.2f;
        noisy.pixels[i] = i % 2 ? 0.0f : 0.6f; /* every pixel far off */
        close.pixels[i] = 0.21f;               /* every pixel slightly off */
    }
    bright_reference.pixels[0] = noisy.pixels[0] = 1700.0f; /* the light, right in both */
    image_metrics worse = image_compare(&noisy, &bright_reference), better = image_compare(&close, &dim_reference);
    CHECK(worse.psnr < better.psnr, "PSNR %.1f dB of the far-off image >= %.1f dB of the close one", worse.psnr,
          better.psnr);
    double shown = srgb_encode(0.21) - srgb_encode(0.2);
    CHECK_NEAR(better.psnr, 10.0 * log10(1.0 / (shown * shown)), 1e-4, "PSNR of a uniform display offset");
    image_free(&bright_reference), image_free(&noisy), image_free(&dim_reference), image_free(&close);
}

/* An alias without a value in alias_of ("--live-time" for "--budget") takes
 * the next word as its option's value, with the option's range check; one
 * with a value ("--smooth" for "--shading smooth") takes none. */
static void test_option_aliases(void)
{
    typedef struct {
        double budget;
        int shading;
    } settings;
    static const option table[] = {
        {"--budget", "SECONDS", OPTION_DOUBLE, offsetof(settings, budget), .min = 0.01, .max = 100,
         .default_text = "30", .help = "a budget"},
        {"--live-time", "SECONDS", OPTION_DOUBLE, 0, .alias_of = "--budget"},
        {"--shading", NULL, OPTION_CHOICE, offsetof(settings, shading), .choices = "flat|smooth", .help = "shading"},
        {"--smooth", NULL, OPTION_FLAG, 0, .alias_of = "--shading smooth"},
        {0},
    };
    settings st;
    option_group group = {table, &st};
    char err[256] = "", *argv[] = {"program", "--live-time", "7.5", "--smooth", "--live-time", "1000", "--live-time"};
    int i = 1;
    CHECK(options_set_defaults(&group, 1, err, sizeof err) == 0 && st.budget == 30, "default: %s", err);
    CHECK(options_parse_one(&group, 1, 7, argv, &i, err, sizeof err) == 1 && i == 2 && st.budget == 7.5,
          "--live-time 7.5 -> budget %g, i %d: %s", st.budget, i, err);
    i = 3;
    CHECK(options_parse_one(&group, 1, 7, argv, &i, err, sizeof err) == 1 && i == 3 && st.shading == 1,
          "--smooth -> shading %d, i %d: %s", st.shading, i, err);
    i = 4;
    CHECK(options_parse_one(&group, 1, 7, argv, &i, err, sizeof err) == 2 && strstr(err, "argv:5: --budget wants"),
          "--live-time 1000 must be refused by --budget's range: %s", err);
    i = 6;
    CHECK(options_parse_one(&group, 1, 7, argv, &i, err, sizeof err) == 2 && strstr(err, "argv:6: --live-time needs"),
          "--live-time at the end needs a value: %s", err);
}

/* --bounces A:B keeps the terms K^A E .. K^B E; "A:" all from A on. */
static void test_bounce_window(void)
{
    bounce_window one_two = {1, 2}, from_two = {2, RENDER_BOUNCES_UNLIMITED};
    CHECK(!bounces_keep(one_two, 0) && bounces_keep(one_two, 1) && bounces_keep(one_two, 2) &&
              !bounces_keep(one_two, 3),
          "1:2 keeps exactly the terms 1 and 2");
    CHECK(bounces_keep(from_two, 1000) && !bounces_keep(from_two, 1), "2: keeps every term from 2 on");
    CHECK(bounces_keep_all_from(from_two, 2) && bounces_keep_all_from(from_two, 3) &&
              !bounces_keep_all_from(from_two, 1),
          "2: keeps all terms from 2 and from 3 on, not all from 1 on");
    CHECK(!bounces_keep_all_from(one_two, 2), "1:2 does not keep all terms from 2 on");
}

int main(void)
{
    RUN_TEST(test_vector_algebra);
    RUN_TEST(test_orthonormal_basis);
    RUN_TEST(test_rng_is_deterministic_and_uniform);
    RUN_TEST(test_hemisphere_samplers_integrate_cosine);
    RUN_TEST(test_triangle_sampler_is_uniform);
    RUN_TEST(test_cone_sampler_stays_in_cone);
    RUN_TEST(test_unit_circle_matches_the_library);
    RUN_TEST(test_pfm_round_trip_and_orientation);
    RUN_TEST(test_png_and_tone_mapping);
    RUN_TEST(test_failed_write_leaves_nothing);
    RUN_TEST(test_metrics);
    RUN_TEST(test_psnr_is_not_fooled_by_a_bright_light);
    RUN_TEST(test_option_aliases);
    RUN_TEST(test_bounce_window);
    return CHECK_EXIT_STATUS();
}
