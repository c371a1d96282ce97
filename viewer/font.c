/* font.c — the labels' font atlas (see font.h). */
#include "font.h"

#include <errno.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <stb/stb_truetype.h>

#include "font8x8.h"

static unsigned char *read_file(const char *path, char *err, size_t err_size)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, err_size, "%s:0: cannot open the font: %s", path, strerror(errno));
        return NULL;
    }
    unsigned char *data = NULL;
    long size = fseek(f, 0, SEEK_END) == 0 ? ftell(f) : -1;
    if (size > 0 && size < (64L << 20) && fseek(f, 0, SEEK_SET) == 0 && (data = malloc((size_t)size)) &&
        fread(data, 1, (size_t)size, f) != (size_t)size) {
        free(data);
        data = NULL;
    }
    fclose(f);
    if (!data)
        snprintf(err, err_size, "%s:0: cannot read the font", path);
    return data;
}

/* The 8x8 bitmap font: 16 x 6 cells of 8 x 8, the last one solid. */
static int bitmap_atlas(font_atlas *f)
{
    f->width = 128, f->height = 48;
    f->pixels = calloc((size_t)f->width * (size_t)f->height, 1);
    if (!f->pixels)
        return 2;
    for (int g = 0; g < 96; g++)
        for (int row = 0; row < 8; row++)
            for (int col = 0; col < 8; col++) {
                int on = g == 95 ? 1 : (font8x8[g][row] >> col) & 1;
                f->pixels[((g / 16) * 8 + row) * f->width + (g % 16) * 8 + col] = on ? 255 : 0;
            }
    for (int g = 0; g < FONT_GLYPH_COUNT; g++) {
        float s = (float)(g % 16) * 8 / 128.0f, t = (float)(g / 16) * 8 / 48.0f;
        f->glyphs[g] = (glyph){s, t, s + 8 / 128.0f, t + 8 / 48.0f, 0, -8, 8, 0, 8};
    }
    f->ascent = 8;
    f->solid_s = (15 * 8 + 4) / 128.0f, f->solid_t = (5 * 8 + 4) / 48.0f;
    snprintf(f->source, sizeof f->source, "8x8 bitmap");
    return 0;
}

/* Bake the printable ASCII range; a 2x2 solid patch in the last corner. */
static int truetype_atlas(font_atlas *f, const unsigned char *data, float pixel_height)
{
    stbtt_fontinfo info;
    if (!stbtt_InitFont(&info, data, stbtt_GetFontOffsetForIndex(data, 0)))
        return 1;
    int size = 256;
    while (size * size < pixel_height * pixel_height * 200)
        size *= 2;
    f->width = f->height = size;
    f->pixels = calloc((size_t)size * (size_t)size, 1);
    stbtt_bakedchar baked[FONT_GLYPH_COUNT];
    if (!f->pixels)
        return 2;
    int used =
        stbtt_BakeFontBitmap(data, 0, pixel_height, f->pixels, size, size, FONT_GLYPH_FIRST, FONT_GLYPH_COUNT, baked);
    if (used <= 0 || used > size - 3)
        return 1;
    for (int g = 0; g < FONT_GLYPH_COUNT; g++) {
        const stbtt_bakedchar *b = &baked[g];
        f->glyphs[g] = (glyph){(float)b->x0 / size,
                               (float)b->y0 / size,
                               (float)b->x1 / size,
                               (float)b->y1 / size,
                               b->xoff,
                               b->yoff,
                               b->xoff + (float)(b->x1 - b->x0),
                               b->yoff + (float)(b->y1 - b->y0),
                               b->xadvance};
    }
    for (int y = size - 2; y < size; y++)
        memset(f->pixels + (size_t)y * (size_t)size + size - 2, 255, 2);
    f->solid_s = f->solid_t = (size - 1.0f) / size;
    int ascent, descent, gap;
    stbtt_GetFontVMetrics(&info, &ascent, &descent, &gap);
    f->ascent = (float)ascent * stbtt_ScaleForPixelHeight(&info, pixel_height);
    return 0;
}

int font_atlas_make(font_atlas *f, const char *ttf_path, float pixel_height, char *err, size_t err_size)
{
    memset(f, 0, sizeof *f);
    unsigned char *data = ttf_path ? read_file(ttf_path, err, err_size) : NULL;
    bool readable = data != NULL;
    int status = data ? truetype_atlas(f, data, pixel_height) : 1;
    free(data);
    if (status == 0) {
        snprintf(f->source, sizeof f->source, "%s", ttf_path);
        return 0;
    }
    if (readable && status == 1)
        snprintf(err, err_size, "%s:0: not a TrueType font stb_truetype can read", ttf_path);
    font_atlas_free(f);
    if (bitmap_atlas(f))
        return 2;
    return 1;
}

void font_atlas_free(font_atlas *f)
{
    free(f->pixels);
    f->pixels = NULL;
}
