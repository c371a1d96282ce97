/* radiosity_setup.c — what chapters 3 and 03c share around their lectures:
 * options, meshing steps, stats (radiosity_setup.h).  Nothing here is the lecture. */
#include "radiosity_setup.h"

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_io.h"
#include "render.h"
#include "sampling.h"

/* The default --patch-size: a tenth of the largest side of the scene's
 * bounding box, so that a scene gets the same mesh in metres as in
 * millimetres (no unit is baked in). */
#define PATCH_SIZE_DEFAULT "largest-side/10"
static const double PATCH_SIZE_PARTS = 10.0;
/* Chapter 03c's default: every surface is one root (one cell per triangle, 12 x 6 per sphere). */
#define ROOTS_DEFAULT "surfaces"

const char *const solver_names[4] = {"jacobi", "gauss-seidel", "shooting", "direct"};

/* --patch-size: a positive length; where it was given is kept for the
 * message when it makes too many patches. */
static int parse_patch_size(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    radiosity_options *o = state;
    char *end;
    if (argv_index < 0 && (!strcmp(value, PATCH_SIZE_DEFAULT) || !strcmp(value, ROOTS_DEFAULT))) { /* the default */
        o->patch_size = 0.0, o->patch_size_argv = 0;
        return 0;
    }
    double size = strtod(value, &end);
    if (end == value || *end || !isfinite(size) || !(size > 0.0)) {
        snprintf(why, why_size, "must be positive (scene units), not '%s'", value);
        return 2;
    }
    o->patch_size = size;
    o->patch_size_argv = argv_index > 0 ? argv_index : 0; /* 0: the default */
    return 0;
}

/* --adaptive-levels N also turns --adaptive on. */
static int parse_adaptive_levels(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    radiosity_options *o = state;
    char *end;
    long levels = strtol(value, &end, 10);
    if (end == value || *end || levels < 1 || levels > 8) {
        snprintf(why, why_size, "wants a whole number in [1, 8], not '%s'", value);
        return 2;
    }
    o->adaptive_levels = (int)levels;
    if (argv_index > 0) /* given on the command line, not the default */
        o->adaptive = true;
    return 0;
}

/* --eps: a form factor in (0, 1]; --levels: 1..12; where each was given is kept for messages. */
static int parse_eps(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    radiosity_options *o = state;
    char *end;
    double eps = strtod(value, &end);
    if (end == value || *end || !isfinite(eps) || !(eps > 0.0) || eps > 1.0) {
        snprintf(why, why_size, "wants a form factor in (0, 1], not '%s'", value);
        return 2;
    }
    o->eps = eps, o->eps_argv = argv_index > 0 ? argv_index : 0;
    return 0;
}

static int parse_levels(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    radiosity_options *o = state;
    char *end;
    long levels = strtol(value, &end, 10);
    if (end == value || *end || levels < 1 || levels > 12) {
        snprintf(why, why_size, "wants a whole number in [1, 12], not '%s'", value);
        return 2;
    }
    o->levels = (int)levels, o->levels_argv = argv_index > 0 ? argv_index : 0;
    return 0;
}

#define OPTION_FIELD(field) offsetof(radiosity_options, field)
/* The options both chapters solve with, in both tables (one spelling). */
#define SOLVE_OPTIONS                                                                                                  \
    {"--tol",                                                                                                          \
     "T",                                                                                                              \
     OPTION_DOUBLE,                                                                                                    \
     OPTION_FIELD(tolerance),                                                                                          \
     .min = 0.0,                                                                                                       \
     .max = 1.0,                                                                                                       \
     .default_text = "1e-4",                                                                                           \
     .help = "stop when the residual falls below T (a fraction of the source power)"},                                 \
        {"--iterations",                                                                                               \
         "N",                                                                                                          \
         OPTION_INT,                                                                                                   \
         OPTION_FIELD(max_iterations),                                                                                 \
         .min = 1,                                                                                                     \
         .max = 100000000,                                                                                             \
         .default_text = "1000",                                                                                       \
         .help = "at most N iterations (--solver shooting: N x patches shots)"},                                       \
        {"--quadrature",                                                                                               \
         "M",                                                                                                          \
         OPTION_INT,                                                                                                   \
         OPTION_FIELD(quadrature),                                                                                     \
         .min = 1,                                                                                                     \
         .max = 16,                                                                                                    \
         .default_text = "4",                                                                                          \
         .help = "M x M points per patch triangle for near form factors"},                                             \
        {"--shading",                                                                                                  \
         NULL,                                                                                                         \
         OPTION_CHOICE,                                                                                                \
         OPTION_FIELD(smooth),                                                                                         \
         .choices = "flat|smooth",                                                                                     \
         .default_text = "flat",                                                                                       \
         .help = "patch colours, or interpolated vertex radiance"},                                                    \
    {                                                                                                                  \
        "--smooth", NULL, OPTION_FLAG, 0, .alias_of = "--shading smooth"                                               \
    }

const option RADIOSITY_OPTIONS[] = {
    {"--patch-size", "S", OPTION_CUSTOM, 0, .parse = parse_patch_size, .default_text = PATCH_SIZE_DEFAULT,
     .help = "target patch edge in scene units; by default a tenth of the scene's largest extent (56 in the "
             "Cornell box, in mm; 0.1 in a room of 1 m)"},
    {"--adaptive", NULL, OPTION_FLAG, OPTION_FIELD(adaptive),
     .help = "refine patches where the radiance changes fast (shadow edges)"},
    {"--adaptive-levels", "N", OPTION_CUSTOM, 0, .parse = parse_adaptive_levels, .default_text = "2",
     .help = "refinement rounds, 1..8, each splitting patches in four; implies --adaptive"},
    {"--adaptive-threshold", "T", OPTION_DOUBLE, OPTION_FIELD(adaptive_threshold), .min = 1e-6, .max = 1e6,
     .default_text = "0.1", .help = "split where a patch and the mean of its corners differ by T x the mean radiance"},
    {"--solver", NULL, OPTION_CHOICE, OPTION_FIELD(solver), .choices = "jacobi|gauss-seidel|shooting|direct",
     .default_text = "jacobi", .help = "how L = E + KL is solved (hierarchically: 03c_hierarchical)"},
    SOLVE_OPTIONS,
    {"--max-patches", "N", OPTION_INT, OPTION_FIELD(max_patches), .min = 1, .max = 1 << 30, .default_text = "16384",
     .help = "refuse matrix solvers above N patches (16384: 2 GiB of doubles for the direct solve)"},
    {"--reciprocity", NULL, OPTION_CHOICE, OPTION_FIELD(enforce_reciprocity), .choices = "check|enforce",
     .default_text = "check", .help = "report A_i F_ij against A_j F_ji, or average them"},
    {"--formfactors", "FILE.csv", OPTION_STRING, OPTION_FIELD(formfactors_path),
     .help = "write the surface-to-surface form factors (from,to,F)"},
    {0},
};

const option HIERARCHICAL_OPTIONS[] = {
    {"--patch-size", "S", OPTION_CUSTOM, 0, .parse = parse_patch_size, .default_text = ROOTS_DEFAULT,
     .help = "the roots' edge in scene units; by default every surface is one root (a cell per triangle, 12 x 6 "
             "per sphere)"},
    {"--eps", "E", OPTION_CUSTOM, 0, .parse = parse_eps, .default_text = "1e-2",
     .help = "link two elements when both form-factor estimates are below E, in (0, 1]"},
    {"--eps-spread", "S", OPTION_DOUBLE, OPTION_FIELD(eps_spread), .min = 0.0, .max = 1.0, .default_text = "1e-3",
     .help = "solve, then refine again where rho F (the source's spread) passes S x the receiver's radiance; 0: "
             "one pass"},
    {"--levels", "N", OPTION_CUSTOM, 0, .parse = parse_levels, .default_text = "8",
     .help = "split an element at most N times below its surface, 1..12; by default fewer where the scene has so "
             "many surfaces that 8 could pass the element limit"},
    SOLVE_OPTIONS,
    {0},
};
#undef SOLVE_OPTIONS
#undef OPTION_FIELD

void record_residual(radiosity_stats *stats, double residual)
{
    stats->residual = residual;
    if (stats->history_count == stats->history_capacity) {
        int capacity = stats->history_capacity ? 2 * stats->history_capacity : 64;
        double *history = realloc(stats->history, (size_t)capacity * sizeof *history);
        if (!history)
            return;
        stats->history = history, stats->history_capacity = capacity;
    }
    stats->history[stats->history_count++] = residual;
}

void write_radiosity_stats(FILE *json, const radiosity_options *o, const radiosity_stats *r, const scene *s,
                           const patch_mesh *m, const vec3 *radiance, bool have_matrix)
{
    int patches = m->patch_count;
    fprintf(json, ",\n  \"solver\": \"%s\",\n  \"solver_used\": \"%s\",\n  \"patch_size\": ",
            o->hierarchical ? "hierarchical" : solver_names[o->solver], r->solver_used ? r->solver_used : "none");
    json_number(json, o->patch_size);
    fprintf(json, ",\n  \"patches\": %d,\n  \"refinements\": %d,\n  \"iterations\": %d,\n  \"shots\": %d", patches,
            r->refinements, r->iterations, r->shots);
    json_field_number(json, "residual", r->residual);
    json_field_number(json, "tolerance", o->tolerance);
    fprintf(json, ",\n  \"converged\": %s,\n  \"no_light\": %s,\n  \"residual_history\": [",
            r->converged ? "true" : "false", r->no_light ? "true" : "false");
    for (int k = 0; k < r->history_count; k++) {
        if (k)
            fputs(", ", json);
        json_number(json, r->history[k]);
    }
    fprintf(json, "],\n  \"formfactor_s\": ");
    json_number(json, r->formfactor_s);
    json_field_number(json, "solve_s", r->solve_s);
    fprintf(json, ",\n  \"visibility_rays\": %llu,\n  \"reciprocity\": \"%s\"", (unsigned long long)r->visibility_rays,
            o->enforce_reciprocity ? "enforce" : "check");
    if (r->have_matrix_checks) { /* hierarchical: each leaf's links and its ancestors' */
        if (!o->hierarchical)
            json_field_number(json, "reciprocity_error", r->reciprocity_error);
        json_field_number(json, "row_sum_min", r->row_sum_min);
        json_field_number(json, "row_sum_max", r->row_sum_max);
    }
    fprintf(json, ",\n  \"matrix_bytes\": %.0f", have_matrix ? (double)patches * patches * 4.0 : 0.0);
    if (o->hierarchical) {
        fprintf(json, ",\n  \"elements\": %ld,\n  \"links\": %ld,\n  \"levels\": %d", r->elements, r->links, r->levels);
        json_field_number(json, "eps", o->eps);
        json_field_number(json, "eps_spread", o->eps_spread);
        fprintf(json, ",\n  \"first_pass_links\": %ld", r->first_pass_links);
        json_field_number(json, "hierarchy_bytes", r->hierarchy_bytes);
    }
    /* Each surface's mean over its whole area: a patch partly inside a solid
     * (the floor under a box) carries light on its exposed part only. */
    vec3 *whole = malloc((size_t)patches * sizeof *whole + 1);
    for (int i = 0; whole && i < patches; i++)
        whole[i] = v3_scale(radiance[i], m->patches[i].unburied);
    json_surface_radiance(json, s, m, whole ? whole : radiance);
    free(whole);
}

void radiosity_report(const radiosity_options *o, const radiosity_stats *r, int patches, bool quiet)
{
    if (r->no_light)
        fprintf(stderr,
                "warning: %s: the scene has no light (no point light, no emitter): "
                "the solution is zero and the image black\n",
                o->program);
    else if (!r->converged)
        fprintf(stderr,
                "warning: %s: %s stopped at the iteration cap (%d iterations) with residual %.3g "
                "above --tol %.3g; raise --iterations\n",
                o->program, r->solver_used, r->iterations, r->residual, o->tolerance);
    if (!quiet && o->hierarchical)
        fprintf(stderr, "%s: hierarchy of %ld elements, %ld links, %d levels, %.1f MiB\n", o->program, r->elements,
                r->links, r->levels, r->hierarchy_bytes / 1048576.0);
    if (!quiet)
        fprintf(stderr, "%s: %d patches, form factors %.2f s, %s %d iterations %.2f s, residual %.3g\n", o->program,
                patches, r->formfactor_s, r->solver_used, r->iterations, r->solve_s, r->residual);
}

enum { MESH_CELL_LIMIT = 4000000 }; /* beyond this even shooting would take hours */

static int check_mesh_size(const radiosity_options *o, double cells, char *err, size_t err_size)
{
    if (!(cells > MESH_CELL_LIMIT))
        return 0;
    snprintf(err, err_size, "argv:%d: --patch-size %g gives about %.3g patches, more than this chapter meshes (%d)",
             o->patch_size_argv, o->patch_size, cells, MESH_CELL_LIMIT); /* argv:0 only if the default did */
    return 2;
}

int radiosity_check_matrix_size(const radiosity_options *o, int n, char *err, size_t err_size)
{
    if (o->solver == SOLVER_SHOOTING || o->hierarchical || n <= o->max_patches)
        return 0;
    snprintf(err, err_size,
             "argv:0: %d patches need a %d x %d matrix (%.2f GiB as doubles), over the limit "
             "--max-patches %d (2 GiB); use --solver shooting, a larger --patch-size, or raise --max-patches",
             n, n, n, (double)n * n * 8.0 / 1073741824.0, o->max_patches);
    return 2;
}

static int warned_specular, warned_phong, warned_spheres;

/* Spheres are meshed unless mirror or glass (radiosity cannot carry their light: they only block it). */
static bool *spheres_to_mesh(const scene *s, const char *program)
{
    bool *mesh = calloc((size_t)s->surface_count + 1, sizeof *mesh);
    for (int i = 0; mesh && i < s->surface_count; i++) {
        const material *m = &s->materials[s->surfaces[i].material];
        if (s->surfaces[i].kind != SURFACE_SPHERE)
            continue;
        mesh[i] = m->kind != MATERIAL_MIRROR && m->kind != MATERIAL_GLASS;
        if (!mesh[i])
            warn_once(&warned_spheres,
                      "%s: mirror and glass spheres are not meshed into patches; they "
                      "block light but carry no radiance (black in the image)",
                      program);
    }
    return mesh;
}

int radiosity_mesh_scene(patch_mesh *m, const scene *s, radiosity_options *o, char *err, size_t err_size)
{
    bool hierarchical = o->hierarchical;
    if (!(o->patch_size > 0.0)) /* the default: from the scene's size */
        o->patch_size = v3_max_component(v3_sub(s->bounds.hi, s->bounds.lo)) / PATCH_SIZE_PARTS;
    double size = hierarchical && o->patch_size_argv == 0 ? INFINITY : o->patch_size; /* roots: whole surfaces */
    bool *spheres = spheres_to_mesh(s, o->program);
    if (!spheres || check_mesh_size(o, patch_mesh_estimate(s, size, spheres), err, err_size)) {
        free(spheres);
        return spheres ? 2 : (snprintf(err, err_size, "argv:0: out of memory while meshing"), 2);
    }
    int failed = patch_mesh_build(m, s, size, spheres);
    free(spheres);
    if (failed) {
        snprintf(err, err_size, "argv:0: out of memory while meshing");
        return 2;
    }
    return hierarchical ? 0 : radiosity_collect_patches(m, s, o, err, err_size);
}

void radiosity_material(const scene *s, int surface, vec3 *albedo, vec3 *emission)
{
    const material *m = &s->materials[s->surfaces[surface].material];
    *albedo = m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS ? m->specular : m->albedo;
    *emission = m->kind == MATERIAL_EMITTER ? m->emission : v3_splat(0.0);
}

int radiosity_collect_patches(patch_mesh *mesh, const scene *s, const radiosity_options *o, char *err, size_t err_size)
{
    if (patch_mesh_collect(mesh, o->quadrature)) {
        snprintf(err, err_size, "argv:0: out of memory for the patches");
        return 2;
    }
    for (int i = 0; i < mesh->patch_count; i++) {
        patch *p = &mesh->patches[i];
        const material *m = &s->materials[s->surfaces[p->surface].material];
        radiosity_material(s, p->surface, &p->albedo, &p->emission);
        if (m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS)
            warn_once(&warned_specular,
                      "%s: radiosity models diffuse reflection only; mirrors and glass "
                      "are treated as diffuse surfaces with their colour as albedo",
                      o->program);
        else if (m->kind == MATERIAL_PHONG)
            warn_once(&warned_phong, "%s: Phong surfaces are treated as diffuse with albedo kd (ks dropped)",
                      o->program);
    }
    return 0;
}

int radiosity_refine(patch_mesh *m, const scene *s, const radiosity_options *o, radiosity_stats *r,
                     const vec3 *radiance, bool quiet, char *err, size_t err_size)
{
    if (!o->adaptive || o->hierarchical || r->refinements == o->adaptive_levels || r->no_light)
        return 0;
    int split = patch_mesh_refine(m, radiance, o->adaptive_threshold);
    if (split < 0)
        snprintf(err, err_size, "argv:0: out of memory while refining the mesh");
    if (split <= 0)
        return split;
    r->refinements++;
    if (!quiet)
        fprintf(stderr, "%s: refinement %d split %d of %d patches\n", o->program, r->refinements, split,
                m->patch_count);
    return radiosity_collect_patches(m, s, o, err, err_size) ? -1 : split;
}

/* Is the scene closed: does every one of a few fixed cosine-weighted rays
 * from each patch's centroid hit it?  Then every row should sum to 1.
 * Patches inside a solid (the floor under a box: the ray along the
 * normal meets a back face) or against one (the box's bottom on the
 * floor: it escapes) have none to sum and are marked in buried. */
static bool closed_scene(const patch_mesh *m, const scene *s, bool *buried)
{
    static const double u[4][2] = {{0.125, 0.375}, {0.375, 0.875}, {0.625, 0.125}, {0.875, 0.625}};
    bool closed = true;
    for (int i = 0; i < m->patch_count; i++) {
        const patch *p = &m->patches[i];
        onb basis = onb_from_normal(p->normal);
        hit h;
        bool ahead = scene_intersect(s, (ray){scene_offset_origin(s, p->centroid, p->normal, p->normal), p->normal},
                                     INFINITY, &h);
        buried[i] = !ahead || v3_dot(h.normal, p->normal) > 0.0; /* or facing a surface it rests on */
        for (int k = 0; k < 4 && closed && !buried[i]; k++) {
            vec3 d = onb_to_world(basis, cosine_sample_hemisphere(u[k][0], u[k][1]));
            closed = scene_intersect(s, (ray){scene_offset_origin(s, p->centroid, p->normal, d), d}, INFINITY, &h);
        }
    }
    return closed;
}

/* The bias of L a missing row fraction may cause before a warning: 1 %. */
static const double ROW_SUM_BIAS = 0.01;

void radiosity_warn_row_sums(const float *F, const patch_mesh *m, const scene *s, const radiosity_options *o)
{
    size_t n = (size_t)m->patch_count;
    double rho = 0.0; /* the largest albedo: how much a missing row fraction is amplified */
    for (size_t i = 0; i < n; i++)
        rho = fmax(rho, v3_max_component(m->patches[i].albedo));
    double bearable = ROW_SUM_BIAS * (1.0 - rho) / fmax(rho, 1e-9);
    bool *buried = malloc(n * sizeof *buried + 1);
    char names[256] = "";
    double worst = 1.0;
    for (int surface = 0; buried && closed_scene(m, s, buried) && surface < s->surface_count; surface++) {
        double area = 0.0, sum = 0.0;
        for (size_t i = 0; i < n; i++)
            if (m->patches[i].surface == surface && !buried[i]) {
                area += m->patches[i].area;
                for (size_t j = 0; j < n; j++)
                    sum += m->patches[i].area * F[i * n + j];
            }
        if (!(area > 0.0) || sum / area >= 1.0 - bearable)
            continue;
        worst = fmin(worst, sum / area);
        size_t used = strlen(names);
        snprintf(names + used, sizeof names - used, "%s%s", used ? ", " : "", s->surfaces[surface].name);
    }
    free(buried);
    if (names[0])
        fprintf(stderr,
                "warning: %s: in this closed scene the form factors of surfaces sum to as little as %.3f (%s), "
                "below 1 - %.2g, which biases L by more than %.0f %% at albedo %.2g; use a smaller --patch-size "
                "(now %g)\n",
                o->program, worst, names, bearable, 100.0 * ROW_SUM_BIAS, rho, o->patch_size);
}

static int warned_back;

void radiosity_view_set(radiosity_view *v, const radiosity_options *opt, const radiosity_stats *stats, const scene *s,
                        const patch_mesh *m, const vec3 *radiance, const render_options *o, bool have_matrix,
                        point_to_polygon_fn point_to_polygon)
{
    *v = (radiosity_view){.opt = opt,
                          .stats = stats,
                          .scene = s,
                          .mesh = m,
                          .radiance = radiance,
                          .exposure = o->exposure,
                          .point_lights = o->bounce_min == 0,
                          .have_matrix = have_matrix,
                          .point_to_polygon = point_to_polygon};
}

vec3 radiosity_view_radiance(const void *view, const scene *s, ray r, rng *g, render_counters *counters)
{
    const radiosity_view *v = view;
    (void)g;
    (void)counters;
    bool back = false;
    vec3 L = patch_mesh_seen(v->mesh, s, r, v->radiance, v->opt->smooth, &back);
    if (back)
        warn_once(&warned_back,
                  "%s: the camera sees the back of a surface; patches are one-sided (front = right-hand rule), backs "
                  "render black",
                  v->opt->program);
    return L;
}

probe_result radiosity_view_probe(const void *view, const scene *s, const probe *pr, uint64_t seed,
                                  render_counters *counters)
{
    const radiosity_view *v = view;
    (void)seed;
    (void)counters;
    vec3 E =
        patch_mesh_irradiance(v->mesh, s, v->radiance, pr->position, pr->normal, v->point_lights, v->point_to_polygon);
    return (probe_result){.irradiance = E, .standard_error = v3_splat(0.0)};
}

int radiosity_view_write_output(const void *view, const scene *s, const char *path, char *err, size_t err_size)
{
    const radiosity_view *v = view;
    (void)s;
    return write_patch_ply(path, v->mesh, v->radiance, v->opt->smooth, v->exposure, v->opt->program, err, err_size);
}

void radiosity_view_write_stats(const void *view, FILE *json)
{
    const radiosity_view *v = view;
    write_radiosity_stats(json, v->opt, v->stats, v->scene, v->mesh, v->radiance, v->have_matrix);
}
