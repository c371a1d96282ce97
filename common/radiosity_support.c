/* radiosity_support.c — chapter 3's options and statistics (see radiosity_support.h). */
#include "radiosity_support.h"

#include <stdlib.h>
#include <string.h>

#include "mesh_io.h"
#include "render.h"

const char *const solver_names[4] = {"jacobi", "gauss-seidel", "shooting", "direct"};

const char radiosity_options_help[] =
    "  --patch-size S         target patch edge in scene units (default 50, for the Cornell box in mm)\n"
    "  --adaptive             refine patches where the radiance changes fast (shadow edges)\n"
    "  --adaptive-levels N    refinement rounds, each splitting patches in four (default 2)\n"
    "  --adaptive-threshold T split where a patch and the mean of its corners differ by T x the mean radiance (default 0.1)\n"
    "  --solver NAME          jacobi | gauss-seidel | shooting | direct (default jacobi)\n"
    "  --tol T                stop when the residual falls below T (fraction of source power; default 1e-4)\n"
    "  --iterations N         at most N iterations (shooting: N x patches shots; default 1000)\n"
    "  --max-patches N        refuse matrix solvers above N patches (default 16384: 2 GiB of doubles)\n"
    "  --quadrature M         M x M points per patch triangle for near form factors (default 4)\n"
    "  --reciprocity check|enforce  report A_i F_ij vs A_j F_ji, or average them (default check)\n"
    "  --shading flat|smooth  patch colours, or interpolated vertex radiance (default flat)\n"
    "  --smooth               same as --shading smooth\n"
    "  --formfactors FILE.csv write surface-to-surface form factors (from,to,F)\n"
    "  --out FILE.ply         also write the mesh with per-vertex radiance (PLY)\n";

int radiosity_parse_option(void *state_pointer, int argc, char **argv, int *i, char *err, size_t err_size)
{
    radiosity_options *st = state_pointer;
    const char *a = argv[*i];
    if (!strcmp(a, "--patch-size")) {
        st->patch_size_argv = *i;
        int status = parse_double_option(argc, argv, i, -1e300, 1e300, &st->patch_size, err, err_size);
        if (status == 1 && !(st->patch_size > 0.0)) {
            snprintf(err, err_size, "argv:%d: --patch-size must be positive (scene units), not '%s'", *i, argv[*i]);
            return 2;
        }
        return status;
    }
    if (!strcmp(a, "--adaptive")) {
        st->adaptive = true;
        return 1;
    }
    if (!strcmp(a, "--adaptive-levels")) {
        st->adaptive = true;
        return parse_int_option(argc, argv, i, 1, 8, &st->adaptive_levels, err, err_size);
    }
    if (!strcmp(a, "--adaptive-threshold"))
        return parse_double_option(argc, argv, i, 1e-6, 1e6, &st->adaptive_threshold, err, err_size);
    if (!strcmp(a, "--solver") || !strcmp(a, "--shading") || !strcmp(a, "--reciprocity")) {
        const char *v = *i + 1 < argc ? argv[++*i] : "";
        if (!strcmp(a, "--solver")) {
            for (int k = 0; k < 4; k++)
                if (!strcmp(v, solver_names[k])) {
                    st->solver = (solver_kind)k;
                    return 1;
                }
            snprintf(err, err_size, "argv:%d: --solver wants jacobi, gauss-seidel, shooting or direct, not '%s'", *i, v);
        } else if (!strcmp(a, "--shading")) {
            if (!strcmp(v, "flat") || !strcmp(v, "smooth")) {
                st->smooth = !strcmp(v, "smooth");
                return 1;
            }
            snprintf(err, err_size, "argv:%d: --shading wants flat or smooth, not '%s'", *i, v);
        } else {
            if (!strcmp(v, "check") || !strcmp(v, "enforce")) {
                st->enforce_reciprocity = !strcmp(v, "enforce");
                return 1;
            }
            snprintf(err, err_size, "argv:%d: --reciprocity wants check or enforce, not '%s'", *i, v);
        }
        return 2;
    }
    if (!strcmp(a, "--smooth")) {
        st->smooth = true;
        return 1;
    }
    if (!strcmp(a, "--tol"))
        return parse_double_option(argc, argv, i, 0.0, 1.0, &st->tolerance, err, err_size);
    if (!strcmp(a, "--iterations"))
        return parse_int_option(argc, argv, i, 1, 100000000, &st->max_iterations, err, err_size);
    if (!strcmp(a, "--max-patches"))
        return parse_int_option(argc, argv, i, 1, 1 << 30, &st->max_patches, err, err_size);
    if (!strcmp(a, "--quadrature"))
        return parse_int_option(argc, argv, i, 1, 16, &st->quadrature, err, err_size);
    if (!strcmp(a, "--formfactors")) {
        if (*i + 1 >= argc) {
            snprintf(err, err_size, "argv:%d: --formfactors needs a file name", *i);
            return 2;
        }
        st->formfactors_path = argv[++*i];
        return 1;
    }
    return 0;
}

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
    fprintf(json, ",\n  \"solver\": \"%s\",\n  \"solver_used\": \"%s\",\n  \"patch_size\": ", solver_names[o->solver],
            r->solver_used ? r->solver_used : "none");
    json_number(json, o->patch_size);
    fprintf(json, ",\n  \"patches\": %d,\n  \"refinements\": %d,\n  \"iterations\": %d,\n  \"shots\": %d",
            patches, r->refinements, r->iterations, r->shots);
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
    if (r->have_matrix_checks) {
        json_field_number(json, "reciprocity_error", r->reciprocity_error);
        json_field_number(json, "row_sum_min", r->row_sum_min);
        json_field_number(json, "row_sum_max", r->row_sum_max);
    }
    fprintf(json, ",\n  \"matrix_bytes\": %.0f", have_matrix ? (double)patches * patches * 4.0 : 0.0);
    json_surface_radiance(json, s, m, radiance);
}

void radiosity_report(const radiosity_options *o, const radiosity_stats *r, int patches, bool quiet)
{
    if (r->no_light)
        fprintf(stderr, "03_radiosity: nothing in the scene emits light (no emitter, no point light): "
                        "the solution is zero and the image black\n");
    else if (!r->converged)
        fprintf(stderr, "03_radiosity: %s stopped at the iteration cap (%d iterations) with residual %.3g "
                        "above --tol %.3g; raise --iterations\n", r->solver_used, r->iterations, r->residual,
                o->tolerance);
    if (!quiet)
        fprintf(stderr, "03_radiosity: %d patches, form factors %.2f s, %s %d iterations %.2f s, residual %.3g\n",
                patches, r->formfactor_s, r->solver_used, r->iterations, r->solve_s, r->residual);
}

enum { MESH_CELL_LIMIT = 4000000 }; /* beyond this even shooting would take hours */

static int check_mesh_size(const radiosity_options *o, double cells, char *err, size_t err_size)
{
    if (!(cells > MESH_CELL_LIMIT))
        return 0;
    snprintf(err, err_size, "argv:%d: --patch-size %g gives about %.3g patches, more than this chapter meshes (%d)",
             o->patch_size_argv, o->patch_size, cells, MESH_CELL_LIMIT);
    return 2;
}

int radiosity_check_matrix_size(const radiosity_options *o, int n, char *err, size_t err_size)
{
    if (o->solver == SOLVER_SHOOTING || n <= o->max_patches)
        return 0;
    snprintf(err, err_size, "argv:0: %d patches need a %d x %d matrix (%.2f GiB as doubles), over the limit "
             "--max-patches %d (2 GiB); use --solver shooting, a larger --patch-size, or raise --max-patches",
             n, n, n, (double)n * n * 8.0 / 1073741824.0, o->max_patches);
    return 2;
}

static int warned_specular, warned_phong, warned_spheres;

int radiosity_mesh_scene(patch_mesh *m, const scene *s, const radiosity_options *o, char *err, size_t err_size)
{
    if (check_mesh_size(o, patch_mesh_estimate(s, o->patch_size), err, err_size))
        return 2;
    for (int i = 0; i < s->surface_count; i++)
        if (s->surfaces[i].kind == SURFACE_SPHERE)
            warn_once(&warned_spheres, "03_radiosity: spheres are not meshed into patches; they block light "
                                       "but carry no radiance (black in the image)");
    if (patch_mesh_build(m, s, o->patch_size)) {
        snprintf(err, err_size, "argv:0: out of memory while meshing");
        return 2;
    }
    return radiosity_collect_patches(m, s, o, err, err_size);
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
        p->albedo = m->albedo;
        p->emission = m->kind == MATERIAL_EMITTER ? m->emission : v3_splat(0.0);
        if (m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS) {
            warn_once(&warned_specular, "03_radiosity: radiosity models diffuse reflection only; mirrors and glass "
                                        "are treated as diffuse surfaces with their colour as albedo");
            p->albedo = m->specular;
        } else if (m->kind == MATERIAL_PHONG) {
            warn_once(&warned_phong, "03_radiosity: Phong surfaces are treated as diffuse with albedo kd (ks dropped)");
        }
    }
    return 0;
}

int radiosity_refine(patch_mesh *m, const scene *s, const radiosity_options *o, radiosity_stats *r,
                     const vec3 *radiance, bool quiet, char *err, size_t err_size)
{
    if (!o->adaptive || r->refinements == o->adaptive_levels || r->no_light)
        return 0;
    int split = patch_mesh_refine(m, radiance, o->adaptive_threshold);
    if (split < 0)
        snprintf(err, err_size, "argv:0: out of memory while refining the mesh");
    if (split <= 0)
        return split;
    r->refinements++;
    if (!quiet)
        fprintf(stderr, "03_radiosity: refinement %d split %d of %d patches\n", r->refinements, split, m->patch_count);
    return radiosity_collect_patches(m, s, o, err, err_size) ? -1 : split;
}
