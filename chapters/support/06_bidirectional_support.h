/* 06_bidirectional_support.h — what lecture 6 does not teach, for
 * chapters/06_bidirectional.c: its state and options, the storage of a
 * pass's light subpaths (lists per chunk of paths, joined in a fixed order so
 * that the image does not depend on the thread count), warnings and stats.
 * Private to chapter 6. */
#ifndef CHAPTERS_BIDIRECTIONAL_SUPPORT_H
#define CHAPTERS_BIDIRECTIONAL_SUPPORT_H

#include <stdint.h>
#include <stdio.h>

#include "../photonmap_model.h"
#include "options.h"
#include "photon_grid.h"
#include "render.h"

typedef enum { METHOD_LIGHT, METHOD_BDPT, METHOD_VCM } method_kind; /* --method, in order */
enum { MAX_VERTICES = 64, MAX_PATH = 2 * MAX_VERTICES, CHUNK = 1024 };

/* A vertex of a subpath.  alpha is the subpath's weight up to x: the product
 * of (R13)'s factors over their densities (R14); 1 / its density at a light's
 * own point, 1 at the camera. */
typedef enum { AT_CAMERA, AT_POINT_LIGHT, AT_SURFACE } vertex_kind;
typedef struct {
    vec3 x, n; /* the point; the normal as the scene file orients it (0 at the camera, a point light) */
    vec3 alpha;
    const material *m; /* NULL at the camera and a point light */
    int kind, surface; /* vertex_kind; the surface, or the point light's number */
    int index, path;   /* its place in its subpath, and (light subpaths) which one of the pass */
} path_vertex;

typedef struct {
    vec3 eye, forward;
    camera_frame frame; /* the image plane at distance 1 (scene.h) */
    double pixel_area;  /* of one pixel on that plane */
    int width, height;
} pinhole;

typedef struct {
    int method, merge_off, connect_off; /* options */
    bool single_strategy;               /* --strategy S,T */
    int strategy_s, strategy_t, check_paths;
    double radius, alpha;
    /* From prepare and begin_pass. */
    bool merge, connect;
    bounce_window bounces;  /* --bounces A:B keeps paths of A + 1 .. B + 1 edges: K^A E .. K^B E (R6) */
    int light_cap, eye_cap; /* subpaths hold at most light_cap, eye_cap vertices */
    uint64_t seed, light_rays;
    pinhole camera;
    double *light_probability; /* per surface (0: not a light), then per point light */
    double current_radius;
    int light_paths, passes; /* per pass: one per pixel */
    path_vertex *light_vertices;
    int *path_first, *path_count;              /* light subpath p: light_vertices[path_first[p]] ... */
    vec3 *light_image;                         /* this pass's light tracing (t = 1), one value per pixel */
    photon_grid grid;                          /* over light_vertices */
    double check_worst_sum, check_worst_ratio; /* --check: the largest |sum of weights - 1|, |C p / f - 1| */
    long check_connections;
} bidir_state;

extern const option BIDIR_OPTIONS[];
/* Counted in the stats: a path dropped because its density underflowed; a
 * subpath cut at MAX_VERTICES (warned once).  Thread-safe. */
void note_dropped_path(void);
void note_truncated_walk(void);

/* A chunk of light subpaths, traced by one thread: their vertices, and light
 * tracing's values for pixels. */
typedef struct {
    int pixel;
    vec3 value;
} splat;
typedef struct {
    path_vertex *vertices;
    splat *splats;
    size_t vertex_count, vertex_capacity, splat_count, splat_capacity;
    uint64_t rays;
} chunk;

/* 0, or 2 when out of memory. */
int chunk_add_vertices(chunk *c, const path_vertex *v, int n);
int chunk_add_splat(chunk *c, int pixel, vec3 value);
/* A pass of st->light_paths light subpaths, `trace` making path p into a
 * chunk (in parallel), then the chunks joined in order into st's
 * light_vertices (path_first, path_count), light_image, and the photon grid
 * when merging.  0, or 2 when out of memory. */
typedef int light_path_tracer(const bidir_state *st, const scene *s, int pass, int path, chunk *out);
int light_pass(bidir_state *st, const scene *s, int pass, light_path_tracer *trace);

/* The camera, one light subpath per pixel, and each light's probability to
 * be picked (by power, as chapter 4's lights).  0, or 2 with a message. */
int bidir_allocate(bidir_state *st, const scene *s, int width, int height, char *err, size_t err_size);
/* A light (a surface number, or surface_count + a point light's) picked by
 * power with the uniform number u in [0, 1). */
int pick_light(const bidir_state *st, const scene *s, double u);
/* Where the unit direction w from the eye crosses the image: its pixel
 * (row-major) and cos theta to the view axis; false outside the image. */
bool pixel_seen(const pinhole *c, vec3 w, int *pixel, double *cos_theta);
/* What the options cannot render, said once (a pinhole is never hit: t = 0). */
void bidir_warn_impossible(const bidir_state *st, const scene *s);
void bidir_write_stats(const void *state, FILE *json);
void bidir_finish(void *state);

#endif
