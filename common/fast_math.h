/* fast_math.h — the project's one fast-math file: measured speed tricks
 * for functions whose library versions showed up in profiles.
 *
 * Read sampling.h's formulas with the library functions in mind: each
 * function here returns what they would, to about an ulp, only faster.
 *
 * unit_circle(u) = (cos 2 pi u, sin 2 pi u), the point at turn u of the unit
 * circle: every direction sampler (sampling.h) needs one.  glibc's sincos
 * took 10 % of chapter 4's time on smallpt's scene (perf, 1 thread): it
 * reduces any angle, with tables and branches, where here the angle is a
 * fraction of a turn, u in [0, 1), whose reduction is exact:
 *   - 4u = q + f, q the quarter turn (0..3) and f in [0, 1) its fraction,
 *     both exact (a power-of-two multiple, then an integer part);
 *   - within a quarter, f > 1/2 is the complement of 1 - f (exact too), so
 *     the angle x = (pi / 2) min(f, 1 - f) is at most pi / 4;
 *   - there, Taylor series to x^15 and x^16 (the next terms are below 5e-17)
 *     in y = x^2, summed by Estrin's scheme (pairs of terms, then pairs of
 *     pairs: a chain of four steps where Horner's rule has eight);
 *   - the quarter turn q swaps and negates cos and sin, by bit masks: q and
 *     the complement are coin flips, which branches would mispredict.
 * Each comes out within a few 1e-16 of the library's (tests/test_common.c
 * compares them over a million turns). */
#ifndef COMMON_FAST_MATH_H
#define COMMON_FAST_MATH_H

#include <stdint.h>
#include <string.h>

#include "vec.h" /* M_PI */

typedef struct {
    double cos, sin;
} circle_point;

static inline circle_point unit_circle(double u)
{
    double quarters = 4.0 * u;
    int q = (int)quarters & 3; /* & 3: u = 1 (outside the range) is the turn's start, not a fifth quarter */
    double f = quarters - (int)quarters;
    int complement = f > 0.5;
    double rest = 1.0 - f;
    double x = (f < rest ? f : rest) * (M_PI / 2.0); /* min(f, 1 - f): a min instruction */
    double y = x * x, y2 = y * y, y4 = y2 * y2;
    double s =
        x * ((1.0 + y * (-1.0 / 6)) + y2 * (1.0 / 120 + y * (-1.0 / 5040)) +
             y4 * ((1.0 / 362880 + y * (-1.0 / 39916800)) + y2 * (1.0 / 6227020800 + y * (-1.0 / 1307674368000))));
    double c = (1.0 + y * (-1.0 / 2)) + y2 * (1.0 / 24 + y * (-1.0 / 720)) +
               y4 * ((1.0 / 40320 + y * (-1.0 / 3628800)) + y2 * (1.0 / 479001600 + y * (-1.0 / 87178291200))) +
               y4 * y4 * (1.0 / 20922789888000);
    /* Each quarter turn maps (cos, sin) to (-sin, cos); the complement swaps them.  By bit masks: GCC compiled
     * selects of doubles here to branches, three coin flips a direction (cachegrind). */
    uint64_t swap = -(uint64_t)(complement ^ (q & 1)), c_bits, s_bits;
    memcpy(&c_bits, &c, sizeof c_bits);
    memcpy(&s_bits, &s, sizeof s_bits);
    uint64_t cos_bits = (s_bits & swap) | (c_bits & ~swap), sin_bits = (c_bits & swap) | (s_bits & ~swap);
    cos_bits ^= (uint64_t)(q == 1 || q == 2) << 63; /* the signs of the quarters 1, 2 (cos) and 2, 3 (sin) */
    sin_bits ^= (uint64_t)(q >= 2) << 63;
    circle_point p;
    memcpy(&p.cos, &cos_bits, sizeof p.cos);
    memcpy(&p.sin, &sin_bits, sizeof p.sin);
    return p;
}

#endif
