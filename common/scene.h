/* scene.h — the scene model, the .scene parser, and ray intersection.
 *
 * A scene is a list of named surfaces (quads, triangles, spheres, OBJ meshes),
 * each with a material, plus point lights, probes and a camera.  For ray
 * casting every planar surface is stored as triangles (a quad is two) and
 * every sphere as itself; a BVH over those primitives answers
 * scene_intersect() and scene_occluded().
 *
 * The file format is described in docs/scene-format.md.
 */
#ifndef COMMON_SCENE_H
#define COMMON_SCENE_H

#include <stddef.h>
#include <stdbool.h>
#include <stdint.h>

#include "vec.h"

enum { SCENE_NAME_MAX = 64 };

typedef enum {
    MATERIAL_DIFFUSE, /* Lambertian: albedo */
    MATERIAL_PHONG,   /* local model: albedo = kd, specular = ks, exponent */
    MATERIAL_MIRROR,  /* perfect mirror: specular = reflectance */
    MATERIAL_GLASS,   /* dielectric: ior, specular = tint (1,1,1 if not given) */
    MATERIAL_EMITTER, /* Lambertian emitter: emission = radiance, albedo = optional diffuse reflectance */
} material_kind;

typedef struct {
    char name[SCENE_NAME_MAX];
    material_kind kind;
    vec3 albedo;     /* diffuse reflectance rho (kd for phong) */
    vec3 specular;   /* phong ks, mirror reflectance, glass tint */
    double exponent; /* phong exponent */
    double ior;      /* glass index of refraction */
    vec3 emission;   /* emitted radiance (emitter only), on the front side */
} material;

typedef enum { SURFACE_QUAD, SURFACE_TRIANGLE, SURFACE_SPHERE, SURFACE_MESH } surface_kind;

typedef struct {
    char name[SCENE_NAME_MAX];
    surface_kind kind;
    int material;       /* index into scene.materials */
    vec3 vertex[4];     /* quad (4) or triangle (3) as written in the file */
    int vertex_count;   /* 4, 3, or 0 for spheres and meshes */
    vec3 center;        /* sphere */
    double radius;      /* sphere */
    int first_triangle; /* this surface's triangles in scene.triangles */
    int triangle_count; /* 0 for spheres */
    double area;        /* total surface area; an emitting sphere's: that of its cap (below) */
    /* An emitting sphere cut by an opaque sphere emits toward the camera only
     * from the cap { centre + radius * n : n . cap_axis >= cap_cos } (scene.c:
     * emitter_cap); the samplers and the emitter's power count that cap only.
     * cap_cos = -1: the whole sphere. */
    vec3 cap_axis;
    double cap_cos;
    bool parallelogram; /* a quad with vertex[0] + vertex[2] = vertex[1] + vertex[3]: sampled directly */
    int line;           /* line of the statement in the scene file */
} surface;

/* A triangle ready for intersection: p0, edges e1 = p1 - p0, e2 = p2 - p0,
 * unit geometric normal n = normalize(e1 x e2) (right-hand rule). */
typedef struct {
    vec3 p0, e1, e2, normal;
    double area;
    int surface;
} triangle;

typedef struct {
    char name[SCENE_NAME_MAX];
    vec3 position;
    vec3 intensity; /* W/sr per channel, isotropic */
} point_light;

typedef struct {
    char name[SCENE_NAME_MAX];
    vec3 position;
    vec3 normal; /* unit */
} probe;

typedef struct {
    vec3 eye, look, up;
    double fov_degrees; /* vertical field of view */
    /* Near distance: camera rays start this far from the eye (0: at the
     * eye), so what lies closer is not seen.  smallpt's camera sits behind
     * its front wall and starts its rays 140 units ahead (on a sphere, not a
     * plane: compiled by GCC, its Ray(cam.o + d * 140, d.norm()) normalises d
     * before it computes the origin). */
    double near;
} camera;

typedef struct {
    vec3 lo, hi;
} aabb;

/* What traversal reads (defined in bvh.h, private to the BVH code). */
typedef struct wide_node wide_node;
typedef struct leaf_pair leaf_pair;
typedef struct sphere_pair sphere_pair;

/* The BVH over the primitives (common/bvh.c): an 8-wide tree whose leaves
 * hold at most 4 primitives, copied in leaf order.  Each array is its own
 * allocation. */
typedef struct {
    int *primitive_order;      /* leaf order: primitive indices (the tests look at it) */
    wide_node *nodes;          /* node_count of them, depth-first, 64-byte aligned; root 0 */
    int node_count;            /* 0 when the scene has no primitives */
    leaf_pair *leaf_pairs;     /* the primitives in leaf order, two by two, 64-byte aligned */
    int leaf_pair_count;       /* each leaf's primitives in pairs of their own: a leaf of 3 has 2 */
    int primitive_count;       /* triangles + spheres */
    double unit;               /* a power of two: the boxes hold coordinates / unit (any scene fits a float) */
    double largest_coordinate; /* largest |coordinate| of the root box, in units: sets the box tests' margin */
    int linear;                /* 1: every primitive tested, the tree unused: cheaper in some small scenes */
    sphere_pair *sphere_pairs; /* the spheres two by two, for linear search's two-wide SIMD tests */
    int sphere_pair_count;
} scene_bvh;

typedef struct scene {
    char path[1024];
    camera camera;
    int width, height; /* `image` statement; 512 x 512 if absent */
    vec3 background;   /* radiance of rays that escape */

    material *materials;
    int material_count;
    surface *surfaces;
    int surface_count;
    triangle *triangles;
    int triangle_count;
    point_light *lights;
    int light_count;
    probe *probes;
    int probe_count;

    /* Emitting surfaces (material kind MATERIAL_EMITTER), for light sampling. */
    int *emitters; /* surface indices */
    int emitter_count;
    double emitter_area; /* total area of all emitting surfaces */

    /* Primitives: index i < triangle_count is triangle i; i >= triangle_count
     * is the sphere surface sphere_surfaces[i - triangle_count]. */
    int *sphere_surfaces;
    int sphere_count;
    scene_bvh bvh;

    /* Per triangle: the area of its surface's triangles up to and including
     * it (the last one's is the surface's area), for surface_sample_point. */
    double *triangle_area_cdf;

    aabb bounds; /* of all geometry */
    /* Scene-relative self-intersection offset.  A hit point computed in
     * double precision is off its surface by a few ulps of the coordinates'
     * magnitude (about 1e-16 relative); a ray leaving it must not re-hit
     * the same surface.  We move secondary ray origins by
     *   epsilon = 1e-9 * (largest absolute coordinate of the bounds)
     * along the surface normal: seven orders of magnitude above the rounding
     * error, and far below anything visible (5.6e-7 mm in the Cornell box).
     * Scaling the scene scales epsilon with it, so a scene in metres or in
     * millimetres renders the same (a fixed 1e-4 as in smallpt does not). */
    double epsilon;
} scene;

typedef struct {
    vec3 origin, direction; /* direction need not be unit for occlusion; unit for shading */
} ray;

typedef struct {
    double t;      /* ray parameter of the hit */
    vec3 point;    /* origin + t * direction */
    vec3 normal;   /* unit geometric normal as the file orients it (not flipped toward the ray) */
    int surface;   /* index into scene.surfaces */
    int primitive; /* triangle index, or triangle_count + sphere number */
} hit;

/* Parse a .scene file.  Returns 0 on success.  On any error returns 2,
 * frees what it allocated and writes one line "file:line: message" (no
 * trailing newline) into err.  Errors in an OBJ file name the OBJ file and
 * its line. */
int scene_load(const char *path, scene *out, char *err, size_t err_size);
void scene_free(scene *s);

/* Closest hit with epsilon-free t in (0, t_max); returns 1 if found. */
int scene_intersect(const scene *s, ray r, double t_max, hit *out);
/* Brute force over all primitives: the BVH's reference in the tests. */
int scene_intersect_brute_force(const scene *s, ray r, double t_max, hit *out);
/* Is anything between a and b?  Both ends are moved off their surfaces by
 * scene.epsilon toward each other, so a and b may lie on surfaces. */
int scene_occluded(const scene *s, vec3 a, vec3 b);

/* A ray origin for leaving surface point p (geometric normal n) in
 * direction d: p moved by scene.epsilon to the side of n that d points to.
 * (Inline: a few flops, at every bounce of every path.) */
static inline vec3 scene_offset_origin(const scene *s, vec3 p, vec3 n, vec3 d)
{
    return v3_madd(p, n, v3_dot(n, d) >= 0.0 ? s->epsilon : -s->epsilon);
}

/* Low-level intersection routines (exposed for the unit tests). */
/* Baldwin & Weber (2016) coordinate-transformation test, each edge moved
 * out by 1e-11 of the scene so a ray through a shared edge or a quad's
 * diagonal cannot slip between two triangles; returns t > 0 or INFINITY. */
double intersect_triangle(const triangle *tri, ray r);
/* Numerically robust ray-sphere (Haines et al., Ray Tracing Gems ch. 7):
 * accurate for radius 1e5 walls; returns the smallest t > 0 or INFINITY. */
double intersect_sphere(vec3 center, double radius, ray r);

/* Uniform point on an emitting or any triangulated surface, chosen in
 * proportion to area: returns point and unit normal; pdf = 1 / surface.area.
 * For spheres, uniform on the sphere, or on its cap (cap_cos). */
void surface_sample_point(const scene *s, int surface_index, double u1, double u2, double u3, vec3 *point,
                          vec3 *normal);

/* A sphere sampled whole (not cut to a cap by emitter_cap). */
static inline bool surface_is_whole_sphere(const surface *f)
{
    return f->kind == SURFACE_SPHERE && !(f->cap_cos > -1.0);
}

/* Works out every emitting sphere's cap and area, and the total emitter
 * area, for the camera's position (scene_load does; call it again after
 * moving the camera). */
void scene_settle_emitters(scene *s);

/* The scene's size for lengths chosen relative to it (the photon radius of
 * chapters 5 and 6): the diagonal of the geometry's bounds, or of the points
 * the camera sees when those are ten times smaller (walls made of spheres of
 * radius 1e5, as in smallpt, put the bounds a thousand rooms away). */
double scene_diagonal(const scene *s);

/* Index of a named surface or material, -1 if none. */
int scene_find_surface(const scene *s, const char *name);

/* Camera ray through image position (px, py) in pixels, (0,0) = top-left
 * corner of the image, y down.  Direction is unit. */
ray camera_ray(const camera *c, int width, int height, double px, double py);

/* The same, with the camera's frame worked out once per image rather than
 * once per ray: the unnormalised direction through image position (px, py)
 * is top_left + px * step_x + py * step_y (no division per ray). */
typedef struct {
    vec3 eye, top_left, step_x, step_y;
    double near; /* camera.near: a ray's origin is eye + near * (its unit direction) */
} camera_frame;
camera_frame camera_frame_make(const camera *c, int width, int height);
ray camera_frame_ray(const camera_frame *f, double px, double py);

#endif
