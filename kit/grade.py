#!/usr/bin/python3
"""Grade a student's tree by the rubric (kit/rubric.json); write REPORT/report.json and report.html.

usage: kit/grade.py SUBMISSION [--report DIR] [--chapters "01_local ..."] [--seed N] [--jobs N]
                   [--statistical-only] [--timeout S] [--memory MIB] [--name NAME] [--unsafe]
       kit/grade.py --gradings-that-fit [--memory MIB]   (how many gradings of a class this machine runs at once)
       kit/grade.py --make-reference [--jobs N] [--build DIR]   (instructor: render kit/reference/ with this
                      tree's build/ (or DIR): the statistics and the report's picture of each criterion; then
                      kit/heldout/ as --make-heldout does)
       kit/grade.py --make-heldout [--jobs N] [--build DIR]     (instructor: only kit/heldout/: each compare and
                      surfaces criterion's held-out variant, another camera or patch size drawn at random (the
                      seed kept in the file; delete the file to draw anew), and the solution's reference for it)

  SUBMISSION          a filled-in handout or any copy of this project (a directory)
  --report DIR        where the report goes (default SUBMISSION/out/grade)
  --chapters "A B"    chapters to grade (default: the handout's, else every chapter in the rubric)
  --seed N            grading seed (default 1): compare criteria render batch b with seed N * 1000 + b;
                      grade criteria run with every chapter seed shifted by N (tests/lib.py Context;
                      1 = the tests' own seeds)
  --jobs N            renders run at once and make -j (default 2)
  --statistical-only  only the criteria of kind compare, without their pictures (for calibration)
  --timeout S         per criterion, whole process group killed after S seconds (default 300)
  --memory MIB        memory cap of the whole grading: every program of it, in all its sandboxes together
                      (one cgroup; default 4096); a run killed by it fails its criterion, saying so
  --gradings-that-fit print how many gradings of --memory MIB each (and one core each) this machine can run
                      at once, from its free memory and cores (kit/grade_class.py's default --jobs; over
                      ssh, the N of a login file's "N/host" line), and exit
  --rubric FILE       another rubric than kit/rubric.json (the kit's tests grade with small ones)
  --sandbox user      where user namespaces are blocked (a Docker container: Gradescope), the weaker
                      fallback of kit/sandbox.py: a uid of its own, per-user and per-process limits,
                      nothing hidden but what is unreadable to others (the report says so)
  --public            grade the compare and surfaces criteria against the public references (kit/reference/,
                      which the handout ships: the student's self-check), not their held-out variants
  --unsafe            grade without the sandbox (where bubblewrap or cgroups are missing); the report
                      says so.  Never for code you do not trust.

Held-out grading data: where kit/heldout/ has a criterion's variant (an
instructor's tree: a handout has only the README there) that variant is
graded instead of the public criterion, so replaying the public references'
numbers fails; the report says which was graded.

The graded tree is this project's files (without the instructor's kit, tests
of the kit and references) with the submission's versions of the files that
hold the graded chapters' exercises: a submission changes those files and
nothing else (not the Makefile, not common/'s other files, not the tests).
The chapters after those graded and those their criteria run (chapter 4's
compare with chapter 3) have their exercises stubbed there, as in a handout:
the sandbox lends no later chapter's solution.
Everything of the submission's runs inside a sandbox (kit/sandbox.py:
bubblewrap, its own namespaces, uid 65534, caps on processes, memory, CPU
time and file size): its build, its unit tests, every program a criterion
starts; one sandbox serves the grading (kit/sandbox.py Session: its runner
starts the programs, and kills whatever a run leaves behind), so what it
costs is paid once, not per program.  The judging (kit/criterion.py, the tests, the comparisons) runs
outside, from this project's kit/ and tests/, on the output files read back
as data.  A crash, hang, NaN pixel or missing output fails its criterion
with a message; after a criterion times out the chapter's other criteria
are skipped (a hanging submission costs one time-out per chapter).
A submission that is not a readable directory, is larger than
SUBMISSION_LIMIT_MIB, or holds device files, FIFOs, sockets or symbolic
links that lead out of it is refused.  Exit status 0 whenever grading ran,
2 on bad arguments, a refused submission, or no sandbox (without --unsafe).
"""
import datetime
import hashlib
import html
import json
import os
import re
import resource
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time

KIT = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(KIT)
sys.path.insert(0, KIT)
import compare  # noqa: E402
import markers  # noqa: E402
import rubric as rubric_module  # noqa: E402
import sandbox  # noqa: E402

SKIPPED_DIRS = {"build", "out", ".git", "__pycache__", "node_modules"}  # never graded, never copied


def skipped(directory):
    """SKIPPED_DIRS and build-*/ (`make BUILD=build-x`; git ignores both)."""
    return directory in SKIPPED_DIRS or directory.startswith("build-")
SUBMISSION_LIMIT_MIB, SUBMISSION_FILE_LIMIT = 64, 20000
# What the graded tree never holds: the instructor's kit (references, rubric, calibration), the kit's
# own tests and the bug corpus.  Only the scenes of kit/ (public inputs) are lent.
NOT_LENT = ("kit/", "tests/mutants/", "tests/grade_kit.py", "tests/grade_handout.py", ".ci/", ".git/")
LENT_FROM_KIT = ("kit/scenes/",)


def usage_error(message):
    print(f"kit/grade.py: {message} (see --help)", file=sys.stderr)
    sys.exit(2)


def parse_args(argv):
    opts = {"report": None, "chapters": None, "seed": 1, "jobs": 2, "statistical_only": False, "timeout": 300.0,
            "memory": 4096, "make_reference": False, "name": None, "submission": None, "unsafe": False,
            "rubric": None, "make_heldout": False, "public": False, "build": "build",
            "sandbox": "bwrap", "gradings_that_fit": False}
    valued = {"--report": str, "--chapters": str, "--seed": int, "--jobs": int, "--timeout": float,
              "--memory": int, "--name": str, "--rubric": str, "--build": str, "--sandbox": str}
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in ("-h", "--help"):
            print(__doc__.strip())
            sys.exit(0)
        elif a == "--statistical-only":
            opts["statistical_only"] = True
        elif a == "--make-reference":
            opts["make_reference"] = True
        elif a == "--unsafe":
            opts["unsafe"] = True
        elif a in ("--make-heldout", "--public", "--gradings-that-fit"):
            opts[a[2:].replace("-", "_")] = True
        elif a in valued:
            if i + 1 >= len(argv):
                usage_error(f"{a} needs a value")
            try:
                opts[a[2:].replace("-", "_")] = valued[a](argv[i + 1])
            except ValueError:
                usage_error(f"{a} {argv[i + 1]}: not a valid {valued[a].__name__}")
            i += 1
        elif a.startswith("-"):
            usage_error(f"unknown option {a}")
        elif opts["submission"] is None:
            opts["submission"] = a
        else:
            usage_error(f"unexpected argument {a}")
        i += 1
    if opts["jobs"] < 1 or opts["timeout"] <= 0 or opts["memory"] < 64 or opts["seed"] < 0:
        usage_error("--jobs, --timeout, --memory and --seed must be positive")
    return opts


def run_limited(cmd, cwd, timeout, memory, env=None):
    """The judge (kit/criterion.py, trusted) or, with --unsafe, a submission's program, in its own
    process group killed on time-out: (returncode or None on time-out, stdout, stderr)."""
    def set_limits():  # memory None: the judge, whose sandboxes have caps of their own (inherited otherwise)
        if memory is not None:
            resource.setrlimit(resource.RLIMIT_AS, (memory << 20, memory << 20))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    p = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                         start_new_session=True, preexec_fn=set_limits, env=env)
    try:
        out, err = p.communicate(timeout=timeout)
        return p.returncode, out.decode(errors="replace"), err.decode(errors="replace")
    except subprocess.TimeoutExpired:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        out, err = p.communicate()
        return None, out.decode(errors="replace"), err.decode(errors="replace")
    finally:
        try:  # leftovers of a finished criterion (a child that outlived it)
            os.killpg(p.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


# ---- the submission: checked, then the graded tree -------------------------------------------------

class Refused(Exception):
    """A submission that is not graded, with the one-line reason."""


def check_submission(submission):
    """Refused unless the submission is a readable directory of plain files, directories and
    symbolic links that stay inside it, at most SUBMISSION_LIMIT_MIB and SUBMISSION_FILE_LIMIT files."""
    if not os.path.isdir(submission):
        raise Refused(f"{submission}: not a directory" if os.path.exists(submission) else f"{submission}: missing")
    real_top, size, count = os.path.realpath(submission), 0, 0
    for top, dirs, files in os.walk(submission, onerror=lambda e: (_ for _ in ()).throw(
            Refused(f"{e.filename}: cannot read: {e.strerror}"))):
        dirs[:] = [d for d in dirs if not skipped(d)]
        for name in dirs + files:
            path = os.path.join(top, name)
            info = os.lstat(path)
            if stat.S_ISLNK(info.st_mode):
                target = os.path.realpath(path)
                if target != real_top and not target.startswith(real_top + os.sep):
                    raise Refused(f"{path}: a symbolic link out of the submission (to {os.readlink(path)})")
            elif not (stat.S_ISREG(info.st_mode) or stat.S_ISDIR(info.st_mode)):
                raise Refused(f"{path}: not a plain file or directory (a device, FIFO or socket)")
            elif stat.S_ISREG(info.st_mode):
                if not os.access(path, os.R_OK):
                    raise Refused(f"{path}: cannot read")
                size, count = size + info.st_size, count + 1
                if size > SUBMISSION_LIMIT_MIB << 20 or count > SUBMISSION_FILE_LIMIT:
                    raise Refused(f"{submission}: larger than {SUBMISSION_LIMIT_MIB} MiB or "
                                  f"{SUBMISSION_FILE_LIMIT} files (build/, out/ and .git/ not counted)")


def project_files(root):
    """The project's files, relative to root: git's list where root is a repository and git runs,
    else every file (a handout need not be one)."""
    if os.path.isdir(os.path.join(root, ".git")):
        try:
            r = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True)
        except OSError:  # no git on this machine (a runner image without it): every file, below
            r = None
        if r is not None and r.returncode == 0:
            return [f for f in r.stdout.decode().split("\0") if f and os.path.isfile(os.path.join(root, f))]
    found = []
    for top, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if not skipped(d))
        found += [os.path.relpath(os.path.join(top, f), root) for f in sorted(files)]
    return found


def submitted_files(chapters):
    """The files a submission hands in for these chapters: those holding their exercises."""
    names = markers.chapter_names(ROOT)
    return sorted({e.file for e in markers.all_exercises(ROOT) if names.get(e.lecture) in chapters})


def later_chapters(needed):
    """The chapters after every chapter in `needed` (the graded ones and those their criteria run):
    their solutions are not lent (stubbed_later).  A chapter builds on earlier ones only (chapter 2
    links chapter 1's model, chapter 5 chapter 4's), so these are never needed."""
    names = sorted(markers.chapter_names(ROOT).values())
    return [c for c in names if c > max(needed)]


def stubbed_later(rel, stubbed_chapters):
    """The text of project file rel with the exercises of stubbed_chapters stubbed as in a handout,
    or None where it holds none: a grading's sandbox must not lend a later chapter's solution."""
    names = markers.chapter_names(ROOT)
    mine = [e for e in markers.all_exercises(ROOT) if e.file == rel and names.get(e.lecture) in stubbed_chapters]
    if not mine:
        return None
    with open(os.path.join(ROOT, rel)) as f:
        return markers.stub_file(f.read(), mine)


def prepare(submission, work, chapters, stubbed_chapters=()):
    """work/src: this project's files but the instructor's (NOT_LENT), with the submission's versions
    of the files that hold the graded chapters' exercises and the exercises of stubbed_chapters
    (later_chapters) stubbed; everything root's and read-only but an empty build/ (the sandbox
    user's).  Returns (src, the submitted files that are missing)."""
    src = os.path.join(work, "src")
    lent = [f for f in project_files(ROOT) if not f.startswith(NOT_LENT) or f.startswith(LENT_FROM_KIT)]
    submitted, missing = submitted_files(chapters), []
    for rel in lent:
        os.makedirs(os.path.dirname(os.path.join(src, rel)), exist_ok=True)
        stubbed = stubbed_later(rel, stubbed_chapters) if rel not in submitted else None
        if stubbed is not None:
            with open(os.path.join(src, rel), "w") as f:
                f.write(stubbed)
        elif rel not in submitted:
            shutil.copyfile(os.path.join(ROOT, rel), os.path.join(src, rel))
    for rel in submitted:
        mine = os.path.join(submission, rel)
        if os.path.isfile(mine):  # check_submission: a link here stays inside the submission
            os.makedirs(os.path.dirname(os.path.join(src, rel)), exist_ok=True)
            shutil.copyfile(mine, os.path.join(src, rel))
        else:
            missing.append(rel)
    for top, dirs, files in os.walk(work):
        if top != work:  # work itself stays mkdtemp's 0700 until private_scratch opens it to the sandbox's uid
            os.chmod(top, 0o755)
        for f in files:
            os.chmod(os.path.join(top, f), 0o644)
    os.makedirs(os.path.join(src, "build"))
    os.makedirs(os.path.join(work, "scratch"), mode=0o755)
    return src, missing


# ---- building and running the submission --------------------------------------------------------

def sandbox_spec(src, opts, writable_build):
    """How kit/sandbox.py starts the submission's programs: the graded tree read-only (its build/
    writable while it builds), caps from --memory and the time-out."""
    return {"binds": [[src, False]] + ([[os.path.join(src, "build"), True]] if writable_build else []),
            "limits": {"memory_mib": opts["memory"], "processes": 64, "cpu_seconds": 2 * opts["timeout"] * opts["jobs"],
                       "file_mib": 512, "tmp_mib": 512},
            "threads": opts["jobs"], "mode": opts.get("sandbox", "bwrap"), "uid": opts.get("uid", sandbox.SANDBOX_UID)}


def run_submission(argv, src, opts, timeout, writable_build=False):
    """(returncode or None on time-out, stdout, stderr, what stopped it) of a program of the
    submission (its build, its unit tests): in a sandbox, or directly with --unsafe."""
    if opts.get("unsafe", False):
        code, out, err = run_limited(argv, src, timeout, opts["memory"], dict(os.environ, MAKEFLAGS=""))
        return code, out, err, "" if code is not None else f"time-out after {timeout:.0f} s"
    if opts.get("session") and not writable_build:
        r = sandbox.Client(opts["session"].client_spec()).run(argv, src, timeout)
        return r.returncode, r.stdout, r.stderr, r.stopped
    spec = sandbox_spec(src, opts, writable_build)
    spec["limits"]["cpu_seconds"] = max(spec["limits"]["cpu_seconds"], 2 * timeout * opts["jobs"])
    box = sandbox.Sandbox(spec["binds"], limits=sandbox.Limits(**spec["limits"]), threads=opts["jobs"],
                          mode=spec["mode"], uid=spec["uid"])
    r = box.run(argv, cwd=src, timeout=timeout)
    return r.returncode, r.stdout, r.stderr, r.stopped


def fresh_session(src, opts):
    """Before each criterion: the grading's sandbox (kit/sandbox.py Session, bwrap only) with nothing
    of the last criterion running in it; a new one where it ended or its runner does not answer."""
    if opts.get("unsafe", False) or opts["sandbox"] != "bwrap":
        return
    session = opts.get("session")
    if session and session.alive() and sandbox.Client(session.client_spec()).reset():
        return
    if session:
        session.close()
    spec = sandbox_spec(src, opts, writable_build=False)
    try:
        opts["session"] = sandbox.Session([tuple(b) for b in spec["binds"]] +
                                          [(os.path.join(os.path.dirname(src), "scratch"), True)],
                                          limits=sandbox.Limits(**spec["limits"]), threads=opts["jobs"])
    except OSError as e:  # each program then gets a sandbox of its own: as safe, slower
        opts["session"] = None
        print(f"kit/grade.py: {e}; a sandbox per program instead", file=sys.stderr)


def build(src, chapters, units, opts):
    """{target: error text or None}; chapters that do not compile get their compiler output.
    The instructor's Makefile, with the project's list of common/ sources (an extra file of the
    submission's in common/ is not linked: it is not even in the graded tree)."""
    targets = [f"build/{c}" for c in chapters] + [f"build/tests/{u}" for u in units]
    make = ["make", "-k", f"-j{opts['jobs']}", "BUILD=build"]
    run_submission(make + targets, src, opts, 900, writable_build=True)
    result = {}
    for t in targets:
        if os.path.exists(os.path.join(src, t)):
            result[t] = None
            continue
        code, out, err, stopped = run_submission(["make", "BUILD=build", t], src, opts, 600, writable_build=True)
        text = (out + err).strip()
        lines = [ln for ln in text.splitlines() if "error" in ln or "undefined reference" in ln]
        result[t] = ("\n".join(lines[:30]) + "\n\n" if lines else "") + text[-4000:] if code is not None \
            else f"the build was stopped: {stopped}"
    return result


C_COMPILER = shutil.which("cc") or "/usr/bin/cc"  # the grader's own builds (trusted_sites), whatever PATH is


def test_includes_submitted(test, chapters):
    """Whether tests/TEST.c includes a file the submission hands in (common/optics.h): then the
    submission's code runs in the test's process and could print its "ok" lines itself."""
    r = subprocess.run([C_COMPILER, "-std=c17", "-MM", "-Icommon", f"tests/{test}.c"], cwd=ROOT,
                       capture_output=True, text=True)
    return bool(set(r.stdout.replace("\\\n", " ").split()) & set(submitted_files(chapters)))


def trusted_sites(test, work, timeout):
    """The "site" lines (tests/check.h) of tests/TEST.c built from this tree (the solution's
    headers) and run here, outside the sandbox: the values the submission's run must reproduce.
    None where it does not build alone (a test that needs common/'s objects)."""
    exe = os.path.join(work, "trusted", test)
    os.makedirs(os.path.dirname(exe), exist_ok=True)
    built = subprocess.run([C_COMPILER, "-std=c17", "-O2", "-D_POSIX_C_SOURCE=200809L", "-Icommon", f"tests/{test}.c",
                            "-o", exe, "-lm"], cwd=ROOT, capture_output=True, text=True)
    if built.returncode != 0:
        return None
    code, out, _ = run_limited([exe], ROOT, timeout, 1024)
    return parse_sites(out) if code == 0 else None


LIMIT_ORDER = ("memory", "time", "output")  # the report's "limit" of a criterion: the first of these a run met
LIMIT_WORDS = {"memory": "memory", "time": "time", "output": "file size"}


def limit_met(row, stops, build_error, opts):
    """The cap that stopped a run of the failed criterion row ("memory", "time", "output"; None): from
    the runs its sandboxes noted (stops: kit/sandbox.py record_stop), a build the sandbox stopped, or
    the criterion's own time-out; the message is made to say so where it does not yet."""
    if build_error and build_error.startswith("the build was stopped: "):
        stops = stops + [sandbox.limit_of(build_error.split(": ", 1)[1])]
    if row["message"].startswith("timed out after "):
        stops = stops + ["time"]
    limit = next((k for k in LIMIT_ORDER if k in stops), None)
    if limit and LIMIT_WORDS[limit] not in row["message"].lower():
        said = {"memory": sandbox.memory_stop(opts["memory"]), "time": "stopped by a time cap (time-out or CPU time)",
                "output": "a file reached the file size cap (512 MiB)"}[limit]
        row["message"] = f"{said}; {row['message']}" if row["message"] else said
    return limit


def memory_summary(opts, grading_group):
    """The report's "memory": the cap, what it bounds, and the most the grading's programs held at once."""
    if opts.get("unsafe", False):
        return {"cap_mib": opts["memory"], "scope": "each process (--unsafe: RLIMIT_AS)", "peak_mib": None}
    if grading_group is None:
        return {"cap_mib": opts["memory"], "peak_mib": None,
                "scope": "each process (RLIMIT_AS) and the grading's uid's resident memory, looked at every 0.1 s "
                         "(--sandbox user without cgroups)"}
    return {"cap_mib": opts["memory"], "scope": "the whole grading (one cgroup)", "peak_mib": grading_group.peak_mib()}


def parse_sites(out):
    """{"file:line": (checks, held, sum of values, sum of tolerances)} from a test's stdout."""
    sites = {}
    for line in out.splitlines():
        words = line.split()
        if len(words) == 6 and words[0] == "site":
            try:
                sites[words[1]] = (int(words[2]), int(words[3]), float(words[4]), float(words[5]))
            except ValueError:
                continue
    return sites


def sites_that_differ(mine, solution):
    """The check sites whose counts or values differ from the solution's beyond what the checks
    allow (each value within its tolerance of the expected: two such sums differ by at most twice
    the tolerances' sum)."""
    differ = []
    for where, (checks, held, values, tolerances) in sorted(solution.items()):
        got = mine.get(where)
        if got is None or got[0] != checks or got[1] != held or \
                not abs(got[2] - values) <= 2 * tolerances + 1e-12 * max(1.0, abs(values)):
            differ.append(where)
    return differ


def run_unit(src, c, opts):
    """(passed, message, measured): every case of the C unit test, against the submission's common/;
    where the test holds submitted code, the values behind its checks against the solution's."""
    exe = os.path.join(src, "build", "tests", c["test"])
    code, out, err, stopped = run_submission([exe], src, opts, opts["timeout"])
    if code is None:
        return False, f"stopped: {stopped}", []
    if c.get("trusted_sites"):
        differ = sites_that_differ(parse_sites(out), c["trusted_sites"])
        if differ:
            return False, (f"the values behind {len(differ)} of the test's {len(c['trusted_sites'])} checks differ "
                           f"from the solution's run of the same test ({', '.join(differ[:4])}): its \"ok\" lines "
                           "are not what the checks computed"), []
    failed = [ln[5:] for ln in out.splitlines() if ln.startswith("FAIL ")]
    passed = [ln for ln in out.splitlines() if ln.startswith("ok   ")]
    measured = [{"quantity": "cases passed", "measured": len(passed), "expected": len(passed) + len(failed),
                 "passed": not failed, "text": f"{len(passed)} of {len(passed) + len(failed)} cases passed"}]
    if failed:
        return False, f"{len(failed)} of {len(failed) + len(passed)} cases failed: " + "; ".join(failed[:5]), measured
    if code != 0 or not passed:
        return False, compare.describe_exit(code, err) + f" after {len(passed)} cases passed", measured
    return True, f"{len(passed)} cases passed", measured


def submission_hash(submission):
    """(sha256 hex, number of files) over the submission's files as graded (the same files prepare()
    copies): each file's path relative to the submission and its bytes, in sorted order.  Two
    gradings of one hash graded the same code."""
    digest, count = hashlib.sha256(), 0
    skip_dirs = {"build", "out", ".git", "__pycache__", "node_modules"}
    for top, dirs, files in os.walk(submission):
        dirs[:] = sorted(d for d in dirs if d not in skip_dirs)
        for name in sorted(files):
            path = os.path.join(top, name)
            if name.endswith(".o") or not os.path.isfile(path) or os.path.islink(path):
                continue
            rel = os.path.relpath(path, submission)
            digest.update(rel.encode() + b"\0")
            with open(path, "rb") as f:
                digest.update(hashlib.sha256(f.read()).digest())
            count += 1
    return digest.hexdigest(), count


TODO_CALL = re.compile(r'\bTODO_ONCE\(\s*"(\w+)"\s*\)')


def stubs_in_source(src, submitted):
    """{(file, line, name)} of every TODO_ONCE("name") call in the submission's C sources (the
    files it hands in): the stubs a handout starts with that are still there, even those no run
    reached (a stub that calls another); not the later chapters' stubs (later_chapters)."""
    found = set()
    for folder in ("chapters", "common"):
        top = os.path.join(src, folder)
        for name in sorted(os.listdir(top)) if os.path.isdir(top) else []:
            if not name.endswith((".c", ".h")) or f"{folder}/{name}" not in submitted:
                continue
            try:
                with open(os.path.join(top, name), errors="replace") as f:
                    for number, line in enumerate(f, 1):
                        if line.lstrip().startswith(("*", "/*", "//")):  # a comment about stubs (common/todo.h)
                            continue
                        for m in TODO_CALL.finditer(line):
                            found.add((f"{folder}/{name}", number, m[1]))
            except OSError:
                continue
    return found


def still_to_write(results, in_source=()):
    """The stubs the runs reported and those still in the source, once each, sorted by file and
    line, each with the criteria that reached it: [{"name", "file", "line", "criteria": [...]}]."""
    found = {key: {"name": key[2], "file": key[0], "line": key[1], "criteria": []} for key in in_source}
    for r in results:
        for t in r.get("todos", []):
            key = (t["file"], t["line"], t["name"])
            found.setdefault(key, {"name": t["name"], "file": t["file"], "line": t["line"], "criteria": []})
            found[key]["criteria"].append(r["name"])
    return [found[k] for k in sorted(found)]


def run_criterion(src, c, opts, images_dir):
    """The judge, kit/criterion.py of this kit (not the submission's), outside the sandbox; every
    program it starts of the submission's is sandboxed (sandbox_spec) unless --unsafe."""
    cmd = [sys.executable, os.path.join(KIT, "criterion.py"), src, "build", json.dumps(c), str(opts["seed"]),
           str(opts["jobs"]), images_dir]
    if not opts.get("unsafe", False):
        spec = sandbox_spec(src, opts, writable_build=False)
        spec["scratch"] = os.path.join(os.path.dirname(src), "scratch")
        if opts.get("session"):
            spec["session"] = opts["session"].client_spec()
        cmd.append(json.dumps(spec))
    scratch = os.path.join(os.path.dirname(src), "scratch")  # the tests' temporary files, removed with the grading
    os.makedirs(scratch, exist_ok=True)  # a tree graded in place (the calibration) may have none beside it
    env = dict(os.environ, OMP_NUM_THREADS=str(opts["jobs"]), OMP_WAIT_POLICY="passive", PYTHONDONTWRITEBYTECODE="1",
               TMPDIR=scratch)
    code, out, err = run_limited(cmd, src, c.get("timeout", opts["timeout"]),
                                 opts["memory"] if opts.get("unsafe", False) else None, env)
    if code is None:
        return {"passed": False, "p_value": None, "images": {}, "timed_out": True,
                "message": f"timed out after {c.get('timeout', opts['timeout']):.0f} s (its programs killed)"}
    marker = out.rfind("@@RESULT@@ ")
    if marker < 0:
        return {"passed": False, "p_value": None, "images": {},
                "message": "the criterion died: " + compare.describe_exit(code, err)}
    return json.loads(out[marker + len("@@RESULT@@ "):])


def chapters_run_by(criteria, all_chapters):
    """The chapters the criteria run: their own, and those their tests name (chapter 4's compares
    with chapter 3's radiosity); the others need not be built."""
    needed = {c["chapter"] for c in criteria}
    for module in {c["module"] for c in criteria if c["kind"] == "grade"}:
        with open(os.path.join(ROOT, "tests", module + ".py")) as f:
            text = f.read()
        needed |= {ch for ch in all_chapters if ch in text}
    return sorted(ch for ch in all_chapters if ch in needed)


def chapters_to_grade(opts, rub):
    in_rubric = []
    for c in rub["criteria"]:
        if c["chapter"] not in in_rubric:
            in_rubric.append(c["chapter"])
    if opts["chapters"]:
        chosen = opts["chapters"].split()
        unknown = [c for c in chosen if c not in in_rubric]
        if unknown:
            usage_error(f"no criteria for {' '.join(unknown)} in kit/rubric.json (chapters: {' '.join(in_rubric)})")
        return chosen
    handout = os.path.join(ROOT, "kit", "handout.json")
    if os.path.exists(handout):
        with open(handout) as f:
            return [c for c in json.load(f)["chapters"] if c in in_rubric]
    return in_rubric


def make_reference(opts, rub):
    """kit/reference/ (unless --make-heldout), then kit/heldout/, from the solution in opts["build"]."""
    build_dir = opts["build"]
    for c in rub["criteria"]:
        if c["kind"] not in ("compare", "surfaces"):
            continue
        if not opts["make_heldout"]:
            if c["kind"] == "compare":
                compare.make_reference(ROOT, build_dir, c, rub, opts["jobs"])
                compare.make_preview(ROOT, build_dir, c, opts["jobs"])
                print(f"picture: {compare.preview_path(c)}", flush=True)
            else:
                compare.make_surfaces_reference(ROOT, build_dir, c)
            print(f"reference: {compare.reference_path(c)}", flush=True)
        t0 = time.time()
        about = compare.make_heldout(ROOT, build_dir, c, rub, opts["jobs"])
        print(f"held-out: {compare.heldout_path(c)}: {about['description']}; a replay of the public reference: "
              f"{about['replay_of_public']} ({time.time() - t0:.0f} s)", flush=True)


STYLE = """
body{font-family:sans-serif;margin:2em;max-width:80em;line-height:1.35}
table{border-collapse:collapse;width:100%}
td,th{border:1px solid #ccc;padding:6px 8px;vertical-align:top;text-align:left}
.pass{color:#070}.fail{color:#b00}.todo{background:#fff4d6;border:1px solid #e0b040;padding:8px 14px;margin:1em 0}
.todo li{margin:2px 0}code{background:#f2f2f2;padding:0 3px}pre{white-space:pre-wrap;background:#f6f6f6;padding:6px}
.sentence{margin:0 0 4px 0}details{margin:4px 0;font-size:92%}details li{margin:2px 0}
figure{display:inline-block;margin:4px 14px 4px 0;vertical-align:top}figcaption{font-size:85%;max-width:256px;overflow-wrap:anywhere}
img{image-rendering:pixelated;border:1px solid #999;width:256px}.swatch{display:inline-block;width:12px;height:12px;
vertical-align:middle;border:1px solid #555;margin:0 3px 0 8px}.meta{color:#555;font-size:90%}
"""

IMAGE_CAPTIONS = (("student", "your submission"), ("reference", "the solution"),
                  ("tiles", "the tiles that differ, filled: stronger = larger difference"),
                  ("heat", "|difference| / standard error"))


def html_todos(report):
    h = html.escape
    todos = report.get("still_to_write", [])
    if not todos:
        return []
    items = "".join(f"<li><code>{h(t['name'])}</code> ({h(t['file'])}:{t['line']}): " +
                    (f"reached by {h(', '.join(t['criteria']))}" if t["criteria"] else
                     "no run reached it yet (a function that calls it is still to write too)") + "</li>"
                    for t in todos)
    return [f"<div class=todo><b>Still to write:</b> " +
            ", ".join(f"<code>{h(t['name'])}</code> ({h(t['file'])}:{t['line']})" for t in todos) +
            f"<details><summary>which criteria reached each stub</summary><ul>{items}</ul></details>"
            "<small>These functions are still the handout's stubs (<code>TODO_ONCE</code>; a run that reaches one "
            "prints <code>TODO name is not implemented</code>). Criteria that reach them cannot pass yet.</small>"
            "</div>"]


def html_images(c):
    h = html.escape
    im = c.get("images") or {}
    if not im:
        return ""
    preview = c.get("preview") or {}
    notes = {"student": preview.get("student", ""), "reference": preview.get("reference", "")}
    figures = "".join(f"<figure><img src='{h(im[k])}' alt='{h(label)}'><figcaption><b>{h(label)}</b>"
                      f"{'<br>' + h(notes[k]) if notes.get(k) else ''}</figcaption></figure>"
                      for k, label in IMAGE_CAPTIONS if k in im)
    marked = sum(1 for m in c.get("measured", []) if m.get("quantity") == "tiles that differ from the solution's"
                 and m.get("measured"))
    grid = preview.get("grid", "tiles")
    legend = (f"<div class=meta>Grid: the {h(grid)} the test compares. Outlined:"
              f"<span class=swatch style='background:rgb{compare.png.BRIGHTER}'></span>brighter than the "
              "solution"
              f"<span class=swatch style='background:rgb{compare.png.DARKER}'></span>darker than the solution; "
              "tiles without a mark agree." + ("" if marked else " No tile differs.") + "</div>")
    return f"<div>{figures}</div>{legend}"


def html_criterion(c):
    h = html.escape
    cls = "pass" if c["passed"] else "fail"
    p = "" if c["p_value"] is None else f"<br><small>p = {c['p_value']:.3g}</small>"
    measured = c.get("measured") or []
    details = ""
    if len(measured) > 1:
        details += (f"<details><summary>all {len(measured)} measured values</summary><ul>" +
                    "".join(f"<li class={'pass' if m.get('passed') else 'fail'}>{h(m['text'])}</li>" for m in measured)
                    + "</ul></details>")
    if c.get("commands"):
        details += (f"<details><summary>commands it ran ({len(c['commands'])})</summary><ul>" +
                    "".join(f"<li><code>{h(x)}</code></li>" for x in c["commands"]) + "</ul></details>")
    if c.get("todos"):
        details += ("<div class=meta>reached the stubs " +
                    ", ".join(f"<code>{h(t['name'])}</code>" for t in c["todos"]) + "</div>")
    message = c["message"]
    body = f"<pre>{h(message)}</pre>" if "\n" in message else f"<p class=sentence>{h(message)}</p>"
    test = f"<br><small>{h(c['test'])}</small>" if c.get("test") else ""
    images = html_images(c)
    return (f"<tr><td>{h(c['name'])}<br><small>exercises "
            f"{h(', '.join(c['exercises']))}; {h(c.get('kind', ''))}{'; graded with ' + h(c['reference']) if c.get('reference') else ''}</small>{test}</td><td>{c['points']} / {c['max']}"
            f"</td><td class={cls}>{'pass' if c['passed'] else 'FAIL'}{p}</td><td>{body}{details}</td></tr>" +
            (f"<tr><td colspan=4>{images}</td></tr>" if images else ""))


def write_html(path, report, name):
    h = html.escape
    out = ["<!doctype html><meta charset=utf-8><title>grading report</title><style>" + STYLE + "</style>",
           f"<h1>Grading report{': ' + h(name) if name else ''}</h1>",
           f"<p><b>{report['total']} / {report['max']}</b> points.</p>"]
    if report.get("sandbox", "").startswith("none"):
        out.append(f"<p class=fail><b>Graded without a sandbox</b>: {h(report['sandbox'])}.</p>")
    out += html_todos(report)
    for chapter in report["chapters"]:
        rows = [c for c in report["criteria"] if c["chapter"] == chapter]
        got = sum(c["points"] for c in rows)
        out.append(f"<h2>{h(chapter)}: {got} / {sum(c['max'] for c in rows)}</h2>")
        if report["build_errors"].get(chapter):
            out.append(f"<p class=fail>does not compile:</p><pre>{h(report['build_errors'][chapter])}</pre>")
        out.append("<table><tr><th>criterion</th><th>points</th><th>result</th><th>what was measured</th></tr>")
        out += [html_criterion(c) for c in rows]
        out.append("</table>")
    out.append(f"<p class=meta>Graded {h(report.get('date', ''))} with seed {report['seed']}; submission sha256 "
               f"{h(report.get('submission_sha256', ''))} ({report.get('submission_files', '?')} files); "
               f"{report.get('seconds', '?')} s. Family-wise alpha {report['family_alpha']} over the statistical "
               f"criteria ({h(report['statistics'])}): a correct solution fails a grading by chance at most that "
               f"often. Sandbox: {h(report.get('sandbox', ''))}.{memory_sentence(report.get('memory'))}</p>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


def memory_sentence(memory):
    """The report page's words on the memory cap (report["memory"], memory_summary)."""
    if not memory:
        return ""
    peak = f"; the most its programs held at once: {memory['peak_mib']:.0f} MiB" if memory.get("peak_mib") else ""
    return f" Memory cap: {memory['cap_mib']} MiB for {html.escape(str(memory['scope']))}{peak}."


SCRATCH_PREFIX = "gi-grade-"


def end_on_signals():
    """SIGTERM, SIGHUP and SIGINT end a grading through main's `finally:`, which ends its sandboxes and
    removes its cgroups and its scratch directory.  SIGKILL cannot be caught: the next grading removes
    what such a one left (remove_stale_scratch)."""
    def stop(signum, frame):
        raise SystemExit(128 + signum)
    for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
        signal.signal(sig, stop)


def remove_stale_scratch():
    """Scratch directories of gradings that were killed: named gi-grade-PID-..., their grader gone."""
    top = tempfile.gettempdir()
    for name in os.listdir(top):
        parts = name[len(SCRATCH_PREFIX):].split("-")
        if not name.startswith(SCRATCH_PREFIX) or not parts[0].isdigit():
            continue
        try:
            with open(f"/proc/{parts[0]}/cmdline", "rb") as f:
                alive = b"grade.py" in f.read()
        except OSError:
            alive = False
        path = os.path.join(top, name)
        # only a real directory the grader made (not a link, nor one a student's uid made in /tmp)
        if not alive and os.path.isdir(path) and not os.path.islink(path) and os.lstat(path).st_uid == os.geteuid():
            shutil.rmtree(path, ignore_errors=True)


def private_scratch(work, uid):
    """The scratch directory open to the grader and to the sandbox's uid (its group) only: no other
    grading's student code (another uid under --sandbox user) can enter it."""
    if os.geteuid() == 0:
        os.chown(work, 0, uid)
    os.chmod(work, 0o750 if os.geteuid() == 0 else 0o700)  # not root: the sandbox runs as the grader


def main(argv):
    end_on_signals()
    opts = parse_args(argv)
    if opts["gradings_that_fit"]:
        print(sandbox.gradings_that_fit(opts["memory"]))
        return
    try:
        rub = rubric_module.load(ROOT, opts["rubric"])
    except ValueError as e:
        usage_error(str(e))
    if opts["make_reference"] or opts["make_heldout"]:
        make_reference(opts, rub)
        return
    if opts["submission"] is None:
        usage_error("no SUBMISSION directory given")
    submission = os.path.abspath(opts["submission"])
    try:
        check_submission(submission)
    except Refused as e:
        print(f"kit/grade.py: not graded: {e}", file=sys.stderr)
        sys.exit(2)
    chapters = chapters_to_grade(opts, rub)
    report_dir = os.path.abspath(opts["report"] or os.path.join(submission, "out", "grade"))
    try:
        os.makedirs(report_dir, exist_ok=True)
        with tempfile.TemporaryFile(dir=report_dir):
            pass
    except OSError as e:
        print(f"kit/grade.py: REPORT {report_dir}: cannot write there: {e.strerror}", file=sys.stderr)
        sys.exit(2)
    if opts["sandbox"] not in ("bwrap", "user"):
        usage_error(f"--sandbox {opts['sandbox']}: bwrap or user")
    why_not = None if opts.get("unsafe", False) else \
        sandbox.unavailable() if opts["sandbox"] == "bwrap" else sandbox.fallback_unavailable()
    if why_not and not os.path.exists(os.path.join(ROOT, "kit", "handout.json")):
        print(f"kit/grade.py: no sandbox for the submission's code: {why_not} (UNSAFE=1 / --unsafe grades "
              "without one: only for code you trust)", file=sys.stderr)
        sys.exit(2)
    if why_not:  # a handout grading itself: the student's own code on the student's machine
        print(f"kit/grade.py: self-check without a sandbox ({why_not})", file=sys.stderr)
        opts["unsafe"] = True
    opts["uid"] = sandbox.user_for_grading() if opts["sandbox"] == "user" else sandbox.SANDBOX_UID
    tag = f"gi-sandbox-{os.getpid()}-{int(time.time())}"
    os.environ[sandbox.TAG_VARIABLE] = tag
    criteria = [c for c in rub["criteria"] if c["chapter"] in chapters and
                (not opts["statistical_only"] or rubric_module.statistical(c))]
    try:  # the held-out variants where kit/heldout/ has them (the instructor's), unless --public
        criteria = [compare.graded_variant(c, opts["public"]) for c in criteria]
    except ValueError as e:
        print(f"kit/grade.py: {e}", file=sys.stderr)
        sys.exit(2)
    start = time.time()
    date = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    digest, files = submission_hash(submission)
    remove_stale_scratch()
    if not opts.get("unsafe", False):
        sandbox.remove_stale_groups()  # a killed grading's (SIGKILL), empty
    work = tempfile.mkdtemp(prefix=f"{SCRATCH_PREFIX}{os.getpid()}-")
    # The grader's own temporaries (a run's captured output, the judge's session) inside work too: a
    # grading killed by SIGKILL leaves them where the next grading's remove_stale_scratch looks.
    tempfile.tempdir = work
    stops = os.path.join(work, "stops.jsonl")  # the runs a cap stopped (kit/sandbox.py record_stop)
    os.environ[sandbox.STOPS_VARIABLE] = stops
    try:
        grading_group = None  # the cgroup of the whole grading: its memory cap bounds all its sandboxes together
        if not opts.get("unsafe", False):
            try:
                grading_group = sandbox.GradingGroup(tag, opts["memory"])
            except OSError as e:
                if opts["sandbox"] == "bwrap":
                    print(f"kit/grade.py: no sandbox for the submission's code: cannot make the grading's cgroup "
                          f"(its memory cap): {e.strerror or e}", file=sys.stderr)
                    sys.exit(2)
                # --sandbox user without cgroups: each process's address space and the uid's resident sum
                # looked at every 0.1 s (kit/sandbox.py user_memory_mib)
        names = sorted(markers.chapter_names(ROOT).values())
        needed = set(chapters) | set(chapters_run_by(criteria, names))
        src, missing = prepare(submission, work, chapters, later_chapters(needed))
        if not opts.get("unsafe", False):  # the sandbox user writes the build and nothing else of the tree
            os.chown(os.path.join(src, "build"), opts["uid"], opts["uid"])
            private_scratch(work, opts["uid"])
        absent = {c for c in chapters for f in missing if f == f"chapters/{c}.c"}
        present = [c for c in chapters if c not in absent]
        all_chapters = sorted(os.path.splitext(f)[0] for f in os.listdir(os.path.join(src, "chapters"))
                              if f.endswith(".c") and f[:2].isdigit()) if os.path.isdir(
                                  os.path.join(src, "chapters")) else []
        units = sorted({c["test"] for c in criteria if c["kind"] == "unit"})
        built = build(src, chapters_run_by(criteria, all_chapters), units, opts)
        results, hung = [], {}
        for c in criteria:
            fresh_session(src, opts)
            sandbox.recorded_stops(stops)  # from here on: this criterion's
            row = {"chapter": c["chapter"], "name": c["name"], "points": 0, "max": c["points"], "passed": False,
                   "p_value": None, "message": "", "exercises": c["exercises"], "kind": c["kind"], "limit": None}
            if c["kind"] == "grade":
                row["test"] = f"tests/{c['module']}.py {c['test']}"
            if c["kind"] in ("compare", "surfaces"):
                row["reference"] = c.get("heldout") or "the public reference (kit/reference/, as in the handout)"
            error = built.get(f"build/{c['chapter']}")
            t0 = time.time()
            if c["chapter"] not in present:
                row["message"] = f"chapters/{c['chapter']}.c is not in the submission"
            elif c["chapter"] in hung:
                row["message"] = f"not run: the criterion '{hung[c['chapter']]}' of this chapter timed out"
            elif error:
                row["message"] = f"{c['chapter']} does not compile:\n" + error[:1500]
            elif c["kind"] == "unit":
                if built.get(f"build/tests/{c['test']}"):
                    row["message"] = f"tests/{c['test']}.c does not compile against the submission's common/:\n" + \
                        built[f"build/tests/{c['test']}"][:1500]
                else:
                    if test_includes_submitted(c["test"], chapters):
                        c = dict(c, trusted_sites=trusted_sites(c["test"], work, opts["timeout"]) or {})
                    row["passed"], row["message"], row["measured"] = run_unit(src, c, opts)
                    row["commands"] = [f"build/tests/{c['test']}"]
            else:
                r = run_criterion(src, c, opts, "" if opts["statistical_only"] else report_dir)
                row.update({k: r[k] for k in ("passed", "p_value", "message")})
                row["images"] = r.get("images", {})
                if r.get("preview"):
                    row["preview"] = r["preview"]
                row.update({k: r.get(k, []) for k in ("measured", "commands", "todos")})
                if r.get("timed_out"):
                    hung[c["chapter"]] = c["name"]
            row["limit"] = None if row["passed"] else limit_met(row, sandbox.recorded_stops(stops), error, opts)
            row["points"] = c["points"] if row["passed"] else 0
            row["seconds"] = round(time.time() - t0, 2)
            results.append(row)
            print(f"{'pass' if row['passed'] else 'FAIL'} {c['chapter']}: {c['name']} ({row['points']}/{c['points']})"
                  + ("" if row["passed"] else ": " + row["message"].splitlines()[0][:200] if row["message"] else ""),
                  flush=True)
        report = {"submission": submission, "total": sum(r["points"] for r in results),
                  "max": sum(r["max"] for r in results), "criteria": results, "chapters": chapters,
                  "still_to_write": still_to_write(results, stubs_in_source(src, submitted_files(chapters))), "date": date,
                  "submission_sha256": digest, "submission_files": files,
                  "seed": opts["seed"], "family_alpha": rub["family_alpha"],
                  "sandbox": "none: graded with --unsafe (UNSAFE=1), the submission's code ran unconfined"
                             if opts.get("unsafe", False) else "bubblewrap (kit/sandbox.py)" if opts["sandbox"] == "bwrap"
                             else f"a separate user (uid {opts['uid']}) with per-user and per-process limits "
                                  "(--sandbox user: no namespaces here, the file system is not hidden; no sockets: a seccomp "
                                  "filter)",
                  "statistics": "Welch's t per tile and channel and on the image mean, one-sided F on the noise, "
                                "Holm within a criterion, Bonferroni over the compare criteria",
                  "build_errors": {c: built.get(f"build/{c}") for c in chapters if built.get(f"build/{c}")},
                  "memory": memory_summary(opts, grading_group),
                  "seconds": round(time.time() - start, 1)}
        with open(os.path.join(report_dir, "report.json"), "w") as f:
            json.dump(report, f, indent=1)
        write_html(os.path.join(report_dir, "report.html"), report, opts["name"] or os.path.basename(submission))
        print(f"{report['total']} / {report['max']} points in {report['seconds']} s; report: "
              f"{os.path.join(report_dir, 'report.html')}")
    finally:
        if opts.get("session"):
            opts["session"].close()
        if not opts.get("unsafe", False):
            sandbox.remove_groups(tag)  # the grading's group (grading_group) and every sandbox's in it
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main(sys.argv[1:])
