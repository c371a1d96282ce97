/* backend.c — GLFW window, EGL surfaceless and OSMesa contexts (see backend.h). */
#include "backend.h"

#include <dlfcn.h>
#include <stdint.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include <glad/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

/* Only the EGL and OSMesa constants we need, so their headers (and their
 * link-time symbols) stay out of the binary: both libraries are dlopen()ed. */
typedef void *egl_display;
typedef void *egl_context;
typedef void (*gl_proc)(void);
enum {
    EGL_NONE_ = 0x3038,
    EGL_OPENGL_API_ = 0x30A2,
    EGL_PLATFORM_SURFACELESS_MESA_ = 0x31DD,
    EGL_CONTEXT_MAJOR_VERSION_ = 0x3098,
    EGL_CONTEXT_MINOR_VERSION_ = 0x30FB,
    EGL_CONTEXT_OPENGL_PROFILE_MASK_ = 0x30FD,
    EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT_ = 0x1,
    EGL_EXTENSIONS_ = 0x3055,
    OSMESA_FORMAT_ = 0x22,
    OSMESA_RGBA_ = 0x1908,
    OSMESA_DEPTH_BITS_ = 0x30,
    OSMESA_STENCIL_BITS_ = 0x31,
    OSMESA_ACCUM_BITS_ = 0x32,
    OSMESA_PROFILE_ = 0x33,
    OSMESA_CORE_PROFILE_ = 0x34,
    OSMESA_CONTEXT_MAJOR_VERSION_ = 0x36,
    OSMESA_CONTEXT_MINOR_VERSION_ = 0x37,
};

static struct {
    backend_kind kind;
    bool open;
    GLFWwindow *window;
    void *library;
    /* EGL */
    egl_display display;
    egl_context context;
    unsigned (*eglTerminate)(egl_display);
    unsigned (*eglDestroyContext)(egl_display, egl_context);
    unsigned (*eglMakeCurrent)(egl_display, void *, void *, egl_context);
    gl_proc (*eglGetProcAddress)(const char *);
    /* OSMesa */
    void *osmesa_context;
    unsigned char *osmesa_buffer;
    void (*OSMesaDestroyContext)(void *);
    gl_proc (*OSMesaGetProcAddress)(const char *);
} B;

const char *backend_name(backend_kind kind)
{
    return kind == BACKEND_GLFW ? "glfw" : kind == BACKEND_EGL ? "egl" : "osmesa";
}

bool backend_parse(const char *name, backend_kind *out)
{
    if (!strcmp(name, "glfw"))
        *out = BACKEND_GLFW;
    else if (!strcmp(name, "egl"))
        *out = BACKEND_EGL;
    else if (!strcmp(name, "osmesa"))
        *out = BACKEND_OSMESA;
    else
        return false;
    return true;
}

GLFWwindow *backend_window(void) { return B.window; }

/* dlsym into a function pointer without the ISO C object-to-function cast. */
static bool symbol(const char *name, void *function_pointer, char *err, size_t err_size)
{
    void *p = dlsym(B.library, name);
    if (!p) {
        snprintf(err, err_size, "viewer: %s has no symbol %s", B.kind == BACKEND_EGL ? "libEGL" : "libOSMesa", name);
        return false;
    }
    memcpy(function_pointer, &p, sizeof p);
    return true;
}

static GLADapiproc load_glfw(const char *name) { return (GLADapiproc)glfwGetProcAddress(name); }
static GLADapiproc load_egl(const char *name) { return (GLADapiproc)B.eglGetProcAddress(name); }
static GLADapiproc load_osmesa(const char *name) { return (GLADapiproc)B.OSMesaGetProcAddress(name); }

static void glfw_error(int code, const char *message)
{
    (void)code;
    fprintf(stderr, "viewer: glfw: %s\n", message);
}

/* Keep a library loaded until the process ends, whoever dlclose()s it.
 * glfwTerminate() unloads libGL (and with it Mesa's GLX driver); the
 * driver's process-lifetime allocations would then show up in
 * LeakSanitizer as leaks of an "unknown module" that no suppression can
 * name (the sanitizer build runs the viewer tests too). */
static void pin_library(const char *name)
{
    void *handle = dlopen(name, RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
    (void)handle; /* not an error if absent: GLFW says so when it needs it */
}

/* Mesa's software DRI driver, shared by its GLX and EGL front ends. */
static void pin_dri_driver(void)
{
    static const char *paths[] = {"/usr/lib/x86_64-linux-gnu/dri/swrast_dri.so",
                                  "/usr/lib/aarch64-linux-gnu/dri/swrast_dri.so", "/usr/lib64/dri/swrast_dri.so",
                                  "/usr/lib/dri/swrast_dri.so"};
    for (size_t i = 0; i < sizeof paths / sizeof *paths; i++)
        if (access(paths[i], R_OK) == 0) {
            pin_library(paths[i]);
            return;
        }
}

static int open_glfw(int width, int height, const char *title, char *err, size_t err_size)
{
    pin_library("libGL.so.1");
    pin_library("libGLX_mesa.so.0");
    pin_dri_driver();
    glfwSetErrorCallback(glfw_error);
    if (!glfwInit()) {
        snprintf(err, err_size, "viewer: glfw: cannot initialise (no X display? $DISPLAY=%s); try --headless",
                 getenv("DISPLAY") ? getenv("DISPLAY") : "unset");
        return 3;
    }
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
    glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
    glfwWindowHint(GLFW_SRGB_CAPABLE, GLFW_FALSE);
    glfwWindowHint(GLFW_SCALE_TO_MONITOR, GLFW_FALSE);
    B.window = glfwCreateWindow(width, height, title, NULL, NULL);
    if (!B.window) {
        glfwTerminate();
        snprintf(err, err_size, "viewer: glfw: cannot open a %dx%d OpenGL 3.3 core window; try --headless", width,
                 height);
        return 3;
    }
    glfwMakeContextCurrent(B.window);
    glfwSwapInterval(1);
    if (!gladLoadGL(load_glfw)) {
        snprintf(err, err_size, "viewer: glfw: cannot load the OpenGL 3.3 functions");
        return 3;
    }
    return 0;
}

static int open_egl(char *err, size_t err_size)
{
    pin_library("libEGL_mesa.so.0");
    pin_dri_driver();
    B.library = dlopen("libEGL.so.1", RTLD_NOW | RTLD_LOCAL);
    if (!B.library) {
        snprintf(err, err_size, "viewer: egl: cannot load libEGL.so.1 (apt-get install libegl1): %s", dlerror());
        return 3;
    }
    egl_display (*eglGetPlatformDisplay)(unsigned, void *, const intptr_t *);
    egl_display (*eglGetPlatformDisplayEXT)(unsigned, void *, const int *);
    unsigned (*eglInitialize)(egl_display, int *, int *);
    unsigned (*eglBindAPI)(unsigned);
    egl_context (*eglCreateContext)(egl_display, void *, egl_context, const int *);
    const char *(*eglQueryString)(egl_display, int);
    if (!symbol("eglGetProcAddress", &B.eglGetProcAddress, err, err_size) ||
        !symbol("eglInitialize", &eglInitialize, err, err_size) || !symbol("eglBindAPI", &eglBindAPI, err, err_size) ||
        !symbol("eglCreateContext", &eglCreateContext, err, err_size) ||
        !symbol("eglMakeCurrent", &B.eglMakeCurrent, err, err_size) ||
        !symbol("eglDestroyContext", &B.eglDestroyContext, err, err_size) ||
        !symbol("eglQueryString", &eglQueryString, err, err_size) ||
        !symbol("eglTerminate", &B.eglTerminate, err, err_size))
        return 3;
    (void)eglGetPlatformDisplay;
    gl_proc p = B.eglGetProcAddress("eglGetPlatformDisplayEXT");
    memcpy(&eglGetPlatformDisplayEXT, &p, sizeof p);
    const char *client_extensions = eglQueryString(NULL, EGL_EXTENSIONS_);
    if (!eglGetPlatformDisplayEXT || !client_extensions ||
        !strstr(client_extensions, "EGL_MESA_platform_surfaceless")) {
        snprintf(err, err_size, "viewer: egl: no EGL_MESA_platform_surfaceless (is Mesa's libegl-mesa0 installed?)");
        return 3;
    }
    B.display = eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA_, NULL, NULL);
    int major = 0, minor = 0;
    if (!B.display || !eglInitialize(B.display, &major, &minor)) {
        snprintf(err, err_size, "viewer: egl: cannot initialise the surfaceless display");
        return 3;
    }
    const char *extensions = eglQueryString(B.display, EGL_EXTENSIONS_);
    if (!extensions || !strstr(extensions, "EGL_KHR_surfaceless_context") ||
        !strstr(extensions, "EGL_KHR_no_config_context")) {
        snprintf(err, err_size, "viewer: egl: the display lacks EGL_KHR_surfaceless_context / no_config_context");
        return 3;
    }
    if (!eglBindAPI(EGL_OPENGL_API_)) {
        snprintf(err, err_size, "viewer: egl: desktop OpenGL is not available");
        return 3;
    }
    const int attributes[] = {
        EGL_CONTEXT_MAJOR_VERSION_,           3,        EGL_CONTEXT_MINOR_VERSION_, 3, EGL_CONTEXT_OPENGL_PROFILE_MASK_,
        EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT_, EGL_NONE_};
    B.context = eglCreateContext(B.display, NULL /* EGL_NO_CONFIG_KHR */, NULL, attributes);
    if (!B.context || !B.eglMakeCurrent(B.display, NULL, NULL, B.context)) {
        snprintf(err, err_size, "viewer: egl: cannot create an OpenGL 3.3 core context");
        return 3;
    }
    if (!gladLoadGL(load_egl)) {
        snprintf(err, err_size, "viewer: egl: cannot load the OpenGL 3.3 functions");
        return 3;
    }
    return 0;
}

static int open_osmesa(char *err, size_t err_size)
{
    B.library = dlopen("libOSMesa.so.8", RTLD_NOW | RTLD_LOCAL);
    if (!B.library)
        B.library = dlopen("libOSMesa.so", RTLD_NOW | RTLD_LOCAL);
    if (!B.library) {
        snprintf(err, err_size, "viewer: osmesa: cannot load libOSMesa (apt-get install libosmesa6): %s", dlerror());
        return 3;
    }
    void *(*OSMesaCreateContextAttribs)(const int *, void *);
    unsigned char (*OSMesaMakeCurrent)(void *, void *, unsigned, int, int);
    if (!symbol("OSMesaCreateContextAttribs", &OSMesaCreateContextAttribs, err, err_size) ||
        !symbol("OSMesaMakeCurrent", &OSMesaMakeCurrent, err, err_size) ||
        !symbol("OSMesaGetProcAddress", &B.OSMesaGetProcAddress, err, err_size) ||
        !symbol("OSMesaDestroyContext", &B.OSMesaDestroyContext, err, err_size))
        return 3;
    const int attributes[] = {OSMESA_FORMAT_,
                              OSMESA_RGBA_,
                              OSMESA_DEPTH_BITS_,
                              24,
                              OSMESA_STENCIL_BITS_,
                              0,
                              OSMESA_ACCUM_BITS_,
                              0,
                              OSMESA_PROFILE_,
                              OSMESA_CORE_PROFILE_,
                              OSMESA_CONTEXT_MAJOR_VERSION_,
                              3,
                              OSMESA_CONTEXT_MINOR_VERSION_,
                              3,
                              0};
    B.osmesa_context = OSMesaCreateContextAttribs(attributes, NULL);
    /* OSMesa wants a colour buffer to make a context current; we draw into
     * our own framebuffer object, so a tiny one does. */
    static unsigned char buffer[4 * 4 * 4];
    if (!B.osmesa_context || !OSMesaMakeCurrent(B.osmesa_context, buffer, 0x1401 /* GL_UNSIGNED_BYTE */, 4, 4)) {
        snprintf(err, err_size, "viewer: osmesa: cannot create an OpenGL 3.3 core context");
        return 3;
    }
    if (!gladLoadGL(load_osmesa)) {
        snprintf(err, err_size, "viewer: osmesa: cannot load the OpenGL 3.3 functions");
        return 3;
    }
    return 0;
}

int backend_open(backend_kind kind, int width, int height, const char *title, char *err, size_t err_size)
{
    memset(&B, 0, sizeof B);
    B.kind = kind;
    int status = kind == BACKEND_GLFW  ? open_glfw(width, height, title, err, err_size)
                 : kind == BACKEND_EGL ? open_egl(err, err_size)
                                       : open_osmesa(err, err_size);
    B.open = status == 0;
    if (!B.open)
        backend_close();
    return status;
}

void backend_close(void)
{
    if (B.kind == BACKEND_GLFW) {
        if (B.window)
            glfwDestroyWindow(B.window);
        if (B.window || B.open)
            glfwTerminate();
        B.window = NULL;
    } else if (B.kind == BACKEND_EGL && B.library) {
        if (B.context) {
            B.eglMakeCurrent(B.display, NULL, NULL, NULL);
            B.eglDestroyContext(B.display, B.context);
        }
        if (B.display && B.eglTerminate)
            B.eglTerminate(B.display);
    } else if (B.kind == BACKEND_OSMESA && B.library) {
        if (B.osmesa_context)
            B.OSMesaDestroyContext(B.osmesa_context);
    }
    /* The GL libraries stay loaded: Mesa registers atexit handlers and
     * thread-local state that must outlive an early dlclose. */
    B.open = false;
}
