/* bidir_store.h — bookkeeping for chapter 6 (bidirectional methods).
 *
 * Nothing here is the lecture: the chapter's state and options, the storage
 * of a pass's light subpaths (lists per chunk of paths, joined in a fixed
 * order so that the image does not depend on the thread count), the lights'
 * pick by power, the pixel a direction from the eye is seen in, warnings,
 * the probes' and surface means' plumbing (walk_stats.h) and the stats.
 * Linked into every program, so it names nothing a chapter defines: what it
 * needs of one (is a material specular? the lights' power? the trace of one
 * light subpath) comes in as an argument. */
#ifndef COMMON_BIDIR_STORE_H
#define COMMON_BIDIR_STORE_H

#include <stdint.h>
#include <stdio.h>

#include "options.h"
#include "photon_grid.h"
#include "render.h"
#include "walk_stats.h"

typedef enum { METHOD_LIGHT, METHOD_BDPT, METHOD_VCM } method_kind; /* --method, in order */
enum { MAX_VERTICES = 64, MAX_PATH = 2 * MAX_VERTICES, CHUNK = 1024 };
enum { COUNT_EYE_RAYS, COUNT_SHADOW_RAYS, COUNT_MERGES, COUNT_PROBE_RAYS }; /* the chapter's counters */

/* A vertex of a subpath.  alpha is the subpath's weight up to x: the product
 * of (R13)'s factors over their densities (R14); 1 / its density at a light's
 * own point, 1 at the camera. */
typedef enum { AT_CAMERA, AT_POINT_LIGHT, AT_SURFACE, AT_SENSOR } vertex_kind;
typedef struct {
    vec3 x, n; /* the point; the normal as the scene file orients it (0 at the camera, a point light) */
    vec3 alpha;
    const material *m; /* NULL at the camera and a point light */
    int kind, surface; /* vertex_kind; the surface, the point light's number, or (a sensor) the bounce at its point */
    int index;         /* its place in its subpath */
    bool specular;     /* on a mirror or glass (f a delta): asked so often that it is kept */
} path_vertex;

/* The edges x_i -> x_{i+1} of a path x_0 .. x_k: the unit direction w[i] and
 * the length d[i], found once for all the densities (R14) of the path (the
 * chapter's area_pdf asks for each edge eight times). */
typedef struct {
    vec3 w[MAX_PATH];
    double d[MAX_PATH];
} path_edges;
void path_edges_of(const path_vertex *x, int k, path_edges *e);
/* The eye's first non-specular vertex on x_0 .. x_k (0: it sees the light through mirrors only). */
int first_from_eye(const path_vertex *x, int k);
/* The unit direction from x_j to x_{j+dir} (dir 1 or -1) on those edges. */
static inline vec3 path_toward(const path_edges *e, int j, int dir) { return dir == 1 ? e->w[j] : v3_neg(e->w[j - 1]); }

typedef struct {
    vec3 eye, forward;
    camera_frame frame; /* the image plane at distance 1 (scene.h) */
    double pixel_area;  /* of one pixel on that plane */
    int width, height;
} pinhole;

/* A chunk of light subpaths, traced by one thread: their vertices, and light
 * tracing's values for pixels.  Kept from pass to pass (emptied, not freed):
 * fresh memory every pass cost more than the tracing (page faults).  The
 * vertices go straight into the chunk's slice of the pass's light_vertices
 * (not copied there afterwards: 10 MB a pass at 128x128); a chunk that
 * outgrows its slice goes on in `spill`, and the slices are widened. */
typedef struct {
    int pixel;
    vec3 value;
} splat;
typedef struct {
    path_vertex *vertices; /* its slice, or spill */
    path_vertex *spill;
    splat *splats;
    size_t vertex_count, vertex_capacity, spill_capacity, splat_count, splat_capacity;
    uint64_t rays;
} chunk;

/* A chapter's answer to "is this material a mirror or glass?" */
typedef bool specular_test(const material *m);
typedef struct bidir_state bidir_state;
/* --check: one pair of random subpaths and every join of them, tallied by bidir_check_record. */
typedef void path_pair_check(bidir_state *st, const scene *s, rng *g);

struct bidir_state {
    /* What the chapter defines, set before render_main (bidir_prepare calls them). */
    specular_test *is_specular;
    double (*total_light_power)(const scene *s);
    walk_reflected_fn *sensor; /* its one-sample estimate at a point: probes, surface means */
    path_pair_check *check;
    int method, merge_off, connect_off; /* options */
    bool single_strategy;               /* --strategy S,T */
    int strategy_s, strategy_t, check_paths, probe_samples, surface_samples;
    double radius, alpha;
    /* From prepare and begin_pass. */
    bool merge, connect;
    bounce_window bounces;  /* --bounces A:B keeps paths of A + 1 .. B + 1 edges: K^A E .. K^B E (R6) */
    int light_cap, eye_cap; /* subpaths hold at most light_cap, eye_cap vertices */
    uint64_t seed, light_rays;
    pinhole camera;
    double *light_probability; /* per surface (0: not a light), then per point light */
    double current_radius;
    int light_paths, passes;     /* per pass: one per pixel */
    path_vertex *light_vertices; /* chunk c's slice from c * slice (the rest of a slice is unused) */
    size_t light_vertex_capacity, slice;
    chunk *chunks;                /* the pass's chunks of light subpaths (light_pass) */
    int *path_first, *path_count; /* light subpath p: light_vertices[path_first[p]] ... */
    vec3 *light_image;            /* this pass's light tracing (t = 1), one value per pixel */
    photon_grid grid;             /* over the light vertices merging can use: */
    uint32_t *mergeable;          /* their indices in light_vertices (not on a light, mirror, glass) */
    size_t mergeable_capacity;
    double check_worst_sum, check_worst_ratio; /* --check: the largest |sum of weights - 1|, |C p / f - 1| */
    long check_connections, check_out_of_range;
    const scene *scene;
    surface_average *surface_averages; /* --surface-samples (walk_stats.h) */
    int surface_average_count;
    uint64_t surface_rays;
};

extern const option BIDIR_OPTIONS[];
/* Counted in the stats: a path dropped because its density underflowed; a
 * subpath cut at MAX_VERTICES (warned once).  Thread-safe. */
void note_dropped_path(void);
void note_truncated_walk(void);

/* 0, or 2 when out of memory. */
int chunk_add_vertices(chunk *c, const path_vertex *v, int n);
int chunk_add_splat(chunk *c, int pixel, vec3 value);
/* A pass of st->light_paths light subpaths, `trace` making path p into a
 * chunk (in parallel), then the chunks joined in order into st's
 * light_vertices (path_first, path_count), light_image, and the photon grid
 * when merging.  0, or 2 with a message when out of memory. */
typedef int light_path_tracer(const bidir_state *st, const scene *s, int pass, int path, chunk *out);
int light_pass(bidir_state *st, const scene *s, int pass, light_path_tracer *trace, char *err, size_t err_size);

/* The path of the strategy (s, t) in x, as the chapter's join: s = 0, the
 * eye vertices z_{t-1} .. z_0; s > 0, from what x holds: (s - 1, t)'s path,
 * its eye vertices moved one place on and y_{s-1} put before them (t + 1
 * vertices copied, not s + t).  Returns k = s + t - 1. */
int bidir_join_step(path_vertex *x, const path_vertex *y, int s, const path_vertex *z, int t);
/* The chapter's .prepare: the bounce window and the subpaths' caps, which
 * strategies the options leave, the camera, one light subpath per pixel,
 * each light's probability to be picked (by power: as chapter 4's lights),
 * the first radius, warnings, with --surface-samples the surface means
 * (from st->sensor), and --check N (N pairs by st->check).  0, or 2 with a
 * message. */
int bidir_prepare(void *state, const scene *s, const render_options *o, char *err, size_t err_size);
/* --check: one join's weights summed over all strategies, and its value
 * (-1 when the path has a mirror or glass on it: not compared) times its
 * density over the path integral's integrand: the worst of each.  A path
 * whose density or integrand is out of a double's normal range (0,
 * subnormal or infinite: 64 vertices of G ~ 1e-6 / mm^2 underflow) is
 * counted (out_of_range), not compared; a NaN error counts as DBL_MAX. */
void bidir_check_record(bidir_state *st, double weight_sum, double value, double density, double integrand);
/* The chapter's .probe: a probe's irradiance from st->sensor (walk_probe). */
probe_result bidir_probe(const void *state, const scene *s, const probe *p, uint64_t seed, render_counters *counters);
/* A light (a surface number, or surface_count + a point light's) picked by
 * power with the uniform number u in [0, 1). */
int pick_light(const bidir_state *st, const scene *s, double u);
/* Where the unit direction w from the eye crosses the image: its pixel
 * (row-major) and cos theta to the view axis; false outside the image. */
bool pixel_seen(const pinhole *c, vec3 w, int *pixel, double *cos_theta);
/* Where the segment from x to the eye is camera.near from the eye (scene.h;
 * the eye itself when near is 0): the end of the shadow ray that joins x to
 * the camera.  False when x is nearer than that, where no camera ray sees it. */
bool pinhole_sensor_point(const pinhole *c, vec3 x, vec3 *sensor);
/* The pixel of a camera ray (pixel_seen; 0 if none). */
int pixel_of_ray(const pinhole *c, vec3 w);
void bidir_write_stats(const void *state, FILE *json);
void bidir_finish(void *state);

#endif
