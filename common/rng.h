/* rng.h — a small deterministic random number generator.
 *
 * PCG (O'Neill 2014, pcg-random.org): a 64-bit linear congruential generator
 * whose state is scrambled by an output permutation, seeded per (seed, pixel,
 * sample) by a 64-bit hash.  Every sample of every pixel therefore has its
 * own stream that does not depend on which thread renders it or in which
 * order: an image is bit-identical for any --threads.
 *
 * The state can be read out two ways, both from O'Neill's paper:
 *   rng_next_u32  PCG-XSH-RR 64/32, the classic pcg32: 32 bits per step;
 *   rng_next_u64  PCG-RXS-M-XS 64/64: all 64 bits from one step, which is
 *                 what a uniform double (53 bits) needs.  A path tracer draws
 *                 some ten numbers per path vertex, so one step per number
 *                 rather than two matters.
 *
 * Primary sample space (Kelemen et al. 2002; chapter 7): a generator given a
 * `replay` vector hands out its stored numbers u_0, u_1, ... in order instead,
 * so that the code that draws a path is a function of that vector; past the
 * stored ones it draws fresh numbers and stores them.  One test of a pointer
 * per number, measured as no cost to the other chapters.
 */
#ifndef COMMON_RNG_H
#define COMMON_RNG_H

#include <stdint.h>

typedef struct primary_samples primary_samples;
typedef struct {
    uint64_t state, increment;
    primary_samples *replay; /* NULL: the generator's own numbers */
} rng;

/* A vector of uniform numbers in [0, 1) read in order (next).  The first
 * `count` are given; a read past them takes a number from `fresh` and, while
 * there is room, stores it (capacity; past that it is not kept). */
struct primary_samples {
    double *u;
    int count, capacity, next;
    rng fresh;
};

/* SplitMix64 finaliser: spreads nearby integers (pixel 17, pixel 18) to
 * unrelated 64-bit values. */
static inline uint64_t hash64(uint64_t x)
{
    x += 0x9e3779b97f4a7c15ull;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
    return x ^ (x >> 31);
}

/* Advance the LCG and return the state it left. */
static inline uint64_t rng_step(rng *g)
{
    uint64_t old = g->state;
    g->state = old * 6364136223846793005ull + g->increment;
    return old;
}

static inline uint32_t rng_next_u32(rng *g)
{
    uint64_t old = rng_step(g);
    uint32_t xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((-rot) & 31u));
}

static inline uint64_t rng_next_u64(rng *g)
{
    uint64_t old = rng_step(g);
    uint64_t word = ((old >> ((old >> 59u) + 5u)) ^ old) * 12605985483452484001ull;
    return (word >> 43u) ^ word;
}

/* A stream for sample `sample` of item `index` (pixel, probe, patch ...). */
static inline rng rng_for(uint64_t seed, uint64_t index, uint64_t sample)
{
    rng g = {.state = 0, .increment = (hash64(seed ^ 0x5851f42d4c957f2dull) << 1u) | 1u, .replay = NULL};
    uint64_t init = hash64(hash64(seed) ^ hash64(index + 0x632be59bd9b4e019ull) ^ (sample * 0xd1342543de82ef95ull));
    rng_step(&g);
    g.state += init;
    rng_step(&g);
    return g;
}

/* Uniform double in [0, 1): the top 53 bits of one 64-bit output (converted
 * through int64_t, which the hardware does in one instruction; they fit). */
static inline double rng_fresh_uniform(rng *g)
{
    return (double)(int64_t)(rng_next_u64(g) >> 11) * (1.0 / 9007199254740992.0);
}

/* The next number of a replayed vector (primary_samples). */
static inline double primary_sample_next(primary_samples *p)
{
    if (p->next < p->count)
        return p->u[p->next++];
    double u = rng_fresh_uniform(&p->fresh);
    if (p->next < p->capacity) {
        p->u[p->next] = u;
        p->count = p->next + 1;
    }
    p->next++;
    return u;
}

static inline double rng_uniform(rng *g) { return g->replay ? primary_sample_next(g->replay) : rng_fresh_uniform(g); }

#endif
