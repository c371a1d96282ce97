/* bvh.c — the BVH and the ray queries (bvh.h says how it works).
 *
 * Reading order: boxes, the build (binned SAH over primitive references),
 * the collapse to an 8-wide tree, the primitive tests, the traversal, and the
 * public queries (scene_intersect, scene_intersect_brute_force,
 * scene_occluded).
 *
 * The build's speed (bench/bench_embree.c times it against Embree's): every
 * shortcut in it gives the tree the binned SAH gives, bit for bit (fill_bins,
 * sweep_bins, split_two and best_binned_split say why), so the traversal's
 * speed is the same as without them.
 */
#define _DEFAULT_SOURCE /* madvise's MADV_HUGEPAGE (Linux), for the build's large arrays */
#include "bvh.h"

#include "rng.h"
#include "sampling.h"

#include <float.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#ifdef __SSE__
#include <emmintrin.h> /* four-wide float SIMD for the box tests, two-wide double for sphere pairs */
#endif

/* SAH bins per axis (Wald 2007 uses 16 to 32), and the depth past which the
 * build splits in the middle of the list, so the tree depth (and the
 * traversal stack) stays bounded whatever the input.  The stack holds at
 * most BVH_WIDTH - 1 entries per level. */
enum { BVH_BINS = 32, BVH_SAH_MAX_DEPTH = 48, BVH_STACK_SIZE = (BVH_WIDTH - 1) * (BVH_SAH_MAX_DEPTH + 32) };
/* Subtrees of at least this many primitives are built as OpenMP tasks. */
enum { BVH_TASK_MIN = 4096 };

/* Triangles intersect with a margin of this fraction of scene.epsilon
 * around their edges (see triangle_transform): 1e-11 of the scene, five
 * orders of magnitude above the rounding it covers, and small enough that
 * ray origins moved off a surface by epsilon stay outside the triangle. */
static const double EDGE_MARGIN = 1e-2;

/* ------------------------------------------------------------------------ */
/* Boxes                                                                     */

static aabb aabb_empty(void) { return (aabb){v3_splat(INFINITY), v3_splat(-INFINITY)}; }
static aabb aabb_add_point(aabb b, vec3 p) { return (aabb){v3_min(b.lo, p), v3_max(b.hi, p)}; }
static aabb aabb_union(aabb a, aabb b) { return (aabb){v3_min(a.lo, b.lo), v3_max(a.hi, b.hi)}; }

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

/* Bounds of all primitives (triangles and spheres). */
aabb bvh_geometry_bounds(const scene *s)
{
    aabb bounds = aabb_empty();
    for (int i = 0; i < s->triangle_count + s->sphere_count; i++)
        bounds = aabb_union(bounds, primitive_bounds(s, i));
    return bounds;
}

/* ------------------------------------------------------------------------ */
/* The build: binned SAH over primitive references                          */

/* A box in single precision.  The tree's boxes are only a filter in front of
 * the double-precision primitive tests, so float is enough as long as no box
 * is ever smaller than what it bounds: every coordinate is rounded outward. */
typedef struct {
    float lo[3], hi[3];
} box3f;

static box3f box3f_empty(void) { return (box3f){{INFINITY, INFINITY, INFINITY}, {-INFINITY, -INFINITY, -INFINITY}}; }
static double box3f_half_area(const box3f *b)
{
    double dx = b->hi[0] - b->lo[0], dy = b->hi[1] - b->lo[1], dz = b->hi[2] - b->lo[2];
    return dx * dy + dy * dz + dz * dx;
}
/* step if condition, else 0, by a bit mask: no branch, and an infinite step
 * times 0 is not NaN. */
static inline float step_if(int condition, float step)
{
    uint32_t bits;
    memcpy(&bits, &step, sizeof bits);
    bits &= -(uint32_t)condition;
    memcpy(&step, &bits, sizeof step);
    return step;
}
/* x rounded to a float not above (below) it: when the nearest float is on
 * the wrong side, step at least one ulp (|f| 2^-23, plus FLT_MIN for the
 * floats near zero) further.  No branch: the comparison is a coin flip
 * (written as a select, GCC compiled it to a branch). */
static float round_down(double x)
{
    float f = (float)x, step = fabsf(f) * 0x1p-23f + FLT_MIN;
    return f - step_if((double)f > x, step);
}
static float round_up(double x)
{
    float f = (float)x, step = fabsf(f) * 0x1p-23f + FLT_MIN;
    return f + step_if((double)f < x, step);
}

/* What the build moves around: 32 bytes a primitive, so partitioning a
 * range reads and swaps contiguous memory (Wald 2007's "primitive
 * references"; Embree's PrimRef). */
typedef struct {
    float lo[3];
    int primitive;
    float hi[3];
    int unused;
} prim_ref;

/* The largest power of two not above |x| (1 for 0, subnormals, inf and
 * NaN): x's exponent bits alone.  Scaling by it is exact. */
static inline double power_of_two_below(double x)
{
    uint64_t bits;
    double power;
    memcpy(&bits, &x, sizeof bits);
    bits &= 0x7ff0000000000000u;
    memcpy(&power, &bits, sizeof power);
    return power >= DBL_MIN && power < INFINITY ? power : 1.0;
}

/* 1 / p for a power of two p from power_of_two_below, without a division
 * (exact either way): the exponent negated, unless 1 / p would be subnormal. */
static inline double reciprocal_power_of_two(double p)
{
    uint64_t bits;
    memcpy(&bits, &p, sizeof bits);
    uint64_t exponent = bits >> 52;
    if (exponent >= 2046)
        return 1.0 / p;
    bits = (2046 - exponent) << 52;
    double inverse;
    memcpy(&inverse, &bits, sizeof inverse);
    return inverse;
}

/* A primitive's box for the BVH in the tree's units (coordinates / unit,
 * exact), rounded outward to float.  Triangles intersect with a margin
 * around their edges (see triangle_transform), far below a float's
 * rounding, which therefore covers it. */
static prim_ref make_prim_ref(const scene *s, int primitive, double inv_unit)
{
    prim_ref r = {.primitive = primitive};
    if (primitive >= s->triangle_count) {
        aabb b = primitive_bounds(s, primitive);
        for (int a = 0; a < 3; a++) {
            r.lo[a] = round_down(v3_get(b.lo, a) * inv_unit);
            r.hi[a] = round_up(v3_get(b.hi, a) * inv_unit);
        }
        return r;
    }
    /* A triangle: primitive_bounds' box, with the comparisons inline (fmin
     * and fmax are calls, for their NaN rules; no coordinate is NaN). */
    const triangle *t = &s->triangles[primitive];
    double margin = EDGE_MARGIN * s->epsilon;
    for (int a = 0; a < 3; a++) {
        double p0 = v3_get(t->p0, a), p1 = p0 + v3_get(t->e1, a), p2 = p0 + v3_get(t->e2, a);
        double lo = p1 < p0 ? p1 : p0, hi = p1 > p0 ? p1 : p0;
        lo = p2 < lo ? p2 : lo;
        hi = p2 > hi ? p2 : hi;
        r.lo[a] = round_down((lo - margin) * inv_unit);
        r.hi[a] = round_up((hi + margin) * inv_unit);
    }
    return r;
}

/* The binary tree as built.  Node `index` over references [first, first +
 * count) owns node indices [index, index + 2 count - 1): its left child
 * (of `left` references, as build_subtree calls it) is index + 1, its right
 * child index + 2 left.  Known before the children are built, these indices let the
 * two subtrees be built at once, and make the tree the same for any number
 * of threads (unused indices are never read). */
typedef struct {
    box3f box;
    int first, count;
    int left, right; /* child node indices, -1 for a leaf */
} build_node;

typedef struct {
    prim_ref *refs;
    build_node *nodes;
    int *leaf_count; /* [first]: the count of the leaf over references first.., 0 where no leaf starts */
    int *pair_first; /* [first]: that leaf's first leaf_pair (number_leaf_pairs) */
} builder;

#ifdef __SSE2__
#include <emmintrin.h> /* four-wide float to int, for the bin indices */
#endif

/* Which of `bins` bins along an axis a reference falls into. */
static int bin_of(const prim_ref *r, int axis, float lo, float scale, int bins)
{
    int bin = (int)((r->lo[axis] + r->hi[axis] - lo) * scale);
    return bin < 0 ? 0 : bin >= bins ? bins - 1 : bin;
}

/* A box four floats a corner, the fourth unused, so SSE grows it in two
 * instructions: a bin's box, or the box of centroids. */
typedef struct {
    _Alignas(16) float lo[4];
    float hi[4];
} box4;

static box4 box4_empty(void)
{
    return (box4){{INFINITY, INFINITY, INFINITY, INFINITY}, {-INFINITY, -INFINITY, -INFINITY, -INFINITY}};
}

/* Grows b by the box lo, hi (four floats each, the fourth ignored). */
static inline void box4_grow(box4 *b, const float *lo, const float *hi)
{
#ifdef __SSE__
    _mm_store_ps(b->lo, _mm_min_ps(_mm_loadu_ps(lo), _mm_load_ps(b->lo)));
    _mm_store_ps(b->hi, _mm_max_ps(_mm_loadu_ps(hi), _mm_load_ps(b->hi)));
#else
    for (int a = 0; a < 3; a++) {
        b->lo[a] = lo[a] < b->lo[a] ? lo[a] : b->lo[a];
        b->hi[a] = hi[a] > b->hi[a] ? hi[a] : b->hi[a];
    }
#endif
}

/* Grows b by r's centroid times two (lo + hi, as bin_of reads it). */
static inline void box4_grow_centroid(box4 *b, const prim_ref *r)
{
#ifdef __SSE2__
    /* The fourth lanes hold the primitive index: masked off before adding
     * (an integer read as a float is a subnormal, slow in arithmetic). */
    const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
    __m128 c = _mm_add_ps(_mm_and_ps(_mm_load_ps(r->lo), xyz), _mm_and_ps(_mm_load_ps(r->hi), xyz));
    _mm_store_ps(b->lo, _mm_min_ps(c, _mm_load_ps(b->lo)));
    _mm_store_ps(b->hi, _mm_max_ps(c, _mm_load_ps(b->hi)));
#else
    float c[4] = {r->lo[0] + r->hi[0], r->lo[1] + r->hi[1], r->lo[2] + r->hi[2], 0.0f};
    box4_grow(b, c, c);
#endif
}

static box3f box3f_of(const box4 *b) { return (box3f){{b->lo[0], b->lo[1], b->lo[2]}, {b->hi[0], b->hi[1], b->hi[2]}}; }

/* A node's box and the box of its references' centroids (times two). */
typedef struct {
    box3f box, centroids;
} node_bounds;

/* The bounds of references [first, first + count). */
static node_bounds bounds_of_refs(const prim_ref *refs, int first, int count)
{
    box4 all = box4_empty(), centres = box4_empty();
    for (int i = first; i < first + count; i++) {
        box4_grow(&all, refs[i].lo, refs[i].hi);
        box4_grow_centroid(&centres, &refs[i]);
    }
    return (node_bounds){box3f_of(&all), box3f_of(&centres)};
}

/* Boxes and counts of the bins along the three axes. */
typedef struct {
    box4 box[3][BVH_BINS];
    int count[3][BVH_BINS];
} bin_set;

/* The bins of a node along the three axes: bin k of axis a takes the
 * references whose bin_of(a) is k.  `lo`, `scale` and `last` (bins - 1)
 * per axis, four wide for bin_all_axes. */
typedef struct {
    _Alignas(16) float lo[4];
    float scale[4], last[4];
    int bins;
    bin_set set;
} sah_bins;

/* The bins of reference r along all three axes at once: bin_of's
 * arithmetic four wide (lane 3 unused), clamped before the conversion. */
static inline void bin_all_axes(const sah_bins *g, const prim_ref *r, int k[4])
{
#ifdef __SSE2__
    const __m128 xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
    __m128 c = _mm_add_ps(_mm_and_ps(_mm_load_ps(r->lo), xyz), _mm_and_ps(_mm_load_ps(r->hi), xyz));
    __m128 x = _mm_mul_ps(_mm_sub_ps(c, _mm_load_ps(g->lo)), _mm_load_ps(g->scale));
    x = _mm_min_ps(_mm_max_ps(x, _mm_setzero_ps()), _mm_load_ps(g->last));
    _mm_storeu_si128((__m128i *)k, _mm_cvttps_epi32(x));
#else
    for (int a = 0; a < 3; a++)
        k[a] = bin_of(r, a, g->lo[a], g->scale[a], g->bins);
#endif
}

static void bin_set_clear(bin_set *set, int bins)
{
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < bins; k++) {
            set->box[a][k] = box4_empty();
            set->count[a][k] = 0;
        }
}

static inline void bin_set_add(bin_set *set, const sah_bins *g, const prim_ref *r)
{
    int k[4];
    bin_all_axes(g, r, k);
    for (int a = 0; a < 3; a++) {
        set->count[a][k[a]]++;
        box4_grow(&set->box[a][k[a]], r->lo, r->hi);
    }
}

/* Sets up and fills the bins of references [first, first + count), read
 * once.  A large node fills two sets of bins, the even and the odd
 * references, merged after (sums and min / max: the same bins): two
 * references in a row often fall into the same bin, and each would wait for
 * the other's update. */
static void fill_bins(sah_bins *g, const prim_ref *refs, int first, int count, const box3f *centroids)
{
    g->bins = count < BVH_BINS ? count : BVH_BINS;
    for (int a = 0; a < 3; a++) {
        float width = centroids->hi[a] - centroids->lo[a];
        g->lo[a] = centroids->lo[a];
        g->scale[a] = width > 0.0f ? (float)g->bins * (1.0f - 1e-6f) / width : 0.0f;
        g->last[a] = (float)(g->bins - 1);
    }
    g->lo[3] = g->scale[3] = g->last[3] = 0.0f;
    bin_set *even = &g->set;
    bin_set_clear(even, g->bins);
    int i = first, end = first + count;
    if (count >= 4 * BVH_BINS) {
        bin_set odd;
        bin_set_clear(&odd, g->bins);
        for (; i + 1 < end; i += 2) {
            bin_set_add(even, g, &refs[i]);
            bin_set_add(&odd, g, &refs[i + 1]);
        }
        for (int a = 0; a < 3; a++)
            for (int k = 0; k < g->bins; k++) {
                even->count[a][k] += odd.count[a][k];
                box4_grow(&even->box[a][k], odd.box[a][k].lo, odd.box[a][k].hi);
            }
    }
    for (; i < end; i++)
        bin_set_add(even, g, &refs[i]);
}

/* box3f_half_area's arithmetic, two doubles at a time where SSE2 has them. */
static inline double box4_half_area(const box4 *b)
{
#ifdef __SSE2__
    __m128 lo = _mm_load_ps(b->lo), hi = _mm_load_ps(b->hi);
    __m128d dxy = _mm_sub_pd(_mm_cvtps_pd(hi), _mm_cvtps_pd(lo));
    __m128d dz = _mm_sub_sd(_mm_cvtps_pd(_mm_movehl_ps(hi, hi)), _mm_cvtps_pd(_mm_movehl_ps(lo, lo)));
    __m128d products = _mm_mul_pd(dxy, _mm_shuffle_pd(dxy, dz, 1)); /* dx dy, dy dz */
    return _mm_cvtsd_f64(products) + _mm_cvtsd_f64(_mm_unpackhi_pd(products, products)) +
           _mm_cvtsd_f64(_mm_mul_sd(dz, dxy));
#else
    double dx = b->hi[0] - b->lo[0], dy = b->hi[1] - b->lo[1], dz = b->hi[2] - b->lo[2];
    return dx * dy + dy * dz + dz * dx;
#endif
}

typedef struct {
    int axis, bin; /* bins < bin go left; axis -1: no split */
    int bins;      /* of the node (see best_binned_split) */
    double cost;   /* area(left) n(left) + area(right) n(right) */
    float lo, scale;
} sah_split;

/* The surface area heuristic prices a subtree for a random ray: a node's box
 * is hit with probability area(box) / area(parent).  Splitting costs one
 * traversal step plus the expected primitive tests of both children; a leaf
 * costs its tests (MacDonald and Booth 1990), one a pair of primitives, as
 * leaves test two at a time (bvh.h: leaf_pair; Embree's builder prices its
 * leaves of four alike).  Priced so, leaves of two and four are as cheap as
 * leaves of one and three: the knobbly torus of 10^3 triangles (bench/)
 * has 110 wide nodes instead of 231, that of 10^5 13,841 instead of 18,831. */
static const double SAH_TRAVERSAL_COST = 1.0, SAH_PRIMITIVE_COST = 1.0;

/* The tests n primitives of a leaf take: one a pair (bvh.h: leaf_pair). */
static inline int pair_tests(int n) { return (n + 1) / 2; }

/* Along one axis whose bins are filled: the cheapest split, if cheaper than
 * `best`.  Only the bins holding references are swept: a split beside an
 * empty bin costs what the split on its other side costs, and of equal
 * costs the sweep keeps the first it meets, the highest bin, as it would. */
static void sweep_bins(const sah_bins *g, int axis, sah_split *best)
{
    double left_cost[BVH_BINS];
    int used[BVH_BINS], m = 0;
    for (int k = 0; k < g->bins; k++)
        if (g->set.count[axis][k] > 0)
            used[m++] = k;
    box4 box = box4_empty();
    int n = 0;
    for (int j = 0; j < m - 1; j++) {
        box4_grow(&box, g->set.box[axis][used[j]].lo, g->set.box[axis][used[j]].hi);
        n += g->set.count[axis][used[j]];
        left_cost[j] = box4_half_area(&box) * pair_tests(n);
    }
    box = box4_empty();
    n = 0;
    for (int j = m - 1; j > 0; j--) {
        box4_grow(&box, g->set.box[axis][used[j]].lo, g->set.box[axis][used[j]].hi);
        n += g->set.count[axis][used[j]];
        double cost = left_cost[j - 1] + box4_half_area(&box) * pair_tests(n);
        if (cost < best->cost)
            *best = (sah_split){.axis = axis,
                                .bin = used[j],
                                .bins = g->bins,
                                .cost = cost,
                                .lo = g->lo[axis],
                                .scale = g->scale[axis]};
    }
}

/* Bins references [first, first + count) along all three axes in one pass
 * (the references are read once) and returns the cheapest split, and in
 * boxes[0], boxes[1] the boxes of its two sides (the unions of their bins).
 * All three axes are tried: the longest one is not always the best (a
 * room's walls are as long in every direction).  A node of fewer references
 * than BVH_BINS gets as many bins as references: the bins' fixed cost
 * (clearing and sweeping them) would otherwise dominate the small nodes. */
static sah_split best_binned_split(const prim_ref *refs, int first, int count, const box3f *centroids, box3f boxes[2])
{
    sah_bins g;
    fill_bins(&g, refs, first, count, centroids);
    sah_split best = {.axis = -1, .cost = INFINITY};
    for (int a = 0; a < 3; a++)
        if (g.scale[a] > 0.0f) /* else all centroids lie in one plane across this axis */
            sweep_bins(&g, a, &best);
    if (best.axis < 0)
        return best;
    box4 side[2] = {box4_empty(), box4_empty()};
    for (int k = 0; k < g.bins; k++)
        box4_grow(&side[k >= best.bin], g.set.box[best.axis][k].lo, g.set.box[best.axis][k].hi);
    boxes[0] = box3f_of(&side[0]);
    boxes[1] = box3f_of(&side[1]);
    return best;
}

/* Moves the references of bins < split.bin to the front; returns how many,
 * and the centroid bounds of each side in centroids[0], centroids[1]. */
static int partition_refs(prim_ref *refs, int first, int count, sah_split split, box3f centroids[2])
{
    box4 side[2] = {box4_empty(), box4_empty()};
    int i = first, j = first + count - 1;
    while (i <= j) {
        if (bin_of(&refs[i], split.axis, split.lo, split.scale, split.bins) < split.bin) {
            box4_grow_centroid(&side[0], &refs[i++]);
        } else {
            box4_grow_centroid(&side[1], &refs[i]);
            prim_ref tmp = refs[i];
            refs[i] = refs[j];
            refs[j--] = tmp;
        }
    }
    centroids[0] = box3f_of(&side[0]);
    centroids[1] = box3f_of(&side[1]);
    return i - first;
}

/* choose_split of two references, in closed form (over two fifths of the
 * nodes at 10^5 triangles): of two bins, every axis where the centroids differ
 * puts the lower in bin 0, the other in bin 1, at the same cost (the sum of
 * their areas), so the sweep keeps the first such axis, and the partition
 * puts the lower first. */
static int split_two(prim_ref *refs, int first, const node_bounds *bounds, node_bounds child[2])
{
    const prim_ref *r = &refs[first];
    int axis = -1;
    for (int a = 2; a >= 0; a--)
        if (r[0].lo[a] + r[0].hi[a] != r[1].lo[a] + r[1].hi[a])
            axis = a;
    if (axis < 0)
        return 0;
    int swap = r[1].lo[axis] + r[1].hi[axis] < r[0].lo[axis] + r[0].hi[axis];
    child[swap] = bounds_of_refs(refs, first, 1);
    child[!swap] = bounds_of_refs(refs, first + 1, 1);
    double cost = box3f_half_area(&child[0].box) * 1 + box3f_half_area(&child[1].box) * 1;
    double split_cost = SAH_TRAVERSAL_COST + SAH_PRIMITIVE_COST * cost / box3f_half_area(&bounds->box);
    if (!(split_cost < SAH_PRIMITIVE_COST * pair_tests(2)))
        return 0;
    if (swap) {
        prim_ref tmp = refs[first];
        refs[first] = refs[first + 1];
        refs[first + 1] = tmp;
    }
    return 1;
}

/* Where to split references [first, first + count) of bounds *bounds: the
 * number that go left (0 < result < count) after reordering them, with the
 * bounds of both sides in child[0], child[1], or 0 when a leaf is cheaper
 * than any split (offered only if count <= BVH_LEAF_SIZE). */
static int choose_split(prim_ref *refs, int first, int count, const node_bounds *bounds, int depth,
                        node_bounds child[2])
{
    int left = count <= BVH_LEAF_SIZE ? 0 : count / 2; /* a pathological list: halve it */
    if (count == 2 && depth < BVH_SAH_MAX_DEPTH)
        return split_two(refs, first, bounds, child);
    if (depth < BVH_SAH_MAX_DEPTH) {
        box3f boxes[2], centroids[2];
        sah_split best = best_binned_split(refs, first, count, &bounds->centroids, boxes);
        if (best.axis >= 0) {
            /* Leaf or split?  Both in units of one primitive test per unit area. */
            double split_cost = SAH_TRAVERSAL_COST + SAH_PRIMITIVE_COST * best.cost / box3f_half_area(&bounds->box);
            if (count <= BVH_LEAF_SIZE && !(split_cost < SAH_PRIMITIVE_COST * pair_tests(count)))
                return 0;
            int cut = partition_refs(refs, first, count, best, centroids);
            if (cut > 0 && cut < count) {
                child[0] = (node_bounds){boxes[0], centroids[0]};
                child[1] = (node_bounds){boxes[1], centroids[1]};
                return cut;
            }
            left = count / 2;
        }
    }
    if (left > 0) {
        child[0] = bounds_of_refs(refs, first, left);
        child[1] = bounds_of_refs(refs, first + left, count - left);
    }
    return left;
}

/* Builds node `index` over references [first, first + count), of bounds
 * `bounds`, and its subtree. */
static void build_subtree(builder *b, int index, int first, int count, int depth, node_bounds bounds)
{
    build_node *node = &b->nodes[index];
    node->box = bounds.box;
    node->first = first;
    node->count = count;
    node->left = node->right = -1;
    node_bounds child[2];
    int left = count > 1 ? choose_split(b->refs, first, count, &bounds, depth, child) : 0;
    if (left == 0) {
        b->leaf_count[first] = count;
        return;
    }
    node->left = index + 1;
    node->right = index + 2 * left;
    if (left >= BVH_TASK_MIN) {
        node_bounds left_bounds = child[0];
#pragma omp task default(none) firstprivate(b, index, first, left, depth, left_bounds)
        build_subtree(b, index + 1, first, left, depth + 1, left_bounds);
    } else {
        build_subtree(b, index + 1, first, left, depth + 1, child[0]);
    }
    build_subtree(b, index + 2 * left, first + left, count - left, depth + 1, child[1]);
}

/* ------------------------------------------------------------------------ */
/* The 8-wide tree traversal reads                                           */

/* Child slot k of wide node `out` gets the box of build node `index`. */
static void set_child_box(wide_node *out, int k, const box3f *box)
{
    for (int a = 0; a < 3; a++) {
        out->bounds[a][k] = box->lo[a];
        out->bounds[3 + a][k] = box->hi[a];
    }
}

/* wide_node.child of a binary-tree leaf: its pairs (bvh.h). */
static int leaf_child(const build_node *leaf, const int *pair_first)
{
    return ~(pair_first[leaf->first] << 2 | ((leaf->count + 1) / 2 - 1));
}

/* Makes wide node *count from binary node `index` (an inner node) and,
 * recursively, its subtree; returns its index.  The node takes the two
 * children, then opens the inner child of largest surface area (the one a
 * ray most likely enters) in its place, until it has BVH_WIDTH children or
 * all are leaves (Wald et al. 2008). */
static int collapse(const build_node *nodes, const int *pair_first, int index, wide_node *wide, int *wide_count)
{
    int out = (*wide_count)++;
    int kids[BVH_WIDTH] = {nodes[index].left, nodes[index].right}, n = 2;
    while (n < BVH_WIDTH) {
        int open = -1;
        double largest = -1.0;
        for (int k = 0; k < n; k++)
            if (nodes[kids[k]].left >= 0 && box3f_half_area(&nodes[kids[k]].box) > largest) {
                largest = box3f_half_area(&nodes[kids[k]].box);
                open = k;
            }
        if (open < 0)
            break;
        int inner = kids[open];
        kids[open] = nodes[inner].left;
        kids[n++] = nodes[inner].right;
    }
    box3f empty = box3f_empty();
    for (int k = 0; k < BVH_WIDTH; k++) {
        set_child_box(&wide[out], k, k < n ? &nodes[kids[k]].box : &empty);
        wide[out].child[k] = 0;
        wide[out].unused[k] = 0;
    }
    for (int k = 0; k < n; k++) {
        const build_node *kid = &nodes[kids[k]];
        int child =
            kid->left < 0 ? leaf_child(kid, pair_first) : collapse(nodes, pair_first, kids[k], wide, wide_count);
        wide[out].child[k] = child;
    }
    return out;
}

/* A root that is a leaf becomes child 0 of a wide node of its own. */
static void root_leaf(const build_node *root, const int *pair_first, wide_node *wide)
{
    box3f empty = box3f_empty();
    for (int k = 0; k < BVH_WIDTH; k++) {
        set_child_box(wide, k, k == 0 ? &root->box : &empty);
        wide->child[k] = k == 0 ? leaf_child(root, pair_first) : 0;
        wide->unused[k] = 0;
    }
}

/* One primitive as a lane of a leaf_pair holds it (bvh.h): a triangle's
 * transform (see triangle_transform) or a sphere (row[0] = centre,
 * offset[0] = radius), made once and then copied into its lane. */
typedef struct {
    vec3 row[3];
    double offset[3];
    double u_min, v_min, uv_max;
    int primitive; /* -1: an empty lane */
    int is_sphere;
} leaf_primitive;

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

/* Lane k of *pair gets primitive *p.  A sphere's lane and an empty lane get
 * u_min NaN, which no triangle test passes. */
static void set_lane(leaf_pair *pair, int k, const leaf_primitive *p)
{
    for (int i = 0; i < 3; i++) {
        pair->row[i][0][k] = p->row[i].x;
        pair->row[i][1][k] = p->row[i].y;
        pair->row[i][2][k] = p->row[i].z;
        pair->offset[i][k] = p->offset[i];
    }
    pair->u_min[k] = p->is_sphere || p->primitive < 0 ? NAN : p->u_min;
    pair->v_min[k] = p->v_min;
    pair->uv_max[k] = p->uv_max;
    pair->primitive[k] = p->primitive;
    pair->sphere_lanes |= p->is_sphere << k;
}

/* The pairs of a leaf of `count` references: its primitives two by two, in
 * leaf order, the second lane of the last pair empty for an odd count. */
static void fill_leaf_pairs(const scene *s, const prim_ref *refs, int count, leaf_pair *pairs)
{
    const leaf_primitive empty = {.primitive = -1};
    for (int i = 0; i < count; i += 2) {
        leaf_pair *pair = &pairs[i / 2];
        *pair = (leaf_pair){.sphere_lanes = 0};
        leaf_primitive first = make_leaf_primitive(s, refs[i].primitive);
        leaf_primitive second = i + 1 < count ? make_leaf_primitive(s, refs[i + 1].primitive) : empty;
        set_lane(pair, 0, &first);
        set_lane(pair, 1, &second);
    }
}

/* count records of `size` bytes on a BVH_ALIGNMENT boundary (aligned_alloc
 * wants a multiple of the alignment); from 4 MB on, on 2 MB boundaries and
 * in huge pages where the system has them, as Embree's allocator does (at
 * 10^6 triangles the build's page faults and TLB misses took half its time). */
enum { HUGE_PAGE = 1 << 21, HUGE_ARRAY = 2 * HUGE_PAGE };
static void *aligned_array(size_t count, size_t size)
{
    size_t bytes = (count * size + BVH_ALIGNMENT - 1) / BVH_ALIGNMENT * BVH_ALIGNMENT;
    if (bytes < HUGE_ARRAY)
        return aligned_alloc(BVH_ALIGNMENT, bytes);
    bytes = (bytes + HUGE_PAGE - 1) / HUGE_PAGE * HUGE_PAGE;
    void *p = aligned_alloc(HUGE_PAGE, bytes);
#ifdef MADV_HUGEPAGE
    if (p)
        madvise(p, bytes, MADV_HUGEPAGE);
#endif
    return p;
}

/* References [first, first + count) made, and their bounds. */
static node_bounds make_refs(const scene *s, prim_ref *refs, int first, int count)
{
    double inv_unit = 1.0 / s->bvh.unit;
    box4 all = box4_empty(), centres = box4_empty();
    for (int i = first; i < first + count; i++) {
        refs[i] = make_prim_ref(s, i, inv_unit);
        box4_grow(&all, refs[i].lo, refs[i].hi);
        box4_grow_centroid(&centres, &refs[i]);
    }
    return (node_bounds){box3f_of(&all), box3f_of(&centres)};
}

static void box3f_merge(box3f *into, const box3f *other)
{
    for (int a = 0; a < 3; a++) {
        into->lo[a] = other->lo[a] < into->lo[a] ? other->lo[a] : into->lo[a];
        into->hi[a] = other->hi[a] > into->hi[a] ? other->hi[a] : into->hi[a];
    }
}

/* The binary tree over n primitives: b->nodes (2 n - 1 of them, indexed as
 * build_node says) and b->refs in leaf order.  The references are made in
 * chunks of BVH_TASK_MIN, their bounds merged in a fixed order (min and
 * max: exact in any order anyway). */
static int build_binary_tree(const scene *s, builder *b, int n)
{
    int chunks = (n + BVH_TASK_MIN - 1) / BVH_TASK_MIN;
    node_bounds *parts = malloc((size_t)chunks * sizeof *parts);
    if (parts == NULL)
        return -1;
#pragma omp parallel for schedule(static) default(none) shared(s, b, n, parts, chunks) if (n >= BVH_TASK_MIN)
    for (int c = 0; c < chunks; c++) {
        int first = c * BVH_TASK_MIN;
        parts[c] = make_refs(s, b->refs, first, n - first < BVH_TASK_MIN ? n - first : BVH_TASK_MIN);
    }
    node_bounds root = parts[0];
    for (int c = 1; c < chunks; c++) {
        box3f_merge(&root.box, &parts[c].box);
        box3f_merge(&root.centroids, &parts[c].centroids);
    }
    free(parts);
#pragma omp parallel if (n >= BVH_TASK_MIN) default(none) shared(b, n, root)
#pragma omp single
    build_subtree(b, 0, 0, n, 0, root);
    return 0;
}

/* The wide nodes from the binary tree (see collapse). */
static void collapse_tree(const builder *b, scene_bvh *bvh)
{
    bvh->node_count = 0;
    if (b->nodes[0].left < 0) {
        root_leaf(&b->nodes[0], b->pair_first, bvh->nodes);
        bvh->node_count = 1;
    } else {
        collapse(b->nodes, b->pair_first, 0, bvh->nodes, &bvh->node_count);
    }
}

/* Numbers each leaf's pairs in leaf order (b->pair_first); returns how many. */
static int number_leaf_pairs(const builder *b, int n)
{
    int pairs = 0;
    for (int i = 0; i < n; i++) {
        b->pair_first[i] = pairs;
        pairs += (b->leaf_count[i] + 1) / 2;
    }
    return pairs;
}

/* The arrays traversal reads, from the binary tree. */
static int build_wide_tree(scene *s, const builder *b, int n)
{
    scene_bvh *bvh = &s->bvh;
    /* A binary tree with n leaves has n - 1 inner nodes; a wide node takes
     * at least one of them. */
    bvh->nodes = aligned_array((size_t)(n > 1 ? n - 1 : 1), sizeof *bvh->nodes);
    bvh->primitive_order = malloc((size_t)n * sizeof *bvh->primitive_order);
    if (bvh->nodes == NULL || bvh->primitive_order == NULL)
        return -1;
    bvh->leaf_pair_count = number_leaf_pairs(b, n);
    bvh->leaf_pairs = aligned_array((size_t)bvh->leaf_pair_count, sizeof *bvh->leaf_pairs);
    if (bvh->leaf_pairs == NULL)
        return -1;
    const box3f *root = &b->nodes[0].box;
    for (int a = 0; a < 3; a++)
        bvh->largest_coordinate = fmax(bvh->largest_coordinate, fmax(fabs(root->lo[a]), fabs(root->hi[a])));
    collapse_tree(b, bvh);
#pragma omp parallel for schedule(static) default(none) shared(bvh, b, n) if (n >= BVH_TASK_MIN)
    for (int i = 0; i < n; i++)
        bvh->primitive_order[i] = b->refs[i].primitive;
#pragma omp parallel for schedule(static) default(none) shared(s, b, bvh, n) if (n >= BVH_TASK_MIN)
    for (int i = 0; i < n; i++)
        if (b->leaf_count[i] > 0)
            fill_leaf_pairs(s, b->refs + i, b->leaf_count[i], &bvh->leaf_pairs[b->pair_first[i]]);
    return 0;
}

static int linear_is_cheaper(const scene *s);

/* The spheres in pairs, in the order of their indices, for linear search
 * (bvh.h: sphere_pair): lane 0 holds spheres 0, 2, 4 ..., lane 1 spheres
 * 1, 3, 5 ..., so that along a lane a later sphere never has the lower
 * index, which nearest_sphere's tie rule relies on. */
static int make_sphere_pairs(scene *s)
{
    scene_bvh *bvh = &s->bvh;
    bvh->sphere_pair_count = (s->sphere_count + 1) / 2;
    if (bvh->sphere_pair_count == 0)
        return 0;
    bvh->sphere_pairs = malloc((size_t)bvh->sphere_pair_count * sizeof *bvh->sphere_pairs);
    if (bvh->sphere_pairs == NULL)
        return -1;
    for (int i = 0; i < 2 * bvh->sphere_pair_count; i++) {
        sphere_pair *pair = &bvh->sphere_pairs[i / 2];
        int k = i % 2;
        if (i == s->sphere_count) { /* the empty lane: radius NaN fails sphere_hit's disc >= 0 */
            pair->x[k] = pair->y[k] = pair->z[k] = 0.0;
            pair->radius[k] = NAN;
            pair->primitive[k] = -1;
            continue;
        }
        const surface *sphere = &s->surfaces[s->sphere_surfaces[i]];
        pair->x[k] = sphere->center.x, pair->y[k] = sphere->center.y, pair->z[k] = sphere->center.z;
        pair->radius[k] = sphere->radius;
        pair->primitive[k] = s->triangle_count + i;
    }
    return 0;
}

int bvh_build(scene *s)
{
    scene_bvh *bvh = &s->bvh;
    int n = s->triangle_count + s->sphere_count;
    memset(bvh, 0, sizeof *bvh);
    if (n == 0)
        return 0; /* nothing to intersect: traverse() sees node_count == 0 */
    /* The tree's unit: the scene's largest coordinate is 1 to 2 units, so
     * that a scene in light years or in nanometres fits a float's range. */
    vec3 largest = v3_max(v3_max(s->bounds.lo, v3_neg(s->bounds.lo)), v3_max(s->bounds.hi, v3_neg(s->bounds.hi)));
    bvh->unit = power_of_two_below(v3_max_component(largest));
    /* The temporaries from malloc below 4 MB (16-byte aligned, as the SSE
     * loads of a prim_ref want): between Embree's builds in the bench, the
     * bunny (3,678 triangles) took 3.9 ms with aligned_alloc here and 1.6 ms
     * with malloc, which reuses freed pages more often (a fresh page costs a
     * fault, about 10 us on the project's machine). */
    size_t ref_bytes = (size_t)n * sizeof(prim_ref), node_bytes = (size_t)(2 * n - 1) * sizeof(build_node);
    builder b = {.refs = ref_bytes < HUGE_ARRAY ? malloc(ref_bytes) : aligned_array((size_t)n, sizeof(prim_ref)),
                 .nodes = node_bytes < HUGE_ARRAY ? malloc(node_bytes)
                                                  : aligned_array((size_t)(2 * n - 1), sizeof(build_node)),
                 .leaf_count = calloc((size_t)n, sizeof(int)),
                 .pair_first = malloc((size_t)n * sizeof(int))};
    int status = -1;
    if (b.refs && b.nodes && b.leaf_count && b.pair_first) {
        status = build_binary_tree(s, &b, n);
        if (status == 0)
            status = build_wide_tree(s, &b, n);
    }
    free(b.refs);
    free(b.nodes);
    free(b.leaf_count);
    free(b.pair_first);
    bvh->primitive_count = status == 0 ? n : 0;
    if (status != 0)
        bvh->node_count = 0;
    else
        bvh->linear = linear_is_cheaper(s);
    if (status == 0 && make_sphere_pairs(s) != 0) { /* made for every scene, so that bvh.linear may be switched */
        bvh_free(bvh);
        return -1;
    }
    return status;
}

void bvh_free(scene_bvh *bvh)
{
    free(bvh->primitive_order);
    free(bvh->nodes);
    free(bvh->leaf_pairs);
    free(bvh->sphere_pairs);
    memset(bvh, 0, sizeof *bvh);
}

size_t bvh_memory_bytes(const scene_bvh *bvh)
{
    return (size_t)bvh->node_count * sizeof(wide_node) + (size_t)bvh->leaf_pair_count * sizeof(leaf_pair) +
           (size_t)bvh->primitive_count * sizeof *bvh->primitive_order +
           (size_t)bvh->sphere_pair_count * sizeof(sphere_pair);
}

/* ------------------------------------------------------------------------ */
/* Intersection                                                              */

/* The ray in the triangle's coordinates (see triangle_transform): w along
 * the ray is w_o + t w_d, zero at t = -w_o / w_d; the hit point there gives
 * u and v.  No branch: for incoherent rays each condition is a coin flip
 * (about half the planes are behind the ray or beyond the nearest hit, and
 * then u and v are), and a mispredicted branch costs more than computing
 * u and v for every triangle of a leaf.  A ray parallel to the plane has
 * w_d = 0 and t = +-inf or NaN, which fails the t conditions, so there is no
 * NaN out. */
static inline double triangle_hit(const leaf_primitive *p, vec3 origin, vec3 direction, double t_max)
{
    double w_o = v3_dot(p->row[2], origin) + p->offset[2];
    double w_d = v3_dot(p->row[2], direction);
    double t = -w_o / w_d;
    vec3 h = v3_madd(origin, direction, t);
    double u = v3_dot(p->row[0], h) + p->offset[0];
    double v = v3_dot(p->row[1], h) + p->offset[1];
    int hit = (t > 0.0) & (t < t_max) & (u >= p->u_min) & (v >= p->v_min) & (u + v <= p->uv_max);
    return hit ? t : INFINITY;
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
static inline double sphere_hit(vec3 center, double radius, vec3 origin, vec3 direction, double a, double inv_a)
{
    vec3 f = v3_sub(origin, center);
    double b = v3_dot(f, direction);
    double c = v3_dot(f, f) - radius * radius;
    vec3 l = v3_madd(f, direction, -b * inv_a); /* f minus its component along d */
    double disc = a * (radius * radius - v3_dot(l, l));
    if (!(disc >= 0.0))
        return INFINITY;
    double q = -(b + copysign(sqrt(disc), b));
    if (q == 0.0)
        return INFINITY; /* ray starts on the sphere and grazes it */
    /* The nearer root if it is ahead, else the farther one (selects, not
     * branches: which root is ahead is a coin flip for rays inside). */
    double t0 = c / q, t1 = q * inv_a;
    double near = t0 < t1 ? t0 : t1, far = t0 < t1 ? t1 : t0;
    return near > 0.0 ? near : far > 0.0 ? far : INFINITY;
}

double intersect_sphere(vec3 center, double radius, ray r)
{
    double a = v3_dot(r.direction, r.direction);
    return sphere_hit(center, radius, r.origin, r.direction, a, 1.0 / a);
}

/* Does hit (t, primitive) beat the nearest so far (nearest, found)?  Nearer,
 * or as near with a lower index (found -1: no hit yet), so that the brute
 * force and linear search give one hit whatever the order they test in.
 * An empty lane (t INFINITY) never beats: nearest is only infinite while
 * found is -1.  better_hit is this rule in SSE2 lanes. */
static inline int is_better_hit(double t, int primitive, double nearest, int found)
{
    return t < nearest || (t == nearest && found >= 0 && primitive < found);
}

/* Linear search's spheres, two by two (bvh.h: sphere_pair).  With SSE2
 * each lane does sphere_hit's operations in the same order, so each t is
 * the scalar one to the bit.  No branch: whether a sphere is hit, and
 * whether nearer than the nearest so far, are coin flips (with branches
 * the pairs took twice as long on smallpt's scene). */
#ifdef __SSE2__
static inline __m128d select_pd(__m128d mask, __m128d yes, __m128d no)
{
    return _mm_or_pd(_mm_and_pd(mask, yes), _mm_andnot_pd(mask, no));
}

/* sphere_hit on both spheres of a pair: t, or INFINITY where it misses. */
static inline __m128d sphere_pair_hits(const sphere_pair *p, vec3 origin, vec3 direction, double a, double inv_a)
{
    const __m128d sign = _mm_set1_pd(-0.0), zero = _mm_setzero_pd(), infinity = _mm_set1_pd(INFINITY);
    __m128d dx = _mm_set1_pd(direction.x), dy = _mm_set1_pd(direction.y), dz = _mm_set1_pd(direction.z);
    __m128d fx = _mm_sub_pd(_mm_set1_pd(origin.x), _mm_loadu_pd(p->x));
    __m128d fy = _mm_sub_pd(_mm_set1_pd(origin.y), _mm_loadu_pd(p->y));
    __m128d fz = _mm_sub_pd(_mm_set1_pd(origin.z), _mm_loadu_pd(p->z));
    __m128d radius = _mm_loadu_pd(p->radius), radius2 = _mm_mul_pd(radius, radius);
    __m128d b = _mm_add_pd(_mm_add_pd(_mm_mul_pd(fx, dx), _mm_mul_pd(fy, dy)), _mm_mul_pd(fz, dz));
    __m128d c = _mm_sub_pd(_mm_add_pd(_mm_add_pd(_mm_mul_pd(fx, fx), _mm_mul_pd(fy, fy)), _mm_mul_pd(fz, fz)), radius2);
    __m128d along = _mm_mul_pd(_mm_xor_pd(b, sign), _mm_set1_pd(inv_a)); /* -b / a */
    __m128d lx = _mm_add_pd(fx, _mm_mul_pd(dx, along)), ly = _mm_add_pd(fy, _mm_mul_pd(dy, along)),
            lz = _mm_add_pd(fz, _mm_mul_pd(dz, along));
    __m128d l2 = _mm_add_pd(_mm_add_pd(_mm_mul_pd(lx, lx), _mm_mul_pd(ly, ly)), _mm_mul_pd(lz, lz));
    __m128d disc = _mm_mul_pd(_mm_set1_pd(a), _mm_sub_pd(radius2, l2));
    __m128d root = _mm_sqrt_pd(_mm_max_pd(disc, zero)); /* lanes with disc < 0 are masked out below */
    __m128d q = _mm_xor_pd(_mm_add_pd(b, _mm_or_pd(root, _mm_and_pd(b, sign))), sign);
    __m128d t0 = _mm_div_pd(c, q), t1 = _mm_mul_pd(q, _mm_set1_pd(inv_a));
    __m128d near = _mm_min_pd(t0, t1), far = _mm_max_pd(t1, t0); /* t0 < t1 ? t0 : t1, and the other */
    __m128d t = select_pd(_mm_cmpgt_pd(near, zero), near, far);  /* far, if ahead: the test below */
    __m128d hit = _mm_and_pd(_mm_and_pd(_mm_cmpge_pd(disc, zero), _mm_cmpneq_pd(q, zero)), _mm_cmpgt_pd(t, zero));
    return select_pd(hit, t, infinity);
}

/* Lanes where hit (t, primitive) beats (best, best_primitive) by
 * scene_intersect_brute_force's rule: nearer, or as near with a lower index
 * (a best_primitive of -1 is no hit yet). */
static inline __m128d better_hit(__m128d t, __m128d primitive, __m128d best, __m128d best_primitive)
{
    __m128d tie = _mm_and_pd(_mm_cmpeq_pd(t, best), _mm_and_pd(_mm_cmpge_pd(best_primitive, _mm_setzero_pd()),
                                                               _mm_cmplt_pd(primitive, best_primitive)));
    return _mm_or_pd(_mm_cmplt_pd(t, best), tie);
}

/* The nearest sphere hit below *nearest (the triangles' nearest, or t_max),
 * kept lane by lane, then the better of the two lanes: no branch, as which
 * lane wins is a coin flip.  Within a lane a hit only replaces a strictly
 * farther one: the one it ties with has the lower index (a triangle's, or
 * an earlier sphere's of the lane: make_sphere_pairs), so the tie rule
 * holds with one comparison, and min is the nearer t. */
static void nearest_sphere(const scene_bvh *bvh, vec3 origin, vec3 direction, double *nearest, int *found)
{
    double a = v3_dot(direction, direction), inv_a = 1.0 / a;
    __m128d best = _mm_set1_pd(*nearest), best_primitive = _mm_set1_pd(*found);
    for (int i = 0; i < bvh->sphere_pair_count; i++) {
        __m128d t = sphere_pair_hits(&bvh->sphere_pairs[i], origin, direction, a, inv_a);
        __m128d primitive = _mm_loadu_pd(bvh->sphere_pairs[i].primitive);
        best_primitive = select_pd(_mm_cmplt_pd(t, best), primitive, best_primitive);
        best = _mm_min_pd(t, best); /* t < best ? t : best */
    }
    __m128d other = _mm_unpackhi_pd(best, best), other_primitive = _mm_unpackhi_pd(best_primitive, best_primitive);
    __m128d better = better_hit(other, other_primitive, best, best_primitive);
    *nearest = _mm_cvtsd_f64(select_pd(better, other, best));
    *found = (int)_mm_cvtsd_f64(select_pd(better, other_primitive, best_primitive));
}

/* Does a sphere block the ray before t_max? */
static int any_sphere_hit(const scene_bvh *bvh, vec3 origin, vec3 direction, double t_max)
{
    double a = v3_dot(direction, direction), inv_a = 1.0 / a;
    __m128d blocked = _mm_setzero_pd(), end = _mm_set1_pd(t_max);
    for (int i = 0; i < bvh->sphere_pair_count; i++)
        blocked =
            _mm_or_pd(blocked, _mm_cmplt_pd(sphere_pair_hits(&bvh->sphere_pairs[i], origin, direction, a, inv_a), end));
    return _mm_movemask_pd(blocked) != 0;
}
#else
static double pair_lane_hit(const sphere_pair *p, int k, vec3 origin, vec3 direction, double a, double inv_a)
{
    return sphere_hit(v3(p->x[k], p->y[k], p->z[k]), p->radius[k], origin, direction, a, inv_a);
}

static void nearest_sphere(const scene_bvh *bvh, vec3 origin, vec3 direction, double *nearest, int *found)
{
    double a = v3_dot(direction, direction), inv_a = 1.0 / a;
    for (int i = 0; i < 2 * bvh->sphere_pair_count; i++) {
        const sphere_pair *p = &bvh->sphere_pairs[i / 2];
        double t = pair_lane_hit(p, i % 2, origin, direction, a, inv_a);
        int primitive = (int)p->primitive[i % 2];
        if (is_better_hit(t, primitive, *nearest, *found))
            *nearest = t, *found = primitive;
    }
}

static int any_sphere_hit(const scene_bvh *bvh, vec3 origin, vec3 direction, double t_max)
{
    double a = v3_dot(direction, direction), inv_a = 1.0 / a;
    for (int i = 0; i < 2 * bvh->sphere_pair_count; i++)
        if (pair_lane_hit(&bvh->sphere_pairs[i / 2], i % 2, origin, direction, a, inv_a) < t_max)
            return 1;
    return 0;
}
#endif

/* The ray as the pair tests read it: each coordinate in both lanes. */
typedef struct {
    vec3 origin, direction;
#ifdef __SSE2__
    __m128d o[3], d[3];
#endif
} pair_ray;

static inline pair_ray make_pair_ray(vec3 origin, vec3 direction)
{
    pair_ray r = {.origin = origin, .direction = direction};
#ifdef __SSE2__
    r.o[0] = _mm_set1_pd(origin.x), r.o[1] = _mm_set1_pd(origin.y), r.o[2] = _mm_set1_pd(origin.z);
    r.d[0] = _mm_set1_pd(direction.x), r.d[1] = _mm_set1_pd(direction.y), r.d[2] = _mm_set1_pd(direction.z);
#endif
    return r;
}

/* triangle_hit on both lanes of a pair: t[k], or INFINITY where lane k
 * misses (as a sphere's or an empty lane always does: its u_min is NaN).
 * With SSE2 each lane does triangle_hit's operations in the same order, so
 * each t is triangle_hit's to the bit. */
#ifdef __SSE2__
static inline __m128d dot_pair(const double (*row)[2], const __m128d v[3])
{
    return _mm_add_pd(_mm_add_pd(_mm_mul_pd(_mm_load_pd(row[0]), v[0]), _mm_mul_pd(_mm_load_pd(row[1]), v[1])),
                      _mm_mul_pd(_mm_load_pd(row[2]), v[2]));
}

static inline __m128d triangle_pair_hits_sse(const leaf_pair *p, const pair_ray *r, double t_max)
{
    __m128d w_o = _mm_add_pd(dot_pair(p->row[2], r->o), _mm_load_pd(p->offset[2]));
    __m128d w_d = dot_pair(p->row[2], r->d);
    __m128d t = _mm_div_pd(_mm_xor_pd(w_o, _mm_set1_pd(-0.0)), w_d);
    __m128d h[3];
    for (int a = 0; a < 3; a++)
        h[a] = _mm_add_pd(r->o[a], _mm_mul_pd(r->d[a], t));
    __m128d u = _mm_add_pd(dot_pair(p->row[0], h), _mm_load_pd(p->offset[0]));
    __m128d v = _mm_add_pd(dot_pair(p->row[1], h), _mm_load_pd(p->offset[1]));
    __m128d hit = _mm_and_pd(_mm_cmpgt_pd(t, _mm_setzero_pd()), _mm_cmplt_pd(t, _mm_set1_pd(t_max)));
    hit = _mm_and_pd(hit, _mm_and_pd(_mm_cmpge_pd(u, _mm_load_pd(p->u_min)), _mm_cmpge_pd(v, _mm_load_pd(p->v_min))));
    hit = _mm_and_pd(hit, _mm_cmple_pd(_mm_add_pd(u, v), _mm_load_pd(p->uv_max)));
    return select_pd(hit, t, _mm_set1_pd(INFINITY));
}

static inline void triangle_pair_hits(const leaf_pair *p, const pair_ray *r, double t_max, double t_out[2])
{
    _mm_storeu_pd(t_out, triangle_pair_hits_sse(p, r, t_max));
}
#else
static inline void triangle_pair_hits(const leaf_pair *p, const pair_ray *r, double t_max, double t_out[2])
{
    for (int k = 0; k < 2; k++) {
        leaf_primitive lane = {.u_min = p->u_min[k], .v_min = p->v_min[k], .uv_max = p->uv_max[k]};
        for (int i = 0; i < 3; i++) {
            lane.row[i] = v3(p->row[i][0][k], p->row[i][1][k], p->row[i][2][k]);
            lane.offset[i] = p->offset[i][k];
        }
        t_out[k] = triangle_hit(&lane, r->origin, r->direction, t_max);
    }
}
#endif

/* Both lanes of a leaf pair, triangles and spheres: t[k] if below t_max,
 * else INFINITY.  a = direction . direction and its inverse, once per ray
 * for the spheres. */
static inline void leaf_pair_hits(const leaf_pair *p, const pair_ray *r, double a, double inv_a, double t_max,
                                  double t[2])
{
    triangle_pair_hits(p, r, t_max, t);
    if (p->sphere_lanes) /* no branch missed in a scene of triangles only */
        for (int k = 0; k < 2; k++)
            if (p->sphere_lanes >> k & 1) {
                vec3 center = v3(p->row[0][0][k], p->row[0][1][k], p->row[0][2][k]);
                double hit = sphere_hit(center, p->offset[0][k], r->origin, r->direction, a, inv_a);
                t[k] = hit < t_max ? hit : INFINITY;
            }
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

/* The nearer of a leaf pair's two hits (leaf_pair_hits), and its lane: of
 * equal t, lane 0, the first in leaf order, as testing one at a time. */
static inline double nearer_lane(const leaf_pair *p, const pair_ray *r, double a, double inv_a, double t_max, int *lane)
{
#ifdef __SSE2__
    if (!p->sphere_lanes) {
        __m128d t = triangle_pair_hits_sse(p, r, t_max), other = _mm_unpackhi_pd(t, t);
        *lane = _mm_comilt_sd(other, t);
        return _mm_cvtsd_f64(_mm_min_sd(other, t));
    }
#endif
    double t[2];
    leaf_pair_hits(p, r, a, inv_a, t_max, t);
    *lane = t[1] < t[0];
    return t[*lane];
}

/* What the box test needs of a ray, worked out once per ray.
 *
 * The boxes are tested in single precision, which rounds: the ray's origin
 * and direction, b - o and (b - o) / d are each off by up to half a float
 * ulp, about 6e-8 of the coordinates involved.  A box whose primitive the
 * double-precision test would hit must never be culled by that rounding.
 * So every box is tested as if it were larger by a margin m far above it:
 * m = 2^-18 (largest |origin coordinate| + largest |scene coordinate|),
 * 64 float ulps of anything the ray can reach inside the scene (Ize 2013
 * bounds the same errors).  Growing the box's near face by m moves it to
 * where the origin would be m further along the axis, so the margin costs
 * nothing per node: the near faces are measured from origin + m sign(d),
 * the far faces from origin - m sign(d) (near_origin, far_origin).  A box
 * is then entered a little too early or left a little too late, which only
 * costs a primitive test now and then.
 *
 * near_face[a] and far_face[a] are the rows of wide_node.bounds the ray
 * meets first and leaves by along axis a (lo if d_a > 0, hi if not). */
typedef struct {
    float near_origin[3], far_origin[3], inv_dir[3];
    int near_face[3], far_face[3];
    double t_scale; /* t along the scaled ray = t_scale * t along the ray */
#ifdef __SSE__
    __m128 near_origin4[3], far_origin4[3], inv_dir4[3]; /* the same in all four lanes, for box_hits */
#endif
} wide_ray;

/* traverse() is copied into each of its two callers, with any_hit a
 * constant there: without the copy GCC calls one shared function, passes
 * the ray through memory and tests any_hit in the loop (10% slower). */
#if defined(__GNUC__)
#define ALWAYS_INLINE __attribute__((always_inline)) inline
#else
#define ALWAYS_INLINE inline
#endif

static ALWAYS_INLINE wide_ray setup_wide_ray(const scene *s, vec3 origin, vec3 direction)
{
    /* In the tree's units, and the direction scaled by a power of two to
     * about 1, so t (then also scaled: t_scale) stays in a float's range. */
    double dx = fabs(direction.x), dy = fabs(direction.y), dz = fabs(direction.z);
    /* The largest component by two selects, which compile to max instructions; nested, they compiled to a
     * branch, a coin flip for diffuse bounces (bench_embree: 20 % more rays a second that miss the scene's box). */
    double largest_direction = dx > dy ? dx : dy;
    largest_direction = largest_direction > dz ? largest_direction : dz;
    double direction_unit = power_of_two_below(largest_direction);
    double inv_unit = reciprocal_power_of_two(s->bvh.unit),
           inv_direction_unit = reciprocal_power_of_two(direction_unit);
    double o[3] = {origin.x * inv_unit, origin.y * inv_unit, origin.z * inv_unit};
    double d[3] = {direction.x * inv_direction_unit, direction.y * inv_direction_unit,
                   direction.z * inv_direction_unit};
    double largest = s->bvh.largest_coordinate;
    for (int a = 0; a < 3; a++)
        largest = fabs(o[a]) > largest ? fabs(o[a]) : largest;
    double margin = 0x1p-18 * largest;
    wide_ray r = {.t_scale = direction_unit * inv_unit};
    for (int a = 0; a < 3; a++) {
        double inv = 1.0 / d[a];          /* 1/0 = inf is what the slab test wants for an axis-parallel ray */
        int negative = signbit(inv) != 0; /* arithmetic, not branches: the signs are coin flips */
        r.inv_dir[a] = (float)inv;
        r.near_origin[a] = (float)(o[a] + copysign(margin, inv));
        r.far_origin[a] = (float)(o[a] - copysign(margin, inv));
        r.near_face[a] = a + 3 * negative;
        r.far_face[a] = a + 3 - 3 * negative;
#ifdef __SSE__
        r.near_origin4[a] = _mm_set1_ps(r.near_origin[a]);
        r.far_origin4[a] = _mm_set1_ps(r.far_origin[a]);
        r.inv_dir4[a] = _mm_set1_ps(r.inv_dir[a]);
#endif
    }
    return r;
}

/* Slab test (Kay & Kajiya) against the eight child boxes of a node: bit k of
 * the result is set when the ray enters box k before t_max (and leaves it
 * after 0), entry[k] is where it enters.  The comparisons are written so
 * that a NaN (0 * inf: a ray lying in a slab plane) never shrinks the
 * interval: max(x, acc) and min(x, acc) keep acc when x is NaN, which is
 * what SSE's maxps and minps do with the NaN first. */
#ifdef __SSE__
static inline int box_hits(const wide_node *node, const wide_ray *r, float t_max, float entry[BVH_WIDTH])
{
    int mask = 0;
    for (int half = 0; half < BVH_WIDTH; half += 4) {
        __m128 t_near = _mm_setzero_ps(), t_far = _mm_set1_ps(t_max);
        for (int a = 0; a < 3; a++) {
            __m128 near = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(node->bounds[r->near_face[a]] + half), r->near_origin4[a]),
                                     r->inv_dir4[a]);
            __m128 far = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(node->bounds[r->far_face[a]] + half), r->far_origin4[a]),
                                    r->inv_dir4[a]);
            t_near = _mm_max_ps(near, t_near);
            t_far = _mm_min_ps(far, t_far);
        }
        _mm_storeu_ps(entry + half, t_near);
        mask |= _mm_movemask_ps(_mm_cmple_ps(t_near, t_far)) << half;
    }
    return mask;
}
#else
static inline int box_hits(const wide_node *node, const wide_ray *r, float t_max, float entry[BVH_WIDTH])
{
    int mask = 0;
    for (int k = 0; k < BVH_WIDTH; k++) {
        float t_near = 0.0f, t_far = t_max;
        for (int a = 0; a < 3; a++) {
            float near = (node->bounds[r->near_face[a]][k] - r->near_origin[a]) * r->inv_dir[a];
            float far = (node->bounds[r->far_face[a]][k] - r->far_origin[a]) * r->inv_dir[a];
            t_near = near > t_near ? near : t_near;
            t_far = far < t_far ? far : t_far;
        }
        entry[k] = t_near;
        mask |= (t_near <= t_far) << k;
    }
    return mask;
}
#endif

/* The traversal stack: wide-tree children waiting, and where the ray
 * enters each (to skip those that start beyond a hit found since). */
typedef struct {
    int child[BVH_STACK_SIZE];
    float entry[BVH_STACK_SIZE];
    int top;
} wide_stack;

/* The children of a node that the ray enters (mask), in the order to
 * visit them: returns the one to visit now and pushes the others, the
 * nearest last so that it is popped first.  Shadow rays (any_hit) need
 * no order: any hit ends them. */
static ALWAYS_INLINE int visit_children(const wide_node *node, int mask, const float entry[BVH_WIDTH], int any_hit,
                                        wide_stack *stack)
{
    int nearest = __builtin_ctz((unsigned)mask);
    mask &= mask - 1;
    if (mask == 0) /* one child: the common case deep in the tree */
        return node->child[nearest];
    int other = __builtin_ctz((unsigned)mask);
    mask &= mask - 1;
    if (mask == 0) { /* two: no sort, one comparison */
        if (!any_hit && entry[other] < entry[nearest]) {
            int tmp = other;
            other = nearest;
            nearest = tmp;
        }
        stack->child[stack->top] = node->child[other];
        stack->entry[stack->top++] = entry[other];
        return node->child[nearest];
    }
    int hit[BVH_WIDTH] = {nearest, other}, n = 2;
    for (; mask; mask &= mask - 1)
        hit[n++] = __builtin_ctz((unsigned)mask);
    if (!any_hit) /* insertion sort of three or more, farthest first */
        for (int i = 1; i < n; i++)
            for (int j = i; j > 0 && entry[hit[j]] > entry[hit[j - 1]]; j--) {
                int tmp = hit[j];
                hit[j] = hit[j - 1];
                hit[j - 1] = tmp;
            }
    for (int i = 0; i < n - 1; i++) {
        stack->child[stack->top] = node->child[hit[i]];
        stack->entry[stack->top++] = entry[hit[i]];
    }
    return node->child[hit[n - 1]];
}

/* The pairs of leaf `leaf` (a negative wide_node.child) against the ray:
 * the nearest hit below *nearest, into *nearest and *found; returns 1 if
 * there is one.  any_hit: the first hit is enough. */
static ALWAYS_INLINE int leaf_nearest(const scene *s, int leaf, vec3 origin, vec3 direction, double a, double inv_a,
                                      int any_hit, double *nearest, int *found)
{
    pair_ray r = make_pair_ray(origin, direction); /* here, not per ray: a miss ray would pay for it */
    const leaf_pair *p = s->bvh.leaf_pairs + bvh_leaf_first(leaf), *end = p + bvh_leaf_count(leaf);
    int hit = 0;
    for (; p < end; p++) {
        int lane;
        double t = nearer_lane(p, &r, a, inv_a, *nearest, &lane);
        if (t < *nearest) {
            *nearest = t;
            *found = p->primitive[lane];
            /* fill_hit will read the triangle (its normal, surface): fetch it while the
             * traversal goes on (on 10^6 triangles it was a cache miss, 7% of the time). */
            if (!any_hit && *found < s->triangle_count)
                __builtin_prefetch(&s->triangles[*found]);
            hit = 1;
            if (any_hit)
                break;
        }
    }
    return hit;
}

/* The one BVH traversal, iterative with an explicit stack.  any_hit: stop
 * at the first hit found (shadow rays need no nearest).  `child` is what is
 * visited next: a wide node (>= 0) or a leaf (< 0).  The boxes are compared
 * with nearest_bound, the nearest hit's t rounded up to a float.  A shadow
 * ray (any_hit) tests its primitives from origin + step direction to t_max -
 * 2 step, and its boxes along the whole of origin + t direction, t from 0 to
 * t_max (a longer segment: only a box more now and then), so that its set-up
 * need not wait for the square root and division that give step
 * (scene_occluded: 3 % more shadow rays a second on the Cornell box and a
 * 10^4-triangle torus, interleaved runs).  Closest hits have step 0. */
static ALWAYS_INLINE int traverse(const scene *s, vec3 origin, vec3 direction, double t_max, int any_hit, double step,
                                  double *t_out, int *primitive_out, int *tests)
{
    if (s->bvh.node_count == 0)
        return 0;
    const wide_node *nodes = s->bvh.nodes;
    wide_ray r = setup_wide_ray(s, origin, direction);
    float nearest_bound = round_up(t_max * r.t_scale);
    if (any_hit) { /* the primitives' segment, within the boxes' */
        origin = v3_madd(origin, direction, step);
        t_max -= 2.0 * step;
    }
    double a = v3_dot(direction, direction), inv_a = 1.0 / a;
    wide_stack stack;
    stack.top = 0;
    int found = -1, child = 0;
    double nearest = t_max;
    for (;;) {
        if (child >= 0) {
            float entry[BVH_WIDTH];
            if (tests) /* NULL but in linear_is_cheaper: the compiler drops these */
                ++*tests;
            int mask = box_hits(&nodes[child], &r, nearest_bound, entry);
            if (mask) {
                child = visit_children(&nodes[child], mask, entry, any_hit, &stack);
                continue;
            }
        } else {
            if (tests) /* a leaf's visit, as much as a test (popped, sorted before), and one a pair */
                *tests += 1 + bvh_leaf_count(child);
            if (leaf_nearest(s, child, origin, direction, a, inv_a, any_hit, &nearest, &found)) {
                if (any_hit)
                    goto done;
                nearest_bound = round_up(nearest * r.t_scale);
            }
        }
        /* Pop, skipping boxes that start beyond the nearest hit found since. */
        do {
            if (stack.top == 0)
                goto done;
            stack.top--;
        } while (stack.entry[stack.top] > nearest_bound);
        child = stack.child[stack.top];
    }
done:
    if (found < 0)
        return 0;
    *t_out = nearest;
    *primitive_out = found;
    return 1;
}

static int linear_intersect(const scene *s, ray r, double t_max, hit *out);

int scene_intersect(const scene *s, ray r, double t_max, hit *out)
{
    if (s->bvh.linear)
        return linear_intersect(s, r, t_max, out);
    double t;
    int primitive;
    if (!traverse(s, r.origin, r.direction, t_max, 0, 0.0, &t, &primitive, NULL))
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
    double a = v3_dot(r.direction, r.direction), inv_a = 1.0 / a;
    pair_ray pr = make_pair_ray(r.origin, r.direction);
    double nearest = t_max;
    int found = -1;
    for (int i = 0; i < s->bvh.leaf_pair_count; i++) {
        const leaf_pair *p = &s->bvh.leaf_pairs[i];
        double t[2];
        leaf_pair_hits(p, &pr, a, inv_a, t_max, t);
        for (int k = 0; k < 2; k++)
            if (is_better_hit(t[k], p->primitive[k], nearest, found)) {
                nearest = t[k];
                found = p->primitive[k];
            }
    }
    if (found < 0)
        return 0;
    fill_hit(s, r, nearest, found, out);
    return 1;
}

/* Is testing every primitive cheaper than the tree, for rays that start
 * where rays start: on the primitives?  Measured by the tree itself on up
 * to 64 such rays (from primitives spread over the list, directions uniform
 * from a fixed seed): the nodes, leaves and leaf pairs they test on
 * average, plus one for the ray's set-up (setup_wide_ray), against linear
 * search's tests: one per leaf pair (the triangles two at a time) and one
 * per pair of spheres.  A node test, a leaf's visit (pop, sort), a pair of
 * triangles and a pair of spheres cost about alike (measured: on smallpt's
 * scene the tree's 9.8 tests took 220 ns a ray, the five sphere pairs
 * 98 ns).  smallpt's scene (nine spheres, six of them walls whose boxes
 * hold the whole room): 7.8 with the tree against 5.  The Cornell box (32
 * triangles in 16 pairs): 6.3 against 16, and 2.2x faster with the tree; 6
 * triangles (scenes/crease.scene): 4.5 against 3.  The choice changes no
 * result: both give scene_intersect_brute_force's hit to the bit.
 *
 * The rays cost: 256 of them took 40 us, 3.5x what the Cornell box's whole
 * build takes Embree (bench_embree --builds-only).  So they stop after 16
 * once the mean is under 2/3 or over 3/2 of linear search's (the Cornell
 * box: 6.3 against 16; smallpt's: 7.8 against 5), and only a near tie
 * takes all 64.  The k-th ray starts on primitive frac(k phi) n (phi the
 * golden ratio), so that the first 16 already spread over the whole list. */
enum { LINEAR_RAYS = 64, LINEAR_RAYS_CLEAR = 16 };
static int triangle_pass_length(const scene *s);
static int linear_is_cheaper(const scene *s)
{
    const int64_t n = s->bvh.primitive_count; /* 64-bit: the products below would overflow an int */
    const int64_t linear_tests = triangle_pass_length(s) + (s->sphere_count + 1) / 2;
    int tests = 0, rays = 0;
    while (rays < LINEAR_RAYS) {
        rng g = rng_for(0x6c696e656172ull, (uint64_t)rays, 0);
        vec3 d = uniform_sample_sphere(rng_uniform(&g), rng_uniform(&g)), point, normal;
        uint64_t spread = ((uint64_t)rays * 0x9e3779b97f4a7c15ull) >> 32; /* frac(rays phi) in 32 bits */
        int primitive = (int)((spread * (uint64_t)n) >> 32);
        if (primitive < s->triangle_count) {
            const triangle *t = &s->triangles[primitive];
            point = v3_madd(t->p0, v3_add(t->e1, t->e2), 1.0 / 3.0);
            normal = t->normal;
        } else {
            const surface *sphere = &s->surfaces[s->sphere_surfaces[primitive - s->triangle_count]];
            normal = uniform_sample_sphere(rng_uniform(&g), rng_uniform(&g));
            point = v3_madd(sphere->center, normal, sphere->radius);
        }
        double t;
        int found;
        tests++; /* the set-up */
        traverse(s, scene_offset_origin(s, point, normal, d), d, INFINITY, 0, 0.0, &t, &found, &tests);
        rays++;
        if (rays >= LINEAR_RAYS_CLEAR && (2 * tests > 3 * linear_tests * rays || 3 * tests < 2 * linear_tests * rays))
            break;
    }
    return linear_tests * rays <= tests;
}

/* How many leaf pairs linear search reads for its triangles (the spheres
 * it skips there are in sphere_pairs): none when there are no triangles
 * (smallpt's scene), all of them otherwise. */
static int triangle_pass_length(const scene *s) { return s->triangle_count > 0 ? s->bvh.leaf_pair_count : 0; }

/* A linear scene (bvh.linear): every triangle tested, then the spheres two
 * by two; the same hit as scene_intersect_brute_force, to the bit. */
static int linear_intersect(const scene *s, ray r, double t_max, hit *out)
{
    const scene_bvh *bvh = &s->bvh;
    pair_ray pr = make_pair_ray(r.origin, r.direction);
    double nearest = t_max;
    int found = -1;
    for (int i = 0, n = triangle_pass_length(s); i < n; i++) {
        const leaf_pair *p = &bvh->leaf_pairs[i];
        double t[2];
        triangle_pair_hits(p, &pr, t_max, t);
        for (int k = 0; k < 2; k++)
            if (is_better_hit(t[k], p->primitive[k], nearest, found))
                nearest = t[k], found = p->primitive[k];
    }
    nearest_sphere(bvh, r.origin, r.direction, &nearest, &found);
    if (found < 0)
        return 0;
    fill_hit(s, r, nearest, found, out);
    return 1;
}

/* Does the ray hit any primitive before t_max?  Every one tested (bvh.linear). */
static int any_primitive_hit(const scene *s, vec3 origin, vec3 direction, double t_max)
{
    const scene_bvh *bvh = &s->bvh;
    pair_ray pr = make_pair_ray(origin, direction);
    for (int i = 0, n = triangle_pass_length(s); i < n; i++) {
        double t[2];
        triangle_pair_hits(&bvh->leaf_pairs[i], &pr, t_max, t);
        if (t[0] < t_max || t[1] < t_max)
            return 1;
    }
    return any_sphere_hit(bvh, origin, direction, t_max);
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
    double t;
    int primitive;
    if (s->bvh.linear)
        return any_primitive_hit(s, v3_madd(a, d, step), d, 1.0 - 2.0 * step);
    return traverse(s, a, d, 1.0, 1, step, &t, &primitive, NULL);
}
