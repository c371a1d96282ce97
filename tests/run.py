#!/usr/bin/python3
"""The test runner behind `make test`.

usage: tests/run.py [-k TEXT] BUILD_DIR [BUILD_DIR ...]   (e.g. build build/asan)

  -k TEXT     run only the grading tests whose full name contains TEXT
              (BUILD:grade_MODULE:test_NAME); the C unit tests are skipped
  -h, --help  this text

For every build directory it runs
  1. the C unit tests build/tests/test_*  (lines "ok   name" / "FAIL name: ...")
  2. the grading tests tests/grade_*.py    (functions test_*(ctx))
and ends with the line "N passed, N failed".  Exit status 1 if anything failed.
"""
import glob
import importlib.util
import os
import shutil
import subprocess
import sys
import time
import traceback

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import lib  # noqa: E402

SANITIZER_ENV = {
    "ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0:exitcode=99",
    "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1:exitcode=99",
}


def run_unit_tests(build, report):
    for exe in sorted(glob.glob(os.path.join(lib.ROOT, build, "tests", "test_*"))):
        if exe.endswith(".d") or not os.access(exe, os.X_OK):
            continue
        name = os.path.basename(exe)
        start = time.time()
        try:
            result = subprocess.run([exe], cwd=lib.ROOT, capture_output=True, text=True, timeout=900,
                                    stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            report(f"{build}:{name}", False, "timed out")
            continue
        seen = 0
        for line in result.stdout.splitlines():
            if line.startswith("ok   "):
                report(f"{build}:{name}:{line[5:]}", True, "")
                seen += 1
            elif line.startswith("FAIL "):
                report(f"{build}:{name}:{line[5:].split(':', 1)[0]}", False, line[5:])
                seen += 1
        if result.returncode != 0 or seen == 0:
            report(f"{build}:{name}", False,
                   f"exit status {result.returncode} after {time.time() - start:.1f} s\n{result.stderr[-3000:]}")


def run_grading_tests(build, report, only):
    for path in sorted(glob.glob(os.path.join(lib.ROOT, "tests", "grade_*.py"))):
        module_name = os.path.splitext(os.path.basename(path))[0]
        spec = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        for name in sorted(n for n in dir(module) if n.startswith("test_")):
            full = f"{build}:{module_name}:{name}"
            if only and only not in full:
                continue
            ctx = lib.Context(build)
            start = time.time()
            try:
                getattr(module, name)(ctx)
                report(full, True, f"{time.time() - start:.1f} s")
                shutil.rmtree(ctx.scratch, ignore_errors=True)  # a failed test's files are kept to look at
            except Exception as e:  # an AssertionError is a failed grade; anything else too
                detail = str(e) if isinstance(e, AssertionError) else traceback.format_exc()
                report(full, False, f"{detail}\n     (its files: {ctx.scratch})")


def main():
    args = sys.argv[1:]
    if "-h" in args or "--help" in args:
        print(__doc__.strip())
        return
    unknown = [a for a in args if a.startswith("-") and a != "-k"]
    if unknown or args[-1:] == ["-k"]:
        print(f"tests/run.py: bad arguments {' '.join(unknown) or '-k without TEXT'} (see --help)", file=sys.stderr)
        sys.exit(2)
    only = None
    if "-k" in args:
        i = args.index("-k")
        only = args[i + 1]
        del args[i:i + 2]
    builds = args or ["build"]
    counts = {"passed": 0, "failed": 0}

    def report(name, ok, detail):
        counts["passed" if ok else "failed"] += 1
        if ok:
            print(f"ok   {name}" + (f"  ({detail})" if detail else ""), flush=True)
        else:
            print(f"FAIL {name}: {detail}", flush=True)

    # OpenMP threads that spin while they wait for work take the CPU from the other tests' programs
    # on a loaded 2-core machine (chapter 5: 1.3 s of CPU at 64 passes spinning, 0.05 s passive).
    os.environ.setdefault("OMP_WAIT_POLICY", "passive")
    for build in builds:
        if "asan" in build:
            os.environ.update(SANITIZER_ENV)
        if not only:
            run_unit_tests(build, report)
        run_grading_tests(build, report, only)
    print(f"{counts['passed']} passed, {counts['failed']} failed")
    sys.exit(1 if counts["failed"] else 0)


if __name__ == "__main__":
    main()
