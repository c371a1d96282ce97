#!/usr/bin/python3
"""Write a student handout: this project without the solutions of the chosen chapters.

usage: kit/handout.py OUT_DIR [CHAPTER ...]        (make handout OUT=DIR CHAPTERS="03_radiosity ...")

  OUT_DIR   a directory that does not exist yet or is empty
  CHAPTER   e.g. 03_radiosity (default: every chapter with [exercise N.M] markers)

The tree is the project's tracked files (git ls-files) minus what only the
instructor may see (INSTRUCTOR_ONLY below: the kit's own tests and mutants,
the slides, which quote the solutions).  In the chosen chapters every function
marked [exercise N.M] gets a stub body (kit/markers.py): it prints
"file:line: TODO name is not implemented" once and returns zero, so the
handout compiles without warnings and runs, with black or partial images.
assignments/NN_name/ASSIGNMENT.md says what to write and how it is graded
(from the markers and kit/rubric.json); `make grade` in the handout grades it.
"""
import json
import os
import shutil
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import markers  # noqa: E402
import rubric as rubric_module  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INSTRUCTOR_ONLY = ("tests/mutants/", "tests/grade_kit.py", "kit/handout.py", "kit/calibrate.py", "kit/README.md",
                   "kit/CALIBRATION.md", "slides/", ".ci/")


def fail(message):
    print(f"kit/handout.py: {message}", file=sys.stderr)
    sys.exit(2)


def tracked_files(root):
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as e:
        fail(f"git ls-files failed in {root}: {e}")
    files = [f for f in out.decode().split("\0") if f]
    return [f for f in files if not f.startswith(INSTRUCTOR_ONLY) and os.path.isfile(os.path.join(root, f))]


def assignment_text(chapter, exercises, criteria, rub):
    lines = [f"# Assignment: {chapter}", "",
             f"Write the bodies of the functions below.  In this handout each one is a stub that prints",
             "`file:line: TODO name is not implemented` once and returns zero, so the chapter builds and",
             "runs from the start (its images are black or partial until you fill them in).", "",
             "    make                       # build every chapter into build/",
             f"    build/{chapter} --help",
             "    make demo                  # render the Cornell box with every chapter",
             "    make grade                 # grade this tree: out/grade/report.html and report.json", "",
             "## What to write", "",
             "| exercise | function | where | equations |", "|---|---|---|---|"]
    for e in exercises:
        lines.append(f"| {e.id} | `{e.name}` | `{e.file}:{e.line}` | {' '.join(e.labels) or '—'} |")
    for e in exercises:
        lines += ["", f"### Exercise {e.id}: `{e.name}`", "", f"`{e.signature}` in `{e.file}`", ""]
        lines += ["> " + ln if ln else ">" for ln in e.comment.splitlines()]
    total = sum(c["points"] for c in criteria)
    lines += ["", f"## How it is graded ({total} points)", "",
              "Each criterion is all or nothing.  Run `make grade` to see your score before you hand in.", "",
              "| criterion | points | exercises | what is checked |", "|---|---|---|---|"]
    for c in criteria:
        lines.append(f"| {c['name']} | {c['points']} | {', '.join(c['exercises'])} | {c['what']} |")
    lines += ["", "Criteria marked *vs reference* compare your image with the solution's, rendered with other",
              "seeds: the mean of each tile of "
              f"{rub['tile']}x{rub['tile']} pixels and each colour channel, over {rub['batches']} renders with",
              f"different seeds, against {rub['reference_batches']} of the solution, by Welch's t-test (both",
              "variances counted) with Holm's correction over the tiles and channels; all statistical criteria",
              f"together falsely fail a correct solution with probability at most {rub['family_alpha']}",
              "(Bonferroni over the criteria).  A compile error gives 0 for the chapter; a crash, a time-out,",
              "a NaN pixel or a missing output fails the criterion with a message.", ""]
    return "\n".join(lines)


def main(argv):
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        sys.exit(0 if argv else 2)
    out, chosen = os.path.abspath(argv[0]), argv[1:]
    if os.path.exists(out) and (not os.path.isdir(out) or os.listdir(out)):
        fail(f"{argv[0]}: exists and is not an empty directory")
    if out == ROOT or out.startswith(ROOT + os.sep) and not out.startswith(os.path.join(ROOT, "out") + os.sep):
        fail(f"{argv[0]}: inside the project (use a directory outside it, or under out/)")
    names = markers.chapter_names(ROOT)
    try:
        exercises = markers.all_exercises(ROOT)
        rub = rubric_module.load(ROOT)
    except ValueError as e:
        fail(str(e))
    marked = sorted({names[e.lecture] for e in exercises if e.lecture in names})
    chosen = chosen or marked
    for c in chosen:
        if c not in names.values():
            fail(f"no chapter {c} (chapters: {' '.join(sorted(names.values()))})")
        if c not in marked:
            fail(f"chapter {c} has no [exercise N.M] markers")
    stubbed = [e for e in exercises if names.get(e.lecture) in chosen]

    files = tracked_files(ROOT)
    by_file = {}
    for e in stubbed:
        by_file.setdefault(e.file, []).append(e)
    os.makedirs(out, exist_ok=True)
    for rel in files:
        dst = os.path.join(out, rel)
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        if rel in by_file:
            with open(os.path.join(ROOT, rel)) as f:
                text = f.read()
            with open(dst, "w") as f:
                f.write(markers.stub_file(text, by_file[rel]))
        else:
            shutil.copy2(os.path.join(ROOT, rel), dst)
    if "common/todo.h" not in files:
        shutil.copy2(os.path.join(ROOT, "common", "todo.h"), os.path.join(out, "common", "todo.h"))
    for chapter in chosen:
        ex = [e for e in stubbed if names[e.lecture] == chapter]
        crit = [c for c in rub["criteria"] if c["chapter"] == chapter]
        os.makedirs(os.path.join(out, "assignments", chapter), exist_ok=True)
        with open(os.path.join(out, "assignments", chapter, "ASSIGNMENT.md"), "w") as f:
            f.write(assignment_text(chapter, ex, crit, rub))
    with open(os.path.join(out, "kit", "handout.json"), "w") as f:
        json.dump({"chapters": chosen, "stubbed": [f"{e.id} {e.file}:{e.name}" for e in stubbed]}, f, indent=1)
    print(f"handout in {out}: {len(files)} files, {len(stubbed)} functions stubbed in {' '.join(chosen)}")


if __name__ == "__main__":
    main(sys.argv[1:])
