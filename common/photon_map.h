/* photon_map.h — what chapter 5 (photon mapping) stores, and its bookkeeping.
 *
 * The lecture's data structure, the photon, is here so that the storage
 * (growing arrays, merging the lists of parallel chunks in a fixed order,
 * the spatial index of photon_grid.h) and the statistics (stored power and
 * per-surface power in batches, their JSON) stay out of the chapter file.
 */
#ifndef COMMON_PHOTON_MAP_H
#define COMMON_PHOTON_MAP_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include "photon_grid.h"
#include "render.h"
#include "scene.h"
#include "vec.h"

/* A photon where it landed: a packet of flux Phi_p arriving from w_p. */
typedef struct {
    vec3 position; /* first member: photon_grid_build reads it */
    vec3 from;     /* w_p: unit, toward where the photon came from */
    vec3 normal;   /* the surface's unit normal on the side the photon arrived */
    vec3 power;    /* Phi_p (per channel), already divided by the photons of the pass */
    int bounces;   /* scatterings before it landed: 0 = straight from a light */
    bool caustic;  /* it scattered, and only off mirrors and glass (the path L S+ D) */
    bool front;    /* it arrived on the side the surface's normal (as in the file) points to */
    int surface;
    uint32_t path; /* which emitted photon of its pass it is (batch statistics) */
} photon;

typedef struct {
    photon *photons;
    size_t count, capacity;
    photon_grid grid; /* built by photon_map_index */
} photon_map;

int photon_map_add(photon_map *map, const photon *p); /* 0, or 2 when out of memory */
/* Build the spatial index for searches of radius <= radius.  0 or 2. */
int photon_map_index(photon_map *map, double radius);
void photon_map_free(photon_map *map);

/* Empty `global` and `caustic`, then append the photons of lists[0..n-1]
 * in list order (every photon to global, caustic ones to caustic too), and
 * free the lists.  0, or 2 when out of memory. */
int photon_maps_merge(photon_map *lists, int n, photon_map *global, photon_map *caustic);

/* Running sums over the passes, per batch of emitted photons (photon.path
 * modulo PROBE_BATCHES of render.h: independent batches, whose spread is the
 * standard error): the stored power of each map, and the power landing on
 * the front of each surface after a number of bounces the --bounces window keeps. */
#define PHOTON_BATCHES PROBE_BATCHES /* the old name, until 05_photonmap.c says PROBE_BATCHES */
typedef struct {
    vec3 global[PROBE_BATCHES], caustic[PROBE_BATCHES];
    vec3 *surface; /* surface_count x PROBE_BATCHES */
    uint64_t stored_global, stored_caustic;
    int passes;
} photon_tally;

void photon_tally_add(photon_tally *tally, const photon_map *global, int bounce_min, int bounce_max);
/* "stored_power" and "surfaces" (a Lambertian surface's mean exitant
 * radiance L = L_e + rho / pi * Phi / A from the power Phi landing on it),
 * each with standard errors; members of the stats object (",\n  ..."). */
void photon_tally_write(FILE *json, const photon_tally *tally, const scene *s, bool keep_emission);

/* Does ray r cross, at a parameter t in [0, t_max], the disc of the given
 * radius around `center` in the plane of unit `normal`, arriving from the
 * side the normal faces?  (A probe counts the photons that fly through it.) */
static inline bool ray_crosses_disc(ray r, double t_max, vec3 center, vec3 normal, double radius)
{
    double facing = -v3_dot(r.direction, normal);
    double t = v3_dot(v3_sub(r.origin, center), normal) / facing;
    vec3 offset = v3_sub(v3_madd(r.origin, r.direction, t), center);
    return facing > 0.0 && t >= 0.0 && t <= t_max && v3_dot(offset, offset) <= radius * radius;
}

#endif
