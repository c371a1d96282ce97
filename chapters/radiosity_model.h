/* radiosity_model.h — what chapter 03c (hierarchical radiosity) uses of
 * chapter 3's lecture.
 *
 * Defined in chapters/03_radiosity.c, where lecture 3 reads it: Lambert's
 * closed form of the inner integral of the form factor (R10).  Chapter 03c
 * computes its links' form factors and its oracle's estimates with exactly
 * this function; the Makefile links chapter 3's object into it (with
 * chapter 3's main renamed), so neither chapter includes the other.
 */
#ifndef CHAPTERS_RADIOSITY_MODEL_H
#define CHAPTERS_RADIOSITY_MODEL_H

#include "vec.h"

/* The form factor from a differential area at x (unit normal n) to a
 * polygon (count corners, at most 8 after clipping to n's half-space), by
 * Lambert's contour formula (chapter 3's exercise 3.1). */
double point_to_polygon(vec3 x, vec3 n, const vec3 *polygon, int count);

#endif
