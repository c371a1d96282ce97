/* image.h — linear RGB float images, files, tone mapping and error metrics.
 *
 * Pixels are stored row by row from the top of the image (as the camera sees
 * it); PFM files store rows from the bottom, and image_read_pfm /
 * image_write_pfm convert.
 */
#ifndef COMMON_IMAGE_H
#define COMMON_IMAGE_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "vec.h"

typedef struct {
    int width, height;
    float *pixels; /* 3 * width * height floats, RGB, top row first */
} image;

image image_new(int width, int height); /* zero-filled; pixels NULL if out of memory */
void image_free(image *img);
static inline vec3 image_get(const image *img, int x, int y)
{
    const float *p = img->pixels + 3 * ((size_t)y * (size_t)img->width + (size_t)x);
    return v3(p[0], p[1], p[2]);
}
static inline void image_set(image *img, int x, int y, vec3 c)
{
    float *p = img->pixels + 3 * ((size_t)y * (size_t)img->width + (size_t)x);
    p[0] = (float)c.x, p[1] = (float)c.y, p[2] = (float)c.z;
}

/* An output file that appears under its name only when complete: it is
 * written as "<path>.tmp.<pid>" and renamed over path by
 * atomic_file_commit(), so a crash, Ctrl-C or a full disk never leaves a
 * half-written file under the output name.  Every output of the project
 * (images, stats, meshes, tables, screenshots) goes through it. */
typedef struct {
    FILE *file;
    const char *path;
    char temporary[4200];
} atomic_file;
/* 0, or 2 with "path:0: cannot write: reason" in err. */
int atomic_file_open(atomic_file *a, const char *path, char *err, size_t err_size);
/* Close; rename into place unless `failed` or a write error occurred
 * (then the temporary is removed).  0, or 2 with a message in err. */
int atomic_file_commit(atomic_file *a, int failed, char *err, size_t err_size);

/* 8-bit RGB rows (top first) as a PNG into an open file; nonzero on failure. */
int png_write_rgb8(FILE *f, const uint8_t *rgb, int width, int height);

/* All writers are atomic: they write "<path>.tmp.<pid>" and rename it over
 * path only when complete, so a crash or a full disk never leaves a
 * half-written file under the output name.  They return 0, or 2 with a
 * one-line message in err. */
int image_write_pfm(const image *img, const char *path, char *err, size_t err_size);
/* 8-bit sRGB PNG of the image scaled by 2^exposure_stops. */
int image_write_png(const image *img, const char *path, double exposure_stops, char *err, size_t err_size);
/* Picks the format from the extension (.pfm or .png). */
int image_write(const image *img, const char *path, double exposure_stops, char *err, size_t err_size);
int image_read_pfm(const char *path, image *out, char *err, size_t err_size);

/* Tone mapping: linear radiance -> 8-bit sRGB (IEC 61966-2-1 transfer
 * curve), after multiplying by 2^exposure_stops and clamping to [0, 1]. */
uint8_t tonemap_srgb8(double linear, double exposure_stops);
double srgb_encode(double linear01);

/* Error metrics of `test` against `reference` (same size).
 * rmse: sqrt(mean over pixels and channels of (t - r)^2).
 * relmse: mean of (t - r)^2 / (r^2 + 0.01), the relative MSE used in
 *         rendering papers (the 0.01 keeps black pixels from dominating).
 * psnr: 10 log10(1 / mse) of the displayed values (clamped to [0, 1] and
 *       sRGB-encoded, as the PNG at exposure 0), peak 1: a peak taken from
 *       HDR radiance (a light of 1700) would make a bad image score high.
 * ssim: mean SSIM (Wang et al. 2004) of the tone-mapped luminance,
 *       8x8 windows, stride 4, constants K1 = 0.01, K2 = 0.03. */
typedef struct {
    double rmse, relmse, psnr, ssim;
} image_metrics;
image_metrics image_compare(const image *test, const image *reference);

/* Does the path end in ext (".png")?  Case-insensitive. */
int path_has_extension(const char *path, const char *ext);

#endif
