#!/usr/bin/python3
"""The test runner behind `make test`.

usage: tests/run.py [-k TEXT] [-j N] [--cluster] [--save-durations] BUILD_DIR [BUILD_DIR ...]   (e.g. build build/asan)

  -k TEXT     run only the grading tests whose full name contains TEXT
              (BUILD:grade_MODULE:test_NAME); the C unit tests are skipped
  --cluster   run the class-scale tests instead (the instructor's tests named "cluster_" here: hosts over
              ssh, Slurm, the Gradescope container; `make test-cluster`; long, so not part of `make test`)
  -j N        run N tests at a time (default: one more than the CPUs this process may use, at most 4,
              and up to two more while the machine leaves half a core idle)
  --save-durations  write each grading test's time into tests/durations.json (the order of the next runs)
  -h, --help  this text

For every build directory it runs
  1. the C unit tests build/tests/test_*  (lines "ok   name" / "FAIL name: ...")
  2. the grading tests tests/grade_*.py    (functions test_*(ctx))
and ends with the line "N passed, N failed".  Exit status 1 if anything failed.  A grading test's
"ok" line gives its wall time and its CPU seconds (its programs' and sandboxes' included): what it costs
make test's budget, which its wall time, stretched by whatever ran beside it, does not say.

Tests run longest first (tests/durations.json: the seconds each took when last saved, 5 for a
test not there), so that no worker is left with a long one at the end.  Tests run side by side (-j):
most of them wait on one-threaded work (a Python check, a compiler, a sandbox, a short render) part
of the time: two at a time kept a 2-core machine 1.6 cores busy on average (a fresh clone's `make
test`: 26.6 CPU minutes in 16.5), and so did three (1407 CPU s in 14:02), so one more than the CPUs
run at once, and another (at most two more) whenever the machine has left over half a core idle for
a second since the last one started (IDLE_FOR_ANOTHER).  Each sequence of tests runs in a process of
its own.  Every test has its own scratch directory.  A module says what else it needs:
  RUN_IN_SEQUENCE = True  its tests share files outside their scratch (the decks in build/slides that
                          the sanitizer pass reuses): over all build directories they run one after
                          another in one worker, in the order given;
  RUN_ALONE = {names}     (or True: every test of the module) these tests check what the whole
                          machine holds afterwards (no temporary directory, cgroup or process left
                          by a grading, the instructor's tree unchanged): they run first, one at a
                          time, beside only C unit tests and tests of modules that say
                          GRADES_NOTHING = True; the module's other tests run side by side;
  a function tear_down    called with no arguments after the sequence that ran the module's tests, in
                          the process that ran them (a module's cache of handouts: a sequence's
                          process ends with os._exit, which runs no atexit handler).
"""
import glob
import importlib.util
import json
import multiprocessing
import os
import queue
import re
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
PLAIN_ENV = {key: os.environ.get(key) for key in SANITIZER_ENV}


def use_environment_of(build):
    """The sanitizer options for a build/asan test, the caller's environment for any other."""
    for key, value in (SANITIZER_ENV if "asan" in build else PLAIN_ENV).items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


def run_unit_test(build, exe):
    """One C unit-test executable: [(name, ok, detail)] for its ok/FAIL lines."""
    name = os.path.basename(exe)
    start = time.time()
    try:
        result = subprocess.run([exe], cwd=lib.ROOT, capture_output=True, text=True, timeout=900,
                                stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return [(f"{build}:{name}", False, "timed out")]
    results = []
    for line in result.stdout.splitlines():
        if line.startswith("ok   "):
            results.append((f"{build}:{name}:{line[5:]}", True, ""))
        elif line.startswith("FAIL "):
            results.append((f"{build}:{name}:{line[5:].split(':', 1)[0]}", False, line[5:]))
    if result.returncode != 0 or not results:
        results.append((f"{build}:{name}", False,
                        f"exit status {result.returncode} after {time.time() - start:.1f} s\n{result.stderr[-3000:]}"))
    return results


def run_grading_test(build, module, name):
    """One test function: [(name, ok, detail)]."""
    full = f"{build}:{module.__name__}:{name}"
    ctx = lib.Context(build)
    start, cpu = time.time(), cpu_seconds()
    try:
        getattr(module, name)(ctx)
        ctx.close()  # a failed test's files are kept to look at
        return [(full, True, f"{time.time() - start:.1f} s, {cpu_seconds() - cpu:.1f} CPU s")]
    except Exception as e:  # an AssertionError is a failed grade; anything else too
        detail = str(e) if isinstance(e, AssertionError) else traceback.format_exc()
        where = f"\n     (its files: {ctx.made_scratch})" if ctx.made_scratch else ""
        return [(full, False, detail + where)]


def cpu_seconds():
    """CPU time of this process and the children it has waited for (the programs a test ran, sandboxes
    included): a test's own cost, which its wall time under load is not (make test's budget is CPU bound)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def load_modules(prefix):
    modules = []
    for path in sorted(glob.glob(os.path.join(lib.ROOT, "tests", prefix + "*.py"))):
        module_name = os.path.splitext(os.path.basename(path))[0]
        spec = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        modules.append(module)
    return modules


def plan(builds, only, cluster):
    """The work as (side by side, alone): lists of sequences, each a list of (function, build,
    *arguments) run in order."""
    modules = load_modules("cluster_" if cluster else "grade_")
    in_sequence = {m.__name__: [] for m in modules if getattr(m, "RUN_IN_SEQUENCE", False)}
    by_itself, single = [], []
    for build in builds:
        if not only and not cluster:
            for exe in sorted(glob.glob(os.path.join(lib.ROOT, build, "tests", "test_*"))):
                if not exe.endswith(".d") and os.access(exe, os.X_OK):
                    single.append([(run_unit_test, build, exe)])
        for module in modules:
            for name in sorted(n for n in dir(module) if n.startswith("test_")):
                if only and only not in f"{build}:{module.__name__}:{name}":
                    continue
                task = (run_grading_test, build, module, name)
                alone = getattr(module, "RUN_ALONE", ())
                if alone is True or name in alone:
                    by_itself.append([task])
                elif module.__name__ in in_sequence:
                    in_sequence[module.__name__].append(task)
                else:
                    single.append([task])
    side_by_side = [s for s in in_sequence.values() if s] + single
    known = saved_durations()
    side_by_side.sort(key=lambda sequence: -sum(known.get(task_name(task), UNKNOWN_SECONDS) for task in sequence))
    return side_by_side, by_itself


DURATIONS = os.path.join(lib.ROOT, "tests", "durations.json")
UNKNOWN_SECONDS = 5.0


def task_name(task):
    function, build, *arguments = task
    if function is run_unit_test:
        return f"{build}:{os.path.basename(arguments[0])}"
    return f"{build}:{arguments[0].__name__}:{arguments[1]}"


def saved_durations():
    try:
        with open(DURATIONS) as f:
            return json.load(f)
    except (OSError, ValueError):
        return {}


def save_durations(measured):
    """Merge this run's times (seconds, one decimal) into tests/durations.json."""
    durations = dict(saved_durations(), **measured)
    with open(DURATIONS + ".partial", "w") as f:
        json.dump(dict(sorted(durations.items())), f, indent=0)
        f.write("\n")
    os.replace(DURATIONS + ".partial", DURATIONS)


def run_sequence(sequence):
    results = []
    try:
        for function, build, *arguments in sequence:
            use_environment_of(build)
            results += function(build, *arguments)
    finally:
        for module in dict.fromkeys(arguments[0] for function, _, *arguments in sequence
                                    if function is run_grading_test):
            if hasattr(module, "tear_down"):
                module.tear_down()
    return results


def run_in_child(index, results):
    try:
        results.put((index, run_sequence(SEQUENCES[index])))
    except BaseException:  # never leave the runner waiting for a sequence that died
        results.put((index, [(f"sequence {index}", False, traceback.format_exc())]))


SEQUENCES = []
# Another test starts beside the usual number when the machine left this much of a core idle over a second.
# Fresh clones' make test, idle 2-core machine: 11:15 at 0.7 (three running almost throughout, 1.76 cores
# busy), 10:33 and 11:12 at 0.5 (1.75): no difference the runs can show.
IDLE_FOR_ANOTHER = 0.5


class IdleCores:
    """How many cores the whole machine left idle since the last look (/proc/stat: idle and iowait
    jiffies over all jiffies, times the cores), or None before two looks or where there is no /proc/stat."""

    def __init__(self):
        self.last = self.read()

    @staticmethod
    def read():
        try:
            with open("/proc/stat") as f:
                words = f.readline().split()
            values = [int(w) for w in words[1:]]
            return sum(values), values[3] + values[4]
        except (OSError, ValueError, IndexError):
            return None

    def since_last(self):
        now, last = self.read(), self.last
        self.last = now
        if now is None or last is None or now[0] <= last[0]:
            return None
        return (now[1] - last[1]) / (now[0] - last[0]) * os.cpu_count()


def beside_alone(sequence):
    """Whether the sequence may run beside the RUN_ALONE tests: C unit tests, and tests of modules
    that say GRADES_NOTHING (no grading, no handout: none of the files, cgroups or processes the
    RUN_ALONE tests look for, nothing written in the instructor's tree)."""
    return all(function is run_unit_test or getattr(arguments[0], "GRADES_NOTHING", False)
               for function, build, *arguments in sequence)


def run_all(sequences, alone, jobs, report, most=None):
    """Run the RUN_ALONE tests (alone: one sequence) first, one after another, beside only sequences
    that may run beside them (beside_alone), and the other sequences, each in a process of its own,
    `jobs` at a time (longest first: the order given), and more, up to `most`, while the machine leaves
    cores idle: most tests wait part of the time (a compiler, a sandbox starting, a Python check).  An
    extra test starts only after a second with over IDLE_FOR_ANOTHER cores idle, one at a time; a
    machine busy with other work never gets more than `jobs`."""
    SEQUENCES[:] = ([alone] if alone else []) + sequences
    if jobs == 1:
        for sequence in SEQUENCES:
            for result in run_sequence(sequence):
                report(*result)
        return
    fork = multiprocessing.get_context("fork")  # the children inherit the loaded test modules
    results, pending, running = fork.Queue(), list(range(len(SEQUENCES))), {}
    alone_index = 0 if alone else None
    idle, spare, looked = IdleCores(), None, time.monotonic()  # spare: idle cores over the last look's second
    while pending or running:
        if time.monotonic() - looked >= 1.0:
            spare, looked = idle.since_last(), time.monotonic()
        extra = len(running) < (most or jobs) and spare is not None and spare > IDLE_FOR_ANOTHER
        alone_busy = alone_index in running or alone_index in pending
        allowed = [i for i in pending if not alone_busy or i == alone_index or beside_alone(SEQUENCES[i])]
        if allowed and (len(running) < jobs or extra):
            index = allowed[0]
            pending.remove(index)
            running[index] = fork.Process(target=run_in_child, args=(index, results), daemon=True)
            running[index].start()
            idle.since_last()  # the next look covers only the time since this start
            spare, looked = None, time.monotonic()
            continue
        try:
            index, finished = results.get(timeout=1.0)
        except queue.Empty:
            continue
        for result in finished:
            report(*result)
        running.pop(index).join()


def parse_arguments(args):
    if "-h" in args or "--help" in args:
        print(__doc__.strip())
        sys.exit(0)
    options = {"-k": None, "-j": None}
    rest, flags = [], set()
    while args:
        word = args.pop(0)
        if word in ("--cluster", "--save-durations"):
            flags.add(word)
        elif word in options:
            if not args:
                bad(f"{word} without a value")
            options[word] = args.pop(0)
        elif word.startswith("-"):
            bad(word)
        else:
            rest.append(word)
    if options["-j"] is not None and (not options["-j"].isdigit() or not 1 <= int(options["-j"]) <= 64):
        bad(f"-j {options['-j']} (a number of tests at a time, 1 to 64)")
    return options["-k"], options["-j"] and int(options["-j"]), flags, rest or ["build"]


def bad(what):
    print(f"tests/run.py: bad arguments: {what} (see --help)", file=sys.stderr)
    sys.exit(2)


def main():
    only, jobs, flags, builds = parse_arguments(sys.argv[1:])
    most = None  # -j N: N at a time; by default one more than the CPUs, and up to two more on idle cores
    if jobs is None:
        jobs = min(4, len(os.sched_getaffinity(0)) + 1)
        most = jobs + 2
    cluster = "--cluster" in flags
    counts = {"passed": 0, "failed": 0}
    measured = {}

    def report(name, ok, detail):
        counts["passed" if ok else "failed"] += 1
        seconds = re.fullmatch(r"([0-9.]+) s(, [0-9.]+ CPU s)?", detail or "")
        if seconds:
            measured[name] = float(seconds.group(1))
        if ok:
            print(f"ok   {name}" + (f"  ({detail})" if detail else ""), flush=True)
        else:
            print(f"FAIL {name}: {detail}", flush=True)

    # OpenMP threads that spin while they wait for work take the CPU from the other tests' programs
    # on a loaded 2-core machine (chapter 5: 1.3 s of CPU at 64 passes spinning, 0.05 s passive).
    os.environ.setdefault("OMP_WAIT_POLICY", "passive")
    side_by_side, by_itself = plan(builds, only, cluster)
    run_all(side_by_side, [task for sequence in by_itself for task in sequence], jobs, report, most)
    if "--save-durations" in flags:
        save_durations(measured)
    print(f"{counts['passed']} passed, {counts['failed']} failed")
    sys.exit(1 if counts["failed"] else 0)


if __name__ == "__main__":
    main()
