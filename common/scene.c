/* scene.c — the scene model: loading (the parser is scene_parse.c, the BVH
 * bvh.c), what is computed after parsing (areas, emitters, bounds, epsilon,
 * the area tables for sampling), surface sampling, lookup and the camera.
 */
#include "scene.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bvh.h"
#include "sampling.h"
#include "scene_parse.h"

/* ------------------------------------------------------------------------ */
/* After parsing                                                             */

/* Areas (and the per-triangle area tables), emitters, sphere list, bounds
 * and epsilon.  Returns 0, or -1 when out of memory. */
static int finish_scene(scene *s)
{
    s->triangle_area_cdf = malloc((size_t)(s->triangle_count ? s->triangle_count : 1) * sizeof *s->triangle_area_cdf);
    if (s->triangle_area_cdf == NULL)
        return -1;
    for (int i = 0; i < s->surface_count; i++) {
        surface *surf = &s->surfaces[i];
        if (surf->kind == SURFACE_SPHERE) {
            surf->area = 4.0 * M_PI * surf->radius * surf->radius;
            surf->cap_cos = -1.0; /* whole; emitter_cap may cut an emitting one */
            s->sphere_count++;
        } else {
            /* Summed in triangle order: the running sums are the table
             * surface_sample_point searches, and the last one is the area. */
            surf->area = 0.0;
            for (int t = surf->first_triangle; t < surf->first_triangle + surf->triangle_count; t++) {
                surf->area += s->triangles[t].area;
                s->triangle_area_cdf[t] = surf->area;
            }
        }
        if (s->materials[surf->material].kind == MATERIAL_EMITTER)
            s->emitter_count++;
    }
    s->sphere_surfaces = malloc((size_t)(s->sphere_count ? s->sphere_count : 1) * sizeof *s->sphere_surfaces);
    s->emitters = malloc((size_t)(s->emitter_count ? s->emitter_count : 1) * sizeof *s->emitters);
    if (s->sphere_surfaces == NULL || s->emitters == NULL)
        return -1;
    int spheres = 0, emitters = 0;
    for (int i = 0; i < s->surface_count; i++) {
        if (s->surfaces[i].kind == SURFACE_SPHERE)
            s->sphere_surfaces[spheres++] = i;
        if (s->materials[s->surfaces[i].material].kind == MATERIAL_EMITTER)
            s->emitters[emitters++] = i;
    }
    scene_settle_emitters(s);

    s->bounds = bvh_geometry_bounds(s);
    /* The offset described in scene.h: 1e-9 of the largest coordinate. */
    double largest = fmax(v3_max_component(v3_max(v3_neg(s->bounds.lo), s->bounds.hi)), 0.0);
    s->epsilon = 1e-9 * largest;
    /* Cannot happen for valid geometry (it has a nonzero size), but a zero
     * epsilon would silently bring self-intersection back. */
    if (!(s->epsilon > 0.0))
        s->epsilon = 1e-9 * fmax(v3_max_component(v3_sub(s->bounds.hi, s->bounds.lo)), 1.0);
    return 0;
}

/* Where an emitting sphere can shine.  A sphere T whose surface crosses the
 * emitting sphere S's splits S in two caps; an opaque T (anything but glass)
 * is a closed wall: light from the cap on T's far side from the camera meets
 * T's back, which reflects it back to that side, so it never reaches the
 * camera (smallpt's light, a sphere of radius 600 of which 0.27 pokes through
 * the ceiling sphere: only 2e-4 of its area is in the room).  Sampling a cap
 * that holds every point that can shine toward the camera is unbiased: the
 * points left out contribute nothing.  With several cuts, the live part is
 * the intersection of their caps; we keep the smallest cap, which contains it.
 * The camera's side: the point where its central ray starts (camera.near).
 * The planes of S's cut by T: with d = |c_T - c_S| and unit a = (c_T - c_S) / d,
 * the circle where the surfaces cross is at (y - c_S) . a = h,
 *   h = (d^2 + r_S^2 - r_T^2) / (2 d)   ((d - r_T)(d + r_T): no cancellation for r_T = 1e5),
 * and S's points beyond it are inside T; a cap of cos c has area 2 pi r_S^2 (1 - c). */
static void emitter_cap(scene *s, surface *emitter)
{
    vec3 forward = v3_normalize(v3_sub(s->camera.look, s->camera.eye));
    vec3 camera_at = v3_madd(s->camera.eye, forward, s->camera.near);
    double r_s = emitter->radius;
    for (int k = 0; k < s->sphere_count; k++) {
        const surface *t = &s->surfaces[s->sphere_surfaces[k]];
        vec3 axis = v3_sub(t->center, emitter->center);
        double d = v3_length(axis), r_t = t->radius;
        if (t == emitter || s->materials[t->material].kind == MATERIAL_GLASS || !(d > fabs(r_t - r_s)) ||
            !(d < r_t + r_s))
            continue; /* not a wall across the emitter */
        double h = ((d - r_t) * (d + r_t) + r_s * r_s) / (2.0 * d), cos_cut = fmin(fmax(h / r_s, -1.0), 1.0);
        bool camera_inside = v3_length(v3_sub(camera_at, t->center)) < r_t;
        vec3 toward = v3_scale(axis, (camera_inside ? 1.0 : -1.0) / d);
        double cap_cos = camera_inside ? cos_cut : -cos_cut; /* the cap on the camera's side */
        if (cap_cos > emitter->cap_cos) {
            emitter->cap_cos = cap_cos;
            emitter->cap_axis = toward;
        }
    }
    emitter->area = 2.0 * M_PI * r_s * r_s * (1.0 - emitter->cap_cos);
}

void scene_settle_emitters(scene *s)
{
    s->emitter_area = 0.0;
    for (int e = 0; e < s->emitter_count; e++) {
        surface *surf = &s->surfaces[s->emitters[e]];
        if (surf->kind == SURFACE_SPHERE) {
            surf->cap_cos = -1.0;
            surf->area = 4.0 * M_PI * surf->radius * surf->radius;
            emitter_cap(s, surf);
        }
        s->emitter_area += surf->area;
    }
}

/* ------------------------------------------------------------------------ */
/* Loading                                                                   */

int scene_load(const char *path, scene *out, char *err, size_t err_size)
{
    memset(out, 0, sizeof *out);
    if (err && err_size)
        err[0] = '\0';
    snprintf(out->path, sizeof out->path, "%s", path);
    out->width = 512;
    out->height = 512;
    out->background = v3_splat(0.0);

    int lines = 0;
    int status = scene_parse(path, out, err, err_size, &lines);
    if (status == 0 && (finish_scene(out) || bvh_build(out)))
        status = scene_parse_error(path, lines, err, err_size, "out of memory");
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
    free(s->triangle_area_cdf);
    bvh_free(&s->bvh);
    memset(s, 0, sizeof *s);
}

/* ------------------------------------------------------------------------ */
/* Sampling, lookup, camera                                                  */

void surface_sample_point(const scene *s, int surface_index, double u1, double u2, double u3, vec3 *point, vec3 *normal)
{
    const surface *surf = &s->surfaces[surface_index];
    if (surf->kind == SURFACE_SPHERE) { /* uniform on the sphere, or on its cap: cos uniform in [cap_cos, 1] */
        vec3 direction = surface_is_whole_sphere(surf) ? uniform_sample_sphere(u1, u2)
                                                       : onb_to_world(onb_from_normal(surf->cap_axis),
                                                                      uniform_sample_cone(u1, u2, surf->cap_cos));
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
    /* Pick a triangle with probability area / total area: the first one
     * whose running area sum exceeds u3 * area (the last if none does, as
     * rounding may leave target at the total), by binary search. */
    double target = u3 * surf->area;
    const double *cdf = s->triangle_area_cdf;
    int lo = surf->first_triangle, hi = surf->first_triangle + surf->triangle_count - 1;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (target < cdf[mid])
            hi = mid;
        else
            lo = mid + 1;
    }
    int chosen = lo;
    const triangle *t = &s->triangles[chosen];
    *point = uniform_sample_triangle(t->p0, v3_add(t->p0, t->e1), v3_add(t->p0, t->e2), u1, u2);
    *normal = t->normal;
}

double scene_diagonal(const scene *s)
{
    double diagonal = v3_length(v3_sub(s->bounds.hi, s->bounds.lo));
    camera_frame f = camera_frame_make(&s->camera, s->width, s->height);
    aabb seen = {v3_splat(INFINITY), v3_splat(-INFINITY)};
    enum { GRID = 32 }; /* camera rays through a 32 x 32 grid over the image */
    for (int i = 0; i < GRID * GRID; i++) {
        hit h;
        if (scene_intersect(
                s, camera_frame_ray(&f, (i % GRID + 0.5) * s->width / GRID, (i / GRID + 0.5) * s->height / GRID),
                INFINITY, &h)) {
            seen.lo = v3_min(seen.lo, h.point);
            seen.hi = v3_max(seen.hi, h.point);
        }
    }
    double seen_diagonal = v3_length(v3_sub(seen.hi, seen.lo));
    return seen_diagonal > 0.0 && seen_diagonal < 0.1 * diagonal ? seen_diagonal : diagonal;
}

int scene_find_surface(const scene *s, const char *name)
{
    for (int i = 0; i < s->surface_count; i++)
        if (strcmp(s->surfaces[i].name, name) == 0)
            return i;
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
        .near = c->near,
    };
}

ray camera_frame_ray(const camera_frame *f, double px, double py)
{
    /* Image x grows to the right, image y grows downward. */
    vec3 direction = v3_add(f->top_left, v3_add(v3_scale(f->step_x, px), v3_scale(f->step_y, py)));
    vec3 unit = v3_normalize(direction);
    return (ray){f->near > 0.0 ? v3_madd(f->eye, unit, f->near) : f->eye, unit};
}

ray camera_ray(const camera *c, int width, int height, double px, double py)
{
    camera_frame f = camera_frame_make(c, width, height);
    return camera_frame_ray(&f, px, py);
}
