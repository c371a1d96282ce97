/* panel_file.c — panels whose image is a PFM file (compare mode, and the
 * live children's outputs), labelled from the stats JSON beside it. */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "viewer.h"

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

/* The stats JSON beside an image, read with cJSON (Debian's libcjson).  The
 * members the label needs sit at the top level or one object down (the
 * metrics' relmse), each name once, so a member is looked for at any depth. */
static const cJSON *member(const cJSON *json, const char *key)
{
    const cJSON *found = cJSON_GetObjectItemCaseSensitive(json, key), *child;
    cJSON_ArrayForEach(child, json)
    {
        if (found)
            break;
        if (cJSON_IsObject(child))
            found = member(child, key);
    }
    return found;
}

static double number_of(const cJSON *json, const char *key)
{
    const cJSON *item = member(json, key);
    return cJSON_IsNumber(item) ? item->valuedouble : NAN;
}

static const char *string_of(const cJSON *json, const char *key)
{
    const cJSON *item = member(json, key);
    return cJSON_IsString(item) ? item->valuestring : "";
}

/* "bounces": [A, B]: the Neumann terms rendered; [0, 1000000] is all of them
 * (false if the stats have none). */
static bool bounces_of(const cJSON *json, int *first, int *last)
{
    const cJSON *window = member(json, "bounces");
    if (!cJSON_IsArray(window) || cJSON_GetArraySize(window) != 2)
        return false;
    const cJSON *a = cJSON_GetArrayItem(window, 0), *b = cJSON_GetArrayItem(window, 1);
    if (!cJSON_IsNumber(a) || !cJSON_IsNumber(b))
        return false;
    *first = (int)a->valuedouble, *last = (int)fmin(b->valuedouble, 1e6);
    return true;
}

/* Append `format ...` and two spaces to out (its length in *used). */
static void append_field(char *out, size_t out_size, size_t *used, const char *format, ...)
{
    if (*used >= out_size)
        return;
    va_list args;
    va_start(args, format);
    int n = vsnprintf(out + *used, out_size - *used, format, args);
    va_end(args);
    *used += n > 0 ? (size_t)n : 0;
    if (*used + 2 < out_size)
        strcpy(out + *used, "  "), *used += 2;
}

static void trim_spaces(char *text)
{
    for (size_t end = strlen(text); end > 0 && text[end - 1] == ' ';)
        text[--end] = '\0';
}

/* What variant of its chapter an image is: the estimator (path tracing),
 * the solver (radiosity), the photon maps, the bidirectional or Metropolis
 * method and the large-step probability, the local model (chapters 1, 2), the
 * bounces unless all of them. */
static void stats_variant(const cJSON *json, char *out, size_t out_size)
{
    const char *solver = string_of(json, "solver_used"), *model = string_of(json, "model");
    size_t used = 0;
    int first, last;
    out[0] = '\0';
    if (!solver[0])
        solver = string_of(json, "solver");
    if (string_of(json, "estimator")[0])
        append_field(out, out_size, &used, "estimator %s", string_of(json, "estimator"));
    if (solver[0])
        append_field(out, out_size, &used, "solver %s", solver);
    if (string_of(json, "maps")[0])
        append_field(out, out_size, &used, "maps %s", string_of(json, "maps"));
    if (string_of(json, "method")[0])
        append_field(out, out_size, &used, "method %s", string_of(json, "method"));
    if (isfinite(number_of(json, "large_step")))
        append_field(out, out_size, &used, "large step %g", number_of(json, "large_step"));
    if (model[0])
        append_field(out, out_size, &used, "model %s%s%s", model,
                     cJSON_IsTrue(member(json, "normalised")) ? " normalised" : "",
                     cJSON_IsFalse(member(json, "shadows")) ? " no shadows" : "");
    if (bounces_of(json, &first, &last) && last < 1000000)
        append_field(out, out_size, &used, "bounces %d:%d", first, last);
    else if (bounces_of(json, &first, &last) && first > 0)
        append_field(out, out_size, &used, "bounces %d:", first);
    trim_spaces(out);
}

/* Label line 2: samples or patches (mutations per pixel for Metropolis), seconds, for a Markov chain its
 * acceptance rate and the normalisation b, the relative error. */
static void stats_detail(const panel *p, const cJSON *json, char *out, size_t out_size)
{
    double patches = number_of(json, "patches"), time_s = number_of(json, "time_s");
    double acceptance = number_of(json, "acceptance"), b = number_of(json, "b");
    size_t used = 0;
    out[0] = '\0';
    if (isfinite(patches))
        append_field(out, out_size, &used, "patches %.0f", patches);
    else if (isfinite(p->spp) && isfinite(acceptance)) /* a Markov chain: --spp counts mutations per pixel */
        append_field(out, out_size, &used, "mutations/px %.0f", p->spp);
    else if (isfinite(p->spp))
        append_field(out, out_size, &used, "spp %.0f", p->spp);
    if (isfinite(time_s))
        append_field(out, out_size, &used, "%.2f s", time_s);
    if (isfinite(acceptance))
        append_field(out, out_size, &used, "accepted %.0f%%", 100.0 * acceptance);
    if (isfinite(b))
        append_field(out, out_size, &used, "b %.3g", b);
    /* The relative error, (t - r)^2 / (r^2 + 0.01): an absolute one (RMSE) is
     * ruled by the few pixels on the light's edge, where radiance is 100 x
     * the walls', and would rank a method by how it draws the light's edge. */
    if (isfinite(p->relmse))
        append_field(out, out_size, &used, "rel.MSE %.3g", p->relmse);
    trim_spaces(out);
}

/* The whole file, NUL-terminated (NULL if missing or larger than a stats file can be). */
static char *read_text(const char *path)
{
    enum { STATS_MAX = 16 << 20 };
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    char *text = malloc(STATS_MAX + 1);
    size_t n = text ? fread(text, 1, STATS_MAX + 1, f) : 0;
    fclose(f);
    if (!text || n > STATS_MAX) {
        free(text);
        return NULL;
    }
    text[n] = '\0';
    return text;
}

void panel_read_stats(panel *p, const char *json_path)
{
    char *text = read_text(json_path);
    cJSON *json = text ? cJSON_Parse(text) : NULL;
    free(text);
    if (!cJSON_IsObject(json)) { /* missing, or being rewritten: keep the label */
        cJSON_Delete(json);
        return;
    }
    static const char *ranked[] = {"hemisphere", "cosine", "light", "mis"};
    const char *estimator = string_of(json, "estimator");
    int first, last;
    if (string_of(json, "chapter")[0])
        snprintf(p->method, sizeof p->method, "%s", string_of(json, "chapter"));
    stats_variant(json, p->variant, sizeof p->variant);
    p->estimator_rank = 0;
    for (int k = 0; k < 4; k++)
        p->estimator_rank = strcmp(estimator, ranked[k]) ? p->estimator_rank : k + 1;
    p->all_bounces = bounces_of(json, &first, &last) && first == 0 && last >= 1000000;
    p->spp = number_of(json, "spp"), p->relmse = number_of(json, "relmse");
    p->has_stats = true;
    if (!p->warning[0] && string_of(json, "warning")[0]) /* a file's warning, as a live child's stderr gives it */
        snprintf(p->warning, sizeof p->warning, "warning: %.150s", string_of(json, "warning")), p->warnings = 1;
    stats_detail(p, json, p->detail, sizeof p->detail);
    cJSON_Delete(json);
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
