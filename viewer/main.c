/* main.c — build/viewer: every method side by side, interactive and headless.
 *
 *   build/viewer A.pfm B.pfm ...            compare mode (also --scene NAME [--dir out])
 *   build/viewer --live scenes/cornell.scene  every chapter as a child process, progressive
 *   build/viewer --raster scenes/cornell-point.scene  GLSL Blinn-Phong beside chapter 1
 *   build/viewer --ply out/cornell-03_radiosity.ply  radiosity's mesh, orbitable
 *   --headless --out FILE.png --size WxH     what the window would show, without one
 *
 * Sections: options · layout · drawing a frame · input · the main loop.
 * `build/viewer --help` lists every option; key H in the window the keys.
 */
#include <ctype.h>
#include <dirent.h>
#include <errno.h>
#include <glob.h>
#include <limits.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "backend.h"
#include "font.h"
#include "viewer.h"
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

/* ---- options ------------------------------------------------------------------------------------- */

typedef enum { MODE_COMPARE, MODE_LIVE, MODE_RASTER, MODE_PLY } viewer_mode;

/* Text metrics, from --font-size PX (default 14): a line of text is PX + 4
 * pixels; a label is 3 lines (+ 4) above its image or a column 18 PX wide
 * beside it (one field a line); the status line is 1 line (+ 4). */
enum { FONT_PX_DEFAULT = 14 };
#define LINE (V.font_px + 4)
#define LABEL_BAND (3 * LINE + 4)
#define STATUS_BAND (LINE + 4)
#define LABEL_COLUMN (18 * V.font_px)

static struct {
    /* options */
    viewer_mode mode;
    backend_kind backend;
    bool backend_given, headless;
    int width, height;               /* framebuffer (window) size */
    int render_width, render_height; /* 3D panels and children; 0: fit the panel */
    const char *out_path, *screenshot_path, *panel_out_path, *raster_shader;
    const char *scene_path, *ply_path, *chapters_dir;
    const char *chapter_filter[PANEL_MAX];
    int chapter_filter_count;
    double live_time;
    int exit_after_updates, frames;
    bool no_shadows, verbose;
    double ambient;
    const char *font_path;
    int font_px;
    camera cam, scene_cam, cam_option;
    int camera_given; /* bits: 1 eye, 2 look, 4 up, 8 fov */

    /* view state */
    double exposure, zoom, cx, cy; /* zoom 1 = fit; (cx, cy): image point at the panel centre, 0..1 */
    bool diff, split, help;
    int reference, split_b; /* panel indices */
    bool reference_given;   /* by --reference, --diff, --split, 1..9 or a right click */
    double split_position;  /* 0..1 of the width */
    double mouse_x, mouse_y;
    bool cursor_given, mouse_inside;
    bool dragging, panning;
    double drag_x, drag_y;
    bool redraw, camera_moved;
    double restart_at; /* when to restart the children after the camera moved; 0 none */
    int screenshot_counter;

    /* content */
    panel panels[PANEL_MAX];
    int panel_count;
    scene scene;
    bool scene_loaded;
    mesh_uniforms uniforms;
    int aspect_w, aspect_h; /* of the images, for the layout */
    vec3 bounds_lo, bounds_hi;
    char temp_dir[PATH_LEN];
    child_spec spec;
    target screen; /* headless framebuffer */
} V;

static volatile sig_atomic_t quit_requested;
static void on_signal(int sig)
{
    (void)sig;
    quit_requested = 1;
}

static int add_file_panel(const char *path, char *err, size_t err_size)
{
    if (V.panel_count >= PANEL_MAX) {
        snprintf(err, err_size, "argv:0: at most %d panels", PANEL_MAX);
        return 2;
    }
    panel *p = &V.panels[V.panel_count];
    memset(p, 0, sizeof *p);
    p->kind = SOURCE_FILE;
    snprintf(p->path, sizeof p->path, "%s", path);
    V.panel_count++;
    return 0;
}

/* DIR/NAME-NN_*.pfm, sorted: the chapters' outputs for one scene. */
static int add_scene_panels(const char *name, const char *dir, int arg, char *err, size_t err_size)
{
    char pattern[PATH_LEN];
    snprintf(pattern, sizeof pattern, "%s/%s-[0-9]*.pfm", dir, name);
    glob_t g;
    int found = glob(pattern, 0, NULL, &g);
    if (found != 0) {
        snprintf(err, err_size, "argv:%d: no %.900s (render the scene with the chapters first, e.g. make demo)", arg,
                 pattern);
        return 2;
    }
    int status = 0;
    for (size_t i = 0; i < g.gl_pathc && !status; i++)
        status = add_file_panel(g.gl_pathv[i], err, err_size);
    globfree(&g);
    return status;
}

/* ---- the option table ----------------------------------------------------------------------------
 * One table: the parser reads it and `build/viewer --help` prints it.  Most
 * options store into a field of V (a flag, a string, a number in a range);
 * the others have a handler. */

typedef enum { OPT_SECTION, OPT_DOC, OPT_FLAG, OPT_STRING, OPT_NUMBER, OPT_INT, OPT_CUSTOM } option_kind;

typedef int option_handler(const char *name, const char *value, int arg, char *err, size_t err_size);

typedef struct {
    const char *name, *alias; /* alias: the same option under an older name */
    const char *value;        /* what follows it, as shown ("WxH"); NULL: a flag */
    option_kind kind;
    void *target;           /* bool *, const char **, double *, int * */
    double lo, hi;          /* OPT_NUMBER, OPT_INT */
    option_handler *handle; /* OPT_CUSTOM */
    const char *help;       /* '\n' starts an indented continuation line */
} option;

static struct {
    const char *scene_name, *dir;
    int scene_arg;
} compare_args = {NULL, "out", 0};

static int bad(char *err, size_t err_size, int i, const char *what, const char *value)
{
    snprintf(err, err_size, "argv:%d: %s%s%s%s", i, what, value ? " '" : "", value ? value : "", value ? "'" : "");
    return 2;
}

static bool parse_size(const char *s, int *w, int *h)
{
    char tail;
    return s && sscanf(s, "%dx%d%c", w, h, &tail) == 2 && *w > 0 && *h > 0 && *w <= 16384 && *h <= 16384;
}

static bool parse_vec(const char *s, vec3 *v)
{
    char tail;
    return s && sscanf(s, "%lf,%lf,%lf%c", &v->x, &v->y, &v->z, &tail) == 3 && v3_is_finite(*v);
}

static bool parse_number(const char *s, double lo, double hi, double *out)
{
    if (!s)
        return false;
    char *end;
    double v = strtod(s, &end);
    if (end == s || *end || !(v >= lo && v <= hi))
        return false;
    *out = v;
    return true;
}

static bool parse_panel_number(const char *s, int *index)
{
    double n;
    if (!parse_number(s, 1, PANEL_MAX, &n) || n != floor(n))
        return false;
    *index = (int)n - 1;
    return true;
}

static void usage(void);
static void print_keys_markdown(void);

static int opt_help(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    (void)value, (void)arg, (void)err, (void)err_size;
    if (!strcmp(name, "--help-keys"))
        print_keys_markdown();
    else
        usage();
    exit(0);
}

static int opt_backend(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    if (!backend_parse(value, &V.backend))
        return bad(err, err_size, arg, "--backend wants glfw, egl or osmesa, not", value);
    (void)name, V.backend_given = true;
    return 0;
}

static int opt_size(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    bool window = !strcmp(name, "--size");
    if (!parse_size(value, window ? &V.width : &V.render_width, window ? &V.height : &V.render_height))
        return bad(err, err_size, arg, window ? "--size wants WxH, not" : "--render-size wants WxH, not", value);
    return 0;
}

static int opt_mode(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    (void)arg, (void)err, (void)err_size;
    V.mode = name[2] == 'l' ? MODE_LIVE : name[2] == 'r' ? MODE_RASTER : MODE_PLY;
    if (V.mode == MODE_PLY)
        V.ply_path = value;
    else
        V.scene_path = value;
    return 0;
}

static int opt_scene(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    (void)name, (void)err, (void)err_size;
    compare_args.scene_name = value, compare_args.scene_arg = arg;
    return 0;
}

static int opt_reference(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    if (!parse_panel_number(value, &V.reference))
        return bad(err, err_size, arg,
                   !strcmp(name, "--diff") ? "--diff wants a panel number, not"
                                           : "--reference wants a panel number, not",
                   value);
    V.reference_given = true;
    V.diff |= !strcmp(name, "--diff");
    return 0;
}

static int opt_split(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    int pa, pb;
    double pos = 0.5;
    char tail;
    int n = sscanf(value, "%d,%d,%lf%c", &pa, &pb, &pos, &tail);
    if ((n != 2 && n != 3) || pa < 1 || pb < 1 || pa > PANEL_MAX || pb > PANEL_MAX || !(pos >= 0 && pos <= 1))
        return bad(err, err_size, arg, "--split wants A,B[,POS] (panel numbers, 0 <= POS <= 1), not", value);
    (void)name;
    V.split = true, V.reference = pa - 1, V.split_b = pb - 1, V.split_position = pos, V.reference_given = true;
    return 0;
}

static int opt_point(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    char tail;
    bool centre = !strcmp(name, "--center");
    double *x = centre ? &V.cx : &V.mouse_x, *y = centre ? &V.cy : &V.mouse_y;
    if (sscanf(value, "%lf,%lf%c", x, y, &tail) != 2 || !isfinite(*x) || !isfinite(*y))
        return bad(err, err_size, arg, centre ? "--center wants U,V, not" : "--cursor wants X,Y in pixels, not", value);
    if (!centre)
        V.cursor_given = V.mouse_inside = true;
    return 0;
}

static int opt_camera(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    vec3 v;
    if (!strcmp(name, "--fov")) {
        if (!parse_number(value, 1e-3, 179, &V.cam_option.fov_degrees))
            return bad(err, err_size, arg, "--fov wants degrees in (0, 179], not", value);
        V.camera_given |= 8;
        return 0;
    }
    if (!parse_vec(value, &v))
        return bad(err, err_size, arg, "wants X,Y,Z, not", value);
    if (name[2] == 'e')
        V.cam_option.eye = v, V.camera_given |= 1;
    else if (name[2] == 'l')
        V.cam_option.look = v, V.camera_given |= 2;
    else
        V.cam_option.up = v, V.camera_given |= 4;
    return 0;
}

static int opt_chapter(const char *name, const char *value, int arg, char *err, size_t err_size)
{
    (void)name, (void)arg, (void)err, (void)err_size;
    if (V.chapter_filter_count < PANEL_MAX)
        V.chapter_filter[V.chapter_filter_count++] = value;
    return 0;
}

#define SECTION(title)                                                                                                 \
    {                                                                                                                  \
        NULL, NULL, NULL, OPT_SECTION, NULL, 0, 0, NULL, title                                                         \
    }
#define FLAG(name, field, help)                                                                                        \
    {                                                                                                                  \
        name, NULL, NULL, OPT_FLAG, &V.field, 0, 0, NULL, help                                                         \
    }
#define STRING(name, value, field, help)                                                                               \
    {                                                                                                                  \
        name, NULL, value, OPT_STRING, &V.field, 0, 0, NULL, help                                                      \
    }
#define NUMBER(name, value, field, lo, hi, help)                                                                       \
    {                                                                                                                  \
        name, NULL, value, OPT_NUMBER, &V.field, lo, hi, NULL, help                                                    \
    }
#define INT(name, value, field, lo, hi, help)                                                                          \
    {                                                                                                                  \
        name, NULL, value, OPT_INT, &V.field, lo, hi, NULL, help                                                       \
    }
#define CUSTOM(name, value, handler, help)                                                                             \
    {                                                                                                                  \
        name, NULL, value, OPT_CUSTOM, NULL, 0, 0, handler, help                                                       \
    }

static const option OPTIONS[] = {
    SECTION("modes:"),
    {"A.pfm B.pfm ...", NULL, NULL, OPT_DOC, NULL, 0, 0, NULL,
     "compare: the images in a grid, with the stats JSON beside each (same name .json)"},
    CUSTOM("--scene", "NAME", opt_scene, "compare DIR/NAME-NN_*.pfm (DIR: --dir, default out)"),
    {"--dir", NULL, "DIR", OPT_STRING, &compare_args.dir, 0, 0, NULL, "where --scene looks (default out)"},
    CUSTOM("--live", "SCENE", opt_mode,
           "run every chapter (build/0*_*) as a child with the viewer's camera and show\n"
           "its progressive images; orbiting restarts them.  A GLSL raster is panel 1."),
    CUSTOM("--raster", "SCENE", opt_mode,
           "the scene rasterised by a GLSL Blinn-Phong shader (chapter 1's local model,\n"
           "no shadows) beside chapter 1's ray-cast image of the same camera"),
    CUSTOM("--ply", "FILE.ply", opt_mode, "radiosity's mesh with smooth per-vertex radiance, orbitable"),
    SECTION("display:"),
    CUSTOM("--backend", "glfw|egl|osmesa", opt_backend, "context (default glfw with a display, else egl, else osmesa)"),
    FLAG("--headless", headless, "no window (egl or osmesa); needs --out or --frames"),
    CUSTOM("--size", "WxH", opt_size, "window / framebuffer size (default 1280x720)"),
    CUSTOM("--render-size", "WxH", opt_size, "size of 3D panels and children's images (default: fit the panel)"),
    STRING("--out", "FILE.png|.ppm", out_path, "write what the window shows (headless: the first complete frame)"),
    STRING("--screenshot", "FILE", screenshot_path, "in a window: save the first complete frame there and exit"),
    STRING("--panel-out", "FILE.pfm", panel_out_path,
           "write panel 1's linear radiance (the GLSL raster, the PLY view ...)"),
    NUMBER("--exposure", "STOPS", exposure, -64, 64, "shared exposure (as the chapters' --exposure)"),
    CUSTOM("--diff", "N", opt_reference, "error heat map of every panel against panel N"),
    FLAG("--heat", diff, "error heat map against the default reference (the best image: see below)"),
    CUSTOM("--reference", "N", opt_reference, "the reference panel for the heat map and the split (default: the best)"),
    CUSTOM("--split", "A,B[,POS]", opt_split, "A/B split slider between panels A and B at POS (0..1, default 0.5)"),
    NUMBER("--zoom", "Z", zoom, 1e-3, 1e4, "shared zoom (1 = fit)"),
    CUSTOM("--center", "U,V", opt_point, "image point (0..1) at the panel centres"),
    CUSTOM("--cursor", "X,Y", opt_point, "cursor position in pixels (shows the radiance under it in every panel)"),
    FLAG("--help-overlay", help, "show the key help"),
    CUSTOM("--help-keys", NULL, opt_help, "print the keys (and mouse) as a Markdown table and exit"),
    INT("--frames", "N", frames, 1, 1e6, "render N frames, print frames per second and exit"),
    STRING("--font", "FILE.ttf", font_path,
           "the labels' font (default " FONT_DEFAULT_PATH ";\n"
           "missing: the 8x8 bitmap font)"),
    INT("--font-size", "PX", font_px, 6, 96, "its pixel height (default 14); the layout below scales with it"),
    CUSTOM("--help", NULL, opt_help, "this list (also -h)"),
    SECTION("3D and live:"),
    CUSTOM("--eye", "X,Y,Z", opt_camera, "camera position (default: the scene's camera)"),
    CUSTOM("--look", "X,Y,Z", opt_camera, "the point looked at"),
    CUSTOM("--up", "X,Y,Z", opt_camera, "the up direction"),
    CUSTOM("--fov", "DEG", opt_camera, "vertical field of view"),
    CUSTOM("--chapter", "NAME", opt_chapter, "only this chapter (repeatable)"),
    STRING("--chapters", "DIR", chapters_dir, "where the chapters are (default: beside the viewer)"),
    {"--budget", "--live-time", "SECONDS", OPT_NUMBER, &V.live_time, 0.01, 1e6, NULL,
     "each child's --time per camera (default 30: the path tracer converged\n"
     "enough to judge); --live-time is the same"},
    INT("--exit-after-updates", "N", exit_after_updates, 1, 1e6,
        "headless live: stop after N updates of every chapter"),
    FLAG("--no-shadows", no_shadows, "chapter 1's option, for the raster and passed to 01_local"),
    NUMBER("--ambient", "LA", ambient, 0, 1e6, "chapter 1's ambient radiance, likewise"),
    STRING("--raster-shader", "FILE.frag", raster_shader, "replace the built-in Blinn-Phong fragment shader"),
    FLAG("--verbose", verbose, "print the layout, every update and (window) every camera move"),
};
enum { OPTION_COUNT = sizeof OPTIONS / sizeof *OPTIONS };

static void usage(void)
{
    printf("usage: build/viewer [A.pfm B.pfm ...] [--scene NAME [--dir DIR]]\n"
           "                    [--live SCENE | --raster SCENE | --ply FILE.ply] [options]\n");
    for (int k = 0; k < OPTION_COUNT; k++) {
        const option *o = &OPTIONS[k];
        if (o->kind == OPT_SECTION) {
            printf("%s\n", o->help);
            continue;
        }
        char head[64];
        snprintf(head, sizeof head, "%s%s%s", o->name, o->value ? " " : "", o->value ? o->value : "");
        printf(strlen(head) > 20 ? "  %s  " : "  %-20s ", head);
        for (const char *line = o->help;;) {
            const char *end = strchr(line, '\n');
            printf("%.*s\n", end ? (int)(end - line) : (int)strlen(line), line);
            if (!end)
                break;
            printf("%23s", "");
            line = end + 1;
        }
    }
    printf("Layout: the bottom %d pixels of the window are the status line (font size + 8).  Above it a grid of\n"
           "n panels: the columns (rows = ceil(n / columns)) and the label's place -- a band of %d pixels above\n"
           "the image (3 lines of font size + 4, + 4) or a column of %d pixels (18 x font size) on its left --\n"
           "that make panel 1's image the largest in the nominal cell (width / columns x height / rows, rounded\n"
           "down); ties keep fewer columns and the label above.  The image is scaled to fit the rest of its\n"
           "cell (zoom 1), centred, its corner on a whole pixel, nearest-neighbour sampled.\n"
           "Default reference: the lowest stats relmse; else a path tracer over all bounces with the most\n"
           "samples (then mis > light > cosine > hemisphere); else the most samples; else panel 1.\n"
           "Exit status: 0, 2 bad input or shader error (file:line: message), 3 no such backend here.\n",
           STATUS_BAND, LABEL_BAND, LABEL_COLUMN);
}

static const option *find_option(const char *name)
{
    if (!strcmp(name, "-h"))
        name = "--help";
    for (int k = 0; k < OPTION_COUNT; k++)
        if (OPTIONS[k].name && OPTIONS[k].kind != OPT_DOC &&
            (!strcmp(OPTIONS[k].name, name) || (OPTIONS[k].alias && !strcmp(OPTIONS[k].alias, name))))
            return &OPTIONS[k];
    return NULL;
}

/* One option of the table with its value (NULL for a flag). */
static int apply_option(const option *o, const char *name, const char *value, int arg, char *err, size_t err_size)
{
    double x;
    char what[160];
    switch (o->kind) {
    case OPT_FLAG: *(bool *)o->target = true; return 0;
    case OPT_STRING: *(const char **)o->target = value; return 0;
    case OPT_CUSTOM: return o->handle(name, value, arg, err, err_size);
    case OPT_NUMBER:
    case OPT_INT:
        if (parse_number(value, o->lo, o->hi, &x) && (o->kind == OPT_NUMBER || x == floor(x))) {
            if (o->kind == OPT_NUMBER)
                *(double *)o->target = x;
            else
                *(int *)o->target = (int)x;
            return 0;
        }
        snprintf(what, sizeof what, "%s wants %s%s in [%g, %g], not", name, o->kind == OPT_INT ? "a whole " : "",
                 o->value, o->lo, o->hi);
        return bad(err, err_size, arg, what, value);
    default: return 0;
    }
}

static int check_options(char *err, size_t err_size);

static int parse_options(int argc, char **argv, char *err, size_t err_size)
{
    V.width = 1280, V.height = 720;
    V.zoom = 1.0, V.cx = V.cy = 0.5;
    V.live_time = 30.0;
    V.font_path = FONT_DEFAULT_PATH, V.font_px = FONT_PX_DEFAULT;
    V.split_position = 0.5;
    V.reference = 0, V.split_b = 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (a[0] != '-' || !a[1]) {
            if (add_file_panel(a, err, err_size))
                return 2;
            continue;
        }
        const option *o = find_option(a);
        if (!o)
            return bad(err, err_size, i, "unknown option", a);
        const char *value = NULL;
        if (o->value) {
            if (i + 1 >= argc)
                return bad(err, err_size, i, "missing value after", a);
            value = argv[++i];
        }
        if (apply_option(o, a, value, i, err, err_size))
            return 2;
    }
    return check_options(err, err_size);
}

static int check_options(char *err, size_t err_size)
{
    if (compare_args.scene_name &&
        add_scene_panels(compare_args.scene_name, compare_args.dir, compare_args.scene_arg, err, err_size))
        return 2;
    if (V.mode != MODE_COMPARE && V.panel_count)
        return bad(err, err_size, 0, "image files and --live/--raster/--ply do not mix", NULL);
    if (V.mode == MODE_COMPARE && !V.panel_count) {
        usage();
        return bad(err, err_size, 0, "nothing to show: give PFM files, --scene, --live, --raster or --ply", NULL);
    }
    if (V.headless && V.backend_given && V.backend == BACKEND_GLFW)
        return bad(err, err_size, 0, "--headless needs --backend egl or osmesa", NULL);
    if (V.headless && !V.out_path && !V.frames && !V.panel_out_path && !V.exit_after_updates)
        return bad(err, err_size, 0, "--headless needs --out FILE.png (or --frames N)", NULL);
    if (V.out_path && !path_has_extension(V.out_path, ".png") && !path_has_extension(V.out_path, ".ppm"))
        return bad(err, err_size, 0, "--out wants a .png or .ppm file, not", V.out_path);
    if (V.panel_out_path && !path_has_extension(V.panel_out_path, ".pfm"))
        return bad(err, err_size, 0, "--panel-out wants a .pfm file, not", V.panel_out_path);
    return 0;
}

/* ---- writing the screen ---------------------------------------------------------------------- */

static int write_rgb8(const char *path, int w, int h, const unsigned char *rgb, char *err, size_t err_size)
{
    atomic_file out;
    if (atomic_file_open(&out, path, err, err_size))
        return 2;
    int failed;
    if (path_has_extension(path, ".ppm")) {
        fprintf(out.file, "P6\n%d %d\n255\n", w, h);
        failed = fwrite(rgb, 3, (size_t)w * (size_t)h, out.file) != (size_t)w * (size_t)h;
    } else {
        failed = png_write_rgb8(out.file, rgb, w, h);
    }
    return atomic_file_commit(&out, failed, err, err_size);
}

/* ---- layout ------------------------------------------------------------------------------------ */

/* The grid: the columns (rows follow) and the label's place (above the
 * image, or a column beside it) that make the images largest for their
 * aspect ratio, judged on the nominal cell (width / cols, height / rows,
 * rounded down); ties keep fewer columns, and the label above. */
typedef struct {
    int cols, rows;
    bool beside;
} grid;

static double fitted_height(int area_w, int area_h)
{
    if (area_w < 1 || area_h < 1)
        return 0.0;
    return fmin((double)area_w * V.aspect_h / V.aspect_w, (double)area_h);
}

static grid choose_grid(int n, int width, int height)
{
    grid best = {1, n > 0 ? n : 1, false};
    double best_h = -1.0;
    for (int cols = 1; cols <= (n > 0 ? n : 1); cols++) {
        int rows = (n + cols - 1) / cols, cw = width / cols, ch = (height - STATUS_BAND) / (rows > 0 ? rows : 1);
        double above = fitted_height(cw, ch - LABEL_BAND), beside = fitted_height(cw - LABEL_COLUMN, ch);
        if (above > best_h)
            best = (grid){cols, rows, false}, best_h = above;
        if (beside > best_h)
            best = (grid){cols, rows, true}, best_h = beside;
    }
    return best;
}

/* Panel i of n: its whole cell, its label and its image area. */
static void panel_rects(int i, int n, int width, int height, rect *whole, rect *label, rect *area)
{
    grid g = choose_grid(n, width, height);
    int c = i % g.cols, r = i / g.cols;
    height -= STATUS_BAND;
    whole->x = c * width / g.cols, whole->w = (c + 1) * width / g.cols - whole->x;
    whole->y = r * height / g.rows, whole->h = (r + 1) * height / g.rows - whole->y;
    if (g.beside) {
        *label = (rect){whole->x, whole->y, LABEL_COLUMN, whole->h};
        *area = (rect){whole->x + LABEL_COLUMN, whole->y, whole->w - LABEL_COLUMN, whole->h};
    } else {
        *label = (rect){whole->x, whole->y, whole->w, LABEL_BAND};
        *area = (rect){whole->x, whole->y + LABEL_BAND, whole->w, whole->h - LABEL_BAND};
    }
    area->w = area->w < 1 ? 1 : area->w, area->h = area->h < 1 ? 1 : area->h;
}

static int shown_panels(void) { return V.split ? 1 : V.panel_count; }

/* Where panel p's image sits in area: framebuffer pixel = origin + scale * image pixel. */
static void placement(const panel *p, rect area, double *ox, double *oy, double *scale)
{
    int iw = p->img.width > 0 ? p->img.width : area.w, ih = p->img.height > 0 ? p->img.height : area.h;
    *scale = fmin((double)area.w / iw, (double)area.h / ih) * V.zoom;
    *ox = floor(area.x + area.w / 2.0 - V.cx * iw * *scale + 0.5);
    *oy = floor(area.y + area.h / 2.0 - V.cy * ih * *scale + 0.5);
}

/* The panel under framebuffer point (x, y) and the image point there (0..1); -1 if none. */
static int panel_at(double x, double y, double *u, double *v)
{
    int W = V.width, H = V.height, n = shown_panels();
    for (int i = 0; i < n; i++) {
        rect whole, label, area;
        panel_rects(i, n, W, H, &whole, &label, &area);
        if (x < area.x || y < area.y || x >= area.x + area.w || y >= area.y + area.h)
            continue;
        int index = V.split ? (x < W * V.split_position ? V.reference : V.split_b) : i;
        const panel *p = &V.panels[index];
        if (!p->img.pixels)
            return -1;
        double ox, oy, s;
        placement(p, area, &ox, &oy, &s);
        *u = (x - ox) / s / p->img.width, *v = (y - oy) / s / p->img.height;
        return index;
    }
    return -1;
}

/* ---- drawing a frame ------------------------------------------------------------------------- */

static const float WHITE[4] = {0.95f, 0.95f, 0.95f, 1.0f}, GREY[4] = {0.7f, 0.7f, 0.7f, 1.0f},
                   YELLOW[4] = {1.0f, 0.85f, 0.3f, 1.0f}, BAND[4] = {0.08f, 0.08f, 0.1f, 1.0f},
                   ORANGE[4] = {1.0f, 0.45f, 0.2f, 1.0f}, DIM[4] = {0.0f, 0.0f, 0.0f, 0.65f};

/* The relative MSE of a against b, as the chapters' --ref computes it (common/image.c). */
static double relmse_against(const panel *a, const panel *b)
{
    if (!a->img.pixels || !b->img.pixels || a->img.width != b->img.width || a->img.height != b->img.height)
        return NAN;
    size_t n = (size_t)a->img.width * (size_t)a->img.height * 3;
    double sum = 0.0;
    for (size_t k = 0; k < n; k++) {
        double d = (double)a->img.pixels[k] - b->img.pixels[k], r = b->img.pixels[k];
        sum += d * d / (r * r + 0.01);
    }
    return sum / (double)n;
}

/* What a panel is, in its label: line 1 "[N] chapter  variant" (the
 * estimator, solver, model and bounces from the stats JSON), line 2 the
 * numbers (samples or patches, seconds, error) and the file name. */
static void label_lines(int index, char *title, size_t title_size, char *numbers, size_t numbers_size)
{
    const panel *p = &V.panels[index];
    snprintf(title, title_size, "[%d] %s%s%s", index + 1, p->method, p->variant[0] ? "  " : "", p->variant);
    if (p->kind == SOURCE_CHILD)
        snprintf(numbers, numbers_size, "%s  updates %d", p->detail, p->updates);
    else
        snprintf(numbers, numbers_size, "%s%s%s", p->detail, p->file[0] ? "  " : "", p->file);
}

/* Label line 3: the radiance under the pointer (at the same image point
 * in every panel), or with the heat map the error against the reference. */
static void readout_line(int index, char *line, size_t line_size)
{
    const panel *p = &V.panels[index];
    double u, v;
    line[0] = '\0';
    if (p->warning[0]) { /* a child's warning: more than anything else */
        snprintf(line, line_size, "%s%s", p->warnings > 1 ? "(+more) " : "", p->warning);
        return;
    }
    int under = V.mouse_inside ? panel_at(V.mouse_x, V.mouse_y, &u, &v) : -1;
    if (under >= 0 && p->img.pixels && u >= 0 && v >= 0 && u < 1 && v < 1) {
        int x = (int)floor(u * p->img.width), y = (int)floor(v * p->img.height);
        vec3 c = image_get(&p->img, x, y);
        snprintf(line, line_size, "(%d,%d) %.4g %.4g %.4g", x, y, c.x, c.y, c.z);
    } else if (V.diff && !V.split && index != V.reference && V.reference < V.panel_count) {
        snprintf(line, line_size, "heat vs [%d]  rel.MSE %.3g", V.reference + 1,
                 relmse_against(p, &V.panels[V.reference]));
    }
}

/* Above the image: 3 lines.  Beside it: every field (the parts of a line
 * between double spaces) on a line of its own, so nothing is clipped. */
static void draw_label(int index, rect label, bool beside, const char *title_suffix)
{
    gfx_fill(label, BAND);
    char title[256], numbers[256], lines[3][512];
    label_lines(index, title, sizeof title, numbers, sizeof numbers);
    snprintf(lines[0], sizeof lines[0], "%s%s", title, title_suffix);
    snprintf(lines[1], sizeof lines[1], "%s", numbers);
    readout_line(index, lines[2], sizeof lines[2]);
    const float *colours[3] = {WHITE, GREY, V.panels[index].warning[0] ? ORANGE : YELLOW};
    int y = label.y + 2;
    for (int k = 0; k < 3; k++) {
        char *field = lines[k], *next;
        do {
            next = beside ? strstr(field, "  ") : NULL;
            if (next)
                *next = '\0', next += 2;
            if (*field || !beside)
                gfx_text(label.x + 4, y, field, colours[k], label), y += LINE;
            field = next;
        } while (field);
    }
}

static void draw_help(int width, int height);

/* The status line, the bottom STATUS_BAND pixels whatever the mouse does:
 * with the heat map its reference and its colour legend (1e-3 black at the
 * left end .. 1 at the right, a tick at every decade); then the exposure,
 * the zoom and the help hint. */
static void draw_status(int width, int height)
{
    rect band = {0, height - STATUS_BAND, width, STATUS_BAND};
    gfx_fill(band, BAND);
    int x = 4, y = band.y + (STATUS_BAND - LINE) / 2 + 2;
    char line[256];
    if (V.diff && !V.split && V.reference < V.panel_count) {
        snprintf(line, sizeof line, "heat vs [%d]  1e-3", V.reference + 1);
        gfx_text(x, y, line, YELLOW, band);
        rect bar = {x + gfx_text_width(line) + 6, band.y + 4, 10 * V.font_px, STATUS_BAND - 8};
        gfx_heat_legend(bar);
        for (int k = 1; k < 3; k++)
            gfx_fill((rect){bar.x + k * bar.w / 3, bar.y + bar.h - 3, 1, 3}, WHITE);
        gfx_text(bar.x + bar.w + 6, y, "1", YELLOW, band);
        x = bar.x + bar.w + 6 + 3 * V.font_px;
    }
    snprintf(line, sizeof line, "exposure %+.1f  zoom %.2fx  H: help", V.exposure, V.zoom);
    gfx_text(x, y, line, YELLOW, band);
}

static void draw_frame(GLuint fbo, int width, int height)
{
    V.width = width, V.height = height;
    gfx_begin(fbo, width, height);
    int n = shown_panels();
    bool beside = choose_grid(n, width, height).beside;
    for (int i = 0; i < n; i++) {
        rect whole, label, area;
        panel_rects(i, n, width, height, &whole, &label, &area);
        if (V.split) {
            panel *a = &V.panels[V.reference], *b = &V.panels[V.split_b];
            int split_x = (int)lround(width * V.split_position);
            rect left = {area.x, area.y, split_x - area.x, area.h},
                 right = {split_x, area.y, area.x + area.w - split_x, area.h};
            double ox, oy, s;
            placement(a, area, &ox, &oy, &s);
            gfx_image(left, a->texture, ox, oy, s, V.exposure, PANEL_RADIANCE, 0);
            placement(b, area, &ox, &oy, &s);
            gfx_image(right, b->texture, ox, oy, s, V.exposure, PANEL_RADIANCE, 0);
            gfx_fill((rect){split_x, area.y, 1, area.h}, WHITE);
            char suffix[160];
            snprintf(suffix, sizeof suffix, "  |  [%d] %s", V.split_b + 1, b->method);
            draw_label(V.reference, label, beside, suffix);
            continue;
        }
        panel *p = &V.panels[i];
        double ox, oy, s;
        placement(p, area, &ox, &oy, &s);
        bool heat = V.diff && i != V.reference && V.reference < V.panel_count;
        if (p->img.pixels || p->kind == SOURCE_RASTER || p->kind == SOURCE_PLY)
            gfx_image(area, p->texture, ox, oy, s, V.exposure, heat ? PANEL_HEAT : PANEL_RADIANCE,
                      heat ? V.panels[V.reference].texture : 0);
        else
            gfx_text(area.x + 8, area.y + 8, p->pid > 0 ? "waiting for the first image ..." : "no image", GREY, area);
        if (p->stale) { /* restarted: the old camera's image, dimmed, until the first new pass */
            gfx_fill(area, DIM);
            gfx_text(area.x + 8, area.y + 8, "restarting ...", WHITE, area);
        }
        draw_label(i, label, beside, p->stale ? "  (restarting)" : V.diff && i == V.reference ? "  (reference)" : "");
    }
    draw_status(width, height);
    if (V.help)
        draw_help(width, height);
}

/* ---- 3D panels and children ---------------------------------------------------------------------- */

static void render_3d_panels(void)
{
    for (int i = 0; i < V.panel_count; i++) {
        panel *p = &V.panels[i];
        if (p->kind != SOURCE_RASTER && p->kind != SOURCE_PLY)
            continue;
        camera_matrix(&V.cam, p->target.width, p->target.height, V.bounds_lo, V.bounds_hi, V.uniforms.view_projection);
        V.uniforms.eye[0] = (float)V.cam.eye.x, V.uniforms.eye[1] = (float)V.cam.eye.y;
        V.uniforms.eye[2] = (float)V.cam.eye.z;
        V.uniforms.unlit = p->kind == SOURCE_PLY;
        float background[3] = {0, 0, 0};
        if (V.scene_loaded)
            background[0] = (float)V.scene.background.x, background[1] = (float)V.scene.background.y,
            background[2] = (float)V.scene.background.z;
        panel_render_3d(p, &V.uniforms, background);
    }
}

/* (Re)start every child with the current camera.  Each start is logged:
 *   live: start|restart N children eye=X,Y,Z look=X,Y,Z pids P1,P2,...
 * (the old children are stopped and reaped before the new ones start). */
static int start_children(char *err, size_t err_size)
{
    static int starts;
    char pids[PANEL_MAX * 24] = "";
    size_t used = 0;
    int count = 0;
    V.spec.cam = V.cam;
    for (int i = 0; i < V.panel_count; i++)
        if (V.panels[i].kind == SOURCE_CHILD) {
            child_stop(&V.panels[i]);
            if (child_start(&V.panels[i], &V.spec, err, err_size))
                return 2;
            if (V.verbose)
                printf("spawn %s pid %ld%s\n", V.panels[i].method, (long)V.panels[i].pid,
                       V.panels[i].stale ? " (the old image stale until its first pass)" : "");
            if (used < sizeof pids)
                used +=
                    (size_t)snprintf(pids + used, sizeof pids - used, "%s%ld", count ? "," : "", (long)V.panels[i].pid);
            count++;
        }
    if (count) {
        const vec3 e = V.cam.eye, l = V.cam.look;
        printf("live: %s %d children eye=%.17g,%.17g,%.17g look=%.17g,%.17g,%.17g pids %s\n",
               starts++ ? "restart" : "start", count, e.x, e.y, e.z, l.x, l.y, l.z, pids);
    }
    fflush(stdout);
    return 0;
}

static bool children_running(void)
{
    for (int i = 0; i < V.panel_count; i++)
        if (V.panels[i].kind == SOURCE_CHILD && V.panels[i].pid > 0)
            return true;
    return false;
}

/* Is panel a a better reference than panel b: closer to the true solution?
 * A measured error (stats relmse) first, the lowest; then a path tracer over
 * all bounces (unbiased), the most samples, then the better estimator;
 * then the most samples; panels without stats last. */
static int reference_tier(const panel *p)
{
    if (!p->has_stats || !p->img.pixels)
        return 0;
    if (isfinite(p->relmse))
        return 3;
    if (p->estimator_rank > 0 && p->all_bounces && isfinite(p->spp))
        return 2;
    return isfinite(p->spp) ? 1 : 0;
}

static bool better_reference(const panel *a, const panel *b)
{
    int ta = reference_tier(a), tb = reference_tier(b);
    if (ta != tb)
        return ta > tb;
    if (ta == 3)
        return a->relmse < b->relmse;
    if (ta >= 1 && a->spp != b->spp)
        return a->spp > b->spp;
    return ta == 2 && a->estimator_rank > b->estimator_rank;
}

/* Unless the user named one, the reference is the best image on screen
 * (it may change as live children progress). */
static void auto_reference(void)
{
    if (V.reference_given || V.panel_count < 1)
        return;
    int best = 0;
    for (int i = 1; i < V.panel_count; i++)
        if (better_reference(&V.panels[i], &V.panels[best]))
            best = i;
    if (best != V.reference && V.verbose)
        printf("reference %d %s\n", best + 1, V.panels[best].method);
    V.reference = best;
    if (V.split_b == V.reference && V.panel_count > 1)
        V.split_b = (V.reference + 1) % V.panel_count;
}

/* Poll the files and children; returns true if anything changed. */
static bool poll_sources(void)
{
    bool changed = false;
    for (int i = 0; i < V.panel_count; i++) {
        panel *p = &V.panels[i];
        if (p->kind == SOURCE_FILE && panel_poll(p)) /* compare mode follows a file being re-rendered */
            changed = true;
        if (p->kind != SOURCE_CHILD)
            continue;
        if (panel_poll(p)) {
            changed = true;
            printf("update %s %d %dx%d\n", p->method, p->updates, p->img.width, p->img.height);
        }
        if (child_poll_warnings(p)) {
            changed = true;
            printf("%s: %s\n", p->method, p->warning);
        }
        if (child_reap(p)) {
            changed = true;
            if (V.verbose)
                printf("exit %s %d\n", p->method, p->exit_status);
        }
    }
    if (changed)
        auto_reference();
    fflush(stdout);
    return changed;
}

/* Is the frame the final one for a screenshot?  Children finished (or
 * --exit-after-updates reached by every one). */
static bool complete(void)
{
    for (int i = 0; i < V.panel_count; i++) {
        const panel *p = &V.panels[i];
        if (p->kind != SOURCE_CHILD || p->pid <= 0)
            continue;
        if (!(V.exit_after_updates > 0 && p->updates >= V.exit_after_updates))
            return false;
    }
    return true;
}

static void remove_temp_dir(void)
{
    if (!V.temp_dir[0])
        return;
    DIR *d = opendir(V.temp_dir);
    struct dirent *e;
    while (d && (e = readdir(d))) {
        if (e->d_name[0] == '.')
            continue;
        char path[PATH_LEN + 256];
        snprintf(path, sizeof path, "%s/%s", V.temp_dir, e->d_name);
        unlink(path);
    }
    if (d)
        closedir(d);
    rmdir(V.temp_dir);
    V.temp_dir[0] = '\0';
}

/* build/0*_* beside the viewer (or in --chapters DIR), sorted. */
static int find_chapters(const char *only_chapter, char *err, size_t err_size)
{
    char dir[PATH_LEN];
    if (V.chapters_dir) {
        snprintf(dir, sizeof dir, "%s", V.chapters_dir);
    } else {
        ssize_t n = readlink("/proc/self/exe", dir, sizeof dir - 1);
        dir[n > 0 ? n : 0] = '\0';
        char *slash = strrchr(dir, '/');
        if (slash)
            *slash = '\0';
        else
            snprintf(dir, sizeof dir, "build");
    }
    char pattern[PATH_LEN + 16];
    snprintf(pattern, sizeof pattern, "%s/[0-9][0-9]_*", dir);
    glob_t g;
    if (glob(pattern, 0, NULL, &g) != 0)
        g.gl_pathc = 0;
    int found = 0;
    for (size_t i = 0; i < g.gl_pathc; i++) {
        const char *path = g.gl_pathv[i], *name = strrchr(path, '/') + 1;
        struct stat st;
        if (strchr(name, '.') || stat(path, &st) || !S_ISREG(st.st_mode) || access(path, X_OK))
            continue;
        bool wanted = only_chapter ? !strcmp(name, only_chapter) : V.chapter_filter_count == 0;
        for (int k = 0; k < V.chapter_filter_count && !only_chapter; k++)
            wanted |= !strcmp(name, V.chapter_filter[k]);
        if (!wanted || V.panel_count >= PANEL_MAX)
            continue;
        panel *p = &V.panels[V.panel_count++];
        memset(p, 0, sizeof *p);
        p->kind = SOURCE_CHILD;
        p->exit_status = -1;
        snprintf(p->exe, sizeof p->exe, "%s", path);
        found++;
    }
    globfree(&g);
    if (!found) {
        snprintf(err, err_size, "argv:0: no chapter executable %s in %.900s (run make first)",
                 only_chapter ? only_chapter : "[0-9][0-9]_*", dir);
        return 2;
    }
    return 0;
}

static void apply_camera_options(void);

/* Set up the panels of each mode (the GL context exists). */
static int set_up_compare(char *err, size_t err_size)
{
    for (int i = 0; i < V.panel_count; i++) {
        panel *p = &V.panels[i];
        char path[PATH_LEN];
        snprintf(path, sizeof path, "%s", p->path);
        if (panel_load_pfm(p, path, err, err_size))
            return 2;
    }
    for (int i = 0; i < V.panel_count && V.verbose; i++) {
        char title[256], numbers[256];
        label_lines(i, title, sizeof title, numbers, sizeof numbers);
        printf("panel %d %s %dx%d\n", i + 1, V.panels[i].path, V.panels[i].img.width, V.panels[i].img.height);
        printf("label %d: %s | %s\n", i + 1, title, numbers);
    }
    V.aspect_w = V.panels[0].img.width, V.aspect_h = V.panels[0].img.height; /* the layout fits panel 1 */
    auto_reference();
    return 0;
}

static int set_up_children(int rw, int rh, char *err, size_t err_size);

static int set_up(char *err, size_t err_size)
{
    if (V.mode == MODE_COMPARE)
        return set_up_compare(err, err_size);

    /* 3D modes: the scene (or the PLY) and the camera. */
    int aspect_w = 1, aspect_h = 1;
    if (V.mode == MODE_PLY) {
        panel *p = &V.panels[V.panel_count++];
        memset(p, 0, sizeof *p);
        p->kind = SOURCE_PLY;
        const char *base = strrchr(V.ply_path, '/');
        snprintf(p->method, sizeof p->method, "%s", base ? base + 1 : V.ply_path);
        snprintf(p->detail, sizeof p->detail, "PLY, per-vertex radiance, smooth");
        if (ply_mesh(V.ply_path, &p->mesh, &V.bounds_lo, &V.bounds_hi, err, err_size))
            return 2;
        vec3 centre = v3_scale(v3_add(V.bounds_lo, V.bounds_hi), 0.5);
        double radius = 0.5 * v3_length(v3_sub(V.bounds_hi, V.bounds_lo));
        V.scene_cam = (camera){
            .eye = v3_add(centre, v3(0, 0, -2.6 * radius)), .look = centre, .up = v3(0, 1, 0), .fov_degrees = 40.0};
        aspect_w = V.width, aspect_h = V.height - LABEL_BAND - STATUS_BAND;
    } else {
        if (scene_load(V.scene_path, &V.scene, err, err_size))
            return 2;
        V.scene_loaded = true;
        V.scene_cam = V.scene.camera;
        V.bounds_lo = V.scene.bounds.lo, V.bounds_hi = V.scene.bounds.hi;
        aspect_w = V.scene.width, aspect_h = V.scene.height;
        panel *p = &V.panels[V.panel_count++];
        memset(p, 0, sizeof *p);
        p->kind = SOURCE_RASTER;
        snprintf(p->method, sizeof p->method, "GLSL Blinn-Phong raster");
        snprintf(p->detail, sizeof p->detail, "chapter 1's model, no shadows%s",
                 V.scene.emitter_count ? ", emitters as points" : "");
        if (scene_mesh(&V.scene, &p->mesh, &V.uniforms, v3_splat(V.ambient), err, err_size))
            return 2;
        if (find_chapters(V.mode == MODE_RASTER ? "01_local" : NULL, err, err_size))
            return 2;
    }
    apply_camera_options();

    /* Render size: given, or the scene's aspect fitted into panel 1's area. */
    int rw = V.render_width, rh = V.render_height;
    V.aspect_w = rw ? rw : aspect_w, V.aspect_h = rw ? rh : aspect_h;
    if (!rw) {
        rect whole, label, area;
        panel_rects(0, V.panel_count, V.width, V.height, &whole, &label, &area);
        rw = area.w, rh = (int)lround((double)area.w * aspect_h / aspect_w);
        if (rh > area.h)
            rh = area.h, rw = (int)lround((double)area.h * aspect_w / aspect_h);
        rw = rw < 1 ? 1 : rw, rh = rh < 1 ? 1 : rh;
    }
    for (int i = 0; i < V.panel_count; i++) {
        panel *p = &V.panels[i];
        if ((p->kind == SOURCE_RASTER || p->kind == SOURCE_PLY) &&
            target_create(&p->target, rw, rh, true, err, err_size))
            return 2;
    }
    if (V.verbose)
        printf("render size %dx%d\n", rw, rh);
    return set_up_children(rw, rh, err, err_size);
}

/* Children (live and raster modes): outputs in a private temporary directory. */
static int set_up_children(int rw, int rh, char *err, size_t err_size)
{
    if (V.mode == MODE_LIVE || V.mode == MODE_RASTER) {
        snprintf(V.temp_dir, sizeof V.temp_dir, "%s/viewer-XXXXXX", getenv("TMPDIR") ? getenv("TMPDIR") : "/tmp");
        if (!mkdtemp(V.temp_dir)) {
            snprintf(err, err_size, "viewer: cannot make a temporary directory: %s", strerror(errno));
            V.temp_dir[0] = '\0';
            return 2;
        }
        static char ambient[32];
        snprintf(ambient, sizeof ambient, "%.17g", V.ambient);
        V.spec = (child_spec){.scene_path = V.scene_path,
                              .width = rw,
                              .height = rh,
                              .time_budget = V.mode == MODE_LIVE ? V.live_time : 0.0,
                              .directory = V.temp_dir};
        if (V.mode == MODE_RASTER) {
            if (V.no_shadows)
                V.spec.extra[V.spec.extra_count++] = "--no-shadows";
            V.spec.extra[V.spec.extra_count++] = "--ambient";
            V.spec.extra[V.spec.extra_count++] = ambient;
        }
    }
    return 0;
}

static void apply_camera_options(void)
{
    if (V.camera_given & 1)
        V.scene_cam.eye = V.cam_option.eye;
    if (V.camera_given & 2)
        V.scene_cam.look = V.cam_option.look;
    if (V.camera_given & 4)
        V.scene_cam.up = V.cam_option.up;
    if (V.camera_given & 8)
        V.scene_cam.fov_degrees = V.cam_option.fov_degrees;
    V.cam = V.scene_cam;
}

/* ---- input ---------------------------------------------------------------------------------------- */

static bool three_d(void) { return V.mode != MODE_COMPARE; }

static vec3 rotate(vec3 v, vec3 axis, double angle)
{
    /* Rodrigues */
    double c = cos(angle), s = sin(angle);
    return v3_add(v3_add(v3_scale(v, c), v3_scale(v3_cross(axis, v), s)), v3_scale(axis, v3_dot(axis, v) * (1 - c)));
}

/* --verbose, in a window: every camera move from the keys or the mouse, as
 *   camera: orbit|dolly|reset eye=X,Y,Z look=X,Y,Z */
static void log_camera(const char *what)
{
    if (V.verbose && !V.frames)
        printf("camera: %s eye=%.17g,%.17g,%.17g look=%.17g,%.17g,%.17g\n", what, V.cam.eye.x, V.cam.eye.y, V.cam.eye.z,
               V.cam.look.x, V.cam.look.y, V.cam.look.z);
}

/* Yaw about the camera's up, then pitch about its right axis (skipped near
 * the poles); the distance to the look point stays the same. */
static void orbit(double yaw_degrees, double pitch_degrees)
{
    vec3 up = v3_normalize(V.cam.up), d = v3_sub(V.cam.eye, V.cam.look);
    d = rotate(d, up, -yaw_degrees * M_PI / 180.0);
    vec3 right = v3_normalize(v3_cross(up, d));
    vec3 pitched = rotate(d, right, pitch_degrees * M_PI / 180.0);
    if (fabs(v3_dot(v3_normalize(pitched), up)) < 0.995)
        d = pitched;
    V.cam.eye = v3_add(V.cam.look, d);
    V.camera_moved = true;
    log_camera("orbit");
}

static void dolly(double factor)
{
    V.cam.eye = v3_add(V.cam.look, v3_scale(v3_sub(V.cam.eye, V.cam.look), factor));
    V.camera_moved = true;
    log_camera("dolly");
}

static double zoomed(double factor) { return fmin(fmax(V.zoom * factor, 0.05), 512.0); }

/* Z / X: about the shared centre (V.cx, V.cy), which sits at every panel's
 * centre, so each panel zooms about its own middle (as --zoom does). */
static void zoom_about_centre(double factor)
{
    V.zoom = zoomed(factor);
    V.redraw = true;
}

/* The wheel: about the image point under the cursor. */
static void zoom_at(double factor, double x, double y)
{
    double u, v;
    int index = panel_at(x, y, &u, &v);
    double new_zoom = zoomed(factor);
    if (index >= 0) {
        /* keep the image point under the cursor where it is */
        V.cx = u + (V.cx - u) * V.zoom / new_zoom;
        V.cy = v + (V.cy - v) * V.zoom / new_zoom;
    }
    V.zoom = new_zoom;
    V.redraw = true;
}

static void pan_pixels(double dx, double dy)
{
    rect whole, label, area;
    panel_rects(0, shown_panels(), V.width, V.height, &whole, &label, &area);
    const panel *p = &V.panels[V.split ? V.reference : 0];
    double ox, oy, s;
    placement(p, area, &ox, &oy, &s);
    if (p->img.width > 0) {
        V.cx -= dx / (s * p->img.width);
        V.cy -= dy / (s * p->img.height);
    }
    V.redraw = true;
}

static void screenshot_key(void);

/* ---- the key table ------------------------------------------------------------------------------
 * One table drives everything about the keys: the dispatch (on_key for key
 * codes, on_char for characters, whatever the keyboard layout puts them on),
 * the H overlay and `build/viewer --help-keys`, whose Markdown table
 * viewer/README.md carries verbatim (tests/grade_viewer.py checks that).
 * Rows without an action are the mouse's, handled by the mouse callbacks. */

typedef void key_action(int key); /* key: the GLFW key code, or the character for chars[] */

typedef struct {
    const char *label; /* the keys as shown, " / " between alternatives */
    int keys[10];      /* GLFW key codes (on_key), 0 ends the list */
    unsigned chars[3]; /* Unicode characters (on_char), 0 ends the list */
    key_action *action;
    const char *help;
} key_binding;

static void key_help(int key) { (void)key, V.help = !V.help; }
static void key_exposure_up(int key) { (void)key, V.exposure += 0.5; }
static void key_exposure_down(int key) { (void)key, V.exposure -= 0.5; }
static void key_exposure_reset(int key) { (void)key, V.exposure = 0.0; }
static void key_zoom_in(int key) { (void)key, zoom_about_centre(1.25); }
static void key_zoom_out(int key) { (void)key, zoom_about_centre(0.8); }
static void key_fit(int key) { (void)key, V.zoom = 1.0, V.cx = V.cy = 0.5; }
static void key_heat(int key) { (void)key, V.diff = !V.diff; }
static void key_screenshot(int key) { (void)key, screenshot_key(); }
static void key_quit(int key) { (void)key, quit_requested = 1; }

static void key_arrow(int key)
{
    int dx = key == GLFW_KEY_LEFT ? -1 : key == GLFW_KEY_RIGHT ? 1 : 0;
    int dy = key == GLFW_KEY_UP ? 1 : key == GLFW_KEY_DOWN ? -1 : 0;
    if (three_d())
        orbit(5.0 * dx, 5.0 * dy);
    else
        pan_pixels(-40.0 * dx, 40.0 * dy);
}

static void key_dolly(int key)
{
    if (three_d())
        dolly(key == GLFW_KEY_PAGE_UP ? 0.9 : 1.0 / 0.9);
}

static void key_reference(int key)
{
    if (key - GLFW_KEY_1 >= V.panel_count)
        return;
    V.reference = key - GLFW_KEY_1, V.reference_given = true;
    if (V.split_b == V.reference)
        V.split_b = (V.reference + 1) % V.panel_count;
}

static void key_split(int key)
{
    (void)key;
    V.split = !V.split && V.panel_count > 1;
    if (V.split_b == V.reference || V.split_b >= V.panel_count)
        V.split_b = (V.reference + 1) % V.panel_count;
}

static void key_next_b(int key)
{
    (void)key;
    if (V.panel_count > 1)
        do
            V.split_b = (V.split_b + 1) % V.panel_count;
        while (V.split_b == V.reference);
}

static void key_slider(int key)
{
    V.split_position = fmin(1.0, fmax(0.0, V.split_position + (key == GLFW_KEY_COMMA ? -0.02 : 0.02)));
}

static void key_camera_reset(int key)
{
    (void)key;
    if (three_d()) {
        V.cam = V.scene_cam;
        V.camera_moved = true;
        log_camera("reset");
    }
}

static const key_binding KEYS[] = {
    {"H / F1", {GLFW_KEY_H, GLFW_KEY_F1}, {0}, key_help, "show / hide this help"},
    {"+ / =", {0}, {'+', '='}, key_exposure_up, "exposure up half a stop (the keypad's + too)"},
    {"-", {GLFW_KEY_MINUS, GLFW_KEY_KP_SUBTRACT}, {0}, key_exposure_down, "exposure down half a stop (keypad too)"},
    {"0", {GLFW_KEY_0, GLFW_KEY_KP_0}, {0}, key_exposure_reset, "exposure back to 0 (keypad too)"},
    {"Z", {GLFW_KEY_Z}, {0}, key_zoom_in, "zoom in by 1.25 (each panel about its centre)"},
    {"X", {GLFW_KEY_X}, {0}, key_zoom_out, "zoom out by 1.25"},
    {"F", {GLFW_KEY_F}, {0}, key_fit, "fit: zoom 1, centred"},
    {"Left / Right / Up / Down",
     {GLFW_KEY_LEFT, GLFW_KEY_RIGHT, GLFW_KEY_UP, GLFW_KEY_DOWN},
     {0},
     key_arrow,
     "pan 40 window pixels (Left shows more of the left); 3D: orbit 5 degrees"},
    {"PgUp / PgDn",
     {GLFW_KEY_PAGE_UP, GLFW_KEY_PAGE_DOWN},
     {0},
     key_dolly,
     "3D: dolly in / out (distance x 0.9, / 0.9)"},
    {"D", {GLFW_KEY_D}, {0}, key_heat, "heat map: relative error vs the reference (default: the best image)"},
    {"1..9",
     {GLFW_KEY_1, GLFW_KEY_2, GLFW_KEY_3, GLFW_KEY_4, GLFW_KEY_5, GLFW_KEY_6, GLFW_KEY_7, GLFW_KEY_8, GLFW_KEY_9},
     {0},
     key_reference,
     "pick the reference panel"},
    {"S", {GLFW_KEY_S}, {0}, key_split, "A/B split between the reference and panel B"},
    {"Tab", {GLFW_KEY_TAB}, {0}, key_next_b, "next panel B (skipping the reference)"},
    {", / .", {GLFW_KEY_COMMA, GLFW_KEY_PERIOD}, {0}, key_slider, "split slider 2 % of the width left / right"},
    {"C", {GLFW_KEY_C}, {0}, key_camera_reset, "3D: camera back to the scene's"},
    {"P", {GLFW_KEY_P}, {0}, key_screenshot, "screenshot out/viewer-N.png (out/ made if missing)"},
    {"Q / Esc", {GLFW_KEY_Q, GLFW_KEY_ESCAPE}, {0}, key_quit, "quit (exit 0, the children stopped and reaped)"},
    {"wheel", {0}, {0}, NULL, "zoom 1.25 per step at the cursor; 3D: dolly 0.9 per step (Ctrl: zoom)"},
    {"left drag", {0}, {0}, NULL, "pan; 3D: orbit the look point, 0.3 degrees per pixel; split: slider"},
    {"shift drag / middle drag", {0}, {0}, NULL, "pan (in 3D too)"},
    {"right click", {0}, {0}, NULL, "the panel under the cursor becomes the reference, heat map on"},
};
enum { KEY_COUNT = sizeof KEYS / sizeof *KEYS };

/* `build/viewer --help-keys`: the table in Markdown, keys in backticks. */
static void print_keys_markdown(void)
{
    printf("| key | action |\n|---|---|\n");
    for (int k = 0; k < KEY_COUNT; k++) {
        char label[128] = "", *rest = label;
        snprintf(label, sizeof label, "%s", KEYS[k].label);
        printf("| ");
        for (char *token = label; token; token = rest) {
            rest = strstr(token, " / ");
            if (rest)
                *rest = '\0', rest += 3;
            printf(KEYS[k].action ? "`%s`%s" : "%s%s", token, rest ? " / " : "");
        }
        printf(" | %s |\n", KEYS[k].help);
    }
}

/* The H overlay: the same table, centred on the frame. */
static void draw_help(int width, int height)
{
    int label_width = 0, help_width = 0;
    for (int k = 0; k < KEY_COUNT; k++) {
        int lw = gfx_text_width(KEYS[k].label), hw = gfx_text_width(KEYS[k].help);
        label_width = lw > label_width ? lw : label_width;
        help_width = hw > help_width ? hw : help_width;
    }
    int w = label_width + help_width + 16 + 24, h = KEY_COUNT * LINE + 16;
    rect box = {(width - w) / 2, (height - h) / 2, w, h};
    const float shade[4] = {0.0f, 0.0f, 0.0f, 0.8f};
    gfx_fill(box, shade);
    for (int k = 0; k < KEY_COUNT; k++) {
        gfx_text(box.x + 8, box.y + 8 + LINE * k, KEYS[k].label, YELLOW, box);
        gfx_text(box.x + 8 + label_width + 16, box.y + 8 + LINE * k, KEYS[k].help, WHITE, box);
    }
}

static void on_key(GLFWwindow *w, int key, int scancode, int action, int mods)
{
    (void)w, (void)scancode, (void)mods;
    if (action == GLFW_RELEASE)
        return;
    V.redraw = true;
    for (int k = 0; k < KEY_COUNT; k++)
        for (int j = 0; j < 10 && KEYS[k].keys[j]; j++)
            if (KEYS[k].keys[j] == key && KEYS[k].action) {
                KEYS[k].action(key);
                return;
            }
}

/* Characters: '+' wherever the layout puts it, the keypad's too (on_char,
 * not on_key: handling GLFW_KEY_KP_ADD as well would count that key twice). */
static void on_char(GLFWwindow *w, unsigned int codepoint)
{
    (void)w;
    for (int k = 0; k < KEY_COUNT; k++)
        for (int j = 0; j < 3 && KEYS[k].chars[j]; j++)
            if (KEYS[k].chars[j] == codepoint && KEYS[k].action) {
                KEYS[k].action((int)codepoint);
                V.redraw = true;
                return;
            }
}

static void on_cursor(GLFWwindow *w, double x, double y)
{
    int ww, wh, fw, fh;
    glfwGetWindowSize(w, &ww, &wh);
    glfwGetFramebufferSize(w, &fw, &fh);
    x *= ww ? (double)fw / ww : 1.0, y *= wh ? (double)fh / wh : 1.0;
    double dx = x - V.mouse_x, dy = y - V.mouse_y;
    V.mouse_x = x, V.mouse_y = y, V.mouse_inside = true;
    if (V.dragging) {
        if (V.split && !V.panning)
            V.split_position = fmin(fmax(x / V.width, 0.0), 1.0);
        else if (three_d() && !V.panning)
            orbit(dx * 0.3, dy * 0.3);
        else
            pan_pixels(dx, dy);
    }
    V.redraw = true;
}

static void on_cursor_enter(GLFWwindow *w, int entered)
{
    (void)w;
    V.mouse_inside = entered;
    V.redraw = true;
}

static void on_button(GLFWwindow *w, int button, int action, int mods)
{
    (void)w;
    if (button == GLFW_MOUSE_BUTTON_LEFT) {
        V.dragging = action == GLFW_PRESS;
        V.panning = mods & GLFW_MOD_SHIFT;
        if (V.dragging && V.split && !V.panning)
            V.split_position = fmin(fmax(V.mouse_x / V.width, 0.0), 1.0);
    } else if (button == GLFW_MOUSE_BUTTON_MIDDLE) {
        V.dragging = action == GLFW_PRESS;
        V.panning = true;
    } else if (button == GLFW_MOUSE_BUTTON_RIGHT && action == GLFW_PRESS) {
        double u, v;
        int index = panel_at(V.mouse_x, V.mouse_y, &u, &v);
        if (index >= 0 && !V.split)
            V.reference = index, V.diff = true, V.reference_given = true;
    }
    V.redraw = true;
}

static void on_scroll(GLFWwindow *w, double xoffset, double yoffset)
{
    (void)w, (void)xoffset;
    if (three_d() && !(glfwGetKey(w, GLFW_KEY_LEFT_CONTROL) == GLFW_PRESS))
        dolly(pow(0.9, yoffset));
    else
        zoom_at(pow(1.25, yoffset), V.mouse_x, V.mouse_y);
}

static void on_resize(GLFWwindow *w, int width, int height)
{
    (void)w, (void)width, (void)height;
    V.redraw = true;
}

/* ---- the main loop ------------------------------------------------------------------------------- */

static int save_screen(const char *path, int width, int height, char *err, size_t err_size)
{
    unsigned char *rgb = malloc((size_t)width * (size_t)height * 3);
    if (!rgb) {
        snprintf(err, err_size, "%s:0: out of memory", path);
        return 2;
    }
    gfx_read_rgb8(width, height, rgb);
    int status = write_rgb8(path, width, height, rgb, err, err_size);
    free(rgb);
    if (!status)
        printf("wrote %s\n", path);
    return status;
}

/* P: out/viewer-N.png (out/ made if missing), N counting from 1 in each
 * session; never into the current directory itself (the repository root). */
static void screenshot_key(void)
{
    char path[64], err[512];
    if (mkdir("out", 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "out:0: cannot make the screenshot directory: %s\n", strerror(errno));
        return;
    }
    snprintf(path, sizeof path, "out/viewer-%d.png", ++V.screenshot_counter);
    int w, h;
    glfwGetFramebufferSize(backend_window(), &w, &h);
    draw_frame(0, w, h);
    if (save_screen(path, w, h, err, sizeof err))
        fprintf(stderr, "%s\n", err);
    fflush(stdout);
}

static int write_panel_out(char *err, size_t err_size)
{
    if (!V.panel_out_path)
        return 0;
    if (!V.panels[0].img.pixels) {
        snprintf(err, err_size, "%s:0: panel 1 has no image", V.panel_out_path);
        return 2;
    }
    return image_write_pfm(&V.panels[0].img, V.panel_out_path, err, err_size);
}

/* Libraries mapped into the process: which GL implementation is really in use. */
static void print_gl_libraries(void)
{
    FILE *f = fopen("/proc/self/maps", "r");
    char line[1024];
    const char *names[] = {"libOSMesa", "libEGL_mesa", "libGLX_mesa", "libglfw"};
    bool seen[4] = {false};
    while (f && fgets(line, sizeof line, f))
        for (int k = 0; k < 4; k++)
            seen[k] |= strstr(line, names[k]) != NULL;
    if (f)
        fclose(f);
    printf("libraries:");
    for (int k = 0; k < 4; k++)
        if (seen[k])
            printf(" %s", names[k]);
    printf("\n");
}

static void run_frames(GLuint fbo, int width, int height)
{
    GLFWwindow *window = backend_window();
    double start = now_seconds();
    for (int f = 0; f < V.frames; f++) {
        if (V.mode == MODE_RASTER || V.mode == MODE_PLY) { /* as when orbiting: the 3D panel is redrawn */
            orbit(0.5, 0.0);
            render_3d_panels();
        }
        draw_frame(fbo, width, height);
        if (window)
            glfwSwapBuffers(window);
        glFinish();
    }
    double elapsed = now_seconds() - start;
    printf("frames %d  %.1f fps  %.2f ms/frame  %dx%d  %d panels  backend %s\n", V.frames, V.frames / elapsed,
           1e3 * elapsed / V.frames, width, height, shown_panels(), backend_name(V.backend));
}

static int headless_loop(char *err, size_t err_size)
{
    if (target_create(&V.screen, V.width, V.height, false, err, err_size))
        return 2;
    render_3d_panels();
    while (!quit_requested) {
        poll_sources();
        if (complete())
            break;
        struct timespec pause = {0, 50 * 1000 * 1000}; /* wait for the children's next file */
        nanosleep(&pause, NULL);
    }
    if (quit_requested) {
        snprintf(err, err_size, "viewer: interrupted");
        return 2;
    }
    for (int i = 0; i < V.panel_count; i++)
        child_stop(&V.panels[i]);
    draw_frame(V.screen.fbo, V.width, V.height);
    int status = 0;
    if (V.out_path)
        status = save_screen(V.out_path, V.width, V.height, err, err_size);
    if (!status)
        status = write_panel_out(err, err_size);
    if (!status && V.frames)
        run_frames(V.screen.fbo, V.width, V.height);
    return status;
}

static int window_loop(char *err, size_t err_size)
{
    GLFWwindow *window = backend_window();
    glfwSetKeyCallback(window, on_key);
    glfwSetCharCallback(window, on_char);
    glfwSetCursorPosCallback(window, on_cursor);
    glfwSetCursorEnterCallback(window, on_cursor_enter);
    glfwSetMouseButtonCallback(window, on_button);
    glfwSetScrollCallback(window, on_scroll);
    glfwSetFramebufferSizeCallback(window, on_resize);
    render_3d_panels();
    V.redraw = true;
    const char *screenshot = V.screenshot_path ? V.screenshot_path : V.out_path;
    if (V.frames) {
        int w, h;
        glfwGetFramebufferSize(window, &w, &h);
        run_frames(0, w, h);
        return 0;
    }
    while (!quit_requested && !glfwWindowShouldClose(window)) {
        if (poll_sources())
            V.redraw = true;
        if (V.camera_moved) {
            V.camera_moved = false;
            render_3d_panels();
            V.restart_at = now_seconds() + 0.3;
            V.redraw = true;
        }
        /* Restart the children once the camera rests (not on every mouse move). */
        if (V.restart_at > 0 && now_seconds() >= V.restart_at && !V.dragging) {
            V.restart_at = 0;
            if (start_children(err, err_size))
                return 2;
        }
        if (V.redraw) {
            V.redraw = false;
            int w, h;
            glfwGetFramebufferSize(window, &w, &h);
            draw_frame(0, w, h);
            if (screenshot && complete() && V.restart_at == 0) {
                int status = save_screen(screenshot, w, h, err, err_size);
                if (!status)
                    status = write_panel_out(err, err_size);
                return status;
            }
            glfwSwapBuffers(window);
        }
        /* Sleep until input arrives, or a little while when children may
         * have written a new image (no busy waiting). */
        glfwWaitEventsTimeout(children_running() || V.restart_at > 0 ? 0.1 : 0.5);
    }
    return 0;
}

int main(int argc, char **argv)
{
    char err[1024] = "";
    setvbuf(stdout, NULL, _IOLBF, 0);
    int status = parse_options(argc, argv, err, sizeof err);
    if (status) {
        fprintf(stderr, "%s\n", err);
        return status;
    }
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);

    /* The backend: the window when there is a display, else headless. */
    bool display =
        (getenv("DISPLAY") && *getenv("DISPLAY")) || (getenv("WAYLAND_DISPLAY") && *getenv("WAYLAND_DISPLAY"));
    if (!V.backend_given)
        V.backend = V.headless || !display ? BACKEND_EGL : BACKEND_GLFW;
    if (V.backend != BACKEND_GLFW)
        V.headless = true;
    if (V.headless && !V.out_path && !V.frames && !V.panel_out_path && !V.exit_after_updates) {
        fprintf(stderr, "argv:0: no display ($DISPLAY is unset): give --out FILE.png to render headless\n");
        return 2;
    }
    status = backend_open(V.backend, V.width, V.height, "viewer", err, sizeof err);
    if (status == 3 && !V.backend_given && V.backend == BACKEND_EGL) {
        fprintf(stderr, "%s; trying osmesa\n", err);
        V.backend = BACKEND_OSMESA;
        status = backend_open(V.backend, V.width, V.height, "viewer", err, sizeof err);
    }
    if (status) {
        fprintf(stderr, "%s\n", err);
        return status;
    }
    if (V.backend == BACKEND_GLFW) {
        int fw, fh;
        glfwGetFramebufferSize(backend_window(), &fw, &fh);
        V.width = fw, V.height = fh;
    }
    status = gfx_init(V.raster_shader, V.font_path, V.font_px, err, sizeof err);
    if (!status) {
        printf("backend %s: %s\n", backend_name(V.backend), gfx_renderer());
        printf("font: %s, %d px\n", gfx_font(), V.font_px);
        print_gl_libraries();
        status = set_up(err, sizeof err);
    }
    if (!status) {
        if (((V.diff || V.split) && V.reference >= V.panel_count) ||
            (V.split && (V.split_b >= V.panel_count || V.split_b == V.reference))) {
            snprintf(err, sizeof err, "argv:0: --diff / --split name a panel that does not exist (there are %d)",
                     V.panel_count);
            status = 2;
        }
    }
    if (!status)
        status = start_children(err, sizeof err);
    if (!status)
        status = V.headless ? headless_loop(err, sizeof err) : window_loop(err, sizeof err);
    if (status)
        fprintf(stderr, "%s\n", err);

    for (int i = 0; i < V.panel_count; i++)
        panel_free(&V.panels[i]);
    remove_temp_dir();
    if (V.screen.fbo)
        target_destroy(&V.screen);
    if (V.scene_loaded)
        scene_free(&V.scene);
    gfx_shutdown();
    backend_close();
    return status;
}
