"""The caustic region of scenes/cornell-spheres.scene: the pixels that see the floor within
CAUSTIC_RADIUS of the point where the glass ball focuses the light; and the SDS region of
scenes/sds.scene: the pixels that see the room only in the mirror ball or through the glass ball
(sds_region: where the paths L S .. D S .. E are).

Geometry, not a threshold on a noisy reference (which would pick the pixels whose noise
happens to be high): the ball is a lens, so light from the light's centre through the
ball's centre continues to the floor at the focus; a pixel is in the region when the ray
through its centre hits the floor (y = 0) within CAUSTIC_RADIUS of the focus without
hitting the ball first.  The scene file gives the camera, the ball and the light.
Standard library only (used by tradeoff.py and bench/bench_05_photonmap.py).
"""
import hashlib
import json
import math
import os
import tempfile

CAUSTIC_RADIUS = 80.0  # mm: the bright core of the caustic and its falloff (the ball's radius is 100)


def _scene_numbers(path, ball_name="glass_ball"):
    camera = ball = light = None
    with open(path) as f:
        for line in f:
            w = line.split("#", 1)[0].split()
            if not w:
                continue
            if w[0] == "camera":
                camera = [float(v) for v in (w[2:5] + w[6:9] + w[10:13] + [w[14]])]
            elif w[0] == "sphere" and w[1] == ball_name:
                ball = [float(v) for v in w[3:7]]
            elif w[0] == "quad" and w[1] == "light":
                v = [float(x) for x in w[3:15]]
                light = [sum(v[k::3]) / 4 for k in range(3)]
    return camera, ball, light


def _sub(a, b): return [a[i] - b[i] for i in range(3)]
def _dot(a, b): return sum(a[i] * b[i] for i in range(3))
def _cross(a, b): return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
def _unit(a):
    n = math.sqrt(_dot(a, a))
    return [x / n for x in a]


def focus(scene_path):
    _, ball, light = _scene_numbers(scene_path)
    c, r = ball[:3], ball[3]
    t = c[1] / (light[1] - c[1])
    return [c[0] + (c[0] - light[0]) * t, 0.0, c[2] + (c[2] - light[2]) * t]


def caustic_region(width, height, scene_path=None, radius=CAUSTIC_RADIUS):
    """[(x, y)] pixel coordinates (top row 0) of the caustic region."""
    scene_path = scene_path or os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                            "scenes", "cornell-spheres.scene")
    camera, ball, _ = _scene_numbers(scene_path)
    eye, look, up, fov = camera[0:3], camera[3:6], camera[6:9], camera[9]
    forward = _unit(_sub(look, eye))
    right = _unit(_cross(forward, up))
    true_up = _cross(right, forward)
    half = math.tan(math.radians(fov) / 2)
    f = focus(scene_path)
    centre, r = ball[:3], ball[3]
    region = []
    for py in range(height):
        for px in range(width):
            sx = (2 * (px + 0.5) / width - 1) * half * width / height
            sy = (1 - 2 * (py + 0.5) / height) * half
            d = _unit([forward[i] + sx * right[i] + sy * true_up[i] for i in range(3)])
            if d[1] >= 0:
                continue
            t_floor = -eye[1] / d[1]
            oc = _sub(eye, centre)
            b = _dot(oc, d)
            disc = b * b - (_dot(oc, oc) - r * r)
            if disc > 0 and -b - math.sqrt(disc) < t_floor:
                continue  # the ball is in front of the floor here
            p = [eye[i] + t_floor * d[i] for i in range(3)]
            if (p[0] - f[0]) ** 2 + (p[2] - f[2]) ** 2 <= radius * radius:
                region.append((px, py))
    return region


def _sphere_hit(origin, d, sphere):
    """Distance along unit d to the first crossing of the sphere after origin, or None."""
    oc = _sub(origin, sphere[:3])
    b = _dot(oc, d)
    disc = b * b - (_dot(oc, oc) - sphere[3] * sphere[3])
    if disc <= 0:
        return None
    for t in (-b - math.sqrt(disc), -b + math.sqrt(disc)):
        if t > 1e-6:
            return t
    return None


def sds_region(width, height, scene_path=None):
    """[(x, y)] pixel coordinates (top row 0) of the SDS region of sds.scene: the pixels whose centre
    ray hits the mirror ball or the glass ball.  They see the room only by specular reflection or
    refraction, and the light that reaches what they see through the glass or off the mirror (the
    glass ball's caustic on the floor, the light the mirror ball throws on the walls) makes paths
    L S .. D S .. E: no join renders them, only merging, or an eye path that happens to hit the
    13 mm light.  (The caustic itself, seen in the mirror, covers about 4 pixels of 128 x 128:
    too few to measure alone.)"""
    scene_path = scene_path or os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                            "scenes", "sds.scene")
    camera, glass, _ = _scene_numbers(scene_path)
    mirror = _scene_numbers(scene_path, "mirror_ball")[1]
    eye, look, up, fov = camera[0:3], camera[3:6], camera[6:9], camera[9]
    forward = _unit(_sub(look, eye))
    right = _unit(_cross(forward, up))
    true_up = _cross(right, forward)
    half = math.tan(math.radians(fov) / 2)
    region = []
    for py in range(height):
        for px in range(width):
            sx = (2 * (px + 0.5) / width - 1) * half * width / height
            sy = (1 - 2 * (py + 0.5) / height) * half
            d = _unit([forward[i] + sx * right[i] + sy * true_up[i] for i in range(3)])
            if _sphere_hit(eye, d, mirror) is not None or _sphere_hit(eye, d, glass) is not None:
                region.append((px, py))
    return region


SDS_CAUSTIC_RADIUS = 150.0  # mm around the focus, seen in the mirror: the caustic (about 30 mm) and its halo
LIGHT_IMAGE_MARGIN = 1      # pixels around the light's image in the mirror left out too (its jittered edge)
REGION_VERSION = 1          # part of sds_mirror_regions' cache key: raise it when the rule changes


def _light_rect(path):
    """(y, x_min, x_max, z_min, z_max) of the scene's light quad (horizontal, facing down)."""
    with open(path) as f:
        for line in f:
            w = line.split("#", 1)[0].split()
            if w and w[0] == "quad" and w[1] == "light":
                v = [float(x) for x in w[3:15]]
                return v[1], min(v[0::3]), max(v[0::3]), min(v[2::3]), max(v[2::3])
    return None


def _refract(d, n, eta):
    """d refracted at a surface of normal n (against d) with eta = n_from / n_to, or None (total reflection)."""
    c = -_dot(d, n)
    k = 1 - eta * eta * (1 - c * c)
    return None if k < 0 else _unit([eta * d[i] + (eta * c - math.sqrt(k)) * n[i] for i in range(3)])


def _sees_light(origin, d, mirror, glass, rect, depth=6):
    """Whether the ray reaches the light quad rect = (y, x0, x1, z0, z1) through mirror and glass alone (E S.. L),
    following both the reflected and the refracted ray at the glass (index 1.5), up to depth specular bounces."""
    hits = [(t, ball) for ball in (mirror, glass) for t in [_sphere_hit(origin, d, ball)] if t is not None]
    t_ball, ball = min(hits) if hits else (math.inf, None)
    if d[1] > 0:
        t = (rect[0] - origin[1]) / d[1]
        q = [origin[i] + t * d[i] for i in range(3)]
        if t < t_ball and rect[1] <= q[0] <= rect[2] and rect[3] <= q[2] <= rect[4]:
            return True
    if ball is None or depth == 0:
        return False
    p = [origin[i] + t_ball * d[i] for i in range(3)]
    n = _unit(_sub(p, ball[:3]))
    entering = _dot(d, n) < 0
    n = n if entering else [-x for x in n]
    reflected = [d[i] - 2 * _dot(d, n) * n[i] for i in range(3)]
    if _sees_light(p, reflected, mirror, glass, rect, depth - 1):
        return True
    if ball is glass:
        refracted = _refract(d, n, 1 / 1.5 if entering else 1.5)
        return refracted is not None and _sees_light(p, refracted, mirror, glass, rect, depth - 1)
    return False


def _light_image_pixel(eye, forward, right, true_up, half, width, height, mirror, light):
    """The pixel (x, y) that sees the light's centre in the mirror ball: the point P on the ball whose normal
    halves the angle between the eye and the light (the law of reflection), found by iteration, projected."""
    c, r = mirror[:3], mirror[3]
    n = _unit(_sub(eye, c))
    for _ in range(100):
        p = [c[k] + r * n[k] for k in range(3)]
        n = _unit([a + b for a, b in zip(_unit(_sub(eye, p)), _unit(_sub(light, p)))])
    d = _sub([c[k] + r * n[k] for k in range(3)], eye)
    depth = _dot(d, forward)
    sx, sy = _dot(d, right) / depth, _dot(d, true_up) / depth
    return (int((sx / (half * width / height) + 1) / 2 * width), int((1 - sy / half) / 2 * height))


def sds_mirror_regions(width, height, scene_path=None, sub=4, light_sub=None):
    """sds_mirror_regions_traced's answer, kept in a file of the temporary directory under the hash of the scene
    and the arguments (the fine rays that find the light's images take seconds in Python)."""
    scene_path = scene_path or os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                            "scenes", "sds.scene")
    with open(scene_path, "rb") as f:
        key = hashlib.sha1(f.read() + repr((width, height, sub, light_sub, REGION_VERSION)).encode()).hexdigest()
    path = os.path.join(tempfile.gettempdir(), f"sds-regions-{key}.json")
    try:
        with open(path) as f:
            return {k: [tuple(p) for p in v] for k, v in json.load(f).items()}
    except (OSError, ValueError):
        pass
    found = sds_mirror_regions_traced(width, height, scene_path, sub, light_sub)
    with open(path + f".{os.getpid()}", "w") as f:
        json.dump(found, f)
    os.replace(path + f".{os.getpid()}", path)
    return found


def sds_mirror_regions_traced(width, height, scene_path=None, sub=4, light_sub=None):
    """The SDS region of sds.scene as seen in the mirror ball, by geometry (sub x sub rays per pixel, no
    image):
      "mirror":  the pixels every one of whose rays hits the mirror ball (no pixel on the ball's rim),
                 less the light's image: a pixel any of whose reflected rays hits the light quad, and its
                 LIGHT_IMAGE_MARGIN neighbours: every image of the light the mirror shows, directly or
                 through the glass ball (paths E S .. S L, _sees_light: only an eye path that hits the
                 13 mm light renders them, rare and huge samples: the noisiest pixels of the image, and
                 no caustic);
      "caustic": those of them any of whose reflected rays reaches the floor, past the glass ball, within
                 SDS_CAUSTIC_RADIUS of the glass ball's focus: the caustic L S S D S E itself;
      "light":   the light's images left out (with their margin; light_sub x light_sub rays a pixel look
                 for them: at 128 x 128 they are smaller than a pixel).
    Each a list of (x, y), top row 0."""
    scene_path = scene_path or os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                            "scenes", "sds.scene")
    light_sub = light_sub or max(16, 2048 // width)  # rays 1/16 of a pixel of 128 x 128 apart at any size
    camera, glass, _ = _scene_numbers(scene_path)
    mirror = _scene_numbers(scene_path, "mirror_ball")[1]
    ly, x0, x1, z0, z1 = _light_rect(scene_path)
    f = focus(scene_path)
    eye, look, up, fov = camera[0:3], camera[3:6], camera[6:9], camera[9]
    forward = _unit(_sub(look, eye))
    right = _unit(_cross(forward, up))
    true_up = _cross(right, forward)
    half = math.tan(math.radians(fov) / 2)
    inside, light, caustic = set(), set(), set()

    def _pixel_rays(px, py, n):
        """(direction, distance to the mirror ball or None) of n x n rays through pixel (px, py)."""
        out = []
        for j in range(n):
            for i in range(n):
                sx = (2 * (px + (i + 0.5) / n) / width - 1) * half * width / height
                sy = (1 - 2 * (py + (j + 0.5) / n) / height) * half
                d = _unit([forward[k] + sx * right[k] + sy * true_up[k] for k in range(3)])
                out.append((d, _sphere_hit(eye, d, mirror)))
        return out
    for py in range(height):
        for px in range(width):
            hits = _pixel_rays(px, py, sub)
            if all(t is None for _, t in hits):
                continue
            if all(t is not None for _, t in hits):
                inside.add((px, py))
            for d, t in hits + ([] if light_sub == sub else _pixel_rays(px, py, light_sub)):
                if t is None:
                    continue  # a ray past the ball's rim
                p = [eye[k] + t * d[k] for k in range(3)]
                n = _unit(_sub(p, mirror[:3]))
                r = [d[k] - 2 * _dot(d, n) * n[k] for k in range(3)]
                if _sees_light(p, r, mirror, glass, (ly, x0, x1, z0, z1)):
                    light.add((px, py))
                elif r[1] < 0:
                    t_floor = -p[1] / r[1]
                    t_glass = _sphere_hit(p, r, glass)
                    q = [p[k] + t_floor * r[k] for k in range(3)]
                    if (t_glass is None or t_glass > t_floor) and \
                            (q[0] - f[0]) ** 2 + (q[2] - f[2]) ** 2 <= SDS_CAUSTIC_RADIUS ** 2:
                        caustic.add((px, py))
    light.add(_light_image_pixel(eye, forward, right, true_up, half, width, height, mirror,
                                 [(x0 + x1) / 2, ly, (z0 + z1) / 2]))
    near = {(x + dx, y + dy) for x, y in light for dx in range(-LIGHT_IMAGE_MARGIN, LIGHT_IMAGE_MARGIN + 1)
            for dy in range(-LIGHT_IMAGE_MARGIN, LIGHT_IMAGE_MARGIN + 1)}
    keep = sorted(inside - near, key=lambda p: (p[1], p[0]))
    return {"mirror": keep, "caustic": [p for p in keep if p in caustic],
            "light": sorted(near & inside, key=lambda p: (p[1], p[0]))}


if __name__ == "__main__":
    reg = caustic_region(32, 32)
    print(len(reg), reg)
    print(len(sds_region(32, 32)), "pixels of the SDS region of sds.scene at 32 x 32")
    for size in (64, 128):
        print(size, {k: len(v) for k, v in sds_mirror_regions(size, size).items()})
