/* test_scene.c — unit tests of common/scene.c: the parser (valid scenes, OBJ
 * meshes, the corpus of malformed inputs in tests/bad/), ray-triangle and
 * ray-sphere intersection, the BVH against brute force, occlusion, sampling
 * and the camera.  Run from the repository root. */
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bvh.h"
#include "check.h"
#include "rng.h"
#include "sampling.h"
#include "scene.h"

static char temp_dir[] = "/tmp/test_scene_XXXXXX";

/* Write `text` to temp_dir/name; returns the full path in a static buffer. */
static const char *write_temp(const char *name, const char *text)
{
    static char path[512];
    snprintf(path, sizeof path, "%s/%s", temp_dir, name);
    FILE *f = fopen(path, "wb");
    if (f == NULL)
        return NULL;
    fputs(text, f);
    fclose(f);
    return path;
}

static const char CORNELL[] = "# Cornell box (Cornell data page geometry), light lowered by 0.1 mm\n"
                              "camera eye 278 273 -800  look 278 273 0  up 0 1 0  fov 39.3076\n"
                              "material white diffuse 0.725 0.71 0.68\n"
                              "material red   diffuse 0.63 0.065 0.05\n"
                              "material green diffuse 0.14 0.45 0.091\n"
                              "material lamp  emitter 17 12 4  diffuse 0.78 0.78 0.78\n"
                              "quad floor     white  552.8 0 0   0 0 0   0 0 559.2   549.6 0 559.2\n"
                              "quad ceiling   white  556 548.8 0   556 548.8 559.2   0 548.8 559.2   0 548.8 0\n"
                              "quad light     lamp   343 548.7 227   343 548.7 332   213 548.7 332   213 548.7 227\n"
                              "quad back_wall white  549.6 0 559.2   0 0 559.2   0 548.8 559.2   556 548.8 559.2\n"
                              "quad green_wall green 0 0 559.2   0 0 0   0 548.8 0   0 548.8 559.2\n"
                              "# the red wall is not planar: two triangles\n"
                              "triangle red_wall_a red  552.8 0 0   549.6 0 559.2   556 548.8 559.2\n"
                              "triangle red_wall_b red  552.8 0 0   556 548.8 559.2   556 548.8 0\n"
                              "quad short_1 white 130 165 65  82 165 225  240 165 272  290 165 114\n"
                              "quad short_2 white 290 0 114  290 165 114  240 165 272  240 0 272\n"
                              "quad short_3 white 130 0 65  130 165 65  290 165 114  290 0 114\n"
                              "quad short_4 white 82 0 225  82 165 225  130 165 65  130 0 65\n"
                              "quad short_5 white 240 0 272  240 165 272  82 165 225  82 0 225\n"
                              "quad tall_1 white 423 330 247  265 330 296  314 330 456  472 330 406\n"
                              "quad tall_2 white 423 0 247  423 330 247  472 330 406  472 0 406\n"
                              "quad tall_3 white 472 0 406  472 330 406  314 330 456  314 0 456\n"
                              "quad tall_4 white 314 0 456  314 330 456  265 330 296  265 0 296\n"
                              "quad tall_5 white 265 0 296  265 330 296  423 330 247  423 0 247\n"
                              "light bulb point 278 500 279.5  1000 1000 1000\n"
                              "probe floor_center 278 0 279.5  0 2 0   # normalised on load\n";

static int load_text(const char *name, const char *text, scene *s, char *err, size_t err_size)
{
    const char *path = write_temp(name, text);
    if (path == NULL) {
        snprintf(err, err_size, "cannot write %s", name);
        return -1;
    }
    int status = scene_load(path, s, err, err_size);
    unlink(path);
    return status;
}

/* ---------------------------------------------------------------- triangles */

static triangle make_triangle(vec3 a, vec3 b, vec3 c)
{
    triangle t = {.p0 = a, .e1 = v3_sub(b, a), .e2 = v3_sub(c, a)};
    t.normal = v3_normalize(v3_cross(t.e1, t.e2));
    t.area = triangle_area(a, b, c);
    return t;
}

static void test_triangle_hit_and_miss(void)
{
    triangle t = make_triangle(v3(0, 0, 0), v3(1, 0, 0), v3(0, 1, 0));
    CHECK_NEAR(intersect_triangle(&t, (ray){v3(0.25, 0.25, 1), v3(0, 0, -1)}), 1.0, 1e-15, "front hit");
    CHECK_NEAR(intersect_triangle(&t, (ray){v3(0.25, 0.25, -2), v3(0, 0, 1)}), 2.0, 1e-15, "back hit (no culling)");
    CHECK_NEAR(intersect_triangle(&t, (ray){v3(0.25, 0.25, 2), v3(0, 0, -2)}), 1.0, 1e-15, "non-unit direction");
    CHECK(isinf(intersect_triangle(&t, (ray){v3(0.25, 0.25, 1), v3(0, 0, 1)})), "triangle behind the ray");
    CHECK(isinf(intersect_triangle(&t, (ray){v3(0.6, 0.6, 1), v3(0, 0, -1)})), "outside the hypotenuse");
    CHECK(isinf(intersect_triangle(&t, (ray){v3(-0.1, 0.5, 1), v3(0, 0, -1)})), "outside the left edge");
    CHECK(isinf(intersect_triangle(&t, (ray){v3(0.2, 0.2, 0), v3(0, 0, -1)})),
          "origin on the triangle: t = 0 is no hit");
}

static void test_triangle_edges_and_grazing(void)
{
    triangle t = make_triangle(v3(0, 0, 0), v3(1, 0, 0), v3(0, 1, 0));
    /* Exactly on edges and vertices: a hit or a miss, never NaN. */
    vec3 on_boundary[] = {v3(0.5, 0, 1), v3(0, 0.5, 1), v3(0.5, 0.5, 1), v3(0, 0, 1), v3(1, 0, 1), v3(0, 1, 1)};
    for (size_t i = 0; i < sizeof on_boundary / sizeof on_boundary[0]; i++) {
        double hit_t = intersect_triangle(&t, (ray){on_boundary[i], v3(0, 0, -1)});
        CHECK(!isnan(hit_t), "NaN on boundary point %zu", i);
        CHECK(isinf(hit_t) || fabs(hit_t - 1.0) < 1e-15, "boundary point %zu: t = %g", i, hit_t);
    }
    /* Rays in the triangle's plane and parallel to it: misses, not NaN. */
    ray grazing[] = {
        {v3(-1, 0.25, 0), v3(1, 0, 0)},      {v3(-1, -1, 0), v3(1, 1, 0)},   {v3(0.25, -1, 0), v3(0, 1, 0)},
        {v3(-1, 0.25, 1e-300), v3(1, 0, 0)}, {v3(0.2, 0.2, 1), v3(1, 0, 0)}, {v3(0.2, 0.2, 1), v3(0, 0, 0)},
    };
    for (size_t i = 0; i < sizeof grazing / sizeof grazing[0]; i++) {
        double hit_t = intersect_triangle(&t, grazing[i]);
        CHECK(isinf(hit_t), "grazing ray %zu: t = %g", i, hit_t);
    }
    /* Almost parallel: a tiny determinant must not produce NaN either. */
    rng g = rng_for(1, 2, 3);
    for (int i = 0; i < 100000; i++) {
        ray r = {v3(rng_uniform(&g) * 2 - 0.5, rng_uniform(&g) * 2 - 0.5, (rng_uniform(&g) - 0.5) * 1e-12),
                 v3(rng_uniform(&g) - 0.5, rng_uniform(&g) - 0.5, (rng_uniform(&g) - 0.5) * 1e-200)};
        double hit_t = intersect_triangle(&t, r);
        if (isnan(hit_t) || hit_t <= 0.0) {
            CHECK(0, "near-parallel ray %d: t = %g", i, hit_t);
            break;
        }
    }
}

/* ------------------------------------------------------------------ spheres */

static void test_sphere_basic(void)
{
    vec3 c = v3(1, 2, 3);
    CHECK_NEAR(intersect_sphere(c, 2, (ray){v3(1, 2, -7), v3(0, 0, 1)}), 8.0, 1e-14, "front hit");
    CHECK_NEAR(intersect_sphere(c, 2, (ray){v3(1, 2, 3), v3(0, 0, 1)}), 2.0, 1e-14, "from the centre");
    CHECK_NEAR(intersect_sphere(c, 2, (ray){v3(1, 2, 4), v3(0, 0, -1)}), 3.0, 1e-14, "from inside");
    CHECK_NEAR(intersect_sphere(c, 2, (ray){v3(1, 2, -7), v3(0, 0, 4)}), 2.0, 1e-14, "non-unit direction");
    CHECK(isinf(intersect_sphere(c, 2, (ray){v3(1, 2, 7), v3(0, 0, 1)})), "sphere behind the ray");
    CHECK(isinf(intersect_sphere(c, 2, (ray){v3(1, 4.5, -7), v3(0, 0, 1)})), "passes above");
    CHECK(isinf(intersect_sphere(c, 2, (ray){v3(1, 2, 5), v3(0, 0, 1)})), "leaving from the surface");
    double tangent = intersect_sphere(c, 2, (ray){v3(1, 4, -7), v3(0, 0, 1)});
    CHECK(!isnan(tangent), "tangent ray gave NaN");
}

/* smallpt's walls are spheres of radius 1e5.  The naive quadratic loses
 * most digits there; the Ray Tracing Gems form must not. */
static void test_sphere_huge_radius(void)
{
    const double r = 1e5;
    const vec3 c = v3(1e5 + 1, 40.8, 81.6); /* smallpt's left wall: surface near x = 1 */
    const vec3 o = v3(50, 52, 295.6);       /* smallpt's camera position */

    /* Straight toward -x: the surface point at (y, z) = (52, 295.6) is
     * x = 1 + q / (r + sqrt(r^2 - q)), q = dy^2 + dz^2 (no cancellation). */
    double q = (52 - 40.8) * (52 - 40.8) + (295.6 - 81.6) * (295.6 - 81.6);
    double expected = 50.0 - (1.0 + q / (r + sqrt(r * r - q)));
    CHECK_NEAR(intersect_sphere(c, r, (ray){o, v3(-1, 0, 0)}), expected, 1e-9, "t toward the wall");

    rng g = rng_for(7, 0, 0);
    double worst = 0.0;
    for (int i = 0; i < 10000; i++) {
        vec3 d = v3_normalize(v3(-1.0, rng_uniform(&g) - 0.5, rng_uniform(&g) - 0.5));
        double t = intersect_sphere(c, r, (ray){o, d});
        CHECK(isfinite(t) && t > 0, "ray %d missed the wall", i);
        if (!(isfinite(t) && t > 0))
            break;
        vec3 p = v3_madd(o, d, t);
        double residual = fabs(v3_length(v3_sub(p, c)) - r) / t;
        if (residual > worst)
            worst = residual;
    }
    CHECK(worst < 1e-9, "hit point off the sphere by %g of the distance travelled", worst);

    /* From outside, 50 units away from a sphere of radius 1e5. */
    CHECK_NEAR(intersect_sphere(v3(0, 0, 0), r, (ray){v3(0, 0, r + 50), v3(0, 0, -1)}), 50.0, 1e-9, "outside");
}

/* -------------------------------------------------------------- the parser */

static void test_parse_cornell(void)
{
    scene s;
    char err[512] = "";
    int status = load_text("cornell.scene", CORNELL, &s, err, sizeof err);
    CHECK(status == 0, "load failed: %.300s", err);
    if (status)
        return;
    CHECK(s.material_count == 4, "materials %d", s.material_count);
    CHECK(s.surface_count == 17, "surfaces %d", s.surface_count);
    CHECK(s.triangle_count == 32, "triangles %d", s.triangle_count);
    CHECK(s.sphere_count == 0, "spheres %d", s.sphere_count);
    CHECK(s.light_count == 1 && s.probe_count == 1, "lights %d probes %d", s.light_count, s.probe_count);
    CHECK(s.width == 512 && s.height == 512, "default image size %dx%d", s.width, s.height);
    CHECK(s.background.x == 0 && s.background.y == 0 && s.background.z == 0, "default background");
    CHECK_NEAR(s.camera.fov_degrees, 39.3076, 0, "fov");
    CHECK_NEAR(s.camera.eye.z, -800, 0, "eye z");

    int light = scene_find_surface(&s, "light");
    CHECK(light >= 0, "no surface 'light'");
    CHECK(scene_find_surface(&s, "nonexistent") == -1, "find of a missing name");
    CHECK(s.emitter_count == 1 && s.emitters[0] == light, "emitters");
    CHECK_NEAR(s.emitter_area, 130.0 * 105.0, 1e-9, "emitter area");
    CHECK_NEAR(s.surfaces[light].area, 13650.0, 1e-9, "light area");
    CHECK(s.surfaces[light].kind == SURFACE_QUAD && s.surfaces[light].triangle_count == 2, "light is a quad");
    CHECK(s.surfaces[light].line == 9, "light on line %d", s.surfaces[light].line);
    const material *lamp = &s.materials[s.surfaces[light].material];
    CHECK(lamp->kind == MATERIAL_EMITTER, "lamp kind");
    CHECK_NEAR(lamp->emission.x, 17, 0, "lamp radiance");
    CHECK_NEAR(lamp->albedo.y, 0.78, 0, "lamp diffuse albedo");
    /* The light faces down (into the box), the floor up: right-hand rule. */
    const triangle *lt = &s.triangles[s.surfaces[light].first_triangle];
    CHECK_NEAR(lt->normal.y, -1, 1e-15, "light normal");
    int floor = scene_find_surface(&s, "floor");
    CHECK_NEAR(s.triangles[s.surfaces[floor].first_triangle].normal.y, 1, 1e-15, "floor normal");
    /* Trapezoid: (552.8 + 549.6) / 2 * 559.2 (cornellbox.md: 308 231 mm^2). */
    CHECK_NEAR(s.surfaces[floor].area, 308231.04, 1e-6, "floor area");
    CHECK_NEAR(s.probes[0].normal.y, 1, 0, "probe normal normalised");
    CHECK_NEAR(s.lights[0].intensity.z, 1000, 0, "light intensity");

    CHECK_NEAR(s.bounds.hi.x, 556.0, 0, "bounds");
    CHECK_NEAR(s.bounds.hi.z, 559.2, 0, "bounds");
    CHECK_NEAR(s.epsilon, 1e-9 * 559.2, 1e-20, "epsilon");

    /* Structure of the BVH: leaves of at most 2 pairs that together cover
     * the pairs once, every primitive in one lane of them (the second lane of
     * a leaf's last pair empty for an odd count, no other lane), the leaf
     * order the lanes' order, every inner node reached once. */
    int seen[64] = {0}, covered[64] = {0}, node_seen[64] = {0};
    int leaf_total = 0;
    CHECK(s.bvh.primitive_count == s.triangle_count && s.bvh.node_count <= 64 && s.bvh.leaf_pair_count <= 64,
          "%d nodes, %d pairs", s.bvh.node_count, s.bvh.leaf_pair_count);
    for (int i = 0; i < s.bvh.node_count; i++)
        for (int k = 0; k < BVH_WIDTH; k++) {
            const wide_node *n = &s.bvh.nodes[i];
            bool empty = n->bounds[0][k] > n->bounds[3][k];
            if (empty)
                continue;
            if (n->child[k] >= 0) {
                CHECK(n->child[k] > i && n->child[k] < s.bvh.node_count, "child %d of node %d", n->child[k], i);
                node_seen[n->child[k]]++;
                continue;
            }
            int first = bvh_leaf_first(n->child[k]), count = bvh_leaf_count(n->child[k]);
            CHECK(count >= 1 && count <= 2 && first >= 0 && first + count <= s.bvh.leaf_pair_count, "leaf %d + %d",
                  first, count);
            for (int j = first; j < first + count; j++) {
                const leaf_pair *p = &s.bvh.leaf_pairs[j];
                covered[j]++;
                CHECK(p->primitive[0] >= 0 && (p->primitive[1] >= 0 || j == first + count - 1) && p->sphere_lanes == 0,
                      "pair %d: lanes %d %d", j, p->primitive[0], p->primitive[1]);
                leaf_total += (p->primitive[0] >= 0) + (p->primitive[1] >= 0);
            }
        }
    for (int i = 1; i < s.bvh.node_count; i++)
        CHECK(node_seen[i] == 1, "node %d is reached %d times", i, node_seen[i]);
    for (int i = 0; i < s.bvh.leaf_pair_count; i++)
        CHECK(covered[i] == 1, "pair %d covered %d times", i, covered[i]);
    int order = 0;
    for (int i = 0; i < 2 * s.bvh.leaf_pair_count; i++) {
        int primitive = s.bvh.leaf_pairs[i / 2].primitive[i % 2];
        if (primitive < 0)
            continue;
        seen[primitive]++;
        CHECK(order < s.triangle_count && s.bvh.primitive_order[order++] == primitive, "lane %d is out of leaf order",
              i);
    }
    for (int i = 0; i < s.triangle_count; i++)
        CHECK(seen[i] == 1, "primitive %d appears %d times", i, seen[i]);
    CHECK(leaf_total == s.triangle_count, "leaves hold %d primitives", leaf_total);
    scene_free(&s);
    CHECK(s.surfaces == NULL && s.bvh.nodes == NULL, "scene_free clears the scene");
}

static void test_parse_syntax_variants(void)
{
    const char text[] = "\t# tabs, CRLF, comments at the end of statements\r\n"
                        "image 320 240   # size\r\n"
                        "background 0.1 0.2 0.3\r\n"
                        "camera eye 0 0 -5 look 0 0 0 up 0 1 0 fov 40\r\n"
                        "\r\n"
                        "material p phong kd 0.5 0.4 0.3 ks 0.5 0.6 0.7 exp 20\n"
                        "material m mirror 0.9 0.9 0.9\n"
                        "material g glass 1.5\n"
                        "material tinted glass 1.33 0.9 0.95 1\n"
                        "material e emitter 1e1 0 2.5E-1\n"
                        "sphere ball g 0 0 0 1\n"
                        "sphere ball2 tinted 3 0 0 .5\n"
                        "triangle tri\tp  -1 -1 2  1 -1 2  0 1 2\n"
                        "probe pr 0 0 -3  0 0 1\n";
    scene s;
    char err[512] = "";
    int status = load_text("variants.scene", text, &s, err, sizeof err);
    CHECK(status == 0, "load failed: %.300s", err);
    if (status)
        return;
    CHECK(s.width == 320 && s.height == 240, "image %dx%d", s.width, s.height);
    CHECK_NEAR(s.background.z, 0.3, 0, "background");
    CHECK(s.material_count == 5, "materials %d", s.material_count);
    CHECK(s.materials[0].kind == MATERIAL_PHONG, "phong");
    CHECK_NEAR(s.materials[0].albedo.x, 0.5, 0, "kd");
    CHECK_NEAR(s.materials[0].specular.z, 0.7, 0, "ks");
    CHECK_NEAR(s.materials[0].exponent, 20, 0, "exp");
    CHECK(s.materials[1].kind == MATERIAL_MIRROR && s.materials[1].specular.y == 0.9, "mirror");
    CHECK(s.materials[2].kind == MATERIAL_GLASS && s.materials[2].ior == 1.5, "glass ior");
    CHECK(s.materials[2].specular.x == 1 && s.materials[2].specular.y == 1, "glass default tint");
    CHECK(s.materials[3].specular.y == 0.95 && s.materials[3].ior == 1.33, "glass tint");
    CHECK(s.materials[4].kind == MATERIAL_EMITTER && s.materials[4].emission.x == 10 &&
              s.materials[4].emission.z == 0.25 && s.materials[4].albedo.x == 0,
          "emitter");
    CHECK(s.emitter_count == 0, "no surface uses the emitter");
    CHECK(s.sphere_count == 2 && s.triangle_count == 1, "spheres %d triangles %d", s.sphere_count, s.triangle_count);
    int ball = scene_find_surface(&s, "ball");
    CHECK_NEAR(s.surfaces[ball].area, 4 * M_PI, 1e-14, "sphere area");
    CHECK_NEAR(s.bounds.hi.x, 3.5, 0, "bounds include spheres");
    CHECK_NEAR(s.bounds.lo.y, -1, 0, "bounds");
    CHECK_NEAR(s.epsilon, 3.5e-9, 1e-24, "epsilon");
    hit h;
    CHECK(scene_intersect(&s, (ray){v3(0, 0, -5), v3(0, 0, 1)}, INFINITY, &h), "camera ray misses the ball");
    CHECK(h.surface == ball && fabs(h.t - 4) < 1e-14, "hit surface %d at t %g", h.surface, h.t);
    CHECK_NEAR(h.normal.z, -1, 1e-15, "sphere normal points out");
    CHECK(!scene_intersect(&s, (ray){v3(0, 0, -5), v3(0, 0, 1)}, 3.9, &h), "t_max must cut the ray");
    scene_free(&s);
}

static void test_obj_meshes(void)
{
    char cwd[1024];
    CHECK(getcwd(cwd, sizeof cwd) != NULL, "getcwd");
    char text[4096];
    /* An absolute path, then a path relative to the scene file. */
    snprintf(text, sizeof text,
             "camera eye 0 0 -5 look 0 0 0 up 0 1 0 fov 40\n"
             "material white diffuse 0.5 0.5 0.5\n"
             "material lamp emitter 1 1 1\n"
             "mesh cube white %s/tests/data/cube.obj\n"
             "mesh pentagon lamp pentagon.obj\n"
             "mesh circle white circle.obj\n",
             cwd);
    /* A 64-gon: one face of many corners, area (n/2) sin(2 pi / n). */
    char circle[8192];
    size_t used = 0;
    for (int i = 0; i < 64; i++)
        used += (size_t)snprintf(circle + used, sizeof circle - used, "v %.17g %.17g 5\n", cos(2 * M_PI * i / 64),
                                 sin(2 * M_PI * i / 64));
    used += (size_t)snprintf(circle + used, sizeof circle - used, "f");
    for (int i = 1; i <= 64; i++)
        used += (size_t)snprintf(circle + used, sizeof circle - used, " %d", i);
    snprintf(circle + used, sizeof circle - used, "\n");
    write_temp("circle.obj", circle);
    FILE *src = fopen("tests/data/pentagon.obj", "rb");
    CHECK(src != NULL, "tests/data/pentagon.obj missing (run from the repository root)");
    if (src == NULL)
        return;
    char obj[2048];
    size_t n = fread(obj, 1, sizeof obj - 1, src);
    obj[n] = '\0';
    fclose(src);
    write_temp("pentagon.obj", obj);

    scene s;
    char err[512] = "";
    int status = load_text("mesh.scene", text, &s, err, sizeof err);
    char pentagon_path[512];
    snprintf(pentagon_path, sizeof pentagon_path, "%s/pentagon.obj", temp_dir);
    unlink(pentagon_path);
    snprintf(pentagon_path, sizeof pentagon_path, "%s/circle.obj", temp_dir);
    unlink(pentagon_path);
    CHECK(status == 0, "load failed: %.300s", err);
    if (status)
        return;
    int cube = scene_find_surface(&s, "cube"), pentagon = scene_find_surface(&s, "pentagon");
    CHECK(s.surfaces[cube].kind == SURFACE_MESH, "mesh kind");
    CHECK(s.surfaces[cube].triangle_count == 12, "cube triangles %d (degenerate face dropped)",
          s.surfaces[cube].triangle_count);
    CHECK_NEAR(s.surfaces[cube].area, 24.0, 1e-12, "cube area");
    for (int i = 0; i < s.surfaces[cube].triangle_count; i++) {
        const triangle *t = &s.triangles[s.surfaces[cube].first_triangle + i];
        vec3 centroid = v3_add(t->p0, v3_scale(v3_add(t->e1, t->e2), 1.0 / 3.0));
        CHECK(v3_dot(t->normal, centroid) > 0.9, "cube triangle %d normal points inward", i);
    }
    CHECK(s.surfaces[pentagon].triangle_count == 3, "pentagon triangles %d", s.surfaces[pentagon].triangle_count);
    CHECK_NEAR(s.surfaces[pentagon].area, 2.5 * sin(72.0 * M_PI / 180.0), 1e-12, "pentagon area");
    CHECK(s.emitter_count == 1 && s.emitters[0] == pentagon, "mesh emitter");
    int circle_index = scene_find_surface(&s, "circle");
    CHECK(s.surfaces[circle_index].triangle_count == 62, "64-gon triangles %d",
          s.surfaces[circle_index].triangle_count);
    CHECK_NEAR(s.surfaces[circle_index].area, 32 * sin(2 * M_PI / 64), 1e-12, "64-gon area");
    CHECK_NEAR(s.triangles[s.surfaces[pentagon].first_triangle].normal.z, 1, 1e-15, "pentagon normal");
    scene_free(&s);
}

/* Every file in tests/bad/ must fail with "file:line:" where the first line
 * says which: "# expect-line: N" (this file) or "# expect: PATH:N" (an OBJ it
 * references).  A file with no such comment (the empty file) expects line 0. */
static void test_bad_corpus(void)
{
    DIR *dir = opendir("tests/bad");
    CHECK(dir != NULL, "cannot open tests/bad (run from the repository root)");
    if (dir == NULL)
        return;
    int files = 0;
    struct dirent *entry;
    while ((entry = readdir(dir)) != NULL) {
        size_t len = strlen(entry->d_name);
        if (len < 6 || strcmp(entry->d_name + len - 6, ".scene") != 0)
            continue;
        char path[512], expected[600], first_line[512] = "";
        snprintf(path, sizeof path, "tests/bad/%s", entry->d_name);
        FILE *f = fopen(path, "rb");
        if (f == NULL || fgets(first_line, sizeof first_line, f) == NULL)
            first_line[0] = '\0';
        if (f)
            fclose(f);
        int line = 0;
        char target[512];
        if (sscanf(first_line, "# expect-line: %d", &line) == 1) {
            snprintf(expected, sizeof expected, "%s:%d: ", path, line);
        } else if (sscanf(first_line, "# expect: %511s", target) == 1) {
            snprintf(expected, sizeof expected, "%s: ", target);
        } else {
            snprintf(expected, sizeof expected, "%s:0: ", path);
        }
        scene s;
        char err[1024] = "";
        int status = scene_load(path, &s, err, sizeof err);
        /* (precisions keep the messages inside check.h's buffer) */
        CHECK(status == 2, "%.120s: status %d, expected 2", path, status);
        CHECK(strncmp(err, expected, strlen(expected)) == 0, "error '%.200s', expected it to start with '%.150s'", err,
              expected);
        CHECK(strlen(err) > strlen(expected) + 5, "no message after the location: '%.200s'", err);
        CHECK(strchr(err, '\n') == NULL, "%.120s: error has more than one line", path);
        CHECK(s.materials == NULL && s.surfaces == NULL && s.triangles == NULL && s.bvh.nodes == NULL,
              "%.120s: a failed load must free everything", path);
        if (status == 0)
            scene_free(&s);
        files++;
    }
    closedir(dir);
    CHECK(files >= 30, "only %d bad scene files", files);
}

static void test_error_messages(void)
{
    scene s;
    char err[512];
    CHECK(scene_load("tests/bad/does-not-exist.scene", &s, err, sizeof err) == 2, "missing file loads");
    const char *expected = "tests/bad/does-not-exist.scene:0: ";
    CHECK(strncmp(err, expected, strlen(expected)) == 0, "missing file message '%.200s'", err);
    CHECK(scene_load("tests/bad/nonplanar-quad.scene", &s, err, sizeof err) == 2, "non-planar quad loads");
    CHECK(strstr(err, "split it into two triangles") != NULL, "non-planar advice missing: '%.200s'", err);
    /* A short buffer is filled safely (truncated, terminated). */
    char tiny[12];
    memset(tiny, 'x', sizeof tiny);
    CHECK(scene_load("tests/bad/nan-radius.scene", &s, tiny, sizeof tiny) == 2, "nan radius loads");
    CHECK(memchr(tiny, '\0', sizeof tiny) != NULL, "short error buffer not terminated");
    CHECK(scene_load("tests/bad/nan-radius.scene", &s, NULL, 0) == 2, "NULL error buffer");
}

/* ------------------------------------------------------ BVH and occlusion */

/* A scene of random triangles and spheres of mixed sizes. */
static char *random_scene_text(void)
{
    size_t capacity = 1 << 20, used = 0;
    char *text = malloc(capacity);
    if (text == NULL)
        return NULL;
    used += (size_t)snprintf(text + used, capacity - used,
                             "camera eye 5 5 -20 look 5 5 5 up 0 1 0 fov 40\n"
                             "material white diffuse 0.5 0.5 0.5\n"
                             "quad ground white -5 0 -5  -5 0 15  15 0 15  15 0 -5\n");
    rng g = rng_for(42, 0, 0);
    for (int i = 0; i < 600; i++) {
        vec3 a = v3(10 * rng_uniform(&g), 10 * rng_uniform(&g), 10 * rng_uniform(&g));
        double size = i % 10 == 0 ? 5.0 : 0.8;
        vec3 b = v3_add(
            a, v3(size * (rng_uniform(&g) - 0.5), size * (rng_uniform(&g) - 0.5), size * (rng_uniform(&g) - 0.5)));
        vec3 c = v3_add(
            a, v3(size * (rng_uniform(&g) - 0.5), size * (rng_uniform(&g) - 0.5), size * (rng_uniform(&g) - 0.5)));
        used += (size_t)snprintf(text + used, capacity - used,
                                 "triangle t%d white %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", i, a.x,
                                 a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z);
    }
    for (int i = 0; i < 40; i++) {
        used += (size_t)snprintf(text + used, capacity - used, "sphere s%d white %.17g %.17g %.17g %.17g\n", i,
                                 10 * rng_uniform(&g), 10 * rng_uniform(&g), 10 * rng_uniform(&g),
                                 0.05 + 0.6 * rng_uniform(&g));
    }
    return text;
}

static vec3 random_direction(rng *g)
{
    vec3 d = uniform_sample_sphere(rng_uniform(g), rng_uniform(g));
    /* Some rays along axes or in axis planes: zero components (inf 1/d). */
    int kind = (int)(rng_next_u32(g) % 8);
    if (kind == 0)
        d.x = 0;
    if (kind == 1)
        d = v3(0, 0, d.z < 0 ? -1 : 1);
    if (kind == 2)
        d.y = 0;
    return d;
}

/* A scene where the tree only adds work (smallpt's: nine spheres, six of
 * them walls whose boxes hold the room) is searched by testing every
 * primitive (bvh.linear); the Cornell box by the tree.  Both ways give the
 * same hits, to the last bit: forced the other way, they agree. */
static void test_linear_search_of_small_scenes(void)
{
    const char *paths[] = {"scenes/smallpt.scene", "scenes/cornell.scene"};
    for (int k = 0; k < 2; k++) {
        scene s;
        char err[512] = "";
        int status = scene_load(paths[k], &s, err, sizeof err);
        CHECK(status == 0, "%s: %.300s", paths[k], err);
        if (status)
            continue;
        CHECK(s.bvh.linear == (k == 0), "%s: linear %d", paths[k], s.bvh.linear);
        rng g = rng_for(17, (uint64_t)k, 0);
        int mismatches = 0, hits = 0;
        for (int i = 0; i < 20000; i++) {
            vec3 lo = s.bounds.lo, size = v3_sub(s.bounds.hi, s.bounds.lo);
            if (k == 0)
                lo = v3(1, 0, 0), size = v3(98, 81.6, 170); /* the room, not the walls' spheres */
            vec3 o =
                v3(lo.x + size.x * rng_uniform(&g), lo.y + size.y * rng_uniform(&g), lo.z + size.z * rng_uniform(&g));
            vec3 d = random_direction(&g), end = v3_madd(o, d, 50 * rng_uniform(&g));
            hit a, b;
            int linear = s.bvh.linear;
            int found_a = scene_intersect(&s, (ray){o, d}, INFINITY, &a), blocked_a = scene_occluded(&s, o, end);
            s.bvh.linear = !linear;
            int found_b = scene_intersect(&s, (ray){o, d}, INFINITY, &b), blocked_b = scene_occluded(&s, o, end);
            s.bvh.linear = linear;
            hits += found_a;
            if (found_a != found_b || blocked_a != blocked_b || (found_a && (a.t != b.t || a.primitive != b.primitive)))
                mismatches++;
        }
        CHECK(mismatches == 0, "%s: %d of 20000 rays differ between the tree and testing every primitive", paths[k],
              mismatches);
        CHECK(hits > 10000, "%s: only %d hits", paths[k], hits);
        scene_free(&s);
    }
}

/* Equally near hits: the lowest primitive index wins, whichever way the
 * scene is searched.  Five spheres in one place give every ray five equal
 * t (the same arithmetic on the same numbers); linear search keeps them in
 * two lanes (0, 2, 4 and 1, 3), where a tie rule that let a later sphere win
 * within its lane would answer 3 or 4. */
static void test_equal_hits_go_to_the_lowest_index(void)
{
    const char *text = "camera eye 0 0 -5 look 0 0 0 up 0 1 0 fov 40\n"
                       "material white diffuse 0.5 0.5 0.5\n"
                       "sphere a white 0 0 0 1\nsphere b white 0 0 0 1\nsphere c white 0 0 0 1\n"
                       "sphere d white 0 0 0 1\nsphere e white 0 0 0 1\n";
    scene s;
    char err[512] = "";
    int status = load_text("ties.scene", text, &s, err, sizeof err);
    CHECK(status == 0, "ties.scene: %.300s", err);
    if (status)
        return;
    rng g = rng_for(23, 0, 0);
    int wrong = 0, misses = 0;
    for (int i = 0; i < 200; i++) {
        vec3 d = v3_normalize(v3_sub(v3(rng_uniform(&g) - 0.5, rng_uniform(&g) - 0.5, 0.0), v3(0, 0, -5)));
        ray r = {v3(0, 0, -5), d};
        for (int way = 0; way < 3; way++) {
            hit h;
            s.bvh.linear = way == 1;
            int found =
                way == 2 ? scene_intersect_brute_force(&s, r, INFINITY, &h) : scene_intersect(&s, r, INFINITY, &h);
            misses += !found;
            wrong += found && h.primitive != s.triangle_count;
        }
    }
    CHECK(misses == 0, "%d of 600 rays missed five spheres in their path", misses);
    CHECK(wrong == 0, "%d of 600 equally near hits did not go to the first sphere", wrong);
    scene_free(&s);
}

static void test_bvh_matches_brute_force(void)
{
    char *text = random_scene_text();
    CHECK(text != NULL, "out of memory");
    if (text == NULL)
        return;
    scene s;
    char err[512] = "";
    int status = load_text("random.scene", text, &s, err, sizeof err);
    free(text);
    CHECK(status == 0, "load failed: %.300s", err);
    if (status)
        return;
    CHECK(s.triangle_count >= 590 && s.sphere_count == 40, "primitives %d + %d", s.triangle_count, s.sphere_count);

    rng g = rng_for(9, 0, 0);
    int mismatches = 0, hits = 0, lane_mismatches = 0, lane_checked = 0;
    const int rays = 100000;
    for (int i = 0; i < rays; i++) {
        ray r = {v3(14 * rng_uniform(&g) - 2, 14 * rng_uniform(&g) - 2, 14 * rng_uniform(&g) - 2),
                 random_direction(&g)};
        double t_max = i % 2 ? INFINITY : 15 * rng_uniform(&g);
        hit a, b;
        int found_a = scene_intersect(&s, r, t_max, &a);
        int found_b = scene_intersect_brute_force(&s, r, t_max, &b);
        hit c; /* linear search: the leaf pairs' triangles, then the spheres two by two (SIMD) */
        s.bvh.linear = 1;
        int found_c = scene_intersect(&s, r, t_max, &c);
        s.bvh.linear = 0;
        hits += found_b;
        int same = found_a == found_b && found_c == found_b;
        if (same && found_c)
            same = c.primitive == b.primitive && c.t == b.t;
        if (same && found_a)
            same = a.primitive == b.primitive && a.t == b.t && a.surface == b.surface && a.normal.x == b.normal.x;
        if (same && found_a)
            same = a.t > 0 && a.t < t_max;
        if (!same && mismatches++ == 0)
            CHECK(0, "ray %d: bvh %d (t %g, prim %d), brute force %d (t %g, prim %d)", i, found_a, found_a ? a.t : 0,
                  found_a ? a.primitive : -1, found_b, found_b ? b.t : 0, found_b ? b.primitive : -1);
        /* The two-lane tests give the one-at-a-time tests' t to the bit (intersect_triangle and
         * intersect_sphere): the lanes do the same operations in the same order.  intersect_triangle's edge
         * tolerance is the triangle's own, so near an edge it may miss where the scene's test hits. */
        if (found_a) {
            const triangle *tri = a.primitive < s.triangle_count ? &s.triangles[a.primitive] : NULL;
            const surface *sphere = tri ? NULL : &s.surfaces[s.sphere_surfaces[a.primitive - s.triangle_count]];
            double alone = tri ? intersect_triangle(tri, r) : intersect_sphere(sphere->center, sphere->radius, r);
            lane_checked += isfinite(alone);
            if (isfinite(alone) && alone != a.t && lane_mismatches++ == 0)
                CHECK(0, "ray %d: primitive %d at t %.17g in the tree, %.17g alone", i, a.primitive, a.t, alone);
        }
    }
    CHECK(mismatches == 0, "%d of %d rays differ", mismatches, rays);
    CHECK(lane_mismatches == 0 && lane_checked > hits * 9 / 10, "%d of %d hits differ from the one-at-a-time test",
          lane_mismatches, lane_checked);
    CHECK(hits > rays / 4 && hits < rays, "only %d hits: the test scene is too sparse", hits);

    /* Occlusion between random points agrees with the nearest hit, away
     * from the epsilon bands at both ends. */
    int disagreements = 0, blocked = 0, checked = 0;
    for (int i = 0; i < 20000; i++) {
        vec3 a = v3(12 * rng_uniform(&g) - 1, 12 * rng_uniform(&g) - 1, 12 * rng_uniform(&g) - 1);
        vec3 b = v3(12 * rng_uniform(&g) - 1, 12 * rng_uniform(&g) - 1, 12 * rng_uniform(&g) - 1);
        vec3 d = v3_sub(b, a);
        double band = 3 * s.epsilon / v3_length(d);
        hit h;
        int found = scene_intersect_brute_force(&s, (ray){a, d}, 1.0, &h);
        if (found && (h.t < band || h.t > 1 - band))
            continue; /* ambiguous: at an end */
        checked++;
        blocked += found;
        if (scene_occluded(&s, a, b) != found)
            disagreements++;
        s.bvh.linear = 1;
        if (scene_occluded(&s, a, b) != found)
            disagreements++;
        s.bvh.linear = 0;
    }
    CHECK(disagreements == 0,
          "occluded (by the tree or linear search) disagrees with intersect %d times on %d segments", disagreements,
          checked);
    CHECK(blocked > checked / 10 && blocked < checked, "%d of %d segments blocked", blocked, checked);
    scene_free(&s);
}

static void test_occlusion_between_surfaces(void)
{
    scene s;
    char err[512] = "";
    int status = load_text("cornell.scene", CORNELL, &s, err, sizeof err);
    CHECK(status == 0, "load failed: %.300s", err);
    if (status)
        return;
    vec3 light_center = v3(278, 548.7, 279.5);
    /* Both ends on surfaces: the back corner of the floor by the green wall
     * sees the light; the front corner does not (the short block is between). */
    CHECK(!scene_occluded(&s, v3(20, 0, 540), light_center), "floor corner to light");
    CHECK(!scene_occluded(&s, light_center, v3(20, 0, 540)), "light to floor corner (symmetry)");
    CHECK(scene_occluded(&s, v3(50, 0, 50), light_center), "front floor corner behind the short block");
    /* Under the tall block (top at y = 330, around (370, 350)). */
    CHECK(scene_occluded(&s, v3(370, 0, 350), light_center), "floor under the tall block");
    /* On the top of the short block, looking up: visible. */
    CHECK(!scene_occluded(&s, v3(185, 165, 170), light_center), "short block top to light");
    /* Through the short block from one side face to the other. */
    CHECK(scene_occluded(&s, v3(185, 80, 40), v3(185, 80, 300)), "through the short block");
    /* Offset origin: moves to the side the direction points to. */
    vec3 p = scene_offset_origin(&s, v3(100, 0, 100), v3(0, 1, 0), v3(0.3, 0.9, 0.1));
    CHECK(p.y == s.epsilon && p.x == 100, "offset up: y = %g", p.y);
    p = scene_offset_origin(&s, v3(100, 0, 100), v3(0, 1, 0), v3(0.3, -0.9, 0.1));
    CHECK(p.y == -s.epsilon, "offset down: y = %g", p.y);
    /* A ray leaving the floor from the offset origin does not hit the floor. */
    hit h;
    vec3 up = v3_normalize(v3(0.01, 1, 0.02));
    CHECK(scene_intersect(&s, (ray){scene_offset_origin(&s, v3(500, 0, 100), v3(0, 1, 0), up), up}, INFINITY, &h),
          "ray up from the floor escapes");
    CHECK(h.surface == scene_find_surface(&s, "ceiling"), "ray up from the floor hits surface %d", h.surface);
    scene_free(&s);
}

/* ------------------------------------------------------ sampling and camera */

static void test_surface_sampling(void)
{
    const char text[] = "camera eye 0 0 -5 look 0 0 0 up 0 1 0 fov 40\n"
                        "material white diffuse 0.5 0.5 0.5\n"
                        "quad q white  0 0 0  3 0 0  3 1 0  0 2 0\n"
                        "sphere ball white 10 0 0 2\n";
    scene s;
    char err[512] = "";
    int status = load_text("sampling.scene", text, &s, err, sizeof err);
    CHECK(status == 0, "load failed: %.300s", err);
    if (status)
        return;
    /* Triangles (v0 v1 v2) of area 1.5 and (v0 v2 v3) of area 3. */
    int quad = scene_find_surface(&s, "q"), ball = scene_find_surface(&s, "ball");
    CHECK_NEAR(s.surfaces[quad].area, 4.5, 1e-15, "quad area");
    rng g = rng_for(5, 0, 0);
    const int n = 100000;
    int in_first = 0;
    vec3 sphere_mean = v3(0, 0, 0);
    for (int i = 0; i < n; i++) {
        vec3 p, normal;
        surface_sample_point(&s, quad, rng_uniform(&g), rng_uniform(&g), rng_uniform(&g), &p, &normal);
        if (p.y < p.x / 3.0)
            in_first++;
        if (!(p.z == 0 && p.x >= 0 && p.x <= 3 && p.y >= 0 && p.y <= 2 - p.x / 3.0 + 1e-12) || normal.z != 1) {
            CHECK(0, "sample %d (%g %g %g) off the quad", i, p.x, p.y, p.z);
            break;
        }
        surface_sample_point(&s, ball, rng_uniform(&g), rng_uniform(&g), rng_uniform(&g), &p, &normal);
        vec3 from_center = v3_sub(p, v3(10, 0, 0));
        if (fabs(v3_length(from_center) - 2) > 1e-12 || v3_length(v3_sub(v3_scale(from_center, 0.5), normal)) > 1e-12) {
            CHECK(0, "sphere sample %d off the sphere or wrong normal", i);
            break;
        }
        sphere_mean = v3_add(sphere_mean, v3_scale(from_center, 1.0 / n));
    }
    /* Binomial: p = 1/3, sigma = sqrt(p (1 - p) / n) = 0.0015; allow 5 sigma. */
    CHECK_NEAR((double)in_first / n, 1.0 / 3.0, 5 * sqrt(2.0 / 9.0 / n), "fraction in the smaller triangle");
    /* Each coordinate of a uniform point on a sphere of radius 2 has variance 4/3. */
    CHECK(v3_length(sphere_mean) < 5 * sqrt(4.0 / 3.0 / n) * sqrt(3.0), "sphere samples biased: mean offset %g",
          v3_length(sphere_mean));
    /* u3 at the ends of [0, 1) stays inside the surface. */
    vec3 p, normal;
    surface_sample_point(&s, quad, 0.5, 0.5, 0.0, &p, &normal);
    CHECK(p.y <= p.x / 3.0 + 1e-12, "u3 = 0 picks the first triangle");
    surface_sample_point(&s, quad, 0.5, 0.5, 0.9999999999, &p, &normal);
    CHECK(p.y >= p.x / 3.0 - 1e-12, "u3 near 1 picks the last triangle");
    scene_free(&s);
}

/* A mesh's triangle is picked in proportion to its area: the frequencies
 * match the area fractions, and every u3 picks the triangle that the running
 * sum of areas picks (the first whose sum exceeds u3 * area, the last if
 * none does). */
static void test_mesh_sampling_by_area(void)
{
    /* Six right triangles of areas 1, 2, 3, 4, 0.5, 5.5 (legs 2 and
     * area), triangle k in x in [10 k, 10 k + 2]. */
    static const double areas[] = {1, 2, 3, 4, 0.5, 5.5};
    enum { TRIANGLES = sizeof areas / sizeof areas[0] };
    char obj[1024] = "";
    for (int k = 0; k < TRIANGLES; k++) {
        char line[128];
        snprintf(line, sizeof line, "v %d 0 0\nv %d 0 0\nv %d %.17g 0\nf %d %d %d\n", 10 * k, 10 * k + 2, 10 * k,
                 areas[k], 3 * k + 1, 3 * k + 2, 3 * k + 3);
        strncat(obj, line, sizeof obj - strlen(obj) - 1);
    }
    CHECK(write_temp("unequal.obj", obj) != NULL, "cannot write unequal.obj");
    const char text[] = "camera eye 0 0 -5 look 0 0 0 up 0 1 0 fov 40\n"
                        "material white diffuse 0.5 0.5 0.5\n"
                        "mesh m white unequal.obj\n";
    scene s;
    char err[512] = "";
    int status = load_text("unequal.scene", text, &s, err, sizeof err);
    char obj_path[512];
    snprintf(obj_path, sizeof obj_path, "%s/unequal.obj", temp_dir);
    unlink(obj_path);
    CHECK(status == 0, "load failed: %.300s", err);
    if (status)
        return;
    int mesh = scene_find_surface(&s, "m");
    const surface *surf = &s.surfaces[mesh];
    CHECK(surf->triangle_count == TRIANGLES, "triangles %d", surf->triangle_count);
    CHECK_NEAR(surf->area, 16.0, 1e-12, "mesh area");
    if (surf->triangle_count != TRIANGLES) {
        scene_free(&s);
        return;
    }

    /* Frequencies: binomial, 5 sigma each. */
    rng g = rng_for(11, 0, 0);
    const int n = 200000;
    int picked[TRIANGLES] = {0};
    for (int i = 0; i < n; i++) {
        double u1 = rng_uniform(&g);
        double u2 = rng_uniform(&g);
        double u3 = rng_uniform(&g);
        vec3 p, normal;
        surface_sample_point(&s, mesh, u1, u2, u3, &p, &normal);
        int k = (int)floor(p.x / 10.0);
        if (k < 0 || k >= TRIANGLES || p.x > 10 * k + 2 + 1e-12 || p.y < -1e-12 || p.y > areas[k] + 1e-12) {
            CHECK(0, "sample %d (%g %g %g) off the mesh", i, p.x, p.y, p.z);
            break;
        }
        picked[k]++;
    }
    for (int k = 0; k < TRIANGLES; k++) {
        double expected = areas[k] / 16.0;
        char what[64];
        snprintf(what, sizeof what, "fraction of samples in triangle %d", k);
        CHECK_NEAR((double)picked[k] / n, expected, 5 * sqrt(expected * (1 - expected) / n), what);
    }

    /* The mapping u3 -> triangle: a linear scan of the running sums, on a
     * fine grid of u3 and just around each boundary. */
    for (int j = 0; j <= 4000; j++) {
        double u3[3] = {j / 4000.0, 0, 0};
        int tries = 1;
        if (j < TRIANGLES) {
            double boundary = s.triangle_area_cdf[surf->first_triangle + j] / surf->area;
            u3[0] = nextafter(boundary, 0.0);
            u3[1] = boundary;
            u3[2] = nextafter(boundary, 1.0);
            tries = 3;
        }
        for (int t = 0; t < tries; t++) {
            double u = u3[t] < 1.0 ? u3[t] : nextafter(1.0, 0.0);
            double target = u * surf->area, cumulative = 0.0;
            int expected = TRIANGLES - 1;
            for (int k = 0; k < TRIANGLES - 1; k++) {
                cumulative += s.triangles[surf->first_triangle + k].area;
                if (target < cumulative) {
                    expected = k;
                    break;
                }
            }
            vec3 p, normal;
            surface_sample_point(&s, mesh, 0.25, 0.25, u, &p, &normal);
            int k = (int)floor(p.x / 10.0);
            if (k != expected) {
                CHECK(0, "u3 = %.17g picks triangle %d, the running sum picks %d", u, k, expected);
                j = 4001;
                break;
            }
        }
    }
    scene_free(&s);
}

static void test_camera_ray(void)
{
    camera c = {.eye = v3(278, 273, -800), .look = v3(278, 273, 0), .up = v3(0, 1, 0), .fov_degrees = 39.3076};
    ray center = camera_ray(&c, 512, 512, 256, 256);
    CHECK(center.origin.x == 278 && center.origin.z == -800, "ray starts at the eye");
    CHECK_NEAR(center.direction.z, 1, 1e-15, "centre ray along +z");
    CHECK_NEAR(center.direction.x, 0, 1e-15, "centre ray x");
    double half_fov = 0.5 * 39.3076 * M_PI / 180.0;
    /* Left edge of the image: toward +x (the red wall, x = 550, is on the left). */
    ray left = camera_ray(&c, 512, 512, 0, 256);
    CHECK(left.direction.x > 0, "left edge points toward -x (%g)", left.direction.x);
    CHECK_NEAR(atan2(left.direction.x, left.direction.z), half_fov, 1e-12, "horizontal half angle (square image)");
    /* Top edge: up; image y grows downward. */
    ray top = camera_ray(&c, 512, 512, 256, 0);
    CHECK_NEAR(atan2(top.direction.y, top.direction.z), half_fov, 1e-12, "vertical half angle");
    ray bottom = camera_ray(&c, 512, 512, 256, 512);
    CHECK(bottom.direction.y < 0, "bottom edge points down");
    /* fov is vertical: a wide image keeps the vertical angle. */
    ray wide_top = camera_ray(&c, 1024, 512, 512, 0);
    CHECK_NEAR(atan2(wide_top.direction.y, wide_top.direction.z), half_fov, 1e-12, "vertical fov on a wide image");
    ray wide_left = camera_ray(&c, 1024, 512, 0, 256);
    CHECK_NEAR(wide_left.direction.x / wide_left.direction.z, 2 * tan(half_fov), 1e-12, "horizontal extent doubles");
    CHECK_NEAR(v3_length(wide_left.direction), 1, 1e-15, "unit direction");
}

int main(void)
{
    if (mkdtemp(temp_dir) == NULL) {
        perror("mkdtemp");
        return 1;
    }
    RUN_TEST(test_triangle_hit_and_miss);
    RUN_TEST(test_triangle_edges_and_grazing);
    RUN_TEST(test_sphere_basic);
    RUN_TEST(test_sphere_huge_radius);
    RUN_TEST(test_parse_cornell);
    RUN_TEST(test_parse_syntax_variants);
    RUN_TEST(test_obj_meshes);
    RUN_TEST(test_bad_corpus);
    RUN_TEST(test_error_messages);
    RUN_TEST(test_bvh_matches_brute_force);
    RUN_TEST(test_linear_search_of_small_scenes);
    RUN_TEST(test_equal_hits_go_to_the_lowest_index);
    RUN_TEST(test_occlusion_between_surfaces);
    RUN_TEST(test_surface_sampling);
    RUN_TEST(test_mesh_sampling_by_area);
    RUN_TEST(test_camera_ray);
    rmdir(temp_dir);
    return CHECK_EXIT_STATUS();
}
