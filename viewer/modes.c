/* modes.c — each mode's panels: compare (PFM files), live and raster (chapters run as
 * children), PLY; the default reference; polling the files and the children. */
#include <dirent.h>
#include <errno.h>
#include <glob.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "app.h"

/* ---- 3D panels and children ---------------------------------------------------------------------- */

void render_3d_panels(void)
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
int start_children(char *err, size_t err_size)
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

bool children_running(void)
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
bool poll_sources(void)
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
bool complete(void)
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

void remove_temp_dir(void)
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
    snprintf(pattern, sizeof pattern, "%s/[0-9][0-9]*_*", dir);
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
                 only_chapter ? only_chapter : "[0-9][0-9]*_*", dir);
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

int set_up(char *err, size_t err_size)
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
