/* photon_grid.h — finding the points near a point: a hashed uniform grid.
 *
 * Photon mapping (chapter 5) asks, millions of times, "which photons lie
 * within distance r of x?" (and "which are the k nearest?").  This is
 * infrastructure, not the lecture: any spatial index answers it (Jensen used
 * a kd-tree).  Here space is cut into cubes of side `cell_size`, and each
 * cube's integer coordinates are hashed into one of `bucket_count` buckets
 * (so the table's size depends on the number of points, not on the scene's
 * extent over the radius, which grows without bound as a progressive
 * radius shrinks).  The cubes' side is twice the largest radius, so a query
 * visits only 2 x 2 x 2 cubes: x's own and, along each axis, its neighbour on
 * the side nearer x; two cubes that hash to the same bucket are visited once.
 *
 * Points are kept in bucket order, and in their original order within a
 * bucket (a stable counting sort): a query returns the same points in the
 * same order on every run, whatever the thread count that made the input.
 */
#ifndef COMMON_PHOTON_GRID_H
#define COMMON_PHOTON_GRID_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "vec.h"

typedef struct {
    double cell_size;
    uint32_t bucket_count;
    uint32_t *bucket_start; /* bucket_count + 1 offsets into order / position */
    uint32_t *order;        /* the points' indices, grouped by bucket */
    vec3 *position;         /* position[j] is the point order[j]: the search reads only this array */
    size_t count;
    /* Kept for photon_grid_rebuild: the arrays' sizes, and each point's bucket while sorting. */
    uint32_t *point_bucket;
    size_t bucket_capacity, point_capacity;
} photon_grid;

/* Index `count` points: point i is at *(const vec3 *)((const char *)first + i * stride)
 * (a member of an array of structs).  Returns 0, or 2 when out of memory.
 * cell_size > 0 is the largest radius the grid will be asked about. */
int photon_grid_build(photon_grid *grid, const void *first, size_t stride, size_t count, double cell_size);
/* The same, but of the `count` points whose indices are which[0 .. count - 1] (in increasing order; NULL: all of
 * 0 .. count - 1), into the arrays of the grid's earlier build, grown when too small (a zeroed grid the first
 * time): a grid rebuilt every pass needs no fresh memory, whose page faults cost more than the sort. */
int photon_grid_rebuild(photon_grid *grid, const void *first, size_t stride, const uint32_t *which, size_t count,
                        double cell_size);
void photon_grid_free(photon_grid *grid);

/* for (photon_grid_search(g, x, r2, &c); photon_grid_next(g, &c, &i, &d2);) ...
 * visits every point i with |p_i - x|^2 <= r2 (d2 = that squared distance).  Squared, so that
 * the radius photon_grid_nearest_radius2 returns keeps its K-th point (sqrt, then squaring
 * again, rounds below it about one time in four). */
typedef struct {
    vec3 center;
    double radius2;
    uint32_t bucket[8]; /* the 2 x 2 x 2 cubes' buckets, each once */
    int bucket_count, current;
    uint32_t next, end;
} photon_grid_cursor;

void photon_grid_search(const photon_grid *grid, vec3 x, double radius2, photon_grid_cursor *cursor);
bool photon_grid_next(const photon_grid *grid, photon_grid_cursor *cursor, uint32_t *index, double *distance2);

/* The squared radius of the smallest ball around x that holds the k
 * points nearest to x, searching within `radius` (radius^2 when fewer than
 * k lie within it).  k <= PHOTON_GRID_MAX_NEAREST. */
enum { PHOTON_GRID_MAX_NEAREST = 4096 };
double photon_grid_nearest_radius2(const photon_grid *grid, vec3 x, double radius, int k);

#endif
