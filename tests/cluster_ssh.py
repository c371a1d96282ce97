"""A class graded over ssh on hosts this test makes, one of them lost in the middle (`make test-cluster`).

The hosts: each an sshd (Debian's openssh-server) in a network namespace of its own (`ip netns`),
reached from here through a veth pair on a private /30 that nothing else on the machine uses, with
its own host key, a client key the test makes, and its own hostname (a UTS namespace).  Every host
has its own copy of the grader: the project's tracked files, copied per host and bind-mounted in the
host's own mount namespace at one path (Cluster.grader), which is empty here on the controller: a grading
that ran anywhere but on a host would find no grader there.  The submissions and the class report
are on the file system the hosts share with the controller, as they would be on NFS (kit/grade_class.py
--remote-root).  Each host has its own temporary directory (sshd's SetEnv TMPDIR).  The only
network traffic is ssh to these hosts' addresses; every wait has a bound, and the namespaces, the
sshd processes, the gradings and the files are removed at the end, on a failure too.

The class (CLASS_SIZE submissions, chapter 1, a small rubric: build_class) is graded twice: over ssh,
with one host's network and every process (sshd, its gradings and their sandboxes) killed while it
grades, and on this machine alone; each student must end with exactly one report, the joblog and the
summary must agree with the reports, and the totals of both runs must be equal student by student.
"""
import csv
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import lib

ROOT = lib.ROOT
PY = "/usr/bin/python3"
HOSTS = 2                  # sshd hosts; each grades one submission at a time (the machine has 2 cores)
# One class at a time (tests/run.py): two would share the 2 cores the hosts' single slots stand for, and
# /run/sshd, which the first to finish removes if it made it.
RUN_IN_SEQUENCE = True


def run(cmd, timeout=60, check=True, **kw):
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL, **kw)
    if check and r.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)}: exit {r.returncode}: {r.stderr[-1500:]}")
    return r


def missing_tools():
    """What this machine lacks for the hosts (None when nothing)."""
    for tool in ("ip", "nsenter", "unshare", "ssh", "ssh-keygen", "parallel", "bwrap"):
        if not shutil.which(tool):
            return f"{tool} is missing (make deps-cluster installs CLUSTER_PACKAGES)"
    if not os.path.exists("/usr/sbin/sshd"):
        return "/usr/sbin/sshd is missing (openssh-server; make deps-cluster)"
    if os.geteuid() != 0:
        return "not root: network namespaces need root"
    return None


def used_networks():
    """The IPv4 networks this machine has addresses or routes on."""
    text = run(["ip", "-o", "-4", "addr"]).stdout + run(["ip", "-4", "route"]).stdout
    return set(re.findall(r"(\d+\.\d+\.\d+)\.\d+", text))


def process_tree(roots):
    """roots and every descendant of theirs (by /proc's parent links)."""
    children = {}
    for name in os.listdir("/proc"):
        if name.isdigit():
            try:
                with open(f"/proc/{name}/stat") as f:
                    parent = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(parent, []).append(int(name))
    found, todo = set(), list(roots)
    while todo:
        p = todo.pop()
        if p not in found:
            found.add(p)
            todo += children.get(p, [])
    return found


def signal_all(pids, sig):
    for p in pids:
        try:
            os.kill(p, sig)
        except ProcessLookupError:
            pass


class Cluster:
    """HOSTS sshd hosts in network namespaces; see the module.  Use as a context manager."""

    def __init__(self, top, count=HOSTS):
        self.top, self.count = top, count
        self.tag = f"gs{os.getpid() % 10 ** 7}"
        self.names = [f"gi-host{i + 1}" for i in range(count)]
        self.namespaces = [f"{self.tag}-{name}" for name in self.names]
        self.links = [f"{self.tag}h{i + 1}" for i in range(count)]  # this side's end of each veth pair
        self.sshd, self.addresses, self.killed_graders = [], [], []
        self.made_run_sshd = False
        self.ssh_config = os.path.join(top, "ssh_config")
        self.grader = os.path.join(top, "grader")  # each host sees its own copy of the grader here (empty here)

    def __enter__(self):
        # SIGTERM (a runner or CI stopping the test) ends it through close() too
        self.old_handler = signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc):
        try:
            self.close()
        finally:
            signal.signal(signal.SIGTERM, self.old_handler)

    def subnet(self):
        """A 10.x.y.0/24 that no address or route of the machine is on (the hosts' /30s are in it)."""
        used = used_networks()
        for k in range(200):
            n = (os.getpid() + 7919 * k) % 60000
            prefix = f"10.{200 + n // 1000 % 50}.{n % 250}"
            if prefix not in used:
                return prefix
        raise AssertionError("no free private /24 for the test hosts")

    def start(self):
        os.makedirs(self.top, exist_ok=True)
        # the sandbox's uid must pass through to each host's temporary directory (grade.py's scratch there)
        for d in (os.path.dirname(self.top), self.top):
            os.chmod(d, os.stat(d).st_mode | 0o111)
        if not os.path.isdir("/run/sshd"):  # sshd's privilege separation directory
            os.makedirs("/run/sshd", mode=0o755)
            self.made_run_sshd = True
        key = os.path.join(self.top, "client_key")
        run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", "gi-cluster-test", "-f", key])
        prefix = self.subnet()
        known, config = [], []
        for i, (name, ns, link) in enumerate(zip(self.names, self.namespaces, self.links)):
            home = os.path.join(self.top, name)
            os.makedirs(os.path.join(home, "tmp"), mode=0o711)
            os.chmod(home, 0o711)
            os.makedirs(os.path.join(home, "root"), mode=0o700)
            host_key = os.path.join(home, "host_key")
            run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", name, "-f", host_key])
            mine, theirs = f"{prefix}.{4 * i + 1}", f"{prefix}.{4 * i + 2}"
            run(["ip", "netns", "add", ns])
            run(["ip", "link", "add", link, "type", "veth", "peer", "name", "eth0", "netns", ns])
            run(["ip", "addr", "add", f"{mine}/30", "dev", link])
            run(["ip", "link", "set", link, "up"])
            for cmd in (["ip", "addr", "add", f"{theirs}/30", "dev", "eth0"], ["ip", "link", "set", "eth0", "up"],
                        ["ip", "link", "set", "lo", "up"]):
                run(["ip", "netns", "exec", ns, *cmd])
            self.addresses.append(theirs)
            with open(key + ".pub") as f:
                authorized = self.write(os.path.join(home, "authorized_keys"), f.read())
            sshd_config = self.write(os.path.join(home, "sshd_config"), "\n".join([
                f"ListenAddress {theirs}:22", f"HostKey {host_key}", f"AuthorizedKeysFile {authorized}",
                f"PidFile {home}/sshd.pid", "PermitRootLogin prohibit-password", "PasswordAuthentication no",
                "KbdInteractiveAuthentication no", "UsePAM no", "StrictModes no", "X11Forwarding no",
                "AllowTcpForwarding no", "PermitTunnel no", "MaxStartups 30", "MaxSessions 30",
                "ClientAliveInterval 5", "ClientAliveCountMax 3", f"SetEnv TMPDIR={home}/tmp", ""]))
            grader = self.copy_grader(os.path.join(home, "grader"))
            # its own hostname (UTS), its own grader at self.grader and its own root's home (mount namespace:
            # the shells of its sessions run no start-up file of this machine's root, and a host lost in
            # the middle leaves no lock of theirs behind), then sshd.  (nsenter, not `ip netns exec`,
            # which mounts a sysfs of its own over /sys and its cgroups.)
            script = (f"hostname {name} && mount --bind {grader} {self.grader} && "
                      f"mount --bind {home}/root {os.path.expanduser('~root')} && "
                      f"exec /usr/sbin/sshd -D -e -f {sshd_config}")
            with open(os.path.join(home, "sshd.log"), "w") as log:
                self.sshd.append(subprocess.Popen(
                    ["nsenter", f"--net=/run/netns/{ns}", "unshare", "--mount", "--uts", "--propagation",
                     "private", "sh", "-c", script], stdin=subprocess.DEVNULL, stdout=log, stderr=log))
            with open(host_key + ".pub") as f:
                known.append(f"{theirs} {' '.join(f.read().split()[:2])}")
            config += [f"Host {name}", f"  HostName {theirs}", "  User root", f"  IdentityFile {key}",
                       "  IdentitiesOnly yes", f"  UserKnownHostsFile {self.top}/known_hosts",
                       "  GlobalKnownHostsFile /dev/null", "  StrictHostKeyChecking yes", "  BatchMode yes",
                       "  ConnectTimeout 5", "  ServerAliveInterval 2", "  ServerAliveCountMax 3",
                       "  LogLevel ERROR", ""]
        self.write(os.path.join(self.top, "known_hosts"), "\n".join(known) + "\n")
        self.write(self.ssh_config, "\n".join(config))
        for name in self.names:
            self.wait_for(name)

    def write(self, path, text):
        with open(path, "w") as f:
            f.write(text)
        return path

    def copy_grader(self, dst):
        """The project's tracked files (as they are in the work tree) and nothing else."""
        os.makedirs(self.grader, exist_ok=True)
        files = run(["git", "ls-files", "-z"], cwd=ROOT).stdout.split("\0")
        for rel in files:
            if rel and not rel.startswith(("slides/", "docs/", "bench/", "tradeoff/")) and \
                    os.path.isfile(os.path.join(ROOT, rel)):
                os.makedirs(os.path.dirname(os.path.join(dst, rel)) or dst, exist_ok=True)
                shutil.copy2(os.path.join(ROOT, rel), os.path.join(dst, rel))
        return dst

    def ssh(self, name, *command, timeout=20):
        """ssh to the host: CompletedProcess (None when it took more than `timeout` seconds)."""
        try:
            return run(["ssh", "-F", self.ssh_config, name, "--", *command], timeout=timeout, check=False)
        except subprocess.TimeoutExpired:
            return None

    def wait_for(self, name):
        """Until the host answers over ssh (at most 60 s: the machine may be busy)."""
        deadline, last = time.time() + 60, None
        while time.time() < deadline:
            index = self.names.index(name)
            if self.sshd[index].poll() is not None:
                with open(os.path.join(self.top, name, "sshd.log")) as f:
                    raise AssertionError(f"sshd of {name} ended: {f.read()[-1500:]}")
            last = self.ssh(name, "hostname", timeout=20) or last
            if last and last.returncode == 0:
                assert last.stdout.strip() == name, f"{name} calls itself {last.stdout.strip()!r}"
                return
            time.sleep(0.3)
        raise AssertionError(f"{name} did not answer over ssh in 60 s: {last.stderr[-800:] if last else ''}")

    def pids(self, index):
        """The host's processes and all their descendants (a sandbox has a network namespace of its own)."""
        r = run(["ip", "netns", "pids", self.namespaces[index]], check=False)
        roots = [int(p) for p in r.stdout.split()]
        if self.sshd[index].poll() is None:
            roots.append(self.sshd[index].pid)
        return process_tree(roots)

    def lose(self, index):
        """The host is lost: its network first (no goodbye reaches the controller), then every process
        it runs (sshd, the gradings, their sandboxes) killed at once.  The grader pids killed are kept
        (their cgroups are removed at the end, as a rebooted machine would have none)."""
        run(["ip", "link", "set", self.links[index], "down"], check=False)
        for _ in range(5):  # stopped first, so that none forks a child that escapes the kill
            pids = self.pids(index)
            signal_all(pids, signal.SIGSTOP)
        for p in pids:
            try:
                with open(f"/proc/{p}/cmdline", "rb") as f:
                    if b"kit/grade.py" in f.read():
                        self.killed_graders.append(p)
            except OSError:
                pass
        signal_all(pids, signal.SIGKILL)
        self.sshd[index].wait(timeout=30)

    def close(self):
        for i in range(len(self.sshd)):
            if self.sshd[i].poll() is None or self.pids(i):
                pids = self.pids(i)
                signal_all(pids, signal.SIGSTOP)
                signal_all(pids, signal.SIGKILL)
                try:
                    self.sshd[i].wait(timeout=30)
                except subprocess.TimeoutExpired:
                    pass
        sys.path.insert(0, os.path.join(ROOT, "kit"))
        import sandbox
        for p in self.killed_graders:  # a grader killed with its host leaves its (empty) cgroups
            sandbox.remove_groups(f"gi-sandbox-{p}")
        for ns in self.namespaces:  # deleting the namespace deletes its veth pair
            run(["ip", "netns", "del", ns], check=False)
        for link in self.links:
            run(["ip", "link", "del", link], check=False)
        if self.made_run_sshd:
            shutil.rmtree("/run/sshd", ignore_errors=True)
        shutil.rmtree(self.top, ignore_errors=True)


# ---- the class -------------------------------------------------------------------------------------

CHAPTER = "chapters/01_local.c"
# A small rubric of chapter 1's (about 10-30 s a grading, most of it the build): five criteria and a unit test.
CRITERIA = ("point light pixel is R1", "point light probe inverse square cosine", "shadow ray blocks point light",
            "area light probe converges to lambert formula", "blinn phong pixel classic and normalised",
            "unit tests test_common")
CLASS_OPTIONS = ["--chapters", "01_local", "--seed", "7", "--timeout", "40", "--memory", "1024"]
# C run before main in every run of the chapter (kit/grade.py runs the submission's programs in its sandbox)
HANG = "for (volatile int i = 0;; i++) continue;"
SEGFAULT = "raise(SIGSEGV);"
MEMORY = "volatile char *m = malloc(3L << 30); for (long j = 0; m && j < (3L << 30); j += 4096) m[j] = 1;"
OUTPUT = ("signal(SIGXFSZ, SIG_DFL); static char block[1 << 20]; memset(block, 'x', sizeof block);"
          "for (int i = 0; i < 600; i++) if (fwrite(block, 1, sizeof block, stdout) != sizeof block) break;")


def class_rubric(path):
    with open(os.path.join(ROOT, "kit", "rubric.json")) as f:
        rub = json.load(f)
    rub["criteria"] = [c for c in rub["criteria"] if c["chapter"] == "01_local" and c["name"] in CRITERIA]
    assert len(rub["criteria"]) == len(CRITERIA), [c["name"] for c in rub["criteria"]]
    with open(path, "w") as f:
        json.dump(rub, f)
    return path


def chapter_tree(top, text):
    os.makedirs(os.path.join(top, "chapters"))
    with open(os.path.join(top, CHAPTER), "w") as f:
        f.write(text)
    return top


def with_constructor(text, body):
    return text + ("\n#include <signal.h>\n#include <stdio.h>\n#include <stdlib.h>\n#include <string.h>\n"
                   "__attribute__((constructor)) static void class_probe(int argc, char **argv)\n{\n"
                   f"    (void)argc, (void)argv;\n    {body}\n}}\n")


def build_class(ctx, top, victim):
    """The class: {student: kind} with the submissions in top/<student>.  The solution (8 times), a
    plain chapter-1 handout (6), handouts with one exercise solved (6), the mutants that apply to
    chapter 1 alone, and buggy or hostile ones: a hang, a crash, 3 GiB of memory, 600 MiB of output,
    a compile error, the sandbox tests' hostile submission (its classmate `victim`), an empty
    directory, and three the kit refuses (a FIFO, a link out, a missing directory)."""
    import grade_sandbox
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import markers
    os.makedirs(top)
    with open(os.path.join(ROOT, CHAPTER)) as f:
        solution = f.read()
    kinds = {}
    for i in range(8):
        chapter_tree(os.path.join(top, f"full-{i + 1}"), solution)
        kinds[f"full-{i + 1}"] = "full"
    handout = os.path.join(ctx.scratch, "handout")
    r = run(["make", "--no-print-directory", "handout", f"OUT={handout}", "CHAPTERS=01_local"], cwd=ROOT, timeout=300)
    for i in range(6):
        shutil.copytree(handout, os.path.join(top, f"handout-{i + 1}"), symlinks=True)
        kinds[f"handout-{i + 1}"] = "handout"
    answers = {e.name: e for e in markers.parse_file(ROOT, CHAPTER)}
    for k, name in enumerate(sorted(answers) * 2):
        student = f"solved-{name}-{k // len(answers) + 1}"
        tree = shutil.copytree(handout, os.path.join(top, student), symlinks=True)
        stub = {e.name: e for e in markers.parse_file(tree, CHAPTER)}[name]
        with open(os.path.join(tree, CHAPTER)) as f:
            text = f.read()
        with open(os.path.join(tree, CHAPTER), "w") as f:
            f.write(text[:stub.body_start] + answers[name].body + text[stub.body_end:])
        kinds[student] = "partial"
    for patch in sorted(os.listdir(os.path.join(ROOT, "tests", "mutants"))):
        tree = chapter_tree(os.path.join(top, "mutant-" + patch.split("_")[0]), solution)
        r = run(["patch", "-s", "-p1", "-i", os.path.join(ROOT, "tests", "mutants", patch)], cwd=tree, check=False)
        if r.returncode != 0 or os.listdir(tree) != ["chapters"] or os.listdir(os.path.join(tree, "chapters")) != \
                ["01_local.c"]:
            shutil.rmtree(tree)  # a mutant of another file
            continue
        kinds[os.path.basename(tree)] = "mutant"
    for student, body in (("hangs", HANG), ("crashes", SEGFAULT), ("memory-hog", MEMORY), ("output-hog", OUTPUT)):
        chapter_tree(os.path.join(top, student), with_constructor(solution, body))
        kinds[student] = student
    chapter_tree(os.path.join(top, "compile-error"), solution + "\nthis is not C;\n")
    kinds["compile-error"] = "compile-error"
    grade_sandbox.submission(ctx, os.path.join(top, "hostile"), grade_sandbox.hostile_constructor(victim))
    kinds["hostile"] = "hostile"
    os.makedirs(os.path.join(top, "empty"))
    kinds["empty"] = "empty"
    os.mkfifo(os.path.join(chapter_tree(os.path.join(top, "refused-fifo"), solution), "chapters", "pipe"))
    os.symlink(os.path.join(ROOT, "kit", "rubric.json"),
               os.path.join(chapter_tree(os.path.join(top, "refused-link"), solution), "chapters", "ref.json"))
    kinds["refused-fifo"] = kinds["refused-link"] = kinds["refused-missing"] = "refused"
    return kinds


# ---- checks of a class's report ----------------------------------------------------------------------

def summary_rows(report):
    with open(os.path.join(report, "summary.csv")) as f:
        return {row["student"]: row for row in csv.DictReader(f)}


def check_reports(report, kinds, rows):
    """Exactly one report.json per graded student, in its own directory, none for the others; no
    attempt's directory left; each verdict as its kind says."""
    found = []
    for top, dirs, files in os.walk(report):
        found += [os.path.relpath(top, report) for f in files if f == "report.json"]
    graded = sorted(n for n, row in rows.items() if row["status"] == "graded")
    assert sorted(found) == graded, f"report.json files {sorted(found)} against the graded students {graded}"
    assert sorted(rows) == sorted(kinds), f"summary rows {sorted(rows)} against the class {sorted(kinds)}"
    for name, kind in kinds.items():
        row = rows[name]
        if kind == "refused":
            assert row["status"].startswith("not graded: "), (name, row["status"])
            continue
        assert row["status"] == "graded", (name, row["status"])
        total, top = int(row["total"]), int(row["max"])
        if kind == "full":
            assert total == top == 45, (name, total, top)
        elif kind in ("handout", "empty", "compile-error", "hostile", "hangs", "crashes", "memory-hog",
                      "output-hog"):
            assert total < top, (name, kind, total)
    if "hangs" in kinds:  # the whole class of build_class
        limits = {name: rows[name]["limits"] for name in ("hangs", "memory-hog", "output-hog")}
        assert ": time" in limits["hangs"] and ": memory" in limits["memory-hog"] and \
            ": file size" in limits["output-hog"], limits
    assert not any(rows[n]["limits"] for n, kind in kinds.items() if kind == "full"), "a solution hit a limit"


def check_plots(report, rows):
    """scores.svg has one bar per tenth of the maximum with the number of graded totals in it, its
    height proportional; criteria.svg one bar per criterion with the number that passed it."""
    graded = [r for r in rows.values() if r["status"] == "graded"]
    top = int(graded[0]["max"])
    expected = [0] * 10
    for r in graded:
        expected[min(9, int(r["total"]) * 10 // top)] += 1
    with open(os.path.join(report, "scores.svg")) as f:
        svg = f.read()
    bars = re.findall(r"<rect class='bar' data-low='[^']*' data-high='[^']*' data-count='(\d+)' x='[^']*' "
                      r"y='[^']*' width='[^']*' height='([^']*)'", svg)
    assert [int(c) for c, _ in bars] == expected, f"histogram {bars} against totals {expected}"
    unit = max(float(h) / int(c) for c, h in bars if int(c))
    assert all(abs(float(h) - unit * int(c)) < 0.02 for c, h in bars), f"bar heights not proportional: {bars}"
    with open(os.path.join(report, "criteria.csv")) as f:
        passed = {}
        for row in csv.DictReader(f):
            passed[row["criterion"]] = passed.get(row["criterion"], 0) + (row["passed"] == "True")
    with open(os.path.join(report, "criteria.svg")) as f:
        svg = f.read()
    bars = re.findall(r"<rect class='bar' data-passed='(\d+)' data-graded='(\d+)'", svg)
    assert [int(p) for p, _ in bars] == [passed[c] for c in CRITERIA] and \
        all(int(g) == len(graded) for _, g in bars), f"pass rates {bars} against {passed}"
    with open(os.path.join(report, "summary.html")) as f:
        page = f.read()
    for part in ("scores.svg", "criteria.svg", "Slowest gradings", "Submissions that hit a limit", "memory-hog"):
        assert part in page, f"summary.html lacks {part}"


def check_joblog(report, rows):
    """GNU parallel's log: for every student a last row that ended well (exit 0: graded or refused),
    from the machine that graded it; no student twice among the graded rows."""
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import grade_class
    status = grade_class.read_joblog(os.path.join(report, "joblog.tsv"))
    assert sorted(status) == sorted(rows), f"joblog students {sorted(status)} against {sorted(rows)}"
    for name, s in status.items():
        assert s["exit"] == "0", (name, s)
        if rows[name]["status"] == "graded":
            assert s["host"] == rows[name]["host"], f"{name}: joblog says {s['host']}, its attempt {rows[name]['host']}"
    with open(os.path.join(report, "joblog.tsv")) as f:
        ok = [ln.split("\t")[-1].split()[3] for ln in f.read().splitlines()[1:] if ln.split("\t")[6] == "0"]
    assert len(ok) == len(set(ok)), f"a student graded twice in the joblog: {sorted(ok)}"


def check_slots(report, names):
    """No host ran two gradings at once (the login file gives each one slot): its attempts' times do not
    overlap (a lost attempt, which never ended, counts till the next one of that host starts)."""
    spans = {}
    top = os.path.join(report, ".attempts")
    for student in os.listdir(top):
        for f in os.listdir(os.path.join(top, student)):
            if f.endswith(".json"):
                with open(os.path.join(top, student, f)) as fh:
                    a = json.load(fh)
                spans.setdefault(a["host"], []).append((a["started"], a["ended"], student))
    assert set(spans) <= set(names), f"attempts on {sorted(spans)}, not only on {names}"
    for host, attempts in spans.items():
        attempts.sort(key=lambda a: a[0])
        for (s0, e0, n0), (s1, _, n1) in zip(attempts, attempts[1:]):
            assert e0 is not None and e0 <= s1, f"{host} graded {n0} and {n1} at once"


# ---- the test --------------------------------------------------------------------------------------

def grade_class_command(report, rubric, *extra):
    return [PY, os.path.join(ROOT, "kit", "grade_class.py"), "--report", report, "--rubric", rubric,
            *CLASS_OPTIONS, *extra]


def test_class_over_ssh_survives_a_lost_host_and_scores_as_one_machine(ctx):
    """The class over HOSTS ssh hosts, gi-host1 lost while it grades: every student ends with exactly one
    report (or its refusal), those gi-host1 was grading regraded on another host and said so in the
    summary, the joblog consistent with the reports, the plots with the totals; then the same class
    with the same seed on this machine alone gives every student the same total."""
    why = missing_tools()
    assert why is None, why
    if "asan" in ctx.build:
        return
    start = time.time()
    ssh_report, local_report = ctx.path("ssh-report"), ctx.path("local-report")
    kinds = build_class(ctx, ctx.path("class"), os.path.join(ssh_report, "full-1", "report.json"))
    assert len(kinds) >= 40, f"a class of {len(kinds)}"
    rubric = class_rubric(ctx.path("rubric.json"))
    dirs = [os.path.join(ctx.path("class"), n) for n in kinds]
    listing = ctx.write("class.txt", "\n".join(dirs) + "\n")
    made = time.time()
    with Cluster(ctx.path("hosts")) as cluster:
        up = time.time()
        logins = ctx.write("logins", "".join(f"1/{name}\n" for name in cluster.names))
        with open(ctx.path("ssh-class.log"), "w") as log:
            p = subprocess.Popen(grade_class_command(ssh_report, rubric, "--sshloginfile", logins, "--ssh",
                                                     f"ssh -F {cluster.ssh_config}", "--remote-root", cluster.grader,
                                                     "@" + listing), stdout=log, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            lost, lost_at = wait_and_lose(cluster, p, ssh_report, len(kinds))
            p.wait(timeout=3600)
        finally:  # on a failure: grade_class.py, GNU parallel and its ssh clients
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        ssh_seconds = time.time() - up
        with open(ctx.path("ssh-class.log")) as f:
            assert p.returncode == 0, f"grade_class.py over ssh: exit {p.returncode}: {f.read()[-3000:]}"
        rows = summary_rows(ssh_report)
        check_reports(ssh_report, kinds, rows)
        check_joblog(ssh_report, rows)
        check_plots(ssh_report, rows)
        check_slots(ssh_report, cluster.names)
        hosts = {row["host"] for row in rows.values()}
        assert hosts == set(cluster.names), f"graded by {hosts}, not by both hosts"
        for name in lost:
            attempts = rows[name]["attempts"].split("+")
            assert attempts[0] == cluster.names[0] and rows[name]["host"] != cluster.names[0] and \
                len(attempts) >= 2, f"{name}, lost with {cluster.names[0]}: attempts {attempts}, " \
                                    f"host {rows[name]['host']}"
        retried = {n for n, row in rows.items() if "+" in row["attempts"]}
        assert retried >= set(lost), (retried, lost)
        with open(os.path.join(ssh_report, "summary.html")) as f:
            page = f.read()
        assert all(f"<td>{n}</td><td>{cluster.names[0]} + " in page for n in lost), "the summary hides a retry"
    local_start = time.time()
    r = run(grade_class_command(local_report, rubric, "--jobs", str(HOSTS), "@" + listing), timeout=3600,
            check=False)
    local_seconds = time.time() - local_start
    assert r.returncode == 0, f"grade_class.py here: exit {r.returncode}: {r.stderr[-2000:]}"
    local = summary_rows(local_report)
    check_reports(local_report, kinds, local)
    differ = {n: (rows[n]["total"], local[n]["total"]) for n in kinds if rows[n]["total"] != local[n]["total"]}
    assert not differ, f"the same seed gave other totals over ssh and here (ssh, here): {differ}"
    with open(os.path.join(ssh_report, "full-1", "report.json")) as f:
        assert json.load(f)["total"] == 45, "the hostile submission changed its classmate's report"
    print(f"cluster_ssh: a class of {len(kinds)} ({sum(1 for r in rows.values() if r['status'] == 'graded')} "
          f"graded) made in {made - start:.0f} s; {HOSTS} hosts up in {up - made:.0f} s; graded over ssh in "
          f"{ssh_seconds:.0f} s, {cluster.names[0]} lost after {lost_at:.0f} s with {len(lost)} grading(s) "
          f"({', '.join(lost)}), regraded; graded here in {local_seconds:.0f} s", flush=True)


def wait_and_lose(cluster, p, report, size):
    """Once about two thirds of the class have reports and the first host is grading (an attempt of its that
    started over 3 s ago), lose that host; (students it was grading, seconds since the start)."""
    start = time.time()
    while time.time() - start < 1800:
        if p.poll() is not None:
            raise AssertionError("the class ended before a host could be lost")
        done = sum(1 for n in os.listdir(report) if os.path.exists(os.path.join(report, n, "report.json"))) \
            if os.path.isdir(report) else 0
        running = running_on(report, cluster.names[0], older_than=3)
        if done >= size * 2 // 3 and running:
            cluster.lose(0)
            time.sleep(1)
            return sorted(running), time.time() - start
        time.sleep(0.5)
    raise AssertionError("no moment to lose a host in 30 minutes")


def running_on(report, host, older_than):
    """The students whose attempt on host has not ended and started over older_than seconds ago."""
    found = set()
    top = os.path.join(report, ".attempts")
    for name in os.listdir(top) if os.path.isdir(top) else []:
        for f in os.listdir(os.path.join(top, name)):
            if f.startswith(host + "-") and f.endswith(".json"):
                try:
                    with open(os.path.join(top, name, f)) as fh:
                        a = json.load(fh)
                except (OSError, ValueError):
                    continue
                if a.get("ended") is None and time.time() - a["started"] > older_than:
                    found.add(name)
    return found


def test_the_last_pass_regrades_a_lost_hosts_students_over_ssh(ctx):
    """With --retries 1 nothing a lost host was grading is tried again in the first pass: the last pass
    (GNU parallel's --resume-failed) must regrade it, and every student must still end with exactly one
    report, graded by the host that is left.  A small class (solutions and plain handouts) over two
    hosts, the first lost while it grades."""
    why = missing_tools()
    assert why is None, why
    if "asan" in ctx.build:
        return
    report = ctx.path("report")
    top = ctx.path("class")
    with open(os.path.join(ROOT, CHAPTER)) as f:
        solution = f.read()
    handout = os.path.join(ctx.scratch, "handout")
    run(["make", "--no-print-directory", "handout", f"OUT={handout}", "CHAPTERS=01_local"], cwd=ROOT, timeout=300)
    kinds = {}
    for i in range(3):
        chapter_tree(os.path.join(top, f"full-{i + 1}"), solution)
        shutil.copytree(handout, os.path.join(top, f"handout-{i + 1}"), symlinks=True)
        kinds[f"full-{i + 1}"], kinds[f"handout-{i + 1}"] = "full", "handout"
    listing = ctx.write("class.txt", "".join(os.path.join(top, n) + "\n" for n in sorted(kinds)))
    rubric = class_rubric(ctx.path("rubric.json"))
    with Cluster(ctx.path("hosts")) as cluster:
        logins = ctx.write("logins", "".join(f"1/{name}\n" for name in cluster.names))
        with open(ctx.path("class.log"), "w") as log:
            p = subprocess.Popen(grade_class_command(report, rubric, "--retries", "1", "--sshloginfile", logins,
                                                     "--ssh", f"ssh -F {cluster.ssh_config}", "--remote-root",
                                                     cluster.grader, "@" + listing),
                                 stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                 start_new_session=True)
        try:
            lost, _ = wait_and_lose(cluster, p, report, len(kinds))
            p.wait(timeout=1800)
        finally:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        with open(ctx.path("class.log")) as f:
            output = f.read()
        assert p.returncode == 0, f"grade_class.py: exit {p.returncode}: {output[-3000:]}"
        rows = summary_rows(report)
        check_reports(report, kinds, rows)
        check_joblog(report, rows)
        check_slots(report, cluster.names)
        for name in lost:
            attempts = rows[name]["attempts"].split("+")
            assert attempts[0] == cluster.names[0] and rows[name]["host"] == cluster.names[1], \
                f"{name}, lost with {cluster.names[0]}: attempts {attempts}, host {rows[name]['host']}"
        with open(os.path.join(report, "joblog.tsv")) as f:
            failed_first = [ln.split("\t")[-1].split()[3] for ln in f.read().splitlines()[1:]
                            if ln.split("\t")[6] != "0"]
        assert set(lost) <= set(failed_first), f"the first pass did not fail {lost}: {failed_first}"
        assert f"{cluster.names[0]} does not answer over ssh: left out of the last pass" in output, output[-2000:]
        with open(os.path.join(report, "last-pass-logins")) as f:
            assert f.read() == f"1/{cluster.names[1]}\n"
