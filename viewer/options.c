/* options.c — the viewer's command line, as the chapters': one table per
 * section (common/options.h) sets the defaults, parses argv with its range
 * checks and "argv:N: message" errors, and prints --help, so an option
 * cannot be documented one way and parsed another.  A word that is not an
 * option is an image to compare. */
#include <glob.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app.h"
#include "font.h"
#include "options.h"

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

/* ---- the options that need more than a field and a range --------------------------------------- */

static int wants(char *why, size_t why_size, const char *what, const char *value)
{
    snprintf(why, why_size, "wants %s, not '%s'", what, value);
    return 2;
}

static int parse_mode(viewer_mode mode, const char *value)
{
    V.mode = mode;
    if (mode == MODE_PLY)
        V.ply_path = value;
    else
        V.scene_path = value;
    return 0;
}
static int parse_live(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    (void)state, (void)argv_index, (void)why, (void)why_size;
    return parse_mode(MODE_LIVE, value);
}
static int parse_raster(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    (void)state, (void)argv_index, (void)why, (void)why_size;
    return parse_mode(MODE_RASTER, value);
}
static int parse_ply(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    (void)state, (void)argv_index, (void)why, (void)why_size;
    return parse_mode(MODE_PLY, value);
}

static int parse_scene(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    (void)why, (void)why_size;
    v->compare_scene = value;
    v->compare_scene_argv = argv_index;
    return 0;
}

static int parse_backend(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    (void)argv_index;
    if (!backend_parse(value, &v->backend))
        return wants(why, why_size, "glfw, egl or osmesa", value);
    v->backend_given = true;
    return 0;
}

static bool parse_wxh(const char *s, int *w, int *h)
{
    char tail;
    return sscanf(s, "%dx%d%c", w, h, &tail) == 2 && *w > 0 && *h > 0 && *w <= 16384 && *h <= 16384;
}
static int parse_size(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    (void)argv_index;
    return parse_wxh(value, &v->width, &v->height) ? 0 : wants(why, why_size, "WxH (1 .. 16384 each)", value);
}
static int parse_render_size(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    (void)argv_index;
    return parse_wxh(value, &v->render_width, &v->render_height) ? 0
                                                                 : wants(why, why_size, "WxH (1 .. 16384 each)", value);
}

/* A panel number 1 .. PANEL_MAX into *index (0-based). */
static bool parse_panel_number(const char *s, int *index)
{
    char *end;
    long n = strtol(s, &end, 10);
    if (end == s || *end || n < 1 || n > PANEL_MAX)
        return false;
    *index = (int)n - 1;
    return true;
}
static int parse_reference(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    (void)argv_index;
    if (!parse_panel_number(value, &v->reference))
        return wants(why, why_size, "a panel number", value);
    v->reference_given = true;
    return 0;
}
static int parse_diff(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    v->diff = true;
    return parse_reference(state, value, argv_index, why, why_size);
}

static int parse_split(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    int pa, pb;
    double pos = 0.5;
    char tail;
    int n = sscanf(value, "%d,%d,%lf%c", &pa, &pb, &pos, &tail);
    (void)argv_index;
    if ((n != 2 && n != 3) || pa < 1 || pb < 1 || pa > PANEL_MAX || pb > PANEL_MAX || !(pos >= 0 && pos <= 1))
        return wants(why, why_size, "A,B[,POS] (panel numbers, 0 <= POS <= 1)", value);
    v->split = true, v->reference = pa - 1, v->split_b = pb - 1, v->split_position = pos, v->reference_given = true;
    return 0;
}

static bool parse_pair(const char *value, double *x, double *y)
{
    char tail;
    return sscanf(value, "%lf,%lf%c", x, y, &tail) == 2 && isfinite(*x) && isfinite(*y);
}
static int parse_center(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    (void)argv_index;
    return parse_pair(value, &v->cx, &v->cy) ? 0 : wants(why, why_size, "U,V", value);
}
static int parse_cursor(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    (void)argv_index;
    if (!parse_pair(value, &v->mouse_x, &v->mouse_y))
        return wants(why, why_size, "X,Y in pixels", value);
    v->cursor_given = v->mouse_inside = true;
    return 0;
}

/* --eye, --look, --up: X,Y,Z into *p, and `given` into camera_given. */
static int parse_camera_point(int given, vec3 *p, const char *value, char *why, size_t why_size)
{
    char tail;
    if (sscanf(value, "%lf,%lf,%lf%c", &p->x, &p->y, &p->z, &tail) != 3 || !v3_is_finite(*p))
        return wants(why, why_size, "X,Y,Z", value);
    V.camera_given |= given;
    return 0;
}
static int parse_eye(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    (void)argv_index;
    return parse_camera_point(GIVEN_EYE, &((viewer_state *)state)->cam_option.eye, value, why, why_size);
}
static int parse_look(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    (void)argv_index;
    return parse_camera_point(GIVEN_LOOK, &((viewer_state *)state)->cam_option.look, value, why, why_size);
}
static int parse_up(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    (void)argv_index;
    return parse_camera_point(GIVEN_UP, &((viewer_state *)state)->cam_option.up, value, why, why_size);
}

static int parse_chapter(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    viewer_state *v = state;
    (void)argv_index, (void)why, (void)why_size;
    if (v->chapter_filter_count < PANEL_MAX)
        v->chapter_filter[v->chapter_filter_count++] = value;
    return 0;
}

/* ---- the tables --------------------------------------------------------------------------------- */

#define FIELD(name) offsetof(viewer_state, name)
static const option MODE_OPTIONS[] = {
    {"--scene", "NAME", OPTION_CUSTOM, 0, .parse = parse_scene, .help = "compare DIR/NAME-NN_*.pfm (DIR: --dir)"},
    {"--dir", "DIR", OPTION_STRING, FIELD(compare_dir), .default_text = "out", .help = "where --scene looks"},
    {"--live", "SCENE", OPTION_CUSTOM, 0, .parse = parse_live,
     .help = "run every chapter (build/0*_*) as a child with the viewer's camera and show its progressive images; "
             "orbiting restarts them.  A GLSL raster is panel 1."},
    {"--raster", "SCENE", OPTION_CUSTOM, 0, .parse = parse_raster,
     .help = "the scene rasterised by a GLSL Blinn-Phong shader (chapter 1's local model, no shadows) beside "
             "chapter 1's ray-cast image of the same camera"},
    {"--ply", "FILE.ply", OPTION_CUSTOM, 0, .parse = parse_ply,
     .help = "radiosity's mesh with smooth per-vertex radiance, orbitable"},
    {0},
};

static const option DISPLAY_OPTIONS[] = {
    {"--backend", "glfw|egl|osmesa", OPTION_CUSTOM, 0, .parse = parse_backend,
     .help = "context (default glfw with a display, else egl, else osmesa)"},
    {"--headless", NULL, OPTION_FLAG, FIELD(headless), .help = "no window (egl or osmesa); needs --out or --frames"},
    {"--size", "WxH", OPTION_CUSTOM, 0, .parse = parse_size, .default_text = "1280x720",
     .help = "window / framebuffer size"},
    {"--render-size", "WxH", OPTION_CUSTOM, 0, .parse = parse_render_size,
     .help = "size of 3D panels and children's images (default: fit the panel)"},
    {"--out", "FILE.png|.ppm", OPTION_STRING, FIELD(out_path),
     .help = "write what the window shows (headless: the first complete frame)"},
    {"--screenshot", "FILE", OPTION_STRING, FIELD(screenshot_path),
     .help = "in a window: save the first complete frame there and exit"},
    {"--panel-out", "FILE.pfm", OPTION_STRING, FIELD(panel_out_path),
     .help = "write panel 1's linear radiance (the GLSL raster, the PLY view ...)"},
    {"--exposure", "STOPS", OPTION_DOUBLE, FIELD(exposure), .min = -64, .max = 64, .default_text = "0",
     .help = "shared exposure (as the chapters' --exposure)"},
    {"--diff", "N", OPTION_CUSTOM, 0, .parse = parse_diff, .help = "error heat map of every panel against panel N"},
    {"--heat", NULL, OPTION_FLAG, FIELD(diff),
     .help = "error heat map against the default reference (the best image: see below)"},
    {"--reference", "N", OPTION_CUSTOM, 0, .parse = parse_reference,
     .help = "the reference panel for the heat map and the split (default: the best)"},
    {"--split", "A,B[,POS]", OPTION_CUSTOM, 0, .parse = parse_split,
     .help = "A/B split slider between panels A and B at POS (0..1, default 0.5)"},
    {"--zoom", "Z", OPTION_DOUBLE, FIELD(zoom), .min = 1e-3, .max = 1e4, .default_text = "1",
     .help = "shared zoom (1 = fit)"},
    {"--center", "U,V", OPTION_CUSTOM, 0, .parse = parse_center, .default_text = "0.5,0.5",
     .help = "image point (0..1) at the panel centres"},
    {"--cursor", "X,Y", OPTION_CUSTOM, 0, .parse = parse_cursor,
     .help = "cursor position in pixels (shows the radiance under it in every panel)"},
    {"--help-overlay", NULL, OPTION_FLAG, FIELD(help), .help = "show the key help"},
    {"--help-keys", NULL, OPTION_FLAG, FIELD(print_keys),
     .help = "print the keys (and mouse) as a Markdown table and exit"},
    {"--frames", "N", OPTION_INT, FIELD(frames), .min = 1, .max = 1e6,
     .help = "render N frames, print frames per second and exit"},
    {"--font", "FILE.ttf", OPTION_STRING, FIELD(font_path), .default_text = FONT_DEFAULT_PATH,
     .help = "the labels' font (missing: the 8x8 bitmap font)"},
    {"--font-size", "PX", OPTION_INT, FIELD(font_px), .min = 6, .max = 96, .default_text = "14",
     .help = "its pixel height; the layout below scales with it"},
    {"--help", NULL, OPTION_FLAG, FIELD(print_help), .help = "this list (also -h)"},
    {0},
};

static const option LIVE_OPTIONS[] = {
    {"--eye", "X,Y,Z", OPTION_CUSTOM, 0, .parse = parse_eye, .help = "camera position (default: the scene's camera)"},
    {"--look", "X,Y,Z", OPTION_CUSTOM, 0, .parse = parse_look, .help = "the point looked at"},
    {"--up", "X,Y,Z", OPTION_CUSTOM, 0, .parse = parse_up, .help = "the up direction"},
    {"--fov", "DEG", OPTION_DOUBLE, FIELD(cam_option.fov_degrees), .min = 1e-3, .max = 179,
     .help = "vertical field of view"},
    {"--chapter", "NAME", OPTION_CUSTOM, 0, .parse = parse_chapter, .help = "only this chapter (repeatable)"},
    {"--chapters", "DIR", OPTION_STRING, FIELD(chapters_dir),
     .help = "where the chapters are (default: beside the viewer)"},
    {"--budget", "SECONDS", OPTION_DOUBLE, FIELD(live_time), .min = 0.01, .max = 1e6, .default_text = "30",
     .help = "each child's --time per camera (the default: the path tracer converged enough to judge)"},
    {"--live-time", "SECONDS", OPTION_DOUBLE, 0, .alias_of = "--budget"},
    {"--exit-after-updates", "N", OPTION_INT, FIELD(exit_after_updates), .min = 1, .max = 1e6,
     .help = "headless live: stop after N updates of every chapter"},
    {"--no-shadows", NULL, OPTION_FLAG, FIELD(no_shadows),
     .help = "chapter 1's option, for the raster and passed to 01_local"},
    {"--ambient", "LA", OPTION_DOUBLE, FIELD(ambient), .min = 0, .max = 1e6,
     .help = "chapter 1's ambient radiance, likewise"},
    {"--raster-shader", "FILE.frag", OPTION_STRING, FIELD(raster_shader),
     .help = "replace the built-in Blinn-Phong fragment shader"},
    {"--verbose", NULL, OPTION_FLAG, FIELD(verbose),
     .help = "print the layout, every update and (window) every camera move"},
    {0},
};
#undef FIELD

static const struct {
    const char *title;
    const option *table;
} SECTIONS[] = {{"modes:", MODE_OPTIONS}, {"display:", DISPLAY_OPTIONS}, {"3D and live:", LIVE_OPTIONS}};
enum { SECTION_COUNT = sizeof SECTIONS / sizeof *SECTIONS };

static void usage(void)
{
    printf("usage: build/viewer [A.pfm B.pfm ...] [--scene NAME [--dir DIR]]\n"
           "                    [--live SCENE | --raster SCENE | --ply FILE.ply] [options]\n");
    for (int k = 0; k < SECTION_COUNT; k++) {
        printf("%s\n", SECTIONS[k].title);
        if (SECTIONS[k].table == MODE_OPTIONS)
            printf("  %-24s %s\n", "A.pfm B.pfm ...",
                   "compare: the images in a grid, each with its stats (X.json beside X.pfm)");
        options_print_help(stdout, SECTIONS[k].table);
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

static int bad(char *err, size_t err_size, const char *what, const char *value)
{
    snprintf(err, err_size, "argv:0: %s%s%s%s", what, value ? " '" : "", value ? value : "", value ? "'" : "");
    return 2;
}

/* What no single option can check: the options together. */
static int check_options(char *err, size_t err_size)
{
    if (V.cam_option.fov_degrees > 0)
        V.camera_given |= GIVEN_FOV;
    if (V.compare_scene && add_scene_panels(V.compare_scene, V.compare_dir, V.compare_scene_argv, err, err_size))
        return 2;
    if (V.mode != MODE_COMPARE && V.panel_count)
        return bad(err, err_size, "image files and --live/--raster/--ply do not mix", NULL);
    if (V.mode == MODE_COMPARE && !V.panel_count) {
        usage();
        return bad(err, err_size, "nothing to show: give PFM files, --scene, --live, --raster or --ply", NULL);
    }
    if (V.headless && V.backend_given && V.backend == BACKEND_GLFW)
        return bad(err, err_size, "--headless needs --backend egl or osmesa", NULL);
    if (V.headless && !V.out_path && !V.frames && !V.panel_out_path && !V.exit_after_updates)
        return bad(err, err_size, "--headless needs --out FILE.png (or --frames N)", NULL);
    if (V.out_path && !path_has_extension(V.out_path, ".png") && !path_has_extension(V.out_path, ".ppm"))
        return bad(err, err_size, "--out wants a .png or .ppm file, not", V.out_path);
    if (V.panel_out_path && !path_has_extension(V.panel_out_path, ".pfm"))
        return bad(err, err_size, "--panel-out wants a .pfm file, not", V.panel_out_path);
    return 0;
}

int parse_options(int argc, char **argv, char *err, size_t err_size)
{
    option_group groups[SECTION_COUNT];
    for (int k = 0; k < SECTION_COUNT; k++)
        groups[k] = (option_group){SECTIONS[k].table, &V};
    if (options_set_defaults(groups, SECTION_COUNT, err, err_size))
        return 2;
    V.reference = 0, V.split_b = 1, V.split_position = 0.5;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h"))
            V.print_help = true;
        else if (a[0] != '-' || !a[1]) {
            if (add_file_panel(a, err, err_size))
                return 2;
        } else {
            int status = options_parse_one(groups, SECTION_COUNT, argc, argv, &i, err, err_size);
            if (status == 0) {
                snprintf(err, err_size, "argv:%d: unknown option '%s' (see --help)", i, a);
                return 2;
            }
            if (status != 1)
                return status;
        }
        if (V.print_help || V.print_keys) {
            if (V.print_keys)
                print_keys_markdown();
            else
                usage();
            exit(0);
        }
    }
    return check_options(err, err_size);
}
