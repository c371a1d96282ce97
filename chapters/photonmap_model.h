/* photonmap_model.h — what chapter 6 uses of lecture 5 (photon mapping).
 *
 * Defined in chapters/05_photonmap.c, where lecture 5 reads it: a photon
 * carries flux, and chapter 4's scattering weight is one for radiance
 * (as_flux undoes the (n_i / n_t)^2 of a refraction).  Chapter 6's light
 * subpaths are photons: they carry flux the same way.  The photon grid
 * itself (which photons lie within r of x?) is infrastructure, in
 * common/photon_grid.h, for both chapters.  The Makefile links chapter 5's
 * object into chapter 6 (with chapter 5's main renamed), so neither chapter
 * includes the other.
 */
#ifndef CHAPTERS_PHOTONMAP_MODEL_H
#define CHAPTERS_PHOTONMAP_MODEL_H

#include "pathtrace_model.h"

/* The weight of one scattering at v toward w_i for a carrier of flux, from
 * chapter 4's weight for radiance (the same but for refraction into glass). */
vec3 as_flux(const vertex *v, vec3 radiance_weight, vec3 w_i);

#endif
