/* fuzz_scene.c — libFuzzer target for the .scene parser (make fuzz).
 *
 * Each input is written to a file and loaded with scene_load(): it must
 * either load (and then survive a few ray queries) or fail with one
 * "file:line: message" line, without any sanitizer report.  Inputs that
 * crash are saved by libFuzzer into tests/fuzz/findings/, which `make test`
 * replays through every chapter (tests/grade_bad_input.py).
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "scene.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static char path[64];
    if (!path[0])
        snprintf(path, sizeof path, "/tmp/fuzz_scene_%ld.scene", (long)getpid());
    FILE *f = fopen(path, "wb");
    if (!f)
        return 0;
    fwrite(data, 1, size, f);
    fclose(f);
    scene s;
    char err[1024];
    if (scene_load(path, &s, err, sizeof err) == 0) {
        for (int i = 0; i < 16; i++) {
            ray r = camera_ray(&s.camera, 4, 4, (i % 4) + 0.5, (i / 4) + 0.5);
            hit h;
            scene_intersect(&s, r, INFINITY, &h);
        }
        scene_free(&s);
    } else if (strncmp(err, path, strlen(path)) != 0 || strchr(err, '\n')) {
        /* Every error must name the file (or an OBJ it references) and be one line. */
        if (!strstr(err, ".obj:"))
            abort();
    }
    return 0;
}
