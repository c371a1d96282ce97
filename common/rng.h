/* rng.h — a small deterministic random number generator.
 *
 * PCG32 (O'Neill 2014, pcg-random.org), seeded per (seed, pixel, sample) by a
 * 64-bit hash.  Every sample of every pixel therefore has its own stream that
 * does not depend on which thread renders it or in which order: an image is
 * bit-identical for any --threads.
 */
#ifndef COMMON_RNG_H
#define COMMON_RNG_H

#include <stdint.h>

typedef struct { uint64_t state, increment; } rng;

/* SplitMix64 finaliser: spreads nearby integers (pixel 17, pixel 18) to
 * unrelated 64-bit values. */
static inline uint64_t hash64(uint64_t x)
{
    x += 0x9e3779b97f4a7c15ull;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
    return x ^ (x >> 31);
}

static inline uint32_t rng_next_u32(rng *g)
{
    uint64_t old = g->state;
    g->state = old * 6364136223846793005ull + g->increment;
    uint32_t xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((-rot) & 31u));
}

/* A stream for sample `sample` of item `index` (pixel, probe, patch ...). */
static inline rng rng_for(uint64_t seed, uint64_t index, uint64_t sample)
{
    rng g = {.state = 0, .increment = (hash64(seed ^ 0x5851f42d4c957f2dull) << 1u) | 1u};
    uint64_t init = hash64(hash64(seed) ^ hash64(index + 0x632be59bd9b4e019ull) ^ (sample * 0xd1342543de82ef95ull));
    rng_next_u32(&g);
    g.state += init;
    rng_next_u32(&g);
    return g;
}

/* Uniform double in [0, 1): 53 random bits from two outputs. */
static inline double rng_uniform(rng *g)
{
    uint64_t hi = rng_next_u32(g) >> 5; /* 27 bits */
    uint64_t lo = rng_next_u32(g) >> 6; /* 26 bits */
    return (double)((hi << 26) | lo) * (1.0 / 9007199254740992.0);
}

#endif
