/* scene.c — the .scene parser, OBJ meshes, the BVH, and ray intersection.
 *
 * Reading order: small helpers (errors, numbers, growing arrays), the line
 * reader, one function per statement, the OBJ reader, what is computed after
 * parsing (triangles, areas, bounds, epsilon), the BVH build, the ray
 * queries, sampling and the camera.
 */
#include "scene.h"

#include <errno.h>
#include <float.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sampling.h"

#ifdef __SSE2__
#include <emmintrin.h> /* two-wide double SIMD for the BVH box tests */
#endif

/* Lines longer than this are rejected (a scene line is far shorter; a
 * longer one is almost certainly not a scene file). */
enum { LINE_CAPACITY = 4096 };
/* A line of LINE_CAPACITY characters has at most half as many fields
 * (an OBJ polygon may have many corners). */
enum { MAX_FIELDS = LINE_CAPACITY / 2 + 1 };
enum { PATH_CAPACITY = 4096 };
/* BVH: at most this many primitives in a leaf, this many SAH bins (with 16
 * the Cornell box's tree costs incoherent rays 3% more node visits). */
enum { BVH_LEAF_SIZE = 4, BVH_BINS = 64 };
/* Past this depth the build splits in the middle of the list, so the tree
 * depth (and the traversal stack) stays bounded whatever the input. */
enum { BVH_SAH_MAX_DEPTH = 48, BVH_STACK_SIZE = 128 };

/* A triangle (or quad half) counts as degenerate when its area is below this
 * fraction of the squared size of its bounding box: collinear or coincident
 * vertices up to rounding. */
static const double DEGENERATE_AREA = 1e-12;
/* A quad is planar when its 4th vertex is within this fraction of its size
 * from the plane of the first three. */
static const double PLANARITY_TOLERANCE = 1e-6;
/* Triangles intersect with a margin of this fraction of scene.epsilon
 * around their edges (see triangle_transform): 1e-11 of the scene, five
 * orders of magnitude above the rounding it covers, and small enough that
 * ray origins moved off a surface by epsilon stay outside the BVH boxes,
 * which grow by the margin too (see bvh_primitive_bounds). */
static const double EDGE_MARGIN = 1e-2;

/* ------------------------------------------------------------------------ */
/* Errors                                                                    */

typedef struct {
    const char *path; /* file being read (scene or OBJ) */
    int line;
    char *err;
    size_t err_size;
} error_context;

/* Write "path:line: message" into err and return 2 (the exit status of a
 * bad input), so callers can write `return fail(...)`. */
static int fail(const error_context *ctx, const char *format, ...)
{
    if (ctx->err == NULL || ctx->err_size == 0) return 2;
    int n = snprintf(ctx->err, ctx->err_size, "%s:%d: ", ctx->path, ctx->line);
    if (n >= 0 && (size_t)n < ctx->err_size) {
        va_list args;
        va_start(args, format);
        vsnprintf(ctx->err + n, ctx->err_size - (size_t)n, format, args);
        va_end(args);
    }
    /* One line, whatever the message contains (names come from the file). */
    for (char *c = ctx->err; *c; c++)
        if (*c == '\n' || *c == '\r') *c = ' ';
    return 2;
}

/* ------------------------------------------------------------------------ */
/* Growing arrays                                                            */

/* Make room for one more element in *array (count used, *capacity
 * allocated).  Returns 0 on success, -1 when out of memory. */
static int reserve_one(void **array, int *capacity, int count, size_t element_size)
{
    if (count < *capacity) return 0;
    if (*capacity > INT_MAX / 2) return -1;
    int new_capacity = *capacity ? 2 * *capacity : 16;
    void *grown = realloc(*array, (size_t)new_capacity * element_size);
    if (grown == NULL) return -1;
    *array = grown;
    *capacity = new_capacity;
    return 0;
}

/* ------------------------------------------------------------------------ */
/* Reading lines and fields                                                  */

typedef enum { LINE_OK, LINE_END, LINE_TOO_LONG, LINE_BINARY } line_status;

/* Read one line (without its newline) into buffer.  Control characters
 * other than tab and carriage return mean the file is not text. */
static line_status read_line(FILE *file, char *buffer, size_t capacity)
{
    size_t length = 0;
    int c = getc(file);
    if (c == EOF) return LINE_END;
    while (c != EOF && c != '\n') {
        unsigned char byte = (unsigned char)c;
        if ((byte < 0x20 && byte != '\t' && byte != '\r' && byte != '\f' && byte != '\v') || byte == 0x7f)
            return LINE_BINARY;
        if (length + 1 >= capacity) return LINE_TOO_LONG;
        buffer[length++] = (char)c;
        c = getc(file);
    }
    buffer[length] = '\0';
    return LINE_OK;
}

static int fail_line(const error_context *ctx, line_status status)
{
    if (status == LINE_TOO_LONG) return fail(ctx, "line longer than %d characters", LINE_CAPACITY - 1);
    return fail(ctx, "binary data (control character or NUL byte): not a text file");
}

typedef struct {
    char *field[MAX_FIELDS];
    int count;
} fields;

static int is_blank(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }

/* Cut a line at '#' and split it at blanks, in place. */
static void split_fields(char *line, fields *f)
{
    f->count = 0;
    char *comment = strchr(line, '#');
    if (comment) *comment = '\0';
    char *c = line;
    for (;;) {
        while (is_blank(*c)) c++;
        if (*c == '\0') break;
        f->field[f->count++] = c; /* cannot overflow: fields are separated by blanks */
        while (*c && !is_blank(*c)) c++;
        if (*c == '\0') break;
        *c++ = '\0';
    }
}

/* A finite double filling the whole field ("1e400", "nan", "inf", "3x" fail). */
static int parse_number(const error_context *ctx, const char *text, const char *what, double *out)
{
    char *end;
    *out = 0.0; /* defined even on error */
    errno = 0;
    double value = strtod(text, &end);
    if (end == text || *end != '\0') return fail(ctx, "%s: '%s' is not a number", what, text);
    if (!isfinite(value) || (errno == ERANGE && fabs(value) > 1.0))
        return fail(ctx, "%s: '%s' is not a finite number", what, text);
    *out = value;
    return 0;
}

static int parse_vec3(const error_context *ctx, char **text, const char *what, vec3 *out)
{
    double x, y, z;
    if (parse_number(ctx, text[0], what, &x) || parse_number(ctx, text[1], what, &y) ||
        parse_number(ctx, text[2], what, &z))
        return 2;
    *out = v3(x, y, z);
    return 0;
}

/* A colour whose channels must lie in [0, 1] (reflectances). */
static int parse_reflectance(const error_context *ctx, char **text, const char *what, vec3 *out)
{
    if (parse_vec3(ctx, text, what, out)) return 2;
    if (v3_min_component(*out) < 0.0 || v3_max_component(*out) > 1.0)
        return fail(ctx, "%s %g %g %g: each channel must be in [0, 1]", what, out->x, out->y, out->z);
    return 0;
}

/* A colour whose channels must be >= 0 (radiance, intensity). */
static int parse_nonnegative(const error_context *ctx, char **text, const char *what, vec3 *out)
{
    if (parse_vec3(ctx, text, what, out)) return 2;
    if (v3_min_component(*out) < 0.0)
        return fail(ctx, "%s %g %g %g: must not be negative", what, out->x, out->y, out->z);
    return 0;
}

static int expect_keyword(const error_context *ctx, const char *text, const char *keyword, const char *usage)
{
    if (strcmp(text, keyword) != 0) return fail(ctx, "expected '%s' but found '%s'; usage: %s", keyword, text, usage);
    return 0;
}

static int expect_field_count(const error_context *ctx, const fields *f, int expected, const char *usage)
{
    if (f->count != expected)
        return fail(ctx, "%s field%s (%d after '%s', expected %d); usage: %s", f->count < expected ? "missing" : "extra",
                    abs(f->count - expected) == 1 ? "" : "s", f->count - 1, f->field[0], expected - 1, usage);
    return 0;
}

/* ------------------------------------------------------------------------ */
/* The parser's state                                                        */

typedef struct {
    scene *s;
    error_context ctx;
    char directory[PATH_CAPACITY]; /* of the scene file, for mesh paths */
    int has_camera;
    int material_capacity, surface_capacity, triangle_capacity, light_capacity, probe_capacity;
} parser;

static int out_of_memory(parser *p) { return fail(&p->ctx, "out of memory"); }

static int check_name(parser *p, const char *name)
{
    if (strlen(name) >= SCENE_NAME_MAX) return fail(&p->ctx, "name '%.20s...' longer than %d characters", name, SCENE_NAME_MAX - 1);
    return 0;
}

static int find_material(const scene *s, const char *name)
{
    for (int i = 0; i < s->material_count; i++)
        if (strcmp(s->materials[i].name, name) == 0) return i;
    return -1;
}

/* Surfaces, lights and probes share one namespace: graders ask by name. */
static int check_object_name(parser *p, const char *name)
{
    if (check_name(p, name)) return 2;
    const scene *s = p->s;
    int taken = scene_find_surface(s, name) >= 0;
    for (int i = 0; i < s->light_count && !taken; i++) taken = strcmp(s->lights[i].name, name) == 0;
    for (int i = 0; i < s->probe_count && !taken; i++) taken = strcmp(s->probes[i].name, name) == 0;
    if (taken) return fail(&p->ctx, "duplicate name '%s' (surfaces, lights and probes need distinct names)", name);
    return 0;
}

static int material_reference(parser *p, const char *name, int *index)
{
    *index = find_material(p->s, name);
    if (*index < 0) return fail(&p->ctx, "unknown material '%s' (materials must be defined before use)", name);
    return 0;
}

/* ------------------------------------------------------------------------ */
/* Statements                                                                */

static int parse_camera(parser *p, fields *f)
{
    static const char usage[] = "camera eye X Y Z look X Y Z up X Y Z fov DEGREES";
    const error_context *ctx = &p->ctx;
    if (p->has_camera) return fail(ctx, "second camera statement (a scene has one camera)");
    if (expect_field_count(ctx, f, 15, usage)) return 2;
    camera c;
    if (expect_keyword(ctx, f->field[1], "eye", usage) || parse_vec3(ctx, f->field + 2, "camera eye", &c.eye) ||
        expect_keyword(ctx, f->field[5], "look", usage) || parse_vec3(ctx, f->field + 6, "camera look", &c.look) ||
        expect_keyword(ctx, f->field[9], "up", usage) || parse_vec3(ctx, f->field + 10, "camera up", &c.up) ||
        expect_keyword(ctx, f->field[13], "fov", usage) ||
        parse_number(ctx, f->field[14], "camera fov", &c.fov_degrees))
        return 2;
    vec3 view = v3_sub(c.look, c.eye);
    double view_length = v3_length(view), up_length = v3_length(c.up);
    if (!(view_length > 0.0)) return fail(ctx, "camera eye and look are the same point");
    if (!(up_length > 0.0)) return fail(ctx, "camera up is the zero vector");
    /* sin of the angle between view and up; near 0 leaves "right" undefined. */
    if (v3_length(v3_cross(view, c.up)) <= 1e-9 * view_length * up_length)
        return fail(ctx, "camera up is parallel to the view direction");
    if (!(c.fov_degrees > 0.0 && c.fov_degrees < 180.0))
        return fail(ctx, "camera fov %g: must be between 0 and 180 degrees (exclusive)", c.fov_degrees);
    p->s->camera = c;
    p->has_camera = 1;
    return 0;
}

static int parse_image_size(const error_context *ctx, const char *text, int *out)
{
    char *end;
    errno = 0;
    long value = strtol(text, &end, 10);
    if (end == text || *end != '\0') return fail(ctx, "image size '%s' is not an integer", text);
    if (errno == ERANGE || value < 1 || value > 65536) return fail(ctx, "image size '%s' must be in 1..65536", text);
    *out = (int)value;
    return 0;
}

static int parse_image(parser *p, fields *f)
{
    if (expect_field_count(&p->ctx, f, 3, "image WIDTH HEIGHT")) return 2;
    if (parse_image_size(&p->ctx, f->field[1], &p->s->width) || parse_image_size(&p->ctx, f->field[2], &p->s->height))
        return 2;
    return 0;
}

static int parse_background(parser *p, fields *f)
{
    if (expect_field_count(&p->ctx, f, 4, "background R G B")) return 2;
    return parse_nonnegative(&p->ctx, f->field + 1, "background", &p->s->background);
}

static int parse_material(parser *p, fields *f)
{
    const error_context *ctx = &p->ctx;
    scene *s = p->s;
    if (f->count < 3) return fail(ctx, "missing fields; usage: material NAME diffuse|phong|mirror|glass|emitter ...");
    const char *name = f->field[1], *kind = f->field[2];
    if (check_name(p, name)) return 2;
    if (find_material(s, name) >= 0) return fail(ctx, "duplicate material name '%s'", name);

    material m = {.specular = v3_splat(0.0), .ior = 1.0};
    snprintf(m.name, sizeof m.name, "%s", name);
    if (strcmp(kind, "diffuse") == 0) {
        m.kind = MATERIAL_DIFFUSE;
        if (expect_field_count(ctx, f, 6, "material NAME diffuse R G B") ||
            parse_reflectance(ctx, f->field + 3, "diffuse albedo", &m.albedo))
            return 2;
    } else if (strcmp(kind, "phong") == 0) {
        static const char usage[] = "material NAME phong kd R G B ks R G B exp N";
        m.kind = MATERIAL_PHONG;
        if (expect_field_count(ctx, f, 13, usage) || expect_keyword(ctx, f->field[3], "kd", usage) ||
            parse_reflectance(ctx, f->field + 4, "phong kd", &m.albedo) ||
            expect_keyword(ctx, f->field[7], "ks", usage) ||
            parse_reflectance(ctx, f->field + 8, "phong ks", &m.specular) ||
            expect_keyword(ctx, f->field[11], "exp", usage) ||
            parse_number(ctx, f->field[12], "phong exponent", &m.exponent))
            return 2;
        if (m.exponent < 0.0) return fail(ctx, "phong exponent %g must not be negative", m.exponent);
    } else if (strcmp(kind, "mirror") == 0) {
        m.kind = MATERIAL_MIRROR;
        if (expect_field_count(ctx, f, 6, "material NAME mirror R G B") ||
            parse_reflectance(ctx, f->field + 3, "mirror reflectance", &m.specular))
            return 2;
    } else if (strcmp(kind, "glass") == 0) {
        m.kind = MATERIAL_GLASS;
        m.specular = v3_splat(1.0);
        if (f->count != 4 && expect_field_count(ctx, f, 7, "material NAME glass IOR [R G B]")) return 2;
        if (parse_number(ctx, f->field[3], "glass IOR", &m.ior)) return 2;
        if (!(m.ior > 0.0)) return fail(ctx, "glass IOR %g must be positive", m.ior);
        if (f->count == 7 && parse_reflectance(ctx, f->field + 4, "glass tint", &m.specular)) return 2;
    } else if (strcmp(kind, "emitter") == 0) {
        static const char usage[] = "material NAME emitter R G B [diffuse R G B]";
        m.kind = MATERIAL_EMITTER;
        if (f->count != 6 && expect_field_count(ctx, f, 10, usage)) return 2;
        if (parse_nonnegative(ctx, f->field + 3, "emitter radiance", &m.emission)) return 2;
        if (f->count == 10 && (expect_keyword(ctx, f->field[6], "diffuse", usage) ||
                               parse_reflectance(ctx, f->field + 7, "emitter diffuse albedo", &m.albedo)))
            return 2;
    } else {
        return fail(ctx, "unknown material kind '%s' (diffuse, phong, mirror, glass or emitter)", kind);
    }
    if (reserve_one((void **)&s->materials, &p->material_capacity, s->material_count, sizeof *s->materials))
        return out_of_memory(p);
    s->materials[s->material_count++] = m;
    return 0;
}

/* Area and degeneracy of triangle (a, b, c), relative to its own size. */
static double bounding_box_diagonal_squared(const vec3 *points, int count)
{
    vec3 lo = points[0], hi = points[0];
    for (int i = 1; i < count; i++) {
        lo = v3_min(lo, points[i]);
        hi = v3_max(hi, points[i]);
    }
    vec3 d = v3_sub(hi, lo);
    return v3_dot(d, d);
}

static int is_degenerate_triangle(vec3 a, vec3 b, vec3 c)
{
    vec3 points[3] = {a, b, c};
    return !(triangle_area(a, b, c) > DEGENERATE_AREA * bounding_box_diagonal_squared(points, 3));
}

/* Append triangle (a, b, c) of surface `surface` to the scene. */
static int add_triangle(parser *p, vec3 a, vec3 b, vec3 c, int surface)
{
    scene *s = p->s;
    if (reserve_one((void **)&s->triangles, &p->triangle_capacity, s->triangle_count, sizeof *s->triangles)) return -1;
    triangle t;
    t.p0 = a;
    t.e1 = v3_sub(b, a);
    t.e2 = v3_sub(c, a);
    vec3 n = v3_cross(t.e1, t.e2);
    t.area = 0.5 * v3_length(n);
    t.normal = v3_normalize(n);
    t.surface = surface;
    s->triangles[s->triangle_count++] = t;
    return 0;
}

/* Start a new named surface; the caller fills in the geometry. */
static int begin_surface(parser *p, fields *f, surface_kind kind, surface **out)
{
    scene *s = p->s;
    int material_index;
    if (check_object_name(p, f->field[1]) || material_reference(p, f->field[2], &material_index)) return 2;
    if (reserve_one((void **)&s->surfaces, &p->surface_capacity, s->surface_count, sizeof *s->surfaces))
        return out_of_memory(p);
    surface *surf = &s->surfaces[s->surface_count];
    memset(surf, 0, sizeof *surf);
    snprintf(surf->name, sizeof surf->name, "%s", f->field[1]);
    surf->kind = kind;
    surf->material = material_index;
    surf->line = p->ctx.line;
    surf->first_triangle = s->triangle_count;
    *out = surf;
    return 0;
}

static int parse_polygon(parser *p, fields *f, int vertex_count)
{
    const error_context *ctx = &p->ctx;
    const char *usage = vertex_count == 4 ? "quad NAME MATERIAL X0 Y0 Z0 X1 Y1 Z1 X2 Y2 Z2 X3 Y3 Z3"
                                          : "triangle NAME MATERIAL X0 Y0 Z0 X1 Y1 Z1 X2 Y2 Z2";
    if (expect_field_count(ctx, f, 3 + 3 * vertex_count, usage)) return 2;
    vec3 v[4];
    for (int i = 0; i < vertex_count; i++)
        if (parse_vec3(ctx, f->field + 3 + 3 * i, "vertex coordinate", &v[i])) return 2;

    if (vertex_count == 3 && is_degenerate_triangle(v[0], v[1], v[2]))
        return fail(ctx, "triangle '%s' has zero area (coincident or collinear vertices)", f->field[1]);
    if (vertex_count == 4) {
        /* Stored as triangles (v0, v1, v2) and (v0, v2, v3). */
        if (is_degenerate_triangle(v[0], v[1], v[2]) || is_degenerate_triangle(v[0], v[2], v[3]))
            return fail(ctx, "quad '%s' has zero area (coincident or collinear vertices)", f->field[1]);
        vec3 n = v3_normalize(v3_cross(v3_sub(v[1], v[0]), v3_sub(v[2], v[0])));
        double off_plane = fabs(v3_dot(v3_sub(v[3], v[0]), n));
        double size = sqrt(bounding_box_diagonal_squared(v, 4));
        if (off_plane > PLANARITY_TOLERANCE * size)
            return fail(ctx, "quad '%s' is not planar (4th vertex %g off the plane of the first three); "
                             "split it into two triangles", f->field[1], off_plane);
        vec3 n2 = v3_cross(v3_sub(v[2], v[0]), v3_sub(v[3], v[0]));
        if (v3_dot(n, n2) <= 0.0)
            return fail(ctx, "quad '%s' crosses itself or is not convex; check the vertex order", f->field[1]);
    }

    surface *surf;
    if (begin_surface(p, f, vertex_count == 4 ? SURFACE_QUAD : SURFACE_TRIANGLE, &surf)) return 2;
    int surface_index = p->s->surface_count;
    for (int i = 0; i < vertex_count; i++) surf->vertex[i] = v[i];
    surf->vertex_count = vertex_count;
    for (int i = 1; i + 1 < vertex_count; i++)
        if (add_triangle(p, v[0], v[i], v[i + 1], surface_index)) return out_of_memory(p);
    surf->triangle_count = vertex_count - 2;
    surf->parallelogram = vertex_count == 4 && v3_length(v3_sub(v3_add(v[0], v[2]), v3_add(v[1], v[3]))) <=
                                                   1e-12 * sqrt(bounding_box_diagonal_squared(v, 4));
    p->s->surface_count++;
    return 0;
}

static int parse_sphere(parser *p, fields *f)
{
    const error_context *ctx = &p->ctx;
    if (expect_field_count(ctx, f, 7, "sphere NAME MATERIAL CX CY CZ RADIUS")) return 2;
    vec3 center;
    double radius;
    if (parse_vec3(ctx, f->field + 3, "sphere center", &center) || parse_number(ctx, f->field[6], "sphere radius", &radius))
        return 2;
    if (!(radius > 0.0)) return fail(ctx, "sphere '%s' radius %g must be positive", f->field[1], radius);
    surface *surf;
    if (begin_surface(p, f, SURFACE_SPHERE, &surf)) return 2;
    surf->center = center;
    surf->radius = radius;
    p->s->surface_count++;
    return 0;
}

static int load_obj(parser *p, const char *obj_path, int surface_index);

static int parse_mesh(parser *p, fields *f)
{
    const error_context *ctx = &p->ctx;
    if (expect_field_count(ctx, f, 4, "mesh NAME MATERIAL FILE.obj")) return 2;
    const char *file = f->field[3];
    char obj_path[PATH_CAPACITY];
    int n = file[0] == '/' ? snprintf(obj_path, sizeof obj_path, "%s", file)
                           : snprintf(obj_path, sizeof obj_path, "%s%s", p->directory, file);
    if (n < 0 || (size_t)n >= sizeof obj_path) return fail(ctx, "mesh path too long");
    surface *mesh;
    if (begin_surface(p, f, SURFACE_MESH, &mesh)) return 2;
    int surface_index = p->s->surface_count++;
    /* The OBJ reader appends triangles (not surfaces), so `mesh` stays valid. */
    if (load_obj(p, obj_path, surface_index)) return 2;
    mesh->triangle_count = p->s->triangle_count - mesh->first_triangle;
    return 0;
}

static int parse_light(parser *p, fields *f)
{
    const error_context *ctx = &p->ctx;
    scene *s = p->s;
    static const char usage[] = "light NAME point X Y Z I_R I_G I_B";
    if (f->count >= 3 && strcmp(f->field[2], "point") != 0)
        return fail(ctx, "unknown light kind '%s' (only 'point'); usage: %s", f->field[2], usage);
    if (expect_field_count(ctx, f, 9, usage)) return 2;
    point_light light;
    if (check_object_name(p, f->field[1]) || parse_vec3(ctx, f->field + 3, "light position", &light.position) ||
        parse_nonnegative(ctx, f->field + 6, "light intensity", &light.intensity))
        return 2;
    snprintf(light.name, sizeof light.name, "%s", f->field[1]);
    if (reserve_one((void **)&s->lights, &p->light_capacity, s->light_count, sizeof *s->lights)) return out_of_memory(p);
    s->lights[s->light_count++] = light;
    return 0;
}

static int parse_probe(parser *p, fields *f)
{
    const error_context *ctx = &p->ctx;
    scene *s = p->s;
    if (expect_field_count(ctx, f, 8, "probe NAME X Y Z NX NY NZ")) return 2;
    probe pr;
    if (check_object_name(p, f->field[1]) || parse_vec3(ctx, f->field + 2, "probe position", &pr.position) ||
        parse_vec3(ctx, f->field + 5, "probe normal", &pr.normal))
        return 2;
    double length = v3_length(pr.normal);
    if (!(length > 0.0) || !isfinite(length)) return fail(ctx, "probe '%s' normal must be a nonzero vector", f->field[1]);
    pr.normal = v3_scale(pr.normal, 1.0 / length);
    snprintf(pr.name, sizeof pr.name, "%s", f->field[1]);
    if (reserve_one((void **)&s->probes, &p->probe_capacity, s->probe_count, sizeof *s->probes)) return out_of_memory(p);
    s->probes[s->probe_count++] = pr;
    return 0;
}

static int parse_statement(parser *p, fields *f)
{
    const char *keyword = f->field[0];
    if (strcmp(keyword, "camera") == 0) return parse_camera(p, f);
    if (strcmp(keyword, "image") == 0) return parse_image(p, f);
    if (strcmp(keyword, "background") == 0) return parse_background(p, f);
    if (strcmp(keyword, "material") == 0) return parse_material(p, f);
    if (strcmp(keyword, "quad") == 0) return parse_polygon(p, f, 4);
    if (strcmp(keyword, "triangle") == 0) return parse_polygon(p, f, 3);
    if (strcmp(keyword, "sphere") == 0) return parse_sphere(p, f);
    if (strcmp(keyword, "mesh") == 0) return parse_mesh(p, f);
    if (strcmp(keyword, "light") == 0) return parse_light(p, f);
    if (strcmp(keyword, "probe") == 0) return parse_probe(p, f);
    return fail(&p->ctx, "unknown statement '%.40s'", keyword);
}

/* ------------------------------------------------------------------------ */
/* OBJ meshes: `v` and `f` only                                              */

/* One face corner "i", "i/j", "i//k" or "i/j/k": the vertex index i, 1-based,
 * negative meaning relative to the end of the vertex list so far. */
static int parse_face_vertex(const error_context *ctx, const char *text, int vertex_count, int *out)
{
    char *end;
    errno = 0;
    long index = strtol(text, &end, 10);
    if (end == text || (*end != '\0' && *end != '/')) return fail(ctx, "bad face vertex '%s'", text);
    if (*end == '/') {
        /* Texture and normal indices: optional integers, not used. */
        const char *c = end + 1;
        if (*c != '/' && *c != '\0') {
            (void)strtol(c, &end, 10);
            if (end == c) return fail(ctx, "bad face vertex '%s'", text);
            c = end;
        }
        if (*c == '/') {
            c++;
            (void)strtol(c, &end, 10);
            if (end == c) return fail(ctx, "bad face vertex '%s'", text);
            c = end;
        }
        if (*c != '\0') return fail(ctx, "bad face vertex '%s'", text);
    }
    if (index == 0) return fail(ctx, "vertex index 0 in '%s' (OBJ indices start at 1)", text);
    long resolved = index > 0 ? index - 1 : vertex_count + index;
    if (errno == ERANGE || resolved < 0 || resolved >= vertex_count)
        return fail(ctx, "vertex index %s out of range (%d vertices defined so far)", text, vertex_count);
    *out = (int)resolved;
    return 0;
}

typedef struct {
    vec3 *vertices;
    int vertex_count, vertex_capacity;
} obj_state;

static int read_obj_lines(parser *p, FILE *file, error_context *ctx, obj_state *obj, int surface_index,
                          int *face_count)
{
    char line[LINE_CAPACITY];
    fields f;
    line_status status;
    while ((status = read_line(file, line, sizeof line)) != LINE_END) {
        ctx->line++;
        if (status != LINE_OK) return fail_line(ctx, status);
        split_fields(line, &f);
        if (f.count == 0) continue;
        if (strcmp(f.field[0], "v") == 0) {
            /* x y z, optionally followed by w or a vertex colour */
            if (f.count < 4 || f.count > 7) return fail(ctx, "vertex needs 3 coordinates: v X Y Z");
            vec3 v;
            if (parse_vec3(ctx, f.field + 1, "vertex coordinate", &v)) return 2;
            for (int i = 4; i < f.count; i++) {
                double ignored;
                if (parse_number(ctx, f.field[i], "vertex", &ignored)) return 2;
            }
            if (reserve_one((void **)&obj->vertices, &obj->vertex_capacity, obj->vertex_count, sizeof *obj->vertices))
                return fail(ctx, "out of memory");
            obj->vertices[obj->vertex_count++] = v;
        } else if (strcmp(f.field[0], "f") == 0) {
            int corner_count = f.count - 1;
            if (corner_count < 3) return fail(ctx, "face needs at least 3 vertices, has %d", corner_count);
            /* Fan triangulation (corner 0, i - 1, i); zero-area triangles are dropped. */
            int first, previous, current;
            if (parse_face_vertex(ctx, f.field[1], obj->vertex_count, &first) ||
                parse_face_vertex(ctx, f.field[2], obj->vertex_count, &previous))
                return 2;
            for (int i = 3; i <= corner_count; i++, previous = current) {
                if (parse_face_vertex(ctx, f.field[i], obj->vertex_count, &current)) return 2;
                vec3 a = obj->vertices[first], b = obj->vertices[previous], c = obj->vertices[current];
                if (is_degenerate_triangle(a, b, c)) continue;
                if (add_triangle(p, a, b, c, surface_index)) return fail(ctx, "out of memory");
            }
            (*face_count)++;
        }
        /* Anything else (vn, vt, o, g, s, usemtl, mtllib, l, ...) is not geometry we use. */
    }
    if (ferror(file)) return fail(ctx, "read error");
    return 0;
}

static int load_obj(parser *p, const char *obj_path, int surface_index)
{
    FILE *file = fopen(obj_path, "rb");
    if (file == NULL) return fail(&p->ctx, "cannot open mesh '%s': %s", obj_path, strerror(errno));
    error_context ctx = {.path = obj_path, .line = 0, .err = p->ctx.err, .err_size = p->ctx.err_size};
    obj_state obj = {0};
    int face_count = 0;
    int first_triangle = p->s->triangle_count;
    int status = read_obj_lines(p, file, &ctx, &obj, surface_index, &face_count);
    fclose(file);
    free(obj.vertices);
    if (status) return status;
    if (face_count == 0) return fail(&ctx, "no faces in mesh");
    if (p->s->triangle_count == first_triangle) return fail(&ctx, "every face of the mesh has zero area");
    return 0;
}

/* ------------------------------------------------------------------------ */
/* After parsing                                                             */

static aabb aabb_empty(void) { return (aabb){v3_splat(INFINITY), v3_splat(-INFINITY)}; }
static aabb aabb_add_point(aabb b, vec3 p) { return (aabb){v3_min(b.lo, p), v3_max(b.hi, p)}; }
static aabb aabb_union(aabb a, aabb b) { return (aabb){v3_min(a.lo, b.lo), v3_max(a.hi, b.hi)}; }
static double aabb_half_area(aabb b)
{
    vec3 d = v3_sub(b.hi, b.lo);
    return d.x * d.y + d.y * d.z + d.z * d.x;
}

static aabb triangle_bounds(const triangle *t)
{
    aabb b = aabb_add_point(aabb_empty(), t->p0);
    b = aabb_add_point(b, v3_add(t->p0, t->e1));
    return aabb_add_point(b, v3_add(t->p0, t->e2));
}

static aabb sphere_bounds(const surface *sphere)
{
    vec3 r = v3_splat(sphere->radius);
    return (aabb){v3_sub(sphere->center, r), v3_add(sphere->center, r)};
}

static aabb primitive_bounds(const scene *s, int primitive)
{
    if (primitive < s->triangle_count) return triangle_bounds(&s->triangles[primitive]);
    return sphere_bounds(&s->surfaces[s->sphere_surfaces[primitive - s->triangle_count]]);
}

/* Areas, emitters, sphere list, bounds and epsilon. */
static int finish_scene(scene *s)
{
    for (int i = 0; i < s->surface_count; i++) {
        surface *surf = &s->surfaces[i];
        if (surf->kind == SURFACE_SPHERE) {
            surf->area = 4.0 * M_PI * surf->radius * surf->radius;
            s->sphere_count++;
        } else {
            surf->area = 0.0;
            for (int t = 0; t < surf->triangle_count; t++) surf->area += s->triangles[surf->first_triangle + t].area;
        }
        if (s->materials[surf->material].kind == MATERIAL_EMITTER) s->emitter_count++;
    }
    s->sphere_surfaces = malloc((size_t)(s->sphere_count ? s->sphere_count : 1) * sizeof *s->sphere_surfaces);
    s->emitters = malloc((size_t)(s->emitter_count ? s->emitter_count : 1) * sizeof *s->emitters);
    if (s->sphere_surfaces == NULL || s->emitters == NULL) return -1;
    int spheres = 0, emitters = 0;
    s->emitter_area = 0.0;
    for (int i = 0; i < s->surface_count; i++) {
        if (s->surfaces[i].kind == SURFACE_SPHERE) s->sphere_surfaces[spheres++] = i;
        if (s->materials[s->surfaces[i].material].kind == MATERIAL_EMITTER) {
            s->emitters[emitters++] = i;
            s->emitter_area += s->surfaces[i].area;
        }
    }

    s->bounds = aabb_empty();
    for (int i = 0; i < s->triangle_count + s->sphere_count; i++) s->bounds = aabb_union(s->bounds, primitive_bounds(s, i));
    /* The offset described in scene.h: 1e-9 of the largest coordinate. */
    double largest = fmax(v3_max_component(v3_max(v3_neg(s->bounds.lo), s->bounds.hi)), 0.0);
    s->epsilon = 1e-9 * largest;
    /* Cannot happen for valid geometry (it has a nonzero size), but a zero
     * epsilon would silently bring self-intersection back. */
    if (!(s->epsilon > 0.0)) s->epsilon = 1e-9 * fmax(v3_max_component(v3_sub(s->bounds.hi, s->bounds.lo)), 1.0);
    return 0;
}

/* ------------------------------------------------------------------------ */
/* BVH: binned surface area heuristic                                        */

typedef struct {
    scene *s;
    aabb *bounds;     /* per primitive */
    vec3 *centroids;  /* per primitive */
} bvh_builder;

/* Which of BVH_BINS bins along `axis` a centroid falls into. */
static int bin_of(vec3 centroid, int axis, double lo, double scale)
{
    int bin = (int)((v3_get(centroid, axis) - lo) * scale);
    return bin < 0 ? 0 : bin >= BVH_BINS ? BVH_BINS - 1 : bin;
}

/* The surface area heuristic prices a subtree for a random ray: a node's box
 * is hit with probability area(box) / area(parent).  Splitting costs one
 * traversal step (a node visit: two box tests) plus the expected primitive
 * tests of both children; a leaf costs a test of every primitive in it.  In
 * traverse() a node visit and a triangle test cost about the same (some 40
 * instructions each); measured on the Cornell box, 1 : 1 beats making
 * leaves bigger (2 : 1 tests more triangles than it saves boxes). */
static const double SAH_TRAVERSAL_COST = 1.0, SAH_PRIMITIVE_COST = 1.0;

/* Choose where to split primitives [first, first+count): returns the number
 * that go left (0 < result < count) after reordering them, or 0 when a leaf
 * is cheaper than any split (only offered if count <= BVH_LEAF_SIZE).  All
 * three axes are tried: the longest one is not always the best (a room's
 * walls are as long in every direction). */
static int bvh_partition(bvh_builder *b, int first, int count, int depth, int *axis_out)
{
    int *order = b->s->primitive_order;
    aabb centroid_box = aabb_empty(), node_box = aabb_empty();
    for (int i = first; i < first + count; i++) {
        centroid_box = aabb_add_point(centroid_box, b->centroids[order[i]]);
        node_box = aabb_union(node_box, b->bounds[order[i]]);
    }
    vec3 extent = v3_sub(centroid_box.hi, centroid_box.lo);
    *axis_out = extent.x >= extent.y && extent.x >= extent.z ? 0 : extent.y >= extent.z ? 1 : 2;
    /* A pathological tree: split the list in half. */
    if (depth >= BVH_SAH_MAX_DEPTH) return count <= BVH_LEAF_SIZE ? 0 : count / 2;

    double best_cost = INFINITY, best_lo = 0.0, best_scale = 0.0;
    int best_split = -1, best_axis = -1;
    for (int axis = 0; axis < 3; axis++) {
        double lo = v3_get(centroid_box.lo, axis), width = v3_get(extent, axis);
        if (!(width > 0.0)) continue; /* all centroids in one plane across this axis */
        double scale = BVH_BINS / width * (1.0 - 1e-9);
        int bin_count[BVH_BINS] = {0};
        aabb bin_box[BVH_BINS];
        for (int k = 0; k < BVH_BINS; k++) bin_box[k] = aabb_empty();
        for (int i = first; i < first + count; i++) {
            int k = bin_of(b->centroids[order[i]], axis, lo, scale);
            bin_count[k]++;
            bin_box[k] = aabb_union(bin_box[k], b->bounds[order[i]]);
        }
        /* Cost of splitting after bin k: area(left) * n(left) + area(right) * n(right). */
        double left_cost[BVH_BINS];
        aabb box = aabb_empty();
        int n = 0;
        for (int k = 0; k < BVH_BINS - 1; k++) {
            box = aabb_union(box, bin_box[k]);
            n += bin_count[k];
            left_cost[k] = n ? aabb_half_area(box) * n : 0.0;
        }
        box = aabb_empty();
        n = 0;
        for (int k = BVH_BINS - 1; k > 0; k--) {
            box = aabb_union(box, bin_box[k]);
            n += bin_count[k];
            if (n == 0 || n == count) continue;
            double cost = left_cost[k - 1] + aabb_half_area(box) * n;
            if (cost < best_cost) {
                best_cost = cost;
                best_split = k;
                best_axis = axis;
                best_lo = lo;
                best_scale = scale;
            }
        }
    }
    if (best_split < 0) return count <= BVH_LEAF_SIZE ? 0 : count / 2;
    /* Leaf or split?  Both in units of one primitive test per unit area. */
    double area = aabb_half_area(node_box);
    double split_cost = SAH_TRAVERSAL_COST + SAH_PRIMITIVE_COST * best_cost / area;
    if (count <= BVH_LEAF_SIZE && !(split_cost < SAH_PRIMITIVE_COST * count)) return 0;
    *axis_out = best_axis;

    /* Move the primitives of bins < best_split to the front. */
    int i = first, j = first + count - 1;
    while (i <= j) {
        if (bin_of(b->centroids[order[i]], best_axis, best_lo, best_scale) < best_split) {
            i++;
        } else {
            int tmp = order[i];
            order[i] = order[j];
            order[j--] = tmp;
        }
    }
    int left = i - first;
    return left > 0 && left < count ? left : count / 2;
}

/* What traversal reads.  scene.nodes and scene.primitive_order are the
 * BVH as built (the tests and tools look at them); traversal reads a copy
 * laid out for speed, in the same allocation after the nodes (so scene.h and
 * scene_free do not change):
 *   - trace_node: an inner node holding the boxes of both its children, so
 *     one visit tests two boxes that lie side by side in memory.  Each box
 *     is stored by face (lo x, y, z, hi x, y, z) and, within a face, by
 *     child: the same arithmetic for the two children on adjacent doubles,
 *     done by two-wide SIMD instructions (see box_entries).  A ray picks
 *     the near and far face of each slab by an index computed once per ray
 *     instead of a branch per box.
 *   - leaf_primitive: the primitives copied in leaf order, so a leaf is one
 *     contiguous run of memory with no primitive_order indirection.  Each
 *     keeps its original index for hit.primitive. */
typedef struct {
    double bounds[12];   /* face f (lo x, y, z, hi x, y, z = 0 .. 5) of child k at [2 f + k] */
    int child[2];        /* trace_node index of an inner child, first leaf_primitive of a leaf */
    int count[2];        /* primitives of a leaf child, 0 for an inner child */
    int unused[4];       /* pads the node to 128 bytes: nodes[index] is then a shift, not a multiply */
} trace_node;

typedef struct {
    /* Triangle: the rows of the map to its own coordinates and the limits
     * of u, v and u + v (see triangle_transform).  Sphere: row[0] = center,
     * offset[0] = radius. */
    vec3 row[3];
    double offset[3];
    double u_min, v_min, uv_max;
    int primitive; /* index into the primitives (see scene.h) */
    int is_sphere;
} leaf_primitive;

static int bvh_capacity(const scene *s) { return 2 * (s->triangle_count + s->sphere_count); }
static const trace_node *trace_nodes(const scene *s) { return (const trace_node *)(s->nodes + bvh_capacity(s)); }
static const leaf_primitive *leaf_primitives(const scene *s)
{
    return (const leaf_primitive *)(trace_nodes(s) + bvh_capacity(s));
}

/* Baldwin & Weber, "Fast Ray-Triangle Intersections by Coordinate
 * Transformation" (JCGT 2016).  Every point is x = p0 + u e1 + v e2 + w n
 * for n = e1 x e2; the triangle is w = 0, u >= 0, v >= 0, u + v <= 1.  The
 * map x -> (u, v, w) is the inverse of the matrix with columns e1, e2, n,
 * whose rows are (e2 x n) / |n|^2, (n x e1) / |n|^2 and n / |n|^2: computed
 * once per triangle here, it leaves a ray test of a few dot products.
 *
 * Watertightness: two triangles sharing an edge compute u and v with
 * different roundings, so a ray exactly through the edge (the diagonal of a
 * quad, seen by a camera on its axis) could slip between them.  Each edge
 * is therefore moved out by `tolerance` (EDGE_MARGIN * scene.epsilon), far
 * above the rounding and far below anything visible.  In u, v units that is
 * tolerance / height over the edge, and the height over edge p0-p2 (where
 * u = 0) is |n| / |e2|, and so on. */
static leaf_primitive triangle_transform(const triangle *t, int primitive, double tolerance)
{
    vec3 n = v3_cross(t->e1, t->e2);
    double inv = 1.0 / v3_dot(n, n);
    leaf_primitive p = {.row = {v3_scale(v3_cross(t->e2, n), inv), v3_scale(v3_cross(n, t->e1), inv), v3_scale(n, inv)},
                        .primitive = primitive};
    for (int i = 0; i < 3; i++) p.offset[i] = -v3_dot(p.row[i], t->p0);
    double tolerance_per_length = tolerance / v3_length(n);
    p.u_min = -tolerance_per_length * v3_length(t->e2);
    p.v_min = -tolerance_per_length * v3_length(t->e1);
    p.uv_max = 1.0 + tolerance_per_length * v3_length(v3_sub(t->e2, t->e1));
    return p;
}

static leaf_primitive make_leaf_primitive(const scene *s, int primitive)
{
    if (primitive < s->triangle_count) return triangle_transform(&s->triangles[primitive], primitive, EDGE_MARGIN * s->epsilon);
    const surface *sphere = &s->surfaces[s->sphere_surfaces[primitive - s->triangle_count]];
    return (leaf_primitive){.row = {sphere->center}, .offset = {sphere->radius}, .primitive = primitive, .is_sphere = 1};
}

/* Child k of trace node `out` becomes BVH node `index` (recursively). */
static void trace_set_child(scene *s, trace_node *nodes, int *trace_count, int out, int k, int index)
{
    const bvh_node *node = &s->nodes[index];
    const double faces[6] = {node->bounds.lo.x, node->bounds.lo.y, node->bounds.lo.z,
                             node->bounds.hi.x, node->bounds.hi.y, node->bounds.hi.z};
    for (int f = 0; f < 6; f++) nodes[out].bounds[2 * f + k] = faces[f];
    nodes[out].count[k] = node->count;
    if (node->count > 0) {
        nodes[out].child[k] = node->first;
        return;
    }
    int inner = (*trace_count)++;
    nodes[out].child[k] = inner;
    trace_set_child(s, nodes, trace_count, inner, 0, index + 1);
    trace_set_child(s, nodes, trace_count, inner, 1, node->second_child);
}

static void build_trace_copy(scene *s)
{
    trace_node *nodes = (trace_node *)trace_nodes(s);
    leaf_primitive *prims = (leaf_primitive *)leaf_primitives(s);
    int trace_count = 1;
    if (s->nodes[0].count > 0) {
        /* A root leaf becomes child 0 of trace node 0; child 1 is an empty
         * box (lo = +inf, hi = -inf), which every ray misses. */
        for (int f = 0; f < 6; f++) nodes[0].bounds[2 * f + 1] = f < 3 ? INFINITY : -INFINITY;
        nodes[0].child[1] = nodes[0].count[1] = 0;
        trace_set_child(s, nodes, &trace_count, 0, 0, 0);
    } else {
        /* The root's own box is never tested: its children's are. */
        trace_set_child(s, nodes, &trace_count, 0, 0, 1);
        trace_set_child(s, nodes, &trace_count, 0, 1, s->nodes[0].second_child);
    }
    for (int i = 0; i < s->triangle_count + s->sphere_count; i++) prims[i] = make_leaf_primitive(s, s->primitive_order[i]);
}

/* Builds node `index = node_count` over primitives [first, first+count) and
 * its subtree.  Node indices are handed out before recursing, so the first
 * child of a node is the next index (depth-first layout). */
static void bvh_build_node(bvh_builder *b, int first, int count, int depth);

/* A primitive's box for the BVH.  Triangles intersect with a margin around
 * their edges (see triangle_transform), so their boxes grow by it too, but
 * only within the triangle's plane: along axis i that is
 * margin * sqrt(1 - n_i^2), zero across an axis-aligned wall, whose box
 * then stays flat. */
static aabb bvh_primitive_bounds(const scene *s, int primitive)
{
    aabb b = primitive_bounds(s, primitive);
    if (primitive >= s->triangle_count) return b;
    vec3 n = s->triangles[primitive].normal;
    vec3 pad = v3(sqrt(fmax(1.0 - n.x * n.x, 0.0)), sqrt(fmax(1.0 - n.y * n.y, 0.0)), sqrt(fmax(1.0 - n.z * n.z, 0.0)));
    pad = v3_scale(pad, EDGE_MARGIN * s->epsilon);
    return (aabb){v3_sub(b.lo, pad), v3_add(b.hi, pad)};
}

static int build_bvh(scene *s)
{
    int n = s->triangle_count + s->sphere_count;
    s->node_count = 0;
    if (n == 0) return 0; /* nothing to intersect: traverse() sees node_count == 0 */
    s->primitive_order = malloc((size_t)n * sizeof *s->primitive_order);
    size_t capacity = (size_t)bvh_capacity(s);
    s->nodes = malloc(capacity * (sizeof(bvh_node) + sizeof(trace_node)) + (size_t)n * sizeof(leaf_primitive));
    bvh_builder b = {.s = s, .bounds = malloc((size_t)n * sizeof(aabb)), .centroids = malloc((size_t)n * sizeof(vec3))};
    int ok = s->primitive_order && s->nodes && b.bounds && b.centroids;
    if (ok) {
        for (int i = 0; i < n; i++) {
            s->primitive_order[i] = i;
            b.bounds[i] = bvh_primitive_bounds(s, i);
            b.centroids[i] = v3_scale(v3_add(b.bounds[i].lo, b.bounds[i].hi), 0.5);
        }
        bvh_build_node(&b, 0, n, 0);
        build_trace_copy(s);
    }
    free(b.bounds);
    free(b.centroids);
    return ok ? 0 : -1;
}

static void bvh_build_node(bvh_builder *b, int first, int count, int depth)
{
    int index = b->s->node_count++;
    bvh_node *node = &b->s->nodes[index];
    node->bounds = aabb_empty();
    for (int i = first; i < first + count; i++) node->bounds = aabb_union(node->bounds, b->bounds[b->s->primitive_order[i]]);
    node->first = first;
    node->axis = 0;
    node->second_child = -1;
    int axis = 0;
    int left = count > 1 ? bvh_partition(b, first, count, depth, &axis) : 0;
    if (left == 0) {
        node->count = count;
        return;
    }
    node->count = 0;
    node->axis = axis;
    bvh_build_node(b, first, left, depth + 1);         /* becomes index + 1 */
    b->s->nodes[index].second_child = b->s->node_count;
    bvh_build_node(b, first + left, count - left, depth + 1);
}

/* ------------------------------------------------------------------------ */
/* Loading                                                                   */

static int parse_file(parser *p, FILE *file)
{
    char line[LINE_CAPACITY];
    fields f;
    line_status status;
    while ((status = read_line(file, line, sizeof line)) != LINE_END) {
        p->ctx.line++;
        if (status != LINE_OK) return fail_line(&p->ctx, status);
        split_fields(line, &f);
        if (f.count == 0) continue;
        if (parse_statement(p, &f)) return 2;
    }
    if (ferror(file)) return fail(&p->ctx, "read error");
    /* Whole-file checks are reported at the last line. */
    if (!p->has_camera) return fail(&p->ctx, "no camera statement");
    if (p->s->surface_count == 0) return fail(&p->ctx, "no surfaces in the scene");
    return 0;
}

int scene_load(const char *path, scene *out, char *err, size_t err_size)
{
    memset(out, 0, sizeof *out);
    if (err && err_size) err[0] = '\0';
    parser p = {.s = out, .ctx = {.path = path, .line = 0, .err = err, .err_size = err_size}};
    snprintf(out->path, sizeof out->path, "%s", path);
    out->width = 512;
    out->height = 512;
    out->background = v3_splat(0.0);

    /* Mesh files are relative to the scene file's directory. */
    const char *slash = strrchr(path, '/');
    size_t dir_length = slash ? (size_t)(slash - path) + 1 : 0;
    if (dir_length >= sizeof p.directory) return fail(&p.ctx, "path too long");
    memcpy(p.directory, path, dir_length);
    p.directory[dir_length] = '\0';

    FILE *file = fopen(path, "rb");
    if (file == NULL) return fail(&p.ctx, "cannot open file: %s", strerror(errno));
    int status = parse_file(&p, file);
    fclose(file);
    if (status == 0 && (finish_scene(out) || build_bvh(out))) status = out_of_memory(&p);
    if (status) {
        scene_free(out);
        return 2;
    }
    return 0;
}

void scene_free(scene *s)
{
    free(s->materials);
    free(s->surfaces);
    free(s->triangles);
    free(s->lights);
    free(s->probes);
    free(s->emitters);
    free(s->sphere_surfaces);
    free(s->primitive_order);
    free(s->nodes);
    memset(s, 0, sizeof *s);
}

/* ------------------------------------------------------------------------ */
/* Intersection                                                              */

/* The ray in the triangle's coordinates (see triangle_transform): w along
 * the ray is w_o + t w_d, zero at t = -w_o / w_d; the hit point there gives
 * u and v.  About half the planes are behind the ray or beyond the nearest
 * hit, so t is checked first (u and v need the division's result anyway);
 * the u, v conditions are combined into one branch, as they are coin flips
 * for incoherent rays.  A ray parallel to the plane has w_d = 0 and
 * t = +-inf or NaN, which the t check rejects, so there is no NaN out. */
static inline double triangle_hit(const leaf_primitive *p, vec3 origin, vec3 direction, double t_max)
{
    double w_o = v3_dot(p->row[2], origin) + p->offset[2];
    double w_d = v3_dot(p->row[2], direction);
    double t = -w_o / w_d;
    if (!(t > 0.0 && t < t_max)) return INFINITY;
    vec3 h = v3_madd(origin, direction, t);
    double u = v3_dot(p->row[0], h) + p->offset[0];
    double v = v3_dot(p->row[1], h) + p->offset[1];
    int inside = (u >= p->u_min) & (v >= p->v_min) & (u + v <= p->uv_max);
    return inside ? t : INFINITY;
}

double intersect_triangle(const triangle *tri, ray r)
{
    /* The tolerance the triangle would have in a scene of its own. */
    vec3 p1 = v3_add(tri->p0, tri->e1), p2 = v3_add(tri->p0, tri->e2);
    vec3 largest = v3_max(v3_max(v3_max(tri->p0, v3_neg(tri->p0)), v3_max(p1, v3_neg(p1))), v3_max(p2, v3_neg(p2)));
    leaf_primitive p = triangle_transform(tri, 0, EDGE_MARGIN * 1e-9 * v3_max_component(largest));
    return triangle_hit(&p, r.origin, r.direction, INFINITY);
}

/* Haines, Guenther & Akenine-Moller, "Precision Improvements for Ray/Sphere
 * Intersection" (Ray Tracing Gems, ch. 7).  With f = o - c, solve
 * a t^2 + 2 b t + c = 0, a = d.d, b = f.d, c = f.f - r^2.  The textbook
 * discriminant b^2 - a c subtracts two huge numbers when r is large; the
 * same quantity written as a (r^2 - |f - (b/a) d|^2) does not.  The roots
 * come from q = -(b + sign(b) sqrt(disc)) as q / a and c / q, which avoids
 * the other cancellation (-b + sqrt(...) with both nearly equal). */
static inline double sphere_hit(vec3 center, double radius, vec3 origin, vec3 direction)
{
    vec3 f = v3_sub(origin, center);
    double a = v3_dot(direction, direction);
    double b = v3_dot(f, direction);
    double c = v3_dot(f, f) - radius * radius;
    vec3 l = v3_madd(f, direction, -b / a); /* f minus its component along d */
    double disc = a * (radius * radius - v3_dot(l, l));
    if (!(disc >= 0.0)) return INFINITY;
    double q = -(b + copysign(sqrt(disc), b));
    if (q == 0.0) return INFINITY; /* ray starts on the sphere and grazes it */
    double t0 = c / q, t1 = q / a;
    if (t0 > t1) {
        double tmp = t0;
        t0 = t1;
        t1 = tmp;
    }
    if (t0 > 0.0) return t0;
    if (t1 > 0.0) return t1;
    return INFINITY;
}

double intersect_sphere(vec3 center, double radius, ray r) { return sphere_hit(center, radius, r.origin, r.direction); }

/* Hit distance of a leaf primitive if it is below t_max, else INFINITY. */
static inline double primitive_hit(const leaf_primitive *p, vec3 origin, vec3 direction, double t_max)
{
    if (!p->is_sphere) return triangle_hit(p, origin, direction, t_max);
    double t = sphere_hit(p->row[0], p->offset[0], origin, direction);
    return t < t_max ? t : INFINITY;
}

static void fill_hit(const scene *s, ray r, double t, int primitive, hit *out)
{
    out->t = t;
    out->point = v3_madd(r.origin, r.direction, t);
    out->primitive = primitive;
    if (primitive < s->triangle_count) {
        out->surface = s->triangles[primitive].surface;
        out->normal = s->triangles[primitive].normal;
    } else {
        int surface_index = s->sphere_surfaces[primitive - s->triangle_count];
        const surface *sphere = &s->surfaces[surface_index];
        out->surface = surface_index;
        out->normal = v3_scale(v3_sub(out->point, sphere->center), 1.0 / sphere->radius);
    }
}

/* What the slab test needs of a ray, computed once per ray: the division
 * is done here, and for each axis where in trace_node.bounds (counted in
 * doubles) the face lies that the ray meets first (lo if the direction is
 * positive, hi if not) and the face it leaves by.  (ptrdiff_t and a count
 * of doubles, so that each load is one instruction: base + 8 * offset.) */
typedef struct {
    vec3 origin, inv_dir;
    ptrdiff_t near_x, near_y, near_z, far_x, far_y, far_z;
#ifdef __SSE2__
    __m128d origin_x2, origin_y2, origin_z2, inv_dir_x2, inv_dir_y2, inv_dir_z2; /* in both lanes, for box_entries */
#endif
} ray_setup;

static inline ray_setup setup_ray(vec3 origin, vec3 direction)
{
    /* 1/0 = inf is what the slab test wants for an axis-parallel ray. */
    vec3 inv_dir = v3(1.0 / direction.x, 1.0 / direction.y, 1.0 / direction.z);
    ptrdiff_t neg_x = inv_dir.x < 0.0, neg_y = inv_dir.y < 0.0, neg_z = inv_dir.z < 0.0;
    /* face f (lo x, y, z = 0, 1, 2; hi x, y, z = 3, 4, 5) starts at double 2 f */
    return (ray_setup){origin, inv_dir, 2 * (3 * neg_x), 2 * (1 + 3 * neg_y), 2 * (2 + 3 * neg_z),
                       2 * (3 - 3 * neg_x), 2 * (4 - 3 * neg_y), 2 * (5 - 3 * neg_z),
#ifdef __SSE2__
                       _mm_set1_pd(origin.x), _mm_set1_pd(origin.y), _mm_set1_pd(origin.z),
                       _mm_set1_pd(inv_dir.x), _mm_set1_pd(inv_dir.y), _mm_set1_pd(inv_dir.z),
#endif
    };
}

/* Slab test (Kay & Kajiya) against both child boxes of a node: entry[k] is
 * the distance where the ray enters box k, or INFINITY if it misses it or
 * enters beyond t_max.  No branch per axis (they would be mispredicted for
 * incoherent rays); the comparisons are written so that a NaN (0 * inf, a
 * ray lying in a slab plane) never shrinks the interval: `a > b ? a : b`
 * keeps b when a is NaN.  t_far is enlarged by a few ulps (Ize 2013,
 * "Robust BVH Ray Traversal") so rounding never culls a box whose primitive
 * the exact test would hit. */
#ifdef __SSE2__
/* Both boxes at once with SSE2 (every x86-64 processor has it): each
 * instruction below works on a pair of doubles, one per child, and
 * _mm_max_pd(a, b) / _mm_min_pd(a, b) are exactly `a > b ? a : b` /
 * `a < b ? a : b`, NaN behaviour included, so this computes what the plain C
 * version after #else computes, in about a third of the instructions. */
static inline void box_entries(const trace_node *node, const ray_setup *r, double t_max, double entry[2])
{
    const double *b = node->bounds;
    __m128d ox = r->origin_x2, oy = r->origin_y2, oz = r->origin_z2;
    __m128d ix = r->inv_dir_x2, iy = r->inv_dir_y2, iz = r->inv_dir_z2;
    __m128d near_x = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->near_x), ox), ix);
    __m128d far_x = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->far_x), ox), ix);
    __m128d near_y = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->near_y), oy), iy);
    __m128d far_y = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->far_y), oy), iy);
    __m128d near_z = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->near_z), oz), iz);
    __m128d far_z = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(b + r->far_z), oz), iz);
    __m128d t_near = _mm_max_pd(near_x, _mm_setzero_pd());
    t_near = _mm_max_pd(near_y, t_near);
    t_near = _mm_max_pd(near_z, t_near);
    __m128d t_far = _mm_min_pd(far_x, _mm_set1_pd(t_max));
    t_far = _mm_min_pd(far_y, t_far);
    t_far = _mm_min_pd(far_z, t_far);
    __m128d hit = _mm_cmple_pd(t_near, _mm_mul_pd(t_far, _mm_set1_pd(1.0 + 4.0 * DBL_EPSILON)));
    __m128d e = _mm_or_pd(_mm_and_pd(hit, t_near), _mm_andnot_pd(hit, _mm_set1_pd(INFINITY)));
    entry[0] = _mm_cvtsd_f64(e);
    entry[1] = _mm_cvtsd_f64(_mm_unpackhi_pd(e, e));
}
#else
static inline void box_entries(const trace_node *node, const ray_setup *r, double t_max, double entry[2])
{
    const double *b = node->bounds;
    for (int k = 0; k < 2; k++) {
        double near_x = (b[r->near_x + k] - r->origin.x) * r->inv_dir.x;
        double far_x = (b[r->far_x + k] - r->origin.x) * r->inv_dir.x;
        double near_y = (b[r->near_y + k] - r->origin.y) * r->inv_dir.y;
        double far_y = (b[r->far_y + k] - r->origin.y) * r->inv_dir.y;
        double near_z = (b[r->near_z + k] - r->origin.z) * r->inv_dir.z;
        double far_z = (b[r->far_z + k] - r->origin.z) * r->inv_dir.z;
        double t_near = near_x > 0.0 ? near_x : 0.0;
        t_near = near_y > t_near ? near_y : t_near;
        t_near = near_z > t_near ? near_z : t_near;
        double t_far = far_x < t_max ? far_x : t_max;
        t_far = far_y < t_far ? far_y : t_far;
        t_far = far_z < t_far ? far_z : t_far;
        entry[k] = t_near <= t_far * (1.0 + 4.0 * DBL_EPSILON) ? t_near : INFINITY;
    }
}
#endif

/* traverse() is copied into each of its two callers, with any_hit a
 * constant there: without the copy GCC calls one shared function, passes
 * the ray through memory and tests any_hit in the loop (10% slower). */
#if defined(__GNUC__)
#define ALWAYS_INLINE __attribute__((always_inline)) inline
#else
#define ALWAYS_INLINE inline
#endif

/* The one BVH traversal, iterative with an explicit stack.  any_hit: stop
 * at the first hit found (shadow rays need no nearest).  What is visited
 * next is a trace node (count == 0, index = trace node) or a leaf (count
 * primitives from leaf_primitive index). */
static ALWAYS_INLINE int traverse(const scene *s, vec3 origin, vec3 direction, double t_max, int any_hit,
                                  double *t_out, int *primitive_out)
{
    if (s->node_count == 0) return 0;
    const trace_node *nodes = trace_nodes(s);
    const leaf_primitive *prims = leaf_primitives(s);
    ray_setup r = setup_ray(origin, direction);
    int stack_index[BVH_STACK_SIZE], stack_count[BVH_STACK_SIZE];
    double stack_entry[BVH_STACK_SIZE]; /* where the ray enters that box */
    int top = 0;
    int found = -1;
    double nearest = t_max;
    int index = 0, count = 0;
    for (;;) {
        if (count > 0) {
            for (const leaf_primitive *p = prims + index, *end = p + count; p < end; p++) {
                double t = primitive_hit(p, origin, direction, nearest);
                if (t < nearest) {
                    nearest = t;
                    found = p->primitive;
                    if (any_hit) goto done;
                }
            }
        } else {
            const trace_node *node = &nodes[index];
            double entry[2];
            box_entries(node, &r, nearest, entry);
            /* Visit the nearer child first; the farther one waits on the
             * stack.  A branch, not a select: the processor predicts it and
             * starts on the predicted child's boxes while this node's test
             * is still finishing; a select would make every node wait for
             * its parent's test (a chain through the whole traversal). */
            if (entry[1] < entry[0]) {
                /* entry[1] is finite here, and child 1 is nearer. */
                if (entry[0] != INFINITY) {
                    stack_index[top] = node->child[0];
                    stack_count[top] = node->count[0];
                    stack_entry[top++] = entry[0];
                }
                index = node->child[1];
                count = node->count[1];
                continue;
            }
            if (entry[0] != INFINITY) {
                if (entry[1] != INFINITY) {
                    stack_index[top] = node->child[1];
                    stack_count[top] = node->count[1];
                    stack_entry[top++] = entry[1];
                }
                index = node->child[0];
                count = node->count[0];
                continue;
            }
        }
        /* Pop, skipping boxes that start beyond the nearest hit found since. */
        for (;;) {
            if (top == 0) goto done;
            top--;
            if (stack_entry[top] < nearest) break;
        }
        index = stack_index[top];
        count = stack_count[top];
    }
done:
    if (found < 0) return 0;
    *t_out = nearest;
    *primitive_out = found;
    return 1;
}

int scene_intersect(const scene *s, ray r, double t_max, hit *out)
{
    double t;
    int primitive;
    if (!traverse(s, r.origin, r.direction, t_max, 0, &t, &primitive)) return 0;
    fill_hit(s, r, t, primitive, out);
    return 1;
}

/* The same primitive test on the same records as traverse(), so the two
 * agree to the last bit; every primitive is tested, and of equally near ones
 * the lowest index wins, whatever the leaf order. */
int scene_intersect_brute_force(const scene *s, ray r, double t_max, hit *out)
{
    if (s->node_count == 0) return 0;
    const leaf_primitive *prims = leaf_primitives(s);
    double nearest = t_max;
    int found = -1;
    for (int i = 0; i < s->triangle_count + s->sphere_count; i++) {
        double t = primitive_hit(&prims[i], r.origin, r.direction, t_max);
        if (t < nearest || (t == nearest && found >= 0 && prims[i].primitive < found)) {
            nearest = t;
            found = prims[i].primitive;
        }
    }
    if (found < 0) return 0;
    fill_hit(s, r, nearest, found, out);
    return 1;
}

int scene_occluded(const scene *s, vec3 a, vec3 b)
{
    vec3 d = v3_sub(b, a);
    double distance = v3_length(d);
    if (!(distance > 2.0 * s->epsilon)) return 0;
    /* Ray from a + epsilon toward b, ending epsilon short of b:
     * t = epsilon / distance .. 1 - epsilon / distance along d. */
    double step = s->epsilon / distance;
    vec3 origin = v3_madd(a, d, step);
    double t;
    int primitive;
    return traverse(s, origin, d, 1.0 - 2.0 * step, 1, &t, &primitive);
}


/* ------------------------------------------------------------------------ */
/* Sampling, lookup, camera                                                  */

void surface_sample_point(const scene *s, int surface_index, double u1, double u2, double u3, vec3 *point,
                          vec3 *normal)
{
    const surface *surf = &s->surfaces[surface_index];
    if (surf->kind == SURFACE_SPHERE) {
        vec3 direction = uniform_sample_sphere(u1, u2);
        *point = v3_madd(surf->center, direction, surf->radius);
        *normal = direction;
        return;
    }
    if (surf->parallelogram) { /* uniform in (u1, u2) along two sides: no triangle to pick */
        const triangle *t = &s->triangles[surf->first_triangle];
        *point = v3_add(surf->vertex[0], v3_add(v3_scale(v3_sub(surf->vertex[1], surf->vertex[0]), u1),
                                                v3_scale(v3_sub(surf->vertex[3], surf->vertex[0]), u2)));
        *normal = t->normal;
        return;
    }
    /* Pick a triangle with probability area / total area (linear search:
     * emitters are mostly quads, two triangles). */
    double target = u3 * surf->area;
    int last = surf->first_triangle + surf->triangle_count - 1;
    int chosen = last;
    double cumulative = 0.0;
    for (int i = surf->first_triangle; i < last; i++) {
        cumulative += s->triangles[i].area;
        if (target < cumulative) {
            chosen = i;
            break;
        }
    }
    const triangle *t = &s->triangles[chosen];
    *point = uniform_sample_triangle(t->p0, v3_add(t->p0, t->e1), v3_add(t->p0, t->e2), u1, u2);
    *normal = t->normal;
}

int scene_find_surface(const scene *s, const char *name)
{
    for (int i = 0; i < s->surface_count; i++)
        if (strcmp(s->surfaces[i].name, name) == 0) return i;
    return -1;
}

camera_frame camera_frame_make(const camera *c, int width, int height)
{
    vec3 forward = v3_normalize(v3_sub(c->look, c->eye));
    vec3 right = v3_normalize(v3_cross(forward, c->up));
    double half_height = tan(0.5 * c->fov_degrees * M_PI / 180.0);
    vec3 up = v3_cross(right, forward);
    double half_width = half_height * (double)width / (double)height;
    /* The image plane at distance 1 spans [-half_width, half_width] along
     * right and [-half_height, half_height] along up; image y grows downward. */
    return (camera_frame){
        .eye = c->eye,
        .top_left = v3_add(forward, v3_sub(v3_scale(up, half_height), v3_scale(right, half_width))),
        .step_x = v3_scale(right, 2.0 * half_width / width),
        .step_y = v3_scale(up, -2.0 * half_height / height),
    };
}

ray camera_frame_ray(const camera_frame *f, double px, double py)
{
    /* Image x grows to the right, image y grows downward. */
    vec3 direction = v3_add(f->top_left, v3_add(v3_scale(f->step_x, px), v3_scale(f->step_y, py)));
    return (ray){f->eye, v3_normalize(direction)};
}

ray camera_ray(const camera *c, int width, int height, double px, double py)
{
    camera_frame f = camera_frame_make(c, width, height);
    return camera_frame_ray(&f, px, py);
}
