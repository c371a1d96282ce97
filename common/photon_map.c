/* photon_map.c — storage and statistics of chapter 5's photons. */
#include "photon_map.h"

#include <stdlib.h>

#include "render.h"

int photon_map_add(photon_map *map, const photon *p)
{
    if (map->count == map->capacity) {
        size_t capacity = 2 * map->capacity + 256;
        photon *grown = realloc(map->photons, capacity * sizeof *grown);
        if (!grown)
            return 2;
        map->photons = grown, map->capacity = capacity;
    }
    map->photons[map->count++] = *p;
    return 0;
}

int photon_map_index(photon_map *map, double radius)
{
    photon_grid_free(&map->grid);
    static const photon none;
    const photon *first = map->count ? map->photons : &none;
    return photon_grid_build(&map->grid, &first->position, sizeof(photon), map->count, radius);
}

void photon_map_free(photon_map *map)
{
    photon_grid_free(&map->grid);
    free(map->photons);
    *map = (photon_map){0};
}

int photon_maps_merge(photon_map *lists, int n, photon_map *global, photon_map *caustic)
{
    int failed = 0;
    global->count = caustic->count = 0;
    for (int c = 0; c < n; c++) {
        for (size_t i = 0; i < lists[c].count && !failed; i++) {
            const photon *p = &lists[c].photons[i];
            failed = photon_map_add(global, p) || (p->caustic && photon_map_add(caustic, p));
        }
        free(lists[c].photons);
        lists[c] = (photon_map){0};
    }
    return failed ? 2 : 0;
}

void photon_tally_add(photon_tally *t, const photon_map *global, int bounce_min, int bounce_max)
{
    const bounce_window window = {.first = bounce_min, .last = bounce_max};
    for (size_t i = 0; i < global->count; i++) {
        const photon *p = &global->photons[i];
        size_t b = p->path % PROBE_BATCHES;
        t->global[b] = v3_add(t->global[b], p->power);
        if (p->caustic)
            t->caustic[b] = v3_add(t->caustic[b], p->power), t->stored_caustic++;
        /* reflected there, its light is the term K^(bounces + 1) E */
        if (p->front && bounces_keep(window, p->bounces + 1))
            t->surface[(size_t)p->surface * PROBE_BATCHES + b] =
                v3_add(t->surface[(size_t)p->surface * PROBE_BATCHES + b], p->power);
    }
    t->stored_global += global->count;
    t->passes++;
}

/* A batch holds 1/PROBE_BATCHES of the photons: times PROBE_BATCHES, per pass. */
static probe_result batch_estimate(const vec3 *batch, int passes, vec3 factor, vec3 offset)
{
    vec3 scaled[PROBE_BATCHES];
    for (int b = 0; b < PROBE_BATCHES; b++)
        scaled[b] = v3_add(offset, v3_mul(factor, v3_scale(batch[b], (double)PROBE_BATCHES / (passes ? passes : 1))));
    return batch_mean_and_error(scaled, PROBE_BATCHES);
}

static void write_estimate(FILE *json, const char *key, const char *error_key, probe_result r)
{
    fprintf(json, "\"%s\": ", key);
    json_vec3(json, r.irradiance);
    fprintf(json, ", \"%s\": ", error_key);
    json_vec3(json, r.standard_error);
}

void photon_tally_write(FILE *json, const photon_tally *t, const scene *s, bool keep_emission)
{
    fprintf(json, ",\n  \"photons_stored\": {\"global\": %llu, \"caustic\": %llu}",
            (unsigned long long)t->stored_global, (unsigned long long)t->stored_caustic);
    fprintf(json, ",\n  \"stored_power\": {");
    write_estimate(json, "global", "global_standard_error",
                   batch_estimate(t->global, t->passes, v3_splat(1.0), v3_splat(0.0)));
    fputs(", ", json);
    write_estimate(json, "caustic", "caustic_standard_error",
                   batch_estimate(t->caustic, t->passes, v3_splat(1.0), v3_splat(0.0)));
    fprintf(json, "},\n  \"surfaces\": [");
    int written = 0;
    for (int i = 0; i < s->surface_count && t->surface; i++) {
        const material *m = &s->materials[s->surfaces[i].material];
        if (m->kind != MATERIAL_DIFFUSE && m->kind != MATERIAL_EMITTER)
            continue;
        vec3 emitted = m->kind == MATERIAL_EMITTER && keep_emission ? m->emission : v3_splat(0.0);
        probe_result r = batch_estimate(t->surface + (size_t)i * PROBE_BATCHES, t->passes,
                                        v3_scale(m->albedo, 1.0 / (M_PI * s->surfaces[i].area)), emitted);
        fprintf(json, "%s\n    {\"name\": ", written++ ? "," : "");
        json_string(json, s->surfaces[i].name);
        fprintf(json, ", \"area\": ");
        json_number(json, s->surfaces[i].area);
        fprintf(json, ", ");
        write_estimate(json, "radiance", "standard_error", r);
        fputc('}', json);
    }
    fprintf(json, "%s]", written ? "\n  " : "");
}
