/* 07_metropolis.c — Lecture 7: Metropolis light transport.
 *
 * Chapters 4-6 draw every path independently: where the light is hard to find (a room lit through a door ajar) most
 * paths carry nothing.  A Markov chain (Veach and Guibas 1997) instead wanders path space, proposing a change y of its
 * current path x and accepting it with a probability that makes it visit paths as often as they contribute.  It
 * needs only detailed balance (R17), which the acceptance probability gives (R18):
 *
 *   (R17)  f(x) T(x -> y) a(x -> y) = f(y) T(y -> x) a(y -> x)      (R18)  a(x -> y) = min(1, f(y) / f(x))
 *
 * for a symmetric proposal T.  Kelemen et al. (2002) make the chain simple: a path is the vector u of uniform numbers
 * that chapter 6's code turns into it (R19), so a change of path is a change of numbers: a small step nudges each
 * (wrapping around 1), a large step draws them all afresh, so that every path can be reached (ergodicity).  The chain
 * visits u with density f(u) / b; the bootstrap estimates b, the image is b times where the chain went, every
 * proposal splatted with its acceptance probability (R20).  --method:
 *   1. pssmlt  (Kelemen) over a path tracer: chapter 6's eye subpath, each vertex found by the light (s = 0) or joined
 *              to one light vertex (s = 1), weighted by (R15) between the two;
 *   2. mmlt    (the default; Hachisuka, Kaplanyan and Dachsbacher 2014) the chain also chooses the path's length k and
 *              one of chapter 6's strategies (s, t), weighted by (R15) times k + 1 (R21): every path chapter 6 makes.
 * --spp N: N mutations per pixel (one per pixel a pass); chains run side by side, seeded by their number, so the image
 * does not depend on --threads.  --large-step 0 leaves small steps only: a warning, the chain may not be ergodic. */
#include <stdlib.h>
#include <string.h>

#include "bidir_model.h" /* chapter 6's subpaths, strategies and weights; chapter 4's materials */
#include "render.h"

enum { CAMERA_STREAM, LIGHT_STREAM, CONNECT_STREAM, STREAMS }; /* a path's numbers, by what they draw */
enum { MAX_NUMBERS = 512, MAX_SPLATS = 2, MAX_LENGTH = MAX_VERTICES - 2 };
enum { METHOD_PSSMLT, METHOD_MMLT }; /* --method, in order */

/* A state of the chain: the numbers u (by stream), the path length the chain chose (mmlt), and what the path they
 * draw gives: its splats (a pixel and a value) and f, the luminance of their sum. */
typedef struct {
    double u[STREAMS][MAX_NUMBERS];
    int count[STREAMS]; /* how many of u are set; the rest are drawn when first read */
    int length;
    splat splats[MAX_SPLATS];
    int splat_count;
    double f;
} mlt_sample;

/* What a chain did in a pass: rays, mutations, accepted ones, large steps and the sum of their f and f^2. */
typedef struct {
    uint64_t rays, proposed, accepted, large, large_accepted;
    double large_f, large_f2;
} chain_tally;

typedef struct {
    bidir_state bidir; /* chapter 6's: the camera, the lights' pick, --bounces */
    int method, chains, bootstrap, max_length;
    double large_step;
    /* From prepare: the lengths the chain may choose and their probabilities (mmlt), b (R20) and its error. */
    int shortest, longest;
    double length_pdf[MAX_LENGTH + 1], length_cdf[MAX_LENGTH + 2];
    double b, b_error, *bootstrap_f; /* bootstrap_f: the bootstrap's f, cumulated, to pick the chains' start */
    int *bootstrap_length;
    int pixels, active_chains;
    mlt_sample *current; /* one per chain */
    rng *chain_rng;
    splat **records; /* each chain's splats of the pass, added in chain order */
    int *record_count, record_capacity;
    vec3 *splat_sum, *image;   /* all splats so far (H, without b); this pass's image */
    chain_tally *tally, total; /* each chain's of the pass; all of them */
    double bootstrap_b, bootstrap_error;
    uint64_t rays;
} mlt_state;

#define STATE(field) offsetof(mlt_state, field)
static const option MLT_OPTIONS[] = {
    {"--method", NULL, OPTION_CHOICE, STATE(method), .choices = "pssmlt|mmlt", .default_text = "mmlt",
     .help = "primary sample space MLT over a path tracer, or multiplexed over chapter 6's strategies"},
    {"--large-step", "P", OPTION_DOUBLE, STATE(large_step), .min = 0.0, .max = 1.0, .default_text = "0.3",
     .help = "probability of a large step (fresh numbers); 0: small steps only, the chain may not be ergodic"},
    {"--chains", "N", OPTION_INT, STATE(chains), .min = 1, .max = 1 << 20, .default_text = "64",
     .help = "Markov chains (at most one per pixel), each started from the bootstrap (few, long: less start-up bias)"},
    {"--bootstrap", "N", OPTION_INT, STATE(bootstrap), .min = 1, .max = 1 << 28, .default_text = "100000",
     .help = "independent paths that estimate the normalisation b (R20)"},
    {"--max-length", "K", OPTION_INT, STATE(max_length), .min = 1, .max = MAX_LENGTH, .default_text = "24",
     .help = "mmlt: longest path, in edges (--bounces A:B also keeps it within B + 1)"},
    {0},
};
#undef STATE

/* ---- the target: what the path of the numbers u contributes ------------------------------------ */

/* Add strategy (s, t)'s value, weighted, to x's splats: t >= 2 in `pixel`, light tracing (t = 1) where it lands. */
static void add_splat(mlt_sample *x, int pixel, vec3 value)
{
    if (!(v3_max_component(value) > 0.0))
        return;
    for (int i = 0; i < x->splat_count; i++)
        if (x->splats[i].pixel == pixel) {
            x->splats[i].value = v3_add(x->splats[i].value, value);
            return;
        }
    if (x->splat_count < MAX_SPLATS)
        x->splats[x->splat_count++] = (splat){pixel, value};
}

/* The eye subpath of up to `cap` vertices through the image point the camera stream's first two numbers pick. */
static int eye_subpath(const bidir_state *st, const scene *s, rng *g, path_vertex *z, int cap, bool roulette,
                       int *pixel, uint64_t *rays)
{
    ray r = camera_frame_ray(&st->camera.frame, rng_uniform(g) * st->camera.width, rng_uniform(g) * st->camera.height);
    *pixel = pixel_of_ray(&st->camera, r.direction);
    z[0] = (path_vertex){.x = r.origin, .alpha = v3_splat(1.0), .kind = AT_CAMERA};
    int count = cap < 2 ? 1 : extend(s, z, 1, cap, v3_splat(1.0), r.direction, roulette, false, g, rays);
    z[0].x = st->camera.eye; /* the pinhole: its ray began camera.near ahead of it (scene.h) */
    return count;
}

/* 1. pssmlt: a path tracer as chapter 6 makes one.  The eye subpath (with roulette: every length), one light vertex
 * y_0, and at each eye vertex the light it finds (s = 0) and the join to y_0 (s = 1), weighted by (R15) between those
 * two only (a copy of the state that allows one light vertex).  A light seen directly is shared with y_0 joined to
 * the camera (s = 1, t = 1), which lands in the pixel it is seen in. */
static void path_tracer_sample(const mlt_state *m, const scene *s, rng *g, mlt_sample *x, uint64_t *rays)
{
    bidir_state one_light = m->bidir;
    one_light.light_cap = 1;
    path_vertex y[MAX_VERTICES], z[MAX_VERTICES], path[MAX_PATH];
    int pixel, light_pixel = 0; /* set: a handout's stubs return zero light without writing it */
    int t_count = eye_subpath(&one_light, s, &g[CAMERA_STREAM], z, one_light.eye_cap, true, &pixel, rays);
    int s_count = light_subpath(&one_light, s, &g[LIGHT_STREAM], y, rays, false);
    for (int t = 1; t <= t_count; t++)
        for (int s_used = t == 1; s_used <= s_count; s_used++) {
            int k = join(y, s_used, z, t, path);
            if (!keeps_length(&one_light, path, k) || !strategy_allowed(&one_light, path, k, CONNECT, s_used))
                continue;
            vec3 C = strategy_value(&one_light, s, y, s_used, z, t, &light_pixel, rays);
            if (v3_max_component(C) > 0.0)
                add_splat(x, t == 1 ? light_pixel : pixel,
                          v3_scale(C, mis_weight(&one_light, s, path, k, CONNECT, s_used)));
        }
}

/* 2. mmlt (R21): the chain's length k, a strategy (s, t) of the k + 1 with t >= 1 picked by the connection stream's
 * first number, subpaths of exactly s and t vertices (no roulette), their join: (R13) over (R14), weighted by (R15)
 * (n = light_paths for t = 1, as in chapter 6: both pick a pixel once), times k + 1 over the length's probability.
 * [exercise 7.5] */
static void strategy_sample(const mlt_state *m, const scene *s, rng *g, mlt_sample *x, uint64_t *rays)
{
    int k = x->length, s_used = (int)fmin(rng_uniform(&g[CONNECT_STREAM]) * (k + 1), k), t = k + 1 - s_used;
    bidir_state light_cap = m->bidir;
    light_cap.light_cap = s_used;
    path_vertex y[MAX_VERTICES], z[MAX_VERTICES], path[MAX_PATH];
    int pixel, light_pixel;
    int t_count = eye_subpath(&m->bidir, s, &g[CAMERA_STREAM], z, t, false, &pixel, rays);
    int s_count = s_used > 0 ? light_subpath(&light_cap, s, &g[LIGHT_STREAM], y, rays, false) : 0;
    if (t_count < t || s_count < s_used)
        return;
    join(y, s_used, z, t, path);
    if (!keeps_length(&m->bidir, path, k) || !strategy_allowed(&m->bidir, path, k, CONNECT, s_used))
        return;
    vec3 C = strategy_value(&m->bidir, s, y, s_used, z, t, &light_pixel, rays);
    if (v3_max_component(C) > 0.0) /* (R21) */
        add_splat(x, t == 1 ? light_pixel : pixel,
                  v3_scale(C, mis_weight(&m->bidir, s, path, k, CONNECT, s_used) * (k + 1) / m->length_pdf[k]));
}

/* (R19) The path of x's numbers, and f(x): every random number the sampling code draws comes from x's streams (rng.h
 * replays them); numbers past the stored ones are drawn from `fresh` and kept, as a large step would draw them. */
static void evaluate(const mlt_state *m, const scene *s, mlt_sample *x, rng *fresh, uint64_t *rays)
{
    primary_samples streams[STREAMS];
    rng g[STREAMS];
    for (int i = 0; i < STREAMS; i++) {
        streams[i] = (primary_samples){x->u[i], x->count[i], MAX_NUMBERS, 0, rng_for(rng_next_u64(fresh), 0, 0)};
        g[i] = (rng){.replay = &streams[i]};
    }
    x->splat_count = 0;
    if (m->method == METHOD_PSSMLT)
        path_tracer_sample(m, s, g, x, rays);
    else
        strategy_sample(m, s, g, x, rays);
    vec3 sum = v3_splat(0.0);
    for (int i = 0; i < x->splat_count; i++)
        sum = v3_add(sum, x->splats[i].value);
    x->f = v3_is_finite(sum) ? v3_luminance(sum) : 0.0; /* a non-finite path is given no weight */
    for (int i = 0; i < STREAMS; i++)
        x->count[i] = streams[i].count;
}

/* ---- the mutations (R19) ------------------------------------------------------------------------- */

/* Kelemen's small step: u moved by +-s2 exp(-log(s2 / s1) xi), between s1 = 1/1024 and s2 = 1/32, wrapped into
 * [0, 1).  Symmetric: moving back is as likely, so T cancels in (R18). [exercise 7.2] */
static double small_step(double u, rng *g)
{
    const double s1 = 1.0 / 1024.0, s2 = 1.0 / 32.0;      /* s2: measured best on door-ajar (1/128..1/8) */
    double du = s2 * exp(-log(s2 / s1) * rng_uniform(g)); /* (R19) */
    /* Up or down, each with probability 1/2: copysign, not a branch (a coin flip, which the processor mispredicts). */
    u += copysign(du, rng_uniform(g) - 0.5);
    u -= floor(u); /* (R19) wraparound mod 1 */
    return u < 1.0 ? u : 0.0;
}

/* The length of the next path (mmlt): k with probability length_pdf[k], from the uniform number v. */
static int pick_length(const mlt_state *m, double v)
{
    int k = m->shortest;
    while (k < m->longest && v >= m->length_cdf[k + 1])
        k++;
    return k;
}

/* The proposal y from x: a large step draws every number afresh (a count of 0: each is drawn when read) and a new
 * length; a small step moves each number x has, and keeps its length. [exercise 7.3] */
static void propose(const mlt_state *m, const mlt_sample *x, mlt_sample *y, bool large, rng *g)
{
    y->length = large ? pick_length(m, rng_uniform(g)) : x->length;
    for (int i = 0; i < STREAMS; i++) {
        y->count[i] = large ? 0 : x->count[i];
        for (int j = 0; j < y->count[i]; j++)
            y->u[i][j] = small_step(x->u[i][j], g);
    }
}

/* ---- the chain ----------------------------------------------------------------------------------- */

/* (R20) A state's splats, each weighted by `weight` / f (expected-value splatting: weight is the chance the chain is
 * there), into the chain's record of the pass; the image is b times their sum. */
static void record(const mlt_state *m, const mlt_sample *x, double weight, splat *out, int *count)
{
    if (!(weight > 0.0) || !(x->f > 0.0))
        return;
    for (int i = 0; i < x->splat_count && *count < m->record_capacity; i++)
        out[(*count)++] = (splat){x->splats[i].pixel, v3_scale(x->splats[i].value, weight / x->f)};
}

/* One Metropolis-Hastings step of chain c: propose, splat both the proposal (weight a) and the current state
 * (weight 1 - a) (R20), accept with probability a (R18).  A large step's f is one more independent sample of b.
 * [exercise 7.1] */
static void metropolis_step(mlt_state *m, const scene *s, int c, mlt_sample *y)
{
    mlt_sample *x = &m->current[c];
    chain_tally *n = &m->tally[c];
    rng *g = &m->chain_rng[c];
    bool large = rng_uniform(g) < m->large_step;
    propose(m, x, y, large, g);
    evaluate(m, s, y, g, &n->rays);
    double a = x->f > 0.0 ? fmin(1.0, y->f / x->f) : 1.0; /* (R18) */
    record(m, y, a, m->records[c], &m->record_count[c]);
    record(m, x, 1.0 - a, m->records[c], &m->record_count[c]);
    n->proposed++;
    if (large)
        n->large++, n->large_f += y->f, n->large_f2 += y->f * y->f;
    if (rng_uniform(g) < a) {
        memcpy(x, y, sizeof *x);
        n->accepted++;
        n->large_accepted += large;
    }
}

/* (R20) b from the bootstrap and every large step so far (both independent samples of f, u uniform), pooled. */
static void update_b(mlt_state *m)
{
    double n0 = m->bootstrap, n1 = (double)m->total.large, mean1 = n1 > 0 ? m->total.large_f / n1 : 0.0;
    double variance1 = n1 > 1 ? fmax(0.0, m->total.large_f2 / n1 - mean1 * mean1) * n1 / (n1 - 1) : 0.0;
    m->b = (n0 * m->bootstrap_b + m->total.large_f) / (n0 + n1);
    m->b_error = sqrt(n0 * n0 * m->bootstrap_error * m->bootstrap_error + n1 * variance1) / (n0 + n1);
}

/* Before pass i: every chain makes its share of one mutation per pixel (in parallel, each with its own numbers), then
 * the splats and tallies are added in chain order (the same sums for any --threads).  The driver averages the
 * passes' images; so that the average is the latest b times all the splats so far (R20), this pass's image is the
 * change: b_i H_i - b_(i-1) H_(i-1), H the sum of the splats. */
static int begin_pass(void *state_pointer, const scene *s, const render_options *o, int pass, char *err,
                      size_t err_size)
{
    mlt_state *m = state_pointer;
    (void)o, (void)pass, (void)err, (void)err_size;
#pragma omp parallel
    {
        mlt_sample *proposal = calloc(1, sizeof *proposal); /* zeroed: a proposal of no numbers, length 0 */
#pragma omp for schedule(dynamic, 1)
        for (int c = 0; c < m->active_chains; c++) {
            long first = (long)m->pixels * c / m->active_chains, last = (long)m->pixels * (c + 1) / m->active_chains;
            m->record_count[c] = 0;
            m->tally[c] = (chain_tally){0};
            for (long i = first; i < last && proposal; i++)
                metropolis_step(m, s, c, proposal);
        }
        free(proposal);
    }
    double b_before = m->b;
    for (int p = 0; p < m->pixels; p++)
        m->image[p] = v3_scale(m->splat_sum[p], -b_before);
    for (int c = 0; c < m->active_chains; c++) {
        chain_tally *n = &m->tally[c], *all = &m->total;
        all->rays += n->rays, all->proposed += n->proposed, all->accepted += n->accepted;
        all->large += n->large, all->large_accepted += n->large_accepted;
        all->large_f += n->large_f, all->large_f2 += n->large_f2;
        for (int i = 0; i < m->record_count[c]; i++)
            m->splat_sum[m->records[c][i].pixel] = v3_add(m->splat_sum[m->records[c][i].pixel], m->records[c][i].value);
    }
    update_b(m);
    for (int p = 0; p < m->pixels; p++)
        m->image[p] = v3_add(m->image[p], v3_scale(m->splat_sum[p], m->b));
    return 0;
}

/* (R20) Pixel p's part of this pass (begin_pass): the driver's mean over the M passes is b / M times its splats. */
static vec3 radiance(const void *state_pointer, const scene *s, ray r, rng *g, render_counters *counters)
{
    const mlt_state *m = state_pointer;
    (void)s, (void)g, (void)counters;
    return m->image[pixel_of_ray(&m->bidir.camera, r.direction)];
}

/* ---- the bootstrap: b, the lengths' probabilities, the chains' first states ------------------------- */

/* Bootstrap path i: a large step from nothing, with numbers of its own.  The chain that starts there redraws it with
 * the length it had (`length`; 0: draw one), whatever the lengths' probabilities are by then. */
static void bootstrap_sample(const mlt_state *m, const scene *s, int i, int length, mlt_sample *x, uint64_t *rays)
{
    rng g = rng_for(m->bidir.seed ^ 0x626f6f74ull, (uint64_t)i, 0);
    int drawn = pick_length(m, rng_uniform(&g));
    x->length = length > 0 ? length : drawn;
    x->count[CAMERA_STREAM] = x->count[LIGHT_STREAM] = x->count[CONNECT_STREAM] = 0;
    evaluate(m, s, x, &g, rays);
}

/* The bootstrap's paths, in parallel: path i has length shortest + i mod (the number of lengths), so that every
 * length has its share (stratified: b's error is then only the spread within each length). */
static int bootstrap_paths(mlt_state *m, const scene *s)
{
    int n = m->bootstrap, lengths = m->longest - m->shortest + 1;
    uint64_t rays = 0;
    m->bootstrap_length = malloc((size_t)n * sizeof *m->bootstrap_length);
    m->bootstrap_f = calloc((size_t)n + 1, sizeof *m->bootstrap_f);
    if (!m->bootstrap_length || !m->bootstrap_f)
        return 2;
#pragma omp parallel reduction(+ : rays)
    {
        mlt_sample *x = malloc(sizeof *x);
#pragma omp for schedule(dynamic, 256)
        for (int i = 0; i < n; i++) {
            m->bootstrap_length[i] = m->shortest + i % lengths;
            if (x)
                bootstrap_sample(m, s, i, m->bootstrap_length[i], x, &rays);
            m->bootstrap_f[i + 1] = x ? x->f : 0.0;
        }
        free(x);
    }
    m->rays += rays;
    return 0;
}

/* (R20) b = the mean of f over independent paths (u uniform), each length's mean weighted alike (f holds the
 * length's 1 / probability), and its standard error; each length's share of b sets the chain's choice of lengths
 * (R21), with a tenth spread evenly so that every length stays reachable.  The paths are bootstrap_paths' (path i's f
 * in bootstrap_f[i + 1], its length in bootstrap_length[i]); bootstrap_f is left cumulated, bootstrap_f[i] the sum of
 * the first i, for start_chain. [exercise 7.4] */
static void estimate_b(mlt_state *m)
{
    int lengths = m->longest - m->shortest + 1;
    double sum[MAX_LENGTH + 1] = {0}, squares[MAX_LENGTH + 1] = {0}, count[MAX_LENGTH + 1] = {0}, variance = 0.0;
    m->bootstrap_f[0] = 0.0;
    for (int i = 0; i < m->bootstrap; i++) {
        double f = m->bootstrap_f[i + 1];
        int k = m->bootstrap_length[i];
        sum[k] += f, squares[k] += f * f, count[k]++;
        m->bootstrap_f[i + 1] = m->bootstrap_f[i] + f; /* cumulated: the chains pick starts by it */
    }
    m->b = 0.0;
    for (int k = m->shortest; k <= m->longest; k++) {
        double mean = count[k] > 0 ? sum[k] / count[k] : 0.0;
        m->b += mean / lengths; /* (R20) */
        variance += count[k] > 1 ? fmax(0.0, squares[k] / count[k] - mean * mean) / (count[k] - 1) : 0.0;
        sum[k] = mean / lengths;
    }
    m->b_error = sqrt(variance) / lengths;
    m->bootstrap_b = m->b, m->bootstrap_error = m->b_error;
    for (int k = m->shortest; k <= m->longest; k++) {
        m->length_pdf[k] = m->b > 0.0 ? 0.9 * sum[k] / m->b + 0.1 / lengths : 1.0 / lengths; /* (R21) */
        m->length_cdf[k + 1] = m->length_cdf[k] + m->length_pdf[k];
    }
}

/* Start-up bias: chain c starts at a bootstrap path picked with probability proportional to its f, so that it starts
 * as if it had run long already (Veach 1997, 11.3.3); with no light found, anywhere. */
static void start_chain(mlt_state *m, const scene *s, int c, uint64_t *rays)
{
    m->chain_rng[c] = rng_for(m->bidir.seed ^ 0x636861696eull, (uint64_t)c, 0);
    double *cumulated = m->bootstrap_f, pick = rng_uniform(&m->chain_rng[c]) * cumulated[m->bootstrap];
    int low = 0, high = m->bootstrap - 1; /* the i with cumulated[i] <= pick < cumulated[i + 1] */
    while (low < high) {
        int middle = (low + high + 1) / 2;
        if (cumulated[middle] <= pick)
            low = middle;
        else
            high = middle - 1;
    }
    bootstrap_sample(m, s, low, m->bootstrap_length[low], &m->current[c], rays);
}

/* After the scene is loaded: chapter 6's set-up (the camera, the lights' pick, --bounces), the lengths, the
 * bootstrap, the chains. */
static int prepare(void *state_pointer, const scene *s, const render_options *o, char *err, size_t err_size)
{
    mlt_state *m = state_pointer;
    m->bidir.method = METHOD_BDPT;
    if (bidir_prepare(&m->bidir, s, o, err, err_size))
        return 2;
    m->pixels = o->width * o->height;
    m->shortest = o->bounce_min + 1;
    m->longest = o->bounce_max < m->max_length ? o->bounce_max + 1 : m->max_length;
    if (m->shortest > m->longest) /* mmlt: no length kept; pssmlt uses none */
        m->shortest = m->longest;
    for (int k = m->shortest; k <= m->longest; k++) { /* the bootstrap draws every length alike */
        m->length_pdf[k] = 1.0 / (m->longest - m->shortest + 1);
        m->length_cdf[k + 1] = m->length_cdf[k] + m->length_pdf[k];
    }
    if (m->large_step == 0.0)
        fprintf(stderr, "warning: 07_metropolis: --large-step 0: small steps only, the chain may not be ergodic: it "
                        "can stay in one lit region and never reach another (the image then misses light)\n");
    m->active_chains = m->chains < m->pixels ? m->chains : m->pixels;
    m->record_capacity = 2 * MAX_SPLATS * (m->pixels / m->active_chains + 1);
    m->current = malloc((size_t)m->active_chains * sizeof *m->current);
    m->chain_rng = malloc((size_t)m->active_chains * sizeof *m->chain_rng);
    m->records = calloc((size_t)m->active_chains, sizeof *m->records);
    m->record_count = calloc((size_t)m->active_chains, sizeof *m->record_count);
    m->image = calloc((size_t)m->pixels, sizeof *m->image);
    m->splat_sum = calloc((size_t)m->pixels, sizeof *m->splat_sum);
    m->tally = calloc((size_t)m->active_chains, sizeof *m->tally);
    bool failed = !m->current || !m->chain_rng || !m->records || !m->record_count || !m->image || !m->splat_sum ||
                  !m->tally || bootstrap_paths(m, s);
    for (int c = 0; !failed && c < m->active_chains; c++)
        failed = !(m->records[c] = malloc((size_t)m->record_capacity * sizeof(splat)));
    if (failed) {
        snprintf(err, err_size, "argv:0: out of memory for %d chains", m->active_chains);
        return 2;
    }
    estimate_b(m);
    uint64_t rays = 0;
#pragma omp parallel for schedule(dynamic, 1) reduction(+ : rays)
    for (int c = 0; c < m->active_chains; c++)
        start_chain(m, s, c, &rays);
    m->rays += rays;
    return 0;
}

static void write_stats(const void *state_pointer, FILE *json)
{
    const mlt_state *m = state_pointer;
    fprintf(json, ",\n  \"method\": \"%s\"", m->method == METHOD_PSSMLT ? "pssmlt" : "mmlt");
    if (m->large_step == 0.0)
        fprintf(json, ",\n  \"warning\": \"--large-step 0: the chain may not be ergodic\"");
    json_field_number(json, "large_step", m->large_step);
    json_field_number(json, "chains", m->active_chains);
    json_field_number(json, "bootstrap_paths", m->bootstrap);
    json_field_number(json, "b", m->b);
    json_field_number(json, "b_standard_error", m->b_error);
    json_field_number(json, "bootstrap_b", m->bootstrap_b);
    json_field_number(json, "bootstrap_b_standard_error", m->bootstrap_error);
    json_field_number(json, "shortest_length", m->method == METHOD_MMLT ? m->shortest : 1);
    json_field_number(json, "longest_length", m->method == METHOD_MMLT ? m->longest : RENDER_BOUNCES_UNLIMITED);
    json_field_number(json, "mutations", (double)m->total.proposed);
    json_field_number(json, "large_steps", (double)m->total.large);
    json_field_number(json, "acceptance", m->total.proposed ? (double)m->total.accepted / m->total.proposed : 0.0);
    json_field_number(json, "large_step_acceptance",
                      m->total.large ? (double)m->total.large_accepted / m->total.large : 0.0);
    json_field_number(json, "rays", (double)(m->rays + m->total.rays));
}

static void finish(void *state_pointer)
{
    mlt_state *m = state_pointer;
    for (int c = 0; m->records && c < m->active_chains; c++)
        free(m->records[c]);
    free(m->records), free(m->record_count), free(m->current), free(m->chain_rng), free(m->image), free(m->splat_sum),
        free(m->tally);
    free(m->bootstrap_f), free(m->bootstrap_length);
    bidir_finish(&m->bidir);
}

int main(int argc, char **argv)
{
    mlt_state state = {.bidir = {.is_specular = is_specular, .total_light_power = total_light_power}};
    const chapter metropolis = {
        .name = "07_metropolis",
        .description = "Metropolis light transport: a Markov chain over primary sample space (PSSMLT) or over "
                       "chapter 6's strategies (MMLT) (R17-R21)",
        .options = {{MLT_OPTIONS, &state}},
        .default_spp = 16,
        .prepare = prepare,
        .begin_pass = begin_pass,
        .radiance = radiance,
        .write_stats = write_stats,
        .finish = finish,
    };
    return render_main(argc, argv, &metropolis, &state);
}
