/* 02_whitted.c — Lecture 2: Whitted ray tracing.
 *
 * Whitted (1980) keeps two parts of the light transport operator K of
 * (R4): the direct light of the local model (R1), and the *specular* part,
 * perfect mirror reflection and refraction, which is a delta function in
 * the integral of (R2) and therefore needs exactly one ray instead of an
 * integral.  At every hit x seen along -w_o:
 *
 *   L(x, w_o) = L_e(x, w_o)                                     emission
 *             + sum_lights f cos(theta_i) I / r^2 V             local model (R1), shadow rays
 *             + k_r L(x, w_r)                                   reflected ray
 *             + k_t L(x, w_t)                                   refracted ray
 *
 * with k_r = the mirror's colour, or for glass k_r = R and k_t = 1 - R from
 * the exact Fresnel equations (unpolarised light), w_t from Snell's law
 * n_i sin(theta_i) = n_t sin(theta_t), and no refracted ray at all beyond
 * the critical angle (total internal reflection).  Every hit may spawn new
 * rays: the *ray tree*.  Each level of the tree is one more application of
 * the specular part of K, so the tree cut at depth N is the Neumann series
 * (R6) cut after the K^N term (for these paths).
 *
 * What Whitted cannot do: diffuse interreflection (chapter 3), light
 * focused by glass onto a diffuse surface (caustics, chapter 4).
 *
 * Sections: state and options · the interface (Snell, Fresnel, Beer-Lambert) ·
 * shadow rays through glass · the ray tree · statistics · main.
 */
#include <stddef.h>
#include <stdlib.h>

#include "local_model.h"
#include "optics.h"
#include "render.h"

/* ---- state and options ------------------------------------------------------------ */

typedef enum { FRESNEL_EXACT, FRESNEL_SCHLICK } fresnel_formula; /* the order of --fresnel's choices */
typedef enum { GLASS_FILTERS, GLASS_OPAQUE } glass_shadows;      /* the order of --shadows' choices */

enum { MAX_DEPTH_LIMIT = 64 };

typedef struct {
    local_model local;          /* the shading at non-specular hits, as in chapter 1 */
    int fresnel;                /* fresnel_formula: --fresnel exact|schlick */
    int glass_shadows;          /* glass_shadows: --shadows opaque = glass blocks shadow rays like stone */
    int max_depth;              /* --max-depth: deepest ray of the tree (camera ray = 0) */
    double min_weight;          /* --min-weight: prune branches weighing less (Hall & Greenberg 1983) */
    double absorption_distance; /* --absorption D: > 0 turns a glass tint into Beer-Lambert absorption */
    bounce_window bounces;      /* --bounces A:B, copied from the driver's options in prepare() */
    /* Histogram of the ray-tree depth per camera ray, max_depth + 1 bins.
     * The only memory radiance() writes to, with atomic adds: the pointer in
     * the read-only state stays the same, the counts behind it change. */
    unsigned long long *depth_histogram;
} whitted_state;

/* Counter indices: the local model's three first (local_model.h), then ours. */
enum {
    COUNT_REFLECTED_RAYS = LOCAL_MODEL_COUNTERS,
    COUNT_REFRACTED_RAYS,
    COUNT_TOTAL_INTERNAL_REFLECTIONS,
    COUNT_PRUNED_BRANCHES,        /* weight below --min-weight */
    COUNT_DEPTH_LIMITED_BRANCHES, /* would be deeper than --max-depth */
};

/* ---- the interface: Snell, Fresnel, Beer-Lambert ------------------------------------------ */

/* A glass surface separates two media.  Its material's IOR is the
 * *relative* index n_back / n_front: the normal (as the file orients it)
 * points to the front, outside the glass.  A glass ball in air has IOR 1.5;
 * an air bubble in water has IOR 1 / 1.33 (its outside is water). */
typedef struct {
    vec3 normal;     /* unit, on the side the ray comes from */
    double n_i, n_t; /* indices on the incident and transmitted side */
    double cos_i;    /* cos(theta_i) > 0 */
    bool entering;   /* the ray comes from the front (outside) */
} interface;

static interface interface_at(const material *m, vec3 geometric_normal, vec3 direction)
{
    bool entering = v3_dot(direction, geometric_normal) < 0.0;
    vec3 n = entering ? geometric_normal : v3_neg(geometric_normal);
    return (interface){
        .normal = n,
        .n_i = entering ? 1.0 : m->ior,
        .n_t = entering ? m->ior : 1.0,
        .cos_i = fmin(1.0, -v3_dot(direction, n)),
        .entering = entering,
    };
}

/* The fraction R reflected by the interface; 1 - R is transmitted.
 * Exact: R = (r_s^2 + r_p^2) / 2 with Fresnel's amplitude ratios
 * (common/optics.h); Schlick's approximation only for comparison. */
static double fresnel_reflectance(const whitted_state *state, const interface *at)
{
    if (state->fresnel == FRESNEL_SCHLICK)
        return fresnel_schlick(at->cos_i, at->n_i, at->n_t);
    return fresnel_dielectric(at->cos_i, at->n_i, at->n_t, NULL, NULL);
}

/* How the glass tint acts on light going through it:
 *  - without --absorption, as a filter: transmitted light is multiplied by
 *    the tint once, when it enters the glass (Whitted's constant k_t);
 *  - with --absorption D, by Beer-Lambert: the tint is the fraction left
 *    after a path of length D inside the glass, so the absorption
 *    coefficient is sigma = -ln(tint) / D and a path of length l keeps
 *    exp(-sigma l) = tint^(l / D), per channel.  Thick glass is darker than
 *    thin glass, and colour deepens with thickness. */
static vec3 tint_on_entry(const whitted_state *state, const material *m)
{
    return state->absorption_distance > 0.0 ? v3_splat(1.0) : m->specular;
}
static vec3 absorption_along(const whitted_state *state, const material *m, double length)
{
    if (state->absorption_distance <= 0.0)
        return v3_splat(1.0);
    double exponent = length / state->absorption_distance; /* tint^(l/D); pow(0, x > 0) = 0 */
    return v3(pow(m->specular.x, exponent), pow(m->specular.y, exponent), pow(m->specular.z, exponent));
}

/* ---- shadow rays through glass ------------------------------------------------------------ */

/* Which lights does a point see through glass?  Two choices:
 *  opaque   (--shadows opaque): glass blocks light like stone.  Then the
 *           floor under a glass slab is black and a glass ball casts the
 *           same shadow as a stone ball: wrong, and badly so.
 *  filtered (default): the shadow ray goes on in a straight line through
 *           glass, losing at each crossing the Fresnel reflectance and the
 *           tint (Beer-Lambert with --absorption).  Refraction of the
 *           shadow ray is ignored: a shadow ray must end at the light
 *           sample, and a bent path would miss it.  Each crossing is
 *           weighted as if light entered from the optically thinner side:
 *           by reciprocity 1 - R is the same on both sides of an interface
 *           when the angles are related by Snell's law, so for a slab with
 *           parallel faces the result is exactly the light the slab
 *           transmits; only the sideways shift of its shadow is lost.  The
 *           bright spot a glass ball focuses (a caustic) is beyond a shadow
 *           ray; chapter 4 finds it.
 * Any other surface (diffuse, mirror, emitter) stops the shadow ray. */
enum { MAX_GLASS_CROSSINGS = 64 };

static vec3 shadow_transmittance(const void *context, const scene *s, vec3 x, vec3 y, render_counters *counters)
{
    const whitted_state *state = context; /* set in main() */
    vec3 to_light = v3_sub(y, x);
    double distance = v3_length(to_light);
    if (!(distance > 2.0 * s->epsilon))
        return v3_splat(1.0);
    vec3 direction = v3_scale(to_light, 1.0 / distance);
    /* Start epsilon off x and stop epsilon short of y, as scene_occluded() does. */
    ray r = {v3_madd(x, direction, s->epsilon), direction};
    double remaining = distance - 2.0 * s->epsilon;
    vec3 transmitted = v3_splat(1.0);
    for (int crossing = 0; crossing <= MAX_GLASS_CROSSINGS; crossing++) {
        counters->value[COUNT_SHADOW_RAYS]++;
        hit h;
        if (!scene_intersect(s, r, remaining, &h))
            return transmitted;
        const material *m = &s->materials[s->surfaces[h.surface].material];
        if (m->kind != MATERIAL_GLASS || state->glass_shadows == GLASS_OPAQUE || crossing == MAX_GLASS_CROSSINGS)
            return v3_splat(0.0);
        interface at = interface_at(m, h.normal, direction);
        double n_thin = fmin(at.n_i, at.n_t), n_dense = fmax(at.n_i, at.n_t);
        double R = state->fresnel == FRESNEL_SCHLICK ? fresnel_schlick(at.cos_i, n_thin, n_dense)
                                                     : fresnel_dielectric(at.cos_i, n_thin, n_dense, NULL, NULL);
        vec3 filter = at.entering ? tint_on_entry(state, m) : absorption_along(state, m, h.t);
        transmitted = v3_mul(transmitted, v3_scale(filter, 1.0 - R));
        if (v3_max_component(transmitted) <= 0.0)
            return transmitted;
        /* Go on from just behind the glass surface. */
        vec3 origin = scene_offset_origin(s, h.point, h.normal, direction);
        remaining -= v3_dot(v3_sub(origin, r.origin), direction);
        r.origin = origin;
        if (remaining <= 0.0)
            return transmitted;
    }
    return v3_splat(0.0); /* not reached */
}

/* ---- the ray tree ------------------------------------------------------------------------- */

/* Everything one camera sample's tree needs besides the ray. */
typedef struct {
    const whitted_state *state;
    const scene *s;
    rng *g;
    render_counters *counters;
    int deepest; /* the depth of the deepest ray traced so far */
} ray_tree;

/* Does a contribution that reached the eye after `bounces` interactions
 * belong to the Neumann terms K^A E .. K^B E kept by --bounces A:B (R6)? */
static bool keep_term(const ray_tree *tree, int bounces) { return bounces_keep(tree->state->bounces, bounces); }

static vec3 trace(ray_tree *tree, ray r, int depth, vec3 weight);

/* One branch of the tree: the child ray `child` carries `coefficient` (k_r
 * or k_t) of its parent's radiance; weight is the parent's weight, the
 * product of the coefficients from the eye down to it.  A branch is not
 * traced when it would be deeper than --max-depth, or when its weight falls
 * below --min-weight (Hall & Greenberg's adaptive tree depth: a branch that
 * can change the pixel by at most weight * L is not worth a ray). [exercise 2.3] */
static vec3 branch(ray_tree *tree, ray child, int depth, vec3 weight, vec3 coefficient, int ray_kind)
{
    if (v3_max_component(coefficient) <= 0.0)
        return v3_splat(0.0);
    vec3 child_weight = v3_mul(weight, coefficient);
    if (depth + 1 > tree->state->max_depth) {
        tree->counters->value[COUNT_DEPTH_LIMITED_BRANCHES]++;
        return v3_splat(0.0);
    }
    if (v3_max_component(child_weight) < tree->state->min_weight) {
        tree->counters->value[COUNT_PRUNED_BRANCHES]++;
        return v3_splat(0.0);
    }
    tree->counters->value[ray_kind]++;
    return v3_mul(coefficient, trace(tree, child, depth + 1, child_weight));
}

/* Glass: a reflected ray weighted R and a refracted ray weighted 1 - R
 * (times the tint), or only the reflected ray with weight 1 beyond the
 * critical angle. [exercise 2.4] */
static vec3 dielectric(ray_tree *tree, ray r, const hit *h, const material *m, int depth, vec3 weight)
{
    const whitted_state *state = tree->state;
    const scene *s = tree->s;
    interface at = interface_at(m, h->normal, r.direction);
    /* A ray that arrives at the back of a glass surface has travelled h->t
     * inside that glass: Beer-Lambert (only with --absorption). */
    vec3 absorbed = at.entering ? v3_splat(1.0) : absorption_along(state, m, h->t);
    weight = v3_mul(weight, absorbed);

    double R = fresnel_reflectance(state, &at);
    vec3 refracted_direction;
    bool total_internal_reflection =
        R >= 1.0 || !refract_direction(r.direction, at.normal, at.n_i / at.n_t, &refracted_direction);
    if (total_internal_reflection) {
        tree->counters->value[COUNT_TOTAL_INTERNAL_REFLECTIONS]++;
        R = 1.0; /* all of it is reflected, whatever Schlick says */
    }

    vec3 reflected_direction = v3_reflect(r.direction, at.normal);
    ray reflected = {scene_offset_origin(s, h->point, h->normal, reflected_direction), reflected_direction};
    vec3 L = branch(tree, reflected, depth, weight, v3_splat(R), COUNT_REFLECTED_RAYS);
    if (!total_internal_reflection) {
        /* Radiance crossing into a denser medium is squeezed into a smaller
         * solid angle and grows by (n_t / n_i)^2; it shrinks by the same
         * factor on the way out.  A camera ray that enters a closed glass
         * object leaves it again before it meets a diffuse surface, so the
         * two factors cancel and, like Whitted, we leave both out. */
        refracted_direction = v3_normalize(refracted_direction);
        ray refracted = {scene_offset_origin(s, h->point, h->normal, refracted_direction), refracted_direction};
        vec3 k_t = v3_scale(at.entering ? tint_on_entry(state, m) : v3_splat(1.0), 1.0 - R);
        L = v3_add(L, branch(tree, refracted, depth, weight, k_t, COUNT_REFRACTED_RAYS));
    }
    return v3_mul(absorbed, L);
}

/* The radiance arriving along r, a ray at `depth` in the tree (the camera
 * ray is depth 0; each reflection or refraction adds one). [exercise 2.5] */
static vec3 trace(ray_tree *tree, ray r, int depth, vec3 weight)
{
    const whitted_state *state = tree->state;
    const scene *s = tree->s;
    if (depth > tree->deepest)
        tree->deepest = depth;
    hit h;
    if (!scene_intersect(s, r, INFINITY, &h)) /* escaped: light from the background, K^depth E */
        return keep_term(tree, depth) ? s->background : v3_splat(0.0);

    const material *m = &s->materials[s->surfaces[h.surface].material];
    if (m->kind == MATERIAL_MIRROR) {
        vec3 reflected_direction = v3_reflect(r.direction, h.normal);
        ray reflected = {scene_offset_origin(s, h.point, h.normal, reflected_direction), reflected_direction};
        return branch(tree, reflected, depth, weight, m->specular, COUNT_REFLECTED_RAYS);
    }
    if (m->kind == MATERIAL_GLASS)
        return dielectric(tree, r, &h, m, depth, weight);

    /* Diffuse, Phong, emitter: the local model of chapter 1 (R1), both
     * sides shaded, the normal turned toward the viewer. */
    vec3 w_o = v3_neg(r.direction);
    bool front = v3_dot(h.normal, w_o) > 0.0;
    vec3 n = front ? h.normal : v3_neg(h.normal);
    vec3 L = v3_splat(0.0);
    if (m->kind == MATERIAL_EMITTER && front && keep_term(tree, depth)) /* L_e: the term K^depth E */
        L = m->emission;
    if (keep_term(tree, depth + 1)) /* one more reflection, off this surface: K^(depth+1) E */
        L = v3_add(
            L, direct_light(&state->local, s, h.point, n, w_o, m, state->local.light_samples, tree->g, tree->counters));
    /* The ambient term stands in for all terms from K^(depth+2) E on; it is
     * kept only when --bounces keeps all of those. */
    if (bounces_keep_all_from(state->bounces, depth + 2))
        L = v3_add(L, ambient_light(&state->local, m));
    return L;
}

static vec3 radiance(const void *state_pointer, const scene *s, ray r, rng *g, render_counters *counters)
{
    const whitted_state *state = state_pointer;
    ray_tree tree = {.state = state, .s = s, .g = g, .counters = counters, .deepest = 0};
    vec3 L = trace(&tree, r, 0, v3_splat(1.0));
#pragma omp atomic
    state->depth_histogram[tree.deepest]++;
    return L;
}

static int warned_no_light; /* warn_once flag */

/* ---- statistics --------------------------------------------------------------------------- */

static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    whitted_state *state = state_pointer;
    if (s->light_count == 0 && s->emitter_count == 0)
        warn_once(&warned_no_light, "02_whitted: the scene has no light (no point light, no emitter): "
                                    "the image shows only the ambient term and the background");
    state->bounces = bounce_window_of(o);
    state->depth_histogram = calloc((size_t)state->max_depth + 1, sizeof *state->depth_histogram);
    if (!state->depth_histogram) {
        snprintf(err, err_size, "argv:%d: out of memory for the depth histogram", o->scene_argv);
        return 2;
    }
    return 0;
}

static void write_stats(const void *state_pointer, FILE *json)
{
    const whitted_state *state = state_pointer;
    fprintf(json, ",\n  \"fresnel\": \"%s\",\n  \"glass_shadows\": \"%s\",\n  \"max_depth\": %d,\n  \"min_weight\": ",
            state->fresnel == FRESNEL_EXACT ? "exact" : "schlick",
            state->glass_shadows == GLASS_OPAQUE ? "opaque" : "filtered", state->max_depth);
    json_number(json, state->min_weight);
    json_field_number(json, "absorption_distance", state->absorption_distance);
    local_model_write_stats(&state->local, json);
    /* depth_histogram[k]: camera samples whose deepest ray was at depth k */
    fprintf(json, ",\n  \"depth_histogram\": [");
    for (int k = 0; k <= state->max_depth; k++)
        fprintf(json, "%s%llu", k ? ", " : "", state->depth_histogram ? state->depth_histogram[k] : 0ull);
    fputc(']', json);
}

static void finish(void *state_pointer)
{
    whitted_state *state = state_pointer;
    free(state->depth_histogram);
    state->depth_histogram = NULL;
}

/* ---- main --------------------------------------------------------------------------------- */

#define WHITTED(field) offsetof(whitted_state, field)
static const option WHITTED_OPTIONS[] = {
    {"--fresnel", NULL, OPTION_CHOICE, WHITTED(fresnel), .choices = "exact|schlick", .default_text = "exact",
     .help = "reflectance of glass"},
    {"--shadows", NULL, OPTION_CHOICE, WHITTED(glass_shadows), .choices = "filtered|opaque", .default_text = "filtered",
     .help = "shadow rays pass glass dimmed by Fresnel and tint, or glass blocks light"},
    {"--max-depth", "N", OPTION_INT, WHITTED(max_depth), .min = 0, .max = MAX_DEPTH_LIMIT, .default_text = "10",
     .help = "deepest reflected/refracted ray"},
    {"--min-weight", "W", OPTION_DOUBLE, WHITTED(min_weight), .min = 0.0, .max = 1.0, .default_text = "0",
     .help = "prune branches whose weight is below W (0: the full tree)"},
    {"--absorption", "D", OPTION_DOUBLE, WHITTED(absorption_distance), .min = 1e-300, .max = 1e300,
     .help = "Beer-Lambert: a glass tint is what is left after a path of length D (scene units); "
             "not given: the tint filters once on entry"},
    {0},
};
#undef WHITTED

int main(int argc, char **argv)
{
    whitted_state state = {0};
    state.local.transmittance = shadow_transmittance; /* V(x, y) lets light through glass */
    state.local.transmittance_context = &state;
    const chapter whitted = {
        .name = "02_whitted",
        .description = "Whitted ray tracing: local model (R1) + mirror reflection + refraction with Fresnel",
        .options = {{LOCAL_MODEL_OPTIONS, &state.local}, {WHITTED_OPTIONS, &state}},
        .default_spp = 1,
        .counter_names = {"shadow_rays", "point_light_samples", "area_light_samples", "reflected_rays",
                          "refracted_rays", "total_internal_reflections", "pruned_branches", "depth_limited_branches",
                          NULL},
        .prepare = prepare,
        .radiance = radiance,
        .write_stats = write_stats,
        .finish = finish,
    };
    return render_main(argc, argv, &whitted, &state);
}
