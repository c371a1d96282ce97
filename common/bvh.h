/* bvh.h — private to common/: the BVH's build and the layout traversal reads.
 *
 * The chapters use scene.h only; scene.c calls bvh_build() at load and
 * bvh_free() at scene_free(), and takes the bounds of the geometry from here.
 *
 * How it works (bvh.c has the details and the references):
 *   - Build: a binary tree by the binned surface area heuristic (Wald 2007,
 *     "On fast construction of SAH-based bounding volume hierarchies"), over
 *     compact 32-byte primitive references with single-precision boxes
 *     rounded outward, so a box never shrinks below its primitive.  A node's
 *     references are read twice: once to bin them along all three axes at
 *     once (SSE), once to partition them, which also gives the children's
 *     centroid bounds; the children's boxes are the unions of their bins (as
 *     Embree's builder does: Wald et al. 2014, "Embree: a kernel framework
 *     for efficient CPU ray tracing").  Nodes of two references are split in
 *     closed form.  References and leaf primitives are made in parallel
 *     loops, large subtrees built as OpenMP tasks, each on its own range of
 *     the references; the tree does not depend on the number of threads.
 *     Arrays of 4 MB and more are in huge pages (madvise), as Embree's are.
 *   - Collapse: the binary tree becomes an 8-wide tree (wide_node), each
 *     node holding the boxes of up to eight children side by side, so that
 *     two SSE instructions do one step of the slab test for all eight (Wald
 *     et al. 2008, "Getting rid of packets"; Dammertz et al. 2008, "Shallow
 *     bounding volume hierarchies").  Eight, not four: on a 10^6-triangle
 *     mesh a ray then reads a third fewer levels, and the tree no longer
 *     fits in the caches (1.1-1.4x the closest-hit and 1.2-1.7x the shadow
 *     rays of the 4-wide tree, measured interleaved).
 *   - Traversal: the boxes are tested in single precision, made
 *     conservative by a per-ray margin (Ize 2013, "Robust BVH ray
 *     traversal"): a box can be entered by mistake, never missed.  The
 *     primitives are then tested in double precision, exactly as before, so
 *     every hit (t, primitive) is the one the double-precision test gives.
 *   - Leaves: the primitives copied in leaf order, two side by side
 *     (leaf_pair): a precomputed double-precision triangle transform or a
 *     sphere in each lane of SSE2 registers, so that one pass of the
 *     triangle test's arithmetic tests two triangles and gives both t to the
 *     bit as the one-at-a-time test would, and the traversal asks once per
 *     pair, not once per triangle, whether a nearer hit was found (Embree's
 *     leaves hold four float triangles for the same reasons: Wald et al.
 *     2014, "Embree: a kernel framework for efficient CPU ray tracing").
 *   - Linear search: where the tree costs more tests than testing every
 *     primitive (measured on rays of the scene itself at build time, bvh.c:
 *     linear_is_cheaper; smallpt's nine spheres), scene_intersect and
 *     scene_occluded test them all, the spheres two at a time (sphere_pair),
 *     and give the same hit as the tree, to the bit. */
#ifndef COMMON_BVH_H
#define COMMON_BVH_H

#include "scene.h"

/* At most this many primitives in a leaf (two pairs; two bits of wide_node.child count pairs). */
enum { BVH_LEAF_SIZE = 4, BVH_WIDTH = 8 };

/* An inner node of the 8-wide tree.  bounds[f][k] is face f (lo x, y, z =
 * 0, 1, 2; hi x, y, z = 3, 4, 5) of child k: eight floats per face, two SSE
 * registers.  child[k] >= 0 is a wide_node index; child[k] < 0 is a leaf,
 * ~child[k] = first << 2 | (count - 1), its primitives those of the pairs
 * leaf_pairs[first .. first + count - 1].  An unused slot has an empty box
 * (lo = +inf, hi = -inf), which no ray enters. */
struct wide_node {
    float bounds[6][BVH_WIDTH];
    int child[BVH_WIDTH];
    int unused[8]; /* pads the node to 256 bytes, four cache lines */
};

/* Two primitives of a leaf, lane 0 and lane 1 of SSE2 registers.  A
 * triangle lane holds the rows of the map to the triangle's own coordinates
 * and the limits of u, v and u + v (bvh.c: triangle_transform): row[i][a][k]
 * is component a of row i in lane k.  A sphere lane (bit k of sphere_lanes)
 * holds its centre in row[0][0..2][k] and its radius in offset[0][k].  A
 * sphere lane and an empty one (primitive -1: the second lane of a leaf of
 * odd count) have u_min NaN, which fails the triangle test. */
struct leaf_pair {
    double row[3][3][2];
    double offset[3][2];
    double u_min[2], v_min[2], uv_max[2];
    int primitive[2]; /* index into the primitives (see scene.h), -1 in an empty lane */
    int sphere_lanes;
    int unused; /* pads the pair to 256 bytes, four cache lines */
};

/* The spheres, for linear search (scene_bvh.linear), two side by side: the
 * lanes of one SSE2 register each, so that two spheres take one pass of
 * sphere_hit's arithmetic, its square root and division included (on
 * smallpt's nine spheres they were a fifth of chapter 4's time).  In the
 * order of their indices (lane 0 the even ones), so that the nearest hit's
 * tie rule is one comparison a pair.  An odd count leaves a lane with
 * radius NaN, which no ray hits. */
struct sphere_pair {
    double x[2], y[2], z[2], radius[2];
    double primitive[2]; /* the primitive indices, as doubles for SSE2's comparisons (exact below 2^53) */
};

/* Both are allocated on cache-line boundaries, so a record spans whole lines. */
enum { BVH_ALIGNMENT = 64 };
_Static_assert(sizeof(wide_node) == 256, "wide_node is 256 bytes");
_Static_assert(sizeof(leaf_pair) == 256, "leaf_pair is 256 bytes");

/* The leaf a negative wide_node.child names: its first pair and how many. */
static inline int bvh_leaf_first(int child) { return ~child >> 2; }
static inline int bvh_leaf_count(int child) { return (~child & 3) + 1; }

/* The box of all primitives (triangles and spheres, without the edge margin). */
aabb bvh_geometry_bounds(const scene *s);

/* Builds s->bvh over s->triangles and the spheres (needs s->epsilon and
 * s->sphere_surfaces).  Returns 0, or -1 when out of memory. */
int bvh_build(scene *s);

/* Frees what bvh_build allocated and clears the fields. */
void bvh_free(scene_bvh *bvh);

/* Bytes the built BVH keeps (nodes, leaf primitives, leaf order). */
size_t bvh_memory_bytes(const scene_bvh *bvh);

#endif
