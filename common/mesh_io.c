/* mesh_io.c — radiosity's PLY, form-factor table and surface stats (see mesh_io.h). */
#include "mesh_io.h"

#include <math.h>
#include <stdlib.h>

#include "image.h"
#include "render.h"

int write_patch_ply(const char *path, const patch_mesh *m, const vec3 *radiance, bool smooth, double exposure,
                    const char *program, char *err, size_t err_size)
{
    if (!path_has_extension(path, ".ply"))
        return 0;
    atomic_file out;
    if (atomic_file_open(&out, path, err, err_size))
        return 2;
    FILE *f = out.file;
    int corners = 0;
    for (int p = 0; p < m->patch_count; p++)
        corners += m->patches[p].corner_count;
    int vertices = smooth ? m->vertex_count : corners;
    fprintf(f,
            "ply\nformat ascii 1.0\ncomment %s: radiance per vertex (%s shading)\n"
            "element vertex %d\nproperty float x\nproperty float y\nproperty float z\n"
            "property float radiance_r\nproperty float radiance_g\nproperty float radiance_b\n"
            "property uchar red\nproperty uchar green\nproperty uchar blue\n"
            "element face %d\nproperty list uchar int vertex_indices\nend_header\n",
            program, smooth ? "smooth" : "flat", vertices, m->patch_count);
    for (int v = 0; v < vertices; v++) {
        vec3 p, L;
        if (smooth) {
            p = m->vertices[v], L = m->vertex_radiance[v];
        } else {
            int patch_index = 0, k = v;
            while (k >= m->patches[patch_index].corner_count)
                k -= m->patches[patch_index++].corner_count;
            p = m->patches[patch_index].corner[k], L = radiance[patch_index];
        }
        fprintf(f, "%.9g %.9g %.9g %.9g %.9g %.9g %u %u %u\n", p.x, p.y, p.z, L.x, L.y, L.z,
                tonemap_srgb8(L.x, exposure), tonemap_srgb8(L.y, exposure), tonemap_srgb8(L.z, exposure));
    }
    int next = 0;
    for (int p = 0; p < m->patch_count; p++) {
        const mesh_cell *c = &m->cells[m->patches[p].cell];
        fprintf(f, "%d", c->vertex_count);
        for (int k = 0; k < c->vertex_count; k++)
            fprintf(f, " %d", smooth ? c->vertex[k] : next++);
        fputc('\n', f);
    }
    return atomic_file_commit(&out, 0, err, err_size) ? 2 : 1;
}

int write_surface_form_factors(const char *path, const scene *s, const patch_mesh *mesh, form_factor_fn form_factor,
                               const void *context, uint64_t *rays_out, char *err, size_t err_size)
{
    if (!path)
        return 0;
    int m = s->surface_count, n = mesh->patch_count;
    const patch *patches = mesh->patches;
    double *sums = calloc((size_t)m * (size_t)m + 1, sizeof *sums);
    if (!sums) {
        snprintf(err, err_size, "argv:0: out of memory");
        return 2;
    }
    uint64_t rays = 0;
#pragma omp parallel reduction(+ : rays)
    {
        double *local = calloc((size_t)m * (size_t)m + 1, sizeof *local);
#pragma omp for schedule(dynamic, 8)
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++) {
                double f = form_factor(context, i, j, &rays);
                if (local)
                    local[patches[i].surface * m + patches[j].surface] += patches[i].area * f;
            }
#pragma omp critical
        for (int k = 0; local && k < m * m; k++)
            sums[k] += local[k];
        free(local);
    }
    *rays_out += rays;
    double *area = calloc((size_t)m + 1, sizeof *area);
    for (int i = 0; area && i < n; i++)
        area[patches[i].surface] += patches[i].area;
    atomic_file out;
    int status = 2;
    if (area && atomic_file_open(&out, path, err, err_size) == 0) {
        FILE *f = out.file;
        fprintf(f, "from,to,F\n");
        for (int a = 0; a < m; a++)
            for (int b = 0; b < m; b++)
                if (area[a] > 0.0 && area[b] > 0.0)
                    fprintf(f, "%s,%s,%.10g\n", s->surfaces[a].name, s->surfaces[b].name, sums[a * m + b] / area[a]);
        status = atomic_file_commit(&out, 0, err, err_size);
    } else if (!area) {
        snprintf(err, err_size, "argv:0: out of memory");
    }
    free(area);
    free(sums);
    return status;
}

void form_factor_checks(const float *F, const patch_mesh *m, double *reciprocity_error, double *row_sum_min,
                        double *row_sum_max)
{
    size_t n = (size_t)m->patch_count;
    double asymmetric = 0.0, symmetric = 0.0, row_min = INFINITY, row_max = 0.0;
#pragma omp parallel for schedule(dynamic, 8) reduction(+ : asymmetric, symmetric) reduction(min : row_min) \
    reduction(max : row_max)
    for (int i = 0; i < (int)n; i++) {
        double row = 0.0;
        for (size_t j = 0; j < n; j++) {
            double fij = F[(size_t)i * n + j], fji = F[j * n + (size_t)i];
            row += fij;
            if (j > (size_t)i) {
                double gij = m->patches[i].area * fij, gji = m->patches[j].area * fji;
                asymmetric += fabs(gij - gji);
                symmetric += 0.5 * (gij + gji);
            }
        }
        row_min = fmin(row_min, row), row_max = fmax(row_max, row);
    }
    *reciprocity_error = symmetric > 0.0 ? asymmetric / symmetric : 0.0;
    *row_sum_min = row_min, *row_sum_max = row_max;
}

void json_surface_radiance(FILE *json, const scene *s, const patch_mesh *m, const vec3 *radiance)
{
    fprintf(json, ",\n  \"surfaces\": [");
    int written = 0;
    for (int surface_index = 0; radiance && surface_index < s->surface_count; surface_index++) {
        double area = 0.0;
        vec3 sum = v3_splat(0.0);
        for (int p = 0; p < m->patch_count; p++)
            if (m->patches[p].surface == surface_index) {
                area += m->patches[p].area;
                sum = v3_madd(sum, radiance[p], m->patches[p].area);
            }
        if (area <= 0.0)
            continue;
        fprintf(json, "%s\n    {\"name\": ", written++ ? "," : "");
        json_string(json, s->surfaces[surface_index].name);
        fprintf(json, ", \"area\": ");
        json_number(json, area);
        fprintf(json, ", \"radiance\": ");
        json_vec3(json, v3_scale(sum, 1.0 / area));
        fputc('}', json);
    }
    fprintf(json, "%s]", written ? "\n  " : "");
}
