#!/usr/bin/python3
"""Run one rubric criterion against a prepared submission tree; print one JSON line.

usage (by kit/grade.py, in its own process group with resource limits):
  kit/criterion.py SRC_DIR BUILD CRITERION_JSON SEED JOBS IMAGES_DIR

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
import importlib.util
import json
import os
import sys
import traceback

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import compare  # noqa: E402


def recorded():
    """What the criterion's runs recorded: tests/lib.py's lists (compare.py records there too)."""
    try:
        import lib
    except ImportError:
        return {"measured": [], "commands": [], "todos": []}
    return {"measured": lib.MEASURED[:200], "commands": lib.COMMANDS[:100], "todos": lib.TODOS}


def run_grade_test(src, build, c, seed):
    tests = os.path.join(src, "tests")
    sys.path.insert(0, tests)
    import lib
    lib.ROOT = src
    path = os.path.join(tests, c["module"] + ".py")
    spec = importlib.util.spec_from_file_location(c["module"], path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    if hasattr(module, "ROOT"):
        module.ROOT = src
    test = getattr(module, c["test"], None)
    if test is None:
        return False, None, f"no {c['test']} in tests/{c['module']}.py"
    lib.reset_record()
    try:
        test(lib.Context(build, seed=seed))  # grading seed 1 runs the tests' own fixed seeds
        return True, None, passed_message(lib.MEASURED)
    except AssertionError as e:
        return False, None, str(e)[:2000] or "assertion failed"
    except Exception as e:
        return False, None, failed_message(e)[:2000]


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


def main():
    src, build, criterion, seed, jobs, images = sys.argv[1:7]
    c = json.loads(criterion)
    rub = json.load(open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "rubric.json")))
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
