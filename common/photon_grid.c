/* photon_grid.c — the hashed uniform grid of photon_grid.h. */
#include "photon_grid.h"

#include <stdlib.h>
#include <string.h>

#include "rng.h"

/* Integer coordinate of the cube containing coordinate v. */
static int64_t cell_of(double v, double cell_size) { return (int64_t)floor(v / cell_size); }

static uint32_t bucket_of(const photon_grid *g, int64_t cx, int64_t cy, int64_t cz)
{
    uint64_t h = hash64((uint64_t)cx * 0x9e3779b97f4a7c15ull ^ (uint64_t)cy * 0xc2b2ae3d27d4eb4full ^ (uint64_t)cz);
    return (uint32_t)(((h >> 32) * g->bucket_count) >> 32); /* h's top bits scaled to [0, bucket_count) */
}

static uint32_t bucket_of_point(const photon_grid *g, vec3 p)
{
    return bucket_of(g, cell_of(p.x, g->cell_size), cell_of(p.y, g->cell_size), cell_of(p.z, g->cell_size));
}

static vec3 point_at(const void *first, size_t stride, size_t i)
{
    return *(const vec3 *)((const char *)first + i * stride);
}

static bool grow(void **array, size_t n, size_t size)
{
    void *grown = realloc(*array, n * size);
    if (grown)
        *array = grown;
    return grown != NULL;
}

/* Room for `points` points and `buckets` buckets (half as much again when it grows, as counts vary from pass to
 * pass): 0, or 2 when out of memory. */
static int reserve(photon_grid *g, size_t points, size_t buckets)
{
    if (points > g->point_capacity) {
        points += points / 2;
        if (!grow((void **)&g->order, points, sizeof *g->order) ||
            !grow((void **)&g->position, points, sizeof *g->position) ||
            !grow((void **)&g->point_bucket, points, sizeof *g->point_bucket))
            return 2;
        g->point_capacity = points;
    }
    if (buckets > g->bucket_capacity) {
        buckets += buckets / 2;
        if (!grow((void **)&g->bucket_start, buckets, sizeof *g->bucket_start))
            return 2;
        g->bucket_capacity = buckets;
    }
    return 0;
}

int photon_grid_build(photon_grid *g, const void *first, size_t stride, size_t count, double cell_size)
{
    *g = (photon_grid){0};
    return photon_grid_rebuild(g, first, stride, NULL, count, cell_size);
}

int photon_grid_rebuild(photon_grid *g, const void *first, size_t stride, const uint32_t *which, size_t count,
                        double cell_size)
{
    g->cell_size = 2.0 * cell_size; /* cubes of side 2 r: 2 x 2 x 2 per query */
    g->count = count;
    /* About two buckets per point keeps most buckets short; at least one. */
    g->bucket_count = (uint32_t)(count < (1u << 30) ? 2 * count + 1 : (1u << 31));
    if (reserve(g, count + 1, (size_t)g->bucket_count + 1)) {
        photon_grid_free(g);
        return 2;
    }
    memset(g->bucket_start, 0, ((size_t)g->bucket_count + 1) * sizeof *g->bucket_start);
    /* Counting sort by bucket, stable: count into bucket_start[b + 1]; prefix sums, so that bucket b ends at
     * bucket_start[b + 1]; each point, last to first, into the last free place of its bucket, moving that end
     * down to the bucket's start; then the offsets one place down. */
    for (size_t i = 0; i < count; i++) {
        g->point_bucket[i] = bucket_of_point(g, point_at(first, stride, which ? which[i] : i));
        g->bucket_start[g->point_bucket[i] + 1]++;
    }
    for (uint32_t b = 0; b < g->bucket_count; b++)
        g->bucket_start[b + 1] += g->bucket_start[b];
    for (size_t i = count; i-- > 0;) {
        uint32_t slot = --g->bucket_start[g->point_bucket[i] + 1];
        g->order[slot] = (uint32_t)(which ? which[i] : i);
        g->position[slot] = point_at(first, stride, g->order[slot]);
    }
    memmove(g->bucket_start, g->bucket_start + 1, g->bucket_count * sizeof *g->bucket_start);
    g->bucket_start[g->bucket_count] = (uint32_t)count;
    return 0;
}

void photon_grid_free(photon_grid *g)
{
    free(g->bucket_start);
    free(g->order);
    free(g->position);
    free(g->point_bucket);
    *g = (photon_grid){0};
}

void photon_grid_search(const photon_grid *g, vec3 x, double radius2, photon_grid_cursor *c)
{
    *c = (photon_grid_cursor){.center = x, .radius2 = radius2, .current = -1};
    if (g->count == 0)
        return;
    /* The cube holding x and, along each axis, its neighbour on the side nearer x: a ball of radius
     * r <= cell_size / 2 around x lies in these 2 x 2 x 2. */
    double fx = x.x / g->cell_size, fy = x.y / g->cell_size, fz = x.z / g->cell_size;
    int64_t cx = (int64_t)floor(fx), cy = (int64_t)floor(fy), cz = (int64_t)floor(fz);
    int64_t sx = fx - (double)cx < 0.5 ? -1 : 1, sy = fy - (double)cy < 0.5 ? -1 : 1,
            sz = fz - (double)cz < 0.5 ? -1 : 1;
    for (int dx = 0; dx <= 1; dx++)
        for (int dy = 0; dy <= 1; dy++)
            for (int dz = 0; dz <= 1; dz++) {
                uint32_t b = bucket_of(g, cx + dx * sx, cy + dy * sy, cz + dz * sz);
                bool seen = false;
                for (int k = 0; k < c->bucket_count && !seen; k++)
                    seen = c->bucket[k] == b;
                if (!seen)
                    c->bucket[c->bucket_count++] = b;
            }
}

bool photon_grid_next(const photon_grid *g, photon_grid_cursor *c, uint32_t *index, double *distance2)
{
    for (;;) {
        while (c->next < c->end) {
            uint32_t j = c->next++;
            vec3 d = v3_sub(g->position[j], c->center);
            double d2 = v3_dot(d, d);
            if (d2 <= c->radius2) {
                *index = g->order[j];
                *distance2 = d2;
                return true;
            }
        }
        if (++c->current >= c->bucket_count)
            return false;
        c->next = g->bucket_start[c->bucket[c->current]];
        c->end = g->bucket_start[c->bucket[c->current] + 1];
    }
}

/* A max-heap of squared distances: the root is the farthest of those kept. */
static void sift_down(double *d2, int n, int i)
{
    for (;;) {
        int largest = i, l = 2 * i + 1, r = l + 1;
        if (l < n && d2[l] > d2[largest])
            largest = l;
        if (r < n && d2[r] > d2[largest])
            largest = r;
        if (largest == i)
            return;
        double di = d2[i];
        d2[i] = d2[largest];
        d2[largest] = di;
        i = largest;
    }
}

static void sift_up(double *d2, int i)
{
    while (i > 0 && d2[(i - 1) / 2] < d2[i]) {
        int p = (i - 1) / 2;
        double di = d2[i];
        d2[i] = d2[p];
        d2[p] = di;
        i = p;
    }
}

double photon_grid_nearest_radius2(const photon_grid *g, vec3 x, double radius, int k)
{
    double d2[PHOTON_GRID_MAX_NEAREST], dist2;
    photon_grid_cursor c;
    uint32_t i;
    int n = 0;
    k = k < PHOTON_GRID_MAX_NEAREST ? k : PHOTON_GRID_MAX_NEAREST;
    for (photon_grid_search(g, x, radius * radius, &c); photon_grid_next(g, &c, &i, &dist2);) {
        if (n < k) {
            d2[n] = dist2;
            sift_up(d2, n++);
        } else if (k > 0 && dist2 < d2[0]) {
            d2[0] = dist2;
            sift_down(d2, n, 0);
        }
    }
    return n == k && k > 0 ? d2[0] : radius * radius;
}
