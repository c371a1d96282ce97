"""Bad input, for every chapter: the malformed scenes and OBJ files in
tests/bad/ and whatever `make fuzz` found (tests/fuzz/findings/).

Each must end with exit status 2 and one line `file:line: message` (the
line a bad file expects is written in its first line, `# expect-line: N`,
or `# expect: other.obj:N` when the error is in an OBJ it references), with
no output file created, no sanitizer report, no hang.
"""
import glob
import os

import lib
from lib import ROOT

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

TIMEOUT_S = 60  # a hang, not a speed limit: a bad file fails in milliseconds


def chapters(ctx):
    found = sorted(os.path.basename(p) for p in glob.glob(os.path.join(ROOT, ctx.build, "0*_*"))
                   if os.access(p, os.X_OK) and not p.endswith(".d"))
    assert found, f"no chapters built in {ctx.build}"
    return found


def expected_prefix(path):
    rel = os.path.relpath(path, ROOT)
    with open(path, "rb") as f:
        first = f.readline().decode("latin-1")
    if first.startswith("# expect: "):
        return first[len("# expect: "):].strip() + ":"
    if first.startswith("# expect-line: "):
        return f"{rel}:{int(first.split(':')[1])}:"
    return f"{rel}:"


def run_bad(ctx, chapter, scene_rel):
    out = ctx.path("must-not-exist.pfm")
    r = ctx.run(chapter, scene_rel, "--quiet", "--size", "8x8", "--out", out, timeout=TIMEOUT_S)
    assert not os.path.exists(out), f"{chapter} {scene_rel}: an output file was created"
    return r


def test_bad_scene_corpus_every_chapter(ctx):
    """Every bad scene through every chapter; under the sanitizers (each run starts slowly) every
    scene through two chapters in turn, so each file and each chapter still runs there."""
    files = sorted(glob.glob(os.path.join(ROOT, "tests", "bad", "*.scene")))
    assert len(files) >= 40, "the bad-input corpus is missing"
    problems = []
    names = chapters(ctx)
    for i, path in enumerate(files):
        turn = {names[i % len(names)], names[(i + len(names) // 2) % len(names)]}
        for chapter in turn if lib.sanitizer_build(ctx) else names:
            rel = os.path.relpath(path, ROOT)
            r = run_bad(ctx, chapter, rel)
            lines = r.stderr.strip().splitlines()
            prefix = expected_prefix(path)
            if r.returncode != 2 or len(lines) != 1 or not lines[0].startswith(prefix):
                problems.append(f"{chapter} {rel}: exit {r.returncode}, stderr {r.stderr.strip()[:200]!r}, "
                                f"expected one line starting {prefix!r}")
    assert not problems, f"{len(problems)} problems:\n" + "\n".join(problems[:10])


def test_fuzz_findings_never_crash(ctx):
    """Inputs that once crashed the parser (tests/fuzz/findings/): now exit 0
    (a valid scene after all) or 2 with a file:line message; never a crash."""
    files = sorted(f for f in glob.glob(os.path.join(ROOT, "tests", "fuzz", "findings", "*")) if os.path.isfile(f)
                   and not f.endswith(".gitkeep"))
    problems = []
    for chapter in chapters(ctx):
        for path in files:
            rel = os.path.relpath(path, ROOT)
            out = ctx.path("f.pfm")
            r = ctx.run(chapter, rel, "--quiet", "--size", "4x4", "--out", out, timeout=TIMEOUT_S)
            if r.returncode not in (0, 2) or (r.returncode == 2 and not r.stderr.startswith(rel + ":")):
                problems.append(f"{chapter} {rel}: exit {r.returncode}: {r.stderr.strip()[:200]}")
    assert not problems, "\n".join(problems[:10])
