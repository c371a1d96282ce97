/* ply.c — reading a PLY mesh for the --ply panel. */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "viewer.h"

/* PLY (ascii or binary_little_endian): vertex x y z and a colour (float
 * radiance r g b, red green blue, radiance_r ...; uchar colours are taken as
 * sRGB and decoded), faces as index lists (fans).  Enough for radiosity's
 * output, Blender's and MeshLab's. */
typedef struct {
    char name[64];
    int type;
    int list_count_type;
} ply_property; /* type: 0 none 1 int 2 float 3 uchar... */

enum { PLY_CHAR, PLY_UCHAR, PLY_SHORT, PLY_USHORT, PLY_INT, PLY_UINT, PLY_FLOAT, PLY_DOUBLE, PLY_BAD };

static int ply_type(const char *t)
{
    static const char *names[][2] = {{"char", "int8"}, {"uchar", "uint8"}, {"short", "int16"},   {"ushort", "uint16"},
                                     {"int", "int32"}, {"uint", "uint32"}, {"float", "float32"}, {"double", "float64"}};
    for (int i = 0; i < PLY_BAD; i++)
        if (!strcmp(t, names[i][0]) || !strcmp(t, names[i][1]))
            return i;
    return PLY_BAD;
}

static double ply_read(FILE *f, int type, bool ascii, bool *ok)
{
    if (ascii) {
        double v;
        if (fscanf(f, "%lf", &v) != 1)
            *ok = false;
        return *ok ? v : 0.0;
    }
    static const int sizes[] = {1, 1, 2, 2, 4, 4, 4, 8};
    unsigned char b[8] = {0};
    if (fread(b, 1, (size_t)sizes[type], f) != (size_t)sizes[type]) {
        *ok = false;
        return 0.0;
    }
    uint64_t u = 0;
    for (int i = sizes[type] - 1; i >= 0; i--)
        u = u << 8 | b[i];
    switch (type) {
    case PLY_CHAR: return (double)(int8_t)u;
    case PLY_UCHAR: return (double)(uint8_t)u;
    case PLY_SHORT: return (double)(int16_t)u;
    case PLY_USHORT: return (double)(uint16_t)u;
    case PLY_INT: return (double)(int32_t)u;
    case PLY_UINT: return (double)(uint32_t)u;
    case PLY_FLOAT: {
        uint32_t w = (uint32_t)u;
        float x;
        memcpy(&x, &w, 4);
        return x;
    }
    default: {
        double x;
        memcpy(&x, &u, 8);
        return x;
    }
    }
}

static double srgb_decode(double v) { return v <= 0.04045 ? v / 12.92 : pow((v + 0.055) / 1.055, 2.4); }

/* What the header says: the format, the elements and their properties. */
typedef struct {
    const char *path;
    int line_number;
    bool ascii, binary;
    long vertex_count, face_count;
    ply_property vertex[32], face[8];
    int vertex_properties, face_properties;
    int x, y, z, red, green, blue; /* which vertex properties hold the position and the colour */
} ply_header;

/* One `property` line of the current element (1 vertex, 2 face). */
static int ply_property_line(ply_header *h, int element, const char *a, const char *b, const char *c, const char *d,
                             char *err, size_t err_size)
{
    ply_property pr = {.type = PLY_BAD, .list_count_type = -1};
    if (!strcmp(a, "list")) {
        pr.list_count_type = ply_type(b);
        pr.type = ply_type(c);
        snprintf(pr.name, sizeof pr.name, "%s", d);
    } else {
        pr.type = ply_type(a);
        snprintf(pr.name, sizeof pr.name, "%s", b);
    }
    if (pr.type == PLY_BAD || (pr.list_count_type != -1 && pr.list_count_type == PLY_BAD)) {
        snprintf(err, err_size, "%s:%d: unknown property type", h->path, h->line_number);
        return 2;
    }
    if (element == 1 && h->vertex_properties < 32 && pr.list_count_type == -1)
        h->vertex[h->vertex_properties++] = pr;
    else if (element == 2 && h->face_properties < 8)
        h->face[h->face_properties++] = pr;
    else {
        snprintf(err, err_size, "%s:%d: unsupported property", h->path, h->line_number);
        return 2;
    }
    return 0;
}

static int ply_read_header(FILE *f, ply_header *h, char *err, size_t err_size)
{
    char line[512];
    int element = 0; /* 1 vertex, 2 face, 3 other element */
    if (!fgets(line, sizeof line, f) || strncmp(line, "ply", 3)) {
        snprintf(err, err_size, "%s:1: not a PLY file (no 'ply' line)", h->path);
        return 2;
    }
    h->line_number = 1;
    while (fgets(line, sizeof line, f)) {
        h->line_number++;
        char word[64] = "", a[64] = "", b[64] = "", c[64] = "", d[64] = "";
        int n = sscanf(line, "%63s %63s %63s %63s %63s", word, a, b, c, d);
        if (n <= 0 || !strcmp(word, "comment") || !strcmp(word, "obj_info"))
            continue;
        if (!strcmp(word, "end_header"))
            break;
        if (!strcmp(word, "format")) {
            h->ascii = !strcmp(a, "ascii");
            h->binary = !strcmp(a, "binary_little_endian");
            if (!h->ascii && !h->binary) {
                snprintf(err, err_size, "%s:%d: format %s is not supported (ascii, binary_little_endian)", h->path,
                         h->line_number, a);
                return 2;
            }
        } else if (!strcmp(word, "element")) {
            long count = atol(b);
            element = !strcmp(a, "vertex") ? 1 : !strcmp(a, "face") ? 2 : 3;
            if (element == 1)
                h->vertex_count = count;
            else if (element == 2)
                h->face_count = count;
            else if (count > 0) {
                snprintf(err, err_size, "%s:%d: element %s is not supported", h->path, h->line_number, a);
                return 2;
            }
        } else if (!strcmp(word, "property") && ply_property_line(h, element, a, b, c, d, err, err_size)) {
            return 2;
        }
    }
    if (h->vertex_count <= 0 || (!h->ascii && !h->binary)) {
        snprintf(err, err_size, "%s:%d: no vertices or no format in the header", h->path, h->line_number);
        return 2;
    }
    return 0;
}

/* Which vertex properties are the position and the colour.  In order of
 * preference: linear radiance before display colours (radiosity writes
 * both: radiance_r ... and uchar red ...). */
static int ply_find_columns(ply_header *h, char *err, size_t err_size)
{
    static const char *red[] = {"radiance_r", "radiance_red", "L_r", "r", "red"},
                      *green[] = {"radiance_g", "radiance_green", "L_g", "g", "green"},
                      *blue[] = {"radiance_b", "radiance_blue", "L_b", "b", "blue"};
    int rank_r = 99, rank_g = 99, rank_b = 99;
    h->x = h->y = h->z = h->red = h->green = h->blue = -1;
    for (int i = 0; i < h->vertex_properties; i++) {
        const char *name = h->vertex[i].name;
        h->x = !strcmp(name, "x") ? i : h->x;
        h->y = !strcmp(name, "y") ? i : h->y;
        h->z = !strcmp(name, "z") ? i : h->z;
        for (int k = 0; k < 5; k++) {
            if (!strcmp(name, red[k]) && k < rank_r)
                h->red = i, rank_r = k;
            if (!strcmp(name, green[k]) && k < rank_g)
                h->green = i, rank_g = k;
            if (!strcmp(name, blue[k]) && k < rank_b)
                h->blue = i, rank_b = k;
        }
    }
    if (h->x < 0 || h->y < 0 || h->z < 0 || h->red < 0 || h->green < 0 || h->blue < 0) {
        snprintf(err, err_size, "%s:%d: vertices need x y z and a colour (r g b, red green blue or radiance_r ...)",
                 h->path, h->line_number);
        return 2;
    }
    return 0;
}

/* Six doubles a vertex: x y z and linear r g b; the bounds into lo, hi. */
static int ply_read_vertices(FILE *f, const ply_header *h, double *out, vec3 *lo, vec3 *hi, char *err, size_t err_size)
{
    const int column[6] = {h->x, h->y, h->z, h->red, h->green, h->blue};
    bool ok = true;
    *lo = v3_splat(INFINITY), *hi = v3_splat(-INFINITY);
    for (long i = 0; i < h->vertex_count && ok; i++, out += 6) {
        for (int k = 0; k < h->vertex_properties; k++) {
            double x = ply_read(f, h->vertex[k].type, h->ascii, &ok);
            for (int c = 0; c < 6; c++)
                if (k == column[c]) /* a byte colour is sRGB */
                    out[c] = c >= 3 && h->vertex[k].type == PLY_UCHAR ? srgb_decode(x / 255.0) : x;
        }
        *lo = v3_min(*lo, v3(out[0], out[1], out[2]));
        *hi = v3_max(*hi, v3(out[0], out[1], out[2]));
    }
    if (!ok) {
        snprintf(err, err_size, "%s:0: truncated vertex data", h->path);
        return 2;
    }
    return 0;
}

/* One face's vertex indices (at most 64; other face properties skipped). */
static int ply_read_face(FILE *f, const ply_header *h, long indices[64], bool *ok)
{
    int count = 0;
    for (int k = 0; k < h->face_properties && *ok; k++) {
        const ply_property *pr = &h->face[k];
        if (pr->list_count_type < 0) {
            ply_read(f, pr->type, h->ascii, ok);
            continue;
        }
        int n = (int)ply_read(f, pr->list_count_type, h->ascii, ok);
        bool is_indices = !strcmp(pr->name, "vertex_indices") || !strcmp(pr->name, "vertex_index");
        for (int j = 0; j < n && *ok; j++) {
            double x = ply_read(f, pr->type, h->ascii, ok);
            if (is_indices && count < 64)
                indices[count++] = (long)x;
        }
    }
    return count;
}

/* A growing array of mesh vertices (MESH_FLOATS floats each). */
typedef struct {
    float *v;
    size_t used, capacity;
} vertex_list;

/* Corner: position, and the radiance as emission (the PLY panel is unlit). */
static bool put_corner(vertex_list *list, const double *d)
{
    if (list->used + 1 > list->capacity) {
        size_t capacity = 2 * list->capacity + 3;
        float *bigger = realloc(list->v, capacity * MESH_FLOATS * sizeof(float));
        if (!bigger)
            return false;
        list->v = bigger, list->capacity = capacity;
    }
    float *out = list->v + MESH_FLOATS * list->used++;
    memset(out, 0, MESH_FLOATS * sizeof(float));
    out[0] = (float)d[0], out[1] = (float)d[1], out[2] = (float)d[2];
    out[13] = (float)d[3], out[14] = (float)d[4], out[15] = (float)d[5];
    return true;
}

/* The faces as triangle fans into list. */
static int ply_read_faces(FILE *f, const ply_header *h, const double *vertex_data, vertex_list *list, char *err,
                          size_t err_size)
{
    bool ok = true, room = true;
    for (long i = 0; i < h->face_count && ok && room; i++) {
        long indices[64];
        int count = ply_read_face(f, h, indices, &ok);
        for (int j = 0; j < count; j++)
            if (indices[j] < 0 || indices[j] >= h->vertex_count) {
                snprintf(err, err_size, "%s:0: face %ld uses vertex %ld of %ld", h->path, i, indices[j],
                         h->vertex_count);
                return 2;
            }
        for (int j = 1; j + 1 < count && room; j++) {
            const long corner[3] = {indices[0], indices[j], indices[j + 1]};
            for (int k = 0; k < 3 && room; k++)
                room = put_corner(list, vertex_data + 6 * corner[k]);
        }
    }
    if (!room || !ok) {
        snprintf(err, err_size, ok ? "%s:0: out of memory" : "%s:0: truncated face data", h->path);
        return 2;
    }
    return 0;
}

int ply_mesh(const char *path, mesh *m, vec3 *lo, vec3 *hi, char *err, size_t err_size)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, err_size, "%s:0: cannot open: %s", path, strerror(errno));
        return 2;
    }
    ply_header h = {.path = path, .vertex_count = -1};
    double *vertex_data = NULL;
    vertex_list list = {0};
    int status = ply_read_header(f, &h, err, err_size);
    if (!status)
        status = ply_find_columns(&h, err, err_size);
    if (!status) {
        vertex_data = malloc((size_t)h.vertex_count * 6 * sizeof(double));
        if (!vertex_data) {
            snprintf(err, err_size, "%s:0: out of memory", path);
            status = 2;
        }
    }
    if (!status)
        status = ply_read_vertices(f, &h, vertex_data, lo, hi, err, err_size);
    if (!status)
        status = ply_read_faces(f, &h, vertex_data, &list, err, err_size);
    if (!status)
        mesh_upload(m, list.v, (int)list.used);
    free(list.v);
    free(vertex_data);
    fclose(f);
    return status;
}
