/* font.h — the labels' font: a TrueType font (DejaVu Sans by default)
 * rasterised by stb_truetype into an 8-bit coverage atlas at any pixel
 * height, or the built-in 8x8 bitmap font when no TrueType file is found.
 * CPU side only; gfx.c uploads the atlas and draws the quads. */
#ifndef VIEWER_FONT_H
#define VIEWER_FONT_H

#include <stddef.h>

enum { FONT_GLYPH_FIRST = 0x20, FONT_GLYPH_COUNT = 95 }; /* U+0020..U+007E */

/* Quad of one glyph: atlas coordinates (0..1) and pixel offsets from the
 * pen position on the baseline; the pen then moves by advance. */
typedef struct {
    float s0, t0, s1, t1;
    float x0, y0, x1, y1;
    float advance;
} glyph;

typedef struct {
    unsigned char *pixels; /* width x height coverage, row 0 at the top */
    int width, height;
    glyph glyphs[FONT_GLYPH_COUNT];
    float ascent;           /* pixels from the top of a line to the baseline */
    float solid_s, solid_t; /* an atlas point of full coverage (for filled rectangles) */
    char source[256];       /* the file, or "8x8 bitmap" */
} font_atlas;

#define FONT_DEFAULT_PATH "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"

/* Rasterise ttf_path at pixel_height (ascent + descent).  With a missing
 * or unreadable file: the 8x8 bitmap font, and a message in err (returns 1);
 * 0 when the TrueType font is used, 2 out of memory. */
int font_atlas_make(font_atlas *f, const char *ttf_path, float pixel_height, char *err, size_t err_size);
void font_atlas_free(font_atlas *f);

#endif
