#!/usr/bin/python3
"""Run one rubric criterion against a prepared submission tree; print one JSON line.

usage (by kit/grade.py, in its own process group with resource limits):
  kit/criterion.py SRC_DIR BUILD CRITERION_JSON SEED JOBS IMAGES_DIR

SEED is the grading seed: compare criteria render batch b with SEED * 1000 + b;
grade criteria get it as lib.Context(build, seed=SEED), which shifts every
chapter seed the test uses (tests/lib.py shifted_seed; SEED 1 = the tests' own).

Prints {"passed": bool, "p_value": float|null, "message": str, "images": {...}}.
"""
import importlib.util
import json
import os
import sys
import traceback

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import compare  # noqa: E402


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
    try:
        test(lib.Context(build, seed=seed))  # grading seed 1 runs the tests' own fixed seeds
        return True, None, "passed"
    except AssertionError as e:
        return False, None, str(e)[:2000] or "assertion failed"
    except Exception:
        return False, None, traceback.format_exc()[-2000:]


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
        elif c["kind"] == "surfaces":
            out["passed"], out["p_value"], out["message"], out["images"] = compare.run_surfaces(src, build, c, rub)
        else:
            out["message"] = f"unknown kind {c['kind']}"
    except compare.CriterionFailed as e:
        out["message"] = str(e)
    except Exception:
        out["message"] = "grader error: " + traceback.format_exc()[-1500:]
    sys.stdout.flush()
    print("\n@@RESULT@@ " + json.dumps(out))


if __name__ == "__main__":
    main()
