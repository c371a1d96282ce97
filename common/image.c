/* image.c — PFM and PNG files, sRGB tone mapping, error metrics. */
#include "image.h"

#include <errno.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>

image image_new(int width, int height)
{
    image img = {.width = width, .height = height, .pixels = NULL};
    if (width > 0 && height > 0)
        img.pixels = calloc((size_t)width * (size_t)height * 3, sizeof(float));
    return img;
}

void image_free(image *img)
{
    free(img->pixels);
    img->pixels = NULL;
    img->width = img->height = 0;
}

int path_has_extension(const char *path, const char *ext)
{
    size_t n = strlen(path), m = strlen(ext);
    return n >= m && strcasecmp(path + n - m, ext) == 0;
}

/* --- atomic writing -------------------------------------------------------- */

int atomic_file_open(atomic_file *a, const char *path, char *err, size_t err_size)
{
    a->path = path;
    a->file = NULL;
    if (snprintf(a->temporary, sizeof a->temporary, "%s.tmp.%ld", path, (long)getpid()) >= (int)sizeof a->temporary) {
        snprintf(err, err_size, "%s:0: output path too long", path);
        return 2;
    }
    a->file = fopen(a->temporary, "wb");
    if (!a->file) {
        snprintf(err, err_size, "%s:0: cannot write: %s", path, strerror(errno));
        return 2;
    }
    return 0;
}

int atomic_file_commit(atomic_file *a, int failed, char *err, size_t err_size)
{
    errno = 0;
    failed |= fflush(a->file) != 0;
    failed |= ferror(a->file) != 0;
    int saved_errno = errno;
    failed |= fclose(a->file) != 0;
    a->file = NULL;
    if (!saved_errno)
        saved_errno = errno;
    if (!failed && rename(a->temporary, a->path) != 0) {
        saved_errno = errno;
        failed = 1;
    }
    if (failed) {
        remove(a->temporary);
        snprintf(err, err_size, "%s:0: write failed: %s", a->path, saved_errno ? strerror(saved_errno) : "I/O error");
        return 2;
    }
    return 0;
}

typedef int (*write_body_fn)(const image *img, FILE *f, double exposure);

static int write_atomically(const image *img, const char *path, double exposure, write_body_fn body, char *err,
                            size_t err_size)
{
    atomic_file out;
    if (atomic_file_open(&out, path, err, err_size))
        return 2;
    return atomic_file_commit(&out, body(img, out.file, exposure), err, err_size);
}

/* --- PFM ------------------------------------------------------------------- */

/* PFM: "PF\n<w> <h>\n-1.0\n" then little-endian floats, rows bottom to top. */
static int pfm_body(const image *img, FILE *f, double exposure)
{
    (void)exposure;
    if (fprintf(f, "PF\n%d %d\n-1.0\n", img->width, img->height) < 0)
        return 1;
    for (int y = img->height - 1; y >= 0; y--) {
        const float *row = img->pixels + 3 * (size_t)y * (size_t)img->width;
        for (int i = 0; i < 3 * img->width; i++) {
            uint32_t bits;
            memcpy(&bits, &row[i], 4);
            unsigned char le[4] = {(unsigned char)bits, (unsigned char)(bits >> 8), (unsigned char)(bits >> 16),
                                   (unsigned char)(bits >> 24)};
            if (fwrite(le, 1, 4, f) != 4)
                return 1;
        }
    }
    return 0;
}

int image_write_pfm(const image *img, const char *path, char *err, size_t err_size)
{
    return write_atomically(img, path, 0.0, pfm_body, err, err_size);
}

int image_read_pfm(const char *path, image *out, char *err, size_t err_size)
{
    *out = (image){0};
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, err_size, "%s:0: cannot open: %s", path, strerror(errno));
        return 2;
    }
    char magic[3] = {0};
    int width = 0, height = 0;
    double scale = 0.0;
    if (fscanf(f, "%2s %d %d %lf", magic, &width, &height, &scale) != 4 || strcmp(magic, "PF") != 0 || width <= 0 ||
        height <= 0 || width > 1 << 15 || height > 1 << 15 || scale == 0.0 || fgetc(f) == EOF) {
        fclose(f);
        snprintf(err, err_size, "%s:1: not a colour PFM file (expected 'PF', size and scale)", path);
        return 2;
    }
    int little_endian = scale < 0.0;
    *out = image_new(width, height);
    if (!out->pixels) {
        fclose(f);
        snprintf(err, err_size, "%s:0: out of memory", path);
        return 2;
    }
    for (int y = height - 1; y >= 0; y--) {
        float *row = out->pixels + 3 * (size_t)y * (size_t)width;
        for (int i = 0; i < 3 * width; i++) {
            unsigned char b[4];
            if (fread(b, 1, 4, f) != 4) {
                fclose(f);
                image_free(out);
                snprintf(err, err_size, "%s:0: truncated PFM data", path);
                return 2;
            }
            uint32_t bits = little_endian
                                ? (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24
                                : (uint32_t)b[3] | (uint32_t)b[2] << 8 | (uint32_t)b[1] << 16 | (uint32_t)b[0] << 24;
            memcpy(&row[i], &bits, 4);
        }
    }
    fclose(f);
    return 0;
}

/* --- tone mapping and PNG -------------------------------------------------- */

double srgb_encode(double v)
{
    /* IEC 61966-2-1: linear segment near black, then a 1/2.4 power. */
    return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}

uint8_t tonemap_srgb8(double linear, double exposure_stops)
{
    double v = linear * exp2(exposure_stops);
    if (!(v > 0.0)) /* also catches NaN */
        return 0;
    if (v >= 1.0)
        return 255;
    return (uint8_t)lround(255.0 * srgb_encode(v));
}

int png_write_rgb8(FILE *f, const uint8_t *rgb, int width, int height)
{
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    if (!png || !info) {
        png_destroy_write_struct(&png, &info);
        return 1;
    }
    if (setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        return 1;
    }
    png_init_io(png, f);
    png_set_IHDR(png, info, (png_uint_32)width, (png_uint_32)height, 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_set_sRGB(png, info, PNG_sRGB_INTENT_PERCEPTUAL);
    png_write_info(png, info);
    for (int y = 0; y < height; y++)
        png_write_row(png, (png_const_bytep)(rgb + 3 * (size_t)y * (size_t)width));
    png_write_end(png, NULL);
    png_destroy_write_struct(&png, &info);
    return 0;
}

static int png_body(const image *img, FILE *f, double exposure)
{
    size_t n = 3 * (size_t)img->width * (size_t)img->height;
    uint8_t *rgb = malloc(n);
    if (!rgb)
        return 1;
    for (size_t i = 0; i < n; i++)
        rgb[i] = tonemap_srgb8(img->pixels[i], exposure);
    int failed = png_write_rgb8(f, rgb, img->width, img->height);
    free(rgb);
    return failed;
}

int image_write_png(const image *img, const char *path, double exposure_stops, char *err, size_t err_size)
{
    return write_atomically(img, path, exposure_stops, png_body, err, err_size);
}

int image_write(const image *img, const char *path, double exposure_stops, char *err, size_t err_size)
{
    if (path_has_extension(path, ".pfm"))
        return image_write_pfm(img, path, err, err_size);
    if (path_has_extension(path, ".png"))
        return image_write_png(img, path, exposure_stops, err, err_size);
    snprintf(err, err_size, "%s:0: unknown image format (use .pfm or .png)", path);
    return 2;
}

/* --- metrics ----------------------------------------------------------------- */

/* A channel as the PNG shows it at exposure 0: clamped to [0, 1] and
 * sRGB-encoded, so that 1 is the brightest a display can show. */
static double display_value(float linear) { return srgb_encode(fmin(fmax(linear, 0.0), 1.0)); }

/* Luminance after tone mapping to [0, 1] at exposure 0: SSIM is a
 * perceptual measure, so it compares what a person would see. */
static double display_luminance(const image *img, size_t pixel)
{
    const float *p = img->pixels + 3 * pixel;
    return v3_luminance(v3(display_value(p[0]), display_value(p[1]), display_value(p[2])));
}

static double mean_ssim(const image *a, const image *b)
{
    const int window = 8, stride = 4;
    const double c1 = 0.01 * 0.01, c2 = 0.03 * 0.03; /* (K L)^2 with dynamic range L = 1 */
    double total = 0.0;
    long windows = 0;
    for (int y0 = 0; y0 + window <= a->height; y0 += stride)
        for (int x0 = 0; x0 + window <= a->width; x0 += stride) {
            double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
            for (int y = y0; y < y0 + window; y++)
                for (int x = x0; x < x0 + window; x++) {
                    size_t i = (size_t)y * (size_t)a->width + (size_t)x;
                    double la = display_luminance(a, i), lb = display_luminance(b, i);
                    sa += la, sb += lb, saa += la * la, sbb += lb * lb, sab += la * lb;
                }
            double n = window * window;
            double ma = sa / n, mb = sb / n;
            double va = saa / n - ma * ma, vb = sbb / n - mb * mb, cov = sab / n - ma * mb;
            total += ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            windows++;
        }
    return windows ? total / (double)windows : 1.0;
}

image_metrics image_compare(const image *test, const image *reference)
{
    size_t n = (size_t)test->width * (size_t)test->height * 3;
    double squared = 0.0, relative = 0.0, display_squared = 0.0;
    for (size_t i = 0; i < n; i++) {
        double t = test->pixels[i], r = reference->pixels[i];
        double d = t - r, shown = display_value(test->pixels[i]) - display_value(reference->pixels[i]);
        squared += d * d;
        relative += d * d / (r * r + 0.01);
        display_squared += shown * shown;
    }
    double mse = squared / (double)n, display_mse = display_squared / (double)n;
    return (image_metrics){
        .rmse = sqrt(mse),
        .relmse = relative / (double)n,
        .psnr = display_mse > 0.0 ? 10.0 * log10(1.0 / display_mse) : INFINITY,
        .ssim = mean_ssim(test, reference),
    };
}
