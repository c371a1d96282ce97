/* viewer.h — what the viewer's parts share: panels and their sources.
 *
 * Every mode is a grid of panels; a panel is an image in linear radiance
 * plus a label.  Where the image comes from is the panel's source:
 *   SOURCE_FILE    a PFM (compare mode), with its stats JSON beside it
 *   SOURCE_CHILD   a chapter run as a child process writing a PFM (live mode)
 *   SOURCE_RASTER  the scene rasterised by the GLSL Blinn-Phong shader
 *   SOURCE_PLY     radiosity's mesh with per-vertex radiance
 */
#ifndef VIEWER_VIEWER_H
#define VIEWER_VIEWER_H

#include <stdbool.h>
#include <sys/stat.h>
#include <sys/types.h>

#include "gfx.h"
#include "image.h"
#include "scene.h"

enum { PANEL_MAX = 16, PATH_LEN = 4096 };

typedef enum { SOURCE_FILE, SOURCE_CHILD, SOURCE_RASTER, SOURCE_PLY } source_kind;

typedef struct {
    source_kind kind;
    char method[64];  /* label line 1: chapter / method */
    char variant[96]; /* label line 1 after the method: estimator, solver, model, bounces (stats JSON) */
    char detail[160]; /* label line 2: samples or patches, time, error */
    char file[128];   /* label line 2 after the detail: the PFM's file name (compare mode) */
    /* from the stats JSON, to pick the default reference (NAN: not given) */
    bool has_stats;
    double spp, relmse; /* relmse: the stats' relative MSE against --ref (NAN: none) */
    int estimator_rank; /* 0 none, 1 hemisphere, 2 cosine, 3 light, 4 mis */
    bool all_bounces;   /* "bounces": [0, 1000000] */
    image img;          /* linear radiance, top row first */
    GLuint texture;     /* RGB32F copy of img (or the 3D target's colour) */
    int updates;        /* how often the image changed */
    /* SOURCE_FILE and SOURCE_CHILD */
    char path[PATH_LEN], stats_path[PATH_LEN];
    struct stat seen; /* identity of the file last loaded */
    /* SOURCE_CHILD */
    char exe[PATH_LEN], log_path[PATH_LEN];
    pid_t pid;       /* 0 when not running */
    int exit_status; /* of the last run; -1 while running or never run */
    double started;
    int generation;    /* restarts (a new camera) */
    bool stale;        /* restarted: the image is the old camera's until the first new pass */
    char warning[160]; /* the child's last stderr line starting "warning:" ("" none) */
    int warnings;      /* how many of them this run */
    long log_read;     /* bytes of the log already scanned */
    /* 3D sources */
    target target;
    mesh mesh;
} panel;

/* panel_file.c */
double now_seconds(void);
/* Load a PFM into p->img and its texture; read the stats JSON beside it
 * (same name, .json) into the label.  Returns 0, or 2 with a message. */
int panel_load_pfm(panel *p, const char *path, char *err, size_t err_size);
/* Reload a file or child panel whose PFM changed on disk; returns true if it did. */
bool panel_poll(panel *p);
void panel_upload(panel *p);
void panel_free(panel *p);
void panel_read_stats(panel *p, const char *json_path);

/* children.c: chapters as child processes (live and raster modes). */
typedef struct {
    const char *scene_path;
    int width, height;
    double time_budget; /* --time for the chapters; 0: a single default render */
    camera cam;
    const char *extra[8]; /* chapter options passed through (01_local: --no-shadows ...) */
    int extra_count;
    const char *directory; /* temporary directory for outputs and logs */
} child_spec;
int child_start(panel *p, const child_spec *spec, char *err, size_t err_size);
void child_stop(panel *p);
/* Reap a child that ended; returns true if it did now. */
bool child_reap(panel *p);
/* Scan the child's new log lines for "warning:"; returns true if one came. */
bool child_poll_warnings(panel *p);

/* meshes.c, ply.c: scene and PLY meshes, the camera. */
int scene_mesh(const scene *s, mesh *m, mesh_uniforms *u, vec3 ambient, char *err, size_t err_size);
int ply_mesh(const char *path, mesh *m, vec3 *lo, vec3 *hi, char *err, size_t err_size);
/* view_projection for cam at an image of width x height, depth range from the bounds. */
void camera_matrix(const camera *cam, int width, int height, vec3 lo, vec3 hi, float out[16]);
/* Render a 3D panel into its target and read it back into img. */
void panel_render_3d(panel *p, const mesh_uniforms *u, const float background[3]);

#endif
