/* bidir_model.h — what chapter 7 uses of lecture 6 (bidirectional methods).
 *
 * Defined in chapters/06_bidirectional.c, where lecture 6 reads them: the two
 * subpaths (extend, light_subpath), the path of a strategy (s, t) (join), its
 * unweighted value (strategy_value: (R13) over (R14)), the strategies that
 * can draw a path (strategy_allowed) and the power heuristic over them
 * (mis_weight: (R15)).  Chapter 7 (Metropolis light transport) draws the same
 * paths from a vector of uniform numbers: every random number these functions
 * take comes through the rng they are given, which replays that vector
 * (rng.h's primary_samples).  The Makefile links chapter 6's object into
 * chapter 7 (with chapter 6's main renamed), so neither includes the other.
 * The state and the vertices are chapter 6's bookkeeping (common/bidir_store.h).
 */
#ifndef CHAPTERS_BIDIR_MODEL_H
#define CHAPTERS_BIDIR_MODEL_H

#include "bidir_store.h"
#include "photonmap_model.h"

typedef enum { CONNECT, MERGE } technique; /* a join by a shadow ray, or merging (R16) */

/* Does --bounces A:B keep the path x_0 .. x_k of k edges (the term K^(k-1) E, (R6))? */
bool keeps_length(const bidir_state *st, const path_vertex *x, int k);

/* Extend subpath p (count vertices, the last one left toward w with weight alpha) by a random walk, up to `cap`
 * vertices, with or without Russian roulette; a light subpath carries flux.  Returns the new count. */
int extend(const scene *s, path_vertex *p, int count, int cap, vec3 alpha, vec3 w, bool roulette, bool flux, rng *g,
           uint64_t *rays);

/* A light subpath y of at most st->light_cap vertices: a light picked by power, a point, a direction, a walk. */
int light_subpath(const bidir_state *st, const scene *s, rng *g, path_vertex *y, uint64_t *rays, bool roulette);

/* The path x_0 .. x_k of strategy (s, t): y_0 .. y_{s-1}, then z_{t-1} .. z_0.  Returns k = s + t - 1. */
int join(const path_vertex *y, int s_count, const path_vertex *z, int t_count, path_vertex *x);

/* Can the method make x_0 .. x_k by joining s light to t = k + 1 - s eye vertices (or merging at x_s)? */
bool strategy_allowed(const bidir_state *st, const path_vertex *x, int k, technique how, int s);

/* (R15) The power heuristic weight of strategy `used` for x_0 .. x_k among every strategy the method has for it,
 * each made st->light_paths times a pass for t = 1 and once for t >= 2. */
double mis_weight(const bidir_state *st, const scene *s, const path_vertex *x, int k, technique how, int used);

/* The unweighted value of strategy (s, t) on subpaths y, z ((R13) over (R14)); t = 1: light tracing, divided by
 * st->light_paths, its pixel in *pixel. */
vec3 strategy_value(const bidir_state *st, const scene *s, const path_vertex *y, int s_count, const path_vertex *z,
                    int t, int *pixel, uint64_t *rays);

#endif
