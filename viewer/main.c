/* main.c — build/viewer: every method side by side, interactive and headless.
 *
 *   build/viewer A.pfm B.pfm ...            compare mode (also --scene NAME [--dir out])
 *   build/viewer --live scenes/cornell.scene  every chapter as a child process, progressive
 *   build/viewer --raster scenes/cornell-point.scene  GLSL Blinn-Phong beside chapter 1
 *   build/viewer --ply out/cornell-03_radiosity.ply  radiosity's mesh, orbitable
 *   --headless --out FILE.png --size WxH     what the window would show, without one
 *
 * This file: the context, the window and headless loops, writing the screen (app.h: the other files).
 * `build/viewer --help` lists every option; key H in the window the keys.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "app.h"
#include "font.h"
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

viewer_state V;

volatile sig_atomic_t quit_requested;
static void on_signal(int sig)
{
    (void)sig;
    quit_requested = 1;
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

/* ---- the main loop ------------------------------------------------------------------------------- */

int save_screen(const char *path, int width, int height, char *err, size_t err_size)
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
    input_attach(window);
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

/* The backend: the window when there is a display, else headless (EGL,
 * then OSMesa).  0, 2 (no display and nothing to write) or 3, with a message. */
static int open_context(char *err, size_t err_size)
{
    bool display =
        (getenv("DISPLAY") && *getenv("DISPLAY")) || (getenv("WAYLAND_DISPLAY") && *getenv("WAYLAND_DISPLAY"));
    if (!V.backend_given)
        V.backend = V.headless || !display ? BACKEND_EGL : BACKEND_GLFW;
    if (V.backend != BACKEND_GLFW)
        V.headless = true;
    if (V.headless && !V.out_path && !V.frames && !V.panel_out_path && !V.exit_after_updates) {
        snprintf(err, err_size, "argv:0: no display ($DISPLAY is unset): give --out FILE.png to render headless");
        return 2;
    }
    int status = backend_open(V.backend, V.width, V.height, "viewer", err, err_size);
    if (status == 3 && !V.backend_given && V.backend == BACKEND_EGL) {
        fprintf(stderr, "%s; trying osmesa\n", err);
        V.backend = BACKEND_OSMESA;
        status = backend_open(V.backend, V.width, V.height, "viewer", err, err_size);
    }
    if (!status && V.backend == BACKEND_GLFW) {
        int fw, fh;
        glfwGetFramebufferSize(backend_window(), &fw, &fh);
        V.width = fw, V.height = fh;
    }
    return status;
}

static void free_everything(void)
{
    for (int i = 0; i < V.panel_count; i++)
        panel_free(&V.panels[i]);
    remove_temp_dir();
    if (V.screen.fbo)
        target_destroy(&V.screen);
    if (V.scene_loaded)
        scene_free(&V.scene);
    gfx_shutdown();
    backend_close();
}

int main(int argc, char **argv)
{
    char err[1024] = "";
    setvbuf(stdout, NULL, _IOLBF, 0);
    int status = parse_options(argc, argv, err, sizeof err);
    if (!status) {
        signal(SIGINT, on_signal);
        signal(SIGTERM, on_signal);
        signal(SIGPIPE, SIG_IGN);
        status = open_context(err, sizeof err);
    }
    if (status) {
        fprintf(stderr, "%s\n", err);
        return status;
    }
    status = gfx_init(V.raster_shader, V.font_path, V.font_px, err, sizeof err);
    if (!status) {
        printf("backend %s: %s\n", backend_name(V.backend), gfx_renderer());
        printf("font: %s, %d px\n", gfx_font(), V.font_px);
        print_gl_libraries();
        status = set_up(err, sizeof err);
    }
    if (!status && (((V.diff || V.split) && V.reference >= V.panel_count) ||
                    (V.split && (V.split_b >= V.panel_count || V.split_b == V.reference)))) {
        snprintf(err, sizeof err, "argv:0: --diff / --split name a panel that does not exist (there are %d)",
                 V.panel_count);
        status = 2;
    }
    if (!status)
        status = start_children(err, sizeof err);
    if (!status)
        status = V.headless ? headless_loop(err, sizeof err) : window_loop(err, sizeof err);
    if (status)
        fprintf(stderr, "%s\n", err);
    free_everything();
    return status;
}
