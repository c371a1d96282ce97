/* bench_embree.c — the same rays through common/'s BVH and through Embree.
 *
 * usage: build/bench/bench_embree SCENE [--size WxH] [--repeats N] [--seed N]
 *                                 [--fast] [--builds-only] [--json FILE]
 * Measures, on one scene:
 *   - four ray sets made once from a fixed seed: camera rays (one jittered
 *     ray per pixel), diffuse-bounce rays (from each camera hit, cosine
 *     distributed about the normal facing the ray, origin moved off the
 *     surface by scene_offset_origin as chapter 4 does), shadow rays (from
 *     each camera hit to a point drawn uniformly on the emitters by area,
 *     kept when each end faces the other, as next-event estimation casts them)
 *     and miss rays (one per pixel, from outside the scene's box and leaving
 *     it, uniform in direction: no chapter casts them, they time what every
 *     ray costs before and after its first box test: the set-up, the root
 *     node, the exit);
 *   - whether both implementations agree on every ray (both miss, or both hit
 *     the same primitive or at the same distance within a relative 1e-5; for
 *     shadow rays the same blocked / unblocked answer), and each set's hit or
 *     blocked fraction: a second implementation checking the first;
 *   - each set's throughput, ours and Embree's, in million rays per second,
 *     1 thread and all threads (OpenMP, static schedule: one contiguous chunk
 *     of rays per thread), interleaved in repeats (their order alternates), and
 *     the ratio ours / Embree of each repeat: min / median / max;
 *   - the build: our bvh_build() against Embree's rtcCommitScene, each at 1
 *     thread and at all threads, and the memory of each acceleration
 *     structure per primitive: ours from bvh_memory_bytes (the arrays of
 *     scene.bvh, and the heap's growth across the build), Embree's from its
 *     memory monitor (bytes it holds after the commit, and its peak).  The
 *     four builds are interleaved.  Each Embree build runs on a device made
 *     for it ("threads=1" or the default) while no other device is alive:
 *     Embree 3.13 with TBB gives every device the threads of the device that
 *     asks for most, so a "threads=1" device next to a default one builds
 *     on all threads (CPU / wall time 2.0 on 2 cores, as this bench measured
 *     before).  Each build's CPU / wall time (the threads that worked) is
 *     printed.  --builds-only times the builds alone (no rays).
 *
 * How the scene is given to Embree: the triangles as one triangle geometry
 * (vertices rounded to float, primID = our triangle index, vertex and index
 * buffers shared, so outside Embree's count), the spheres as a user geometry
 * whose callbacks call our double-precision intersect_sphere(): smallpt's
 * walls are spheres of radius 1e5, which Embree's float spheres cannot hold.
 * Embree's rays are float, so an origin we moved off a surface by
 * scene.epsilon (1e-9 of the scene) lands back on it: Embree's rays start
 * and shadow rays end a margin later and earlier than ours: EMBREE_MARGIN
 * (eight float roundings) of the largest coordinate of the triangles'
 * vertices and of the rays' ends (not of the spheres' bounds: smallpt's
 * walls reach 1e5, but Embree rounds only the rays there, near 100).  Scene flag: robust
 * (watertight like ours) unless --fast.  Build quality: Embree's default.
 * A benchmark, not a test: it prints numbers and fails only on bad input.
 */
#include <embree3/rtcore.h>
#include <malloc.h>
#include <math.h>
#include <omp.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bvh.h"
#include "rng.h"
#include "sampling.h"
#include "scene.h"

/* Embree's margin, as a fraction of the largest coordinate: 2^-20, eight
 * times float's rounding step (2^-23). */
static const double EMBREE_MARGIN = 1.0 / 1048576.0;
/* Two closest hits agree at the same primitive or within this relative distance. */
static const double SAME_DISTANCE = 1e-5;

enum { SET_CAMERA, SET_BOUNCE, SET_SHADOW, SET_MISS, SET_COUNT };
static const char *const SET_NAME[SET_COUNT] = {"camera", "bounce", "shadow", "miss"};
enum { OURS, EMBREE };
enum { MAX_REPEATS = 64 };

/* One query: a closest-hit ray (a = origin, b = unit direction) or a shadow
 * ray between two surface points a and b (as scene_occluded takes them). */
typedef struct {
    vec3 a, b;
} query;

typedef struct {
    const scene *s;
    query *sets[SET_COUNT];
    long count[SET_COUNT];
    RTCScene embree;
    double margin; /* EMBREE_MARGIN in scene units */
} bench;

static double now_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* CPU seconds of all the process's threads: over a build, CPU / wall time is
 * how many threads worked (idle pool threads asleep count nothing). */
static double cpu_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int by_value(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* min, median, max of n values (sorts a copy). */
static void summary(const double *v, int n, double out[3])
{
    double sorted[MAX_REPEATS];
    memcpy(sorted, v, (size_t)n * sizeof *v);
    qsort(sorted, (size_t)n, sizeof *sorted, by_value);
    out[0] = sorted[0];
    out[1] = n % 2 ? sorted[n / 2] : 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]);
    out[2] = sorted[n - 1];
}

/* ------------------------------------------------------------------------ */
/* The scene in Embree                                                      */

/* Embree's memory monitor: bytes held and the peak since the last reset. */
static atomic_long embree_bytes, embree_peak;

static bool monitor(void *user, ssize_t bytes, bool post)
{
    (void)user, (void)post;
    long now = atomic_fetch_add(&embree_bytes, (long)bytes) + (long)bytes;
    long peak = atomic_load(&embree_peak);
    while (now > peak && !atomic_compare_exchange_weak(&embree_peak, &peak, now))
        ;
    return true;
}

static const surface *sphere_of(const scene *s, unsigned prim) { return &s->surfaces[s->sphere_surfaces[prim]]; }

static void sphere_bounds(const struct RTCBoundsFunctionArguments *args)
{
    const surface *sphere = sphere_of(args->geometryUserPtr, args->primID);
    vec3 c = sphere->center;
    double r = sphere->radius;
    /* Rounded outward to float. */
    *args->bounds_o =
        (struct RTCBounds){nextafterf((float)(c.x - r), -INFINITY), nextafterf((float)(c.y - r), -INFINITY),
                           nextafterf((float)(c.z - r), -INFINITY), 0.0f,
                           nextafterf((float)(c.x + r), INFINITY),  nextafterf((float)(c.y + r), INFINITY),
                           nextafterf((float)(c.z + r), INFINITY),  0.0f};
}

/* Our intersect_sphere from the ray's tnear on (a ray leaving a sphere
 * would otherwise find the sphere again at its float-rounded origin);
 * returns the distance from the ray's origin, or INFINITY.  The callbacks
 * see one ray at a time (N = 1: we cast with Embree's rtcIntersect1 and
 * rtcOccluded1), laid out as RTCRay; Embree's RTCRayN accessors are C++ only. */
static double sphere_distance(const scene *s, unsigned prim, const struct RTCRay *r, vec3 *normal)
{
    const surface *sphere = sphere_of(s, prim);
    vec3 d = {r->dir_x, r->dir_y, r->dir_z};
    vec3 o = v3_madd((vec3){r->org_x, r->org_y, r->org_z}, d, r->tnear);
    double t = intersect_sphere(sphere->center, sphere->radius, (ray){o, d});
    if (!(t < INFINITY) || !(r->tnear + t < r->tfar))
        return INFINITY;
    *normal = v3_sub(v3_madd(o, d, t), sphere->center);
    return r->tnear + t;
}

static void sphere_intersect(const struct RTCIntersectFunctionNArguments *args)
{
    if (args->N != 1 || !args->valid[0])
        return;
    struct RTCRayHit *rh = (struct RTCRayHit *)args->rayhit;
    vec3 normal;
    double t = sphere_distance(args->geometryUserPtr, args->primID, &rh->ray, &normal);
    if (!(t < INFINITY))
        return;
    rh->ray.tfar = (float)t;
    rh->hit.Ng_x = (float)normal.x;
    rh->hit.Ng_y = (float)normal.y;
    rh->hit.Ng_z = (float)normal.z;
    rh->hit.u = rh->hit.v = 0.0f;
    rh->hit.primID = args->primID;
    rh->hit.geomID = args->geomID;
    rh->hit.instID[0] = args->context->instID[0];
}

static void sphere_occluded(const struct RTCOccludedFunctionNArguments *args)
{
    if (args->N != 1 || !args->valid[0])
        return;
    struct RTCRay *r = (struct RTCRay *)args->ray;
    vec3 normal;
    if (sphere_distance(args->geometryUserPtr, args->primID, r, &normal) < INFINITY)
        r->tfar = -INFINITY;
}

/* Our triangles' vertices in float, three per triangle, and their indices
 * (Embree reads a 16-byte vector at the last vertex: one float of padding). */
typedef struct {
    float *vertices;
    unsigned *indices;
} embree_buffers;

static embree_buffers embree_buffers_make(const scene *s)
{
    size_t n = (size_t)s->triangle_count;
    embree_buffers b = {malloc((9 * n + 1) * sizeof(float)), malloc((3 * n + 1) * sizeof(unsigned))};
    if (!b.vertices || !b.indices) {
        fprintf(stderr, "bench_embree: out of memory\n");
        exit(2);
    }
    for (size_t i = 0; i < n; i++) {
        const triangle *t = &s->triangles[i];
        vec3 p[3] = {t->p0, v3_add(t->p0, t->e1), v3_add(t->p0, t->e2)};
        for (int k = 0; k < 3; k++) {
            b.vertices[9 * i + 3 * (size_t)k + 0] = (float)p[k].x;
            b.vertices[9 * i + 3 * (size_t)k + 1] = (float)p[k].y;
            b.vertices[9 * i + 3 * (size_t)k + 2] = (float)p[k].z;
            b.indices[3 * i + (size_t)k] = (unsigned)(3 * i + (size_t)k);
        }
    }
    b.vertices[9 * n] = 0.0f;
    return b;
}

/* A scene with the triangles as geometry 0 and the spheres as geometry 1, not yet committed. */
static RTCScene embree_scene_make(RTCDevice device, const scene *s, embree_buffers b, int robust)
{
    RTCScene es = rtcNewScene(device);
    rtcSetSceneFlags(es, robust ? RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_NONE);
    if (s->triangle_count > 0) {
        RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
        size_t n = (size_t)s->triangle_count;
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, b.vertices, 0, 3 * sizeof(float),
                                   3 * n);
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, b.indices, 0, 3 * sizeof(unsigned),
                                   n);
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(es, g, 0);
        rtcReleaseGeometry(g);
    }
    if (s->sphere_count > 0) {
        RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_USER);
        rtcSetGeometryUserPrimitiveCount(g, (unsigned)s->sphere_count);
        rtcSetGeometryUserData(g, (void *)s);
        rtcSetGeometryBoundsFunction(g, sphere_bounds, NULL);
        rtcSetGeometryIntersectFunction(g, sphere_intersect);
        rtcSetGeometryOccludedFunction(g, sphere_occluded);
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(es, g, 1);
        rtcReleaseGeometry(g);
    }
    return es;
}

/* ------------------------------------------------------------------------ */
/* One query each way                                                       */

/* Embree's closest hit on the ray o + t d, tnear < t < tfar: 1 if found,
 * with the distance and our primitive index. */
static int embree_first_hit(const bench *b, vec3 o, vec3 d, double tnear, double tfar, double *t, int *primitive)
{
    struct RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    struct RTCRayHit rh = {.ray = {.org_x = (float)o.x,
                                   .org_y = (float)o.y,
                                   .org_z = (float)o.z,
                                   .tnear = (float)tnear,
                                   .dir_x = (float)d.x,
                                   .dir_y = (float)d.y,
                                   .dir_z = (float)d.z,
                                   .tfar = (float)tfar,
                                   .mask = ~0u},
                           .hit = {.geomID = RTC_INVALID_GEOMETRY_ID, .instID = {RTC_INVALID_GEOMETRY_ID}}};
    rtcIntersect1(b->embree, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID)
        return 0;
    *t = rh.ray.tfar;
    *primitive = (int)rh.hit.primID + (rh.hit.geomID == 1 ? b->s->triangle_count : 0);
    return 1;
}

static int embree_closest(const bench *b, const query *q, double *t, int *primitive)
{
    return embree_first_hit(b, q->a, q->b, b->margin, INFINITY, t, primitive);
}

/* Embree's occlusion on the segment scene_occluded tests (from a + epsilon
 * toward b, ending epsilon short of b), shortened at both ends by the margin. */
static int embree_occluded(const bench *b, vec3 a, vec3 target)
{
    vec3 d = v3_sub(target, a);
    double distance = v3_length(d);
    if (!(distance > 2.0 * b->s->epsilon))
        return 0;
    double step = b->s->epsilon / distance, margin = b->margin / distance;
    vec3 o = v3_madd(a, d, step);
    double tfar = 1.0 - 2.0 * step - margin;
    if (!(tfar > margin))
        return 0;
    struct RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    struct RTCRay r = {.org_x = (float)o.x,
                       .org_y = (float)o.y,
                       .org_z = (float)o.z,
                       .tnear = (float)margin,
                       .dir_x = (float)d.x,
                       .dir_y = (float)d.y,
                       .dir_z = (float)d.z,
                       .tfar = (float)tfar,
                       .mask = ~0u};
    rtcOccluded1(b->embree, &context, &r);
    return r.tfar < 0.0f;
}

/* 1 if the ray hits (closest-hit sets) or is blocked (shadow set). */
static inline int cast(const bench *b, int which, int set, const query *q)
{
    if (set == SET_SHADOW)
        return which == OURS ? scene_occluded(b->s, q->a, q->b) : embree_occluded(b, q->a, q->b);
    double t;
    int primitive;
    if (which == EMBREE)
        return embree_closest(b, q, &t, &primitive);
    hit h;
    return scene_intersect(b->s, (ray){q->a, q->b}, INFINITY, &h);
}

/* Casts a whole set; returns million rays per second, the hits in *found. */
static double cast_set(const bench *b, int which, int set, int threads, long *found)
{
    const query *q = b->sets[set];
    long n = b->count[set], count = 0;
    double start = now_seconds();
#pragma omp parallel for num_threads(threads) schedule(static) reduction(+ : count)
    for (long i = 0; i < n; i++)
        count += cast(b, which, set, &q[i]);
    double seconds = now_seconds() - start;
    *found = count;
    return n / seconds * 1e-6;
}

/* ------------------------------------------------------------------------ */
/* The ray sets                                                             */

/* A point on the emitters, by area (the point lights' first if none emits). */
static vec3 light_point(const scene *s, rng *g, vec3 *normal, int *has_normal)
{
    double u0 = rng_uniform(g), u1 = rng_uniform(g), u2 = rng_uniform(g), u3 = rng_uniform(g);
    *has_normal = s->emitter_count > 0;
    if (s->emitter_count == 0)
        return s->lights[(int)(u0 * s->light_count) % s->light_count].position;
    double pick = u0 * s->emitter_area;
    int e = 0;
    while (e < s->emitter_count - 1 && pick > s->surfaces[s->emitters[e]].area)
        pick -= s->surfaces[s->emitters[e++]].area;
    vec3 p;
    surface_sample_point(s, s->emitters[e], u1, u2, u3, &p, normal);
    return p;
}

/* From camera hit h (ray direction d): the bounce ray, and the shadow ray
 * if its ends face each other (returns 1 then). */
static int secondary(const scene *s, const hit *h, vec3 d, rng *g, query *bounce, query *shadow)
{
    vec3 n = v3_dot(h->normal, d) < 0.0 ? h->normal : v3_neg(h->normal);
    double u1 = rng_uniform(g), u2 = rng_uniform(g);
    vec3 w = onb_to_world(onb_from_normal(n), cosine_sample_hemisphere(u1, u2));
    *bounce = (query){scene_offset_origin(s, h->point, h->normal, w), w};
    if (s->emitter_count == 0 && s->light_count == 0)
        return 0;
    vec3 light_normal;
    int has_normal;
    vec3 p = light_point(s, g, &light_normal, &has_normal);
    vec3 to_light = v3_sub(p, h->point);
    *shadow = (query){h->point, p};
    return v3_dot(n, to_light) > 0.0 && (!has_normal || v3_dot(light_normal, to_light) < 0.0);
}

static void *checked_malloc(size_t bytes)
{
    void *p = malloc(bytes ? bytes : 1);
    if (!p) {
        fprintf(stderr, "bench_embree: out of memory\n");
        exit(2);
    }
    return p;
}

static void make_sets(bench *b, int width, int height, uint64_t seed)
{
    const scene *s = b->s;
    long n = (long)width * height;
    camera_frame frame = camera_frame_make(&s->camera, width, height);
    query *camera = checked_malloc((size_t)n * sizeof *camera);
    hit *hits = checked_malloc((size_t)n * sizeof *hits);
    char *found = checked_malloc((size_t)n);
#pragma omp parallel for schedule(static)
    for (long i = 0; i < n; i++) {
        rng g = rng_for(seed, (uint64_t)i, 0);
        double jx = rng_uniform(&g), jy = rng_uniform(&g);
        ray r = camera_frame_ray(&frame, (double)(i % width) + jx, (double)(i / width) + jy);
        camera[i] = (query){r.origin, r.direction};
        found[i] = (char)scene_intersect(s, r, INFINITY, &hits[i]);
    }
    query *bounce = checked_malloc((size_t)n * sizeof *bounce), *shadow = checked_malloc((size_t)n * sizeof *shadow);
    long bounces = 0, shadows = 0;
    for (long i = 0; i < n; i++) {
        if (!found[i])
            continue;
        rng g = rng_for(seed, (uint64_t)i, 1);
        int keep_shadow = secondary(s, &hits[i], camera[i].b, &g, &bounce[bounces], &shadow[shadows]);
        bounces++;
        shadows += keep_shadow;
    }
    free(hits);
    free(found);
    /* Miss rays: from twice the box's diagonal out of its centre, away from it. */
    query *miss = checked_malloc((size_t)n * sizeof *miss);
    vec3 centre = v3_scale(v3_add(s->bounds.lo, s->bounds.hi), 0.5);
    double diagonal = v3_length(v3_sub(s->bounds.hi, s->bounds.lo));
    for (long i = 0; i < n; i++) {
        rng g = rng_for(seed, (uint64_t)i, 2);
        vec3 d = uniform_sample_sphere(rng_uniform(&g), rng_uniform(&g));
        miss[i] = (query){v3_madd(centre, d, 2.0 * diagonal), d};
    }
    b->sets[SET_MISS] = miss, b->count[SET_MISS] = n;
    b->sets[SET_CAMERA] = camera, b->count[SET_CAMERA] = n;
    b->sets[SET_BOUNCE] = bounce, b->count[SET_BOUNCE] = bounces;
    b->sets[SET_SHADOW] = shadow, b->count[SET_SHADOW] = shadows;
}

/* ------------------------------------------------------------------------ */
/* Agreement                                                                */

typedef struct {
    long rays, found[2], disagreements, at_ends;
} agreement;

static const char *primitive_name(const scene *s, int primitive)
{
    return primitive < s->triangle_count ? s->surfaces[s->triangles[primitive].surface].name
                                         : sphere_of(s, (unsigned)(primitive - s->triangle_count))->name;
}

/* Prints one disagreement: what each implementation found. */
static void show_disagreement(const bench *b, int set, long i, int ours, const hit *h, int theirs, double t,
                              int primitive)
{
    const scene *s = b->s;
    const query *q = &b->sets[set][i];
    int blocked_by;
    if (set == SET_SHADOW) {
        vec3 d = v3_sub(q->b, q->a);
        double step = s->epsilon / v3_length(d), margin = b->margin / v3_length(d);
        hit blocker;
        int blocked = scene_intersect(s, (ray){v3_madd(q->a, d, step), d}, 1.0 - 2.0 * step, &blocker);
        blocked_by = embree_first_hit(b, v3_madd(q->a, d, step), d, margin, 1.0 - 2.0 * step - margin, &t, &primitive);
        printf(
            "  disagreement, shadow ray %ld from (%.6g %.6g %.6g) to (%.6g %.6g %.6g): ours %s, Embree %s; first hit "
            "on the segment: ours %s at %.3g, Embree's %s at %.3g of its length\n",
            i, q->a.x, q->a.y, q->a.z, q->b.x, q->b.y, q->b.z, ours ? "blocked" : "clear", theirs ? "blocked" : "clear",
            blocked ? s->surfaces[blocker.surface].name : "none", blocked ? blocker.t : 0.0,
            blocked_by ? primitive_name(s, primitive) : "none", blocked_by ? t : 0.0);
        return;
    }
    const char *theirs_name = theirs ? primitive_name(s, primitive) : "";
    printf("  disagreement, %s ray %ld: ours %s %s t %.9g (primitive %d), Embree %s %s t %.9g (primitive %d)\n",
           SET_NAME[set], i, ours ? "hit" : "miss", ours ? s->surfaces[h->surface].name : "", ours ? h->t : 0.0,
           ours ? h->primitive : -1, theirs ? "hit" : "miss", theirs_name, theirs ? t : 0.0, theirs ? primitive : -1);
}

/* Distance from p to the plane of a triangle or to a sphere's surface. */
static double distance_to_primitive(const scene *s, int primitive, vec3 p)
{
    if (primitive < s->triangle_count)
        return fabs(v3_dot(v3_sub(p, s->triangles[primitive].p0), s->triangles[primitive].normal));
    const surface *sphere = sphere_of(s, (unsigned)(primitive - s->triangle_count));
    return fabs(v3_length(v3_sub(p, sphere->center)) - sphere->radius);
}

/* Is a disagreement at a ray's ends: does the primitive either one hit
 * pass within the Embree margin of where the ray starts (or, for a shadow
 * ray, ends)?  There the float rounding of the ray and of the vertices
 * decides, on rays that graze the surface they leave or reach. */
static int near_an_end(const bench *b, int set, const query *q, int ours, const hit *h, int theirs, int primitive)
{
    const scene *s = b->s;
    if (set != SET_SHADOW)
        return (ours && distance_to_primitive(s, h->primitive, q->a) < b->margin) ||
               (theirs && distance_to_primitive(s, primitive, q->a) < b->margin);
    vec3 d = v3_sub(q->b, q->a);
    double length = v3_length(d), step = s->epsilon / length, margin = b->margin / length, t;
    hit blocker;
    int blockers[2], found = 0;
    vec3 o = v3_madd(q->a, d, step);
    blockers[0] = scene_intersect(s, (ray){o, d}, 1.0 - 2.0 * step, &blocker) ? blocker.primitive : -1;
    if (!embree_first_hit(b, o, d, margin, 1.0 - 2.0 * step - margin, &t, &blockers[1]))
        blockers[1] = -1;
    for (int k = 0; k < 2; k++)
        if (blockers[k] >= 0)
            found |= distance_to_primitive(s, blockers[k], q->a) < b->margin ||
                     distance_to_primitive(s, blockers[k], q->b) < b->margin;
    return found;
}

/* Casts every ray of a set through both and counts where they differ and
 * how many of those are at a ray's ends (the first three of each kind are printed). */
static agreement compare_set(const bench *b, int set)
{
    const query *q = b->sets[set];
    long n = b->count[set], found_ours = 0, found_theirs = 0, disagreements = 0, at_ends = 0, shown_of_kind[2] = {0, 0};
#pragma omp parallel for schedule(static) reduction(+ : found_ours, found_theirs, disagreements, at_ends)
    for (long i = 0; i < n; i++) {
        int ours, theirs, agree, primitive = -1;
        double t = 0.0;
        hit h = {0};
        if (set == SET_SHADOW) {
            ours = scene_occluded(b->s, q[i].a, q[i].b);
            theirs = embree_occluded(b, q[i].a, q[i].b);
            agree = ours == theirs;
        } else {
            ours = scene_intersect(b->s, (ray){q[i].a, q[i].b}, INFINITY, &h);
            theirs = embree_closest(b, &q[i], &t, &primitive);
            agree =
                ours == theirs && (!ours || primitive == h.primitive || fabs(t - h.t) <= SAME_DISTANCE * fmax(t, h.t));
        }
        found_ours += ours;
        found_theirs += theirs;
        if (!agree) {
            int at_end = near_an_end(b, set, &q[i], ours, &h, theirs, primitive);
            long shown;
#pragma omp atomic capture
            shown = shown_of_kind[at_end]++;
            if (shown < 3) {
#pragma omp critical
                show_disagreement(b, set, i, ours, &h, theirs, t, primitive);
            }
            disagreements++;
            at_ends += at_end;
        }
    }
    return (agreement){n, {found_ours, found_theirs}, disagreements, at_ends};
}

static RTCDevice device_make(const char *config);

/* ------------------------------------------------------------------------ */
/* Timing                                                                   */

typedef struct {
    int repeats, configs, threads[2];
    agreement agree[SET_COUNT];
    double mrays[2][2][SET_COUNT][MAX_REPEATS]; /* [thread configuration][implementation][set][repeat] */
    double build[4][MAX_REPEATS]; /* seconds: ours 1 thread, Embree 1 thread, Embree all threads, ours all threads */
    double build_cpu[4][MAX_REPEATS]; /* the process's CPU seconds over the same builds */
    long ours_array_bytes, ours_heap_bytes, embree_bytes, embree_peak_bytes, primitives;
    int builds_only; /* no rays cast: agree and mrays unset */
} results;

/* Every set, both implementations, each thread count, in `repeats` rounds;
 * within a round the two alternate which goes first. */
static void time_sets(const bench *b, results *res)
{
    for (int r = 0; r < res->repeats; r++)
        for (int c = 0; c < res->configs; c++)
            for (int set = 0; set < SET_COUNT; set++)
                for (int k = 0; k < 2; k++) {
                    int which = (k + r) % 2;
                    long found;
                    res->mrays[c][which][set][r] = b->count[set] ? cast_set(b, which, set, res->threads[c], &found) : 0;
                }
}

static size_t heap_in_use(void)
{
    struct mallinfo2 m = mallinfo2();
    return m.uordblks + m.hblkhd;
}

static double time_our_build(scene *s, int threads, long *heap_bytes, double *cpu)
{
    int before_threads = omp_get_max_threads();
    omp_set_num_threads(threads);
    bvh_free(&s->bvh);
    if (bvh_build(s)) { /* untimed, as Embree's device gets a commit before the timed one */
        fprintf(stderr, "bench_embree: out of memory in bvh_build\n");
        exit(2);
    }
    bvh_free(&s->bvh);
    size_t before = heap_in_use();
    double start = now_seconds(), cpu_start = cpu_seconds();
    if (bvh_build(s)) {
        fprintf(stderr, "bench_embree: out of memory in bvh_build\n");
        exit(2);
    }
    double seconds = now_seconds() - start;
    *cpu = cpu_seconds() - cpu_start;
    *heap_bytes = (long)(heap_in_use() - before);
    omp_set_num_threads(before_threads);
    return seconds;
}

static double time_embree_build(RTCDevice device, const scene *s, embree_buffers eb, int robust, long *bytes,
                                long *peak, double *cpu)
{
    RTCScene es = embree_scene_make(device, s, eb, robust);
    atomic_store(&embree_bytes, 0);
    atomic_store(&embree_peak, 0);
    double start = now_seconds(), cpu_start = cpu_seconds();
    rtcCommitScene(es);
    double seconds = now_seconds() - start;
    *cpu = cpu_seconds() - cpu_start;
    *bytes = atomic_load(&embree_bytes);
    *peak = atomic_load(&embree_peak);
    rtcReleaseScene(es);
    return seconds;
}

/* One Embree build on a device of its own, made for it and released after
 * it, so that no other device is alive: Embree (3.13 with TBB) runs every
 * device's builds on as many threads as the device that asks for the most
 * ("threads=1" next to a default device builds on all of them).  The
 * device's first commit, untimed, starts its threads. */
static double time_embree_build_alone(int threads, const scene *s, embree_buffers eb, int robust, long *bytes,
                                      long *peak, double *cpu)
{
    char config[32];
    snprintf(config, sizeof config, "threads=%d", threads);
    RTCDevice device = device_make(config);
    long unused_bytes, unused_peak;
    double unused_cpu;
    time_embree_build(device, s, eb, robust, &unused_bytes, &unused_peak, &unused_cpu);
    double seconds = time_embree_build(device, s, eb, robust, bytes, peak, cpu);
    rtcReleaseDevice(device);
    return seconds;
}

/* A pause before each pair of builds (an untimed one, then the timed one,
 * for both implementations), so that they do not share the cores with the
 * other implementation's threads: OpenMP's and TBB's idle threads spin a
 * while before they sleep. */
static void quiet_pause(void)
{
    struct timespec pause = {0, 50 * 1000 * 1000};
    nanosleep(&pause, NULL);
}

/* Builds, interleaved: ours at 1 thread, ours at all threads, Embree at 1
 * thread, Embree at all; each repeat starts with the next of the four. */
static void time_builds(scene *s, embree_buffers eb, int robust, results *res)
{
    static const int slot[4] = {0, 3, 1, 2}; /* build[] of each of the four */
    int all = omp_get_max_threads();
    long bytes, peak;
    for (int r = 0; r < res->repeats; r++)
        for (int k = 0; k < 4; k++) {
            int which = (k + r) % 4;
            double *cpu = &res->build_cpu[slot[which]][r];
            quiet_pause();
            if (which == 0)
                res->build[0][r] = time_our_build(s, 1, &res->ours_heap_bytes, cpu);
            else if (which == 1)
                res->build[3][r] = time_our_build(s, all, &bytes, cpu);
            else if (which == 2)
                res->build[1][r] =
                    time_embree_build_alone(1, s, eb, robust, &res->embree_bytes, &res->embree_peak_bytes, cpu);
            else
                res->build[2][r] = time_embree_build_alone(all, s, eb, robust, &bytes, &peak, cpu);
        }
    long n = s->triangle_count + s->sphere_count;
    res->primitives = n;
    res->ours_array_bytes = (long)bvh_memory_bytes(&s->bvh);
}

/* ------------------------------------------------------------------------ */
/* Output                                                                   */

static void print_results(const bench *b, const results *res)
{
    for (int set = 0; set < SET_COUNT && !res->builds_only; set++) {
        const agreement *a = &res->agree[set];
        double n = a->rays > 0 ? (double)a->rays : 1.0;
        printf("%-6s %8ld rays: %s ours %.2f%%, Embree %.2f%%; %ld disagreements (%.4f%%), %ld of them at a ray's "
               "ends\n",
               SET_NAME[set], a->rays, set == SET_SHADOW ? "blocked" : "hit", 100.0 * a->found[OURS] / n,
               100.0 * a->found[EMBREE] / n, a->disagreements, 100.0 * a->disagreements / n, a->at_ends);
    }
    for (int c = 0; c < res->configs && !res->builds_only; c++)
        for (int set = 0; set < SET_COUNT; set++) {
            double ours[3], theirs[3], ratio[3], r[MAX_REPEATS];
            for (int k = 0; k < res->repeats; k++)
                r[k] = res->mrays[c][OURS][set][k] / res->mrays[c][EMBREE][set][k];
            summary(res->mrays[c][OURS][set], res->repeats, ours);
            summary(res->mrays[c][EMBREE][set], res->repeats, theirs);
            summary(r, res->repeats, ratio);
            printf("threads %d %-6s ours %6.2f Mrays/s, Embree %6.2f Mrays/s (medians); ours/Embree %.3f (min %.3f, "
                   "max %.3f)\n",
                   res->threads[c], SET_NAME[set], ours[1], theirs[1], ratio[1], ratio[0], ratio[2]);
        }
    double ours[3], one[3], all[3], r1[3], rall[3], q1[MAX_REPEATS], qall[MAX_REPEATS];
    for (int k = 0; k < res->repeats; k++) {
        q1[k] = res->build[0][k] / res->build[1][k];
        qall[k] = res->build[3][k] / res->build[2][k];
    }
    double ours_all[3];
    summary(res->build[0], res->repeats, ours);
    summary(res->build[3], res->repeats, ours_all);
    summary(res->build[1], res->repeats, one);
    summary(res->build[2], res->repeats, all);
    summary(q1, res->repeats, r1);
    summary(qall, res->repeats, rall);
    printf("build (medians): ours %.3f ms 1 thread, %.3f ms all threads, Embree %.3f ms 1 thread, %.3f ms all threads; "
           "ours/Embree %.2f (min %.2f, max %.2f) at 1 thread, %.2f (min %.2f, max %.2f) at all\n",
           1e3 * ours[1], 1e3 * ours_all[1], 1e3 * one[1], 1e3 * all[1], r1[1], r1[0], r1[2], rall[1], rall[0],
           rall[2]);
    double busy[4][3]; /* CPU / wall time of each build: the threads that worked */
    for (int c = 0; c < 4; c++) {
        double q[MAX_REPEATS];
        for (int k = 0; k < res->repeats; k++)
            q[k] = res->build_cpu[c][k] / res->build[c][k];
        summary(q, res->repeats, busy[c]);
    }
    printf("build CPU / wall time (medians; the threads at work): ours %.2f 1 thread, %.2f all threads, Embree %.2f 1 "
           "thread, %.2f all threads\n",
           busy[0][1], busy[3][1], busy[1][1], busy[2][1]);
    double n = (double)res->primitives;
    printf("memory per primitive: ours %.1f B (arrays; heap growth %.1f B), Embree %.1f B held after the commit "
           "(peak %.1f B)\n",
           res->ours_array_bytes / n, res->ours_heap_bytes / n, res->embree_bytes / n, res->embree_peak_bytes / n);
    (void)b;
}

static void json_list(FILE *f, const char *name, const double *v, int n, const char *after)
{
    fprintf(f, "\"%s\": [", name);
    for (int k = 0; k < n; k++)
        fprintf(f, "%s%.6g", k ? ", " : "", v[k]);
    fprintf(f, "]%s", after);
}

static void json_sets(FILE *f, const results *res)
{
    fprintf(f, "  \"sets\": [\n");
    for (int set = 0; set < SET_COUNT; set++) {
        const agreement *a = &res->agree[set];
        fprintf(f,
                "    {\"name\": \"%s\", \"rays\": %ld, \"found_ours\": %ld, \"found_embree\": %ld, "
                "\"disagreements\": %ld, \"disagreements_at_ends\": %ld, \"timing\": [\n",
                SET_NAME[set], a->rays, a->found[OURS], a->found[EMBREE], a->disagreements, a->at_ends);
        for (int c = 0; c < res->configs; c++) {
            fprintf(f, "      {\"threads\": %d, ", res->threads[c]);
            json_list(f, "ours_mrays", res->mrays[c][OURS][set], res->repeats, ", ");
            json_list(f, "embree_mrays", res->mrays[c][EMBREE][set], res->repeats,
                      c + 1 < res->configs ? "},\n" : "}\n");
        }
        fprintf(f, "    ]}%s\n", set + 1 < SET_COUNT ? "," : "");
    }
    fprintf(f, "  ],\n");
}

/* The results as one JSON object, written to a temporary and renamed. */
static int write_json(const char *path, const bench *b, const results *res, int robust)
{
    char temporary[1100];
    snprintf(temporary, sizeof temporary, "%s.tmp", path);
    FILE *f = fopen(temporary, "w");
    if (!f)
        return -1;
    fprintf(f, "{\n  \"scene\": \"%s\",\n  \"triangles\": %d,\n  \"spheres\": %d,\n  \"embree_version\": \"%s\",\n",
            b->s->path, b->s->triangle_count, b->s->sphere_count, RTC_VERSION_STRING);
    fprintf(f, "  \"embree_robust\": %s,\n  \"embree_margin\": %.6g,\n  \"repeats\": %d,\n", robust ? "true" : "false",
            b->margin, res->repeats);
    fprintf(f, "  \"builds_only\": %s,\n", res->builds_only ? "true" : "false");
    json_sets(f, res);
    fprintf(f, "  \"build\": {");
    json_list(f, "ours_s", res->build[0], res->repeats, ", ");
    json_list(f, "ours_all_threads_s", res->build[3], res->repeats, ", ");
    json_list(f, "embree_1_thread_s", res->build[1], res->repeats, ", ");
    json_list(f, "embree_all_threads_s", res->build[2], res->repeats, ", ");
    json_list(f, "ours_cpu_s", res->build_cpu[0], res->repeats, ", ");
    json_list(f, "ours_all_threads_cpu_s", res->build_cpu[3], res->repeats, ", ");
    json_list(f, "embree_1_thread_cpu_s", res->build_cpu[1], res->repeats, ", ");
    json_list(f, "embree_all_threads_cpu_s", res->build_cpu[2], res->repeats, "},\n");
    fprintf(f, "  \"threads_all\": %d,\n  \"primitives\": %ld,\n", res->threads[res->configs - 1], res->primitives);
    fprintf(f,
            "  \"memory_bytes\": {\"ours_arrays\": %ld, \"ours_heap_growth\": %ld, \"embree_held\": %ld, "
            "\"embree_peak\": %ld}\n}\n",
            res->ours_array_bytes, res->ours_heap_bytes, res->embree_bytes, res->embree_peak_bytes);
    if (fclose(f) || rename(temporary, path))
        return -1;
    return 0;
}

/* ------------------------------------------------------------------------ */

static double largest_abs(double m, vec3 p) { return fmax(m, v3_max_component(v3_max(p, v3_neg(p)))); }

/* The largest absolute coordinate Embree rounds: the triangles' vertices, the rays' ends. */
static double largest_coordinate(const bench *b, embree_buffers eb)
{
    double m = 0.0;
    for (long i = 0; i < 9L * b->s->triangle_count; i++)
        m = fmax(m, fabs(eb.vertices[i]));
    for (int set = 0; set < SET_COUNT; set++)
        for (long i = 0; i < b->count[set]; i++) {
            m = largest_abs(m, b->sets[set][i].a);
            if (set == SET_SHADOW)
                m = largest_abs(m, b->sets[set][i].b);
        }
    return m;
}

static void embree_error(void *user, enum RTCError code, const char *message)
{
    (void)user;
    fprintf(stderr, "bench_embree: Embree error %d: %s\n", (int)code, message);
    exit(2);
}

static RTCDevice device_make(const char *config)
{
    RTCDevice device = rtcNewDevice(config);
    if (!device) {
        fprintf(stderr, "bench_embree: Embree's rtcNewDevice failed\n");
        exit(2);
    }
    rtcSetDeviceErrorFunction(device, embree_error, NULL);
    rtcSetDeviceMemoryMonitorFunction(device, monitor, NULL);
    return device;
}

typedef struct {
    const char *path, *json;
    int width, height, repeats, robust, builds_only;
    uint64_t seed;
} options;

static int parse_options(int argc, char **argv, options *o)
{
    *o = (options){.path = NULL, .json = NULL, .width = 512, .height = 512, .repeats = 7, .robust = 1, .seed = 1};
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--size") && i + 1 < argc && sscanf(argv[++i], "%dx%d", &o->width, &o->height) == 2)
            continue;
        if (!strcmp(argv[i], "--repeats") && i + 1 < argc)
            o->repeats = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--seed") && i + 1 < argc)
            o->seed = strtoull(argv[++i], NULL, 10);
        else if (!strcmp(argv[i], "--json") && i + 1 < argc)
            o->json = argv[++i];
        else if (!strcmp(argv[i], "--fast"))
            o->robust = 0;
        else if (!strcmp(argv[i], "--builds-only"))
            o->builds_only = 1;
        else if (argv[i][0] != '-' && !o->path)
            o->path = argv[i];
        else
            return -1;
    }
    int ok = o->path && o->width > 0 && o->height > 0 && o->repeats >= 1 && o->repeats <= MAX_REPEATS;
    return ok ? 0 : -1;
}

int main(int argc, char **argv)
{
    options o;
    if (parse_options(argc, argv, &o)) {
        fprintf(stderr,
                "usage: bench_embree SCENE [--size WxH] [--repeats N (1..%d)] [--seed N] [--fast] "
                "[--builds-only] [--json FILE]\n",
                MAX_REPEATS);
        return 2;
    }
    static scene s;
    char err[1024];
    if (scene_load(o.path, &s, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        return 2;
    }
    RTCDevice device = device_make(NULL);
    embree_buffers eb = embree_buffers_make(&s);
    bench b = {.s = &s, .embree = embree_scene_make(device, &s, eb, o.robust)};
    rtcCommitScene(b.embree);
    make_sets(&b, o.builds_only ? 1 : o.width, o.builds_only ? 1 : o.height, o.seed);
    b.margin = EMBREE_MARGIN * largest_coordinate(&b, eb);
    printf("scene %s: %d triangles, %d spheres (an Embree user geometry calling intersect_sphere); Embree %s, "
           "%s scene, default build quality; Embree's rays start and end %.3g later and earlier (float origins)\n",
           s.path, s.triangle_count, s.sphere_count, RTC_VERSION_STRING, o.robust ? "robust" : "fast (not robust)",
           b.margin);
    results res = {
        .repeats = o.repeats, .configs = 1, .threads = {1, omp_get_max_threads()}, .builds_only = o.builds_only};
    if (res.threads[1] > 1)
        res.configs = 2;
    else
        res.threads[0] = 1;
    if (!o.builds_only) {
        for (int set = 0; set < SET_COUNT; set++)
            res.agree[set] = compare_set(&b, set);
        time_sets(&b, &res);
    }
    rtcReleaseScene(b.embree); /* no device alive while the builds are timed (see time_embree_build_alone) */
    rtcReleaseDevice(device);
    time_builds(&s, eb, o.robust, &res);
    print_results(&b, &res);
    int status = 0;
    if (o.json && write_json(o.json, &b, &res, o.robust)) {
        fprintf(stderr, "bench_embree: cannot write %s\n", o.json);
        status = 2;
    }
    for (int set = 0; set < SET_COUNT; set++)
        free(b.sets[set]);
    free(eb.vertices);
    free(eb.indices);
    scene_free(&s);
    return status;
}
