/* bvh.h — private to common/: the BVH's build and the layout traversal reads.
 *
 * The chapters use scene.h only; scene.c calls bvh_build() at load and
 * bvh_free() at scene_free(), and takes the bounds of the geometry from here.
 */
#ifndef COMMON_BVH_H
#define COMMON_BVH_H

#include "scene.h"

/* What traversal reads.  scene.bvh.build_nodes and primitive_order are the
 * BVH as built; traversal reads a copy laid out for speed:
 *   - trace_node: an inner node holding the boxes of both its children, so
 *     one visit tests two boxes that lie side by side in memory.  Each box
 *     is stored by face (lo x, y, z, hi x, y, z) and, within a face, by
 *     child: the same arithmetic for the two children on adjacent doubles,
 *     done by two-wide SIMD instructions (see box_entries).  A ray picks
 *     the near and far face of each slab by an index computed once per ray
 *     instead of a branch per box.
 *   - leaf_primitive: the primitives copied in leaf order, so a leaf is one
 *     contiguous run of memory with no primitive_order indirection.  Each
 *     keeps its original index for hit.primitive. */
struct trace_node {
    double bounds[12]; /* face f (lo x, y, z, hi x, y, z = 0 .. 5) of child k at [2 f + k] */
    int child[2];      /* trace_node index of an inner child, first leaf_primitive of a leaf */
    int count[2];      /* primitives of a leaf child, 0 for an inner child */
    int unused[4];     /* pads the node to 128 bytes: nodes[index] is then a shift, not a multiply */
};

struct leaf_primitive {
    /* Triangle: the rows of the map to its own coordinates and the limits
     * of u, v and u + v (see triangle_transform).  Sphere: row[0] = center,
     * offset[0] = radius. */
    vec3 row[3];
    double offset[3];
    double u_min, v_min, uv_max;
    int primitive; /* index into the primitives (see scene.h) */
    int is_sphere;
};

/* Both are allocated on cache-line boundaries, so a 128-byte record spans
 * exactly two lines. */
enum { BVH_ALIGNMENT = 64 };
_Static_assert(sizeof(trace_node) == 128, "trace_node is 128 bytes");
_Static_assert(sizeof(leaf_primitive) == 128, "leaf_primitive is 128 bytes");

/* The box of all primitives (triangles and spheres, without the edge margin). */
aabb bvh_geometry_bounds(const scene *s);

/* Builds s->bvh over s->triangles and the spheres (needs s->epsilon and
 * s->sphere_surfaces).  Returns 0, or -1 when out of memory. */
int bvh_build(scene *s);

/* Frees what bvh_build allocated and clears the fields. */
void bvh_free(scene_bvh *bvh);

#endif
