/* photon_stats.c — the stats members of a photon-mapping run (nothing here is the lecture). */
#include "photon_stats.h"

#include <stdlib.h>

#include "render.h"

void photon_run_write(FILE *json, const photon_run *run, const scene *s, bool keep_emission)
{
    fprintf(json, ",\n  \"maps\": \"%s\",\n  \"photons_per_pass\": %d,\n  \"gather\": %d,\n  \"nearest\": %d",
            run->maps, run->photons_per_pass, run->gather, run->nearest);
    json_field_number(json, "alpha", run->alpha);
    json_field_number(json, "photon_rays", (double)run->photon_rays);
    fprintf(json, ",\n  \"radius_per_pass\": [");
    for (int i = 0; i < run->tally->passes; i++)
        fprintf(json, "%s%.17g", i ? ", " : "", run->radius_per_pass[i]);
    fprintf(json, "],\n  \"emitted_power\": ");
    json_vec3(json, run->emitted_power);
    photon_tally_write(json, run->tally, s, keep_emission);
}

int photon_radius_record(double **radius_per_pass, int pass, double radius)
{
    double *radii = realloc(*radius_per_pass, (size_t)pass * sizeof *radii);
    if (!radii)
        return 2;
    *radius_per_pass = radii;
    radii[pass - 1] = radius;
    return 0;
}
