#!/usr/bin/python3
"""Run one rubric criterion against a prepared submission tree; print one JSON line.

usage (by kit/grade.py, in its own process group, killed on the criterion's time-out):
  kit/criterion.py SRC_DIR BUILD CRITERION_JSON SEED JOBS IMAGES_DIR [SANDBOX_JSON]

This is the judge: it runs outside any sandbox, from the instructor's kit/ and tests/ (never the
submission's copy), and starts every program of the submission through tests/lib.py's
RUN_PROGRAM, which SANDBOX_JSON ({"binds": [[path, writable], ...], "scratch": DIR, "limits": {...},
"threads": N, "session": {...}}) makes a kit/sandbox.py sandbox: the submission's programs see the
graded tree read-only and the scratch directory where the tests write their scenes and the programs
their outputs, nothing else.  With "session" they run in the grading's sandbox (its runner starts
them; Session.client_spec), else each in a fresh one.  Without SANDBOX_JSON (kit/grade.py --unsafe) they run directly.

SEED is the grading seed: compare criteria render batch b with SEED * 1000 + b;
grade criteria get it as lib.Context(build, seed=SEED), which shifts every
chapter seed the test uses (tests/lib.py shifted_seed; SEED 1 = the tests' own).

Prints {"passed": bool, "p_value": float|null, "message": str, "images": {...},
         "measured": [...], "commands": [...], "todos": [...]} (and "preview" for a compare
criterion given an IMAGES_DIR: what its pictures show, kit/compare.py write_pictures):
measured: what the criterion compared, one dict per comparison with its sentence "text"
(tests/lib.py measurement; compare.py the same for images); commands: the chapter commands it ran
("build/01_local scenes/cornell.scene --size 16x16 ..."); todos: the stubs those runs reported
({"name", "file", "line"}, from "file:line: TODO name is not implemented" on their stderr).
"""
import contextlib
import importlib.util
import json
import os
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import traceback

KIT = os.path.dirname(os.path.abspath(__file__))
TESTS = os.path.join(os.path.dirname(KIT), "tests")  # the instructor's tests, never the submission's
sys.path.insert(0, KIT)
sys.path.insert(0, TESTS)
import compare  # noqa: E402
import lib  # noqa: E402
import sandbox  # noqa: E402


def recorded():
    """What the criterion's runs recorded: tests/lib.py's lists (compare.py records there too)."""
    try:
        import lib
    except ImportError:
        return {"measured": [], "commands": [], "todos": []}
    return {"measured": lib.MEASURED[:200], "commands": lib.COMMANDS[:100], "todos": lib.TODOS}


def run_grade_test(src, build, c, seed):
    lib.ROOT = src  # the programs and the scenes they read are the graded tree's
    path = os.path.join(TESTS, c["module"] + ".py")
    spec = importlib.util.spec_from_file_location(c["module"], path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    if hasattr(module, "ROOT"):
        module.ROOT = src
    test = getattr(module, c["test"], None)
    if test is None:
        return False, None, f"no {c['test']} in tests/{c['module']}.py"
    lib.reset_record()
    ctx = lib.Context(build, seed=seed)  # grading seed 1 runs the tests' own fixed seeds
    try:
        test(ctx)
        return True, None, passed_message(lib.MEASURED)
    except AssertionError as e:
        return False, None, str(e)[:2000] or "assertion failed"
    except Exception as e:
        return False, None, failed_message(e)[:2000]
    finally:
        ctx.close()  # the report holds what the student needs; a calibration of 60 seeds makes 60 of these


def passed_message(measured):
    """A passed test's message: how many comparisons agreed, and the one closest to its limit."""
    def room(m):  # the share of its allowed difference a comparison used (0 = exact)
        if m.get("allowed") is None or not isinstance(m.get("measured"), (int, float)) or \
                not isinstance(m.get("expected"), (int, float)):
            return -1.0  # not a comparison of two numbers (lib.expect)
        d = abs(m["measured"] - m["expected"])
        return d / m["limit"] if m.get("limit") else (0.0 if d == 0 else 1.0)
    if not measured:
        return "passed"
    closest = max(measured, key=room)
    if len(measured) == 1:
        return f"passed: {closest['text']}"
    return f"passed: {len(measured)} comparisons agree; the closest to its limit: {closest['text']}"


def failed_message(error):
    """A test that stopped on an error that is not a failed comparison: the error, and the test's
    line it came from (not the whole traceback)."""
    frames = [f for f in traceback.extract_tb(error.__traceback__) if "/tests/" in f.filename]
    where = f" at tests/{os.path.basename(frames[-1].filename)}:{frames[-1].lineno} ({frames[-1].line})" \
        if frames else ""
    return f"the test stopped: {type(error).__name__}: {error}{where}"


# ---- the submission's programs, sandboxed -----------------------------------------------------------

def lend_scratch(scratch, uid):
    """The test's scratch directories (tempfile.mkdtemp, the judge's) become the sandbox user's, so
    its programs can write their outputs there; the scratch root itself stays the judge's."""
    for name in os.listdir(scratch):
        path = os.path.join(scratch, name)
        try:
            info = os.lstat(path)
            if stat.S_ISDIR(info.st_mode) and info.st_uid != uid:
                os.chown(path, uid, uid)
        except FileNotFoundError:  # removed meanwhile (renders run two at a time)
            continue


def remove_strange_files(scratch):
    """Delete what a run left in scratch that is not a plain file or directory (a symbolic link to a
    file of the grader's, a FIFO, a socket): the judge reads scratch as root.  Their names."""
    removed = []
    for top, dirs, files in os.walk(scratch):
        for name in dirs + files:
            path = os.path.join(top, name)
            try:  # another run (renders run two at a time) may rename or remove its files meanwhile
                mode = os.lstat(path).st_mode
                if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
                    os.unlink(path)
                    removed.append(os.path.relpath(path, scratch))
            except FileNotFoundError:
                continue
        dirs[:] = [d for d in dirs if os.path.isdir(os.path.join(top, d)) and
                   not os.path.islink(os.path.join(top, d))]
    return removed


def sandboxed_runner(spec):
    """RUN_PROGRAM for tests/lib.py: the program inside a fresh sandbox (kit/sandbox.py)."""
    scratch = spec["scratch"]
    if spec.get("session"):  # the grading's sandbox (kit/sandbox.py Session): its runner starts the program
        box = sandbox.Client(spec["session"])
    else:
        box = sandbox.Sandbox([tuple(b) for b in spec["binds"]] + [(scratch, True)],
                              limits=sandbox.Limits(**spec["limits"]), threads=spec["threads"],
                              mode=spec.get("mode", "bwrap"), uid=spec.get("uid", sandbox.SANDBOX_UID))

    # The fallback (mode "user") ends a run by killing every process of its uid, which the grading's
    # runs share: there they run one at a time (compare criteria render two at once otherwise).
    one_at_a_time = threading.Lock() if spec.get("mode") == "user" else contextlib.nullcontext()

    def run(argv, cwd, timeout):
        lend_scratch(scratch, spec.get("uid", sandbox.SANDBOX_UID))
        with one_at_a_time:
            r = box.run(argv, cwd=cwd, timeout=timeout)
        notes = [f"stopped by the grader's sandbox: {r.stopped}"] if r.stopped else []
        removed = remove_strange_files(scratch)
        if removed:
            notes.append(f"the grader's sandbox removed what the run left that is not a plain file: "
                         f"{', '.join(removed[:5])}")
        if r.returncode is None and r.stopped.startswith("time-out"):
            raise subprocess.TimeoutExpired(argv, timeout, output=r.stdout, stderr=r.stderr)
        code = r.returncode if r.returncode is not None else -signal.SIGKILL
        stderr = r.stderr + "".join("\n" + n for n in notes)
        return subprocess.CompletedProcess(argv, code if not removed or code else 1, r.stdout, stderr)
    return run


def main():
    src, build, criterion, seed, jobs, images = sys.argv[1:7]
    if len(sys.argv) > 7:
        spec = json.loads(sys.argv[7])
        tempfile.tempdir = spec["scratch"]  # the tests' and compare's scratch directories go there
        lib.RUN_PROGRAM[0] = sandboxed_runner(spec)
    c = json.loads(criterion)
    rub = json.load(open(os.path.join(KIT, "rubric.json")))
    out = {"passed": False, "p_value": None, "message": "", "images": {}}
    try:
        if c["kind"] == "grade":
            out["passed"], out["p_value"], out["message"] = run_grade_test(src, build, c, int(seed))
        elif c["kind"] == "compare":
            (out["passed"], out["p_value"], out["message"],
             out["images"]) = compare.run_compare(src, build, c, rub, int(seed), int(jobs), images)
            out["preview"] = dict(compare.PREVIEW)  # what the pictures show, for their captions
        elif c["kind"] == "surfaces":
            out["passed"], out["p_value"], out["message"], out["images"] = compare.run_surfaces(src, build, c, rub)
        else:
            out["message"] = f"unknown kind {c['kind']}"
    except compare.CriterionFailed as e:
        out["message"] = str(e)
    except Exception:
        out["message"] = "grader error: " + traceback.format_exc()[-1500:]
    out.update(recorded())
    sys.stdout.flush()
    print("\n@@RESULT@@ " + json.dumps(out))


if __name__ == "__main__":
    main()
