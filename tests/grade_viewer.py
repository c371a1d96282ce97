"""Grading tests of the viewer (issue 6): build/viewer.

Truth comes from outside the viewer:
  * a compare panel must equal the input PFM tone-mapped by the formula of
    DESIGN.md / common/image.c (2^exposure, clamp, IEC 61966-2-1 sRGB curve,
    8 bits), recomputed here in Python, within 1/255;
  * the GLSL Blinn-Phong raster must agree with chapter 1's ray-cast image
    (another program: C, double precision, ray casting) away from silhouettes,
    which are found by a ray caster written here in Python;
  * the GLFW window (under Xvfb) must show what the headless backends write;
  * PLY radiance: a quad of known per-vertex radiance, checked pixel by pixel;
  * live mode: the chapter's progressive files must reach the viewer, and the
    children must be gone when it exits;
  * the window's input (keys, drag, wheel), driven by xdotool under Xvfb: the
    screenshot after exposure keys is the input tone-mapped at the documented
    step, a drag restarts the children with an eye orbited on the sphere about
    the look point (old children reaped, checked in /proc), the wheel dollies
    by the documented factor, Q / Esc exit 0 with no child left.
The layout the tests rely on is the documented one (build/viewer --help):
ceil(sqrt(n)) columns, a 34-pixel label band on top of each panel, the
image scaled to fit the rest, centred on a whole pixel.

Standard library only.  PNGs are decoded here (zlib + the five PNG filters).
"""
import math
import os
import shutil
import signal
import struct
import subprocess
import threading
import time
import zlib

import lib

LABEL_BAND = 34


# ---- helpers ---------------------------------------------------------------------------------

def viewer_env():
    env = dict(os.environ)
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    # The sanitizer build: Mesa, LLVM and X libraries are not instrumented and
    # keep caches until exit; their allocations are not the viewer's leaks.
    env["LSAN_OPTIONS"] = "suppressions=" + os.path.join(lib.ROOT, "viewer", "lsan.supp") + ":print_suppressions=0"
    return env


def run_viewer(ctx, *args, env=None, timeout=120):
    exe = os.path.join(lib.ROOT, ctx.build, "viewer")
    assert os.access(exe, os.X_OK), f"{exe} is not built (make {ctx.build}/viewer)"
    return subprocess.run([exe, *map(str, args)], cwd=lib.ROOT, capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL, env=env or viewer_env())


def ok(result, what):
    assert result.returncode == 0, f"{what}: exit {result.returncode}\nstdout: {result.stdout[-2000:]}\n" \
                                   f"stderr: {result.stderr[-3000:]}"


def read_png(path):
    """8-bit RGB / RGBA PNG -> (width, height, rows of bytes RGB)."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path}: not a PNG"
    pos, idat, width = 8, b"", None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert depth == 8 and colour in (2, 6) and interlace == 0, f"{path}: unsupported PNG kind"
            channels = 3 if colour == 2 else 4
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    raw = zlib.decompress(idat)
    stride = width * channels
    rows, previous = [], bytearray(stride)
    for y in range(height):
        filter_type = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - channels] if i >= channels else 0
            b = previous[i]
            c = previous[i - channels] if i >= channels else 0
            if filter_type == 1:
                line[i] = (line[i] + a) & 255
            elif filter_type == 2:
                line[i] = (line[i] + b) & 255
            elif filter_type == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif filter_type == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append(bytes(line) if channels == 3 else bytes(v for k, v in enumerate(line) if k % 4 != 3))
        previous = line
    return width, height, rows


def rgb_at(png, x, y):
    row = png[2][y]
    return row[3 * x], row[3 * x + 1], row[3 * x + 2]


def tonemap(linear, exposure=0.0):
    """DESIGN.md's tone map (common/image.c tonemap_srgb8), recomputed."""
    v = linear * 2.0 ** exposure
    if not v > 0.0:
        return 0
    if v >= 1.0:
        return 255
    s = 12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055
    return int(math.floor(255.0 * s + 0.5))


def write_pfm(path, width, height, pixel):
    """pixel(x, y) -> (r, g, b), y from the top; PFM rows go bottom to top."""
    with open(path, "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (width, height))
        for y in range(height - 1, -1, -1):
            f.write(b"".join(struct.pack("<3f", *pixel(x, y)) for x in range(width)))


def grid_image_origin(i, n, width, height):
    """Top-left pixel of panel i's area under the documented layout."""
    cols = math.ceil(math.sqrt(n))
    rows = (n + cols - 1) // cols
    c, r = i % cols, i // cols
    return c * width // cols, r * height // rows + LABEL_BAND


def synthetic_inputs(ctx):
    """Three 96x64 PFMs: an HDR ramp (clamping, the linear toe of sRGB), a
    real chapter-1 render, and a colour pattern with zeros and negatives."""
    w, h = 96, 64
    a = ctx.path("ramp.pfm")
    write_pfm(a, w, h, lambda x, y: (4.0 * x / (w - 1), 1e-4 * (y + 1) * (x % 7), (x + y) / (w + h) * 0.3))
    b = ctx.path("cornell.pfm")
    r = ctx.run("01_local", "scenes/cornell.scene", "--quiet", "--size", f"{w}x{h}", "--light-samples", "2",
                "--out", b, "--stats", ctx.path("cornell.json"))
    assert r.returncode == 0, r.stderr
    c = ctx.path("pattern.pfm")
    write_pfm(c, w, h, lambda x, y: (((x // 8 + y // 8) % 2) * 0.5, -0.25 if x < 10 else 0.01 * y, 0.0))
    return [a, b, c], w, h


def check_grid(png, inputs, exposure=0.0):
    """Every image pixel of every panel equals the tone-mapped input within 1."""
    n, (w, h) = len(inputs), (png[0], png[1])
    worst = 0
    for i, path in enumerate(inputs):
        img = lib.read_pfm(path)
        ox, oy = grid_image_origin(i, n, w, h)
        for y in range(img.height):
            for x in range(img.width):
                expected = [tonemap(v, exposure) for v in img.at(x, y)]
                got = rgb_at(png, ox + x, oy + y)
                d = max(abs(e - g) for e, g in zip(expected, got))
                assert d <= 1, f"panel {i + 1} ({os.path.basename(path)}) pixel ({x},{y}): " \
                               f"shows {got}, tone-mapped input is {expected}"
                worst = max(worst, d)
    return worst


def label_has_text(png, i, n):
    w, h = png[0], png[1]
    ox, oy = grid_image_origin(i, n, w, h)
    return any(max(rgb_at(png, x, y)) > 200 for y in range(oy - LABEL_BAND, oy) for x in range(ox, ox + 90))


# ---- compare grid on the headless backends ------------------------------------------------------------

def compare_grid(ctx, backend):
    inputs, w, h = synthetic_inputs(ctx)
    size = f"{2 * w}x{2 * (h + LABEL_BAND)}"  # 3 panels: 2 columns, 2 rows, images at scale 1
    for exposure in (0.0, 1.5):
        out = ctx.path(f"grid-{backend}-{exposure}.png")
        result = run_viewer(ctx, "--headless", "--backend", backend, "--size", size, "--exposure", exposure,
                            "--out", out, *inputs)
        ok(result, f"viewer --backend {backend}")
        png = read_png(out)
        assert (png[0], png[1]) == (2 * w, 2 * (h + LABEL_BAND)), f"screenshot is {png[0]}x{png[1]}, not {size}"
        check_grid(png, inputs, exposure)
        for i in range(3):
            assert label_has_text(png, i, 3), f"panel {i + 1} has no label text"
    return result


def test_compare_grid_osmesa(ctx):
    result = compare_grid(ctx, "osmesa")
    libraries = next(line for line in result.stdout.splitlines() if line.startswith("libraries:"))
    assert "libOSMesa" in libraries and "libEGL_mesa" not in libraries and "libGLX_mesa" not in libraries, \
        f"the osmesa backend must render with libOSMesa alone: {libraries}"


def test_compare_grid_egl(ctx):
    result = compare_grid(ctx, "egl")
    libraries = next(line for line in result.stdout.splitlines() if line.startswith("libraries:"))
    assert "libEGL_mesa" in libraries and "libOSMesa" not in libraries, \
        f"the egl backend must render with Mesa's EGL alone: {libraries}"
    assert "llvmpipe" in result.stdout or "softpipe" in result.stdout or "OpenGL" in result.stdout


def test_split_and_heat_map(ctx):
    """A/B split: left of the slider panel A, right of it panel B, both the
    tone-mapped inputs.  Heat map: a panel identical to the reference is
    black (zero error), a different one is not."""
    inputs, w, h = synthetic_inputs(ctx)
    width, height = w, h + LABEL_BAND
    out = ctx.path("split.png")
    ok(run_viewer(ctx, "--headless", "--backend", "osmesa", "--size", f"{width}x{height}", "--split", "1,3,0.5",
                  "--out", out, *inputs), "viewer --split")
    png = read_png(out)
    a, c = lib.read_pfm(inputs[0]), lib.read_pfm(inputs[2])
    split_x = round(width * 0.5)
    for y in range(h):
        for x in range(w):
            if x == split_x:
                continue  # the slider line
            src = a if x < split_x else c
            expected = [tonemap(v) for v in src.at(x, y)]
            got = rgb_at(png, x, LABEL_BAND + y)
            assert max(abs(e - g) for e, g in zip(expected, got)) <= 1, \
                f"split pixel ({x},{y}) shows {got}, expected {expected} from {'A' if x < split_x else 'B'}"

    same = [inputs[1], inputs[0], inputs[1]]
    out = ctx.path("heat.png")
    ok(run_viewer(ctx, "--headless", "--backend", "osmesa", "--size", f"{2 * w}x{2 * height}", "--diff", "1",
                  "--out", out, *same), "viewer --diff")
    png = read_png(out)
    reference = lib.read_pfm(same[0])
    for i, expect_black in ((2, True), (1, False)):
        ox, oy = grid_image_origin(i, 3, png[0], png[1])
        pixels = [rgb_at(png, ox + x, oy + y) for y in range(h) for x in range(w)]
        if expect_black:
            assert all(p == (0, 0, 0) for p in pixels), "a panel equal to the reference must show zero error (black)"
        else:
            assert sum(1 for p in pixels if max(p) > 0) > w * h // 4, "a different panel shows no error"
    ox, oy = grid_image_origin(0, 3, png[0], png[1])  # the reference itself: plain tone map
    for y in range(0, h, 5):
        for x in range(0, w, 5):
            expected = [tonemap(v) for v in reference.at(x, y)]
            assert max(abs(e - g) for e, g in zip(expected, rgb_at(png, ox + x, oy + y))) <= 1


# ---- GLFW under Xvfb ---------------------------------------------------------------------------

def start_xvfb():
    xvfb = shutil.which("Xvfb")
    assert xvfb, "Xvfb is not installed (apt-get install xvfb; make deps)"
    for number in range(91, 140):
        if os.path.exists(f"/tmp/.X{number}-lock") or os.path.exists(f"/tmp/.X11-unix/X{number}"):
            continue
        proc = subprocess.Popen([xvfb, f":{number}", "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
        deadline = time.time() + 10
        while time.time() < deadline and proc.poll() is None:
            if os.path.exists(f"/tmp/.X11-unix/X{number}"):
                return proc, f":{number}"
            time.sleep(0.05)
        proc.kill()
        proc.wait()
    raise AssertionError("could not start Xvfb")


def test_glfw_window_under_xvfb_equals_headless(ctx):
    inputs, w, h = synthetic_inputs(ctx)
    size = f"{2 * w}x{2 * (h + LABEL_BAND)}"
    headless = ctx.path("headless.png")
    ok(run_viewer(ctx, "--headless", "--backend", "egl", "--size", size, "--out", headless, *inputs), "headless")
    proc, display = start_xvfb()
    try:
        env = viewer_env()
        env["DISPLAY"] = display
        window = ctx.path("window.png")
        result = run_viewer(ctx, "--size", size, "--screenshot", window, *inputs, env=env, timeout=60)
        ok(result, "viewer in a GLFW window under Xvfb")
    finally:
        proc.terminate()
        proc.wait()
    assert "backend glfw" in result.stdout and "libGLX_mesa" in result.stdout, \
        f"the window must come from GLFW on GLX: {result.stdout}"
    a, b = read_png(headless), read_png(window)
    assert (a[0], a[1]) == (b[0], b[1]), f"window {b[0]}x{b[1]}, headless {a[0]}x{a[1]}"
    worst = max(abs(p - q) for ra, rb in zip(a[2], b[2]) for p, q in zip(ra, rb))
    assert worst <= 1, f"window and headless screenshots differ by up to {worst}/255"
    check_grid(b, inputs)


# ---- the window driven by synthetic input (xdotool, XTEST) under Xvfb ------------------------------
#
# The documented input mapping (viewer/README.md, the H overlay): `+` / `-`
# half a stop of exposure per press, `P` a screenshot viewer-N.png in the
# current directory, left drag orbits 0.3 degrees per pixel about the look
# point (distance kept), each wheel step scales the distance to the look point
# by 0.9 (in) or 1/0.9 (out), `Q` / Esc quit with status 0.  The viewer's
# stdout says what happened (`live: start|restart ... eye=... pids ...`,
# `camera: ... eye=... look=...` with --verbose, `wrote FILE`); the tests
# check those, the screenshots and /proc from outside.

EXPOSURE_STEP = 0.5      # stops per `+` / `-` press
ORBIT_DEGREES_PER_PIXEL = 0.3
DOLLY_STEP = 0.9         # distance factor per wheel step towards the look point


class WindowSession:
    """build/viewer in a GLFW window on a private Xvfb, its stdout collected
    line by line, driven by xdotool through XTEST (real input events, in
    order on the X connection, so a later key sees the effect of the earlier
    ones).  Never skips: no xdotool or no Xvfb is a failure."""

    def __init__(self, ctx, *args, cwd=None):
        self.xdotool = shutil.which("xdotool")
        assert self.xdotool, "xdotool is not installed (apt-get install xdotool; make deps)"
        self.lines, self.errors = [], []
        self.changed = threading.Condition()
        self.proc = None
        self.xvfb, self.display = start_xvfb()
        try:
            self.env = viewer_env()
            self.env["DISPLAY"] = self.display
            self.env["TMPDIR"] = ctx.scratch  # the live children's directory, checked for removal
            exe = os.path.join(lib.ROOT, ctx.build, "viewer")
            assert os.access(exe, os.X_OK), f"{exe} is not built (make {ctx.build}/viewer)"
            self.proc = subprocess.Popen([exe, *map(str, args)], cwd=cwd or ctx.scratch, env=self.env, text=True,
                                         stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            self.readers = [threading.Thread(target=self._read, args=(stream, store), daemon=True)
                            for stream, store in ((self.proc.stdout, self.lines), (self.proc.stderr, self.errors))]
            for t in self.readers:
                t.start()
            # The window: mapped (viewable), then focused and the pointer in it.
            found = self.xdo("search", "--sync", "--onlyvisible", "--pid", self.proc.pid, timeout=30)
            self.window = found.split()[0]
            self.xdo("windowfocus", "--sync", self.window)
        except BaseException:
            self.close()
            raise

    def _read(self, stream, store):
        for line in stream:
            with self.changed:
                store.append(line.rstrip("\n"))
                self.changed.notify_all()
        with self.changed:
            self.changed.notify_all()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self.proc and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        if self.proc:
            for t in self.readers:
                t.join(timeout=5)
            self.proc.stdout.close()
            self.proc.stderr.close()
        self.xvfb.terminate()
        self.xvfb.wait()

    def describe(self):
        return f"stdout: {self.lines[-40:]}\nstderr: {self.errors[-40:]}"

    def xdo(self, *args, timeout=10):
        try:
            r = subprocess.run([self.xdotool, *map(str, args)], env=self.env, capture_output=True, text=True,
                               timeout=timeout, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"xdotool {' '.join(map(str, args))} timed out (viewer exit {self.proc.poll()})\n"
                                 f"{self.describe()}") from None
        assert r.returncode == 0, f"xdotool {' '.join(map(str, args))}: exit {r.returncode} {r.stderr}"
        return r.stdout

    def wait_line(self, prefix, after=0, timeout=20):
        """The first stdout line from index `after` on that starts with prefix, and its index."""
        deadline = time.time() + timeout
        with self.changed:
            while True:
                for k in range(after, len(self.lines)):
                    if self.lines[k].startswith(prefix):
                        return self.lines[k], k
                left = deadline - time.time()
                assert left > 0 and self.proc.poll() is None, \
                    f"no line '{prefix}...' from the viewer (exit {self.proc.poll()})\n{self.describe()}"
                self.changed.wait(left)

    def finish(self, key, timeout=20):
        """Press key; the viewer must exit by itself; returns its status."""
        self.xdo("key", key)
        try:
            status = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"the viewer did not exit after {key}\n{self.describe()}") from None
        for t in self.readers:
            t.join(timeout=5)
        return status


def children_of(pid):
    """Processes whose parent is pid (zombies included), from /proc."""
    kids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) ": state ppid ...
        if int(fields[1]) == pid:
            kids.append((int(entry), fields[0]))
    return kids


def process_exists(pid):
    """Anything at all with this pid, a zombie included."""
    return os.path.exists(f"/proc/{pid}")


def parse_live_line(line):
    """'live: start|restart N children eye=X,Y,Z look=X,Y,Z pids P1,P2' -> (eye, look, [pids])."""
    words = line.split()
    eye = [float(v) for v in next(w for w in words if w.startswith("eye=")) [4:].split(",")]
    look = [float(v) for v in next(w for w in words if w.startswith("look=")) [5:].split(",")]
    pids = [int(p) for p in words[words.index("pids") + 1].split(",")]
    return eye, look, pids


def v_sub(a, b): return [a[k] - b[k] for k in range(3)]
def v_dot(a, b): return sum(a[k] * b[k] for k in range(3))
def v_len(a): return math.sqrt(v_dot(a, a))
def v_cross(a, b): return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def test_window_exposure_keys(ctx):
    """`+` twice, then `P`: every panel of the screenshot is its input
    tone-mapped at +1 stop (2 x the documented half stop), within 1/255.
    Then `-` three times (-1/2), the keypad's `+` three times (+1: one step
    per press, not two) and `0` (back to 0), each checked the same way."""
    inputs, w, h = synthetic_inputs(ctx)
    size = f"{2 * w}x{2 * (h + LABEL_BAND)}"
    shots = ((["plus", "plus"], 2 * EXPOSURE_STEP),
             (["minus", "minus", "minus"], -EXPOSURE_STEP),
             (["KP_Add", "KP_Add", "KP_Add"], 2 * EXPOSURE_STEP),
             (["0"], 0.0))
    with WindowSession(ctx, "--size", size, *inputs) as s:
        s.xdo("mousemove", "--window", s.window, 5, 5)  # on a label: the pointer changes no image pixel
        after = 0
        for n, (keys, exposure) in enumerate(shots, 1):
            s.xdo("key", *keys, "p")
            line, after = s.wait_line(f"wrote viewer-{n}.png", after)
            png = read_png(ctx.path(f"viewer-{n}.png"))
            assert (png[0], png[1]) == (2 * w, 2 * (h + LABEL_BAND)), f"screenshot {png[0]}x{png[1]}, not {size}"
            try:
                check_grid(png, inputs, exposure)
            except AssertionError as e:
                raise AssertionError(f"after keys {keys} (expected exposure {exposure:+}): {e}") from None
        status = s.finish("q")
    assert status == 0, f"Q: exit {status}\n{s.describe()}"


def live_args(ctx):
    return ("--live", os.path.join(lib.ROOT, "scenes", "cornell-point.scene"), "--chapter", "01_local",
            "--size", "320x200", "--render-size", "48x48", "--live-time", "60")


def test_window_live_drag_orbits_and_restarts(ctx):
    """A left drag of 40 pixels to the right in --live mode: once the camera
    rests the chapter children restart with the new eye, which lies on the
    sphere about the look point (distance kept to 1e-6 relative), turned
    40 x 0.3 = 12 degrees about the up axis; the old children are gone (not
    even zombies) and the viewer's only children are the new ones."""
    with WindowSession(ctx, *live_args(ctx)) as s:
        line, at = s.wait_line("live: start ")
        eye0, look0, pids0 = parse_live_line(line)
        assert sorted(pid for pid, _ in children_of(s.proc.pid)) == sorted(pids0), \
            f"children {children_of(s.proc.pid)} are not the logged ones {pids0}"
        assert not any(l.startswith("live: restart") for l in s.lines), "a restart before any input"
        x, y = 100, 120
        s.xdo("mousemove", "--window", s.window, x, y)
        s.xdo("mousedown", 1)
        for step in (10, 20, 30, 40):
            s.xdo("mousemove", "--window", s.window, x + step, y)
        s.xdo("mouseup", 1)
        line, at = s.wait_line("live: restart ", at + 1)
        eye1, look1, pids1 = parse_live_line(line)
        assert look1 == look0, f"the look point moved: {look0} -> {look1}"
        d0, d1 = v_sub(eye0, look0), v_sub(eye1, look1)
        assert abs(v_len(d1) - v_len(d0)) <= 1e-6 * v_len(d0), \
            f"orbit changed the distance to the look point: {v_len(d0)!r} -> {v_len(d1)!r}"
        scene_up = parse_scene_surfaces("scenes/cornell-point.scene")[1][2]
        up = [c / v_len(scene_up) for c in scene_up]
        assert abs(v_dot(d1, up) - v_dot(d0, up)) <= 1e-6 * v_len(d0), "a horizontal drag pitched the camera"
        p0 = v_sub(d0, [c * v_dot(d0, up) for c in up])
        p1 = v_sub(d1, [c * v_dot(d1, up) for c in up])
        angle = math.degrees(math.atan2(v_len(v_cross(p0, p1)), v_dot(p0, p1)))
        expected = 40 * ORBIT_DEGREES_PER_PIXEL
        assert abs(angle - expected) <= 1e-6 * expected, f"orbit of {angle} degrees, expected {expected}"
        assert set(pids1).isdisjoint(pids0), f"restart kept the old children {pids0} -> {pids1}"
        for pid in pids0:
            assert not process_exists(pid), f"old child {pid} (previous camera) is still there (zombie/orphan?)"
        kids = children_of(s.proc.pid)
        assert sorted(pid for pid, _ in kids) == sorted(pids1) and all(state != "Z" for _, state in kids), \
            f"the viewer's children are {kids}, expected exactly the new {pids1}"
        status = s.finish("q")
    assert status == 0, f"Q: exit {status}\n{s.describe()}"
    for pid in pids1:
        assert not process_exists(pid), f"child {pid} outlived the viewer"


def test_window_wheel_dollies(ctx):
    """--ply, eye 2 from the look point: two wheel steps in and one out give
    distances 2 * 0.9, 2 * 0.81, 2 * 0.9 (the documented factor), along the
    same line (to 1e-9 relative)."""
    ply = ctx.write("quad.ply", "ply\nformat ascii 1.0\nelement vertex 4\n"
                    "property float x\nproperty float y\nproperty float z\n"
                    "property float red\nproperty float green\nproperty float blue\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "-1 -1 0 0.1 0.25 0\n1 -1 0 0.9 0.25 0\n1 1 0 0.9 0.25 0\n-1 1 0 0.1 0.25 0\n4 0 1 2 3\n")
    eye, look = [0.3, 0.4, 2.0], [0.1, -0.2, 0.0]
    with WindowSession(ctx, "--ply", ply, "--size", "200x150", "--eye", ",".join(map(str, eye)),
                       "--look", ",".join(map(str, look)), "--verbose") as s:
        s.xdo("mousemove", "--window", s.window, 100, 80)
        s.xdo("click", "--repeat", 2, "--delay", 20, 4)  # button 4: wheel up, towards the look point
        s.xdo("click", 5)                                # button 5: wheel down
        status = s.finish("q")  # after the wheel events on the same connection: all of them are handled
    assert status == 0, f"Q: exit {status}\n{s.describe()}"
    moves = [line for line in s.lines if line.startswith("camera: ")]
    assert len(moves) == 3 and all(line.startswith("camera: dolly ") for line in moves), \
        f"expected three dolly moves, got {moves}\n{s.describe()}"
    d0 = v_sub(eye, look)
    for line, factor in zip(moves, (DOLLY_STEP, DOLLY_STEP ** 2, DOLLY_STEP)):
        e, l, _ = parse_live_line(line + " pids 0")
        assert l == look, f"dolly moved the look point: {line}"
        d = v_sub(e, l)
        assert abs(v_len(d) - factor * v_len(d0)) <= 1e-9 * v_len(d0), \
            f"distance {v_len(d)!r}, expected {factor * v_len(d0)!r} ({line})"
        assert v_len(v_cross(d, d0)) <= 1e-9 * v_len(d0) ** 2 and v_dot(d, d0) > 0, f"dolly turned the eye: {line}"


def test_window_quit_keys_leave_no_children(ctx):
    """`Q` and Esc in --live mode: exit status 0, the running chapter children
    stopped and reaped (nothing left in /proc), the temporary directory gone."""
    for key in ("q", "Escape"):
        with WindowSession(ctx, *live_args(ctx)) as s:
            line, _ = s.wait_line("live: start ")
            _, _, pids = parse_live_line(line)
            for pid in pids:
                assert process_exists(pid), f"child {pid} should be running"
            status = s.finish(key)
        assert status == 0, f"{key}: exit {status}\n{s.describe()}"
        for pid in pids:
            assert not process_exists(pid), f"{key}: child {pid} is still there after the viewer exited"
        left = [name for name in os.listdir(ctx.scratch) if name.startswith("viewer-")]
        assert not left, f"{key}: the viewer left its temporary directory {left}"


# ---- the GLSL raster against chapter 1 --------------------------------------------------------------

def parse_scene_surfaces(path):
    """Quads and triangles of a .scene file, as lists of triangles per surface, and its camera."""
    triangles, camera = [], None
    with open(os.path.join(lib.ROOT, path)) as f:
        for line in f:
            words = line.split("#")[0].split()
            if not words:
                continue
            if words[0] == "camera":
                v = words
                camera = ([float(x) for x in v[2:5]], [float(x) for x in v[6:9]], [float(x) for x in v[10:13]],
                          float(v[14]))
            elif words[0] in ("quad", "triangle"):
                n = 4 if words[0] == "quad" else 3
                pts = [[float(x) for x in words[3 + 3 * k:6 + 3 * k]] for k in range(n)]
                triangles.append((words[1], pts[0], pts[1], pts[2]))
                if n == 4:
                    triangles.append((words[1], pts[0], pts[2], pts[3]))
    return triangles, camera


def surface_ids(path, width, height):
    """Which surface each pixel centre sees: an independent ray caster
    (camera rays as DESIGN.md's camera: vertical fov, pixel centres)."""
    tris, (eye, look, up, fov) = parse_scene_surfaces(path)
    def sub(a, b): return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
    def dot(a, b): return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    def cross(a, b): return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    def unit(a):
        n = math.sqrt(dot(a, a))
        return [c / n for c in a]
    forward = unit(sub(look, eye))
    right = unit(cross(forward, up))
    upv = cross(right, forward)
    th = math.tan(math.radians(fov) / 2)
    tw = th * width / height
    pre = [(name, p0, sub(p1, p0), sub(p2, p0)) for name, p0, p1, p2 in tris]
    ids = []
    for y in range(height):
        row = []
        for x in range(width):
            sx = (2 * (x + 0.5) / width - 1) * tw
            sy = (1 - 2 * (y + 0.5) / height) * th
            d = [forward[k] + right[k] * sx + upv[k] * sy for k in range(3)]
            best, best_t = None, float("inf")
            for name, p0, e1, e2 in pre:  # Moller-Trumbore
                p = cross(d, e2)
                det = dot(e1, p)
                if abs(det) < 1e-12:
                    continue
                inv = 1.0 / det
                s = sub(eye, p0)
                u = dot(s, p) * inv
                if u < 0 or u > 1:
                    continue
                q = cross(s, e1)
                v = dot(d, q) * inv
                if v < 0 or u + v > 1:
                    continue
                t = dot(e2, q) * inv
                if 1e-9 < t < best_t:
                    best, best_t = name, t
            row.append(best)
        ids.append(row)
    return ids


def test_raster_matches_chapter1(ctx):
    """GLSL Blinn-Phong (float, rasterised) against chapter 1 (double, ray
    cast) on cornell-point.scene without shadows.  Pixels whose 3x3
    neighbourhood sees more than one surface are left out: there a pixel
    centre may fall on either side of an edge.  Elsewhere both compute the
    same formula at the same points (pixel centres of the same camera), so
    they differ only by float rounding (~1e-7 relative) and the interpolated
    world position (~1e-4 mm): we allow a mean relative difference of 1e-4
    and a worst one of 1e-3 (the glossy highlight amplifies position errors
    by its exponent 30).  Measured on llvmpipe: mean 6e-7, worst 1.3e-5.
    Leaving out 1/pi, the cosine or the specular lobe costs > 10 %."""
    scene, n = "scenes/cornell-point.scene", 96
    raster = ctx.path("raster.pfm")
    shot = ctx.path("raster.png")
    size = f"{2 * n}x{n + LABEL_BAND}"
    ok(run_viewer(ctx, "--raster", scene, "--no-shadows", "--headless", "--backend", "osmesa", "--size", size,
                  "--panel-out", raster, "--out", shot, "--verbose"), "viewer --raster")
    gpu = lib.read_pfm(raster)
    assert (gpu.width, gpu.height) == (n, n), f"raster is {gpu.width}x{gpu.height}"
    cpu, stats = ctx.render("01_local", scene, "--size", f"{n}x{n}", "--no-shadows", name="chapter1")
    ids = surface_ids(scene, n, n)
    total, count, worst, worst_at = 0.0, 0, 0.0, None
    for y in range(1, n - 1):
        for x in range(1, n - 1):
            if len({ids[y + j][x + i] for j in (-1, 0, 1) for i in (-1, 0, 1)}) != 1 or ids[y][x] is None:
                continue
            a, b = gpu.at(x, y), cpu.at(x, y)
            ref = sum(b) / 3
            rel = sum(abs(p - q) for p, q in zip(a, b)) / 3 / max(ref, 1e-3)
            total += rel
            count += 1
            if rel > worst:
                worst, worst_at = rel, (x, y, a, b)
    assert count > n * n // 2, f"only {count} interior pixels"
    mean = total / count
    assert mean < 1e-4, f"mean relative difference raster vs chapter 1 is {mean:.2e} (bound 1e-4)"
    assert worst < 1e-3, f"worst relative difference {worst:.2e} at {worst_at}"
    # Panel 2 is chapter 1 run by the viewer with the viewer's camera: it must
    # be the image we rendered ourselves, tone-mapped.
    png = read_png(shot)
    ox, oy = grid_image_origin(1, 2, png[0], png[1])
    for y in range(0, n, 3):
        for x in range(0, n, 3):
            expected = [tonemap(v) for v in cpu.at(x, y)]
            got = rgb_at(png, ox + x, oy + y)
            assert max(abs(e - g) for e, g in zip(expected, got)) <= 1, \
                f"chapter-1 panel pixel ({x},{y}) shows {got}, expected {expected}"


def test_raster_shader_error_is_reported(ctx):
    bad = ctx.write("bad.frag", "#version 330 core\nout vec4 fragment;\nvoid main() {\n  fragment = vec4(oops);\n}\n")
    result = run_viewer(ctx, "--raster", "scenes/cornell-point.scene", "--headless", "--backend", "osmesa",
                        "--size", "64x64", "--raster-shader", bad, "--out", ctx.path("x.png"))
    assert result.returncode == 2, f"a broken shader must exit 2, not {result.returncode}"
    assert f"{bad}:4:" in result.stderr, f"the message must name the file and line 4: {result.stderr}"
    assert not os.path.exists(ctx.path("x.png"))


def test_bad_input(ctx):
    missing = run_viewer(ctx, "--headless", "--backend", "osmesa", "--out", ctx.path("x.png"), ctx.path("none.pfm"))
    assert missing.returncode == 2 and "none.pfm:0:" in missing.stderr, missing.stderr
    garbage = ctx.write("garbage.pfm", "P6\n1 1\n255\nabc")
    result = run_viewer(ctx, "--headless", "--backend", "osmesa", "--out", ctx.path("x.png"), garbage)
    assert result.returncode == 2 and "garbage.pfm:1:" in result.stderr, result.stderr
    unknown = run_viewer(ctx, "--bogus")
    assert unknown.returncode == 2 and "argv:1:" in unknown.stderr, unknown.stderr
    assert not os.path.exists(ctx.path("x.png"))


# ---- PLY ------------------------------------------------------------------------------------------------

def test_ply_per_vertex_radiance(ctx):
    """A square in the plane z = 0 seen head-on, filling the view: left edge
    radiance 0.1, right edge 0.9 (green constant 0.25).  Smooth shading
    interpolates linearly across a plane facing the camera, so pixel column
    x shows 0.1 + 0.8 * (x + 0.5) / w."""
    ply = ctx.write("quad.ply", "ply\nformat ascii 1.0\ncomment test\nelement vertex 4\n"
                    "property float x\nproperty float y\nproperty float z\n"
                    "property float red\nproperty float green\nproperty float blue\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "-1 -1 0 0.1 0.25 0\n1 -1 0 0.9 0.25 0\n1 1 0 0.9 0.25 0\n-1 1 0 0.1 0.25 0\n4 0 1 2 3\n")
    # fov 90 at distance 1 sees exactly [-1, 1]^2 (camera_ray convention)
    w = h = 64
    out, pfm = ctx.path("ply.png"), ctx.path("ply.pfm")
    ok(run_viewer(ctx, "--ply", ply, "--headless", "--backend", "egl", "--size", f"{w}x{h + LABEL_BAND}",
                  "--eye", "0,0,1", "--look", "0,0,0", "--up", "0,1,0", "--fov", "90", "--out", out,
                  "--panel-out", pfm), "viewer --ply")
    img = lib.read_pfm(pfm)
    assert (img.width, img.height) == (w, h)
    for y in range(2, h - 2, 3):
        for x in range(2, w - 2):
            r, g, _ = img.at(x, y)
            # looking down -z, +x is to the right
            expected = 0.1 + 0.8 * (x + 0.5) / w
            assert abs(r - expected) < 2e-3 and abs(g - 0.25) < 1e-4, \
                f"pixel ({x},{y}) radiance {r:.4f},{g:.4f}; expected {expected:.4f},0.25"
    png = read_png(out)
    for x in range(2, w - 2):
        assert abs(rgb_at(png, x, LABEL_BAND + h // 2)[1] - tonemap(0.25)) <= 1


# ---- live mode --------------------------------------------------------------------------------------

def test_live_progressive_updates(ctx):
    """Chapter 1 as a child with --time: the viewer must see at least two
    successive images, and the child must not outlive the viewer."""
    result = run_viewer(ctx, "--live", "scenes/cornell-point.scene", "--chapter", "01_local", "--headless",
                        "--backend", "osmesa", "--size", "256x162", "--live-time", "20", "--exit-after-updates", "2",
                        "--out", ctx.path("live.png"), "--verbose", timeout=90)
    ok(result, "viewer --live")
    lines = result.stdout.splitlines()
    updates = [line for line in lines if line.startswith("update 01_local ")]
    assert len(updates) >= 2, f"expected two progressive updates, got: {lines}"
    pids = [int(line.split()[-1]) for line in lines if line.startswith("spawn 01_local pid ")]
    assert pids, f"no child reported: {lines}"
    for pid in pids:
        try:
            os.kill(pid, 0)
            alive = True
        except ProcessLookupError:
            alive = False
        assert not alive, f"child {pid} still runs after the viewer exited"
    assert "exit 01_local" not in result.stdout, "the 20 s budget cannot have run out: updates came from --time passes"


def process_gone(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            return any(line.startswith("State:") and "Z" in line.split()[1] for line in f)  # a zombie is dead
    except FileNotFoundError:
        return True


def test_live_children_die_with_a_killed_viewer(ctx):
    """Even a viewer killed by SIGKILL (no clean-up code runs) takes its
    children along: they ask for PR_SET_PDEATHSIG."""
    exe = os.path.join(lib.ROOT, ctx.build, "viewer")
    env = viewer_env()
    env["TMPDIR"] = ctx.scratch  # a killed viewer cannot remove its temporary directory
    proc = subprocess.Popen([exe, "--live", "scenes/cornell-point.scene", "--chapter", "01_local", "--headless",
                             "--backend", "osmesa", "--size", "128x100", "--live-time", "60", "--out",
                             ctx.path("never.png"), "--verbose"], cwd=lib.ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, text=True, env=env)
    try:
        pid = None
        for line in proc.stdout:
            if line.startswith("spawn 01_local pid "):
                pid = int(line.split()[-1])
                break
        assert pid, "the viewer did not report its child"
        assert not process_gone(pid), "the child should be running"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.time() + 5
        while time.time() < deadline and not process_gone(pid):
            time.sleep(0.05)
        assert process_gone(pid), f"child {pid} outlived the killed viewer"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
