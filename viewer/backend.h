/* backend.h — where the OpenGL 3.3 core context comes from.
 *
 *   glfw    a window on an X display (the default when $DISPLAY is set)
 *   egl     headless: EGL on Mesa's surfaceless platform (no display, no window)
 *   osmesa  headless: Mesa's off-screen software renderer
 *
 * Everything after backend_open() is the same code: GL functions come from
 * the glad loader, filled through the backend's own get-proc-address.  The
 * EGL and OSMesa libraries are opened with dlopen() only when chosen, so a
 * process never has two GL implementations fighting over the gl* symbols
 * (the "-lGL -lOSMesa, first one wins" trap), and a missing library is a
 * clear message instead of a link error.
 */
#ifndef VIEWER_BACKEND_H
#define VIEWER_BACKEND_H

#include <stdbool.h>
#include <stddef.h>

typedef enum { BACKEND_GLFW, BACKEND_EGL, BACKEND_OSMESA } backend_kind;

struct GLFWwindow;

/* Create the context (and for glfw a width x height window), make it
 * current and load the GL functions.  Returns 0, or 3 with a message in err
 * when the backend is not available here (no display, no library ...). */
int backend_open(backend_kind kind, int width, int height, const char *title, char *err, size_t err_size);
void backend_close(void);
const char *backend_name(backend_kind kind);
bool backend_parse(const char *name, backend_kind *out);
/* The GLFW window, or NULL for the headless backends. */
struct GLFWwindow *backend_window(void);

#endif
