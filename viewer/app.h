/* app.h — the viewer's state and what its files share (viewer.h: panels and their sources).
 *
 *   options.c  the command line: one option table (common/options.h) for the parser and --help
 *   modes.c    each mode's panels: compare, live and raster children, the PLY; the reference
 *   frame.c    the layout and drawing one frame
 *   input.c    keys (one table for dispatch, the H overlay and --help-keys) and the mouse
 *   main.c     the context, the window and headless loops, writing the screen
 */
#ifndef VIEWER_APP_H
#define VIEWER_APP_H

#include <signal.h>

#include "backend.h"
#include "viewer.h"

typedef enum { MODE_COMPARE, MODE_LIVE, MODE_RASTER, MODE_PLY } viewer_mode;

/* Text metrics, from --font-size PX (default 14): a line of text is PX + 4
 * pixels; a label is 3 lines (+ 4) above its image or a column 18 PX wide
 * beside it (one field a line); the status line is 1 line (+ 4). */
enum { FONT_PX_DEFAULT = 14 };
#define LINE (V.font_px + 4)
#define LABEL_BAND (3 * LINE + 4)
#define STATUS_BAND (LINE + 4)
#define LABEL_COLUMN (18 * V.font_px)

/* --eye --look --up --fov given (viewer_state.camera_given) */
enum { GIVEN_EYE = 1, GIVEN_LOOK = 2, GIVEN_UP = 4, GIVEN_FOV = 8 };

typedef struct {
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
    int camera_given;                        /* GIVEN_EYE | GIVEN_LOOK | ... */
    const char *compare_scene, *compare_dir; /* --scene NAME, --dir DIR */
    int compare_scene_argv;                  /* where --scene stood, for messages */
    bool print_help, print_keys;             /* --help, --help-keys: print and exit */

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
} viewer_state;

extern viewer_state V;
extern volatile sig_atomic_t quit_requested;

extern const float WHITE[4], GREY[4], YELLOW[4], BAND[4], ORANGE[4], DIM[4];

/* options.c: parse argv into V (and compare mode's panels); 0 or 2 with "argv:N: message". */
int parse_options(int argc, char **argv, char *err, size_t err_size);

/* frame.c */
int shown_panels(void);
/* Panel i of n: its whole cell, its label and its image area. */
void panel_rects(int i, int n, int width, int height, rect *whole, rect *label, rect *area);
/* Where panel p's image sits in area: framebuffer pixel = origin + scale * image pixel. */
void placement(const panel *p, rect area, double *ox, double *oy, double *scale);
/* The panel under framebuffer point (x, y) and the image point there (0..1); -1 if none. */
int panel_at(double x, double y, double *u, double *v);
void label_lines(int index, char *title, size_t title_size, char *numbers, size_t numbers_size);
void draw_frame(GLuint fbo, int width, int height);

/* modes.c */
int set_up(char *err, size_t err_size);
void render_3d_panels(void);
int start_children(char *err, size_t err_size);
bool children_running(void);
bool poll_sources(void);
bool complete(void);
void remove_temp_dir(void);

/* input.c */
void print_keys_markdown(void);
void draw_help(int width, int height);
void orbit(double yaw_degrees, double pitch_degrees);
void input_attach(struct GLFWwindow *window);

/* main.c */
int save_screen(const char *path, int width, int height, char *err, size_t err_size);

#endif
