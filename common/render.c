/* render.c — command line, pixel loop, progressive passes, statistics. */
#include "render.h"

#include <errno.h>
#include <limits.h>
#include <signal.h>
#include <omp.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <sys/stat.h>
#include <unistd.h>

enum { ERROR_SIZE = 2048 };

static double now_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

void warn_once(int *flag, const char *format, ...)
{
    int already;
#pragma omp atomic capture
    already = (*flag)++;
    if (already)
        return;
    va_list args;
    va_start(args, format);
    fputs("warning: ", stderr);
    vfprintf(stderr, format, args);
    fputc('\n', stderr);
    va_end(args);
}

probe_result batch_mean_and_error(const vec3 *batch, int count)
{
    vec3 sum = v3_splat(0.0), sum_squares = v3_splat(0.0);
    for (int b = 0; b < count; b++) {
        sum = v3_add(sum, batch[b]);
        sum_squares = v3_add(sum_squares, v3_mul(batch[b], batch[b]));
    }
    vec3 mean = v3_scale(sum, 1.0 / count);
    vec3 variance = v3_sub(v3_scale(sum_squares, 1.0 / count), v3_mul(mean, mean));
    vec3 standard_error = v3(sqrt(fmax(0.0, variance.x) / (count - 1)), sqrt(fmax(0.0, variance.y) / (count - 1)),
                             sqrt(fmax(0.0, variance.z) / (count - 1)));
    return (probe_result){.irradiance = mean, .standard_error = standard_error};
}

/* --- JSON ---------------------------------------------------------------------- */

void json_string(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            fprintf(f, "\\%c", c);
        else if (c < 0x20)
            fprintf(f, "\\u%04x", c);
        else
            fputc(c, f);
    }
    fputc('"', f);
}

void json_number(FILE *f, double v)
{
    if (isfinite(v))
        fprintf(f, "%.17g", v);
    else
        fputs("null", f);
}

void json_field_number(FILE *f, const char *key, double v)
{
    fprintf(f, ",\n  \"%s\": ", key);
    json_number(f, v);
}

void json_vec3(FILE *f, vec3 v)
{
    fputc('[', f);
    json_number(f, v.x);
    fputs(", ", f);
    json_number(f, v.y);
    fputs(", ", f);
    json_number(f, v.z);
    fputc(']', f);
}

/* --- command line ---------------------------------------------------------------- */

/* The options every chapter shares (README's option lists), one row each. */
static int parse_out(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    render_options *o = state;
    if (o->output_count == RENDER_MAX_OUTPUTS) {
        snprintf(why, why_size, "may be given at most %d times", RENDER_MAX_OUTPUTS);
        return 2;
    }
    o->output_argv[o->output_count] = argv_index;
    o->outputs[o->output_count++] = value;
    return 0;
}

static int parse_size(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    render_options *o = state;
    char *end;
    long w = strtol(value, &end, 10), h = 0;
    o->size_argv = argv_index;
    if (*end == 'x' || *end == 'X')
        h = strtol(end + 1, &end, 10);
    if (*end || w < 1 || h < 1 || w > 16384 || h > 16384) {
        snprintf(why, why_size, "wants WxH with 1 <= W, H <= 16384, not '%s'", value);
        return 2;
    }
    o->width = (int)w, o->height = (int)h;
    return 0;
}

static int parse_seed(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    char *end;
    errno = 0;
    long seed = strtol(value, &end, 10);
    (void)argv_index;
    if (errno || end == value || *end || seed < 0 || seed > INT_MAX) {
        snprintf(why, why_size, "wants a whole number in [0, %d], not '%s'", INT_MAX, value);
        return 2;
    }
    ((render_options *)state)->seed = (uint64_t)seed;
    return 0;
}

/* --eye, --look, --up: X,Y,Z into *p, and `given` into camera_override. */
static int parse_camera_point(void *state, int given, vec3 *p, const char *value, int argv_index, char *why,
                              size_t why_size)
{
    render_options *o = state;
    char tail;
    o->camera_argv = argv_index;
    o->camera_override |= given;
    if (sscanf(value, "%lf,%lf,%lf%c", &p->x, &p->y, &p->z, &tail) != 3 || !v3_is_finite(*p)) {
        snprintf(why, why_size, "wants X,Y,Z (three numbers, commas, no spaces), not '%s'", value);
        return 2;
    }
    return 0;
}
static int parse_eye(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    vec3 *eye = &((render_options *)state)->camera_eye;
    return parse_camera_point(state, CAMERA_EYE, eye, value, argv_index, why, why_size);
}
static int parse_look(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    vec3 *look = &((render_options *)state)->camera_look;
    return parse_camera_point(state, CAMERA_LOOK, look, value, argv_index, why, why_size);
}
static int parse_up(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    vec3 *up = &((render_options *)state)->camera_up;
    return parse_camera_point(state, CAMERA_UP, up, value, argv_index, why, why_size);
}

/* --bounces A:B, A: or A (R6). */
static int parse_bounces(void *state, const char *value, int argv_index, char *why, size_t why_size)
{
    render_options *o = state;
    char *end;
    long a = strtol(value, &end, 10), b = a;
    bool ok = end != value && a >= 0;
    (void)argv_index;
    if (ok && *end == ':') {
        const char *rest = end + 1;
        if (*rest == '\0')
            b = RENDER_BOUNCES_UNLIMITED;
        else {
            b = strtol(rest, &end, 10);
            ok = end != rest && !*end;
        }
    } else if (*end)
        ok = false;
    if (!ok || b < a || b > RENDER_BOUNCES_UNLIMITED) {
        snprintf(why, why_size, "wants A:B, A: or A with 0 <= A <= B, not '%s'", value);
        return 2;
    }
    o->bounce_min = (int)a, o->bounce_max = (int)b, o->bounces_given = true;
    return 0;
}

#define DRIVER(field) offsetof(render_options, field)
static const option DRIVER_OPTIONS[] = {
    {"--out", "FILE", OPTION_CUSTOM, 0, .parse = parse_out,
     .help = "write the image: .pfm linear radiance, .png tone-mapped sRGB; may be given several times; "
             "default out/<scene>-<chapter>.png"},
    {"--size", "WxH", OPTION_CUSTOM, 0, .parse = parse_size,
     .help = "image size; default: the scene's `image` statement"},
    {"--spp", "N", OPTION_INT, DRIVER(spp), .min = 1, .max = 1 << 24,
     .help = "samples per pixel; a cap when --time is given"},
    {"--time", "SECONDS", OPTION_DOUBLE, DRIVER(time_budget), .min = 1e-3, .max = 1e6,
     .help = "render progressive passes until the budget is spent"},
    {"--seed", "N", OPTION_CUSTOM, 0, .parse = parse_seed, .default_text = "1",
     .help = "random seed; the image depends only on it, not on --threads"},
    {"--threads", "N", OPTION_INT, DRIVER(threads), .min = 1, .max = 1024,
     .help = "OpenMP threads; default: all cores"},
    {"--ref", "REF.pfm", OPTION_STRING, DRIVER(reference_path),
     .help = "print error metrics against a reference: RMSE; relative MSE, the mean of (t - r)^2 / (r^2 + 0.01); "
             "PSNR of the displayed image (clamped to [0, 1], sRGB; peak 1); SSIM of its luminance"},
    {"--stats", "FILE.json", OPTION_STRING, DRIVER(stats_path), .help = "write statistics as one JSON object"},
    {"--bounces", "A:B", OPTION_CUSTOM, 0, .parse = parse_bounces,
     .default_text = "0:", .help = "keep only the Neumann terms K^A E .. K^B E (R6); 'A:' = A and up"},
    {"--exposure", "STOPS", OPTION_DOUBLE, DRIVER(exposure), .min = -64, .max = 64, .default_text = "0",
     .help = "PNG exposure in stops"},
    {"--eye", "X,Y,Z", OPTION_CUSTOM, 0, .parse = parse_eye, .help = "camera position (overrides the scene's)"},
    {"--look", "X,Y,Z", OPTION_CUSTOM, 0, .parse = parse_look, .help = "the point the camera looks at"},
    {"--up", "X,Y,Z", OPTION_CUSTOM, 0, .parse = parse_up, .help = "the camera's up direction"},
    {"--fov", "DEG", OPTION_DOUBLE, DRIVER(camera_fov), .min = 1e-3, .max = 179.0,
     .help = "vertical field of view in degrees"},
    {"--quiet", NULL, OPTION_FLAG, DRIVER(quiet), .help = "no progress bar"},
    {0},
};
#undef DRIVER

static void print_help(const chapter *ch, const char *program)
{
    printf("%s — %s\n\n"
           "usage: %s [scene] [options]\n\n"
           "  %-24s %s\n"
           "  %-24s %s\n",
           ch->name, ch->description, program, "scene", "a .scene file (default scenes/cornell.scene)", "--help",
           "this text");
    /* The default of --spp is the chapter's: shown here, applied after parsing. */
    option driver[sizeof DRIVER_OPTIONS / sizeof DRIVER_OPTIONS[0]];
    char default_spp[16];
    snprintf(default_spp, sizeof default_spp, "%d", ch->default_spp);
    memcpy(driver, DRIVER_OPTIONS, sizeof driver);
    for (option *row = driver; row->name; row++)
        if (!strcmp(row->name, "--spp"))
            row->default_text = default_spp;
    options_print_help(stdout, driver);
    printf("\n%s options:\n", ch->name);
    for (int g = 0; g < OPTION_MAX_GROUPS && ch->options[g].table; g++)
        options_print_help(stdout, ch->options[g].table);
}

static int parse_command_line(int argc, char **argv, const chapter *ch, render_options *o, bool *help, char *err,
                              size_t err_size)
{
    *o = (render_options){0};
    option_group groups[OPTION_MAX_GROUPS + 1] = {{DRIVER_OPTIONS, o}};
    int group_count = 1;
    while (group_count <= OPTION_MAX_GROUPS && ch->options[group_count - 1].table) {
        groups[group_count] = ch->options[group_count - 1];
        group_count++;
    }
    if (options_set_defaults(groups, group_count, err, err_size))
        return 2;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        int status;
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
            *help = true;
            return 0;
        } else if ((status = options_parse_one(groups, group_count, argc, argv, &i, err, err_size)) != 0) {
            if (status != 1)
                return status;
        } else if (a[0] == '-' && a[1] != '\0') {
            snprintf(err, err_size, "argv:%d: unknown option '%s' (see --help)", i, a);
            return 2;
        } else if (o->scene_path) {
            snprintf(err, err_size, "argv:%d: a second scene file '%s' (only one is rendered)", i, a);
            return 2;
        } else {
            o->scene_path = a;
            o->scene_argv = i;
        }
    }
    o->spp_given = o->spp > 0;
    if (!o->spp_given)
        o->spp = ch->default_spp;
    if (o->camera_fov > 0.0)
        o->camera_override |= CAMERA_FOV;
    if (!o->scene_path)
        o->scene_path = "scenes/cornell.scene";
    return 0;
}

/* The driver may pick the output file name; the chapter's .ply is not an image. */
static bool is_image_path(const char *p) { return path_has_extension(p, ".pfm") || path_has_extension(p, ".png"); }

/* --- progress bar ------------------------------------------------------------------- */

static void show_progress(const render_options *o, double fraction, int pass, double elapsed)
{
    if (o->quiet || !isatty(STDERR_FILENO))
        return;
    const int width = 40;
    int filled = (int)(fraction * width + 0.5);
    fprintf(stderr, "\r[");
    for (int k = 0; k < width; k++)
        fputc(k < filled ? '#' : ' ', stderr);
    fprintf(stderr, "] %3d%%  pass %d  %.1f s", (int)(100 * fraction + 0.5), pass, elapsed);
    fflush(stderr);
}

/* --- the pixel loop -------------------------------------------------------------------- */

/* Where in the pixel sample `index` looks.  One sample looks through the
 * pixel centre (a deterministic image for the local and Whitted chapters);
 * a square number of samples is stratified on a grid with jitter inside each
 * cell; anything else (0 = unknown in advance) is uniformly jittered. */
typedef struct {
    int spp;          /* samples per pixel of the whole render, 0 if unknown */
    int side;         /* of the grid of strata when spp is a square > 1, else 0 */
    double cell_size; /* 1 / side: a multiplication per sample rather than a division */
} pixel_strata;

static pixel_strata pixel_strata_for(int spp)
{
    int side = (int)lround(sqrt((double)spp));
    if (!(spp > 1 && side * side == spp))
        side = 0;
    return (pixel_strata){.spp = spp, .side = side, .cell_size = side > 0 ? 1.0 / side : 0.0};
}

static void pixel_offset(int index, const pixel_strata *strata, rng *g, double *dx, double *dy)
{
    if (strata->spp == 1) {
        *dx = *dy = 0.5;
        return;
    }
    double u1 = rng_uniform(g), u2 = rng_uniform(g);
    if (strata->side > 0) {
        int cell = index % strata->spp, side = strata->side;
        *dx = ((cell % side) + u1) * strata->cell_size;
        *dy = ((cell / side) + u2) * strata->cell_size;
    } else {
        *dx = u1, *dy = u2;
    }
}

/* Set by SIGINT: the pixel loop abandons the pass it is in, and the
 * driver writes the result of the passes completed so far. */
static volatile sig_atomic_t interrupted;
static void on_interrupt(int signal_number)
{
    (void)signal_number;
    interrupted = 1;
}

typedef struct {
    double *sum;  /* running sum of samples of completed passes, 3 per pixel */
    double *pass; /* this pass's samples, added to sum only if the pass completes */
    long samples; /* per pixel so far */
    uint64_t nonfinite;
    render_counters counters;
} accumulation;

static void render_pass(const chapter *ch, const void *state, const scene *s, const render_options *o, int width,
                        int height, int first_sample, int pass_samples, int spp_total, accumulation *acc)
{
    /* Once per pass, not per sample: the camera's frame, the strata, and the
     * seed (a local, so the compiler sees it cannot change inside the loop
     * and hoists the seed's part of rng_for out of it). */
    const camera_frame frame = camera_frame_make(&s->camera, width, height);
    const pixel_strata strata = pixel_strata_for(spp_total);
    const uint64_t seed = o->seed;
#pragma omp parallel
    {
        render_counters local = {{0}};
        uint64_t nonfinite = 0;
#pragma omp for schedule(dynamic, 1)
        for (int y = 0; y < height; y++)
            for (int x = 0; x < width && !interrupted; x++) {
                uint64_t pixel = (uint64_t)y * (uint64_t)width + (uint64_t)x;
                vec3 total = v3_splat(0.0);
                for (int k = first_sample; k < first_sample + pass_samples; k++) {
                    rng g = rng_for(seed, pixel, (uint64_t)k);
                    double dx, dy;
                    pixel_offset(k, &strata, &g, &dx, &dy);
                    ray r = camera_frame_ray(&frame, x + dx, y + dy);
                    vec3 L = ch->radiance(state, s, r, &g, &local);
                    if (v3_is_finite(L))
                        total = v3_add(total, L);
                    else
                        nonfinite++; /* rejected: counts as a zero sample, reported in stats */
                }
                double *p = acc->pass + 3 * pixel;
                p[0] = total.x, p[1] = total.y, p[2] = total.z;
            }
#pragma omp critical
        {
            for (int c = 0; c < RENDER_MAX_COUNTERS; c++)
                acc->counters.value[c] += local.value[c];
            acc->nonfinite += nonfinite;
        }
    }
    if (interrupted)
        return; /* an incomplete pass would leave some pixels with fewer samples */
    size_t n = 3 * (size_t)width * (size_t)height;
    for (size_t i = 0; i < n; i++)
        acc->sum[i] += acc->pass[i];
    acc->samples += pass_samples;
}

static void accumulation_to_image(const accumulation *acc, image *img)
{
    size_t n = 3 * (size_t)img->width * (size_t)img->height;
    for (size_t i = 0; i < n; i++)
        img->pixels[i] = (float)(acc->sum[i] / (double)acc->samples);
}

static int write_outputs(const chapter *ch, const void *state, const scene *s, const render_options *o,
                         const image *img, char *err, size_t err_size)
{
    for (int k = 0; k < o->output_count; k++) {
        const char *path = o->outputs[k];
        if (ch->write_output) {
            int status = ch->write_output(state, s, path, err, err_size);
            if (status == 1)
                continue;
            if (status != 0)
                return 2;
        }
        if (image_write(img, path, o->exposure, err, err_size))
            return 2;
    }
    return 0;
}

/* --- stats ----------------------------------------------------------------------------- */

typedef struct {
    double time_total, time_prepare, time_render;
    long samples_per_pixel;
    int passes;
    bool have_metrics;
    image_metrics metrics;
} run_summary;

static int write_stats(const chapter *ch, const void *state, const scene *s, const render_options *o, int width,
                       int height, const accumulation *acc, const probe_result *probes, const run_summary *run,
                       char *err, size_t err_size)
{
    atomic_file out;
    if (atomic_file_open(&out, o->stats_path, err, err_size))
        return 2;
    FILE *f = out.file;
    fprintf(f, "{\n  \"chapter\": ");
    json_string(f, ch->name);
    fprintf(f, ",\n  \"scene\": ");
    json_string(f, o->scene_path);
    fprintf(f, ",\n  \"width\": %d,\n  \"height\": %d,\n  \"spp\": %ld,\n  \"passes\": %d,\n  \"seed\": %llu", width,
            height, run->samples_per_pixel, run->passes, (unsigned long long)o->seed);
    fprintf(f, ",\n  \"threads\": %d", omp_get_max_threads());
    json_field_number(f, "time_s", run->time_total);
    json_field_number(f, "prepare_s", run->time_prepare);
    json_field_number(f, "render_s", run->time_render);
    fprintf(f, ",\n  \"bounces\": [%d, %d]", o->bounce_min, o->bounce_max);
    fprintf(f, ",\n  \"interrupted\": %s", interrupted ? "true" : "false");
    fprintf(f, ",\n  \"counters\": {\"camera_rays\": %llu",
            (unsigned long long)((uint64_t)run->samples_per_pixel * (uint64_t)width * (uint64_t)height));
    for (int c = 0; c < RENDER_MAX_COUNTERS && ch->counter_names[c]; c++) {
        fputs(", ", f);
        json_string(f, ch->counter_names[c]);
        fprintf(f, ": %llu", (unsigned long long)acc->counters.value[c]);
    }
    fprintf(f, "},\n  \"nonfinite_samples\": %llu", (unsigned long long)acc->nonfinite);
    fprintf(f, ",\n  \"probes\": [");
    for (int p = 0; probes && p < s->probe_count; p++) {
        fprintf(f, "%s\n    {\"name\": ", p ? "," : "");
        json_string(f, s->probes[p].name);
        fprintf(f, ", \"irradiance\": ");
        json_vec3(f, probes[p].irradiance);
        fprintf(f, ", \"standard_error\": ");
        json_vec3(f, probes[p].standard_error);
        fputc('}', f);
    }
    fprintf(f, "%s]", probes && s->probe_count ? "\n  " : "");
    if (run->have_metrics) {
        fprintf(f, ",\n  \"metrics\": {\"reference\": ");
        json_string(f, o->reference_path);
        fprintf(f, ", \"rmse\": ");
        json_number(f, run->metrics.rmse);
        fprintf(f, ", \"relmse\": ");
        json_number(f, run->metrics.relmse);
        fprintf(f, ", \"psnr\": ");
        json_number(f, run->metrics.psnr);
        fprintf(f, ", \"ssim\": ");
        json_number(f, run->metrics.ssim);
        fputc('}', f);
    }
    if (ch->write_stats)
        ch->write_stats(state, f);
    fprintf(f, "\n}\n");
    return atomic_file_commit(&out, 0, err, err_size);
}

/* --- main ----------------------------------------------------------------------------- */

/* Checks that need no rendering come first, so a typo fails in
 * milliseconds rather than after a long render. */
static int check_outputs(const chapter *ch, const render_options *o, char *err, size_t err_size)
{
    for (int k = 0; k < o->output_count; k++) {
        const char *p = o->outputs[k];
        if (!is_image_path(p) && !(ch->write_output && path_has_extension(p, ".ply"))) {
            snprintf(err, err_size, "argv:%d: --out '%s': unknown format (use .pfm or .png%s)", o->output_argv[k], p,
                     ch->write_output ? " or .ply" : "");
            return 2;
        }
    }
    return 0;
}

/* One render from the command line to the files: what the steps below share. */
typedef struct {
    const chapter *ch;
    void *state;
    render_options o;
    scene s;
    image reference, img;
    accumulation acc;
    probe_result *probes;
    run_summary summary;
    double start, render_start;
    char default_output[1200];
} render_job;

/* --eye --look --up --fov replace the scene's camera; refused if degenerate. */
static int override_camera(render_job *job, char *err, size_t err_size)
{
    const render_options *o = &job->o;
    if (!o->camera_override)
        return 0;
    camera c = job->s.camera;
    if (o->camera_override & CAMERA_EYE)
        c.eye = o->camera_eye;
    if (o->camera_override & CAMERA_LOOK)
        c.look = o->camera_look;
    if (o->camera_override & CAMERA_UP)
        c.up = o->camera_up;
    if (o->camera_override & CAMERA_FOV)
        c.fov_degrees = o->camera_fov;
    vec3 view = v3_sub(c.look, c.eye);
    if (v3_length(view) == 0.0 || v3_length(v3_cross(view, c.up)) <= 1e-9 * v3_length(view) * v3_length(c.up)) {
        snprintf(err, err_size, "argv:%d: the camera given by --eye/--look/--up is degenerate", o->camera_argv);
        return 2;
    }
    job->s.camera = c;
    scene_settle_emitters(&job->s); /* which caps of spheres shine toward the camera */
    return 0;
}

/* The image size (--size, else the scene's) and, without --out, out/<scene>-<chapter>.png. */
static void settle_size_and_outputs(render_job *job)
{
    render_options *o = &job->o;
    o->width = o->width ? o->width : job->s.width;
    o->height = o->height ? o->height : job->s.height;
    if (o->output_count > 0)
        return;
    const char *base = strrchr(o->scene_path, '/');
    base = base ? base + 1 : o->scene_path;
    snprintf(job->default_output, sizeof job->default_output, "out/%.*s-%s.png", (int)strcspn(base, "."), base,
             job->ch->name);
    o->outputs[o->output_count++] = job->default_output;
    mkdir("out", 0777); /* may exist already; a failure shows when writing */
}

/* --ref: read it now, so a wrong size fails before the render. */
static int load_reference(render_job *job, char *err, size_t err_size)
{
    const render_options *o = &job->o;
    if (!o->reference_path)
        return 0;
    if (image_read_pfm(o->reference_path, &job->reference, err, err_size))
        return 2;
    if (job->reference.width != o->width || job->reference.height != o->height) {
        snprintf(err, err_size, "%s:0: reference is %dx%d but the image is %dx%d", o->reference_path,
                 job->reference.width, job->reference.height, o->width, o->height);
        return 2;
    }
    return 0;
}

/* The chapter's prepare step, then the image and its two sums. */
static int prepare_and_allocate(render_job *job, char *err, size_t err_size)
{
    const render_options *o = &job->o;
    double prepare_start = now_seconds();
    if (job->ch->prepare && job->ch->prepare(job->state, &job->s, o, err, err_size))
        return 2;
    job->render_start = now_seconds();
    job->summary.time_prepare = job->render_start - prepare_start;
    size_t values = 3 * (size_t)o->width * (size_t)o->height;
    job->img = image_new(o->width, o->height);
    job->acc.sum = calloc(values, sizeof(double));
    job->acc.pass = calloc(values, sizeof(double));
    if (!job->img.pixels || !job->acc.sum || !job->acc.pass) {
        snprintf(err, err_size, "argv:%d: out of memory for a %dx%d image", o->size_argv ? o->size_argv : o->scene_argv,
                 o->width, o->height);
        return 2;
    }
    return 0;
}

/* Progressive passes.  Without --time: the --spp samples in passes of
 * growing size (the bar moves, the overhead stays small).  With --time:
 * passes of 1 spp until the budget is spent (at least one pass), capped
 * by --spp when given; the result so far is written after each pass so
 * a viewer can show it while the render goes on. */
static int render_passes(render_job *job, char *err, size_t err_size)
{
    const chapter *ch = job->ch;
    const render_options *o = &job->o;
    accumulation *acc = &job->acc;
    bool timed = o->time_budget > 0.0;
    int spp_cap = timed ? (o->spp_given ? o->spp : INT_MAX) : o->spp;
    /* Strata need the final count in advance; a timed render jitters. */
    int spp_for_offsets = timed ? (spp_cap == 1 ? 1 : 0) : o->spp;
    double last_write = job->render_start;
    while (acc->samples < spp_cap) {
        int pass_samples = timed ? 1 : (int)fmin((double)(spp_cap - acc->samples), fmax(1.0, acc->samples / 2.0));
        if (ch->begin_pass) {
            pass_samples = 1;
            if (ch->begin_pass(job->state, &job->s, o, job->summary.passes + 1, err, err_size))
                return 2;
            if (interrupted)
                break;
        }
        render_pass(ch, job->state, &job->s, o, o->width, o->height, (int)acc->samples, pass_samples, spp_for_offsets,
                    acc);
        if (interrupted)
            break;
        job->summary.passes++;
        double elapsed = now_seconds() - job->render_start;
        double fraction = timed ? fmin(1.0, elapsed / o->time_budget) : (double)acc->samples / spp_cap;
        show_progress(o, fraction, job->summary.passes, elapsed);
        if (timed && now_seconds() - job->start >= o->time_budget)
            break;
        if (timed && now_seconds() - last_write > 0.5) {
            accumulation_to_image(acc, &job->img);
            if (write_outputs(ch, job->state, &job->s, o, &job->img, err, err_size))
                return 2;
            last_write = now_seconds();
        }
    }
    if (!o->quiet && isatty(STDERR_FILENO))
        fputc('\n', stderr);
    if (interrupted && acc->samples == 0) {
        fprintf(stderr, "%s: interrupted before the first pass was complete; no output written\n", ch->name);
        return 130;
    }
    accumulation_to_image(acc, &job->img);
    job->summary.time_render = now_seconds() - job->render_start;
    job->summary.samples_per_pixel = acc->samples;
    return 0;
}

/* The scene's probes, once the image is done (not after an interrupt). */
static int measure_probes(render_job *job, char *err, size_t err_size)
{
    const scene *s = &job->s;
    if (!job->ch->probe || !s->probe_count || interrupted)
        return 0;
    job->probes = calloc((size_t)s->probe_count, sizeof *job->probes);
    if (!job->probes) {
        snprintf(err, err_size, "argv:%d: out of memory for the scene's %d probes", job->o.scene_argv, s->probe_count);
        return 2;
    }
    for (int p = 0; p < s->probe_count; p++)
        job->probes[p] = job->ch->probe(job->state, s, &s->probes[p], job->o.seed, &job->acc.counters);
    return 0;
}

/* Metrics against --ref, the outputs, the stats; then the status (130 after Ctrl-C). */
static int report(render_job *job, char *err, size_t err_size)
{
    const chapter *ch = job->ch;
    const render_options *o = &job->o;
    run_summary *summary = &job->summary;
    if (o->reference_path) {
        summary->metrics = image_compare(&job->img, &job->reference);
        summary->have_metrics = true;
        fprintf(stderr, "%s: rmse %.6g  relmse %.6g  psnr %.2f dB  ssim %.4f\n", ch->name, summary->metrics.rmse,
                summary->metrics.relmse, summary->metrics.psnr, summary->metrics.ssim);
    }
    if (write_outputs(ch, job->state, &job->s, o, &job->img, err, err_size))
        return 2;
    summary->time_total = now_seconds() - job->start;
    if (o->stats_path &&
        write_stats(ch, job->state, &job->s, o, o->width, o->height, &job->acc, job->probes, summary, err, err_size))
        return 2;
    if (job->acc.nonfinite)
        fprintf(stderr, "warning: %llu non-finite samples were rejected (counted in stats)\n",
                (unsigned long long)job->acc.nonfinite);
    if (!interrupted)
        return 0;
    /* The conventional status of a program ended by SIGINT (128 + 2). */
    fprintf(stderr, "%s: interrupted; wrote the %ld samples per pixel completed so far\n", ch->name, job->acc.samples);
    return 130;
}

/* Everything after the scene is loaded, each step stopping the rest on failure. */
static int render_loaded_scene(render_job *job, char *err, size_t err_size)
{
    int status = override_camera(job, err, err_size);
    if (status)
        return status;
    settle_size_and_outputs(job);
    if ((status = load_reference(job, err, err_size)) || (status = prepare_and_allocate(job, err, err_size)) ||
        (status = render_passes(job, err, err_size)) || (status = measure_probes(job, err, err_size)))
        return status;
    return report(job, err, err_size);
}

static void render_job_free(render_job *job)
{
    free(job->probes);
    free(job->acc.sum);
    free(job->acc.pass);
    image_free(&job->img);
    image_free(&job->reference);
    if (job->ch->finish)
        job->ch->finish(job->state);
    scene_free(&job->s);
}

/* Ctrl-C finishes with what is done; a second Ctrl-C kills at once
 * (SA_RESETHAND restores the default action). */
static void finish_on_first_interrupt(void)
{
    struct sigaction on_sigint = {.sa_handler = on_interrupt, .sa_flags = SA_RESETHAND};
    sigemptyset(&on_sigint.sa_mask);
    sigaction(SIGINT, &on_sigint, NULL);
}

static int run(int argc, char **argv, const chapter *ch, void *state, char *err, size_t err_size)
{
    render_job job = {.ch = ch, .state = state, .start = now_seconds()};
    bool help = false;
    if (parse_command_line(argc, argv, ch, &job.o, &help, err, err_size))
        return 2;
    if (help) {
        print_help(ch, argv[0]);
        return 0;
    }
    if (check_outputs(ch, &job.o, err, err_size))
        return 2;
    if (job.o.threads > 0)
        omp_set_num_threads(job.o.threads);
    finish_on_first_interrupt();
    if (scene_load(job.o.scene_path, &job.s, err, err_size))
        return 2;
    int status = render_loaded_scene(&job, err, err_size);
    render_job_free(&job);
    return status;
}

int render_main(int argc, char **argv, const chapter *ch, void *state)
{
    char err[ERROR_SIZE] = "";
    int status = run(argc, argv, ch, state, err, sizeof err);
    if (status == 2)
        fprintf(stderr, "%s\n", err);
    return status;
}
