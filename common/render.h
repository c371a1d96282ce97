/* render.h — the driver every chapter calls.
 *
 * A chapter fills in a `chapter` struct (its name, its own command-line
 * options, an optional prepare step, and the radiance along one camera ray)
 * and hands control to render_main().  The driver does everything that is
 * not the point of any chapter: the command line (the options README lists),
 * loading the scene, camera rays, the OpenMP pixel loop, progressive passes
 * under a --time budget, the progress bar, statistics JSON, error metrics
 * against a --ref image, and atomic output files.
 */
#ifndef COMMON_RENDER_H
#define COMMON_RENDER_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include "image.h"
#include "options.h"
#include "rng.h"
#include "scene.h"
#include "vec.h"

enum { RENDER_MAX_OUTPUTS = 16, RENDER_MAX_COUNTERS = 16 };
enum { CAMERA_EYE = 1, CAMERA_LOOK = 2, CAMERA_UP = 4, CAMERA_FOV = 8 };
/* --bounces A: (no upper end) */
#define RENDER_BOUNCES_UNLIMITED 1000000

typedef struct {
    const char *scene_path;
    int scene_argv, size_argv, camera_argv; /* their positions in argv (0: not given), for messages */
    const char *outputs[RENDER_MAX_OUTPUTS];
    int output_argv[RENDER_MAX_OUTPUTS]; /* where each --out stood on the command line (for messages) */
    int output_count;
    int width, height; /* --size, or the scene's `image` */
    int spp;           /* samples per pixel (a cap when --time is given) */
    bool spp_given;
    double time_budget; /* seconds; 0 = no budget */
    uint64_t seed;
    int threads; /* 0 = OpenMP default */
    const char *reference_path;
    const char *stats_path;
    int bounce_min, bounce_max; /* --bounces A:B: keep Neumann terms K^A E .. K^B E (R6) */
    bool bounces_given;
    double exposure;                         /* PNG exposure in stops (--exposure) */
    vec3 camera_eye, camera_look, camera_up; /* --eye --look --up --fov override the scene's camera */
    double camera_fov;
    int camera_override; /* which of them were given: CAMERA_EYE | CAMERA_LOOK | ... */
    bool quiet;
} render_options;

/* Per-thread event counts (rays of each kind ...), named by the chapter. */
typedef struct {
    uint64_t value[RENDER_MAX_COUNTERS];
} render_counters;

/* A probe's irradiance estimate and its standard error (0 when exact). */
typedef struct {
    vec3 irradiance, standard_error;
} probe_result;

typedef struct chapter {
    const char *name;        /* "01_local": the executable and the stats' "chapter" */
    const char *description; /* one line for --help */
    /* The chapter's own options: tables and the state each one's offsets
     * are relative to, ended by an empty group (see options.h). */
    option_group options[OPTION_MAX_GROUPS];
    int default_spp;
    /* Names of the counters the chapter increments, NULL-terminated. */
    const char *counter_names[RENDER_MAX_COUNTERS + 1];

    /* After the scene is loaded, before any pixel: precomputation (the
     * radiosity solve).  Return 0, or 2 with a message.  May be NULL. */
    int (*prepare)(void *state, const scene *s, const render_options *o, char *err, size_t err_size);
    /* Radiance arriving along camera ray r.  Called from many threads at
     * once: treat state and scene as read-only, use only g and counters. */
    vec3 (*radiance)(const void *state, const scene *s, ray r, rng *g, render_counters *counters);
    /* Irradiance at a probe (may be NULL: no probes reported). */
    probe_result (*probe)(const void *state, const scene *s, const probe *p, uint64_t seed, render_counters *counters);
    /* Extra members of the stats object, written as `"key": value` pairs each
     * preceded by ",\n  " (may be NULL). */
    void (*write_stats)(const void *state, FILE *json);
    /* Extra outputs a chapter owns (radiosity's .ply); return 1 if it handled
     * this path, 0 if it is not its format, 2 on error.  May be NULL. */
    int (*write_output)(const void *state, const scene *s, const char *path, char *err, size_t err_size);
    void (*finish)(void *state); /* free the chapter's memory (may be NULL) */
    /* Before each progressive pass (pass = 1, 2, ...; may be NULL): a
     * chapter that builds something per pass (photon mapping traces a new
     * photon map and shrinks its radius) does it here.  With this hook the
     * driver renders one sample per pixel per pass, so sample k of every
     * pixel belongs to pass k + 1.  Return 0, or 2 with a message. */
    int (*begin_pass)(void *state, const scene *s, const render_options *o, int pass, char *err, size_t err_size);
} chapter;

/* Parse the command line, render, write outputs.  Returns the process exit
 * status: 0, or 2 after printing one "file:line: message" line to stderr. */
int render_main(int argc, char **argv, const chapter *ch, void *state);

/* --bounces A:B as a chapter keeps it (its radiance function does not see
 * the options): the Neumann terms K^A E .. K^B E (R6). */
typedef struct {
    int first, last; /* A and B; last = RENDER_BOUNCES_UNLIMITED for "A:" */
} bounce_window;

static inline bounce_window bounce_window_of(const render_options *o)
{
    return (bounce_window){.first = o->bounce_min, .last = o->bounce_max};
}

/* Is the term K^k E (light reflected k times) inside the window (R6)? */
static inline bool bounces_keep(bounce_window w, int k) { return k >= w.first && k <= w.last; }

/* Does the window keep every term from K^k E on (what an ambient term
 * standing in for "all the other bounces" needs)? */
static inline bool bounces_keep_all_from(bounce_window w, int k)
{
    return w.first <= k && w.last == RENDER_BOUNCES_UNLIMITED;
}

/* Probes are estimated from PROBE_BATCHES independent batches, whose spread
 * gives the standard error (batch_mean_and_error), with random numbers
 * seeded by probe_seed(--seed): a stream of their own, apart from the image's. */
enum { PROBE_BATCHES = 32 };
static inline uint64_t probe_seed(uint64_t seed) { return seed ^ 0x70726f6265ull; /* "probe" in ASCII */ }

/* The mean of `count` independent batch estimates and its standard error
 * (the batches' standard deviation over sqrt(count)). */
probe_result batch_mean_and_error(const vec3 *batch, int count);

/* Print a warning once per process (chapters use it for "cannot model X"). */
void warn_once(int *flag, const char *format, ...);

/* JSON helpers for write_stats. */
void json_string(FILE *f, const char *s);
void json_number(FILE *f, double v); /* null for non-finite */
void json_vec3(FILE *f, vec3 v);
/* One more member of the stats object: `,\n  "key": value`. */
void json_field_number(FILE *f, const char *key, double v);


#endif
