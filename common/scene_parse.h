/* scene_parse.h — private to common/: the .scene and OBJ parser.
 *
 * scene_load() (scene.c) sets the defaults, calls scene_parse(), then
 * computes what follows from the geometry and builds the BVH.
 */
#ifndef COMMON_SCENE_PARSE_H
#define COMMON_SCENE_PARSE_H

#include <stddef.h>

#include "scene.h"

/* Reads the scene file at `path` (and its OBJ meshes) into *out: camera,
 * image size, background, materials, surfaces and their triangles, lights,
 * probes.  Returns 0, or 2 with one line "file:line: message" in err; either
 * way *out may hold allocations (scene_free releases them).  *lines is the
 * number of lines read, for errors found after parsing. */
int scene_parse(const char *path, scene *out, char *err, size_t err_size, int *lines);

/* Writes "path:line: message" into err (one line) and returns 2. */
int scene_parse_error(const char *path, int line, char *err, size_t err_size, const char *message);

#endif
