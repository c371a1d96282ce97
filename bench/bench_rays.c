/* bench_rays.c — incoherent ray-casting throughput on a scene.
 *
 * usage: build/bench/bench_rays [scene] [--rays N] [--sorted]
 * Rays start at random points on the scene's surfaces (chosen in proportion
 * to area) and go in uniformly random directions: the rays of the second and
 * later bounces of a path tracer, which is the hard case for a BVH.  Prints
 * closest-hit and shadow-ray throughput in million rays per second for 1
 * thread and for all threads.  A benchmark, not a test.
 *
 * Shadow rays go from the same surface point to a second random surface
 * point through scene_occluded(), which moves both ends off their surfaces
 * (as the chapters call it).  The hit and blocked fractions are checked on
 * a subset of the rays against scene_intersect_brute_force (no BVH).
 *
 * --sorted traces the same rays after sorting them by direction and origin,
 * so that consecutive rays take nearly the same path through the tree: the
 * same work, but the processor's branch predictor now guesses right.  The
 * ratio of the two runs is what incoherence costs.
 */
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "render.h"
#include "sampling.h"
#include "scene.h"

static double now_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* A random point on a random surface, by area. */
static vec3 random_surface_point(const scene *s, rng *g, vec3 *normal)
{
    double total = 0;
    for (int i = 0; i < s->surface_count; i++)
        total += s->surfaces[i].area;
    double pick = rng_uniform(g) * total;
    int i = 0;
    while (i < s->surface_count - 1 && pick > s->surfaces[i].area)
        pick -= s->surfaces[i++].area;
    /* One statement each: the order in which arguments are evaluated is unspecified. */
    double u1 = rng_uniform(g);
    double u2 = rng_uniform(g);
    double u3 = rng_uniform(g);
    vec3 p;
    surface_sample_point(s, i, u1, u2, u3, &p, normal);
    return p;
}

/* r: the closest-hit ray, leaving surface point `from` (its origin is moved
 * off the surface to the side r.direction points to); the shadow ray goes
 * from `from` to `target`. */
typedef struct {
    ray r;
    vec3 from, target;
} bench_ray;

static double run_closest(const scene *s, const bench_ray *rays, long n, int threads, long *hits)
{
    long count = 0;
    double start = now_seconds();
#pragma omp parallel for num_threads(threads) reduction(+ : count) schedule(static)
    for (long i = 0; i < n; i++) {
        hit h;
        count += scene_intersect(s, rays[i].r, INFINITY, &h);
    }
    *hits = count;
    return now_seconds() - start;
}

static double run_shadow(const scene *s, const bench_ray *rays, long n, int threads, long *blocked)
{
    long count = 0;
    double start = now_seconds();
#pragma omp parallel for num_threads(threads) reduction(+ : count) schedule(static)
    for (long i = 0; i < n; i++)
        count += scene_occluded(s, rays[i].from, rays[i].target);
    *blocked = count;
    return now_seconds() - start;
}

/* The same queries without the BVH, on every stride-th ray: closest hits by
 * scene_intersect_brute_force, occlusion by a brute-force closest hit on
 * the segment scene_occluded() tests (from a + epsilon toward b, ending
 * epsilon short of b).  Prints both implementations' fractions on the
 * subset and the rays where they disagree. */
static void check_against_brute_force(const scene *s, const bench_ray *rays, long n, long stride)
{
    long checked = 0, hits = 0, hits_bvh = 0, blocked = 0, blocked_bvh = 0, mismatches = 0;
#pragma omp parallel for reduction(+ : checked, hits, hits_bvh, blocked, blocked_bvh, mismatches) schedule(static)
    for (long i = 0; i < n; i += stride) {
        hit h, h_bvh;
        int found = scene_intersect_brute_force(s, rays[i].r, INFINITY, &h);
        int found_bvh = scene_intersect(s, rays[i].r, INFINITY, &h_bvh);
        mismatches += found != found_bvh || (found && (h.t != h_bvh.t || h.primitive != h_bvh.primitive));
        vec3 d = v3_sub(rays[i].target, rays[i].from);
        double distance = v3_length(d);
        int occluded = 0;
        if (distance > 2.0 * s->epsilon) {
            double step = s->epsilon / distance;
            hit ignored;
            occluded =
                scene_intersect_brute_force(s, (ray){v3_madd(rays[i].from, d, step), d}, 1.0 - 2.0 * step, &ignored);
        }
        int occluded_bvh = scene_occluded(s, rays[i].from, rays[i].target);
        mismatches += occluded != occluded_bvh;
        checked++;
        hits += found;
        hits_bvh += found_bvh;
        blocked += occluded;
        blocked_bvh += occluded_bvh;
    }
    printf("check on %ld rays: brute force %.1f%% hit, %.1f%% blocked; BVH %.1f%% hit, %.1f%% blocked; "
           "%ld disagreements\n",
           checked, 100.0 * hits / checked, 100.0 * blocked / checked, 100.0 * hits_bvh / checked,
           100.0 * blocked_bvh / checked, mismatches);
}

/* Sort key: direction octant, then the direction on an 8 x 8 x 8 grid, then
 * the origin on a grid of 1/8 of the scene. */
static const scene *sort_scene;

static long coherence_key(const bench_ray *b)
{
    vec3 d = b->r.direction, size = v3_sub(sort_scene->bounds.hi, sort_scene->bounds.lo);
    vec3 o = v3_sub(b->r.origin, sort_scene->bounds.lo);
    long octant = (d.x < 0) * 4 + (d.y < 0) * 2 + (d.z < 0);
    long direction = (long)((d.x + 1) * 4) * 81 + (long)((d.y + 1) * 4) * 9 + (long)((d.z + 1) * 4);
    long origin = (long)(8 * o.x / size.x) * 81 + (long)(8 * o.y / size.y) * 9 + (long)(8 * o.z / size.z);
    return (octant * 729 + direction) * 729 + origin;
}

static int by_coherence_key(const void *a, const void *b)
{
    long ka = coherence_key(a), kb = coherence_key(b);
    return (ka > kb) - (ka < kb);
}

int main(int argc, char **argv)
{
    const char *path = "scenes/cornell.scene";
    long n = 4000000;
    int sorted = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--rays") && i + 1 < argc)
            n = atol(argv[++i]);
        else if (!strcmp(argv[i], "--sorted"))
            sorted = 1;
        else
            path = argv[i];
    }
    scene s;
    char err[1024];
    if (scene_load(path, &s, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        return 2;
    }
    bench_ray *rays = malloc((size_t)n * sizeof *rays);
    if (!rays)
        return 2;
    for (long i = 0; i < n; i++) {
        rng g = rng_for(42, (uint64_t)i, 0);
        vec3 normal, other_normal;
        vec3 p = random_surface_point(&s, &g, &normal);
        double u1 = rng_uniform(&g);
        double u2 = rng_uniform(&g);
        vec3 d = uniform_sample_sphere(u1, u2);
        rays[i].r = (ray){scene_offset_origin(&s, p, normal, d), d};
        rays[i].from = p;
        rays[i].target = random_surface_point(&s, &g, &other_normal);
    }
    printf("scene %s: %d triangles, %d spheres, %d BVH nodes, %ld rays%s\n", path, s.triangle_count, s.sphere_count,
           s.bvh.node_count, n, sorted ? ", sorted by direction and origin (coherent)" : "");
    /* Before sorting, so that the checked subset is the same either way. */
    check_against_brute_force(&s, rays, n, n / 20000 > 0 ? n / 20000 : 1);
    if (sorted) {
        sort_scene = &s;
        qsort(rays, (size_t)n, sizeof *rays, by_coherence_key);
    }
    int max_threads = omp_get_max_threads();
    for (int threads = 1; threads <= max_threads; threads = threads == max_threads ? threads + 1 : max_threads) {
        long hits, blocked;
        double t_closest = run_closest(&s, rays, n, threads, &hits);
        double t_shadow = run_shadow(&s, rays, n, threads, &blocked);
        printf("threads %d: closest hit %.2f Mrays/s (%.1f%% hit), shadow %.2f Mrays/s (%.1f%% blocked)\n", threads,
               n / t_closest * 1e-6, 100.0 * hits / n, n / t_shadow * 1e-6, 100.0 * blocked / n);
        if (threads == max_threads)
            break;
    }
    free(rays);
    scene_free(&s);
    return 0;
}
