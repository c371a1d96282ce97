"""The grading report says what to do: a student's half-written chapter 1, graded.

The tree is a chapter-1 handout (make handout) with two of its three exercises written back from
the solution: area_light (1.3) as the solution has it, point_lights (1.2) with a deliberate
mistake (the intensity divided by 4 pi r^2, as if it were the light's power: 1 / (4 pi) = 8 % of
the answer, "too dark by 92 %"), and reflected_fraction (1.1) still the handout's stub.  One
grading of chapter 1 (kit/grade.py, about 30 s) and the report must:
  - name every stub left under "still to write", with its file and line, reached by a run;
  - give every failed criterion a sentence with the measured and expected values, the direction
    and the command it ran; the wrong point light's criterion "too dark by 92 %";
  - show measured values on passed criteria too;
  - show the compare criteria's pictures at 128 pixels or more, with failing tiles marked.
A passed compare criterion of the solution (kit/criterion.py alone, 2 s) shows its pictures at 128
pixels or more with no tile marked, and no tile map; its render is the stored picture of the solution
(kit/reference/<criterion>.png, which must be current).
"""
import json
import os
import re
import subprocess
import sys

import lib
from lib import ROOT

sys.path.insert(0, os.path.join(ROOT, "kit"))
import compare  # noqa: E402  (kit/compare.py: the pictures' sizes)
import grade  # noqa: E402  (kit/grade.py: stubs_in_source)
import markers  # noqa: E402
import png  # noqa: E402

CHAPTER = "01_local"
SOURCE = "chapters/01_local.c"
DIRECTION = re.compile(r"too (dark|bright|large|small|noisy|many|few)|noisier|not a number")
WRONG_POINT_LIGHT = ("v3_scale(light->intensity, 1.0 / r2)", "v3_scale(light->intensity, 1.0 / (4.0 * M_PI * r2))")


def handout(out):
    r = subprocess.run([sys.executable, os.path.join(ROOT, "kit", "handout.py"), out, CHAPTER], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return out


def write_back(tree, written, mistake=None):
    """Put the solution's bodies of the exercises named in `written` into the handout's SOURCE,
    with mistake (old, new) applied to them."""
    solution = {e.name: e for e in markers.parse_file(ROOT, SOURCE)}
    path = os.path.join(tree, SOURCE)
    with open(path) as f:
        text = f.read()
    stubs = sorted((e for e in markers.parse_file(tree, SOURCE) if e.name in written),
                   key=lambda e: -e.body_start)  # from the end: earlier offsets stay valid
    assert {e.name for e in stubs} == set(written), f"{SOURCE} of the handout lacks one of {written}"
    for e in stubs:
        body = solution[e.name].body
        if mistake and mistake[0] in body:
            body = body.replace(*mistake)
            mistake = None
        text = text[:e.body_start] + body + text[e.body_end:]
    assert mistake is None, f"the mistake {WRONG_POINT_LIGHT[0]!r} is not in the solution's bodies any more"
    with open(path, "w") as f:
        f.write(text)


def test_report_names_stubs_and_says_which_way_each_criterion_is_off(ctx):
    if lib.sanitizer_build(ctx):
        return  # kit/grade.py builds the handout itself, whatever the build: the same run in both passes
    tree = handout(ctx.path("student"))
    with open(os.path.join(tree, "kit", "handout.json")) as f:
        stubbed = {s.split(":")[-1] for s in json.load(f)["stubbed"]}
    found = {name for _, _, name in grade.stubs_in_source(tree, grade.submitted_files([CHAPTER]))}
    assert found == stubbed, f"the stubs in the handout's source {sorted(found)}, the handout's {sorted(stubbed)}"

    write_back(tree, ["point_lights", "area_light"], WRONG_POINT_LIGHT)
    left = stubbed - {"point_lights", "area_light"}
    report_dir = ctx.path("report")
    r = subprocess.run([sys.executable, os.path.join(ROOT, "kit", "grade.py"), tree, "--chapters", CHAPTER,
                        "--report", report_dir], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    with open(os.path.join(report_dir, "report.json")) as f:
        report = json.load(f)

    todo = {t["name"]: t for t in report["still_to_write"]}
    assert set(todo) == left, f"still to write: {sorted(todo)}, expected {sorted(left)}"
    for t in todo.values():
        assert t["file"] == SOURCE and t["line"] > 0 and t["criteria"], f"{t}: no file:line, or no run reached it"
    with open(os.path.join(report_dir, "report.html")) as f:
        page = f.read()
    assert "Still to write" in page and all(f"<code>{n}</code>" in page for n in left), "no 'still to write' in HTML"
    assert len(report["submission_sha256"]) == 64 and report["date"] and report["seed"] == 1, report.keys()

    criteria = {c["name"]: c for c in report["criteria"]}
    assert any(not c["passed"] for c in criteria.values()) and any(c["passed"] for c in criteria.values())
    for c in criteria.values():
        message = c["message"]
        assert c.get("measured"), f"{c['name']}: no measured values in the report"
        if c["kind"] in ("grade", "compare"):
            assert c["commands"] and all(x.startswith(f"build/{CHAPTER}") for x in c["commands"]), c["commands"]
        if c["passed"]:
            assert c["kind"] == "unit" or "measured" in message or " vs " in message, \
                f"{c['name']} passed without its measured value: {message}"
        elif "held-out" in c.get("reference", ""):  # the held-out solution's numbers are not given
            assert " vs " not in message and re.search(r"image mean is (darker|brighter)", message), \
                f"{c['name']}: a held-out criterion must say which way, without the solution's means: {message!r}"
        else:
            assert ("measured" in message and "expected" in message) or " vs " in message, \
                f"{c['name']}: no measured and expected value in {message!r}"
            assert DIRECTION.search(message), f"{c['name']}: no direction in {message!r}"
            assert "ran build/" in message.lower(), f"{c['name']}: the message does not say what ran: {message!r}"
    inverse_square = criteria["point light probe inverse square cosine"]
    assert "too dark by 92 %" in inverse_square["message"], inverse_square["message"]
    assert criteria["area light probe converges to lambert formula"]["passed"], "area_light is the solution's"

    compared = [c for c in criteria.values() if c["kind"] == "compare"]
    assert compared and any(not c["passed"] for c in compared)
    for c in compared:
        check_pictures(c, report_dir)
        if not c["passed"]:
            assert re.search(r"\d+ of \d+ tiles too (dark|bright)", c["message"]), c["message"]
            assert c["preview"]["student"].startswith("one render: build/01_local") and \
                "--size 128x128" in c["preview"]["student"], f"{c['name']}: the picture is not its own render: " \
                f"{c['preview']}"
            assert f"<figcaption><b>your submission</b><br>{c['preview']['student']}" in page, \
                f"{c['name']}: the HTML does not say what the picture ran"


def marked_pixels(path):
    """{colour name: pixels of exactly that colour} for the two marks (png.BRIGHTER, png.DARKER)."""
    _, _, pixels = png.read_png(path)
    return {"brighter": pixels.count(png.BRIGHTER), "darker": pixels.count(png.DARKER)}


def check_pictures(c, report_dir):
    """The student's and the solution's pictures at 128 pixels or more; a failed criterion marks its
    failing tiles (in the colour of their direction) and has a tile map, a passed one marks none."""
    assert {"student", "reference"} <= set(c["images"]), f"{c['name']}: pictures {c['images']}"
    for key, name in c["images"].items():
        width, height = png.png_size(os.path.join(report_dir, name))
        assert min(width, height) >= 128, f"{name}: {width}x{height}, expected at least 128 pixels"
    marks = {key: marked_pixels(os.path.join(report_dir, c["images"][key])) for key in ("student", "reference")}
    tiles = [m["measured"] for m in c["measured"] if m["quantity"] == "tiles that differ from the solution's"]
    if c["passed"]:
        assert tiles == [0] and "tiles" not in c["images"], f"{c['name']} passed: tiles {tiles}, {c['images']}"
        assert all(sum(m.values()) == 0 for m in marks.values()), f"{c['name']} passed but marks tiles: {marks}"
    else:
        words = set(re.findall(r"tiles too (dark|bright)", c["message"]))
        for key, m in marks.items():
            for word, colour in (("dark", "darker"), ("bright", "brighter")):
                assert (m[colour] > 0) == (word in words), \
                    f"{c['name']}: {key} picture has {m[colour]} pixels marked {colour}, the message says {words}"
        assert "tiles" in c["images"], f"{c['name']} failed without a tile map"


def test_passed_compare_criterion_marks_no_tile(ctx):
    """The solution's own area-light criterion (kit/criterion.py, as kit/grade.py runs it): it
    passes, its pictures are 128 pixels or more with no tile marked, and its render is the stored
    picture of the solution (mean difference below one 8-bit level: kit/grade.py --make-reference
    makes it current)."""
    rub = json.load(open(os.path.join(ROOT, "kit", "rubric.json")))
    c = next(c for c in rub["criteria"] if c["name"] == "cornell area light vs reference")
    images = ctx.path("images")
    r = subprocess.run([sys.executable, os.path.join(ROOT, "kit", "criterion.py"), ROOT, ctx.build, json.dumps(c),
                        "1", "2", images], cwd=ROOT, capture_output=True, text=True, timeout=300)
    result = json.loads(r.stdout[r.stdout.rfind("@@RESULT@@ ") + len("@@RESULT@@ "):])
    assert result["passed"], result["message"]
    check_pictures(result, images)
    width, height, stored = png.read_png(compare.preview_path(c))
    assert min(width, height) >= 128, f"{compare.preview_path(c)}: {width}x{height}, expected at least 128 pixels"
    assert result["preview"]["student"] == "one render: " + compare.preview_command(c), result["preview"]
    rendered = compare.render_preview(ROOT, ctx.build, c, 2)[2]
    difference = sum(abs(a - b) for p, q in zip(rendered, stored) for a, b in zip(p, q)) / (3 * len(stored))
    assert len(rendered) == len(stored) and difference < 1, \
        f"{compare.preview_path(c)} differs from the solution's render by {difference:.2f} levels on average: " \
        "run kit/grade.py --make-reference"
