"""Grading untrusted code: hostile submissions against kit/grade.py's sandbox (kit/sandbox.py).

Each probe is a small change a student who wants a better grade (or a classmate's worse one)
could hand in: chapter 1's solution with a constructor (run before main) that attacks the
grader, or a submission tree the kit must refuse.  For each: the criterion is graded as the
rubric says, the report names what was stopped, and afterwards the instructor's tree is
byte-identical, no process of the submission is left, another student's report is unchanged, and
no temporary directory or cgroup of the grading is left.  The gradings use a one-criterion rubric
(the chapter-1 pixel under a point light), so each costs one build of chapter 1.
These tests check the kit, not the C code: they run with the plain build only.
"""
import hashlib
import json
import os
import re
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time

import lib

ROOT = lib.ROOT
GRADE = [sys.executable, os.path.join(ROOT, "kit", "grade.py")]
CHAPTER = "chapters/01_local.c"
SECRET = os.path.join(ROOT, "kit", "rubric.json")  # what a submission must never read or change
SECRET_LINE = "The grading rubric (kit/grade.py"        # a line of it that must not reach a report


def instructor_checksums():
    """sha256 of every file of the instructor's tree that grading could touch."""
    digest = {}
    for top in ("kit", "tests", "chapters", "common", "scenes", "Makefile", "viewer"):
        path = os.path.join(ROOT, top)
        walk = [(path, [], [""])] if os.path.isfile(path) else os.walk(path)
        for d, dirs, files in walk:
            dirs[:] = [x for x in dirs if x != "__pycache__"]
            for f in files:
                p = os.path.join(d, f) if f else d
                with open(p, "rb") as fh:
                    digest[os.path.relpath(p, ROOT)] = hashlib.sha256(fh.read()).hexdigest()
    return digest


# The hostile tests check that a grading leaves no temporary directory, cgroup or process (their
# submission's `sleep 7777`) and changes nothing in the instructor's tree, so no other test may run
# beside them (tests/run.py -j); the others run side by side (a fallback grading has a uid of its own).
RUN_ALONE = {"test_hostile_submission_is_contained", "test_the_fallback_sandbox_contains_the_hostile_submission"}


def leftovers():
    """Temporary directories and cgroups a grading makes (and must remove)."""
    tmp = {n for n in os.listdir(tempfile.gettempdir()) if n.startswith(("gi-grade-", "gi-kit-out-", "gi-kit-t"))}
    groups = set()
    for top in ("/sys/fs/cgroup/pids", "/sys/fs/cgroup"):
        if os.path.isdir(top):
            groups |= {n for n in os.listdir(top) if n.startswith("gi-sandbox-")}
    return tmp, groups


def rubric_file(ctx):
    """A rubric of one quick criterion of chapter 1 (kit/rubric.json's own row)."""
    with open(SECRET) as f:
        rub = json.load(f)
    rub["criteria"] = [c for c in rub["criteria"] if c["name"] == "point light pixel is R1"]
    return ctx.write("rubric.json", json.dumps(rub))


def submission(ctx, name, constructor="", extra_files=None, before_includes=""):
    """A submission directory: chapter 1's solution with `constructor` (C statements) run before
    main, `before_includes` at its top, and extra files {relative path: text}."""
    top = ctx.path(name)
    os.makedirs(os.path.join(top, "chapters"))
    with open(os.path.join(ROOT, CHAPTER)) as f:
        text = f.read()
    if constructor:
        text += ("\n#include <dirent.h>\n#include <fcntl.h>\n#include <signal.h>\n#include <stdio.h>\n"
                 "#include <stdlib.h>\n#include <string.h>\n#include <sys/socket.h>\n#include <sys/wait.h>\n#include <netinet/in.h>\n"
                 "#include <unistd.h>\nextern char **environ;\nstatic char stats_output[512];\n"
                 f"static void link_output(void) {{ unlink(stats_output); symlink({c_string(SECRET)}, stats_output); }}\n"
                 "__attribute__((constructor)) static void hostile_probe(int argc, char **argv)\n{\n"
                 "    (void)argc, (void)argv;\n" + constructor + "\n}\n")
    with open(os.path.join(top, CHAPTER), "w") as f:
        f.write(before_includes + text)
    for rel, content in (extra_files or {}).items():
        os.makedirs(os.path.dirname(os.path.join(top, rel)), exist_ok=True)
        with open(os.path.join(top, rel), "w") as f:
            f.write(content)
    return top


def grade(ctx, sub, report, *extra, timeout=600):
    r = subprocess.run(GRADE + [sub, "--report", report, "--chapters", "01_local", "--rubric", rubric_file(ctx),
                                *extra], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    return r


def read_report(report):
    with open(os.path.join(report, "report.json")) as f:
        return json.load(f)


def c_string(s):
    return json.dumps(s)


# The attacks of one submission, each a few lines of C run as the chapter starts (see the module).
def hostile_constructor(victim_report):
    return f"""
    /* 1. fake result lines into every stdout it can open, then kill its parent and everything */
    DIR *proc = opendir("/proc");
    for (struct dirent *e; proc && (e = readdir(proc));) {{
        char path[300];
        snprintf(path, sizeof path, "/proc/%s/fd/1", e->d_name);
        FILE *f = fopen(path, "w");
        if (f) fprintf(f, "\\n@@RESULT@@ {{\\"passed\\": true, \\"p_value\\": null, \\"message\\": \\"forged\\"}}\\n"),
               fclose(f);
    }}
    if (proc) closedir(proc);
    /* 2. read and change the instructor's files, a classmate's report */
    const char *targets[] = {{{c_string(SECRET)}, "/proc/1/root{SECRET}", {c_string(victim_report)}}};
    for (int i = 0; i < 3; i++) {{
        char line[200] = "";
        FILE *f = fopen(targets[i], "r");
        if (f && fgets(line, sizeof line, f)) fprintf(stderr, "LEAK %s\\n", line);
        if (f) fclose(f);
        f = fopen(targets[i], "a");
        if (f) fprintf(stderr, "WROTE %s\\n", targets[i]), fputs("{{}}", f), fclose(f);
    }}
    /* 4. the network */
    int s = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = {{.sin_family = AF_INET, .sin_port = htons(22), .sin_addr = {{htonl(0x7f000001)}}}};
    if (s >= 0 && connect(s, (struct sockaddr *)&a, sizeof a) == 0) fprintf(stderr, "NET connected\\n");
    /* 5. a process that outlives the grading and then rewrites the classmate's report */
    if (fork() == 0) {{
        setsid();
        if (fork() == 0) execl("/bin/sh", "sh", "-c",
                               "sleep 4; echo 0 > " {c_string(victim_report)} "; exec sleep 7777", (char *)0);
        _exit(0);
    }}
    /* 6. the output replaced by a link to the rubric when the chapter is done (the judge is root) */
    for (int i = 1; i + 1 < argc; i++)
        if (!strcmp(argv[i], "--stats"))
            snprintf(stats_output, sizeof stats_output, "%s", argv[i + 1]), atexit(link_output);
    kill(getppid(), SIGKILL);
    /* 3. the environment, last, so it is in the message's tail */
    fprintf(stderr, "ENVNAMES");
    for (char **e = environ; *e; e++) fprintf(stderr, " %.*s", (int)strcspn(*e, "="), *e);
    fprintf(stderr, " END\\n");
"""


def test_hostile_submission_is_contained(ctx):
    """One hostile and one honest student graded as a class: the hostile one forges nothing, reads
    and changes nothing of the grader's or the classmate's, leaves nothing behind."""
    if "asan" in ctx.build:
        return
    before, (tmp_before, groups_before) = instructor_checksums(), leftovers()
    honest = submission(ctx, "honest")
    victim_dir = ctx.path("reports")
    os.makedirs(victim_dir)
    honest_report = os.path.join(victim_dir, "honest")
    r = grade(ctx, honest, honest_report)
    assert r.returncode == 0, f"grading the honest submission: exit {r.returncode}: {r.stderr[-800:]}"
    with open(os.path.join(honest_report, "report.json"), "rb") as f:
        honest_bytes = f.read()
    assert read_report(honest_report)["total"] == 10, f"the honest submission: {read_report(honest_report)}"

    hostile = submission(ctx, "hostile", hostile_constructor(os.path.join(honest_report, "report.json")), {
        "common/evil.c": '#include <stdio.h>\n__attribute__((constructor)) static void f(void) '
                         '{ puts("ok   everything"); }\n',
        "viewer/viewer.mk": f"$(shell touch {ctx.path('viewer-mk-ran')})\n",
        "Makefile": f"all:\n\ttouch {ctx.path('makefile-ran')}\n"})
    hostile_report = ctx.path("hostile-report")
    r = grade(ctx, hostile, hostile_report)
    time.sleep(6)  # the detached process would have written by now
    assert r.returncode == 0, f"grading the hostile submission: exit {r.returncode}: {r.stderr[-800:]}"
    report = read_report(hostile_report)
    text = json.dumps(report)
    row = report["criteria"][0]
    assert not row["passed"] and report["total"] == 0, \
        f"the hostile submission's output is a link, not an image: it must fail, got {row}"
    assert "not a plain file" in row["message"] or "sandbox" in row["message"], \
        f"the message must name what the sandbox stopped: {row['message']!r}"
    assert row["message"] != "forged", "a forged result line was taken"
    assert "LEAK" not in text and "WROTE" not in text and SECRET_LINE not in text, \
        f"the submission read or wrote a grader's file: {text[:1500]}"
    assert "NET connected" not in text, "the submission reached the network"
    assert "ENVNAMES" in row["message"], f"the run's stderr should be in the message: {row['message']!r}"
    names = set(row["message"].split("ENVNAMES")[1].split("END")[0].split())
    assert names <= {"PATH", "HOME", "LANG", "OMP_NUM_THREADS", "OMP_WAIT_POLICY", "PWD"}, f"the sandbox's environment leaks {names}"
    for marker in ("viewer-mk-ran", "makefile-ran"):
        assert not os.path.exists(ctx.path(marker)), f"the submission's {marker[:-4]} ran at build time"
    with open(os.path.join(honest_report, "report.json"), "rb") as f:
        assert f.read() == honest_bytes, "the classmate's report changed after the hostile grading"
    left = subprocess.run(["pgrep", "-f", "sleep 7777"], capture_output=True, text=True).stdout.split()
    assert not left, f"processes of the hostile submission outlived its grading: {left}"
    after = instructor_checksums()
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    assert not changed, f"the instructor's tree changed: {changed[:10]}"
    tmp_after, groups_after = leftovers()
    assert tmp_after <= tmp_before and groups_after <= groups_before, \
        f"the grading left {sorted(tmp_after - tmp_before)} {sorted(groups_after - groups_before)}"


def test_the_fallback_sandbox_contains_the_hostile_submission(ctx):
    """--sandbox user (Gradescope's Docker: no user namespaces) hides no file, so what a submission
    may not read must be unreadable to others there (the archive's set-up does it); the rest holds
    as under bubblewrap: no forged result, no classmate's report changed, nothing left running, no
    connection to a host listener (TCP or unix), no file left in /tmp, /var/tmp or /dev/shm."""
    if "asan" in ctx.build:
        return
    victim_dir = ctx.path("fallback-reports")
    os.makedirs(victim_dir)
    victim = os.path.join(victim_dir, "report.json")
    with open(victim, "w") as f:
        f.write('{"total": 100}')
    os.chmod(victim, 0o644)
    # Without a network namespace: a TCP listener on the host's loopback and a unix socket anyone
    # may connect to, both waiting; without a private /tmp: files left in the shared places.
    tcp = socket.socket()
    tcp.bind(("127.0.0.1", 0))
    tcp.listen()
    unix_dir = ctx.path("unix")
    os.makedirs(unix_dir)
    os.chmod(ctx.path(""), 0o755)
    os.chmod(unix_dir, 0o777)
    unix_path = os.path.join(unix_dir, "listener")
    unix = socket.socket(socket.AF_UNIX)
    unix.bind(unix_path)
    os.chmod(unix_path, 0o777)
    unix.listen()
    left_files = [f"{place}/gi-hostile-left-{os.getpid()}" for place in ("/tmp", "/var/tmp", "/dev/shm")]
    probe = f"""
    /* 7. the host's listeners, TCP and unix; files in the shared temporary places */
    int t = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in b = {{.sin_family = AF_INET, .sin_port = htons({tcp.getsockname()[1]}),
                            .sin_addr = {{htonl(0x7f000001)}}}};
    if (t >= 0 && connect(t, (struct sockaddr *)&b, sizeof b) == 0) fprintf(stderr, "NET connected tcp\\n");
    int u = socket(AF_UNIX, SOCK_STREAM, 0);
    struct sockaddr_un c = {{.sun_family = AF_UNIX}};
    snprintf(c.sun_path, sizeof c.sun_path, "%s", {c_string(unix_path)});
    if (u >= 0 && connect(u, (struct sockaddr *)&c, sizeof c) == 0) fprintf(stderr, "NET connected unix\\n");
    const char *places[] = {{{", ".join(c_string(f) for f in left_files)}}};
    for (int i = 0; i < 3; i++) {{
        FILE *f = fopen(places[i], "w");
        if (f) fputs("left", f), fclose(f);
    }}
"""
    hostile = submission(ctx, "fallback-hostile", probe + hostile_constructor(victim),
                         before_includes="#include <sys/un.h>\n")
    report_dir = ctx.path("fallback-report")
    r = grade(ctx, hostile, report_dir, "--sandbox", "user")
    time.sleep(6)  # the detached process would have written by now
    for listener in (tcp, unix):
        listener.setblocking(False)
        try:
            listener.accept()
            raise AssertionError(f"the fallback's submission connected to the host's {listener.family.name} listener")
        except BlockingIOError:
            pass
        finally:
            listener.close()
    left = [f for f in left_files if os.path.exists(f)]
    for f in left:
        os.unlink(f)
    assert not left, f"the fallback's grading left the submission's files behind: {left}"
    assert r.returncode == 0, f"grading with --sandbox user: exit {r.returncode}: {r.stderr[-800:]}"
    report = read_report(report_dir)
    row = report["criteria"][0]
    assert not row["passed"] and report["total"] == 0 and row["message"] != "forged", row
    assert "a separate user" in report["sandbox"], report["sandbox"]
    assert "WROTE" not in json.dumps(report), f"the submission wrote a grader's file: {row['message'][:600]}"
    with open(victim) as f:
        assert f.read() == '{"total": 100}', "the classmate's report changed"
    left = subprocess.run(["pgrep", "-f", "sleep 7777"], capture_output=True, text=True).stdout.split()
    assert not left, f"processes of the hostile submission outlived its grading: {left}"


def test_a_killed_grading_leaves_no_scratch_to_read(ctx):
    """A grading's scratch directory (the tree it builds, its outputs) is the grader's and its sandbox
    uid's only while it runs; a grading ended by SIGTERM removes it, and one ended by SIGKILL (which
    cannot be caught) leaves it to the next grading, which removes it before it starts; so with
    the grading's cgroup (its memory cap), once no process is left in it."""
    if "asan" in ctx.build:
        return
    honest = submission(ctx, "scratch-honest")
    top = tempfile.gettempdir()
    memory = "/sys/fs/cgroup/memory" if os.path.isdir("/sys/fs/cgroup/memory") else "/sys/fs/cgroup"

    def grading_groups(pid):  # kit/sandbox.py GradingGroup: gi-sandbox-PID-SECONDS
        return [n for n in os.listdir(memory) if n.startswith(f"gi-sandbox-{pid}-") and n.count("-") == 3]

    def start_and_wait(name):
        p = subprocess.Popen(GRADE + [honest, "--report", ctx.path(name), "--chapters", "01_local", "--rubric",
                                      rubric_file(ctx)], cwd=ROOT, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True)
        prefix = f"gi-grade-{p.pid}-"
        for _ in range(600):
            mine = [n for n in os.listdir(top) if n.startswith(prefix)]
            if mine and os.path.isdir(os.path.join(top, mine[0], "scratch")):
                return p, os.path.join(top, mine[0])
            time.sleep(0.05)
        p.kill()
        raise AssertionError(f"no scratch directory {prefix}* appeared")

    p, work = start_and_wait("terminated")
    mode = stat.S_IMODE(os.stat(work).st_mode)
    assert mode & 0o007 == 0, f"the scratch directory {work} is open to others: {oct(mode)}"
    os.killpg(p.pid, signal.SIGTERM)
    p.wait(timeout=60)
    assert not os.path.exists(work), f"a grading ended by SIGTERM left {work}"
    assert not grading_groups(p.pid), f"a grading ended by SIGTERM left its cgroup {grading_groups(p.pid)}"
    p, killed_work = start_and_wait("killed")
    killed = p.pid
    assert grading_groups(killed), "a running grading has a cgroup of its own (its memory cap)"
    os.killpg(p.pid, signal.SIGKILL)
    p.wait(timeout=60)
    assert os.path.exists(killed_work), "SIGKILL cannot be caught: its scratch is left for the next grading"
    # its sandbox dies with it (bwrap --die-with-parent), though not at once on a loaded machine: the next
    # grading removes only groups that hold no process, so wait (at most a minute) until they hold none
    deadline = time.time() + 60
    while time.time() < deadline and any(
            open(os.path.join(d, "cgroup.procs")).read().split() for g in grading_groups(killed)
            for d, _, _ in os.walk(os.path.join(memory, g)) if os.path.exists(os.path.join(d, "cgroup.procs"))):
        time.sleep(0.2)
    p, work = start_and_wait("next")
    os.killpg(p.pid, signal.SIGTERM)
    p.wait(timeout=60)
    assert not os.path.exists(killed_work), f"the next grading did not remove the killed one's {killed_work}"
    assert not grading_groups(killed), f"the next grading did not remove the killed one's {grading_groups(killed)}"
    assert not os.path.exists(work), f"a grading ended by SIGTERM left {work}"


def test_caps_stop_fork_bombs_memory_and_huge_files(ctx):
    """A fork bomb, a 2 GiB file, 3 GiB of memory: the sandbox's caps (processes, file size,
    memory) stop each, the criterion fails and says which cap stopped the run."""
    if "asan" in ctx.build:
        return
    bomb = """
    int children = 0;
    for (int i = 0; i < 5000; i++) {
        pid_t p = fork();
        if (p == 0)
            _exit(0);
        if (p < 0)
            break;
        children++;
    }
    while (wait(NULL) > 0)
        continue;
    fprintf(stderr, "FORKED %d\\n", children);
    signal(SIGXFSZ, SIG_IGN);
    int fd = open("/tmp/huge", O_WRONLY | O_CREAT | O_TRUNC, 0644);
    static char block[1 << 20];
    long written = 0;
    for (int i = 0; fd >= 0 && i < 2048; i++) {
        ssize_t n = write(fd, block, sizeof block);
        if (n <= 0)
            break;
        written += n;
    }
    fprintf(stderr, "WRITTEN %ld\\n", written);
    volatile char *m = malloc(3L << 30); /* volatile: the stores are not optimised away */
    for (long j = 0; m && j < (3L << 30); j += 4096)
        m[j] = 1;
"""
    sub = submission(ctx, "bomb", bomb)
    report_dir = ctx.path("bomb-report")
    start = time.time()
    r = grade(ctx, sub, report_dir, "--memory", "1024")
    assert r.returncode == 0, f"grading: exit {r.returncode}: {r.stderr[-800:]}"
    row = read_report(report_dir)["criteria"][0]
    assert not row["passed"], f"a run stopped by the memory cap cannot pass: {row}"
    assert "memory cap of 1024 MiB" in row["message"], f"the message must name the memory cap: {row['message']!r}"
    assert row["limit"] == "memory", f"the report must record the memory cap as the limit met: {row}"
    memory = read_report(report_dir)["memory"]
    assert memory["cap_mib"] == 1024 and memory["peak_mib"] is not None and memory["peak_mib"] <= 1024, \
        f"the whole grading's memory is capped at 1024 MiB: {memory}"
    forked, written = re.search(r"FORKED (\d+)", row["message"]), re.search(r"WRITTEN (\d+)", row["message"])
    assert forked and int(forked[1]) < 64, f"the process cap (64) must stop the fork bomb: {row['message']!r}"
    assert written and int(written[1]) <= 512 << 20, f"the file size cap (512 MiB) must stop the file: {row['message']!r}"
    assert time.time() - start < 300, "the caps took too long to stop the submission"


def test_a_secret_included_at_build_time_stays_secret(ctx):
    """#include of an absolute path of the instructor's: the file is not in the sandbox, the build
    fails, and its contents are not in the report."""
    if "asan" in ctx.build:
        return
    sub = submission(ctx, "include", before_includes=f'#include "{SECRET}"\n')
    report_dir = ctx.path("include-report")
    r = grade(ctx, sub, report_dir)
    assert r.returncode == 0, f"grading: exit {r.returncode}: {r.stderr[-800:]}"
    report = read_report(report_dir)
    assert report["total"] == 0 and "does not compile" in report["criteria"][0]["message"], report["criteria"][0]
    assert SECRET_LINE not in json.dumps(report), "a line of the instructor's rubric reached the report"


def test_unit_test_ok_lines_forged_from_a_submitted_header_fail(ctx):
    """common/optics.h is handed in (chapter 2's exercises) and included by tests/test_optics.c, so
    its code runs in the unit test's process: a constructor there can print every "ok" line and
    exit.  The grader compares the values behind the checks with the solution's run (tests/check.h
    "site" lines): the forgery fails, the solution's header passes."""
    if "asan" in ctx.build:
        return
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import markers
    with open(SECRET) as f:
        rub = json.load(f)
    rub["criteria"] = [c for c in rub["criteria"] if c["name"] == "unit tests test_optics" and
                       c["chapter"] == "02_whitted"]
    rubric = ctx.write("rubric-optics.json", json.dumps(rub))
    with open(os.path.join(ROOT, "tests", "test_optics.c")) as f:
        names = re.findall(r"RUN_TEST\((\w+)\)", f.read())
    with open(os.path.join(ROOT, "common", "optics.h")) as f:
        header = f.read()
    stubbed = markers.stub_file(header, [e for e in markers.all_exercises(ROOT) if e.file == "common/optics.h"])
    lines = "".join(f'puts("ok   {n}");' for n in names)
    forged = stubbed.replace("#endif", "#include <stdio.h>\n#include <stdlib.h>\n__attribute__((constructor)) "
                             "static void forge(void) { " + lines + " exit(0); }\n#endif")
    results = {}
    for name, text in (("forged", forged), ("solution", header)):
        top = ctx.path(name)
        for rel in ("chapters/02_whitted.c", "common/optics.h"):
            os.makedirs(os.path.dirname(os.path.join(top, rel)), exist_ok=True)
            with open(os.path.join(top, rel), "w") as f:
                f.write(text if rel == "common/optics.h" else open(os.path.join(ROOT, rel)).read())
        report = ctx.path(name + "-report")
        r = subprocess.run(GRADE + [top, "--report", report, "--chapters", "02_whitted", "--rubric", rubric],
                           cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, f"{name}: exit {r.returncode}: {r.stderr[-800:]}"
        results[name] = read_report(report)["criteria"][0]
    assert results["solution"]["passed"], f"the solution's optics.h: {results['solution']['message']}"
    assert not results["forged"]["passed"] and "values behind" in results["forged"]["message"], \
        f"forged ok lines were taken: {results['forged']['message']}"


def test_the_graded_tree_lends_no_later_chapter_solution(ctx):
    """What the sandbox can read is the graded tree: for chapter 1 it holds no answer of a later
    chapter (a submission could print one into its report), but chapter 4's grading lends chapter
    3's solution, which its criteria compare with."""
    if "asan" in ctx.build:
        return  # the kit's Python alone, whatever the build: the same check in both passes
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import grade as kit_grade
    import markers
    names = markers.chapter_names(ROOT)
    exercises = markers.all_exercises(ROOT)
    for graded, needed in ((["01_local"], {"01_local"}), (["04_pathtrace"], {"03_radiosity", "04_pathtrace"})):
        work = ctx.path("prepared-" + graded[0])
        os.makedirs(work)
        src, _ = kit_grade.prepare(ctx.path("no-submission"), work, graded, kit_grade.later_chapters(needed))
        files = kit_grade.project_files(src)
        later = [e for e in exercises if names.get(e.lecture) > max(needed)]
        assert later, f"no chapter after {max(needed)} has exercises: the test checks nothing"
        found = markers.answers_in_tree(src, later, files)
        assert not found, f"grading {graded[0]} lends later answers: " + \
            ", ".join(f"{e.id} {e.name} in {fn.file}" for fn, e in found[:5])
        earlier = [e for e in exercises if names.get(e.lecture) in needed - set(graded)]
        assert len(markers.answers_in_tree(src, earlier, files)) >= len(earlier), \
            f"grading {graded[0]}: the solution of {sorted(needed - set(graded))} its criteria run is not lent"


def test_submissions_the_kit_refuses(ctx):
    """A file, a missing path, devices, FIFOs, sockets, links out of the tree, too large: exit 2 and
    one line naming the path; nothing graded."""
    if "asan" in ctx.build:
        return

    def tree(name, make):
        top = ctx.path(name)
        os.makedirs(os.path.join(top, "chapters"))
        shutil.copy(os.path.join(ROOT, CHAPTER), os.path.join(top, CHAPTER))
        make(top)
        return top

    def sparse_file(path, size):
        with open(path, "w"):
            pass
        os.truncate(path, size)

    def unix_socket(path):
        s = socket.socket(socket.AF_UNIX)
        s.bind(path)
        s.close()

    cases = {
        "a file": (ctx.write("file.txt", "x"), "not a directory"),
        "missing": (ctx.path("nowhere"), "missing"),
        "fifo": (tree("fifo", lambda t: os.mkfifo(os.path.join(t, "chapters", "pipe"))), "chapters/pipe"),
        "device": (tree("device", lambda t: os.mknod(os.path.join(t, "null"), 0o600 | stat.S_IFCHR,
                                                     os.makedev(1, 3))), "null"),
        "socket": (tree("socket", lambda t: unix_socket(os.path.join(t, "sock"))), "sock"),
        "link out": (tree("link", lambda t: os.symlink(SECRET, os.path.join(t, "chapters", "ref.json"))),
                     "a symbolic link out of the submission"),
        "too large": (tree("large", lambda t: sparse_file(os.path.join(t, "big.bin"), 65 << 20)), "larger than"),
    }
    for what, (path, expected) in cases.items():
        r = grade(ctx, path, ctx.path("refused-report"))
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and expected in lines[0], \
            f"{what}: expected exit 2 and one line naming {expected!r}; got {r.returncode}: {r.stderr!r}"
    # In a class, a refused submission is a "not graded" row with the reason; the others stand.
    class_dir = ctx.path("class")
    r = subprocess.run([sys.executable, os.path.join(ROOT, "kit", "grade_class.py"), "--report", class_dir,
                        "--jobs", "2", cases["fifo"][0], cases["link out"][0]], cwd=ROOT, capture_output=True,
                       text=True, timeout=300)
    with open(os.path.join(class_dir, "summary.csv")) as f:
        summary = f.read()
    for what in ("fifo", "link out"):
        assert f"not graded: {cases[what][0]}" in summary and cases[what][1] in summary, \
            f"the class summary must say why {what} was not graded: {summary[:1500]}"
    loop = tree("loop", lambda t: os.symlink(".", os.path.join(t, "loop")))
    r = grade(ctx, loop, ctx.path("loop-report"))
    assert r.returncode == 0 and read_report(ctx.path("loop-report"))["total"] == 10, \
        f"a link inside the tree ('loop -> .') is harmless: {r.returncode} {r.stderr[-500:]}"


def test_make_arguments_are_data(ctx):
    """SUBMISSION, REPORT and CHAPTERS with spaces, quotes and ';' reach the kit as they are."""
    if "asan" in ctx.build:
        return
    marker = ctx.path("injected")
    odd = ctx.path("a dir; touch " + marker + " 'q\"")
    os.makedirs(odd)
    r = subprocess.run(["make", "--no-print-directory", "grade", f"SUBMISSION={odd}/missing",
                        f"REPORT={ctx.path('r; touch ' + marker)}", "CHAPTERS=01_local;touch " + marker],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert not os.path.exists(marker), f"a make variable ran as a command: {r.stdout} {r.stderr}"
    assert r.returncode != 0 and "missing" in r.stderr, f"expected a refusal naming the path: {r.stderr!r}"
    r = subprocess.run(GRADE + [submission(ctx, "plain"), "--report", "/proc/version/report"], capture_output=True,
                       text=True)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "REPORT" in lines[0], \
        f"an unwritable REPORT is one line and exit 2: {r.returncode} {r.stderr!r}"


def test_no_sandbox_no_grading_unless_unsafe(ctx):
    """Where bubblewrap is missing the kit refuses (exit 2, naming the cause)."""
    if "asan" in ctx.build:
        return
    env = dict(os.environ, PATH=ctx.scratch)  # no bwrap on this PATH
    r = subprocess.run(GRADE + [submission(ctx, "plain"), "--report", ctx.path("r"), "--rubric", rubric_file(ctx)],
                       cwd=ROOT,
                       capture_output=True, text=True, env=env)
    assert r.returncode == 2 and "bubblewrap" in r.stderr and "UNSAFE=1" in r.stderr, \
        f"without bwrap the kit must refuse and say why: {r.returncode} {r.stderr!r}"


def test_a_gradings_memory_cap_bounds_its_sandboxes_together(ctx):
    """Two runs side by side in two sandboxes of one grading (each a cgroup of its own, as the build's
    and each program's where no Session serves), each touching 768 MiB, each under its own 1 GiB cap:
    the grading's cgroup (kit/sandbox.py GradingGroup, 1 GiB) bounds their sum, so one is stopped and
    says memory, and the most the grading held at once (its peak) is at most 1 GiB.  (Small: touching
    memory takes seconds a GiB on a loaded virtual machine; tests/cluster_memory.py grades 1.5 GiB
    renders under 2 GiB.)"""
    if "asan" in ctx.build:
        return
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import sandbox
    if sandbox.unavailable():
        raise AssertionError(f"no sandbox here: {sandbox.unavailable()}")
    tag = f"gi-sandbox-test-{os.getpid()}-{int(time.time())}"
    saved = os.environ.get(sandbox.TAG_VARIABLE)
    os.environ[sandbox.TAG_VARIABLE] = tag
    scratch = tempfile.mkdtemp(prefix="gi-kit-tmemory-")
    os.chown(scratch, sandbox.SANDBOX_UID, sandbox.SANDBOX_UID)
    results = []
    try:
        group = sandbox.GradingGroup(tag, 1024)
        box = sandbox.Sandbox([(scratch, True)], limits=sandbox.Limits(memory_mib=1024))
        touch = ("import time\nb = bytearray(768 << 20)\nb[::4096] = b'\\1' * len(range(0, len(b), 4096))\n"
                 "time.sleep(3)\nprint('held 768 MiB')")
        runs = [threading.Thread(target=lambda: results.append(box.run(["/usr/bin/python3", "-c", touch],
                                                                       cwd=scratch, timeout=120)))
                for _ in range(2)]
        for t in runs:
            t.start()
        for t in runs:
            t.join()
        peak = group.peak_mib()
    finally:
        sandbox.remove_groups(tag)
        shutil.rmtree(scratch, ignore_errors=True)
        if saved is None:
            os.environ.pop(sandbox.TAG_VARIABLE, None)
        else:
            os.environ[sandbox.TAG_VARIABLE] = saved
    held = [r for r in results if "held 768 MiB" in r.stdout]
    stopped = [r for r in results if r.limit == "memory"]
    assert len(results) == 2 and len(held) <= 1, \
        f"two runs of 768 MiB held at once under a 1 GiB grading cap: {[(r.stdout, r.stopped) for r in results]}"
    assert stopped and all("memory" in r.stopped for r in stopped), \
        f"the run the grading's cap stopped must say memory: {[(r.returncode, r.stopped, r.stderr[-300:]) for r in results]}"
    assert peak is not None and peak <= 1024, f"the grading held {peak} MiB at once under its 1024 MiB cap"
    assert not any(os.path.exists(os.path.join(sandbox.hierarchy(c), tag)) for c in ("pids", "memory", "cpuacct")), \
        "the grading's cgroup was not removed"


def test_the_fallbacks_memory_is_the_uids_sum(ctx):
    """--sandbox user without a cgroup: RLIMIT_AS holds each process under the cap, not their sum; the
    grader adds up the uid's resident memory and stops a run whose two processes, each under the cap
    (200 MiB of 256), hold more together."""
    if "asan" in ctx.build:
        return
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import sandbox
    if sandbox.fallback_unavailable():
        raise AssertionError(f"no fallback sandbox here: {sandbox.fallback_unavailable()}")
    two = ("import os, time\npid = os.fork()\nb = bytearray(200 << 20)\nb[::4096] = b'\\1' * len(range(0, len(b), 4096))\n"
           "time.sleep(3)\nprint('held 200 MiB')\nos.waitpid(pid, 0) if pid else None")
    saved = sandbox.CGROUP_V1
    sandbox.CGROUP_V1 = ctx.path("no-cgroups")  # as in a container where no cgroup can be made
    try:
        box = sandbox.Sandbox([("/", False)], limits=sandbox.Limits(memory_mib=256), mode="user",
                              uid=sandbox.user_for_grading())
        r = box.run(["/usr/bin/python3", "-c", two], cwd="/", timeout=60)
        alone = box.run(["/usr/bin/python3", "-c", two.replace("os.fork()", "0")], cwd="/", timeout=60)
    finally:
        sandbox.CGROUP_V1 = saved
    assert r.limit == "memory" and "memory" in r.stopped and r.stdout.count("held") < 2, \
        f"two processes of 200 MiB under a 256 MiB cap: {r.returncode} {r.stopped!r} {r.stdout!r}"
    assert alone.returncode == 0 and alone.stdout.count("held") == 1 and not alone.stopped, \
        f"one process of 200 MiB fits a 256 MiB cap: {alone.returncode} {alone.stopped!r} {alone.stderr[-300:]!r}"


def test_gradings_that_fit_the_cores_and_the_memory(ctx):
    """kit/grade_class.py's default --jobs: no more gradings than cores, no more than the free memory
    holds at the cap each (with the judges' and the system's share), at least one; MemTotal where
    a kernel has no MemAvailable; a lower cap of the grader's own cgroup counts."""
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import sandbox

    def meminfo(total_gib, available_gib=None):
        text = f"MemTotal:       {total_gib << 20} kB\nMemFree:        1000 kB\n"
        return text + (f"MemAvailable:   {available_gib << 20} kB\n" if available_gib is not None else "")
    cases = [(4096, meminfo(24, 23), 64, None), (4096, meminfo(24, 23), 2, None), (4096, meminfo(8, 3), 16, None),
             (2048, meminfo(256, 250), 32, None), (4096, meminfo(32), 64, None), (4096, meminfo(64, 60), 64, 16384),
             (512, meminfo(4, 4), 1, None)]
    for cap, text, cores, limit in cases:
        n = sandbox.gradings_that_fit(cap, meminfo=text, cores=cores, limit_mib=limit if limit else 1 << 40)
        free = sandbox.meminfo_mib(text).get("MemAvailable", sandbox.meminfo_mib(text)["MemTotal"])
        free = min(free, limit or free)
        assert isinstance(n, int) and 1 <= n <= cores, f"cap {cap}, {cores} cores: {n} gradings"
        assert n == 1 or n * cap <= free, f"cap {cap} MiB, {free} MiB free: {n} gradings do not fit"
        assert n == cores or (n + 1) * (cap + sandbox.JUDGE_MIB) + sandbox.SYSTEM_MIB > free, \
            f"cap {cap} MiB, {free} MiB free, {cores} cores: {n} gradings leave room for another"
    assert sandbox.gradings_that_fit(4096, meminfo=meminfo(24, 23), cores=64, limit_mib=1 << 40) == 5
    r = subprocess.run(GRADE + ["--gradings-that-fit", "--memory", "4096"], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip().isdigit() and \
        1 <= int(r.stdout) <= len(os.sched_getaffinity(0)), f"kit/grade.py --gradings-that-fit: {r.stdout!r} {r.stderr!r}"
