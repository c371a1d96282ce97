/* bvh.c — the BVH (binned surface area heuristic) and the ray queries.
 *
 * Reading order: boxes, the build, the copy that traversal reads, the
 * primitive tests, the traversal, and the public queries (scene_intersect,
 * scene_intersect_brute_force, scene_occluded).
 */
#include "bvh.h"

#include <float.h>
#include <stdlib.h>
#include <string.h>

#ifdef __SSE2__
#include <emmintrin.h> /* two-wide double SIMD for the BVH box tests */
#endif

/* BVH: at most this many primitives in a leaf, this many SAH bins (with 16
 * the Cornell box's tree costs incoherent rays 3% more node visits). */
enum { BVH_LEAF_SIZE = 4, BVH_BINS = 64 };
/* Past this depth the build splits in the middle of the list, so the tree
 * depth (and the traversal stack) stays bounded whatever the input. */
enum { BVH_SAH_MAX_DEPTH = 48, BVH_STACK_SIZE = 128 };

/* Triangles intersect with a margin of this fraction of scene.epsilon
 * around their edges (see triangle_transform): 1e-11 of the scene, five
 * orders of magnitude above the rounding it covers, and small enough that
 * ray origins moved off a surface by epsilon stay outside the BVH boxes,
 * which grow by the margin too (see bvh_primitive_bounds). */
static const double EDGE_MARGIN = 1e-2;

/* ------------------------------------------------------------------------ */
/* Boxes                                                                     */

static aabb aabb_empty(void) { return (aabb){v3_splat(INFINITY), v3_splat(-INFINITY)}; }
static aabb aabb_add_point(aabb b, vec3 p) { return (aabb){v3_min(b.lo, p), v3_max(b.hi, p)}; }
static aabb aabb_union(aabb a, aabb b) { return (aabb){v3_min(a.lo, b.lo), v3_max(a.hi, b.hi)}; }
static double aabb_half_area(aabb b)
{
    vec3 d = v3_sub(b.hi, b.lo);
    return d.x * d.y + d.y * d.z + d.z * d.x;
}

static aabb triangle_bounds(const triangle *t)
{
    aabb b = aabb_add_point(aabb_empty(), t->p0);
    b = aabb_add_point(b, v3_add(t->p0, t->e1));
    return aabb_add_point(b, v3_add(t->p0, t->e2));
}

static aabb sphere_bounds(const surface *sphere)
{
    vec3 r = v3_splat(sphere->radius);
    return (aabb){v3_sub(sphere->center, r), v3_add(sphere->center, r)};
}

static aabb primitive_bounds(const scene *s, int primitive)
{
    if (primitive < s->triangle_count)
        return triangle_bounds(&s->triangles[primitive]);
    return sphere_bounds(&s->surfaces[s->sphere_surfaces[primitive - s->triangle_count]]);
}


/* ------------------------------------------------------------------------ */
/* BVH: binned surface area heuristic                                        */

typedef struct {
    scene *s;
    aabb *bounds;    /* per primitive */
    vec3 *centroids; /* per primitive */
} bvh_builder;

/* Which of BVH_BINS bins along `axis` a centroid falls into. */
static int bin_of(vec3 centroid, int axis, double lo, double scale)
{
    int bin = (int)((v3_get(centroid, axis) - lo) * scale);
    return bin < 0 ? 0 : bin >= BVH_BINS ? BVH_BINS - 1 : bin;
}

/* The surface area heuristic prices a subtree for a random ray: a node's box
 * is hit with probability area(box) / area(parent).  Splitting costs one
 * traversal step (a node visit: two box tests) plus the expected primitive
 * tests of both children; a leaf costs a test of every primitive in it.  In
 * traverse() a node visit and a triangle test cost about the same (some 40
 * instructions each); measured on the Cornell box, 1 : 1 beats making
 * leaves bigger (2 : 1 tests more triangles than it saves boxes). */
static const double SAH_TRAVERSAL_COST = 1.0, SAH_PRIMITIVE_COST = 1.0;

/* Choose where to split primitives [first, first+count): returns the number
 * that go left (0 < result < count) after reordering them, or 0 when a leaf
 * is cheaper than any split (only offered if count <= BVH_LEAF_SIZE).  All
 * three axes are tried: the longest one is not always the best (a room's
 * walls are as long in every direction). */
static int bvh_partition(bvh_builder *b, int first, int count, int depth, int *axis_out)
{
    int *order = b->s->bvh.primitive_order;
    aabb centroid_box = aabb_empty(), node_box = aabb_empty();
    for (int i = first; i < first + count; i++) {
        centroid_box = aabb_add_point(centroid_box, b->centroids[order[i]]);
        node_box = aabb_union(node_box, b->bounds[order[i]]);
    }
    vec3 extent = v3_sub(centroid_box.hi, centroid_box.lo);
    *axis_out = extent.x >= extent.y && extent.x >= extent.z ? 0 : extent.y >= extent.z ? 1 : 2;
    /* A pathological tree: split the list in half. */
    if (depth >= BVH_SAH_MAX_DEPTH)
        return count <= BVH_LEAF_SIZE ? 0 : count / 2;

    double best_cost = INFINITY, best_lo = 0.0, best_scale = 0.0;
    int best_split = -1, best_axis = -1;
    for (int axis = 0; axis < 3; axis++) {
        double lo = v3_get(centroid_box.lo, axis), width = v3_get(extent, axis);
        if (!(width > 0.0))
            continue; /* all centroids in one plane across this axis */
        double scale = BVH_BINS / width * (1.0 - 1e-9);
        int bin_count[BVH_BINS] = {0};
        aabb bin_box[BVH_BINS];
        for (int k = 0; k < BVH_BINS; k++)
            bin_box[k] = aabb_empty();
        for (int i = first; i < first + count; i++) {
            int k = bin_of(b->centroids[order[i]], axis, lo, scale);
            bin_count[k]++;
            bin_box[k] = aabb_union(bin_box[k], b->bounds[order[i]]);
        }
        /* Cost of splitting after bin k: area(left) * n(left) + area(right) * n(right). */
        double left_cost[BVH_BINS];
        aabb box = aabb_empty();
        int n = 0;
        for (int k = 0; k < BVH_BINS - 1; k++) {
            box = aabb_union(box, bin_box[k]);
            n += bin_count[k];
            left_cost[k] = n ? aabb_half_area(box) * n : 0.0;
        }
        box = aabb_empty();
        n = 0;
        for (int k = BVH_BINS - 1; k > 0; k--) {
            box = aabb_union(box, bin_box[k]);
            n += bin_count[k];
            if (n == 0 || n == count)
                continue;
            double cost = left_cost[k - 1] + aabb_half_area(box) * n;
            if (cost < best_cost) {
                best_cost = cost;
                best_split = k;
                best_axis = axis;
                best_lo = lo;
                best_scale = scale;
            }
        }
    }
    if (best_split < 0)
        return count <= BVH_LEAF_SIZE ? 0 : count / 2;
    /* Leaf or split?  Both in units of one primitive test per unit area. */
    double area = aabb_half_area(node_box);
    double split_cost = SAH_TRAVERSAL_COST + SAH_PRIMITIVE_COST * best_cost / area;
    if (count <= BVH_LEAF_SIZE && !(split_cost < SAH_PRIMITIVE_COST * count))
        return 0;
    *axis_out = best_axis;

    /* Move the primitives of bins < best_split to the front. */
    int i = first, j = first + count - 1;
    while (i <= j) {
        if (bin_of(b->centroids[order[i]], best_axis, best_lo, best_scale) < best_split) {
            i++;
        } else {
            int tmp = order[i];
            order[i] = order[j];
            order[j--] = tmp;
        }
    }
    int left = i - first;
    return left > 0 && left < count ? left : count / 2;
}

/* Bounds of all primitives (triangles and spheres). */
aabb bvh_geometry_bounds(const scene *s)
{
    aabb bounds = aabb_empty();
    for (int i = 0; i < s->triangle_count + s->sphere_count; i++)
        bounds = aabb_union(bounds, primitive_bounds(s, i));
    return bounds;
}

/* ------------------------------------------------------------------------ */
/* The copy traversal reads (trace_node, leaf_primitive: see bvh.h)         */

/* Baldwin & Weber, "Fast Ray-Triangle Intersections by Coordinate
 * Transformation" (JCGT 2016).  Every point is x = p0 + u e1 + v e2 + w n
 * for n = e1 x e2; the triangle is w = 0, u >= 0, v >= 0, u + v <= 1.  The
 * map x -> (u, v, w) is the inverse of the matrix with columns e1, e2, n,
 * whose rows are (e2 x n) / |n|^2, (n x e1) / |n|^2 and n / |n|^2: computed
 * once per triangle here, it leaves a ray test of a few dot products.
 *
 * Watertightness: two triangles sharing an edge compute u and v with
 * different roundings, so a ray exactly through the edge (the diagonal of a
 * quad, seen by a camera on its axis) could slip between them.  Each edge
 * is therefore moved out by `tolerance` (EDGE_MARGIN * scene.epsilon), far
 * above the rounding and far below anything visible.  In u, v units that is
 * tolerance / height over the edge, and the height over edge p0-p2 (where
 * u = 0) is |n| / |e2|, and so on. */
static leaf_primitive triangle_transform(const triangle *t, int primitive, double tolerance)
{
    vec3 n = v3_cross(t->e1, t->e2);
    double inv = 1.0 / v3_dot(n, n);
    leaf_primitive p = {.row = {v3_scale(v3_cross(t->e2, n), inv), v3_scale(v3_cross(n, t->e1), inv), v3_scale(n, inv)},
                        .primitive = primitive};
    for (int i = 0; i < 3; i++)
        p.offset[i] = -v3_dot(p.row[i], t->p0);
    double tolerance_per_length = tolerance / v3_length(n);
    p.u_min = -tolerance_per_length * v3_length(t->e2);
    p.v_min = -tolerance_per_length * v3_length(t->e1);
    p.uv_max = 1.0 + tolerance_per_length * v3_length(v3_sub(t->e2, t->e1));
    return p;
}

static leaf_primitive make_leaf_primitive(const scene *s, int primitive)
{
    if (primitive < s->triangle_count)
        return triangle_transform(&s->triangles[primitive], primitive, EDGE_MARGIN * s->epsilon);
    const surface *sphere = &s->surfaces[s->sphere_surfaces[primitive - s->triangle_count]];
    return (leaf_primitive){
        .row = {sphere->center}, .offset = {sphere->radius}, .primitive = primitive, .is_sphere = 1};
}

/* Child k of trace node `out` becomes BVH node `index` (recursively). */
static void trace_set_child(const bvh_node *build_nodes, trace_node *nodes, int *trace_count, int out, int k, int index)
{
    const bvh_node *node = &build_nodes[index];
    const double faces[6] = {node->bounds.lo.x, node->bounds.lo.y, node->bounds.lo.z,
                             node->bounds.hi.x, node->bounds.hi.y, node->bounds.hi.z};
    for (int f = 0; f < 6; f++)
        nodes[out].bounds[2 * f + k] = faces[f];
    nodes[out].count[k] = node->count;
    if (node->count > 0) {
        nodes[out].child[k] = node->first;
        return;
    }
    int inner = (*trace_count)++;
    nodes[out].child[k] = inner;
    trace_set_child(build_nodes, nodes, trace_count, inner, 0, index + 1);
    trace_set_child(build_nodes, nodes, trace_count, inner, 1, node->second_child);
}

/* Fills bvh->trace_nodes (trace_node_count of them, allocated) and
 * bvh->leaf_primitives from the built tree. */
static void build_trace_copy(const scene *s, scene_bvh *bvh)
{
    const bvh_node *build = bvh->build_nodes;
    trace_node *nodes = bvh->trace_nodes;
    int trace_count = 1;
    if (build[0].count > 0) {
        /* A root leaf becomes child 0 of trace node 0; child 1 is an empty
         * box (lo = +inf, hi = -inf), which every ray misses. */
        for (int f = 0; f < 6; f++)
            nodes[0].bounds[2 * f + 1] = f < 3 ? INFINITY : -INFINITY;
        nodes[0].child[1] = nodes[0].count[1] = 0;
        trace_set_child(build, nodes, &trace_count, 0, 0, 0);
    } else {
        /* The root's own box is never tested: its children's are. */
        trace_set_child(build, nodes, &trace_count, 0, 0, 1);
        trace_set_child(build, nodes, &trace_count, 0, 1, build[0].second_child);
    }
    for (int i = 0; i < s->triangle_count + s->sphere_count; i++)
        bvh->leaf_primitives[i] = make_leaf_primitive(s, bvh->primitive_order[i]);
}

/* Builds node `index = node_count` over primitives [first, first+count) and
 * its subtree.  Node indices are handed out before recursing, so the first
 * child of a node is the next index (depth-first layout). */
static void bvh_build_node(bvh_builder *b, int first, int count, int depth);

/* A primitive's box for the BVH.  Triangles intersect with a margin around
 * their edges (see triangle_transform), so their boxes grow by it too, but
 * only within the triangle's plane: along axis i that is
 * margin * sqrt(1 - n_i^2), zero across an axis-aligned wall, whose box
 * then stays flat. */
static aabb bvh_primitive_bounds(const scene *s, int primitive)
{
    aabb b = primitive_bounds(s, primitive);
    if (primitive >= s->triangle_count)
        return b;
    vec3 n = s->triangles[primitive].normal;
    vec3 pad = v3(sqrt(fmax(1.0 - n.x * n.x, 0.0)), sqrt(fmax(1.0 - n.y * n.y, 0.0)), sqrt(fmax(1.0 - n.z * n.z, 0.0)));
    pad = v3_scale(pad, EDGE_MARGIN * s->epsilon);
    return (aabb){v3_sub(b.lo, pad), v3_add(b.hi, pad)};
}

/* count records of `size` bytes on a BVH_ALIGNMENT boundary (aligned_alloc
 * wants a multiple of the alignment). */
static void *aligned_array(size_t count, size_t size)
{
    size_t bytes = (count * size + BVH_ALIGNMENT - 1) / BVH_ALIGNMENT * BVH_ALIGNMENT;
    return aligned_alloc(BVH_ALIGNMENT, bytes);
}

int bvh_build(scene *s)
{
    scene_bvh *bvh = &s->bvh;
    int n = s->triangle_count + s->sphere_count;
    bvh->node_count = 0;
    if (n == 0)
        return 0; /* nothing to intersect: traverse() sees node_count == 0 */
    bvh->primitive_order = malloc((size_t)n * sizeof *bvh->primitive_order);
    /* A binary tree with at most n leaves has fewer than 2 n nodes. */
    bvh->build_nodes = malloc((size_t)2 * (size_t)n * sizeof *bvh->build_nodes);
    bvh_builder b = {.s = s, .bounds = malloc((size_t)n * sizeof(aabb)), .centroids = malloc((size_t)n * sizeof(vec3))};
    int ok = bvh->primitive_order && bvh->build_nodes && b.bounds && b.centroids;
    if (ok) {
        for (int i = 0; i < n; i++) {
            bvh->primitive_order[i] = i;
            b.bounds[i] = bvh_primitive_bounds(s, i);
            b.centroids[i] = v3_scale(v3_add(b.bounds[i].lo, b.bounds[i].hi), 0.5);
        }
        bvh_build_node(&b, 0, n, 0);
    }
    free(b.bounds);
    free(b.centroids);
    if (!ok)
        return -1;
    /* One trace node per inner node (a root leaf gets one of its own). */
    int inner = 0;
    for (int i = 0; i < bvh->node_count; i++)
        inner += bvh->build_nodes[i].count == 0;
    bvh->trace_node_count = inner > 0 ? inner : 1;
    bvh->trace_nodes = aligned_array((size_t)bvh->trace_node_count, sizeof *bvh->trace_nodes);
    bvh->leaf_primitives = aligned_array((size_t)n, sizeof *bvh->leaf_primitives);
    if (bvh->trace_nodes == NULL || bvh->leaf_primitives == NULL)
        return -1;
    build_trace_copy(s, bvh);
    return 0;
}

void bvh_free(scene_bvh *bvh)
{
    free(bvh->primitive_order);
    free(bvh->build_nodes);
    free(bvh->trace_nodes);
    free(bvh->leaf_primitives);
    memset(bvh, 0, sizeof *bvh);
}

static void bvh_build_node(bvh_builder *b, int first, int count, int depth)
{
    scene_bvh *bvh = &b->s->bvh;
    int index = bvh->node_count++;
    bvh_node *node = &bvh->build_nodes[index];
    node->bounds = aabb_empty();
    for (int i = first; i < first + count; i++)
        node->bounds = aabb_union(node->bounds, b->bounds[bvh->primitive_order[i]]);
    node->first = first;
    node->axis = 0;
    node->second_child = -1;
    int axis = 0;
    int left = count > 1 ? bvh_partition(b, first, count, depth, &axis) : 0;
    if (left == 0) {
        node->count = count;
        return;
    }
    node->count = 0;
    node->axis = axis;
    bvh_build_node(b, first, left, depth + 1); /* becomes index + 1 */
    bvh->build_nodes[index].second_child = bvh->node_count;
    bvh_build_node(b, first + left, count - left, depth + 1);
}

/* ------------------------------------------------------------------------ */
/* Intersection                                                              */

/* The ray in the triangle's coordinates (see triangle_transform): w along
 * the ray is w_o + t w_d, zero at t = -w_o / w_d; the hit point there gives
 * u and v.  About half the planes are behind the ray or beyond the nearest
 * hit, so t is checked first (u and v need the division's result anyway);
 * the u, v conditions are combined into one branch, as they are coin flips
 * for incoherent rays.  A ray parallel to the plane has w_d = 0 and
 * t = +-inf or NaN, which the t check rejects, so there is no NaN out. */
static inline double triangle_hit(const leaf_primitive *p, vec3 origin, vec3 direction, double t_max)
{
    double w_o = v3_dot(p->row[2], origin) + p->offset[2];
    double w_d = v3_dot(p->row[2], direction);
    double t = -w_o / w_d;
    if (!(t > 0.0 && t < t_max))
        return INFINITY;
    vec3 h = v3_madd(origin, direction, t);
    double u = v3_dot(p->row[0], h) + p->offset[0];
    double v = v3_dot(p->row[1], h) + p->offset[1];
    int inside = (u >= p->u_min) & (v >= p->v_min) & (u + v <= p->uv_max);
    return inside ? t : INFINITY;
}

double intersect_triangle(const triangle *tri, ray r)
{
    /* The tolerance the triangle would have in a scene of its own. */
    vec3 p1 = v3_add(tri->p0, tri->e1), p2 = v3_add(tri->p0, tri->e2);
    vec3 largest = v3_max(v3_max(v3_max(tri->p0, v3_neg(tri->p0)), v3_max(p1, v3_neg(p1))), v3_max(p2, v3_neg(p2)));
    leaf_primitive p = triangle_transform(tri, 0, EDGE_MARGIN * 1e-9 * v3_max_component(largest));
    return triangle_hit(&p, r.origin, r.direction, INFINITY);
}

/* Haines, Guenther & Akenine-Moller, "Precision Improvements for Ray/Sphere
 * Intersection" (Ray Tracing Gems, ch. 7).  With f = o - c, solve
 * a t^2 + 2 b t + c = 0, a = d.d, b = f.d, c = f.f - r^2.  The textbook
 * discriminant b^2 - a c subtracts two huge numbers when r is large; the
 * same quantity written as a (r^2 - |f - (b/a) d|^2) does not.  The roots
 * come from q = -(b + sign(b) sqrt(disc)) as q / a and c / q, which avoids
 * the other cancellation (-b + sqrt(...) with both nearly equal). */
static inline double sphere_hit(vec3 center, double radius, vec3 origin, vec3 direction)
{
    vec3 f = v3_sub(origin, center);
    double a = v3_dot(direction, direction);
    double b = v3_dot(f, direction);
    double c = v3_dot(f, f) - radius * radius;
    vec3 l = v3_madd(f, direction, -b / a); /* f minus its component along d */
    double disc = a * (radius * radius - v3_dot(l, l));
    if (!(disc >= 0.0))
        return INFINITY;
    double q = -(b + copysign(sqrt(disc), b));
    if (q == 0.0)
        return INFINITY; /* ray starts on the sphere and grazes it */
    double t0 = c / q, t1 = q / a;
    if (t0 > t1) {
        double tmp = t0;
        t0 = t1;
        t1 = tmp;
    }
    if (t0 > 0.0)
        return t0;
    if (t1 > 0.0)
        return t1;
    return INFINITY;
}

double intersect_sphere(vec3 center, double radius, ray r) { return sphere_hit(center, radius, r.origin, r.direction); }

/* Hit distance of a leaf primitive if it is below t_max, else INFINITY. */
static inline double primitive_hit(const leaf_primitive *p, vec3 origin, vec3 direction, double t_max)
{
    if (!p->is_sphere)
        return triangle_hit(p, origin, direction, t_max);
    double t = sphere_hit(p->row[0], p->offset[0], origin, direction);
    return t < t_max ? t : INFINITY;
}

static void fill_hit(const scene *s, ray r, double t, int primitive, hit *out)
{
    out->t = t;
    out->point = v3_madd(r.origin, r.direction, t);
    out->primitive = primitive;
    if (primitive < s->triangle_count) {
        out->surface = s->triangles[primitive].surface;
        out->normal = s->triangles[primitive].normal;
    } else {
        int surface_index = s->sphere_surfaces[primitive - s->triangle_count];
        const surface *sphere = &s->surfaces[surface_index];
        out->surface = surface_index;
        out->normal = v3_scale(v3_sub(out->point, sphere->center), 1.0 / sphere->radius);
    }
}

/* What the slab test needs of a ray, computed once per ray: the division
 * is done here, and for each axis where in trace_node.bounds (counted in
 * doubles) the face lies that the ray meets first (lo if the direction is
 * positive, hi if not) and the face it leaves by.  (ptrdiff_t and a count
 * of doubles, so that each load is one instruction: base + 8 * offset.) */
typedef struct {
    vec3 origin, inv_dir;
    ptrdiff_t near_x, near_y, near_z, far_x, far_y, far_z;
#ifdef __SSE2__
    __m128d origin_x2, origin_y2, origin_z2, inv_dir_x2, inv_dir_y2, inv_dir_z2; /* in both lanes, for box_entries */
#endif
} ray_setup;

static inline ray_setup setup_ray(vec3 origin, vec3 direction)
{
    /* 1/0 = inf is what the slab test wants for an axis-parallel ray. */
    vec3 inv_dir = v3(1.0 / direction.x, 1.0 / direction.y, 1.0 / direction.z);
    ptrdiff_t neg_x = inv_dir.x < 0.0, neg_y = inv_dir.y < 0.0, neg_z = inv_dir.z < 0.0;
    /* face f (lo x, y, z = 0, 1, 2; hi x, y, z = 3, 4, 5) starts at double 2 f */
    ray_setup r = {.origin = origin,
                   .inv_dir = inv_dir,
                   .near_x = 2 * (3 * neg_x),
                   .near_y = 2 * (1 + 3 * neg_y),
                   .near_z = 2 * (2 + 3 * neg_z),
                   .far_x = 2 * (3 - 3 * neg_x),
                   .far_y = 2 * (4 - 3 * neg_y),
                   .far_z = 2 * (5 - 3 * neg_z)};
#ifdef __SSE2__
    r.origin_x2 = _mm_set1_pd(origin.x);
    r.origin_y2 = _mm_set1_pd(origin.y);
    r.origin_z2 = _mm_set1_pd(origin.z);
    r.inv_dir_x2 = _mm_set1_pd(inv_dir.x);
    r.inv_dir_y2 = _mm_set1_pd(inv_dir.y);
    r.inv_dir_z2 = _mm_set1_pd(inv_dir.z);
#endif
    return r;
}

/* Slab test (Kay & Kajiya) against both child boxes of a node: entry[k] is
 * the distance where the ray enters box k, or INFINITY if it misses it or
 * enters beyond t_max.  No branch per axis (they would be mispredicted for
 * incoherent rays); the comparisons are written so that a NaN (0 * inf, a
 * ray lying in a slab plane) never shrinks the interval: `a > b ? a : b`
 * keeps b when a is NaN.  t_far is enlarged by a few ulps (Ize 2013,
 * "Robust BVH Ray Traversal") so rounding never culls a box whose primitive
 * the exact test would hit. */
#ifdef __SSE2__
/* Both boxes at once with SSE2 (every x86-64 processor has it): each
 * instruction below works on a pair of doubles, one per child, and
 * _mm_max_pd(a, b) / _mm_min_pd(a, b) are exactly `a > b ? a : b` /
 * `a < b ? a : b`, NaN behaviour included, so this computes what the plain C
 * version after #else computes, in about a third of the instructions. */
static inline void box_entries(const trace_node *node, const ray_setup *r, double t_max, double entry[2])
{
    const double *b = node->bounds;
    __m128d ox = r->origin_x2, oy = r->origin_y2, oz = r->origin_z2;
    __m128d ix = r->inv_dir_x2, iy = r->inv_dir_y2, iz = r->inv_dir_z2;
    __m128d near_x = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->near_x), ox), ix);
    __m128d far_x = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->far_x), ox), ix);
    __m128d near_y = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->near_y), oy), iy);
    __m128d far_y = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->far_y), oy), iy);
    __m128d near_z = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->near_z), oz), iz);
    __m128d far_z = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->far_z), oz), iz);
    __m128d t_near = _mm_max_pd(near_x, _mm_setzero_pd());
    t_near = _mm_max_pd(near_y, t_near);
    t_near = _mm_max_pd(near_z, t_near);
    __m128d t_far = _mm_min_pd(far_x, _mm_set1_pd(t_max));
    t_far = _mm_min_pd(far_y, t_far);
    t_far = _mm_min_pd(far_z, t_far);
    __m128d hit = _mm_cmple_pd(t_near, _mm_mul_pd(t_far, _mm_set1_pd(1.0 + 4.0 * DBL_EPSILON)));
    __m128d e = _mm_or_pd(_mm_and_pd(hit, t_near), _mm_andnot_pd(hit, _mm_set1_pd(INFINITY)));
    entry[0] = _mm_cvtsd_f64(e);
    entry[1] = _mm_cvtsd_f64(_mm_unpackhi_pd(e, e));
}
#else
static inline void box_entries(const trace_node *node, const ray_setup *r, double t_max, double entry[2])
{
    const double *b = node->bounds;
    for (int k = 0; k < 2; k++) {
        double near_x = (b[r->near_x + k] - r->origin.x) * r->inv_dir.x;
        double far_x = (b[r->far_x + k] - r->origin.x) * r->inv_dir.x;
        double near_y = (b[r->near_y + k] - r->origin.y) * r->inv_dir.y;
        double far_y = (b[r->far_y + k] - r->origin.y) * r->inv_dir.y;
        double near_z = (b[r->near_z + k] - r->origin.z) * r->inv_dir.z;
        double far_z = (b[r->far_z + k] - r->origin.z) * r->inv_dir.z;
        double t_near = near_x > 0.0 ? near_x : 0.0;
        t_near = near_y > t_near ? near_y : t_near;
        t_near = near_z > t_near ? near_z : t_near;
        double t_far = far_x < t_max ? far_x : t_max;
        t_far = far_y < t_far ? far_y : t_far;
        t_far = far_z < t_far ? far_z : t_far;
        entry[k] = t_near <= t_far * (1.0 + 4.0 * DBL_EPSILON) ? t_near : INFINITY;
    }
}
#endif

/* traverse() is copied into each of its two callers, with any_hit a
 * constant there: without the copy GCC calls one shared function, passes
 * the ray through memory and tests any_hit in the loop (10% slower). */
#if defined(__GNUC__)
#define ALWAYS_INLINE __attribute__((always_inline)) inline
#else
#define ALWAYS_INLINE inline
#endif

/* The one BVH traversal, iterative with an explicit stack.  any_hit: stop
 * at the first hit found (shadow rays need no nearest).  What is visited
 * next is a trace node (count == 0, index = trace node) or a leaf (count
 * primitives from leaf_primitive index). */
static ALWAYS_INLINE int traverse(const scene *s, vec3 origin, vec3 direction, double t_max, int any_hit, double *t_out,
                                  int *primitive_out)
{
    if (s->bvh.node_count == 0)
        return 0;
    const trace_node *nodes = s->bvh.trace_nodes;
    const leaf_primitive *prims = s->bvh.leaf_primitives;
    ray_setup r = setup_ray(origin, direction);
    int stack_index[BVH_STACK_SIZE], stack_count[BVH_STACK_SIZE];
    double stack_entry[BVH_STACK_SIZE]; /* where the ray enters that box */
    int top = 0;
    int found = -1;
    double nearest = t_max;
    int index = 0, count = 0;
    for (;;) {
        if (count > 0) {
            for (const leaf_primitive *p = prims + index, *end = p + count; p < end; p++) {
                double t = primitive_hit(p, origin, direction, nearest);
                if (t < nearest) {
                    nearest = t;
                    found = p->primitive;
                    if (any_hit)
                        goto done;
                }
            }
        } else {
            const trace_node *node = &nodes[index];
            double entry[2];
            box_entries(node, &r, nearest, entry);
            /* Visit the nearer child first; the farther one waits on the
             * stack.  A branch, not a select: the processor predicts it and
             * starts on the predicted child's boxes while this node's test
             * is still finishing; a select would make every node wait for
             * its parent's test (a chain through the whole traversal). */
            if (entry[1] < entry[0]) {
                /* entry[1] is finite here, and child 1 is nearer. */
                if (entry[0] != INFINITY) {
                    stack_index[top] = node->child[0];
                    stack_count[top] = node->count[0];
                    stack_entry[top++] = entry[0];
                }
                index = node->child[1];
                count = node->count[1];
                continue;
            }
            if (entry[0] != INFINITY) {
                if (entry[1] != INFINITY) {
                    stack_index[top] = node->child[1];
                    stack_count[top] = node->count[1];
                    stack_entry[top++] = entry[1];
                }
                index = node->child[0];
                count = node->count[0];
                continue;
            }
        }
        /* Pop, skipping boxes that start beyond the nearest hit found since. */
        for (;;) {
            if (top == 0)
                goto done;
            top--;
            if (stack_entry[top] < nearest)
                break;
        }
        index = stack_index[top];
        count = stack_count[top];
    }
done:
    if (found < 0)
        return 0;
    *t_out = nearest;
    *primitive_out = found;
    return 1;
}

int scene_intersect(const scene *s, ray r, double t_max, hit *out)
{
    double t;
    int primitive;
    if (!traverse(s, r.origin, r.direction, t_max, 0, &t, &primitive))
        return 0;
    fill_hit(s, r, t, primitive, out);
    return 1;
}

/* The same primitive test on the same records as traverse(), so the two
 * agree to the last bit; every primitive is tested, and of equally near ones
 * the lowest index wins, whatever the leaf order. */
int scene_intersect_brute_force(const scene *s, ray r, double t_max, hit *out)
{
    if (s->bvh.node_count == 0)
        return 0;
    const leaf_primitive *prims = s->bvh.leaf_primitives;
    double nearest = t_max;
    int found = -1;
    for (int i = 0; i < s->triangle_count + s->sphere_count; i++) {
        double t = primitive_hit(&prims[i], r.origin, r.direction, t_max);
        if (t < nearest || (t == nearest && found >= 0 && prims[i].primitive < found)) {
            nearest = t;
            found = prims[i].primitive;
        }
    }
    if (found < 0)
        return 0;
    fill_hit(s, r, nearest, found, out);
    return 1;
}

int scene_occluded(const scene *s, vec3 a, vec3 b)
{
    vec3 d = v3_sub(b, a);
    double distance = v3_length(d);
    if (!(distance > 2.0 * s->epsilon))
        return 0;
    /* Ray from a + epsilon toward b, ending epsilon short of b:
     * t = epsilon / distance .. 1 - epsilon / distance along d. */
    double step = s->epsilon / distance;
    vec3 origin = v3_madd(a, d, step);
    double t;
    int primitive;
    return traverse(s, origin, d, 1.0 - 2.0 * step, 1, &t, &primitive);
}
