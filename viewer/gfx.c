/* gfx.c — shaders, font, panels, meshes (see gfx.h). */
#include "gfx.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "font.h"

/* ---- shaders ------------------------------------------------------------------------------
 * Each shader is a C string, one GLSL line per C line, and remembers the C
 * line it starts on, so a compile error prints as viewer/gfx.c:LINE. */

static const int quad_vs_line = __LINE__ + 2;
static const char *quad_vs =
    "#version 330 core\n"
    "layout(location = 0) in vec4 vertex; /* x, y in pixels from the top-left; u, v */\n"
    "uniform vec2 viewport;\n"
    "out vec2 uv;\n"
    "void main() {\n"
    "    uv = vertex.zw;\n"
    "    gl_Position = vec4(2.0 * vertex.x / viewport.x - 1.0, 1.0 - 2.0 * vertex.y / viewport.y, 0.0, 1.0);\n"
    "}\n";

static const int text_fs_line = __LINE__ + 2;
static const char *text_fs = "#version 330 core\n"
                             "uniform sampler2D atlas;\n"
                             "uniform vec4 colour;\n"
                             "in vec2 uv;\n"
                             "out vec4 fragment;\n"
                             "void main() { fragment = vec4(colour.rgb, colour.a * texture(atlas, uv).r); }\n";

/* The tone map of common/image.c: v = L 2^exposure; 0 if not > 0, 1 if >= 1,
 * else the sRGB curve; the 8-bit framebuffer rounds 255 x to nearest. */
static const int panel_fs_line = __LINE__ + 2;
static const char *panel_fs =
    "#version 330 core\n"
    "uniform sampler2D image;      /* linear radiance, row 0 = top */\n"
    "uniform sampler2D reference;  /* for the heat map */\n"
    "uniform vec2 origin;          /* image's top-left corner, framebuffer pixels from the top-left */\n"
    "uniform float scale;          /* framebuffer pixels per image pixel */\n"
    "uniform vec2 viewport;\n"
    "uniform float exposure;       /* stops */\n"
    "uniform int mode;             /* 0 radiance, 1 relative error against reference, 2 legend */\n"
    "out vec4 fragment;\n"
    "float srgb(float linear) {\n"
    "    float v = linear * exp2(exposure);\n"
    "    if (!(v > 0.0)) return 0.0;\n"
    "    if (v >= 1.0) return 1.0;\n"
    "    return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;\n"
    "}\n"
    "vec3 heat(float x) { /* black, purple, red, orange, light yellow */\n"
    "    vec3 c[5] = vec3[5](vec3(0.0), vec3(0.34, 0.06, 0.43), vec3(0.80, 0.16, 0.22), vec3(0.98, 0.55, 0.04),\n"
    "                        vec3(0.99, 1.0, 0.64));\n"
    "    float s = clamp(x, 0.0, 1.0) * 4.0;\n"
    "    int i = min(int(s), 3);\n"
    "    return mix(c[i], c[i + 1], s - float(i));\n"
    "}\n"
    "void main() {\n"
    "    vec2 p = vec2(gl_FragCoord.x, viewport.y - gl_FragCoord.y);\n"
    "    if (mode == 2) { fragment = vec4(heat((p.x - origin.x) / scale), 1.0); return; } /* the legend */\n"
    "    vec2 q = (p - origin) / scale;\n"
    "    ivec2 size = textureSize(image, 0);\n"
    "    ivec2 t = ivec2(floor(q));\n"
    "    if (q.x < 0.0 || q.y < 0.0 || t.x >= size.x || t.y >= size.y) {\n"
    "        fragment = vec4(0.12, 0.12, 0.12, 1.0);\n"
    "        return;\n"
    "    }\n"
    "    vec3 L = texelFetch(image, t, 0).rgb;\n"
    "    if (mode == 1) {\n"
    "        ivec2 rs = textureSize(reference, 0);\n"
    "        ivec2 tr = clamp(ivec2(floor(q / vec2(size) * vec2(rs))), ivec2(0), rs - 1);\n"
    "        vec3 R = texelFetch(reference, tr, 0).rgb;\n"
    "        const vec3 luminance = vec3(0.2126, 0.7152, 0.0722);\n"
    "        float relative = dot(abs(L - R), luminance) / (abs(dot(R, luminance)) + 0.01);\n"
    "        fragment = vec4(heat(log(max(relative, 1e-30)) / log(10.0) / 3.0 + 1.0), 1.0);\n"
    "        return;\n"
    "    }\n"
    "    fragment = vec4(srgb(L.r), srgb(L.g), srgb(L.b), 1.0);\n"
    "}\n";

static const int mesh_vs_line = __LINE__ + 2;
static const char *mesh_vs = "#version 330 core\n"
                             "layout(location = 0) in vec3 position;\n"
                             "layout(location = 1) in vec3 normal;\n"
                             "layout(location = 2) in vec3 kd;\n"
                             "layout(location = 3) in vec3 ks;\n"
                             "layout(location = 4) in float exponent;\n"
                             "layout(location = 5) in vec3 emission;\n"
                             "uniform mat4 view_projection;\n"
                             "out vec3 P, N, Kd, Ks, Le;\n"
                             "out float n_exp;\n"
                             "void main() {\n"
                             "    P = position; N = normal; Kd = kd; Ks = ks; Le = emission; n_exp = exponent;\n"
                             "    gl_Position = view_projection * vec4(position, 1.0);\n"
                             "}\n";

/* Chapter 1's local model (chapters/01_local.c), in linear radiance:
 *   L = Le (front side of emitters) + kd La
 *     + sum over lights [kd/pi cos(theta_i) + ks (N.H)^n] I / r^2     (R1, classic Blinn)
 * shading both sides (the normal turned toward the eye), no shadows. */
static const int mesh_fs_line = __LINE__ + 2;
static const char *mesh_fs = "#version 330 core\n"
                             "const int MAX_LIGHTS = 16;\n"
                             "uniform vec3 eye;\n"
                             "uniform vec3 ambient;\n"
                             "uniform int light_count;\n"
                             "uniform vec3 light_position[MAX_LIGHTS];\n"
                             "uniform vec3 light_intensity[MAX_LIGHTS];\n"
                             "uniform vec3 light_normal[MAX_LIGHTS];\n"
                             "uniform int light_cosine[MAX_LIGHTS];\n"
                             "uniform bool unlit;\n"
                             "in vec3 P, N, Kd, Ks, Le;\n"
                             "in float n_exp;\n"
                             "out vec4 fragment;\n"
                             "const float PI = 3.14159265358979;\n"
                             "void main() {\n"
                             "    if (unlit) { fragment = vec4(Le, 1.0); return; }\n"
                             "    vec3 w_o = normalize(eye - P);\n"
                             "    vec3 n = normalize(N);\n"
                             "    bool front = dot(n, w_o) > 0.0;\n"
                             "    if (!front) n = -n;\n"
                             "    vec3 L = (front ? Le : vec3(0.0)) + Kd * ambient;\n"
                             "    for (int l = 0; l < light_count; l++) {\n"
                             "        vec3 d = light_position[l] - P;\n"
                             "        float r2 = dot(d, d);\n"
                             "        vec3 w_i = d * inversesqrt(r2);\n"
                             "        float cos_i = dot(n, w_i);\n"
                             "        if (cos_i <= 0.0) continue;\n"
                             "        vec3 I = light_intensity[l];\n"
                             "        if (light_cosine[l] != 0) {\n"
                             "            float cos_y = -dot(light_normal[l], w_i);\n"
                             "            if (cos_y <= 0.0) continue;\n"
                             "            I *= cos_y;\n"
                             "        }\n"
                             "        vec3 f = Kd * (cos_i / PI);\n"
                             "        float cos_h = dot(n, normalize(w_i + w_o));\n"
                             "        if (cos_h > 0.0) f += Ks * pow(cos_h, n_exp);\n"
                             "        L += f * I / r2;\n"
                             "    }\n"
                             "    fragment = vec4(L, 1.0);\n"
                             "}\n";

static struct {
    GLuint text_program, panel_program, mesh_program;
    GLuint atlas, vao, vbo;
    GLuint dummy_texture;
    font_atlas font;
    int width, height;
    char renderer[256];
} G;

/* Compile one shader; on failure print Mesa's "0:LINE(COL): message" as
 * "file:LINE: message" with the line counted in file. */
static GLuint compile(GLenum kind, const char *source, const char *file, int first_line, char *err, size_t err_size)
{
    GLuint shader = glCreateShader(kind);
    glShaderSource(shader, 1, &source, NULL);
    glCompileShader(shader);
    GLint ok = 0;
    glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
    if (ok)
        return shader;
    char log[4096] = "";
    glGetShaderInfoLog(shader, sizeof log, NULL, log);
    glDeleteShader(shader);
    int string_index = 0, line = 0, column = 0, consumed = 0;
    if (sscanf(log, "%d:%d(%d): %n", &string_index, &line, &column, &consumed) == 3 && consumed > 0) {
        char *end = strchr(log + consumed, '\n');
        if (end)
            *end = '\0';
        snprintf(err, err_size, "%s:%d: shader: %s", file, first_line + line - 1, log + consumed);
    } else {
        char *end = strchr(log, '\n');
        if (end)
            *end = '\0';
        snprintf(err, err_size, "%s:%d: shader: %s", file, first_line, log[0] ? log : "does not compile");
    }
    return 0;
}

static GLuint link(const char *vs, const char *vs_file, int vs_line, const char *fs, const char *fs_file, int fs_line,
                   char *err, size_t err_size)
{
    GLuint v = compile(GL_VERTEX_SHADER, vs, vs_file, vs_line, err, err_size);
    if (!v)
        return 0;
    GLuint f = compile(GL_FRAGMENT_SHADER, fs, fs_file, fs_line, err, err_size);
    if (!f) {
        glDeleteShader(v);
        return 0;
    }
    GLuint program = glCreateProgram();
    glAttachShader(program, v);
    glAttachShader(program, f);
    glLinkProgram(program);
    glDeleteShader(v);
    glDeleteShader(f);
    GLint ok = 0;
    glGetProgramiv(program, GL_LINK_STATUS, &ok);
    if (!ok) {
        char log[2048] = "";
        glGetProgramInfoLog(program, sizeof log, NULL, log);
        char *end = strchr(log, '\n');
        if (end)
            *end = '\0';
        snprintf(err, err_size, "%s:%d: shader program does not link: %s", fs_file, fs_line, log);
        glDeleteProgram(program);
        return 0;
    }
    return program;
}

static char *read_text_file(const char *path, char *err, size_t err_size)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, err_size, "%s:0: cannot open: %s", path, strerror(errno));
        return NULL;
    }
    size_t capacity = 4096, length = 0;
    char *text = malloc(capacity);
    size_t n;
    while (text && (n = fread(text + length, 1, capacity - length - 1, f)) > 0) {
        length += n;
        if (capacity - length < 2) {
            char *bigger = realloc(text, capacity *= 2);
            if (!bigger)
                free(text);
            text = bigger;
        }
    }
    fclose(f);
    if (!text) {
        snprintf(err, err_size, "%s:0: out of memory", path);
        return NULL;
    }
    text[length] = '\0';
    return text;
}

const char *gfx_renderer(void) { return G.renderer; }

/* The labels' font into G.font and the atlas texture; a missing TrueType
 * file is a warning (the 8x8 bitmap font instead), not an error. */
static int font_init(const char *font_path, int font_px, char *err, size_t err_size)
{
    char why[512] = "";
    int status = font_atlas_make(&G.font, font_path, (float)font_px, why, sizeof why);
    if (status == 2) {
        snprintf(err, err_size, "%s:%d: out of memory for the font atlas", __FILE__, __LINE__);
        return 2;
    }
    if (status == 1)
        fprintf(stderr, "warning: %s; labels in the 8x8 bitmap font\n", why);
    glGenTextures(1, &G.atlas);
    glBindTexture(GL_TEXTURE_2D, G.atlas);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_R8, G.font.width, G.font.height, 0, GL_RED, GL_UNSIGNED_BYTE, G.font.pixels);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    return 0;
}

const char *gfx_font(void) { return G.font.source; }

int gfx_init(const char *raster_shader, const char *font_path, int font_px, char *err, size_t err_size)
{
    memset(&G, 0, sizeof G);
    const GLubyte *renderer = glGetString(GL_RENDERER), *version = glGetString(GL_VERSION);
    snprintf(G.renderer, sizeof G.renderer, "%s; OpenGL %s", renderer ? (const char *)renderer : "?",
             version ? (const char *)version : "?");
    G.text_program = link(quad_vs, __FILE__, quad_vs_line, text_fs, __FILE__, text_fs_line, err, err_size);
    if (!G.text_program)
        return 2;
    G.panel_program = link(quad_vs, __FILE__, quad_vs_line, panel_fs, __FILE__, panel_fs_line, err, err_size);
    if (!G.panel_program)
        return 2;
    if (raster_shader) {
        char *source = read_text_file(raster_shader, err, err_size);
        if (!source)
            return 2;
        G.mesh_program = link(mesh_vs, __FILE__, mesh_vs_line, source, raster_shader, 1, err, err_size);
        free(source);
    } else {
        G.mesh_program = link(mesh_vs, __FILE__, mesh_vs_line, mesh_fs, __FILE__, mesh_fs_line, err, err_size);
    }
    if (!G.mesh_program)
        return 2;

    if (font_init(font_path, font_px, err, err_size))
        return 2;

    float black[3] = {0, 0, 0};
    glGenTextures(1, &G.dummy_texture);
    glBindTexture(GL_TEXTURE_2D, G.dummy_texture);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGB32F, 1, 1, 0, GL_RGB, GL_FLOAT, black);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);

    glGenVertexArrays(1, &G.vao);
    glGenBuffers(1, &G.vbo);
    glBindVertexArray(G.vao);
    glBindBuffer(GL_ARRAY_BUFFER, G.vbo);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 4, GL_FLOAT, GL_FALSE, 4 * sizeof(float), (void *)0);
    glBindVertexArray(0);
    GLenum e = glGetError();
    if (e != GL_NO_ERROR) {
        snprintf(err, err_size, "%s:%d: OpenGL error 0x%x while setting up", __FILE__, __LINE__, e);
        return 2;
    }
    return 0;
}

void gfx_shutdown(void)
{
    glDeleteProgram(G.text_program);
    glDeleteProgram(G.panel_program);
    glDeleteProgram(G.mesh_program);
    glDeleteTextures(1, &G.atlas);
    font_atlas_free(&G.font);
    glDeleteTextures(1, &G.dummy_texture);
    glDeleteBuffers(1, &G.vbo);
    glDeleteVertexArrays(1, &G.vao);
}

/* ---- off-screen targets -------------------------------------------------------------------- */

int target_create(target *t, int width, int height, bool float_colour, char *err, size_t err_size)
{
    memset(t, 0, sizeof *t);
    t->width = width, t->height = height;
    glGenTextures(1, &t->colour);
    glBindTexture(GL_TEXTURE_2D, t->colour);
    glTexImage2D(GL_TEXTURE_2D, 0, float_colour ? GL_RGBA32F : GL_RGBA8, width, height, 0, GL_RGBA,
                 float_colour ? GL_FLOAT : GL_UNSIGNED_BYTE, NULL);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glGenRenderbuffers(1, &t->depth);
    glBindRenderbuffer(GL_RENDERBUFFER, t->depth);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, width, height);
    glGenFramebuffers(1, &t->fbo);
    glBindFramebuffer(GL_FRAMEBUFFER, t->fbo);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, t->colour, 0);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, t->depth);
    GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    if (status != GL_FRAMEBUFFER_COMPLETE) {
        snprintf(err, err_size, "%s:%d: a %dx%d %s framebuffer is not complete (0x%x)", __FILE__, __LINE__, width,
                 height, float_colour ? "RGBA32F" : "RGBA8", status);
        target_destroy(t);
        return 2;
    }
    return 0;
}

void target_destroy(target *t)
{
    glDeleteFramebuffers(1, &t->fbo);
    glDeleteRenderbuffers(1, &t->depth);
    glDeleteTextures(1, &t->colour);
    memset(t, 0, sizeof *t);
}

void target_read_rgb32f(const target *t, float *rgb)
{
    glBindFramebuffer(GL_FRAMEBUFFER, t->fbo);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadPixels(0, 0, t->width, t->height, GL_RGB, GL_FLOAT, rgb);
}

/* ---- 2D drawing ---------------------------------------------------------------------------------- */

void gfx_begin(GLuint fbo, int width, int height)
{
    G.width = width, G.height = height;
    glBindFramebuffer(GL_FRAMEBUFFER, fbo);
    glViewport(0, 0, width, height);
    glDisable(GL_DEPTH_TEST);
    glDisable(GL_SCISSOR_TEST);
    glDisable(GL_BLEND);
    glClearColor(0.05f, 0.05f, 0.05f, 1.0f);
    glClear(GL_COLOR_BUFFER_BIT);
}

static void scissor(rect r)
{
    glEnable(GL_SCISSOR_TEST);
    int x0 = r.x < 0 ? 0 : r.x, y0 = r.y < 0 ? 0 : r.y;
    int x1 = r.x + r.w > G.width ? G.width : r.x + r.w, y1 = r.y + r.h > G.height ? G.height : r.y + r.h;
    glScissor(x0, G.height - y1, x1 > x0 ? x1 - x0 : 0, y1 > y0 ? y1 - y0 : 0);
}

static void draw_quads(const float *vertices, int quad_count)
{
    glBindVertexArray(G.vao);
    glBindBuffer(GL_ARRAY_BUFFER, G.vbo);
    glBufferData(GL_ARRAY_BUFFER, (GLsizeiptr)quad_count * 6 * 4 * sizeof(float), vertices, GL_STREAM_DRAW);
    glDrawArrays(GL_TRIANGLES, 0, quad_count * 6);
    glBindVertexArray(0);
}

/* Two triangles: pixel rectangle (x0, y0)-(x1, y1) with texture rectangle (u0, v0)-(u1, v1). */
static void put_quad(float *v, float x0, float y0, float x1, float y1, float u0, float v0, float u1, float v1)
{
    const float q[6][4] = {{x0, y0, u0, v0}, {x1, y0, u1, v0}, {x1, y1, u1, v1},
                           {x0, y0, u0, v0}, {x1, y1, u1, v1}, {x0, y1, u0, v1}};
    memcpy(v, q, sizeof q);
}

static void use_text_program(const float rgba[4])
{
    glUseProgram(G.text_program);
    glUniform2f(glGetUniformLocation(G.text_program, "viewport"), (float)G.width, (float)G.height);
    glUniform4fv(glGetUniformLocation(G.text_program, "colour"), 1, rgba);
    glUniform1i(glGetUniformLocation(G.text_program, "atlas"), 0);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, G.atlas);
    glEnable(GL_BLEND);
    glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
}

void gfx_fill(rect r, const float rgba[4])
{
    float v[24], u = G.font.solid_s, w = G.font.solid_t;
    put_quad(v, (float)r.x, (float)r.y, (float)(r.x + r.w), (float)(r.y + r.h), u, w, u, w);
    glDisable(GL_SCISSOR_TEST);
    use_text_program(rgba);
    draw_quads(v, 1);
    glDisable(GL_BLEND);
}

static const glyph *glyph_of(int c)
{
    return c >= FONT_GLYPH_FIRST && c < FONT_GLYPH_FIRST + FONT_GLYPH_COUNT ? &G.font.glyphs[c - FONT_GLYPH_FIRST]
                                                                            : NULL;
}

int gfx_text_width(const char *text)
{
    float pen = 0.0f;
    for (const char *c = text; *c; c++) {
        const glyph *g = glyph_of((unsigned char)*c);
        pen += g ? g->advance : 0.0f;
    }
    return (int)ceilf(pen);
}

int gfx_text_ascent(void) { return (int)ceilf(G.font.ascent); }

void gfx_text(int x, int y, const char *text, const float rgba[4], rect clip)
{
    size_t n = strlen(text);
    if (!n)
        return;
    float *v = malloc(n * 24 * sizeof(float));
    if (!v)
        return;
    int quads = 0;
    float pen = (float)x, baseline = (float)y + ceilf(G.font.ascent);
    for (size_t i = 0; i < n; i++) {
        const glyph *g = glyph_of((unsigned char)text[i]);
        if (!g)
            continue; /* anything outside printable ASCII draws nothing */
        /* whole pixels: the baked glyph is copied 1:1 (nearest sampling) */
        float x0 = floorf(pen + g->x0 + 0.5f), y0 = baseline + g->y0;
        if (g->x1 > g->x0)
            put_quad(v + 24 * quads++, x0, y0, x0 + (g->x1 - g->x0), y0 + (g->y1 - g->y0), g->s0, g->t0, g->s1, g->t1);
        pen += g->advance;
    }
    use_text_program(rgba);
    scissor(clip);
    draw_quads(v, quads);
    glDisable(GL_SCISSOR_TEST);
    glDisable(GL_BLEND);
    free(v);
}

void gfx_image(rect area, GLuint texture, double origin_x, double origin_y, double scale, double exposure,
               panel_mode mode, GLuint reference)
{
    float v[24];
    put_quad(v, (float)area.x, (float)area.y, (float)(area.x + area.w), (float)(area.y + area.h), 0, 0, 0, 0);
    GLuint p = G.panel_program;
    glUseProgram(p);
    glUniform2f(glGetUniformLocation(p, "viewport"), (float)G.width, (float)G.height);
    glUniform2f(glGetUniformLocation(p, "origin"), (float)origin_x, (float)origin_y);
    glUniform1f(glGetUniformLocation(p, "scale"), (float)scale);
    glUniform1f(glGetUniformLocation(p, "exposure"), (float)exposure);
    glUniform1i(glGetUniformLocation(p, "mode"), mode == PANEL_LEGEND ? 2 : mode == PANEL_HEAT);
    glUniform1i(glGetUniformLocation(p, "image"), 0);
    glUniform1i(glGetUniformLocation(p, "reference"), 1);
    glActiveTexture(GL_TEXTURE1);
    glBindTexture(GL_TEXTURE_2D, reference ? reference : G.dummy_texture);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, texture ? texture : G.dummy_texture);
    scissor(area);
    draw_quads(v, 1);
    glDisable(GL_SCISSOR_TEST);
}

void gfx_heat_legend(rect bar) { gfx_image(bar, 0, bar.x, bar.y, bar.w, 0.0, PANEL_LEGEND, 0); }

void gfx_read_rgb8(int width, int height, unsigned char *rgb)
{
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    unsigned char *bottom_up = malloc((size_t)width * (size_t)height * 3);
    if (!bottom_up)
        return;
    glReadPixels(0, 0, width, height, GL_RGB, GL_UNSIGNED_BYTE, bottom_up);
    for (int y = 0; y < height; y++)
        memcpy(rgb + (size_t)y * (size_t)width * 3, bottom_up + (size_t)(height - 1 - y) * (size_t)width * 3,
               (size_t)width * 3);
    free(bottom_up);
}

/* ---- meshes ------------------------------------------------------------------------------------------ */

void mesh_upload(mesh *m, const float *vertices, int vertex_count)
{
    glGenVertexArrays(1, &m->vao);
    glGenBuffers(1, &m->vbo);
    glBindVertexArray(m->vao);
    glBindBuffer(GL_ARRAY_BUFFER, m->vbo);
    glBufferData(GL_ARRAY_BUFFER, (GLsizeiptr)vertex_count * MESH_FLOATS * (GLsizeiptr)sizeof(float), vertices,
                 GL_STATIC_DRAW);
    const int sizes[6] = {3, 3, 3, 3, 1, 3};
    size_t offset = 0;
    for (int a = 0; a < 6; a++) {
        glEnableVertexAttribArray((GLuint)a);
        glVertexAttribPointer((GLuint)a, sizes[a], GL_FLOAT, GL_FALSE, MESH_FLOATS * sizeof(float),
                              (void *)(offset * sizeof(float)));
        offset += (size_t)sizes[a];
    }
    glBindVertexArray(0);
    m->vertex_count = vertex_count;
}

void mesh_destroy(mesh *m)
{
    glDeleteBuffers(1, &m->vbo);
    glDeleteVertexArrays(1, &m->vao);
    memset(m, 0, sizeof *m);
}

void mesh_draw(const mesh *m, const target *t, const mesh_uniforms *u, const float background[3])
{
    glBindFramebuffer(GL_FRAMEBUFFER, t->fbo);
    glViewport(0, 0, t->width, t->height);
    glDisable(GL_SCISSOR_TEST);
    glDisable(GL_BLEND);
    glDisable(GL_CULL_FACE);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glClearColor(background[0], background[1], background[2], 1.0f);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    GLuint p = G.mesh_program;
    glUseProgram(p);
    glUniformMatrix4fv(glGetUniformLocation(p, "view_projection"), 1, GL_FALSE, u->view_projection);
    glUniform3fv(glGetUniformLocation(p, "eye"), 1, u->eye);
    glUniform3fv(glGetUniformLocation(p, "ambient"), 1, u->ambient);
    glUniform1i(glGetUniformLocation(p, "light_count"), u->light_count);
    glUniform1i(glGetUniformLocation(p, "unlit"), u->unlit);
    if (u->light_count > 0) {
        glUniform3fv(glGetUniformLocation(p, "light_position"), u->light_count, &u->light_position[0][0]);
        glUniform3fv(glGetUniformLocation(p, "light_intensity"), u->light_count, &u->light_intensity[0][0]);
        glUniform3fv(glGetUniformLocation(p, "light_normal"), u->light_count, &u->light_normal[0][0]);
        glUniform1iv(glGetUniformLocation(p, "light_cosine"), u->light_count, u->light_cosine);
    }
    glBindVertexArray(m->vao);
    glDrawArrays(GL_TRIANGLES, 0, m->vertex_count);
    glBindVertexArray(0);
    glDisable(GL_DEPTH_TEST);
}
