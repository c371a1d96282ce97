"""Gradescope and GitHub Classroom end to end (make test-cluster; tests/run.py --cluster -k gradescope build).

tests/grade_autograder.py checks the archive in a fake /autograder on this machine; these tests run it
where it will run, as far as this machine can show it:

1. A Debian 12 root made by debootstrap (Debian's archive, the mirror of this machine's apt sources),
   entered as root: new mount, PID, IPC and UTS namespaces, the root pivoted to it (pivot_root, not
   chroot: a chroot refuses user namespaces, and bubblewrap needs one), fresh /proc, a read-only
   sysfs, the host's cgroup hierarchies, a small /dev; each layer is an overlay on the cached root.
   The archive is unpacked into /autograder/source, setup.sh runs as root with the host's network (its
   apt-get installs the packages from the mirror), then per submission, in a fresh layer on that
   image and WITHOUT network (a network namespace with only loopback), /autograder/run_autograder
   runs as root, and results.json is checked against Gradescope's fields (tests/grade_autograder.py's
   tables).  Here bubblewrap starts, so this grades in kit/sandbox.py's bubblewrap sandbox.
   Real: Debian's root, setup.sh's apt-get, the absence of network, root.  Not Gradescope's: its
   base image is Ubuntu (22.04 or newer: the same package names), and it builds it with Docker.
2. Docker (real, not imitated): dockerd from Debian's docker.io, started by the test where none answers
   (its own socket; --bridge=none --iptables=false --ip-forward=false --ip-masq=false: it changes no
   network of this machine), the root imported as an image (docker import), setup.sh in a container
   with --network host (its apt-get), committed, and each submission in a container of that image
   with Docker's default seccomp profile and default capabilities, not privileged, --network none.
   There bubblewrap cannot start (Docker's profile refuses the user namespace, /sys/fs/cgroup is
   read-only), so run_autograder grades with the fallback (kit/grade.py --sandbox user).  A container
   with --cap-drop SETUID --cap-drop SETGID has neither sandbox: run_autograder must refuse there,
   saying so, and run none of the submission's code.
3. The handout's GitHub Classroom workflow (.github/workflows/classroom.yml, parsed with Debian's
   python3-yaml), its steps run as a runner would: `actions/checkout` is a fresh git clone of the
   student's pushed commit, each `run:` step runs with bash -eo pipefail (as root; `sudo` is a shim
   that runs the command) in the debian root with network, the steps to run always kept, and
   `actions/upload-artifact` checks the path it would upload.  Imitated: the runner (Ubuntu 24.04 on
   GitHub's machines; git is added, as its image has it).  The bare repository the student pushes to
   has the pre-receive hook of kit/autograder/classroom_guard.py, reading the push ruleset it writes
   for the handout (what GitHub enforces as an organisation ruleset): a push that changes the grader
   files or the workflow, to main or to another branch, is refused and moves no ref, so the
   workflow that runs is the handout's; Gradescope's archive grades the pushed commit as the
   self-check did.

Each submission: the solution scores the maximum, the plain handout its unit tests' points, and a
hostile one (the handout with a constructor that forges results.json now and later, writes the
grader's files, reads the rubric and the references, forges result lines into every stdout, and
leaves a process behind) scores no more than the plain handout, with none of it in results.json
and no file of the grader changed.

Root, debootstrap, docker.io and python3-yaml are needed (the Makefile's CLUSTER_PACKAGES).  The
debootstrap root, the packages setup.sh downloads and dockerd's images are cached in
$GI_CLUSTER_CACHE (default /var/tmp/gi-cluster-cache/gradescope).  Times on 2 cores, the first run
(debootstrap, downloads, docker import) and a cached one: see kit/README.md ("Gradescope").
"""
import fcntl
import io
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import time

import lib
import grade_autograder as autograder

sys.path.insert(0, os.path.join(lib.ROOT, "kit"))
import markers  # noqa: E402
import rubric  # noqa: E402

ROOT = lib.ROOT
RUN_ALONE = True  # long gradings in roots and containers: nothing beside them on 2 cores
CACHE = os.path.join(os.environ.get("GI_CLUSTER_CACHE", "/var/tmp/gi-cluster-cache"), "gradescope")
SUITE = "bookworm"
CHAPTER = "01_local"
SECRET_LINE = "The grading rubric (kit/grade.py"  # a line of kit/rubric.json: never in a student's results
MARKS = ("LEAK", "WROTE", "FORGED")  # what the hostile submission prints when an attack worked

# Enters a root (see the module): run by `unshare --mount --pid --fork --ipc --uts [--net]` as
# sh -c ENTER enter LOWERS UPPER WORK MOUNTPOINT NET APT_CACHE COMMAND...
ENTER = r"""
set -e
lowers=$1 upper=$2 work=$3 root=$4 net=$5 aptcache=$6
shift 6
mount --make-rprivate /
mount -t overlay overlay -o "lowerdir=$lowers,upperdir=$upper,workdir=$work" "$root"
mount -t proc -o nosuid,nodev,noexec proc "$root/proc"
mount -t sysfs -o ro,nosuid,nodev,noexec sysfs "$root/sys"
mount --rbind /sys/fs/cgroup "$root/sys/fs/cgroup"
mount -t tmpfs -o mode=755,nosuid dev "$root/dev"
for n in null zero full random urandom tty; do touch "$root/dev/$n"; mount --bind "/dev/$n" "$root/dev/$n"; done
mkdir "$root/dev/shm" "$root/dev/pts"
mount -t tmpfs -o mode=1777,nosuid,nodev shm "$root/dev/shm"
ln -s /proc/self/fd "$root/dev/fd"
if [ "$net" = host ]; then mount --bind /etc/resolv.conf "$root/etc/resolv.conf"; else ip link set lo up; fi
if [ "$aptcache" != - ]; then mount --bind "$aptcache" "$root/var/cache/apt/archives"; fi
cd "$root"
pivot_root . .
umount -l .
exec chroot . /usr/bin/env -i PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin HOME=/root \
    LANG=C.UTF-8 "$@"
"""

# run_autograder as Gradescope starts it, then 5 s more in the same container: a process the
# submission left behind would forge results.json then, before it is read.
GRADE_COMMAND = ["/bin/sh", "-c", "cd /autograder && ./run_autograder; status=$?; sleep 5; "
                 "test -e /tmp/gi-attack-ran && echo 'the submission ran as' $(stat -c %u /tmp/gi-attack-ran); "
                 "exit $status"]


def run(argv, timeout=600, **kw):
    return subprocess.run(argv, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL, **kw)


def require_root_and_tools():
    missing = [t for t in ("debootstrap", "unshare", "ip", "git") if not shutil.which(t)]
    assert os.geteuid() == 0, "these tests make roots and containers: run them as root (make test-cluster)"
    assert not missing, f"missing {missing}: make deps-cluster installs the Makefile's CLUSTER_PACKAGES"


class Lock:
    """The cache's lock: one test at a time makes or changes it."""

    def __enter__(self):
        os.makedirs(CACHE, exist_ok=True)
        self.f = open(os.path.join(CACHE, "lock"), "w")
        fcntl.flock(self.f, fcntl.LOCK_EX)

    def __exit__(self, *exc):
        self.f.close()


def host_mirror():
    """This machine's Debian mirror (its apt sources), for debootstrap."""
    for path in ("/etc/apt/sources.list.d/debian.sources", "/etc/apt/sources.list"):
        try:
            with open(path) as f:
                text = f.read()
        except OSError:
            continue
        found = re.search(r"^URIs:\s*(\S+/debian)\s*$", text, re.M) or \
            re.search(r"^deb\s+(?:\[[^]]*\]\s+)?(\S+/debian)\s+" + SUITE, text, re.M)
        if found:
            return found.group(1)
    return "http://deb.debian.org/debian"


def debian_root():
    """The cached Debian 12 root (debootstrap --variant=minbase), made the first time (about 2 min)."""
    root = os.path.join(CACHE, "debian12")
    with Lock():
        if os.path.isdir(root):
            return root
        partial = root + ".partial"
        shutil.rmtree(partial, ignore_errors=True)
        mirror = host_mirror()
        r = run(["nice", "debootstrap", "--variant=minbase", SUITE, partial, mirror], timeout=3600)
        assert r.returncode == 0, f"debootstrap {SUITE} from {mirror}: {r.stdout[-2000:]}{r.stderr[-2000:]}"
        with open(os.path.join(partial, "etc", "apt", "sources.list"), "w") as f:
            f.write(f"deb {mirror} {SUITE} main\ndeb {mirror} {SUITE}-updates main\n")
        # The mirror may be a snapshot whose Release files are older than their Valid-Until.
        with open(os.path.join(partial, "etc", "apt", "apt.conf.d", "99gi-snapshot"), "w") as f:
            f.write('Acquire::Check-Valid-Until "false";\n')
        os.rename(partial, root)
    return root


class Layer:
    """A writable layer (an overlay's upper directory) over lower layers, entered with ENTER."""

    def __init__(self, ctx, name, lowers):
        self.lowers, self.upper = list(lowers), ctx.path(f"layer-{name}")
        self.work, self.mountpoint = ctx.path(f"layer-{name}.work"), ctx.path(f"layer-{name}.mnt")
        for d in (self.upper, self.work, self.mountpoint):
            os.makedirs(d)

    def path(self, rel):
        """A file of this layer's own (written before entering: the overlay shows it)."""
        return os.path.join(self.upper, rel.lstrip("/"))

    def enter(self, argv, network=False, apt_cache=None, timeout=1800):
        cmd = ["unshare", "--mount", "--pid", "--fork", "--ipc", "--uts", *([] if network else ["--net"]),
               "/bin/sh", "-c", ENTER, "enter", ":".join(self.lowers), self.upper, self.work, self.mountpoint,
               "host" if network else "none", apt_cache or "-", *argv]
        return run(cmd, timeout=timeout)


def apt_cache():
    d = os.path.join(CACHE, "apt-archives")
    os.makedirs(os.path.join(d, "partial"), exist_ok=True)
    return d


# ---- the submissions --------------------------------------------------------------------------------

def handout(ctx, name):
    tree = ctx.path(name)
    r = autograder.make("handout", f"OUT={tree}", f"CHAPTERS={CHAPTER}")
    assert r.returncode == 0, r.stderr
    return tree


def chapter_exercises():
    names = markers.chapter_names(ROOT)
    return [e for e in markers.all_exercises(ROOT) if names.get(e.lecture) == CHAPTER]


def solution(ctx):
    tree = handout(ctx, "solution")
    for e in chapter_exercises():
        autograder.solve(tree, e.file, e.name)
    return tree


def c_string(s):
    return json.dumps(s)


HOSTILE = r"""
#include <dirent.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static void hostile_read(const char *path)
{
    char line[200] = "";
    FILE *f = fopen(path, "r");
    if (f && fgets(line, sizeof line, f)) fprintf(stderr, "LEAK %s: %s\n", path, line);
    if (f) fclose(f);
}

static void hostile_write(const char *path, const char *text)
{
    FILE *f = fopen(path, "a");
    if (f) fputs(text, f), fclose(f), fprintf(stderr, "WROTE %s\n", path);
}

__attribute__((constructor)) static void hostile_gradescope(void)
{
    static const char forged[] = "{\"score\": 999, \"output\": \"FORGED\", \"tests\": []}";
    close(open("/tmp/gi-attack-ran", O_WRONLY | O_CREAT, 0666)); /* it ran: the refusal test looks */
    /* 1. results.json forged: written, replaced by a rename, and by a process left behind */
    FILE *f = fopen("/autograder/results/results.json", "w");
    if (f) fputs(forged, f), fclose(f), fprintf(stderr, "WROTE results.json\n");
    f = fopen("/autograder/results/.forged.json", "w");
    if (f) {
        fputs(forged, f), fclose(f);
        if (rename("/autograder/results/.forged.json", "/autograder/results/results.json") == 0)
            fprintf(stderr, "WROTE results.json by rename\n");
    }
    if (fork() == 0) {
        setsid();
        if (fork() == 0)
            execl("/bin/sh", "sh", "-c", "for i in 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20; do "
                  "echo '{\"score\": 999, \"output\": \"FORGED late\"}' > /autograder/results/results.json "
                  "2>/dev/null; sleep 1; done", (char *)0);
        _exit(0);
    }
    /* 2. the grader changed: its entry point, the judge, the rubric, the configuration */
    const char *grader[] = {"/autograder/run_autograder", "/autograder/source/run_autograder",
                            "/autograder/source/setup.sh", "/autograder/source/kit/grade.py",
                            "/autograder/source/kit/criterion.py", "/autograder/source/kit/rubric.json",
                            "/autograder/source/autograder.json", "/autograder/source/Makefile",
                            "/autograder/source/tests/lib.py"};
    for (size_t i = 0; i < sizeof grader / sizeof *grader; i++) hostile_write(grader[i], "\n");
    /* 3. the rubric and the references read (their lines would reach the criterion's message) */
    hostile_read("/autograder/source/kit/rubric.json");
    hostile_read("/proc/1/root/autograder/source/kit/rubric.json");
    DIR *refs = opendir("/autograder/source/kit/reference");
    for (struct dirent *e; refs && (e = readdir(refs));) {
        char path[600];
        snprintf(path, sizeof path, "/autograder/source/kit/reference/%s", e->d_name);
        if (strstr(e->d_name, ".json")) hostile_read(path);
    }
    if (refs) closedir(refs), fprintf(stderr, "LEAK listed kit/reference\n");
    /* 4. result lines forged into every stdout it can open */
    DIR *proc = opendir("/proc");
    for (struct dirent *e; proc && (e = readdir(proc));) {
        char path[300];
        snprintf(path, sizeof path, "/proc/%s/fd/1", e->d_name);
        FILE *out = fopen(path, "w");
        if (out) fprintf(out, "\n@@RESULT@@ {\"passed\": true, \"p_value\": null, \"message\": \"FORGED\"}\n"),
                 fclose(out);
    }
    if (proc) closedir(proc);
    fprintf(stderr, "ATTACK-RAN as uid %d\n", (int)getuid());
    exit(3);
}
"""


def hostile(ctx):
    """The handout with HOSTILE at the end of chapter 1: whatever it gains is above the handout's score."""
    tree = handout(ctx, "hostile")
    with open(os.path.join(tree, "chapters", f"{CHAPTER}.c"), "a") as f:
        f.write(HOSTILE)
    return tree


def linked(ctx):
    """A submission whose exercise file is a link to the grader's rubric (Gradescope's upload keeps links)."""
    tree = handout(ctx, "linked")
    os.remove(os.path.join(tree, "chapters", f"{CHAPTER}.c"))
    os.symlink("/autograder/source/kit/rubric.json", os.path.join(tree, "chapters", f"{CHAPTER}.c"))
    return tree


# ---- the checks -------------------------------------------------------------------------------------

def criteria():
    return [c for c in rubric.load(ROOT)["criteria"] if c["chapter"] == CHAPTER]


def unit_points():
    return sum(c["points"] for c in criteria() if c["kind"] == "unit")


def results_of(path, what):
    assert os.path.isfile(path), f"{what}: no results.json"
    results = autograder.check_results(path, criteria())
    with open(path) as f:
        text = f.read()
    assert SECRET_LINE not in text and not any(m in text for m in MARKS), \
        f"{what}: an attack reached results.json: {text[:3000]}"
    return results


def changed_grader_files(upper):
    """The files of the grader (/autograder/source, /autograder/run_autograder) a submission's layer
    holds: anything there was written during grading (Python's own __pycache__ aside)."""
    found = []
    for rel in ("autograder/source", "autograder/run_autograder"):
        top = os.path.join(upper, rel)
        if os.path.lexists(top) and not os.path.isdir(top):
            found.append(rel)
        for base, dirs, files in os.walk(top):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            found += [os.path.relpath(os.path.join(base, f), upper) for f in files]
    return found


def check_hostile(results, stdout, what):
    text = json.dumps(results)
    assert "ATTACK-RAN" in text, f"{what}: the hostile submission's attack did not run: {text[:2000]}"
    assert results["score"] <= unit_points(), f"{what}: the hostile submission scored {results['score']}"
    assert "the submission ran as 0" not in stdout, f"{what}: the submission's code ran as root"


def archive(ctx):
    path = ctx.path("autograder.zip")
    r = autograder.make("autograder", f"OUT={path}", f"CHAPTERS={CHAPTER}")
    assert r.returncode == 0, r.stderr
    return path


def gradescope_image(ctx, base):
    """The archive unpacked into /autograder/source of a layer over the Debian root, and setup.sh run
    there as Gradescope does (as root, with network): the layer (the image)."""
    image = Layer(ctx, "image", [base])
    autograder.unpack(archive(ctx), image.path("autograder"))
    start = time.time()
    with Lock():  # apt's lock of the shared cache of packages is held by a process of another namespace
        r = image.enter(["/bin/sh", "-c", "cd /autograder/source && ./setup.sh"], network=True, apt_cache=apt_cache())
    assert r.returncode == 0, f"setup.sh: {r.stdout[-3000:]}{r.stderr[-3000:]}"
    print(f"     setup.sh in the debian root: {time.time() - start:.0f} s", flush=True)
    return image, r.stdout


def grade_in_layer(ctx, image, base, name, tree):
    layer = Layer(ctx, name, [image.upper, base])
    shutil.copytree(tree, layer.path("autograder/submission"), symlinks=True)
    start = time.time()
    r = layer.enter(GRADE_COMMAND)
    assert r.returncode == 0, f"{name}: run_autograder: {r.stdout[-3000:]}{r.stderr[-3000:]}"
    print(f"     {name}: graded in {time.time() - start:.0f} s", flush=True)
    results = results_of(layer.path("autograder/results/results.json"), name)
    changed = changed_grader_files(layer.upper)
    assert not changed, f"{name}: the grading changed the grader's files: {changed[:10]}"
    return results, r.stdout


def test_gradescope_in_a_debian_root(ctx):
    """Module, part 1: setup.sh in a debootstrapped Debian 12, then run_autograder without network
    in a fresh layer per submission (bubblewrap's sandbox): the solution scores the maximum, the
    handout its unit tests, the hostile handout no more and a linked one nothing, every results.json
    as Gradescope documents it and no file of the grader changed."""
    require_root_and_tools()
    base = debian_root()
    image, setup_output = gradescope_image(ctx, base)
    assert "the sandbox starts" in setup_output, setup_output[-2000:]
    results, _ = grade_in_layer(ctx, image, base, "solution", solution(ctx))
    assert results["score"] == sum(c["points"] for c in criteria()), results["output"]
    results, _ = grade_in_layer(ctx, image, base, "handout", handout(ctx, "handout"))
    assert results["score"] == unit_points(), results["output"]
    assert "Sandbox: bubblewrap" in results["output"], results["output"]
    results, stdout = grade_in_layer(ctx, image, base, "hostile", hostile(ctx))
    check_hostile(results, stdout, "hostile")
    results, _ = grade_in_layer(ctx, image, base, "linked", linked(ctx))
    assert results["score"] == 0 and "link" in results["output"], results["output"]


# ---- Docker -----------------------------------------------------------------------------------------

class Docker:
    """The docker client, to this machine's daemon where one answers, else to a dockerd started here
    (see the module: it changes no network of the machine) and stopped by close()."""

    def __init__(self, ctx):
        assert shutil.which("dockerd") or shutil.which("docker"), "no docker: make deps-cluster installs docker.io"
        self.client = "/usr/bin/docker" if os.path.exists("/usr/bin/docker") else shutil.which("docker")
        self.env, self.daemon, self.log = dict(os.environ), None, ctx.path("dockerd.log")
        self.exec_root = ctx.path("docker-exec")
        if self("info", timeout=60).returncode == 0:
            return
        sock = ctx.path("docker.sock")
        self.env["DOCKER_HOST"] = "unix://" + sock
        for driver in ("overlay2", "vfs"):  # vfs where overlay cannot mount
            with open(self.log, "a") as log:
                self.daemon = subprocess.Popen(
                    ["dockerd", "--data-root", os.path.join(CACHE, f"docker-{driver}"), "--storage-driver", driver,
                     "--exec-root", self.exec_root, "--pidfile", ctx.path("dockerd.pid"), "-H", "unix://" + sock,
                     "--bridge=none", "--iptables=false", "--ip6tables=false", "--ip-forward=false", "--ip-masq=false"],
                    stdout=log, stderr=log, stdin=subprocess.DEVNULL, start_new_session=True)
            deadline = time.monotonic() + 90
            while self.daemon.poll() is None and time.monotonic() < deadline:
                if self("info", timeout=30).returncode == 0:
                    return
                time.sleep(1)
            self.close()
        with open(self.log) as f:
            raise AssertionError(f"dockerd does not start here: {f.read()[-3000:]}")

    def __call__(self, *args, timeout=600, stdin=None):
        return subprocess.run([self.client, *args], env=self.env, capture_output=True, timeout=timeout,
                              stdin=stdin if stdin is not None else subprocess.DEVNULL)

    def ok(self, *args, **kw):
        r = self(*args, **kw)
        assert r.returncode == 0, f"docker {' '.join(args[:3])}: {r.stderr.decode(errors='replace')[-2000:]}"
        return r.stdout.decode(errors="replace").strip()

    def close(self):
        if self.daemon and self.daemon.poll() is None:
            self.daemon.terminate()
            try:
                self.daemon.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.daemon.kill()
                self.daemon.wait()
            with open("/proc/self/mountinfo") as f:  # dockerd leaves its network namespace's file mounted
                left = [line.split()[4] for line in f if line.split()[4].startswith(self.exec_root + "/")]
            for path in reversed(left):
                run(["umount", "-l", path], timeout=60)
        self.daemon = None


def docker_base(docker, root):
    """The Debian root as an image (docker import), imported once into dockerd's cached images."""
    tag = "gi-gradescope-base:debian12"
    with Lock():
        if docker("image", "inspect", tag).returncode != 0:
            tar = subprocess.Popen(["tar", "-C", root, "--numeric-owner", "-c", "."], stdout=subprocess.PIPE)
            docker.ok("import", "-", tag, stdin=tar.stdout, timeout=1200)
            assert tar.wait() == 0, "tar of the debian root failed"
    return tag


def tar_of(path, name):
    """A tar stream (bytes) of path as NAME, everything root's (as Gradescope unpacks it)."""
    data = io.BytesIO()

    def as_root(info):
        info.uid = info.gid = 0
        info.uname = info.gname = "root"
        return info
    with tarfile.open(fileobj=data, mode="w") as t:
        t.add(path, arcname=name, filter=as_root)
    return data.getvalue()


def docker_cp_in(docker, container, path, name):
    r = subprocess.run([docker.client, "cp", "-", f"{container}:/"], input=tar_of(path, name), env=docker.env,
                       capture_output=True, timeout=300)
    assert r.returncode == 0, r.stderr.decode(errors="replace")


def docker_image(ctx, docker, base_tag):
    """Gradescope's image build: the archive in /autograder/source, setup.sh run as root in a container
    (with the host's network, for its apt-get), committed: (image, setup.sh's output)."""
    top = ctx.path("docker-autograder")
    autograder.unpack(archive(ctx), top)
    container = docker.ok("create", "--network", "host", "-v", f"{apt_cache()}:/var/cache/apt/archives", base_tag,
                          "/bin/sh", "-c", "cd /autograder/source && ./setup.sh")
    try:
        docker_cp_in(docker, container, top, "autograder")
        start = time.time()
        with Lock():  # see gradescope_image
            r = docker("start", "-a", container, timeout=1800)
        output = (r.stdout + r.stderr).decode(errors="replace")
        assert r.returncode == 0, f"setup.sh in docker: {output[-3000:]}"
        print(f"     setup.sh in docker: {time.time() - start:.0f} s", flush=True)
        image = f"gi-gradescope-test:{os.getpid()}"
        docker.ok("commit", container, image)
    finally:
        docker("rm", "-f", container)
    return image, output


def grade_in_docker(ctx, docker, image, name, tree, *options):
    """run_autograder in a container of the image: Docker's defaults (seccomp profile, capabilities),
    --network none, plus options: (results, run_autograder's output)."""
    container = docker.ok("create", "--network", "none", *options, image, *GRADE_COMMAND)
    try:
        docker_cp_in(docker, container, tree, "autograder/submission")
        start = time.time()
        r = docker("start", "-a", container, timeout=2400)
        output = (r.stdout + r.stderr).decode(errors="replace")
        assert r.returncode == 0, f"{name}: run_autograder in docker: {output[-3000:]}"
        print(f"     {name}: graded in docker in {time.time() - start:.0f} s", flush=True)
        out = ctx.path(f"{name}-results")
        os.makedirs(out)
        r = docker("cp", f"{container}:/autograder/results", "-")
        assert r.returncode == 0, r.stderr.decode(errors="replace")
        with tarfile.open(fileobj=io.BytesIO(r.stdout)) as t:  # read as data: no member is extracted
            if "results/results.json" in t.getnames():
                with open(os.path.join(out, "results.json"), "wb") as f:
                    f.write(t.extractfile("results/results.json").read())
        results = results_of(os.path.join(out, "results.json"), name)
        changes = [line.split(None, 1)[1] for line in docker.ok("diff", container).splitlines() if " " in line]
        changed = [p for p in changes if p.startswith(("/autograder/source/", "/autograder/run_autograder"))
                   and "__pycache__" not in p and not any(q.startswith(p + "/") for q in changes)]  # a folder: its files
        assert not changed, f"{name}: the grading changed the grader's files: {changed[:10]}"
    finally:
        docker("rm", "-f", container)
    return results, output


def test_gradescope_in_docker(ctx):
    """Module, part 2: Docker's default restrictions (real dockerd, the default seccomp profile and
    capabilities, --network none): bubblewrap cannot start, setup.sh says so, and run_autograder grades
    with the fallback, a separate user: the solution scores the maximum, the handout its unit tests,
    the hostile handout no more; without CAP_SETUID neither sandbox starts and run_autograder refuses,
    saying so, without running the submission's code."""
    require_root_and_tools()
    base = debian_root()
    docker = Docker(ctx)
    try:
        image, setup_output = docker_image(ctx, docker, docker_base(docker, base))
        try:
            assert "bubblewrap's sandbox cannot start" in setup_output and \
                "grades with the fallback" in setup_output, setup_output[-2000:]
            results, _ = grade_in_docker(ctx, docker, image, "docker-solution", solution(ctx))
            assert results["score"] == sum(c["points"] for c in criteria()), results["output"]
            assert "Sandbox: a separate user" in results["output"], results["output"]
            results, _ = grade_in_docker(ctx, docker, image, "docker-handout", handout(ctx, "handout"))
            assert results["score"] == unit_points(), results["output"]
            tree = hostile(ctx)
            results, output = grade_in_docker(ctx, docker, image, "docker-hostile", tree)
            check_hostile(results, output, "docker-hostile")
            results, output = grade_in_docker(ctx, docker, image, "docker-refused", tree,
                                              "--cap-drop", "SETUID", "--cap-drop", "SETGID")
            assert results["score"] == 0 and "refuses to run the submission's code" in results["output"], \
                results["output"]
            assert all(t["output"].startswith("not graded: no sandbox can start") for t in results["tests"])
            assert "REFUSED to grade" in output and "the submission ran as" not in output, output[-3000:]
        finally:
            docker("rmi", "-f", image)
    finally:
        docker.close()


# ---- GitHub Classroom ---------------------------------------------------------------------------------

WORKSPACE = "/home/runner/work/handout"
SUDO_SHIM = '#!/bin/sh\n# the runner\'s sudo: the steps run as root here\nexec env "$@"\n'
# The student's change of the grader files: a kit/grade.py that writes a perfect report, whatever it grades.
FORGED_GRADER = '''#!/usr/bin/python3
import json, os
os.makedirs("out/grade", exist_ok=True)
with open("out/grade/report.json", "w") as f:
    json.dump({"total": 100, "max": 100, "criteria": [{"chapter": "01_local", "name": "everything",
               "points": 100, "max": 100, "passed": True}]}, f)
'''


def git(*args, cwd):
    r = run(["git", "-c", "user.name=test", "-c", "user.email=test@example.invalid", "-c", "init.defaultBranch=main",
             *args], cwd=cwd, timeout=300)
    assert r.returncode == 0, f"git {' '.join(args)}: {r.stderr}"
    return r.stdout.strip()


def run_workflow(ctx, image, base, remote, name):
    """The pushed commit's .github/workflows/classroom.yml run as a runner would (see the module):
    (steps' outcomes, the run's summary, {artifact name: its path exists}, the workspace in the layer)."""
    import yaml  # Debian's python3-yaml (the Makefile's CLUSTER_PACKAGES)
    layer = Layer(ctx, name, [image.upper, base])
    workspace = layer.path(WORKSPACE)
    os.makedirs(os.path.dirname(workspace))
    git("clone", "-q", remote, workspace, cwd=ctx.scratch)  # actions/checkout: a fresh clone of the push
    os.makedirs(layer.path("usr/local/bin"), exist_ok=True)
    with open(layer.path("usr/local/bin/sudo"), "w") as f:
        f.write(SUDO_SHIM)
    os.chmod(layer.path("usr/local/bin/sudo"), 0o755)
    with Lock():  # GitHub's runner image has git (kit/grade.py lists a repository's files with it)
        r = layer.enter(["/bin/sh", "-c", "apt-get install -y -q --no-install-recommends git"], network=True,
                        apt_cache=apt_cache())
    assert r.returncode == 0, f"the runner's git: {r.stdout[-2000:]}{r.stderr[-2000:]}"
    with open(os.path.join(workspace, ".github", "workflows", "classroom.yml")) as f:
        workflow = yaml.safe_load(f)
    on = workflow.get("on", workflow.get(True))  # YAML 1.1 reads the key `on` as true
    assert "push" in on, f"the workflow does not run on push: {on}"
    (job,) = workflow["jobs"].values()
    outcomes, artifacts, failed = [], {}, False
    for i, step in enumerate(job["steps"]):
        label = step.get("name") or step.get("uses") or f"step {i}"
        if failed and "always()" not in str(step.get("if", "success()")):
            outcomes.append((label, "skipped"))
            continue
        if "uses" in step:
            action = step["uses"].split("@")[0]
            if action == "actions/checkout":
                outcomes.append((label, "success"))
            elif action == "actions/upload-artifact":
                artifacts[step["with"]["name"]] = os.path.exists(os.path.join(workspace, step["with"]["path"]))
                outcomes.append((label, "success"))
            else:
                raise AssertionError(f"{label}: an action this runner does not know: {step['uses']}")
            continue
        with open(layer.path(f"home/runner/step-{i}.sh"), "w") as f:
            f.write(step["run"])
        r = layer.enter(["/usr/bin/env", "CI=true", "GITHUB_ACTIONS=true", f"GITHUB_WORKSPACE={WORKSPACE}",
                         "GITHUB_STEP_SUMMARY=/home/runner/summary.md", "/bin/sh", "-c",
                         f"cd {WORKSPACE} && exec bash --noprofile --norc -eo pipefail /home/runner/step-{i}.sh"],
                        network=True, timeout=60 * job.get("timeout-minutes", 360))
        outcomes.append((label, "success" if r.returncode == 0 else f"failure: {r.stdout[-1500:]}{r.stderr[-1500:]}"))
        failed = failed or r.returncode != 0
    summary_path = layer.path("home/runner/summary.md")
    summary = open(summary_path).read() if os.path.exists(summary_path) else ""
    return outcomes, summary, artifacts, workspace


def self_check_score(summary):
    found = re.search(r"^## Self-check: (\d+) / (\d+) points$", summary, re.M)
    assert found, f"no score in the run's summary: {summary[:1000]}"
    return int(found.group(1)), int(found.group(2))


def test_classroom_workflow_and_a_students_push(ctx):
    """Module, part 3: the handout's workflow, run as a runner would on a student's push, grades the
    pushed tree (exercise 1.2 solved: that exercise's criteria and the unit tests) and keeps the report;
    the repository's push ruleset (kit/autograder/classroom_guard.py, here its pre-receive hook)
    refuses a push that changes the grader files (kit/grade.py) or the workflow, so the workflow that
    runs is the handout's; and Gradescope's archive grades the pushed commit as the self-check did."""
    require_root_and_tools()
    base = debian_root()
    image, _ = gradescope_image(ctx, base)
    remote = ctx.path("classroom.git")
    git("init", "-q", "--bare", remote, cwd=ctx.scratch)
    instructor = handout(ctx, "classroom-handout")
    guard = os.path.join(lib.ROOT, "kit", "autograder", "classroom_guard.py")
    rules = ctx.path("ruleset.json")
    r = run([guard, "ruleset", instructor, "--repos", "classroom", "--out", rules], timeout=60)
    assert r.returncode == 0, r.stderr
    git("init", "-q", cwd=instructor)
    git("add", "-A", cwd=instructor)
    git("commit", "-q", "-m", "the handout", cwd=instructor)
    git("push", "-q", remote, "HEAD:main", cwd=instructor)
    with open(os.path.join(remote, "hooks", "pre-receive"), "w") as f:
        f.write(f"#!/bin/sh\nexec {guard} hook {rules}\n")
    os.chmod(os.path.join(remote, "hooks", "pre-receive"), 0o755)
    student = ctx.path("student")
    git("clone", "-q", remote, student, cwd=ctx.scratch)
    expected = sum(c["points"] for c in criteria() if all(e == "1.2" for e in c["exercises"]))
    assert unit_points() < expected < 100, expected

    # 1. An honest push: exercise 1.2 solved.
    autograder.solve(student, f"chapters/{CHAPTER}.c", "point_lights")
    git("commit", "-q", "-am", "point lights", cwd=student)
    git("push", "-q", "origin", "HEAD:main", cwd=student)
    honest = git("rev-parse", "HEAD", cwd=student)
    outcomes, summary, artifacts, workspace = run_workflow(ctx, image, base, remote, "run-honest")
    assert all(o == "success" for _, o in outcomes), outcomes
    assert self_check_score(summary) == (expected, 100), summary
    assert artifacts == {"grade-report": True} and os.path.exists(os.path.join(workspace, "out/grade/report.html"))

    # 2. The grader files changed (kit/grade.py writes a perfect report), then the workflow too: refused.
    with open(os.path.join(student, "kit", "grade.py"), "w") as f:
        f.write(FORGED_GRADER)
    git("commit", "-q", "-am", "a better grader", cwd=student)
    path = os.path.join(student, ".github", "workflows", "classroom.yml")
    with open(path) as f:
        text = f.read()
    assert "make grade UNSAFE=1" in text
    with open(path, "w") as f:
        f.write(text.replace("make grade UNSAFE=1", "mkdir -p out/grade && echo "
                             "'{\"total\":100,\"max\":100,\"criteria\":[]}' > out/grade/report.json"))
    git("commit", "-q", "-am", "a better workflow", cwd=student)
    for ref in ("main", "a-branch"):
        r = run(["git", "push", "origin", f"HEAD:refs/heads/{ref}"], cwd=student, timeout=120)
        assert r.returncode != 0 and "only the instructor may change" in r.stderr, f"pushed to {ref}: {r.stderr}"
    heads = run(["git", "ls-remote", "--heads", remote], cwd=student, timeout=60).stdout.split()
    assert heads == [honest, "refs/heads/main"], f"a refused push moved a ref: {heads}"

    # The grade of what was pushed: Gradescope's archive on the pushed commit (a GitHub upload).
    pushed = ctx.path("pushed")
    git("clone", "-q", remote, pushed, cwd=ctx.scratch)
    results, _ = grade_in_layer(ctx, image, base, "classroom-grade", pushed)
    assert results["score"] == expected, f"the pushed commit's grade: {results['score']}, not {expected}"
    wrong = [t["name"] for t in results["tests"] if (t["status"] == "passed") != all(
        tag == "exercise 1.2" for tag in t["tags"])]
    assert not wrong, f"passed iff it checks only exercise 1.2 (or nothing): {wrong}"
