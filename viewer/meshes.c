/* meshes.c — the 3D panels: the scene as a triangle mesh with its lights for
 * the GLSL raster, the camera's matrix, and rendering a 3D panel. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "viewer.h"

/* ---- meshes --------------------------------------------------------------------------------- */

static void put_vertex(float *v, vec3 position, vec3 normal, const material *m)
{
    vec3 kd = m->albedo, ks = v3_splat(0.0), emission = v3_splat(0.0);
    double exponent = 1.0;
    if (m->kind == MATERIAL_PHONG)
        ks = m->specular, exponent = m->exponent;
    if (m->kind == MATERIAL_MIRROR || m->kind == MATERIAL_GLASS)
        kd = m->specular; /* chapter 1 shades them as diffuse surfaces of their colour */
    if (m->kind == MATERIAL_EMITTER)
        emission = m->emission;
    const float f[MESH_FLOATS] = {(float)position.x, (float)position.y, (float)position.z, (float)normal.x,
                                  (float)normal.y,   (float)normal.z,   (float)kd.x,       (float)kd.y,
                                  (float)kd.z,       (float)ks.x,       (float)ks.y,       (float)ks.z,
                                  (float)exponent,   (float)emission.x, (float)emission.y, (float)emission.z};
    memcpy(v, f, sizeof f);
}

enum { SPHERE_RINGS = 48, SPHERE_SEGMENTS = 96 };

static vec3 sphere_point(vec3 c, double r, int ring, int segment)
{
    double theta = M_PI * ring / SPHERE_RINGS, phi = 2.0 * M_PI * segment / SPHERE_SEGMENTS;
    return v3_add(c, v3_scale(v3(sin(theta) * cos(phi), cos(theta), sin(theta) * sin(phi)), r));
}

/* The raster's lights: the point lights as they are (R1); an emitting surface
 * becomes one point at its centre with the intensity a Lambertian emitter sends
 * (L A cos theta_y for a planar one, L pi r^2 for a sphere): the way a GPU
 * renderer without area lights approximates them. */
static void scene_light_uniforms(const scene *s, mesh_uniforms *u, vec3 ambient)
{
    memset(u, 0, sizeof *u);
    u->ambient[0] = (float)ambient.x, u->ambient[1] = (float)ambient.y, u->ambient[2] = (float)ambient.z;
    for (int l = 0; l < s->light_count && u->light_count < MAX_LIGHTS; l++) {
        int k = u->light_count++;
        const point_light *pl = &s->lights[l];
        u->light_position[k][0] = (float)pl->position.x, u->light_position[k][1] = (float)pl->position.y;
        u->light_position[k][2] = (float)pl->position.z;
        u->light_intensity[k][0] = (float)pl->intensity.x, u->light_intensity[k][1] = (float)pl->intensity.y;
        u->light_intensity[k][2] = (float)pl->intensity.z;
    }
    for (int e = 0; e < s->emitter_count && u->light_count < MAX_LIGHTS; e++) {
        const surface *sf = &s->surfaces[s->emitters[e]];
        vec3 radiance = s->materials[sf->material].emission, centre = v3_splat(0.0), normal = v3(0, -1, 0);
        vec3 intensity;
        int k = u->light_count++;
        if (sf->kind == SURFACE_SPHERE) {
            centre = sf->center;
            intensity = v3_scale(radiance, M_PI * sf->radius * sf->radius);
        } else {
            double area = 0.0;
            for (int t = sf->first_triangle; t < sf->first_triangle + sf->triangle_count; t++) {
                const triangle *tri = &s->triangles[t];
                vec3 c = v3_add(tri->p0, v3_scale(v3_add(tri->e1, tri->e2), 1.0 / 3.0));
                centre = v3_add(centre, v3_scale(c, tri->area));
                area += tri->area;
                normal = tri->normal;
            }
            centre = v3_scale(centre, 1.0 / area);
            /* a hair in front of the surface, so its own plane is not lit edge-on */
            centre = v3_add(centre, v3_scale(normal, 1e-6 * v3_length(v3_sub(s->bounds.hi, s->bounds.lo))));
            intensity = v3_scale(radiance, area);
            u->light_cosine[k] = 1;
        }
        u->light_position[k][0] = (float)centre.x, u->light_position[k][1] = (float)centre.y;
        u->light_position[k][2] = (float)centre.z;
        u->light_intensity[k][0] = (float)intensity.x, u->light_intensity[k][1] = (float)intensity.y;
        u->light_intensity[k][2] = (float)intensity.z;
        u->light_normal[k][0] = (float)normal.x, u->light_normal[k][1] = (float)normal.y;
        u->light_normal[k][2] = (float)normal.z;
    }
}

int scene_mesh(const scene *s, mesh *m, mesh_uniforms *u, vec3 ambient, char *err, size_t err_size)
{
    int vertices = 3 * s->triangle_count + 6 * SPHERE_RINGS * SPHERE_SEGMENTS * s->sphere_count;
    float *v = malloc((size_t)(vertices > 0 ? vertices : 1) * MESH_FLOATS * sizeof(float));
    if (!v) {
        snprintf(err, err_size, "%s:0: out of memory", s->path);
        return 2;
    }
    int n = 0;
    for (int t = 0; t < s->triangle_count; t++) {
        const triangle *tri = &s->triangles[t];
        const material *mat = &s->materials[s->surfaces[tri->surface].material];
        vec3 p[3] = {tri->p0, v3_add(tri->p0, tri->e1), v3_add(tri->p0, tri->e2)};
        for (int k = 0; k < 3; k++)
            put_vertex(v + MESH_FLOATS * n++, p[k], tri->normal, mat);
    }
    for (int i = 0; i < s->surface_count; i++) {
        const surface *sf = &s->surfaces[i];
        if (sf->kind != SURFACE_SPHERE)
            continue;
        const material *mat = &s->materials[sf->material];
        for (int r = 0; r < SPHERE_RINGS; r++)
            for (int g = 0; g < SPHERE_SEGMENTS; g++) {
                vec3 q[6] = {
                    sphere_point(sf->center, sf->radius, r, g),         sphere_point(sf->center, sf->radius, r + 1, g),
                    sphere_point(sf->center, sf->radius, r + 1, g + 1), sphere_point(sf->center, sf->radius, r, g),
                    sphere_point(sf->center, sf->radius, r + 1, g + 1), sphere_point(sf->center, sf->radius, r, g + 1)};
                for (int k = 0; k < 6; k++)
                    put_vertex(v + MESH_FLOATS * n++, q[k], v3_normalize(v3_sub(q[k], sf->center)), mat);
            }
    }
    mesh_upload(m, v, n);
    free(v);
    scene_light_uniforms(s, u, ambient);
    return 0;
}


/* ---- camera ------------------------------------------------------------------------------- */

/* Near and far planes fitted to the bounding box as seen from the eye:
 * far = the farthest corner, near = the distance to the box's nearest
 * point, at least far / 1000 (the eye inside the box).  A 24-bit depth
 * buffer resolves about z^2 / (near 2^24): for the Cornell box seen from
 * 800 mm (near ~ 800, far ~ 1400) a few microns, where the old near plane
 * at far x 1e-4 left 0.3 mm and the light, 0.1 mm below the ceiling,
 * came out as stripes of ceiling.  Both get 1 % of slack. */
static void depth_range(vec3 eye, vec3 lo, vec3 hi, double *near_plane, double *far_plane)
{
    vec3 nearest = v3_min(v3_max(eye, lo), hi);
    double far_sq = 0.0;
    for (int corner = 0; corner < 8; corner++) {
        vec3 c = v3(corner & 1 ? hi.x : lo.x, corner & 2 ? hi.y : lo.y, corner & 4 ? hi.z : lo.z);
        vec3 d = v3_sub(c, eye);
        far_sq = fmax(far_sq, v3_dot(d, d));
    }
    *far_plane = sqrt(far_sq) * 1.01 + 1e-9;
    *near_plane = fmax(v3_length(v3_sub(nearest, eye)) * 0.99, *far_plane * 1e-3);
}

/* Column-major view_projection: look-at, then a perspective projection
 * with the camera's vertical field of view, then y mirrored so that row 0
 * of the target is the top of the image (camera_ray's y grows downward).
 * Pixel centres then fall exactly where camera_ray() sends its rays. */
void camera_matrix(const camera *cam, int width, int height, vec3 lo, vec3 hi, float out[16])
{
    vec3 f = v3_normalize(v3_sub(cam->look, cam->eye));
    vec3 r = v3_normalize(v3_cross(f, cam->up));
    vec3 u = v3_cross(r, f);
    double near_plane, far_plane;
    depth_range(cam->eye, lo, hi, &near_plane, &far_plane);
    double t = tan(0.5 * cam->fov_degrees * M_PI / 180.0), aspect = (double)width / height;
    double view[4][4] = {{r.x, r.y, r.z, -v3_dot(r, cam->eye)},
                         {u.x, u.y, u.z, -v3_dot(u, cam->eye)},
                         {-f.x, -f.y, -f.z, v3_dot(f, cam->eye)},
                         {0, 0, 0, 1}};
    double projection[4][4] = {{1.0 / (t * aspect), 0, 0, 0},
                               {0, -1.0 / t, 0, 0}, /* mirrored y */
                               {0, 0, -(far_plane + near_plane) / (far_plane - near_plane),
                                -2.0 * far_plane * near_plane / (far_plane - near_plane)},
                               {0, 0, -1, 0}};
    for (int row = 0; row < 4; row++)
        for (int col = 0; col < 4; col++) {
            double sum = 0.0;
            for (int k = 0; k < 4; k++)
                sum += projection[row][k] * view[k][col];
            out[col * 4 + row] = (float)sum;
        }
}

void panel_render_3d(panel *p, const mesh_uniforms *u, const float background[3])
{
    mesh_draw(&p->mesh, &p->target, u, background);
    if (p->img.width != p->target.width || p->img.height != p->target.height) {
        image_free(&p->img);
        p->img = image_new(p->target.width, p->target.height);
    }
    if (p->img.pixels)
        target_read_rgb32f(&p->target, p->img.pixels);
    p->texture = p->target.colour;
    p->updates++;
}
