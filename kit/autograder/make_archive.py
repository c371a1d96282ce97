#!/usr/bin/python3
"""Write a Gradescope autograder archive: the instructor's grader for one assignment.

usage: kit/autograder/make_archive.py [--out FILE] [--chapters "01_local ..."] [--seed N]
                                      [--visibility V] [--packages "build-essential ..."] [--unsafe]
       make autograder [OUT=FILE] [CHAPTERS="01_local ..."] [UNSAFE=1]

  --out FILE        the zip to write (default out/autograder.zip; $OUT when make passes it)
  --chapters "A B"  the chapters this assignment grades (default every chapter in the rubric;
                    $CHAPTERS when make passes it)
  --seed N          grading seed (default 1; see kit/grade.py --seed)
  --visibility V    when students see each criterion's result on Gradescope: visible (default),
                    after_due_date, after_published or hidden
  --packages "..."  Debian/Ubuntu packages setup.sh installs (make passes the Makefile's
                    BUILD_PACKAGES); bubblewrap is always added: the sandbox needs it
  --unsafe          ($UNSAFE=1) grade without the sandbox where it cannot start (kit/grade.py --unsafe; the
                    results say so).  In Gradescope's container that lets a submission change the
                    grader itself: use it only for submissions you trust

Gradescope's layout (gradescope-autograders.readthedocs.io, "Autograder Specifications"):
the zip holds setup.sh and run_autograder at its top level; Gradescope unpacks it into
/autograder/source, runs setup.sh once as root when it builds the image, and runs
run_autograder (copied to /autograder/run_autograder) once per submission, which it puts in
/autograder/submission; run_autograder writes /autograder/results/results.json.

Besides the two scripts and autograder.json (what run_autograder grades), the archive is what
kit/grade.py needs and no more solution than the students have: the handout of these chapters
(kit/handout.py: the project with the chapters' exercises stubbed, and those of every later chapter,
not handed out yet; kit/grade.py lends its files
to every graded tree and takes the exercise files from the submission) with the instructor's
kit/ in place of the handout's: the rubric and the references, held-out ones included (the
archive never reaches students); not the handout's handout.json, the mark of a student's
self-check (kit/grade.py grades such a tree without a sandbox where none starts).

OUT, CHAPTERS and UNSAFE come from the environment under `make autograder` (the variables of
make's command line are exported), so spaces, quotes or ';' in them stay data.  Exit status 2 on bad input.
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.dirname(HERE))
import rubric as rubric_module  # noqa: E402

VISIBILITIES = ("visible", "after_due_date", "after_published", "hidden")  # Gradescope's four
SANDBOX_PACKAGES = ("bubblewrap",)
# Of the instructor's kit/, what grading does not read.  A handout's kit holds handout.json, its mark:
# a grader that finds one grades without a sandbox, as a student's self-check (kit/grade.py).
KIT_LEFT_OUT = ("kit/autograder/", "kit/student/", "kit/CALIBRATION.md", "kit/README.md", "kit/handout.json")


def fail(message):
    print(f"kit/autograder/make_archive.py: {message}", file=sys.stderr)
    sys.exit(2)


def parse_args(argv):
    opts = {"out": os.environ.get("OUT") or os.path.join(ROOT, "out", "autograder.zip"),
            "chapters": os.environ.get("CHAPTERS", ""), "seed": "1", "visibility": "visible", "packages": "",
            "unsafe": os.environ.get("UNSAFE", "").strip() not in ("", "0")}
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in ("-h", "--help"):
            print(__doc__.strip())
            sys.exit(0)
        if a == "--unsafe":
            opts["unsafe"] = True
        elif a.startswith("--") and isinstance(opts.get(a[2:]), str):
            if i + 1 >= len(argv):
                fail(f"{a} needs a value (see --help)")
            opts[a[2:]] = argv[i + 1]
            i += 1
        else:
            fail(f"unknown argument {a} (see --help)")
        i += 1
    if not opts["seed"].isdigit():
        fail(f"--seed {opts['seed']}: not a non-negative integer")
    if opts["visibility"] not in VISIBILITIES:
        fail(f"--visibility {opts['visibility']}: one of {', '.join(VISIBILITIES)}")
    return opts


def files_under(top):
    found = []
    for base, dirs, names in os.walk(top):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        found += [os.path.relpath(os.path.join(base, n), top) for n in sorted(names)]
    return found


def instructor_kit():
    """The kit/ files grading reads (tracked ones, as git lists them): the rubric, the references,
    held-out ones included, the judge's code."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "kit"], cwd=ROOT, capture_output=True, check=True).stdout
        files = [f for f in out.decode().split("\0") if f]
    except (OSError, subprocess.CalledProcessError):
        files = [os.path.join("kit", f) for f in files_under(os.path.join(ROOT, "kit"))]
    return sorted(f for f in files if not f.startswith(KIT_LEFT_OUT) and os.path.isfile(os.path.join(ROOT, f)))


def grading_files(chapters, scratch):
    """[(name in the archive, path)]: the handout of these chapters (kit/handout.py: what the
    students have, stubs where they write; kit/grade.py lends its files to the graded tree and finds
    the submitted files by its exercise markers) with the instructor's kit/ in place of the handout's."""
    handout = os.path.join(scratch, "handout")
    r = subprocess.run([sys.executable, os.path.join(ROOT, "kit", "handout.py"), handout, *chapters], cwd=ROOT,
                       capture_output=True, text=True)
    if r.returncode != 0:
        fail("kit/handout.py failed:\n" + r.stderr.strip())
    files = [(f, os.path.join(handout, f)) for f in files_under(handout) if not f.startswith("kit" + os.sep)]
    files += [(f, os.path.join(ROOT, f)) for f in instructor_kit()]
    names = {name for name, _ in files}
    missing = [f for f in ("Makefile", "kit/grade.py", "kit/criterion.py", "kit/rubric.json") if f not in names]
    if missing:
        fail(f"no {', '.join(missing)} in the tree: grading needs them")
    return sorted(files)


def setup_script(packages):
    with open(os.path.join(HERE, "setup.sh")) as f:
        text = f.read()
    marker = 'PACKAGES=""  # written by make_archive.py'
    if marker not in text:
        fail("kit/autograder/setup.sh: no PACKAGES line to fill in")
    return text.replace(marker, f'PACKAGES="{" ".join(packages)}"  # written by make_archive.py')


def add(archive, name, data, executable=False):
    info = zipfile.ZipInfo(name, date_time=(2024, 1, 1, 0, 0, 0))  # the same archive for the same tree
    info.external_attr = (0o100755 if executable else 0o100644) << 16
    info.compress_type = zipfile.ZIP_DEFLATED
    archive.writestr(info, data)


def main(argv):
    opts = parse_args(argv)
    try:
        rub = rubric_module.load(ROOT)
    except ValueError as e:
        fail(str(e))
    in_rubric = list(dict.fromkeys(c["chapter"] for c in rub["criteria"]))
    chapters = opts["chapters"].split() or in_rubric
    unknown = [c for c in chapters if c not in in_rubric]
    if unknown:
        fail(f"CHAPTERS: no criteria for {' '.join(unknown)} in kit/rubric.json (chapters: {' '.join(in_rubric)})")
    packages = list(dict.fromkeys(opts["packages"].split() + list(SANDBOX_PACKAGES)))
    if any(not p.replace("-", "").replace(".", "").replace("+", "").isalnum() for p in packages):
        fail(f"--packages {opts['packages']}: not a list of package names")
    criteria = [c for c in rub["criteria"] if c["chapter"] in chapters]
    config = {"chapters": chapters, "seed": int(opts["seed"]), "visibility": opts["visibility"],
              "max_score": sum(c["points"] for c in criteria), "packages": packages, "unsafe": opts["unsafe"]}
    out = os.path.abspath(opts["out"])
    if os.path.isdir(out):
        fail(f"OUT {opts['out']}: is a directory (name the .zip to write)")
    tmp = out + ".partial"
    scratch = tempfile.mkdtemp(prefix="gi-autograder-archive-")
    try:
        files = grading_files(chapters, scratch)
        os.makedirs(os.path.dirname(out), exist_ok=True)
        with zipfile.ZipFile(tmp, "w") as z:
            add(z, "setup.sh", setup_script(packages), executable=True)
            with open(os.path.join(HERE, "run_autograder")) as f:
                add(z, "run_autograder", f.read(), executable=True)
            add(z, "autograder.json", json.dumps(config, indent=1) + "\n")
            for name, path in files:
                with open(path, "rb") as src:
                    add(z, name, src.read(), executable=os.access(path, os.X_OK))
        os.replace(tmp, out)
    except OSError as e:
        fail(f"OUT {opts['out']}: cannot write: {e.strerror}")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
        if os.path.exists(tmp):
            os.remove(tmp)
    print(f"autograder archive {out}: {len(files) + 3} files, chapters {' '.join(chapters)}, "
          f"{config['max_score']} points; upload it as the assignment's autograder on Gradescope")


if __name__ == "__main__":
    main(sys.argv[1:])
