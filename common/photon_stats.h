/* photon_stats.h — the stats members of a photon-mapping run (chapter 5).
 *
 * Nothing here is the lecture: it records the radius of every pass and
 * writes what the chapter did (its options, the rays its photons traced, the
 * radii, the lights' power) and the tally of photon_map.h as members of the
 * --stats JSON object.
 */
#ifndef COMMON_PHOTON_STATS_H
#define COMMON_PHOTON_STATS_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include "photon_map.h"
#include "scene.h"
#include "vec.h"

typedef struct {
    const char *maps; /* the --maps choice */
    int photons_per_pass, gather, nearest;
    double alpha;
    uint64_t photon_rays;
    const double *radius_per_pass; /* tally->passes of them */
    vec3 emitted_power;
    const photon_tally *tally;
} photon_run;

/* `,\n  "maps": ..., "photons_per_pass", "gather", "nearest", "alpha", "photon_rays",
 * "radius_per_pass", "emitted_power"`, then photon_tally_write's members. */
void photon_run_write(FILE *json, const photon_run *run, const scene *s, bool keep_emission);

/* (*radius_per_pass)[pass - 1] = radius, growing the array (realloc) to `pass` entries: 0, or 2 when
 * out of memory (the array is kept). */
int photon_radius_record(double **radius_per_pass, int pass, double radius);

#endif
