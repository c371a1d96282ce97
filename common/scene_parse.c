/* scene_parse.c — the .scene parser and the OBJ reader.
 *
 * Reading order: small helpers (errors, numbers, growing arrays), the line
 * reader, one function per statement, the OBJ reader, and the file loop.
 * What is computed after parsing (areas, bounds, epsilon) is in scene.c, the
 * BVH in bvh.c.
 */
#include "scene_parse.h"

#include <errno.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sampling.h"

/* Lines longer than this are rejected (a scene line is far shorter; a
 * longer one is almost certainly not a scene file). */
enum { LINE_CAPACITY = 4096 };
/* A line of LINE_CAPACITY characters has at most half as many fields
 * (an OBJ polygon may have many corners). */
enum { MAX_FIELDS = LINE_CAPACITY / 2 + 1 };
enum { PATH_CAPACITY = 4096 };

/* A triangle (or quad half) counts as degenerate when its area is below this
 * fraction of the squared size of its bounding box: collinear or coincident
 * vertices up to rounding. */
static const double DEGENERATE_AREA = 1e-12;
/* A quad is planar when its 4th vertex is within this fraction of its size
 * from the plane of the first three. */
static const double PLANARITY_TOLERANCE = 1e-6;

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
    if (ctx->err == NULL || ctx->err_size == 0)
        return 2;
    int n = snprintf(ctx->err, ctx->err_size, "%s:%d: ", ctx->path, ctx->line);
    if (n >= 0 && (size_t)n < ctx->err_size) {
        va_list args;
        va_start(args, format);
        vsnprintf(ctx->err + n, ctx->err_size - (size_t)n, format, args);
        va_end(args);
    }
    /* One line, whatever the message contains (names come from the file). */
    for (char *c = ctx->err; *c; c++)
        if (*c == '\n' || *c == '\r')
            *c = ' ';
    return 2;
}

/* ------------------------------------------------------------------------ */
/* Growing arrays                                                            */

/* Make room for one more element in *array (count used, *capacity
 * allocated).  Returns 0 on success, -1 when out of memory. */
static int reserve_one(void **array, int *capacity, int count, size_t element_size)
{
    if (count < *capacity)
        return 0;
    if (*capacity > INT_MAX / 2)
        return -1;
    int new_capacity = *capacity ? 2 * *capacity : 16;
    void *grown = realloc(*array, (size_t)new_capacity * element_size);
    if (grown == NULL)
        return -1;
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
    if (c == EOF)
        return LINE_END;
    while (c != EOF && c != '\n') {
        unsigned char byte = (unsigned char)c;
        if ((byte < 0x20 && byte != '\t' && byte != '\r' && byte != '\f' && byte != '\v') || byte == 0x7f)
            return LINE_BINARY;
        if (length + 1 >= capacity)
            return LINE_TOO_LONG;
        buffer[length++] = (char)c;
        c = getc(file);
    }
    buffer[length] = '\0';
    return LINE_OK;
}

static int fail_line(const error_context *ctx, line_status status)
{
    if (status == LINE_TOO_LONG)
        return fail(ctx, "line longer than %d characters", LINE_CAPACITY - 1);
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
    if (comment)
        *comment = '\0';
    char *c = line;
    for (;;) {
        while (is_blank(*c))
            c++;
        if (*c == '\0')
            break;
        f->field[f->count++] = c; /* cannot overflow: fields are separated by blanks */
        while (*c && !is_blank(*c))
            c++;
        if (*c == '\0')
            break;
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
    if (end == text || *end != '\0')
        return fail(ctx, "%s: '%s' is not a number", what, text);
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
    if (parse_vec3(ctx, text, what, out))
        return 2;
    if (v3_min_component(*out) < 0.0 || v3_max_component(*out) > 1.0)
        return fail(ctx, "%s %g %g %g: each channel must be in [0, 1]", what, out->x, out->y, out->z);
    return 0;
}

/* A colour whose channels must be >= 0 (radiance, intensity). */
static int parse_nonnegative(const error_context *ctx, char **text, const char *what, vec3 *out)
{
    if (parse_vec3(ctx, text, what, out))
        return 2;
    if (v3_min_component(*out) < 0.0)
        return fail(ctx, "%s %g %g %g: must not be negative", what, out->x, out->y, out->z);
    return 0;
}

static int expect_keyword(const error_context *ctx, const char *text, const char *keyword, const char *usage)
{
    if (strcmp(text, keyword) != 0)
        return fail(ctx, "expected '%s' but found '%s'; usage: %s", keyword, text, usage);
    return 0;
}

static int expect_field_count(const error_context *ctx, const fields *f, int expected, const char *usage)
{
    if (f->count != expected)
        return fail(ctx, "%s field%s (%d after '%s', expected %d); usage: %s",
                    f->count < expected ? "missing" : "extra", abs(f->count - expected) == 1 ? "" : "s", f->count - 1,
                    f->field[0], expected - 1, usage);
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
    if (strlen(name) >= SCENE_NAME_MAX)
        return fail(&p->ctx, "name '%.20s...' longer than %d characters", name, SCENE_NAME_MAX - 1);
    return 0;
}

static int find_material(const scene *s, const char *name)
{
    for (int i = 0; i < s->material_count; i++)
        if (strcmp(s->materials[i].name, name) == 0)
            return i;
    return -1;
}

/* Surfaces, lights and probes share one namespace: graders ask by name. */
static int check_object_name(parser *p, const char *name)
{
    if (check_name(p, name))
        return 2;
    const scene *s = p->s;
    int taken = scene_find_surface(s, name) >= 0;
    for (int i = 0; i < s->light_count && !taken; i++)
        taken = strcmp(s->lights[i].name, name) == 0;
    for (int i = 0; i < s->probe_count && !taken; i++)
        taken = strcmp(s->probes[i].name, name) == 0;
    if (taken)
        return fail(&p->ctx, "duplicate name '%s' (surfaces, lights and probes need distinct names)", name);
    return 0;
}

static int material_reference(parser *p, const char *name, int *index)
{
    *index = find_material(p->s, name);
    if (*index < 0)
        return fail(&p->ctx, "unknown material '%s' (materials must be defined before use)", name);
    return 0;
}

/* ------------------------------------------------------------------------ */
/* Statements                                                                */

static int parse_camera(parser *p, fields *f)
{
    static const char usage[] = "camera eye X Y Z look X Y Z up X Y Z fov DEGREES [near DISTANCE]";
    const error_context *ctx = &p->ctx;
    if (p->has_camera)
        return fail(ctx, "second camera statement (a scene has one camera)");
    if (f->count != 15 && expect_field_count(ctx, f, 17, usage))
        return 2;
    camera c = {.near = 0.0};
    if (expect_keyword(ctx, f->field[1], "eye", usage) || parse_vec3(ctx, f->field + 2, "camera eye", &c.eye) ||
        expect_keyword(ctx, f->field[5], "look", usage) || parse_vec3(ctx, f->field + 6, "camera look", &c.look) ||
        expect_keyword(ctx, f->field[9], "up", usage) || parse_vec3(ctx, f->field + 10, "camera up", &c.up) ||
        expect_keyword(ctx, f->field[13], "fov", usage) ||
        parse_number(ctx, f->field[14], "camera fov", &c.fov_degrees) ||
        (f->count == 17 &&
         (expect_keyword(ctx, f->field[15], "near", usage) || parse_number(ctx, f->field[16], "camera near", &c.near))))
        return 2;
    vec3 view = v3_sub(c.look, c.eye);
    double view_length = v3_length(view), up_length = v3_length(c.up);
    if (!(view_length > 0.0))
        return fail(ctx, "camera eye and look are the same point");
    if (!(up_length > 0.0))
        return fail(ctx, "camera up is the zero vector");
    /* sin of the angle between view and up; near 0 leaves "right" undefined. */
    if (v3_length(v3_cross(view, c.up)) <= 1e-9 * view_length * up_length)
        return fail(ctx, "camera up is parallel to the view direction");
    if (!(c.fov_degrees > 0.0 && c.fov_degrees < 180.0))
        return fail(ctx, "camera fov %g: must be between 0 and 180 degrees (exclusive)", c.fov_degrees);
    if (!(c.near >= 0.0))
        return fail(ctx, "camera near %g: must be at least 0", c.near);
    p->s->camera = c;
    p->has_camera = 1;
    return 0;
}

static int parse_image_size(const error_context *ctx, const char *text, int *out)
{
    char *end;
    errno = 0;
    long value = strtol(text, &end, 10);
    if (end == text || *end != '\0')
        return fail(ctx, "image size '%s' is not an integer", text);
    if (errno == ERANGE || value < 1 || value > 65536)
        return fail(ctx, "image size '%s' must be in 1..65536", text);
    *out = (int)value;
    return 0;
}

static int parse_image(parser *p, fields *f)
{
    if (expect_field_count(&p->ctx, f, 3, "image WIDTH HEIGHT"))
        return 2;
    if (parse_image_size(&p->ctx, f->field[1], &p->s->width) || parse_image_size(&p->ctx, f->field[2], &p->s->height))
        return 2;
    return 0;
}

static int parse_background(parser *p, fields *f)
{
    if (expect_field_count(&p->ctx, f, 4, "background R G B"))
        return 2;
    return parse_nonnegative(&p->ctx, f->field + 1, "background", &p->s->background);
}

static int parse_material(parser *p, fields *f)
{
    const error_context *ctx = &p->ctx;
    scene *s = p->s;
    if (f->count < 3)
        return fail(ctx, "missing fields; usage: material NAME diffuse|phong|mirror|glass|emitter ...");
    const char *name = f->field[1], *kind = f->field[2];
    if (check_name(p, name))
        return 2;
    if (find_material(s, name) >= 0)
        return fail(ctx, "duplicate material name '%s'", name);

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
        if (m.exponent < 0.0)
            return fail(ctx, "phong exponent %g must not be negative", m.exponent);
    } else if (strcmp(kind, "mirror") == 0) {
        m.kind = MATERIAL_MIRROR;
        if (expect_field_count(ctx, f, 6, "material NAME mirror R G B") ||
            parse_reflectance(ctx, f->field + 3, "mirror reflectance", &m.specular))
            return 2;
    } else if (strcmp(kind, "glass") == 0) {
        m.kind = MATERIAL_GLASS;
        m.specular = v3_splat(1.0);
        if (f->count != 4 && expect_field_count(ctx, f, 7, "material NAME glass IOR [R G B]"))
            return 2;
        if (parse_number(ctx, f->field[3], "glass IOR", &m.ior))
            return 2;
        if (!(m.ior > 0.0))
            return fail(ctx, "glass IOR %g must be positive", m.ior);
        if (f->count == 7 && parse_reflectance(ctx, f->field + 4, "glass tint", &m.specular))
            return 2;
    } else if (strcmp(kind, "emitter") == 0) {
        static const char usage[] = "material NAME emitter R G B [diffuse R G B]";
        m.kind = MATERIAL_EMITTER;
        if (f->count != 6 && expect_field_count(ctx, f, 10, usage))
            return 2;
        if (parse_nonnegative(ctx, f->field + 3, "emitter radiance", &m.emission))
            return 2;
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
    if (reserve_one((void **)&s->triangles, &p->triangle_capacity, s->triangle_count, sizeof *s->triangles))
        return -1;
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
    if (check_object_name(p, f->field[1]) || material_reference(p, f->field[2], &material_index))
        return 2;
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
    if (expect_field_count(ctx, f, 3 + 3 * vertex_count, usage))
        return 2;
    vec3 v[4];
    for (int i = 0; i < vertex_count; i++)
        if (parse_vec3(ctx, f->field + 3 + 3 * i, "vertex coordinate", &v[i]))
            return 2;

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
            return fail(ctx,
                        "quad '%s' is not planar (4th vertex %g off the plane of the first three); "
                        "split it into two triangles",
                        f->field[1], off_plane);
        vec3 n2 = v3_cross(v3_sub(v[2], v[0]), v3_sub(v[3], v[0]));
        if (v3_dot(n, n2) <= 0.0)
            return fail(ctx, "quad '%s' crosses itself or is not convex; check the vertex order", f->field[1]);
    }

    surface *surf;
    if (begin_surface(p, f, vertex_count == 4 ? SURFACE_QUAD : SURFACE_TRIANGLE, &surf))
        return 2;
    int surface_index = p->s->surface_count;
    for (int i = 0; i < vertex_count; i++)
        surf->vertex[i] = v[i];
    surf->vertex_count = vertex_count;
    for (int i = 1; i + 1 < vertex_count; i++)
        if (add_triangle(p, v[0], v[i], v[i + 1], surface_index))
            return out_of_memory(p);
    surf->triangle_count = vertex_count - 2;
    surf->parallelogram = vertex_count == 4 && v3_length(v3_sub(v3_add(v[0], v[2]), v3_add(v[1], v[3]))) <=
                                                   1e-12 * sqrt(bounding_box_diagonal_squared(v, 4));
    p->s->surface_count++;
    return 0;
}

static int parse_sphere(parser *p, fields *f)
{
    const error_context *ctx = &p->ctx;
    if (expect_field_count(ctx, f, 7, "sphere NAME MATERIAL CX CY CZ RADIUS"))
        return 2;
    vec3 center;
    double radius;
    if (parse_vec3(ctx, f->field + 3, "sphere center", &center) ||
        parse_number(ctx, f->field[6], "sphere radius", &radius))
        return 2;
    if (!(radius > 0.0))
        return fail(ctx, "sphere '%s' radius %g must be positive", f->field[1], radius);
    surface *surf;
    if (begin_surface(p, f, SURFACE_SPHERE, &surf))
        return 2;
    surf->center = center;
    surf->radius = radius;
    p->s->surface_count++;
    return 0;
}

static int load_obj(parser *p, const char *obj_path, int surface_index);

static int parse_mesh(parser *p, fields *f)
{
    const error_context *ctx = &p->ctx;
    if (expect_field_count(ctx, f, 4, "mesh NAME MATERIAL FILE.obj"))
        return 2;
    const char *file = f->field[3];
    char obj_path[PATH_CAPACITY];
    int n = file[0] == '/' ? snprintf(obj_path, sizeof obj_path, "%s", file)
                           : snprintf(obj_path, sizeof obj_path, "%s%s", p->directory, file);
    if (n < 0 || (size_t)n >= sizeof obj_path)
        return fail(ctx, "mesh path too long");
    surface *mesh;
    if (begin_surface(p, f, SURFACE_MESH, &mesh))
        return 2;
    int surface_index = p->s->surface_count++;
    /* The OBJ reader appends triangles (not surfaces), so `mesh` stays valid. */
    if (load_obj(p, obj_path, surface_index))
        return 2;
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
    if (expect_field_count(ctx, f, 9, usage))
        return 2;
    point_light light;
    if (check_object_name(p, f->field[1]) || parse_vec3(ctx, f->field + 3, "light position", &light.position) ||
        parse_nonnegative(ctx, f->field + 6, "light intensity", &light.intensity))
        return 2;
    snprintf(light.name, sizeof light.name, "%s", f->field[1]);
    if (reserve_one((void **)&s->lights, &p->light_capacity, s->light_count, sizeof *s->lights))
        return out_of_memory(p);
    s->lights[s->light_count++] = light;
    return 0;
}

static int parse_probe(parser *p, fields *f)
{
    const error_context *ctx = &p->ctx;
    scene *s = p->s;
    if (expect_field_count(ctx, f, 8, "probe NAME X Y Z NX NY NZ"))
        return 2;
    probe pr;
    if (check_object_name(p, f->field[1]) || parse_vec3(ctx, f->field + 2, "probe position", &pr.position) ||
        parse_vec3(ctx, f->field + 5, "probe normal", &pr.normal))
        return 2;
    double length = v3_length(pr.normal);
    if (!(length > 0.0) || !isfinite(length))
        return fail(ctx, "probe '%s' normal must be a nonzero vector", f->field[1]);
    pr.normal = v3_scale(pr.normal, 1.0 / length);
    snprintf(pr.name, sizeof pr.name, "%s", f->field[1]);
    if (reserve_one((void **)&s->probes, &p->probe_capacity, s->probe_count, sizeof *s->probes))
        return out_of_memory(p);
    s->probes[s->probe_count++] = pr;
    return 0;
}

static int parse_statement(parser *p, fields *f)
{
    const char *keyword = f->field[0];
    if (strcmp(keyword, "camera") == 0)
        return parse_camera(p, f);
    if (strcmp(keyword, "image") == 0)
        return parse_image(p, f);
    if (strcmp(keyword, "background") == 0)
        return parse_background(p, f);
    if (strcmp(keyword, "material") == 0)
        return parse_material(p, f);
    if (strcmp(keyword, "quad") == 0)
        return parse_polygon(p, f, 4);
    if (strcmp(keyword, "triangle") == 0)
        return parse_polygon(p, f, 3);
    if (strcmp(keyword, "sphere") == 0)
        return parse_sphere(p, f);
    if (strcmp(keyword, "mesh") == 0)
        return parse_mesh(p, f);
    if (strcmp(keyword, "light") == 0)
        return parse_light(p, f);
    if (strcmp(keyword, "probe") == 0)
        return parse_probe(p, f);
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
    if (end == text || (*end != '\0' && *end != '/'))
        return fail(ctx, "bad face vertex '%s'", text);
    if (*end == '/') {
        /* Texture and normal indices: optional integers, not used. */
        const char *c = end + 1;
        if (*c != '/' && *c != '\0') {
            (void)strtol(c, &end, 10);
            if (end == c)
                return fail(ctx, "bad face vertex '%s'", text);
            c = end;
        }
        if (*c == '/') {
            c++;
            (void)strtol(c, &end, 10);
            if (end == c)
                return fail(ctx, "bad face vertex '%s'", text);
            c = end;
        }
        if (*c != '\0')
            return fail(ctx, "bad face vertex '%s'", text);
    }
    if (index == 0)
        return fail(ctx, "vertex index 0 in '%s' (OBJ indices start at 1)", text);
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

static int read_obj_lines(parser *p, FILE *file, error_context *ctx, obj_state *obj, int surface_index, int *face_count)
{
    char line[LINE_CAPACITY];
    fields f;
    line_status status;
    while ((status = read_line(file, line, sizeof line)) != LINE_END) {
        ctx->line++;
        if (status != LINE_OK)
            return fail_line(ctx, status);
        split_fields(line, &f);
        if (f.count == 0)
            continue;
        if (strcmp(f.field[0], "v") == 0) {
            /* x y z, optionally followed by w or a vertex colour */
            if (f.count < 4 || f.count > 7)
                return fail(ctx, "vertex needs 3 coordinates: v X Y Z");
            vec3 v;
            if (parse_vec3(ctx, f.field + 1, "vertex coordinate", &v))
                return 2;
            for (int i = 4; i < f.count; i++) {
                double ignored;
                if (parse_number(ctx, f.field[i], "vertex", &ignored))
                    return 2;
            }
            if (reserve_one((void **)&obj->vertices, &obj->vertex_capacity, obj->vertex_count, sizeof *obj->vertices))
                return fail(ctx, "out of memory");
            obj->vertices[obj->vertex_count++] = v;
        } else if (strcmp(f.field[0], "f") == 0) {
            int corner_count = f.count - 1;
            if (corner_count < 3)
                return fail(ctx, "face needs at least 3 vertices, has %d", corner_count);
            /* Fan triangulation (corner 0, i - 1, i); zero-area triangles are dropped. */
            int first, previous, current;
            if (parse_face_vertex(ctx, f.field[1], obj->vertex_count, &first) ||
                parse_face_vertex(ctx, f.field[2], obj->vertex_count, &previous))
                return 2;
            for (int i = 3; i <= corner_count; i++, previous = current) {
                if (parse_face_vertex(ctx, f.field[i], obj->vertex_count, &current))
                    return 2;
                vec3 a = obj->vertices[first], b = obj->vertices[previous], c = obj->vertices[current];
                if (is_degenerate_triangle(a, b, c))
                    continue;
                if (add_triangle(p, a, b, c, surface_index))
                    return fail(ctx, "out of memory");
            }
            (*face_count)++;
        }
        /* Anything else (vn, vt, o, g, s, usemtl, mtllib, l, ...) is not geometry we use. */
    }
    if (ferror(file))
        return fail(ctx, "read error");
    return 0;
}

static int load_obj(parser *p, const char *obj_path, int surface_index)
{
    FILE *file = fopen(obj_path, "rb");
    if (file == NULL)
        return fail(&p->ctx, "cannot open mesh '%s': %s", obj_path, strerror(errno));
    error_context ctx = {.path = obj_path, .line = 0, .err = p->ctx.err, .err_size = p->ctx.err_size};
    obj_state obj = {0};
    int face_count = 0;
    int first_triangle = p->s->triangle_count;
    int status = read_obj_lines(p, file, &ctx, &obj, surface_index, &face_count);
    fclose(file);
    free(obj.vertices);
    if (status)
        return status;
    if (face_count == 0)
        return fail(&ctx, "no faces in mesh");
    if (p->s->triangle_count == first_triangle)
        return fail(&ctx, "every face of the mesh has zero area");
    return 0;
}

/* ------------------------------------------------------------------------ */
/* The file                                                                  */

static int parse_file(parser *p, FILE *file)
{
    char line[LINE_CAPACITY];
    fields f;
    line_status status;
    while ((status = read_line(file, line, sizeof line)) != LINE_END) {
        p->ctx.line++;
        if (status != LINE_OK)
            return fail_line(&p->ctx, status);
        split_fields(line, &f);
        if (f.count == 0)
            continue;
        if (parse_statement(p, &f))
            return 2;
    }
    if (ferror(file))
        return fail(&p->ctx, "read error");
    /* Whole-file checks are reported at the last line. */
    if (!p->has_camera)
        return fail(&p->ctx, "no camera statement");
    if (p->s->surface_count == 0)
        return fail(&p->ctx, "no surfaces in the scene");
    return 0;
}

int scene_parse(const char *path, scene *out, char *err, size_t err_size, int *lines)
{
    parser p = {.s = out, .ctx = {.path = path, .line = 0, .err = err, .err_size = err_size}};
    *lines = 0;

    /* Mesh files are relative to the scene file's directory. */
    const char *slash = strrchr(path, '/');
    size_t dir_length = slash ? (size_t)(slash - path) + 1 : 0;
    if (dir_length >= sizeof p.directory)
        return fail(&p.ctx, "path too long");
    memcpy(p.directory, path, dir_length);
    p.directory[dir_length] = '\0';

    FILE *file = fopen(path, "rb");
    if (file == NULL)
        return fail(&p.ctx, "cannot open file: %s", strerror(errno));
    int status = parse_file(&p, file);
    fclose(file);
    *lines = p.ctx.line;
    return status;
}

int scene_parse_error(const char *path, int line, char *err, size_t err_size, const char *message)
{
    error_context ctx = {.path = path, .line = line, .err = err, .err_size = err_size};
    return fail(&ctx, "%s", message);
}
