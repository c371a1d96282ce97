/* vec.h — three-component vectors for points, directions and RGB colours.
 *
 * Plain value types and static inline functions (no GLM, no macros with side
 * effects).  Doubles rather than floats: the scenes span millimetres to
 * 1e5-radius "walls", and double precision lets one scene-relative
 * self-intersection offset work for all of them (see scene.h).
 */
#ifndef COMMON_VEC_H
#define COMMON_VEC_H

#include <math.h>
#include <stdbool.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

typedef struct {
    double x, y, z;
} vec3;

static inline vec3 v3(double x, double y, double z) { return (vec3){x, y, z}; }
static inline vec3 v3_splat(double s) { return (vec3){s, s, s}; }
static inline vec3 v3_add(vec3 a, vec3 b) { return (vec3){a.x + b.x, a.y + b.y, a.z + b.z}; }
static inline vec3 v3_sub(vec3 a, vec3 b) { return (vec3){a.x - b.x, a.y - b.y, a.z - b.z}; }
static inline vec3 v3_scale(vec3 a, double s) { return (vec3){a.x * s, a.y * s, a.z * s}; }
/* Component-wise product: colour times colour (albedo times radiance). */
static inline vec3 v3_mul(vec3 a, vec3 b) { return (vec3){a.x * b.x, a.y * b.y, a.z * b.z}; }
static inline vec3 v3_neg(vec3 a) { return (vec3){-a.x, -a.y, -a.z}; }
/* a + b * s, the step along a ray. */
static inline vec3 v3_madd(vec3 a, vec3 b, double s) { return (vec3){a.x + b.x * s, a.y + b.y * s, a.z + b.z * s}; }
static inline double v3_dot(vec3 a, vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline vec3 v3_cross(vec3 a, vec3 b)
{
    return (vec3){a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
static inline double v3_length(vec3 a) { return sqrt(v3_dot(a, a)); }
static inline vec3 v3_normalize(vec3 a) { return v3_scale(a, 1.0 / v3_length(a)); }
/* fmax and fmin by comparisons.  The compiler turns the libm functions into
 * calls (a plain x86 max instruction would not ignore a NaN argument as they
 * must), and the path tracer asks for a colour's largest channel at every
 * vertex.  The same results: a NaN argument is ignored. */
static inline double max_ignoring_nan(double a, double b) { return a > b || isnan(b) ? a : b; }
static inline double min_ignoring_nan(double a, double b) { return a < b || isnan(b) ? a : b; }
static inline double v3_max_component(vec3 a) { return max_ignoring_nan(a.x, max_ignoring_nan(a.y, a.z)); }
static inline double v3_min_component(vec3 a) { return min_ignoring_nan(a.x, min_ignoring_nan(a.y, a.z)); }
static inline double v3_get(vec3 a, int axis) { return axis == 0 ? a.x : axis == 1 ? a.y : a.z; }
static inline vec3 v3_min(vec3 a, vec3 b) { return (vec3){fmin(a.x, b.x), fmin(a.y, b.y), fmin(a.z, b.z)}; }
static inline vec3 v3_max(vec3 a, vec3 b) { return (vec3){fmax(a.x, b.x), fmax(a.y, b.y), fmax(a.z, b.z)}; }
static inline bool v3_is_finite(vec3 a) { return isfinite(a.x) && isfinite(a.y) && isfinite(a.z); }
/* Mean of the three channels: a colour's "brightness" for statistics. */
static inline double v3_average(vec3 a) { return (a.x + a.y + a.z) / 3.0; }
/* Photometric luminance of linear sRGB (Rec. 709 weights). */
static inline double v3_luminance(vec3 a) { return 0.2126 * a.x + 0.7152 * a.y + 0.0722 * a.z; }

/* Mirror reflection of direction d about normal n (both unit): d - 2(d.n)n. */
static inline vec3 v3_reflect(vec3 d, vec3 n) { return v3_sub(d, v3_scale(n, 2.0 * v3_dot(d, n))); }

/* Orthonormal basis (tangent, bitangent, normal) around a unit normal,
 * branch-free construction of Duff et al., "Building an Orthonormal Basis,
 * Revisited" (JCGT 2017).  Used to turn local hemisphere samples into world
 * directions. */
typedef struct {
    vec3 tangent, bitangent, normal;
} onb;

static inline onb onb_from_normal(vec3 n)
{
    double sign = copysign(1.0, n.z);
    double a = -1.0 / (sign + n.z);
    double b = n.x * n.y * a;
    return (onb){
        .tangent = {1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x},
        .bitangent = {b, sign + n.y * n.y * a, -n.y},
        .normal = n,
    };
}
/* Local (x along tangent, y along bitangent, z along normal) to world. */
static inline vec3 onb_to_world(onb basis, vec3 local)
{
    return v3_add(v3_add(v3_scale(basis.tangent, local.x), v3_scale(basis.bitangent, local.y)),
                  v3_scale(basis.normal, local.z));
}
static inline vec3 onb_to_local(onb basis, vec3 world)
{
    return (vec3){v3_dot(world, basis.tangent), v3_dot(world, basis.bitangent), v3_dot(world, basis.normal)};
}

#endif
