/* input.c — the viewer's keys and mouse: camera moves, zoom and pan, one key table. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

#include "app.h"
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

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
void orbit(double yaw_degrees, double pitch_degrees)
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
void print_keys_markdown(void)
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
void draw_help(int width, int height)
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

void input_attach(GLFWwindow *window)
{
    glfwSetKeyCallback(window, on_key);
    glfwSetCharCallback(window, on_char);
    glfwSetCursorPosCallback(window, on_cursor);
    glfwSetCursorEnterCallback(window, on_cursor_enter);
    glfwSetMouseButtonCallback(window, on_button);
    glfwSetScrollCallback(window, on_scroll);
    glfwSetFramebufferSizeCallback(window, on_resize);
}
