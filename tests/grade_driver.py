"""The shared driver (common/render.c): interruption, time budget, outputs.

Run through chapter 1, the cheapest chapter; every chapter uses the same driver.
"""
import os
import signal
import subprocess
import time

from lib import ROOT, finite_image, read_json, read_pfm

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

CHAPTER = "01_local"


def test_sigint_writes_completed_passes_and_exits_130(ctx):
    """SIGINT mid-render: exit status 130, the image of the completed passes
    (finite, complete), stats saying interrupted, no temporary files left.
    Checked for the cheapest and the most progressive chapter."""
    for chapter in ("01_local", "04_pathtrace"):
        check_sigint(ctx, chapter)


def check_sigint(ctx, chapter):
    """Interrupted after 1.5 s, or later if no pass was complete by then (a loaded machine, the sanitizer
    build): that case must exit 130 too, say so and write nothing; then the test waits longer."""
    pfm, stats = ctx.path(chapter + ".pfm"), ctx.path(chapter + ".json")
    exe = os.path.join(ROOT, ctx.build, chapter)
    for seconds in (1.5, 5, 15):
        child = subprocess.Popen([exe, "scenes/cornell.scene", "--quiet", "--size", "64x64", "--spp", "1000000",
                                  "--out", pfm, "--stats", stats], cwd=ROOT, stderr=subprocess.PIPE, text=True)
        time.sleep(seconds)
        child.send_signal(signal.SIGINT)
        _, stderr = child.communicate(timeout=60)
        assert child.returncode == 130, f"{chapter}: exit {child.returncode}: {stderr}"
        if "before the first pass was complete" not in stderr:
            break
        assert not os.listdir(ctx.scratch), f"{chapter}: no pass complete, yet it wrote {os.listdir(ctx.scratch)}"
    s = read_json(stats)
    assert s["interrupted"] is True and 1 <= s["spp"] < 1000000, s
    img = read_pfm(pfm)
    assert img.width == 64 and finite_image(img)
    assert not [f for f in os.listdir(ctx.scratch) if ".tmp." in f], "temporary files left behind"


def test_time_budget_is_respected_and_progressive(ctx):
    """--time 1 renders several passes and stops near the budget (a generous
    3 s ceiling: this checks that the budget ends the render, not speed)."""
    start = time.time()
    img, s = ctx.render(CHAPTER, "scenes/cornell.scene", "--size", "32x32", "--time", 1)
    assert time.time() - start < 3 + 2 * (ctx.build != "build"), "the render ran far past its --time budget"
    assert s["passes"] >= 2 and s["spp"] == s["passes"], s
    assert finite_image(img)


def test_unwritable_output_is_an_error_without_partial_file(ctx):
    os.makedirs(ctx.path("ro"))
    os.chmod(ctx.path("ro"), 0o500)
    target = ctx.path("ro/x.png")
    r = ctx.run(CHAPTER, "scenes/cornell.scene", "--size", "8x8", "--out", target)
    if os.geteuid() == 0:  # root ignores directory permissions; use a path under a file instead
        target = ctx.write("file", "") + "/x.png"
        r = ctx.run(CHAPTER, "scenes/cornell.scene", "--size", "8x8", "--out", target)
    assert r.returncode == 2 and r.stderr.startswith(target + ":"), r.stderr
    assert not os.path.exists(target)


def test_failed_write_like_a_full_disk(ctx):
    """A write that fails midway (the file-size limit RLIMIT_FSIZE makes
    write() fail with EFBIG, as a full disk fails with ENOSPC): exit 2 with
    'file:0: write failed', no file under the output name, no temporary left."""
    import resource

    def limit_file_size():
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # fail the write instead of killing the process

    out = ctx.path("big.pfm")
    exe = os.path.join(ROOT, ctx.build, CHAPTER)
    r = subprocess.run([exe, "scenes/cornell.scene", "--quiet", "--size", "64x64", "--out", out], cwd=ROOT,
                       capture_output=True, text=True, preexec_fn=limit_file_size, timeout=120)
    assert r.returncode == 2, f"exit {r.returncode}: {r.stderr}"
    assert r.stderr.startswith(out + ":0: write failed"), r.stderr
    assert not os.path.exists(out), "a partial output file was left under the output name"
    assert not [f for f in os.listdir(ctx.scratch) if ".tmp." in f], "temporary file left behind"


def every_chapter(ctx):
    from grade_bad_input import chapters
    return chapters(ctx)


DARK_SCENE = """\
camera eye 0 10 0  look 0 0 0  up 0 0 1  fov 30
image 8 8
material floor diffuse 0.5 0.5 0.5
quad floor floor  -50 0 -50  -50 0 50  50 0 50  50 0 -50
"""


def test_scene_without_light_warns_once(ctx):
    """A scene with no light is valid but surprising: every chapter renders it
    (black, background 0) with exit 0 and says so in one warning line."""
    scene = ctx.write("dark.scene", DARK_SCENE)
    for chapter in every_chapter(ctx):
        pfm = ctx.path(chapter + "-dark.pfm")
        r = ctx.run(chapter, scene, "--quiet", "--spp", 1, "--out", pfm)
        assert r.returncode == 0, f"{chapter}: exit {r.returncode}: {r.stderr}"
        warnings = [line for line in r.stderr.splitlines() if line.startswith("warning:") and "no light" in line]
        assert len(warnings) == 1, f"{chapter}: expected one 'no light' warning, got stderr {r.stderr!r}"
        assert all(p == (0.0, 0.0, 0.0) for p in read_pfm(pfm).pixels), f"{chapter}: a dark scene is not black"


def test_command_line_errors_name_the_argument(ctx):
    """Errors about one argument point at it (argv:N), never at argv:0."""
    for chapter in every_chapter(ctx):
        out = ctx.path("never.png")
        r = ctx.run(chapter, "scenes/cornell.scene", "--quiet", "--size", "8x8", "--out", out, "--out", "x.jpg")
        assert r.returncode == 2 and r.stderr.startswith("argv:8: --out 'x.jpg'"), f"{chapter}: {r.stderr!r}"
        assert not os.path.exists(out), f"{chapter}: an output was written despite the error"
        r = ctx.run(chapter, "scenes/cornell.scene", "--eye", "278,273,0", "--look", "278,273,0")
        assert r.returncode == 2 and r.stderr.startswith("argv:5:"), f"{chapter}: degenerate camera: {r.stderr!r}"
