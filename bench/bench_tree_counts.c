/* bench_tree_counts.c — is the gap to Embree in the tree or in the traversal?
 *
 * Builds a second 8-wide tree over the same primitives with Embree's own
 * builder (rtcBuildBVH: binned SAH, branching factor 8, leaves of at most
 * four, Embree's default quality and costs), and walks both trees, ours
 * (common/bvh.c) and Embree's, with one plain counting traversal: closest
 * hit, children visited nearest first, a box skipped once it starts beyond
 * the nearest hit.  The same rays (a jittered camera ray per pixel, and a
 * cosine-distributed bounce from each camera hit) go through both, and it
 * prints the nodes, leaves and primitives each tree makes a ray visit.  If
 * Embree's tree needed far fewer visits, its builder would explain the gap
 * in rays per second (bench_embree); if the counts are alike, the cost is
 * in how we visit them.  Counts, not times: the traversal is the same code
 * for both trees and the machine's speed does not enter.
 *
 *     build/bench/bench_tree_counts SCENE [--size WxH]      (make bench builds it where Embree is)
 */
#include <embree3/rtcore.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bvh.h"
#include "rng.h"
#include "sampling.h"
#include "scene.h"

/* One node of either tree: a leaf of up to four primitives, or up to eight children and their boxes. */
typedef struct tree_node {
    int is_leaf, count;
    int primitives[4];
    struct tree_node *child[BVH_WIDTH];
    double lo[BVH_WIDTH][3], hi[BVH_WIDTH][3];
} tree_node;

typedef struct {
    double nodes, leaves, primitives;
} counts;

/* ---- Embree's tree ----------------------------------------------------- */

static void *create_node(RTCThreadLocalAllocator allocator, unsigned child_count, void *user)
{
    (void)user;
    tree_node *n = rtcThreadLocalAlloc(allocator, sizeof *n, 16);
    memset(n, 0, sizeof *n);
    n->count = (int)child_count;
    return n;
}

static void set_children(void *node, void **children, unsigned count, void *user)
{
    (void)user;
    for (unsigned k = 0; k < count; k++)
        ((tree_node *)node)->child[k] = children[k];
}

static void set_bounds(void *node, const struct RTCBounds **bounds, unsigned count, void *user)
{
    (void)user;
    tree_node *n = node;
    for (unsigned k = 0; k < count; k++) {
        const float lo[3] = {bounds[k]->lower_x, bounds[k]->lower_y, bounds[k]->lower_z};
        const float hi[3] = {bounds[k]->upper_x, bounds[k]->upper_y, bounds[k]->upper_z};
        for (int a = 0; a < 3; a++)
            n->lo[k][a] = lo[a], n->hi[k][a] = hi[a];
    }
}

static void *create_leaf(RTCThreadLocalAllocator allocator, const struct RTCBuildPrimitive *primitives, size_t count,
                         void *user)
{
    (void)user;
    tree_node *n = rtcThreadLocalAlloc(allocator, sizeof *n, 16);
    memset(n, 0, sizeof *n);
    n->is_leaf = 1;
    n->count = count < 4 ? (int)count : 4; /* maxLeafSize 4: never more */
    for (int i = 0; i < n->count; i++)
        n->primitives[i] = (int)primitives[i].primID;
    return n;
}

/* The box of primitive p, rounded outward to floats. */
static struct RTCBuildPrimitive build_primitive(const scene *s, int p)
{
    vec3 lo, hi;
    if (p < s->triangle_count) {
        const triangle *t = &s->triangles[p];
        vec3 p1 = v3_add(t->p0, t->e1), p2 = v3_add(t->p0, t->e2);
        lo = v3_min(t->p0, v3_min(p1, p2)), hi = v3_max(t->p0, v3_max(p1, p2));
    } else {
        const surface *sphere = &s->surfaces[s->sphere_surfaces[p - s->triangle_count]];
        lo = v3_sub(sphere->center, v3_splat(sphere->radius)), hi = v3_add(sphere->center, v3_splat(sphere->radius));
    }
    return (struct RTCBuildPrimitive){.lower_x = nextafterf((float)lo.x, -INFINITY),
                                      .lower_y = nextafterf((float)lo.y, -INFINITY),
                                      .lower_z = nextafterf((float)lo.z, -INFINITY),
                                      .upper_x = nextafterf((float)hi.x, INFINITY),
                                      .upper_y = nextafterf((float)hi.y, INFINITY),
                                      .upper_z = nextafterf((float)hi.z, INFINITY),
                                      .primID = (unsigned)p};
}

static tree_node *embree_tree(RTCBVH bvh, const scene *s, unsigned block, struct RTCBuildPrimitive **storage)
{
    int n = s->triangle_count + s->sphere_count;
    *storage = malloc((size_t)n * sizeof **storage);
    for (int p = 0; p < n; p++)
        (*storage)[p] = build_primitive(s, p);
    struct RTCBuildArguments args = rtcDefaultBuildArguments();
    args.maxBranchingFactor = BVH_WIDTH;
    args.maxLeafSize = 4;
    args.sahBlockSize = block; /* 4: a leaf costs as a block of four, as Embree's own four-triangle leaves do */
    args.bvh = bvh;
    args.primitives = *storage;
    args.primitiveCount = args.primitiveArrayCapacity = (size_t)n;
    args.createNode = create_node, args.setNodeChildren = set_children, args.setNodeBounds = set_bounds;
    args.createLeaf = create_leaf;
    return rtcBuildBVH(&args);
}

/* ---- our tree, in the same form ---------------------------------------- */

static tree_node *our_subtree(const scene *s, int child)
{
    tree_node *n = calloc(1, sizeof *n);
    if (child < 0) {
        n->is_leaf = 1;
        const leaf_pair *pair = s->bvh.leaf_pairs + bvh_leaf_first(child);
        for (int i = 0; i < bvh_leaf_count(child); i++)
            for (int k = 0; k < 2; k++)
                if (pair[i].primitive[k] >= 0)
                    n->primitives[n->count++] = pair[i].primitive[k];
        return n;
    }
    const wide_node *w = &s->bvh.nodes[child];
    for (int k = 0; k < BVH_WIDTH; k++) {
        if (!(w->bounds[0][k] <= w->bounds[3][k])) /* an unused slot: an empty box */
            continue;
        for (int a = 0; a < 3; a++)
            n->lo[n->count][a] = w->bounds[a][k] * s->bvh.unit, n->hi[n->count][a] = w->bounds[a + 3][k] * s->bvh.unit;
        n->child[n->count++] = our_subtree(s, w->child[k]);
    }
    return n;
}

static void free_ours(tree_node *n)
{
    for (int k = 0; !n->is_leaf && k < n->count; k++)
        free_ours(n->child[k]);
    free(n);
}

/* ---- the counting traversal -------------------------------------------- */

static double primitive_hit(const scene *s, int p, ray r)
{
    if (p < s->triangle_count)
        return intersect_triangle(&s->triangles[p], r);
    const surface *sphere = &s->surfaces[s->sphere_surfaces[p - s->triangle_count]];
    return intersect_sphere(sphere->center, sphere->radius, r);
}

/* Where the ray enters box k of n, or INFINITY if it misses it before t_max. */
static double entry(const tree_node *n, int k, ray r, double t_max)
{
    double near = 0.0, far = t_max, o[3] = {r.origin.x, r.origin.y, r.origin.z};
    double d[3] = {r.direction.x, r.direction.y, r.direction.z};
    for (int a = 0; a < 3; a++) {
        double t0 = (n->lo[k][a] - o[a]) / d[a], t1 = (n->hi[k][a] - o[a]) / d[a];
        near = fmax(near, fmin(t0, t1)), far = fmin(far, fmax(t0, t1));
    }
    return near <= far ? near : INFINITY;
}

static void count_ray(const scene *s, const tree_node *root, ray r, counts *c)
{
    const tree_node *stack[64 * BVH_WIDTH];
    double stack_entry[64 * BVH_WIDTH];
    int top = 0;
    double nearest = INFINITY;
    stack[top] = root, stack_entry[top++] = 0.0;
    while (top > 0) {
        const tree_node *n = stack[--top];
        if (stack_entry[top] > nearest)
            continue;
        if (n->is_leaf) {
            c->leaves++;
            for (int i = 0; i < n->count; i++, c->primitives++)
                nearest = fmin(nearest, primitive_hit(s, n->primitives[i], r));
            continue;
        }
        c->nodes++;
        int order[BVH_WIDTH], hits = 0;
        double t[BVH_WIDTH];
        for (int k = 0; k < n->count; k++)
            if ((t[k] = entry(n, k, r, nearest)) < INFINITY) /* farthest first on the stack: nearest popped first */
                order[hits++] = k;
        for (int i = 1; i < hits; i++)
            for (int j = i; j > 0 && t[order[j]] > t[order[j - 1]]; j--) {
                int swap = order[j];
                order[j] = order[j - 1], order[j - 1] = swap;
            }
        for (int i = 0; i < hits; i++)
            stack[top] = n->child[order[i]], stack_entry[top++] = t[order[i]];
    }
}

/* The rays: a jittered camera ray per pixel, then from each camera hit a cosine-distributed bounce. */
static void count_rays(const scene *s, const tree_node *root, int width, int height, counts c[2], long rays[2])
{
    camera_frame frame = camera_frame_make(&s->camera, width, height);
    for (long i = 0; i < (long)width * height; i++) {
        rng g = rng_for(1, (uint64_t)i, 0);
        ray r = camera_frame_ray(&frame, (double)(i % width) + rng_uniform(&g), (double)(i / width) + rng_uniform(&g));
        count_ray(s, root, r, &c[0]);
        rays[0]++;
        hit h;
        if (!scene_intersect(s, r, INFINITY, &h))
            continue;
        vec3 n = v3_dot(h.normal, r.direction) < 0.0 ? h.normal : v3_neg(h.normal);
        vec3 d = onb_to_world(onb_from_normal(n), cosine_sample_hemisphere(rng_uniform(&g), rng_uniform(&g)));
        count_ray(s, root, (ray){scene_offset_origin(s, h.point, n, d), d}, &c[1]);
        rays[1]++;
    }
}

int main(int argc, char **argv)
{
    int width = 256, height = 256;
    if (argc < 2 || (argc == 4 && (strcmp(argv[2], "--size") || sscanf(argv[3], "%dx%d", &width, &height) != 2)) ||
        (argc != 2 && argc != 4) || width <= 0 || height <= 0) {
        fprintf(stderr, "usage: bench_tree_counts SCENE [--size WxH]\n");
        return 2;
    }
    static scene s;
    char err[1024];
    if (scene_load(argv[1], &s, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        return 2;
    }
    RTCDevice device = rtcNewDevice(NULL);
    RTCBVH bvh[2] = {rtcNewBVH(device), rtcNewBVH(device)};
    struct RTCBuildPrimitive *storage[2];
    tree_node *trees[3] = {our_subtree(&s, 0), embree_tree(bvh[0], &s, 1, &storage[0]),
                           embree_tree(bvh[1], &s, 4, &storage[1])};
    const char *name[3] = {"ours (bvh_build)", "Embree, blocks 1", "Embree, blocks 4"};
    printf("%s: %d primitives, %dx%d camera rays and their bounces; per ray: nodes, leaves, primitives tested\n",
           s.path, s.triangle_count + s.sphere_count, width, height);
    for (int t = 0; t < 3; t++) {
        counts c[2] = {{0}};
        long rays[2] = {0};
        count_rays(&s, trees[t], width, height, c, rays);
        printf("  %-17s camera %5.2f %5.2f %5.2f   bounce %5.2f %5.2f %5.2f\n", name[t], c[0].nodes / rays[0],
               c[0].leaves / rays[0], c[0].primitives / rays[0], c[1].nodes / rays[1], c[1].leaves / rays[1],
               c[1].primitives / rays[1]);
    }
    free_ours(trees[0]);
    for (int i = 0; i < 2; i++)
        rtcReleaseBVH(bvh[i]), free(storage[i]);
    rtcReleaseDevice(device);
    scene_free(&s);
    return 0;
}
