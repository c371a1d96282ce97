/* sources.c — where panel images come from: PFM files and their stats,
 * chapters run as child processes, the scene and PLY meshes (see viewer.h). */
#include "viewer.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

double now_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* ---- PFM panels and their stats ------------------------------------------------------------- */

void panel_upload(panel *p)
{
    if (!p->texture)
        glGenTextures(1, &p->texture);
    glBindTexture(GL_TEXTURE_2D, p->texture);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGB32F, p->img.width, p->img.height, 0, GL_RGB, GL_FLOAT, p->img.pixels);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
}

void panel_free(panel *p)
{
    if (p->pid > 0)
        child_stop(p);
    image_free(&p->img);
    if (p->target.fbo) {
        target_destroy(&p->target);
        p->texture = 0; /* it was the target's colour texture */
    }
    if (p->mesh.vao)
        mesh_destroy(&p->mesh);
    if (p->texture)
        glDeleteTextures(1, &p->texture);
    p->texture = 0;
}

/* The number after "key": anywhere in the JSON text (the stats objects are
 * flat enough that every key we want is unique), or NAN. */
static double json_number_of(const char *json, const char *key)
{
    char pattern[80];
    snprintf(pattern, sizeof pattern, "\"%s\":", key);
    const char *at = strstr(json, pattern);
    if (!at)
        return NAN;
    char *end;
    double v = strtod(at + strlen(pattern), &end);
    return end == at + strlen(pattern) ? NAN : v;
}

static void json_string_of(const char *json, const char *key, char *out, size_t out_size)
{
    char pattern[80];
    snprintf(pattern, sizeof pattern, "\"%s\": \"", key);
    const char *at = strstr(json, pattern);
    if (!at)
        return;
    at += strlen(pattern);
    size_t n = 0;
    while (at[n] && at[n] != '"' && n + 1 < out_size)
        n++;
    memcpy(out, at, n);
    out[n] = '\0';
}

static bool json_true(const char *json, const char *key)
{
    char pattern[80];
    snprintf(pattern, sizeof pattern, "\"%s\": true", key);
    return strstr(json, pattern) != NULL;
}

/* "bounces": [A, B]: the Neumann terms rendered; every one is [0, 1000000]. */
static void json_bounces(const char *json, char *out, size_t out_size)
{
    const char *at = strstr(json, "\"bounces\": [");
    double a, b;
    out[0] = '\0';
    if (!at || sscanf(at + strlen("\"bounces\": ["), "%lf , %lf", &a, &b) != 2 || (a == 0 && b >= 1e6))
        return;
    if (b >= 1e6)
        snprintf(out, out_size, "bounces %.0f:", a);
    else
        snprintf(out, out_size, "bounces %.0f:%.0f", a, b);
}

/* What variant of its chapter an image is: the estimator (path tracing),
 * the solver (radiosity), the photon maps, the local model (chapters 1, 2),
 * the bounces. */
static void stats_variant(const char *json, char *out, size_t out_size)
{
    char estimator[32] = "", solver[32] = "", maps[32] = "", model[32] = "", bounces[48];
    json_string_of(json, "estimator", estimator, sizeof estimator);
    json_string_of(json, "maps", maps, sizeof maps);
    json_string_of(json, "solver_used", solver, sizeof solver);
    if (!solver[0])
        json_string_of(json, "solver", solver, sizeof solver);
    json_string_of(json, "model", model, sizeof model);
    json_bounces(json, bounces, sizeof bounces);
    size_t used = 0;
    out[0] = '\0';
    if (estimator[0])
        used += (size_t)snprintf(out + used, out_size - used, "estimator %s  ", estimator);
    if (solver[0] && used < out_size)
        used += (size_t)snprintf(out + used, out_size - used, "solver %s  ", solver);
    if (maps[0] && used < out_size)
        used += (size_t)snprintf(out + used, out_size - used, "maps %s  ", maps);
    if (model[0] && used < out_size)
        used += (size_t)snprintf(out + used, out_size - used, "model %s%s%s  ", model,
                                 json_true(json, "normalised") ? " normalised" : "",
                                 strstr(json, "\"shadows\": false") ? " no shadows" : "");
    if (bounces[0] && used < out_size)
        used += (size_t)snprintf(out + used, out_size - used, "%s  ", bounces);
    while (used > 0 && used < out_size && out[used - 1] == ' ')
        out[--used] = '\0';
}

void panel_read_stats(panel *p, const char *json_path)
{
    FILE *f = fopen(json_path, "rb");
    if (!f)
        return;
    char json[1 << 16];
    size_t n = fread(json, 1, sizeof json - 1, f);
    fclose(f);
    json[n] = '\0';
    json_string_of(json, "chapter", p->method, sizeof p->method);
    stats_variant(json, p->variant, sizeof p->variant);
    char estimator[32] = "", bounces[48];
    static const char *ranked[] = {"hemisphere", "cosine", "light", "mis"};
    json_string_of(json, "estimator", estimator, sizeof estimator);
    p->estimator_rank = 0;
    for (int k = 0; k < 4; k++)
        p->estimator_rank = strcmp(estimator, ranked[k]) ? p->estimator_rank : k + 1;
    json_bounces(json, bounces, sizeof bounces);
    p->all_bounces = !bounces[0] && strstr(json, "\"bounces\": [");
    p->spp = json_number_of(json, "spp"), p->relmse = json_number_of(json, "relmse");
    p->has_stats = true;
    char detail[160] = "";
    size_t used = 0;
    double patches = json_number_of(json, "patches"), spp = json_number_of(json, "spp");
    double time_s = json_number_of(json, "time_s"), relmse = p->relmse;
    if (isfinite(patches))
        used += (size_t)snprintf(detail + used, sizeof detail - used, "patches %.0f  ", patches);
    else if (isfinite(spp))
        used += (size_t)snprintf(detail + used, sizeof detail - used, "spp %.0f  ", spp);
    if (isfinite(time_s) && used < sizeof detail)
        used += (size_t)snprintf(detail + used, sizeof detail - used, "%.2f s  ", time_s);
    /* The relative error, (t - r)^2 / (r^2 + 0.01): an absolute one (RMSE) is
     * ruled by the few pixels on the light's edge, where radiance is 100 x
     * the walls', and would rank a method by how it draws the light's edge. */
    if (isfinite(relmse) && used < sizeof detail)
        snprintf(detail + used, sizeof detail - used, "rel.MSE %.3g", relmse);
    for (size_t end = strlen(detail); end > 0 && detail[end - 1] == ' ';)
        detail[--end] = '\0';
    snprintf(p->detail, sizeof p->detail, "%s", detail);
}

/* foo/bar/cornell-04_pathtrace.pfm -> cornell-04_pathtrace */
static void stem(const char *path, char *out, size_t out_size)
{
    const char *base = strrchr(path, '/');
    base = base ? base + 1 : path;
    snprintf(out, out_size, "%s", base);
    char *dot = strrchr(out, '.');
    if (dot && dot != out)
        *dot = '\0';
}

int panel_load_pfm(panel *p, const char *path, char *err, size_t err_size)
{
    image img;
    /* A scene or a mesh is not an image to compare: say which mode shows it. */
    if (path_has_extension(path, ".scene")) {
        snprintf(err, err_size, "%s:0: a scene, not an image: --live %s renders it with every chapter", path, path);
        return 2;
    }
    if (path_has_extension(path, ".ply")) {
        snprintf(err, err_size, "%s:0: a mesh, not an image: --ply %s shows it", path, path);
        return 2;
    }
    if (image_read_pfm(path, &img, err, err_size))
        return 2;
    image_free(&p->img);
    p->img = img;
    panel_upload(p);
    p->updates++;
    stat(path, &p->seen);
    if (p->kind == SOURCE_FILE) {
        snprintf(p->path, sizeof p->path, "%s", path);
        stem(path, p->method, sizeof p->method);
        const char *base = strrchr(path, '/');
        snprintf(p->file, sizeof p->file, "%s", base ? base + 1 : path);
        snprintf(p->detail, sizeof p->detail, "%dx%d", img.width, img.height);
        /* the stats beside it: x.pfm -> x.json */
        snprintf(p->stats_path, sizeof p->stats_path, "%s", path);
        char *dot = strrchr(p->stats_path, '.');
        if (dot && strlen(dot) == 4 && strlen(p->stats_path) + 1 < sizeof p->stats_path)
            strcpy(dot, ".json");
        panel_read_stats(p, p->stats_path);
    } else if (p->kind == SOURCE_CHILD) {
        panel_read_stats(p, p->stats_path); /* the chapters rewrite the stats with every pass */
        p->stale = false;                   /* a pass of the current run */
    }
    return 0;
}

bool panel_poll(panel *p)
{
    if (p->kind != SOURCE_FILE && p->kind != SOURCE_CHILD)
        return false;
    struct stat now;
    if (stat(p->path, &now) != 0)
        return false;
    if (p->updates && now.st_ino == p->seen.st_ino && now.st_size == p->seen.st_size &&
        now.st_mtim.tv_sec == p->seen.st_mtim.tv_sec && now.st_mtim.tv_nsec == p->seen.st_mtim.tv_nsec)
        return false;
    char err[512];
    /* Chapters write to a temporary and rename, so the file is whole; if
     * it still fails to read, keep the old image and try again next time. */
    if (panel_load_pfm(p, p->path, err, sizeof err)) {
        p->seen = now;
        return false;
    }
    return true;
}

/* ---- children ------------------------------------------------------------------------------- */

/* The chapter's command line: its scene, outputs, size, budget, the
 * viewer's camera and the mode's extra options. */
typedef struct {
    char size[64], budget[64], eye[128], look[128], up[128], fov[64];
    const char *argv[40];
} child_args;

static const char **child_argv(child_args *a, const panel *p, const child_spec *spec)
{
    snprintf(a->size, sizeof a->size, "%dx%d", spec->width, spec->height);
    snprintf(a->budget, sizeof a->budget, "%g", spec->time_budget);
    snprintf(a->eye, sizeof a->eye, "%.17g,%.17g,%.17g", spec->cam.eye.x, spec->cam.eye.y, spec->cam.eye.z);
    snprintf(a->look, sizeof a->look, "%.17g,%.17g,%.17g", spec->cam.look.x, spec->cam.look.y, spec->cam.look.z);
    snprintf(a->up, sizeof a->up, "%.17g,%.17g,%.17g", spec->cam.up.x, spec->cam.up.y, spec->cam.up.z);
    snprintf(a->fov, sizeof a->fov, "%.17g", spec->cam.fov_degrees);
    const char **argv = a->argv;
    int argc = 0;
    const char *fixed[] = {p->exe,    spec->scene_path, "--quiet", "--out", p->path,
                           "--stats", p->stats_path,    "--size",  a->size};
    for (size_t k = 0; k < sizeof fixed / sizeof *fixed; k++)
        argv[argc++] = fixed[k];
    if (spec->time_budget > 0) {
        argv[argc++] = "--time";
        argv[argc++] = a->budget;
    }
    const char *camera[] = {"--eye", a->eye, "--look", a->look, "--up", a->up, "--fov", a->fov};
    for (size_t k = 0; k < sizeof camera / sizeof *camera; k++)
        argv[argc++] = camera[k];
    for (int i = 0; i < spec->extra_count; i++)
        argv[argc++] = spec->extra[i];
    argv[argc] = NULL;
    return argv;
}

int child_start(panel *p, const child_spec *spec, char *err, size_t err_size)
{
    const char *name = strrchr(p->exe, '/') ? strrchr(p->exe, '/') + 1 : p->exe;
    snprintf(p->method, sizeof p->method, "%.63s", name);
    snprintf(p->path, sizeof p->path, "%.3000s/%.900s.pfm", spec->directory, name);
    snprintf(p->stats_path, sizeof p->stats_path, "%.3000s/%.900s.json", spec->directory, name);
    snprintf(p->log_path, sizeof p->log_path, "%.3000s/%.900s.log", spec->directory, name);
    unlink(p->stats_path);
    /* A restart: the old image stays on screen, marked stale, until the new
     * run's first pass replaces the file (the old one is removed, so it
     * cannot be mistaken for the new run's). */
    p->stale = p->img.pixels != NULL;
    unlink(p->path);
    p->warning[0] = '\0', p->warnings = 0, p->log_read = 0;

    child_args args;
    const char **argv = child_argv(&args, p, spec);
    int log_fd = open(p->log_path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    pid_t parent = getpid();
    fflush(stdout);
    fflush(stderr);
    pid_t pid = fork();
    if (pid < 0) {
        if (log_fd >= 0)
            close(log_fd);
        snprintf(err, err_size, "viewer: cannot start %s: %s", p->exe, strerror(errno));
        return 2;
    }
    if (pid == 0) {
        /* The child dies with the viewer, however the viewer ends. */
        prctl(PR_SET_PDEATHSIG, SIGKILL);
        if (getppid() != parent)
            _exit(127);
        int null_fd = open("/dev/null", O_RDONLY);
        if (null_fd >= 0)
            dup2(null_fd, STDIN_FILENO);
        if (log_fd >= 0) {
            dup2(log_fd, STDOUT_FILENO);
            dup2(log_fd, STDERR_FILENO);
        }
        execv(p->exe, (char *const *)argv);
        fprintf(stderr, "viewer: cannot run %s: %s\n", p->exe, strerror(errno));
        _exit(127);
    }
    if (log_fd >= 0)
        close(log_fd);
    p->pid = pid;
    p->exit_status = -1;
    p->started = now_seconds();
    p->generation++;
    snprintf(p->detail, sizeof p->detail, "running");
    return 0;
}

bool child_poll_warnings(panel *p)
{
    FILE *f = fopen(p->log_path, "r");
    if (!f)
        return false;
    bool found = false;
    char line[512];
    if (fseek(f, p->log_read, SEEK_SET) == 0)
        while (fgets(line, sizeof line, f)) {
            size_t n = strlen(line);
            if (n == 0 || (line[n - 1] != '\n' && n + 1 < sizeof line))
                break;              /* a line still being written: read it next time */
            p->log_read += (long)n; /* (a longer line: the rest is read as a line of its own) */
            line[strcspn(line, "\n")] = '\0';
            if (strncmp(line, "warning:", 8) == 0) {
                snprintf(p->warning, sizeof p->warning, "%.159s", line);
                p->warnings++;
                found = true;
            }
        }
    fclose(f);
    return found;
}

void child_stop(panel *p)
{
    if (p->pid <= 0)
        return;
    kill(p->pid, SIGTERM);
    int status;
    while (waitpid(p->pid, &status, 0) < 0 && errno == EINTR)
        ;
    p->pid = 0;
}

bool child_reap(panel *p)
{
    if (p->pid <= 0)
        return false;
    int status;
    pid_t r = waitpid(p->pid, &status, WNOHANG);
    if (r != p->pid)
        return false;
    p->pid = 0;
    p->exit_status = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    panel_poll(p); /* the final image */
    if (p->exit_status == 0) {
        panel_read_stats(p, p->stats_path);
    } else {
        /* Say why: the last line of the child's log. */
        char last[256] = "", line[256];
        FILE *f = fopen(p->log_path, "r");
        while (f && fgets(line, sizeof line, f))
            if (line[0] != '\n')
                snprintf(last, sizeof last, "%s", line);
        if (f)
            fclose(f);
        last[strcspn(last, "\n")] = '\0';
        fprintf(stderr, "viewer: %s exited with status %d: %s\n", p->exe, p->exit_status, last);
        snprintf(p->detail, sizeof p->detail, "exit %d: %.120s", p->exit_status, last);
    }
    return true;
}

/* ---- meshes --------------------------------------------------------------------------------- */

static void put_vertex(float *v, vec3 position, vec3 normal, const material *m)
{
    vec3 kd = m->albedo, ks = v3_splat(0.0), emission = v3_splat(0.0);
    double exponent = 1.0;
    if (m->kind == MATERIAL_PHONG)
        ks = m->specular, exponent = m->exponent;
    if (m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS)
        kd = m->specular; /* chapter 1 shades them as diffuse surfaces of their colour */
    if (m->kind == MATERIAL_EMITTER)
        emission = m->emission;
    const float f[MESH_FLOATS] = {(float)position.x, (float)position.y, (float)position.z, (float)normal.x,
                                  (float)normal.y,   (float)normal.z,   (float)kd.x,       (float)kd.y,
                                  (float)kd.z,       (float)ks.x,       (float)ks.y,       (float)ks.z,
                                  (float)exponent,   (float)emission.x, (float)emission.y, (float)emission.z};
    memcpy(v, f, sizeof f);
}

enum { SPHERE_RINGS = 48, SPHERE_SEGMENTS = 96 };

static vec3 sphere_point(vec3 c, double r, int ring, int segment)
{
    double theta = M_PI * ring / SPHERE_RINGS, phi = 2.0 * M_PI * segment / SPHERE_SEGMENTS;
    return v3_add(c, v3_scale(v3(sin(theta) * cos(phi), cos(theta), sin(theta) * sin(phi)), r));
}

int scene_mesh(const scene *s, mesh *m, mesh_uniforms *u, vec3 ambient, char *err, size_t err_size)
{
    int vertices = 3 * s->triangle_count + 6 * SPHERE_RINGS * SPHERE_SEGMENTS * s->sphere_count;
    float *v = malloc((size_t)(vertices > 0 ? vertices : 1) * MESH_FLOATS * sizeof(float));
    if (!v) {
        snprintf(err, err_size, "%s:0: out of memory", s->path);
        return 2;
    }
    int n = 0;
    for (int t = 0; t < s->triangle_count; t++) {
        const triangle *tri = &s->triangles[t];
        const material *mat = &s->materials[s->surfaces[tri->surface].material];
        vec3 p[3] = {tri->p0, v3_add(tri->p0, tri->e1), v3_add(tri->p0, tri->e2)};
        for (int k = 0; k < 3; k++)
            put_vertex(v + MESH_FLOATS * n++, p[k], tri->normal, mat);
    }
    for (int i = 0; i < s->surface_count; i++) {
        const surface *sf = &s->surfaces[i];
        if (sf->kind != SURFACE_SPHERE)
            continue;
        const material *mat = &s->materials[sf->material];
        for (int r = 0; r < SPHERE_RINGS; r++)
            for (int g = 0; g < SPHERE_SEGMENTS; g++) {
                vec3 q[6] = {
                    sphere_point(sf->center, sf->radius, r, g),         sphere_point(sf->center, sf->radius, r + 1, g),
                    sphere_point(sf->center, sf->radius, r + 1, g + 1), sphere_point(sf->center, sf->radius, r, g),
                    sphere_point(sf->center, sf->radius, r + 1, g + 1), sphere_point(sf->center, sf->radius, r, g + 1)};
                for (int k = 0; k < 6; k++)
                    put_vertex(v + MESH_FLOATS * n++, q[k], v3_normalize(v3_sub(q[k], sf->center)), mat);
            }
    }
    mesh_upload(m, v, n);
    free(v);

    /* Lights: the point lights as they are (R1); an emitting surface becomes
     * one point at its centre with the intensity a Lambertian emitter sends
     * (L A cos theta_y for a planar one, L pi r^2 for a sphere): the way a
     * GPU renderer without area lights approximates them. */
    memset(u, 0, sizeof *u);
    u->ambient[0] = (float)ambient.x, u->ambient[1] = (float)ambient.y, u->ambient[2] = (float)ambient.z;
    for (int l = 0; l < s->light_count && u->light_count < MAX_LIGHTS; l++) {
        int k = u->light_count++;
        const point_light *pl = &s->lights[l];
        u->light_position[k][0] = (float)pl->position.x, u->light_position[k][1] = (float)pl->position.y;
        u->light_position[k][2] = (float)pl->position.z;
        u->light_intensity[k][0] = (float)pl->intensity.x, u->light_intensity[k][1] = (float)pl->intensity.y;
        u->light_intensity[k][2] = (float)pl->intensity.z;
    }
    for (int e = 0; e < s->emitter_count && u->light_count < MAX_LIGHTS; e++) {
        const surface *sf = &s->surfaces[s->emitters[e]];
        vec3 radiance = s->materials[sf->material].emission, centre = v3_splat(0.0), normal = v3(0, -1, 0);
        vec3 intensity;
        int k = u->light_count++;
        if (sf->kind == SURFACE_SPHERE) {
            centre = sf->center;
            intensity = v3_scale(radiance, M_PI * sf->radius * sf->radius);
        } else {
            double area = 0.0;
            for (int t = sf->first_triangle; t < sf->first_triangle + sf->triangle_count; t++) {
                const triangle *tri = &s->triangles[t];
                vec3 c = v3_add(tri->p0, v3_scale(v3_add(tri->e1, tri->e2), 1.0 / 3.0));
                centre = v3_add(centre, v3_scale(c, tri->area));
                area += tri->area;
                normal = tri->normal;
            }
            centre = v3_scale(centre, 1.0 / area);
            /* a hair in front of the surface, so its own plane is not lit edge-on */
            centre = v3_add(centre, v3_scale(normal, 1e-6 * v3_length(v3_sub(s->bounds.hi, s->bounds.lo))));
            intensity = v3_scale(radiance, area);
            u->light_cosine[k] = 1;
        }
        u->light_position[k][0] = (float)centre.x, u->light_position[k][1] = (float)centre.y;
        u->light_position[k][2] = (float)centre.z;
        u->light_intensity[k][0] = (float)intensity.x, u->light_intensity[k][1] = (float)intensity.y;
        u->light_intensity[k][2] = (float)intensity.z;
        u->light_normal[k][0] = (float)normal.x, u->light_normal[k][1] = (float)normal.y;
        u->light_normal[k][2] = (float)normal.z;
    }
    return 0;
}

/* PLY (ascii or binary_little_endian): vertex x y z and a colour (float
 * radiance r g b, red green blue, radiance_r ...; uchar colours are taken as
 * sRGB and decoded), faces as index lists (fans).  Enough for radiosity's
 * output, Blender's and MeshLab's. */
typedef struct {
    char name[64];
    int type;
    int list_count_type;
} ply_property; /* type: 0 none 1 int 2 float 3 uchar... */

enum { PLY_CHAR, PLY_UCHAR, PLY_SHORT, PLY_USHORT, PLY_INT, PLY_UINT, PLY_FLOAT, PLY_DOUBLE, PLY_BAD };

static int ply_type(const char *t)
{
    static const char *names[][2] = {{"char", "int8"}, {"uchar", "uint8"}, {"short", "int16"},   {"ushort", "uint16"},
                                     {"int", "int32"}, {"uint", "uint32"}, {"float", "float32"}, {"double", "float64"}};
    for (int i = 0; i < PLY_BAD; i++)
        if (!strcmp(t, names[i][0]) || !strcmp(t, names[i][1]))
            return i;
    return PLY_BAD;
}

static double ply_read(FILE *f, int type, bool ascii, bool *ok)
{
    if (ascii) {
        double v;
        if (fscanf(f, "%lf", &v) != 1)
            *ok = false;
        return *ok ? v : 0.0;
    }
    static const int sizes[] = {1, 1, 2, 2, 4, 4, 4, 8};
    unsigned char b[8] = {0};
    if (fread(b, 1, (size_t)sizes[type], f) != (size_t)sizes[type]) {
        *ok = false;
        return 0.0;
    }
    uint64_t u = 0;
    for (int i = sizes[type] - 1; i >= 0; i--)
        u = u << 8 | b[i];
    switch (type) {
    case PLY_CHAR: return (double)(int8_t)u;
    case PLY_UCHAR: return (double)(uint8_t)u;
    case PLY_SHORT: return (double)(int16_t)u;
    case PLY_USHORT: return (double)(uint16_t)u;
    case PLY_INT: return (double)(int32_t)u;
    case PLY_UINT: return (double)(uint32_t)u;
    case PLY_FLOAT: {
        uint32_t w = (uint32_t)u;
        float x;
        memcpy(&x, &w, 4);
        return x;
    }
    default: {
        double x;
        memcpy(&x, &u, 8);
        return x;
    }
    }
}

static double srgb_decode(double v) { return v <= 0.04045 ? v / 12.92 : pow((v + 0.055) / 1.055, 2.4); }

int ply_mesh(const char *path, mesh *m, vec3 *lo, vec3 *hi, char *err, size_t err_size)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, err_size, "%s:0: cannot open: %s", path, strerror(errno));
        return 2;
    }
    char line[512];
    int line_number = 0;
    bool ascii = false, binary = false;
    long vertex_count = -1, face_count = 0;
    ply_property vprops[32], fprops[8];
    int vprop_count = 0, fprop_count = 0;
    int current = 0; /* 1 vertex, 2 face, 3 other element */
    int status = 2;
    float *v = NULL;
    double *vertex_data = NULL;
    if (!fgets(line, sizeof line, f) || strncmp(line, "ply", 3)) {
        snprintf(err, err_size, "%s:1: not a PLY file (no 'ply' line)", path);
        goto done;
    }
    line_number = 1;
    while (fgets(line, sizeof line, f)) {
        line_number++;
        char word[64] = "", a[64] = "", b[64] = "", c[64] = "", d[64] = "";
        int n = sscanf(line, "%63s %63s %63s %63s %63s", word, a, b, c, d);
        if (n <= 0 || !strcmp(word, "comment") || !strcmp(word, "obj_info"))
            continue;
        if (!strcmp(word, "format")) {
            ascii = !strcmp(a, "ascii");
            binary = !strcmp(a, "binary_little_endian");
            if (!ascii && !binary) {
                snprintf(err, err_size, "%s:%d: format %s is not supported (ascii, binary_little_endian)", path,
                         line_number, a);
                goto done;
            }
        } else if (!strcmp(word, "element")) {
            long count = atol(b);
            current = !strcmp(a, "vertex") ? 1 : !strcmp(a, "face") ? 2 : 3;
            if (current == 1)
                vertex_count = count;
            else if (current == 2)
                face_count = count;
            else if (count > 0) {
                snprintf(err, err_size, "%s:%d: element %s is not supported", path, line_number, a);
                goto done;
            }
        } else if (!strcmp(word, "property")) {
            ply_property pr = {.type = PLY_BAD, .list_count_type = -1};
            if (!strcmp(a, "list")) {
                pr.list_count_type = ply_type(b);
                pr.type = ply_type(c);
                snprintf(pr.name, sizeof pr.name, "%s", d);
            } else {
                pr.type = ply_type(a);
                snprintf(pr.name, sizeof pr.name, "%s", b);
            }
            if (pr.type == PLY_BAD || (pr.list_count_type != -1 && pr.list_count_type == PLY_BAD)) {
                snprintf(err, err_size, "%s:%d: unknown property type", path, line_number);
                goto done;
            }
            if (current == 1 && vprop_count < 32 && pr.list_count_type == -1)
                vprops[vprop_count++] = pr;
            else if (current == 2 && fprop_count < 8)
                fprops[fprop_count++] = pr;
            else {
                snprintf(err, err_size, "%s:%d: unsupported property", path, line_number);
                goto done;
            }
        } else if (!strcmp(word, "end_header")) {
            break;
        }
    }
    if (vertex_count <= 0 || (!ascii && !binary)) {
        snprintf(err, err_size, "%s:%d: no vertices or no format in the header", path, line_number);
        goto done;
    }
    int ix = -1, iy = -1, iz = -1, ir = -1, ig = -1, ib = -1;
    /* In order of preference: linear radiance before display colours
     * (radiosity writes both: radiance_r ... and uchar red ...). */
    static const char *red[] = {"radiance_r", "radiance_red", "L_r", "r", "red"},
                      *green[] = {"radiance_g", "radiance_green", "L_g", "g", "green"},
                      *blue[] = {"radiance_b", "radiance_blue", "L_b", "b", "blue"};
    int rank_r = 99, rank_g = 99, rank_b = 99;
    for (int i = 0; i < vprop_count; i++) {
        const char *nm = vprops[i].name;
        ix = !strcmp(nm, "x") ? i : ix, iy = !strcmp(nm, "y") ? i : iy, iz = !strcmp(nm, "z") ? i : iz;
        for (int k = 0; k < 5; k++) {
            if (!strcmp(nm, red[k]) && k < rank_r)
                ir = i, rank_r = k;
            if (!strcmp(nm, green[k]) && k < rank_g)
                ig = i, rank_g = k;
            if (!strcmp(nm, blue[k]) && k < rank_b)
                ib = i, rank_b = k;
        }
    }
    if (ix < 0 || iy < 0 || iz < 0 || ir < 0 || ig < 0 || ib < 0) {
        snprintf(err, err_size, "%s:%d: vertices need x y z and a colour (r g b, red green blue or radiance_r ...)",
                 path, line_number);
        goto done;
    }
    vertex_data = malloc((size_t)vertex_count * 6 * sizeof(double));
    if (!vertex_data) {
        snprintf(err, err_size, "%s:0: out of memory", path);
        goto done;
    }
    bool ok = true;
    *lo = v3_splat(INFINITY), *hi = v3_splat(-INFINITY);
    for (long i = 0; i < vertex_count && ok; i++) {
        double *out = vertex_data + 6 * i;
        for (int k = 0; k < vprop_count; k++) {
            double x = ply_read(f, vprops[k].type, ascii, &ok);
            bool byte_colour = vprops[k].type == PLY_UCHAR;
            if (k == ix)
                out[0] = x;
            if (k == iy)
                out[1] = x;
            if (k == iz)
                out[2] = x;
            if (k == ir)
                out[3] = byte_colour ? srgb_decode(x / 255.0) : x;
            if (k == ig)
                out[4] = byte_colour ? srgb_decode(x / 255.0) : x;
            if (k == ib)
                out[5] = byte_colour ? srgb_decode(x / 255.0) : x;
        }
        *lo = v3_min(*lo, v3(out[0], out[1], out[2]));
        *hi = v3_max(*hi, v3(out[0], out[1], out[2]));
    }
    if (!ok) {
        snprintf(err, err_size, "%s:0: truncated vertex data", path);
        goto done;
    }
    size_t capacity = (size_t)(face_count > 0 ? face_count : 1) * 2 * 3, used = 0;
    v = malloc(capacity * MESH_FLOATS * sizeof(float));
    for (long i = 0; i < face_count && ok && v; i++) {
        long indices[64];
        int count = 0;
        for (int k = 0; k < fprop_count && ok; k++) {
            if (fprops[k].list_count_type < 0) {
                ply_read(f, fprops[k].type, ascii, &ok);
                continue;
            }
            int n = (int)ply_read(f, fprops[k].list_count_type, ascii, &ok);
            bool is_indices = !strcmp(fprops[k].name, "vertex_indices") || !strcmp(fprops[k].name, "vertex_index");
            for (int j = 0; j < n && ok; j++) {
                double x = ply_read(f, fprops[k].type, ascii, &ok);
                if (is_indices && count < 64)
                    indices[count++] = (long)x;
            }
        }
        for (int j = 0; j < count; j++)
            if (indices[j] < 0 || indices[j] >= vertex_count) {
                snprintf(err, err_size, "%s:0: face %ld uses vertex %ld of %ld", path, i, indices[j], vertex_count);
                goto done;
            }
        for (int j = 1; j + 1 < count; j++) { /* a fan */
            if (used + 3 > capacity) {
                float *bigger = realloc(v, (capacity *= 2) * MESH_FLOATS * sizeof(float));
                if (!bigger)
                    break;
                v = bigger;
            }
            const long corner[3] = {indices[0], indices[j], indices[j + 1]};
            for (int k = 0; k < 3; k++) {
                const double *d = vertex_data + 6 * corner[k];
                float *out = v + MESH_FLOATS * used++;
                memset(out, 0, MESH_FLOATS * sizeof(float));
                out[0] = (float)d[0], out[1] = (float)d[1], out[2] = (float)d[2];
                out[13] = (float)d[3], out[14] = (float)d[4], out[15] = (float)d[5]; /* radiance as emission */
            }
        }
    }
    if (!v || !ok) {
        snprintf(err, err_size, v ? "%s:0: truncated face data" : "%s:0: out of memory", path);
        goto done;
    }
    mesh_upload(m, v, (int)used);
    status = 0;
done:
    free(v);
    free(vertex_data);
    fclose(f);
    return status;
}

/* ---- camera ------------------------------------------------------------------------------- */

/* Near and far planes fitted to the bounding box as seen from the eye:
 * far = the farthest corner, near = the distance to the box's nearest
 * point, at least far / 1000 (the eye inside the box).  A 24-bit depth
 * buffer resolves about z^2 / (near 2^24): for the Cornell box seen from
 * 800 mm (near ~ 800, far ~ 1400) a few microns, where the old near plane
 * at far x 1e-4 left 0.3 mm and the light, 0.1 mm below the ceiling,
 * came out as stripes of ceiling.  Both get 1 % of slack. */
static void depth_range(vec3 eye, vec3 lo, vec3 hi, double *near_plane, double *far_plane)
{
    vec3 nearest = v3_min(v3_max(eye, lo), hi);
    double far_sq = 0.0;
    for (int corner = 0; corner < 8; corner++) {
        vec3 c = v3(corner & 1 ? hi.x : lo.x, corner & 2 ? hi.y : lo.y, corner & 4 ? hi.z : lo.z);
        vec3 d = v3_sub(c, eye);
        far_sq = fmax(far_sq, v3_dot(d, d));
    }
    *far_plane = sqrt(far_sq) * 1.01 + 1e-9;
    *near_plane = fmax(v3_length(v3_sub(nearest, eye)) * 0.99, *far_plane * 1e-3);
}

/* Column-major view_projection: look-at, then a perspective projection
 * with the camera's vertical field of view, then y mirrored so that row 0
 * of the target is the top of the image (camera_ray's y grows downward).
 * Pixel centres then fall exactly where camera_ray() sends its rays. */
void camera_matrix(const camera *cam, int width, int height, vec3 lo, vec3 hi, float out[16])
{
    vec3 f = v3_normalize(v3_sub(cam->look, cam->eye));
    vec3 r = v3_normalize(v3_cross(f, cam->up));
    vec3 u = v3_cross(r, f);
    double near_plane, far_plane;
    depth_range(cam->eye, lo, hi, &near_plane, &far_plane);
    double t = tan(0.5 * cam->fov_degrees * M_PI / 180.0), aspect = (double)width / height;
    double view[4][4] = {{r.x, r.y, r.z, -v3_dot(r, cam->eye)},
                         {u.x, u.y, u.z, -v3_dot(u, cam->eye)},
                         {-f.x, -f.y, -f.z, v3_dot(f, cam->eye)},
                         {0, 0, 0, 1}};
    double projection[4][4] = {{1.0 / (t * aspect), 0, 0, 0},
                               {0, -1.0 / t, 0, 0}, /* mirrored y */
                               {0, 0, -(far_plane + near_plane) / (far_plane - near_plane),
                                -2.0 * far_plane * near_plane / (far_plane - near_plane)},
                               {0, 0, -1, 0}};
    for (int row = 0; row < 4; row++)
        for (int col = 0; col < 4; col++) {
            double sum = 0.0;
            for (int k = 0; k < 4; k++)
                sum += projection[row][k] * view[k][col];
            out[col * 4 + row] = (float)sum;
        }
}

void panel_render_3d(panel *p, const mesh_uniforms *u, const float background[3])
{
    mesh_draw(&p->mesh, &p->target, u, background);
    if (p->img.width != p->target.width || p->img.height != p->target.height) {
        image_free(&p->img);
        p->img = image_new(p->target.width, p->target.height);
    }
    if (p->img.pixels)
        target_read_rgb32f(&p->target, p->img.pixels);
    p->texture = p->target.colour;
    p->updates++;
}
