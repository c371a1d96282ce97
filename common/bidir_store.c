/* bidir_store.c — chapter 6's bookkeeping: options, light subpath storage,
 * warnings and stats (bidir_store.h). */
#include <float.h>
#include <stdlib.h>
#include <string.h>

#include "bidir_store.h"

static uint64_t dropped_paths, truncated_walks; /* all threads: rare, so atomic adds */
static int warned_truncation;

void note_dropped_path(void)
{
#pragma omp atomic
    dropped_paths++;
}

void note_truncated_walk(void)
{
#pragma omp atomic
    truncated_walks++;
    warn_once(&warned_truncation,
              "06_bidirectional: a subpath reached %d vertices and was cut there: paths longer than any strategy can "
              "make are missed (count in stats)",
              MAX_VERTICES);
}
static const char *const method_names[] = {"light", "bdpt", "vcm"};

/* --strategy S,T: 0 <= S, T <= MAX_VERTICES, a path of at least one edge. */
static int parse_strategy(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    bidir_state *st = state;
    char *end;
    long s = strtol(value, &end, 10), t = *end == ',' ? strtol(end + 1, &end, 10) : -1;
    (void)argv_index;
    if (*end || s < 0 || t < 0 || s > MAX_VERTICES || t > MAX_VERTICES || s + t < 2) {
        snprintf(why, why_size, "wants S,T with 0 <= S, T <= %d and S + T >= 2, not '%s'", MAX_VERTICES, value);
        return 2;
    }
    st->single_strategy = true;
    st->strategy_s = (int)s;
    st->strategy_t = (int)t;
    return 0;
}

#define STATE(field) offsetof(bidir_state, field)
const option BIDIR_OPTIONS[] = {
    {"--method", NULL, OPTION_CHOICE, STATE(method), .choices = "light|bdpt|vcm", .default_text = "vcm",
     .help = "light tracing (t = 1), bidirectional path tracing, or vertex connection and merging"},
    {"--merge", NULL, OPTION_CHOICE, STATE(merge_off), .choices = "on|off", .default_text = "on",
     .help = "vcm: merge at eye vertices (off: bdpt)"},
    {"--connect", NULL, OPTION_CHOICE, STATE(connect_off), .choices = "on|off", .default_text = "on",
     .help = "vcm: join subpaths (off: progressive photon mapping, chapter 5's --maps global)"},
    {"--strategy", "S,T", OPTION_CUSTOM, 0, .parse = parse_strategy,
     .help = "only strategy (S, T): S light and T eye vertices, unweighted (a path of S + T - 1 edges)"},
    {"--radius", "R", OPTION_DOUBLE, STATE(radius), .min = 0.0, .min_exclusive = true, .max = 1e300,
     .help = "first pass's merging radius (default: 1/200 of the scene's bounding-box diagonal, as chapter 5's)"},
    {"--alpha", "A", OPTION_DOUBLE, STATE(alpha), .min = 0.0, .min_exclusive = true, .max = 1.0,
     .default_text = "0.666667", .help = "radius shrink per pass (R12)"},
    {"--check", "N", OPTION_INT, STATE(check_paths), .min = 0, .max = 1 << 24, .default_text = "0",
     .help = "self-check on N random path pairs: weights add to 1, f / p (R13, R14) is what subpaths carry"},
    {"--probe-samples", "N", OPTION_INT, STATE(probe_samples), .min = PROBE_BATCHES, .max = 1 << 28,
     .default_text = "16384", .help = "samples per probe (a light subpath joined to an eye subpath from the probe)"},
    {"--surface-samples", "N", OPTION_INT, STATE(surface_samples), .min = 0, .max = 1 << 28, .default_text = "0",
     .help = "samples per surface for the stats key \"surfaces\" (0: off)"},
    {0},
};
#undef STATE

/* Room for `needed` items of `size` bytes in *items, reallocated to `grown` items when short: 0, or 2 when out of
 * memory (the array and its capacity then unchanged). */
static int reserve(void **items, size_t *capacity, size_t size, size_t needed, size_t grown)
{
    if (needed <= *capacity)
        return 0;
    void *p = realloc(*items, grown * size);
    if (!p)
        return 2;
    *items = p;
    *capacity = grown;
    return 0;
}

/* Append n items of `size` bytes to a growing array: 0, or 2 when out of memory. */
static int append(void **items, size_t *count, size_t *capacity, size_t size, const void *item, size_t n)
{
    if (reserve(items, capacity, size, *count + n, 2 * (*count + n) + 64))
        return 2;
    memcpy((char *)*items + *count * size, item, n * size);
    *count += n;
    return 0;
}

int chunk_add_vertices(chunk *c, const path_vertex *v, int n)
{
    bool in_slice = c->vertices != c->spill;
    if (in_slice && c->vertex_count + (size_t)n > c->vertex_capacity) { /* out of its slice: on in the spill */
        size_t needed = c->vertex_count + (size_t)n;
        if (reserve((void **)&c->spill, &c->spill_capacity, sizeof *v, needed, 2 * needed + 64))
            return 2;
        memcpy(c->spill, c->vertices, c->vertex_count * sizeof *v);
        c->vertices = c->spill;
        c->vertex_capacity = c->spill_capacity;
        in_slice = false;
    }
    int failed = append((void **)&c->vertices, &c->vertex_count, &c->vertex_capacity, sizeof *v, v, (size_t)n);
    if (!in_slice) { /* append may have moved it */
        c->spill = c->vertices;
        c->spill_capacity = c->vertex_capacity;
    }
    return failed;
}

int chunk_add_splat(chunk *c, int pixel, vec3 value)
{
    splat s = {pixel, value};
    return append((void **)&c->splats, &c->splat_count, &c->splat_capacity, sizeof s, &s, 1);
}

/* The photon grid over the pass's light vertices that merging can use: none on a light's own point (y_0) or on a
 * mirror or glass, which the chapter's merges() would pass over (fewer points to sort and to visit). */
static int index_mergeable(bidir_state *st, const chunk *chunks, int n)
{
    size_t total = 0, found = 0;
    for (int c = 0; c < n; c++)
        total += chunks[c].vertex_count;
    if (reserve((void **)&st->mergeable, &st->mergeable_capacity, sizeof *st->mergeable, total, 2 * total))
        return 2;
    for (int c = 0; c < n; c++)
        for (size_t i = (size_t)c * st->slice; i < (size_t)c * st->slice + chunks[c].vertex_count; i++)
            if (st->light_vertices[i].index > 0 && !st->light_vertices[i].specular)
                st->mergeable[found++] = (uint32_t)i;
    return photon_grid_rebuild(&st->grid, &st->light_vertices[0].x, sizeof *st->light_vertices, st->mergeable, found,
                               st->current_radius);
}

/* light_vertices with room for n slices of `slice` vertices: 0, or 2 when out of memory. */
static int reserve_slices(bidir_state *st, int n, size_t slice)
{
    size_t needed = (size_t)n * slice;
    if (reserve((void **)&st->light_vertices, &st->light_vertex_capacity, sizeof *st->light_vertices, needed, needed))
        return 2;
    st->slice = slice;
    return 0;
}

/* After a pass in which a chunk outgrew its slice: wider slices, every chunk's vertices moved into its own (the last
 * first: a chunk's new place may overlap the next one's old place, never the one before's). */
static int widen_slices(bidir_state *st, chunk *chunks, int n)
{
    size_t most = 0, old = st->slice;
    for (int c = 0; c < n; c++)
        most = chunks[c].vertex_count > most ? chunks[c].vertex_count : most;
    if (reserve_slices(st, n, most + most / 4 + MAX_VERTICES))
        return 2;
    for (int c = n - 1; c >= 0; c--) {
        const path_vertex *from =
            chunks[c].vertices == chunks[c].spill ? chunks[c].spill : st->light_vertices + (size_t)c * old;
        if (chunks[c].vertex_count > 0)
            memmove(st->light_vertices + (size_t)c * st->slice, from, chunks[c].vertex_count * sizeof *from);
    }
    return 0;
}

static int join_chunks(bidir_state *st, chunk *chunks, int n)
{
    bool spilled = false;
    for (int c = 0; c < n; c++)
        spilled |= chunks[c].vertices == chunks[c].spill;
    if (spilled && widen_slices(st, chunks, n))
        return 2;
    memset(st->light_image, 0, (size_t)st->light_paths * sizeof *st->light_image);
    for (int c = 0; c < n; c++) {
        for (int p = c * CHUNK; p < st->light_paths && p < (c + 1) * CHUNK; p++)
            st->path_first[p] += c * (int)st->slice;
        for (size_t i = 0; i < chunks[c].splat_count; i++)
            st->light_image[chunks[c].splats[i].pixel] =
                v3_add(st->light_image[chunks[c].splats[i].pixel], chunks[c].splats[i].value);
        st->light_rays += chunks[c].rays;
    }
    return st->merge ? index_mergeable(st, chunks, n) : 0;
}

static int chunk_count(const bidir_state *st) { return (st->light_paths + CHUNK - 1) / CHUNK; }

int light_pass(bidir_state *st, const scene *s, int pass, light_path_tracer *trace, char *err, size_t err_size)
{
    int n = chunk_count(st), failed = 0;
    if (!st->chunks)
        st->chunks = calloc((size_t)n, sizeof *st->chunks);
    chunk *chunks = st->chunks;
    bool needed = !(st->single_strategy && st->strategy_s == 0);      /* no strategy reads light subpaths */
    if (chunks && st->slice == 0 && reserve_slices(st, n, 8 * CHUNK)) /* 8 vertices a subpath: widened if not */
        chunks = NULL;
    for (int c = 0; chunks && c < n; c++) {
        chunks[c].vertices = st->light_vertices + (size_t)c * st->slice;
        chunks[c].vertex_capacity = st->slice;
        chunks[c].vertex_count = chunks[c].splat_count = 0;
        chunks[c].rays = 0;
    }
    if (chunks && needed && s->emitter_count + s->light_count > 0) {
#pragma omp parallel for schedule(dynamic, 1) reduction(| : failed)
        for (int c = 0; c < n; c++)
            for (int p = c * CHUNK; p < st->light_paths && p < (c + 1) * CHUNK; p++)
                failed |= trace(st, s, pass, p, &chunks[c]);
    }
    failed |= !chunks || join_chunks(st, chunks, n);
    if (!failed)
        return 0;
    snprintf(err, err_size, "argv:0: out of memory for the light subpaths of pass %d", pass);
    return 2;
}

static int allocate(bidir_state *st, const scene *s, int width, int height, double total, char *err, size_t err_size)
{
    camera_frame f = camera_frame_make(&s->camera, width, height);
    vec3 forward = v3_normalize(v3_sub(s->camera.look, s->camera.eye));
    st->camera = (pinhole){s->camera.eye, forward, f, v3_length(f.step_x) * v3_length(f.step_y), width, height};
    st->light_paths = width * height;
    st->light_probability = calloc((size_t)(s->surface_count + s->light_count) + 1, sizeof(double));
    st->path_first = calloc((size_t)st->light_paths, sizeof(int));
    st->path_count = calloc((size_t)st->light_paths, sizeof(int));
    st->light_image = calloc((size_t)st->light_paths, sizeof(vec3));
    if (!st->light_probability || !st->path_first || !st->path_count || !st->light_image) {
        snprintf(err, err_size, "argv:0: out of memory for %d light subpaths", st->light_paths);
        return 2;
    }
    for (int e = 0; e < s->emitter_count && total > 0.0; e++)
        st->light_probability[s->emitters[e]] =
            M_PI * v3_average(s->materials[s->surfaces[s->emitters[e]].material].emission) *
            s->surfaces[s->emitters[e]].area / total;
    for (int l = 0; l < s->light_count && total > 0.0; l++)
        st->light_probability[s->surface_count + l] = 4.0 * M_PI * v3_average(s->lights[l].intensity) / total;
    return 0;
}

int pick_light(const bidir_state *st, const scene *s, double u)
{
    int i = 0, lights = s->surface_count + s->light_count;
    for (; i < lights - 1 && u >= st->light_probability[i]; i++)
        u -= st->light_probability[i];
    return i;
}

int pixel_of_ray(const pinhole *c, vec3 w)
{
    int pixel = 0;
    double cos_theta;
    pixel_seen(c, w, &pixel, &cos_theta);
    return pixel;
}

bool pixel_seen(const pinhole *c, vec3 w, int *pixel, double *cos_theta)
{
    *cos_theta = v3_dot(w, c->forward);
    vec3 q = v3_sub(v3_scale(w, 1.0 / *cos_theta), c->frame.top_left);
    double px = v3_dot(q, c->frame.step_x) / v3_dot(c->frame.step_x, c->frame.step_x);
    double py = v3_dot(q, c->frame.step_y) / v3_dot(c->frame.step_y, c->frame.step_y);
    if (!(*cos_theta > 0.0 && px >= 0.0 && px < c->width && py >= 0.0 && py < c->height))
        return false;
    *pixel = (int)py * c->width + (int)px;
    return true;
}

bool pinhole_sensor_point(const pinhole *c, vec3 x, vec3 *sensor)
{
    double distance = v3_length(v3_sub(x, c->eye)), near = c->frame.near;
    if (near <= 0.0 || !(distance > near)) {
        *sensor = c->eye;
        return near <= 0.0;
    }
    *sensor = v3_add(c->eye, v3_scale(v3_sub(x, c->eye), near / distance));
    return true;
}

int bidir_join_step(path_vertex *x, const path_vertex *y, int s, const path_vertex *z, int t)
{
    if (s == 0) {
        for (int i = 0; i < t; i++)
            x[i] = z[t - 1 - i];
        return t - 1;
    }
    memmove(x + s, x + s - 1, (size_t)t * sizeof *x);
    x[s - 1] = y[s - 1];
    return s + t - 1;
}

int first_from_eye(const path_vertex *x, int k)
{
    int j = k - 1;
    while (j > 0 && x[j].specular)
        j--;
    return j;
}

void path_edges_of(const path_vertex *x, int k, path_edges *e)
{
    for (int i = 0; i < k; i++) {
        e->w[i] = v3_normalize(v3_sub(x[i + 1].x, x[i].x)); /* the chapter's unit(x_i, x_{i+1}), bit for bit */
        e->d[i] = v3_length(v3_sub(x[i + 1].x, x[i].x));
    }
}

/* What the options cannot render, said once (a pinhole is never hit: t = 0). */
static void warn_impossible(const bidir_state *st, const scene *s, specular_test *is_specular)
{
    bool specular = false;
    for (int i = 0; i < s->material_count; i++)
        specular |= is_specular(&s->materials[i]);
    if (st->single_strategy && st->strategy_t == 0)
        fprintf(stderr,
                "warning: 06_bidirectional: strategy (%d,0) needs light paths that hit the camera by chance, but "
                "the camera is a pinhole (its W_e is a delta in position): no light path does, the image is black\n",
                st->strategy_s);
    if (st->method == METHOD_LIGHT && specular && !st->single_strategy)
        fprintf(stderr, "warning: 06_bidirectional: light tracing joins light vertices to the pinhole camera (t = 1), "
                        "never through a mirror or glass (their f is a delta): what the camera sees in them is black "
                        "(--method bdpt or vcm render it)\n");
    if (!st->merge && !st->connect)
        fprintf(stderr, "warning: 06_bidirectional: --connect off without merging leaves no strategy: black\n");
    if (s->emitter_count + s->light_count == 0)
        fprintf(stderr, "warning: 06_bidirectional: the scene has no light: the image is black\n");
}

int bidir_prepare(void *state, const scene *s, const render_options *o, char *err, size_t err_size)
{
    bidir_state *st = state;
    st->bounces = bounce_window_of(o);
    st->seed = o->seed;
    st->scene = s;
    st->light_cap = st->bounces.last + 1 < MAX_VERTICES ? st->bounces.last + 1 : MAX_VERTICES;
    st->eye_cap = st->bounces.last + 2 < MAX_VERTICES ? st->bounces.last + 2 : MAX_VERTICES;
    st->merge = st->method == METHOD_VCM && !st->merge_off && !st->single_strategy;
    st->connect = !(st->method == METHOD_VCM && st->connect_off);
    if (allocate(st, s, o->width, o->height, st->total_light_power(s), err, err_size))
        return 2;
    /* The default radius is chapter 5's, 1/200 of the scene's diagonal at any image size: VCM merges only where
     * the eye sees a mirror or glass (the chapter's may_merge_at), so a radius that shrank with the pixels (as
     * before, to keep merging's weight against the joins on diffuse walls constant) only added noise there. */
    double r = st->radius > 0.0 ? st->radius : 0.005 * scene_diagonal(s);
    st->current_radius = r > 0.0 ? r : 1.0;
    warn_impossible(st, s, st->is_specular);
    for (int n = 0; n < st->check_paths && s->emitter_count + s->light_count > 0; n++) {
        rng g = rng_for(st->seed ^ 0x636865636bull, 0, (uint64_t)n);
        st->check(st, s, &g);
    }
    walk_source w = {st->sensor, st, s, bounces_keep(st->bounces, 0)};
    return st->surface_samples == 0
               ? 0
               : walk_surface_averages(&w, st->seed ^ 0x73757266616365ull, st->surface_samples, &st->surface_averages,
                                       &st->surface_average_count, &st->surface_rays, err, err_size);
}

/* An error that is not a number is as large as can be: DBL_MAX, which the JSON can still hold. */
static double worse(double worst, double error) { return fmax(worst, isfinite(error) ? error : DBL_MAX); }

void bidir_check_record(bidir_state *st, double weight_sum, double value, double density, double integrand)
{
    st->check_worst_sum = worse(st->check_worst_sum, fabs(weight_sum - 1.0));
    st->check_connections++;
    if (value < 0.0)
        return;
    if (!isnormal(density) || !isnormal(integrand)) {
        st->check_out_of_range++;
        return;
    }
    /* In logarithms: value * density / integrand would overflow or underflow where the quotient does not. */
    st->check_worst_ratio = worse(st->check_worst_ratio, fabs(exp(log(value) + log(density) - log(integrand)) - 1.0));
}

probe_result bidir_probe(const void *state, const scene *s, const probe *p, uint64_t seed, render_counters *counters)
{
    const bidir_state *st = state;
    walk_source w = {st->sensor, st, s, false};
    return walk_probe(&w, p, probe_seed(seed), st->probe_samples, &counters->value[COUNT_PROBE_RAYS]);
}

void bidir_write_stats(const void *state, FILE *json)
{
    const bidir_state *st = state;
    fprintf(json, ",\n  \"method\": \"%s\",\n  \"merge\": %s,\n  \"connect\": %s", method_names[st->method],
            st->merge ? "true" : "false", st->connect ? "true" : "false");
    if (st->single_strategy)
        fprintf(json, ",\n  \"strategy\": [%d, %d]", st->strategy_s, st->strategy_t);
    json_field_number(json, "light_paths_per_pass", st->light_paths);
    json_field_number(json, "light_rays", (double)st->light_rays);
    json_field_number(json, "dropped_paths", (double)dropped_paths);
    json_field_number(json, "truncated_paths", (double)truncated_walks);
    json_field_number(json, "alpha", st->alpha);
    json_field_number(json, "last_radius", st->current_radius);
    json_field_number(json, "probe_samples", st->probe_samples);
    json_field_number(json, "surface_samples", st->surface_samples);
    json_field_number(json, "surface_rays", (double)st->surface_rays);
    json_surface_averages(json, st->scene, st->surface_averages, st->surface_average_count);
    if (st->check_paths > 0) {
        fprintf(json, ",\n  \"check\": {\"paths\": %d, \"connections\": %ld, \"out_of_range\": %ld", st->check_paths,
                st->check_connections, st->check_out_of_range);
        fprintf(json, ", \"worst_weight_sum_error\": %.17g, \"worst_f_over_p_error\": %.17g}", st->check_worst_sum,
                st->check_worst_ratio);
    }
}

void bidir_finish(void *state)
{
    bidir_state *st = state;
    photon_grid_free(&st->grid);
    free(st->light_probability);
    free(st->path_first);
    free(st->path_count);
    free(st->light_image);
    for (int c = 0; st->chunks && c < chunk_count(st); c++) {
        free(st->chunks[c].spill);
        free(st->chunks[c].splats);
    }
    free(st->chunks);
    free(st->light_vertices);
    free(st->surface_averages);
    free(st->mergeable);
    st->chunks = NULL;
    st->mergeable = NULL;
    st->surface_averages = NULL;
    st->light_probability = NULL;
    st->light_vertices = NULL;
    st->light_image = NULL;
    st->path_first = st->path_count = NULL;
}
