/* gfx.h — everything the viewer draws, on any backend's OpenGL 3.3 core context.
 *
 * Coordinates are framebuffer pixels with (0, 0) at the top-left corner (as
 * images are stored); the shaders convert.  Images live in float textures
 * whose row 0 is the top row, in linear radiance; tone mapping happens in
 * the panel shader, with the same formula as common/image.c's tonemap_srgb8
 * (2^exposure scale, clamp to [0, 1], IEC 61966-2-1 sRGB curve, rounding
 * to 8 bits by the framebuffer).
 */
#ifndef VIEWER_GFX_H
#define VIEWER_GFX_H

#include <stdbool.h>
#include <stddef.h>

#include <glad/gl.h>

typedef struct {
    int x, y, w, h;
} rect;

/* Compile the shaders and make the font atlas.  raster_shader: a file that
 * replaces the built-in Blinn-Phong fragment shader (NULL: built-in).
 * Returns 0, or 2 with "file:line: message" in err. */
int gfx_init(const char *raster_shader, const char *font_path, int font_px, char *err, size_t err_size);
const char *gfx_font(void); /* the font file in use, or "8x8 bitmap" */
void gfx_shutdown(void);
const char *gfx_renderer(void); /* GL_RENDERER, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)" */

/* An off-screen framebuffer: colour (RGBA8 for the screen image, RGBA32F
 * for a 3D panel's radiance) and depth. */
typedef struct {
    GLuint fbo, colour, depth;
    int width, height;
} target;
int target_create(target *t, int width, int height, bool float_colour, char *err, size_t err_size);
void target_destroy(target *t);

/* Start a frame on framebuffer fbo (0: the window) of size width x height. */
void gfx_begin(GLuint fbo, int width, int height);
void gfx_fill(rect r, const float rgba[4]);
/* One line of text, its top-left at (x, y), clipped to clip; the baseline
 * is gfx_text_ascent() pixels lower.  Printable ASCII only. */
void gfx_text(int x, int y, const char *text, const float rgba[4], rect clip);
int gfx_text_width(const char *text);
int gfx_text_ascent(void);

typedef enum { PANEL_RADIANCE, PANEL_HEAT, PANEL_LEGEND } panel_mode;
/* Draw image texture (w x h) inside area: image pixel (i, j) covers
 * framebuffer pixels origin + scale * [i, i+1) x [j, j+1).  PANEL_HEAT shows
 * the relative error against reference (sampled at the same relative
 * position) on a log scale 1e-3 .. 1. */
void gfx_image(rect area, GLuint texture, double origin_x, double origin_y, double scale, double exposure,
               panel_mode mode, GLuint reference);
/* The heat map's colours from 1e-3 (left end, black) to 1 (right end), a
 * decade every third of the bar. */
void gfx_heat_legend(rect bar);
/* Read the framebuffer of the last gfx_begin as 8-bit RGB, top row first. */
void gfx_read_rgb8(int width, int height, unsigned char *rgb);

/* Triangle meshes for the 3D panels.  Per vertex: position, normal, kd, ks,
 * exponent, emission (16 floats).  With unlit, the colour is the emission
 * (radiosity's per-vertex radiance). */
enum { MESH_FLOATS = 16, MAX_LIGHTS = 16 };
typedef struct {
    GLuint vao, vbo;
    int vertex_count;
} mesh;
void mesh_upload(mesh *m, const float *vertices, int vertex_count);
void mesh_destroy(mesh *m);
typedef struct {
    float view_projection[16]; /* column-major, y flipped: row 0 of the target = top of the image */
    float eye[3];
    float ambient[3];
    int light_count;
    float light_position[MAX_LIGHTS][3], light_intensity[MAX_LIGHTS][3], light_normal[MAX_LIGHTS][3];
    int light_cosine[MAX_LIGHTS]; /* 1: an emitter approximated by a point with intensity L A cos */
    bool unlit;
} mesh_uniforms;
/* Render into t (float target): linear radiance, background as clear colour. */
void mesh_draw(const mesh *m, const target *t, const mesh_uniforms *u, const float background[3]);
/* Read a float target as RGB floats, top row first. */
void target_read_rgb32f(const target *t, float *rgb);

#endif
