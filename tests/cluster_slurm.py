"""A class graded on a real single-machine Slurm (kit/grade_class.py --slurm, kit/slurm_engine.py), a node lost
mid-class.

The test starts its own cluster from Debian's slurm-wlm and munge (make deps-cluster installs them): munged
with a key it makes, slurmctld, and two slurmd "nodes" n1 and n2 on this machine (slurmd -N, Slurm's multiple
slurmd), one CPU each (a 2-core machine grades two submissions at once); slurm.conf, keys, state, spool
and logs are in its scratch directory, the ports free ones it picks, and it stops every daemon and every
process they started when it ends, passed or not.  proctrack/linuxproc and task/none: no cgroup plugin.

The class: 42 submissions of chapter 1 (solutions, the kit's mutant patches of chapter 1 that its rubric
catches, handout stubs, one a whole handout tree, code that does not compile or crashes, a hostile one that
tries to write a classmate's report and kill its grader) and a directory that does not exist, graded with a
five-criterion rubric (kit/grade.py --rubric) and seed 7.  While the array runs, node n2 is lost: its
slurmd, the slurmstepd of its tasks and everything they started are killed (a power cut, not a tidy
shutdown); slurmctld declares it down (SlurmdTimeout 10 s) and ends its tasks NODE_FAIL; n2 then comes back
(ReturnToService=2).  Checked: every submission ends with exactly one report, the killed gradings among
those retried (summary.csv's "retried" column, summary.html), the missing directory "not graded" and not
retried, every report made in the sandbox, the class sent as three job arrays (the cluster's MaxArraySize
is 16) chained by --jobs 2, and each student's report.json (total and points per criterion)
the same as when GNU parallel grades the same class here with the same seed.  11 to 25 min on this 2-core
machine while other work loaded it (load average 3 to 10; Slurm's grading 7 to 15 min with the lost node,
GNU parallel's 4 to 10 min), most of it building chapter 1 in each sandbox.
"""
import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time

import lib

ROOT = lib.ROOT
sys.path.insert(0, os.path.join(ROOT, "kit"))
import sandbox  # noqa: E402

PY = "/usr/bin/python3"
GRADE_CLASS = os.path.join(ROOT, "kit", "grade_class.py")
CHAPTER = "chapters/01_local.c"
RUBRIC_CRITERIA = ("point light pixel is R1", "point light probe inverse square cosine", "shadow ray blocks point light",
                   "area light probe converges to lambert formula", "blinn phong pixel classic and normalised")
SEED = "7"
NODES = ("n1", "n2")
CLASS_TIMEOUT = 2400   # seconds, one grading of the class (Slurm or GNU parallel)
# The cluster's MaxArraySize (Slurm's default 1001): an array's indices stay below it, so the class of 43 goes as
# arrays of 15, 15 and 13, which --jobs 2 chains (each waits for the one before it).
MAX_ARRAY_SIZE = 16
DAEMON_TIMEOUT = 60    # a daemon up, a node declared down, a daemon stopped

# Its two gradings of a class fill both cores, and it kills processes of its own cluster: nothing beside it.
RUN_ALONE = True


def run(argv, timeout=120, **kw):
    return subprocess.run(argv, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL, **kw)


def free_ports(n):
    socks = [socket.socket() for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


# ---- the cluster --------------------------------------------------------------------------------------------

class Cluster:
    """munged, slurmctld and one slurmd per node, all in the foreground (-F, -D) as children of the test,
    everything under `top`."""

    def __init__(self, top):
        self.top = top
        self.conf = os.path.join(top, "slurm.conf")
        self.env = dict(os.environ, SLURM_CONF=self.conf)
        self.daemons = {}  # name: Popen

    def path(self, *parts):
        return os.path.join(self.top, *parts)

    def write_config(self):
        for d in ("munge", "run", "state", "log", *(f"spool/{n}" for n in NODES)):
            os.makedirs(self.path(d), exist_ok=True)
        for d in (os.path.dirname(self.top), self.top):  # munged wants the way to its socket open to all (o+x)
            os.chmod(d, 0o755)
        os.chmod(self.path("run"), 0o755)
        os.chmod(self.path("munge"), 0o700)
        r = run(["mungekey", "--create", "--keyfile", self.path("munge", "munge.key")], timeout=30)
        assert r.returncode == 0, f"mungekey: {r.stderr}"
        host = socket.gethostname()
        ctld, *nodes = free_ports(1 + len(NODES))
        lines = [
            "ClusterName=gradetest", f"SlurmctldHost={host}(127.0.0.1)", f"SlurmctldPort={ctld}",
            "SlurmUser=root", "SlurmdUser=root", "AuthType=auth/munge", "CredType=cred/munge",
            f"AuthInfo=socket={self.path('run', 'munge.sock')}",
            f"StateSaveLocation={self.path('state')}", f"SlurmdSpoolDir={self.path('spool', '%n')}",
            f"SlurmctldPidFile={self.path('run', 'slurmctld.pid')}", f"SlurmdPidFile={self.path('run', 'slurmd-%n.pid')}",
            f"SlurmctldLogFile={self.path('log', 'slurmctld.log')}", f"SlurmdLogFile={self.path('log', 'slurmd-%n.log')}",
            "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/none", "JobAcctGatherType=jobacct_gather/none",
            "AccountingStorageType=accounting_storage/none", "JobCompType=jobcomp/none",
            "SelectType=select/cons_tres", "SelectTypeParameters=CR_Core", "MpiDefault=none", "SwitchType=switch/none",
            "ReturnToService=2", "SlurmdTimeout=10", "SlurmctldTimeout=10", "MinJobAge=3600", "InactiveLimit=0",
            "KillWait=5", f"MaxArraySize={MAX_ARRAY_SIZE}",
            *(f"NodeName={n} NodeHostname={host} NodeAddr=127.0.0.1 Port={p} CPUs=1 RealMemory=4000 State=UNKNOWN"
              for n, p in zip(NODES, nodes)),
            f"PartitionName=grade Nodes={','.join(NODES)} Default=YES MaxTime=INFINITE State=UP",
        ]
        with open(self.conf, "w") as f:
            f.write("\n".join(lines) + "\n")

    def start_daemon(self, name, argv):
        log = open(self.path("log", name + ".out"), "w")
        self.daemons[name] = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                              env=self.env, start_new_session=True)
        log.close()

    def start(self):
        self.write_config()
        self.start_daemon("munged", ["munged", "-F", "-S", self.path("run", "munge.sock"),
                                     f"--key-file={self.path('munge', 'munge.key')}",
                                     f"--log-file={self.path('log', 'munged.log')}",
                                     f"--pid-file={self.path('run', 'munged.pid')}",
                                     f"--seed-file={self.path('munge', 'seed')}"])
        self.until(lambda: os.path.exists(self.path("run", "munge.sock")), "munged's socket")
        self.start_daemon("slurmctld", ["slurmctld", "-D", "-f", self.conf])
        self.until(lambda: run(["sinfo", "-h"], env=self.env, timeout=30).returncode == 0, "slurmctld answering")
        for n in NODES:
            self.start_node(n)
        self.until(lambda: self.idle_nodes() == set(NODES), "both nodes idle")

    def start_node(self, node):
        # nice: the gradings it starts inherit it (the machine is shared)
        self.start_daemon(f"slurmd-{node}", ["nice", "-n", "10", "slurmd", "-D", "-f", self.conf, "-N", node])

    def node_states(self):
        r = run(["sinfo", "-h", "-N", "-o", "%N %T"], env=self.env, timeout=30)
        return dict(line.split() for line in r.stdout.splitlines() if len(line.split()) == 2)

    def idle_nodes(self):
        return {n for n, s in self.node_states().items() if s in ("idle", "mixed", "allocated")}

    def until(self, condition, what, timeout=DAEMON_TIMEOUT):
        deadline = time.time() + timeout
        while time.time() < deadline:
            if condition():
                return
            dead = [n for n, p in self.daemons.items() if p.poll() is not None and n in ("munged", "slurmctld")]
            assert not dead, f"{dead} ended: {self.logs()}"
            time.sleep(0.5)
        raise AssertionError(f"no {what} after {timeout} s: {self.logs()}")

    def logs(self):
        text = []
        for name in sorted(os.listdir(self.path("log"))):
            with open(self.path("log", name), errors="replace") as f:
                text.append(f"--- {name}:\n" + f.read()[-1500:])
        return "\n".join(text)

    def processes_of(self, node=None):
        """The processes this cluster's daemons started (slurmstepd and what it runs, kit/grade.py and its
        sandboxes): those that hold a file under the cluster's directory open, run a script from it or have
        its SLURM_CONF in their environment (of `node` only: its spool directory, its slurmd log, a job's
        SLURMD_NODENAME), and all their descendants."""
        if node:
            marks = (self.path("spool", node) + "/", self.path("log", f"slurmd-{node}.log"), f"SLURMD_NODENAME={node}\0")
        else:
            marks = (self.top + "/", f"SLURM_CONF={self.conf}\0")
        found, children = set(), {}
        for pid in (int(p) for p in os.listdir("/proc") if p.isdigit()):
            try:
                with open(f"/proc/{pid}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
                children.setdefault(ppid, []).append(pid)
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    cmdline = f.read().decode(errors="replace")
                targets = [cmdline]
                try:
                    with open(f"/proc/{pid}/environ", "rb") as f:
                        targets.append(f.read().decode(errors="replace") + "\0")
                except OSError:
                    pass
                for fd in os.listdir(f"/proc/{pid}/fd"):
                    try:
                        targets.append(os.readlink(f"/proc/{pid}/fd/{fd}"))
                    except OSError:
                        pass
            except (OSError, ValueError, IndexError):
                continue
            if pid != os.getpid() and any(m in t for t in targets for m in marks):
                found.add(pid)
        daemons = {p.pid for p in self.daemons.values()}
        stack = list(found)
        while stack:
            for child in children.get(stack.pop(), []):
                if child not in found:
                    found.add(child)
                    stack.append(child)
        return found - daemons - {os.getpid()}

    def kill(self, pids):
        """SIGSTOP, then SIGKILL (nothing forks in between); the command lines of the grade.py killed."""
        graders = set()
        for pid in pids:
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    if b"kit/grade.py" in f.read():
                        graders.add(pid)
                os.kill(pid, signal.SIGSTOP)
            except OSError:
                pass
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        return graders

    def lose_node(self, node):
        """A power cut of `node`: its slurmd, its slurmstepd and everything they started, SIGKILL at once.
        Returns the pids of the kit/grade.py processes killed."""
        daemon = self.daemons.pop(f"slurmd-{node}")
        pids = self.processes_of(node) | {daemon.pid}
        graders = self.kill(pids)
        daemon.wait(timeout=DAEMON_TIMEOUT)
        return graders

    def stop(self):
        """Cancel every job, stop every daemon (SIGTERM, then SIGKILL), kill whatever they started."""
        if "slurmctld" in self.daemons and self.daemons["slurmctld"].poll() is None:
            try:
                run(["scancel", "--full", "--user", "root"], env=self.env, timeout=30)
            except subprocess.TimeoutExpired:
                pass
        for name in sorted(self.daemons, key=lambda n: (n == "munged", n == "slurmctld")):  # slurmd first
            p = self.daemons[name]
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(timeout=DAEMON_TIMEOUT)
        for _ in range(5):
            left = self.processes_of()
            if not left:
                break
            self.kill(left)
            time.sleep(0.5)
        return self.processes_of()


# ---- the class ----------------------------------------------------------------------------------------------

def write_rubric(ctx):
    with open(os.path.join(ROOT, "kit", "rubric.json")) as f:
        rub = json.load(f)
    rub["criteria"] = [c for c in rub["criteria"] if c["name"] in RUBRIC_CRITERIA]
    assert len(rub["criteria"]) == len(RUBRIC_CRITERIA), "a criterion of the test's rubric left kit/rubric.json"
    return ctx.write("rubric.json", json.dumps(rub))


def chapter_source():
    with open(os.path.join(ROOT, CHAPTER)) as f:
        return f.read()


def submission(top, name, text):
    d = os.path.join(top, name)
    os.makedirs(os.path.join(d, "chapters"))
    with open(os.path.join(d, CHAPTER), "w") as f:
        f.write(text)
    return d


HOSTILE = """
#include <signal.h>
#include <stdio.h>
#include <unistd.h>
__attribute__((constructor)) static void hostile_probe(void)
{
    const char *victims[] = {%s};
    for (unsigned i = 0; i < sizeof victims / sizeof victims[0]; i++) {
        FILE *f = fopen(victims[i], "a");
        if (f) fputs("{}", f), fclose(f);
    }
    kill(getppid(), SIGKILL);
}
"""


def make_class(ctx, victim_reports):
    """{student: kind} of the class in ctx's scratch/class-src, the submission list file, the directories."""
    top = ctx.path("class-src")
    os.makedirs(top)
    solution, kinds, dirs = chapter_source(), {}, []

    def add(name, kind, text=None, directory=None):
        dirs.append(directory or submission(top, name, text))
        kinds[name] = kind
    for i in range(25):
        add(f"solution{i:02d}", "solution", solution + f"\n/* student {i}: my own solution */\n")
    # chapter 1's mutants that the five criteria catch (05, the area light's pdf, and 06, Phong's normalisation,
    # only the compare criteria do)
    mutants = sorted(p for p in os.listdir(os.path.join(ROOT, "tests", "mutants")) if p[:2] in
                     ("01", "02", "03", "04", "07", "08"))
    assert len(mutants) == 6, mutants
    for p in mutants:
        d = submission(top, "mutant" + p[:2], solution)
        r = run(["patch", "-p1", "-s", "-i", os.path.join(ROOT, "tests", "mutants", p)], cwd=d, timeout=60)
        assert r.returncode == 0, f"{p}: {r.stdout}{r.stderr}"
        add("mutant" + p[:2], "mutant", directory=d)
    handout = os.path.join(top, "handout-tree")
    r = run([PY, os.path.join(ROOT, "kit", "handout.py"), handout, "01_local"], timeout=300)
    assert r.returncode == 0, r.stderr
    add("handout-tree", "stub", directory=handout)
    with open(os.path.join(handout, CHAPTER)) as f:
        stub = f.read()
    for i in range(2):
        add(f"stub{i}", "stub", stub + f"\n/* student {i}: not started */\n")
    for i in range(3):
        add(f"nocompile{i}", "broken", solution + f"\nthis is not C {i};\n")
    crash = solution.replace("const surface *emitter = &s->surfaces[emitter_surface];",
                             "const surface *emitter = &s->surfaces[emitter_surface];\n"
                             "    if (samples > 0) *(volatile int *)0 = 0;", 1)
    assert crash != solution, "chapter 1's area light changed: the crashing submission needs a new line to break"
    for i in range(3):
        add(f"crash{i}", "broken", crash + f"\n/* {i} */\n")
    hostile = solution + HOSTILE % ", ".join(json.dumps(v) for v in victim_reports)
    for i in range(2):
        add(f"hostile{i}", "hostile", hostile + f"\n/* {i} */\n")
    gone = os.path.join(top, "gone")  # does not exist: refused, "not graded", not retried
    dirs.append(gone)
    listing = ctx.write("class.txt", "".join(d + "\n" for d in dirs))
    return kinds, listing


def read_summary(report):
    with open(os.path.join(report, "summary.csv"), newline="") as f:
        return {row["student"]: row for row in csv.DictReader(f)}


def read_report(report, student):
    with open(os.path.join(report, student, "report.json")) as f:
        return json.load(f)


def attempt_records(report):
    out = []
    top = os.path.join(report, ".slurm", "attempts")
    for name in os.listdir(top) if os.path.isdir(top) else []:
        if name.endswith(".json"):
            try:
                with open(os.path.join(top, name)) as f:
                    out.append(dict(json.load(f), task=name[:-5]))
            except (OSError, ValueError):
                pass
    return out


def grade_on_slurm_losing_a_node(cluster, listing, rubric, report, kinds, out):
    """kit/grade_class.py --slurm; once a few reports are in and n2 has been grading for a few seconds,
    n2 is lost, and brought back once Slurm has declared it down.  Returns (exit status, the students
    whose gradings were killed, the pids of the kit/grade.py killed, seconds)."""
    start = time.time()
    with open(out, "w") as log:
        p = subprocess.Popen([PY, GRADE_CLASS, "--slurm", "@" + listing, "--report", report, "--chapters", "01_local",
                              "--seed", SEED, "--rubric", rubric, "--jobs", "2"], stdout=log, stderr=subprocess.STDOUT,
                             stdin=subprocess.DEVNULL, env=cluster.env, cwd=ROOT)
    killed, graders = set(), set()
    try:
        deadline = time.time() + CLASS_TIMEOUT
        while p.poll() is None and time.time() < deadline and not killed:
            time.sleep(1)
            done = sum(1 for s in kinds if os.path.isfile(os.path.join(report, s, "report.json")))
            on_n2 = [a for a in attempt_records(report) if a["node"] == "n2" and a["exit"] is None and
                     time.time() - a["start"] > 5 and not os.path.isfile(os.path.join(report, a["student"],
                                                                                       "report.json"))]
            if done >= 4 and on_n2:
                graders = cluster.lose_node("n2")
                killed = {a["student"] for a in on_n2}
        assert killed, f"n2 never graded while the class ran (or the class ended first): {open(out).read()[-3000:]}"
        cluster.until(lambda: "down" in cluster.node_states().get("n2", ""), "n2 declared down", timeout=120)
        cluster.start_node("n2")  # the node is back (ReturnToService=2)
        p.wait(timeout=max(1, deadline - time.time()))
    finally:
        if p.poll() is None:
            p.terminate()  # kit/slurm_engine.py cancels its jobs on SIGTERM
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    return p.returncode, killed, graders, time.time() - start


def expect_chained_arrays(report, lines, output):
    """The first round went as ceil(lines / (MAX_ARRAY_SIZE - 1)) arrays, each within MaxArraySize, and each
    array's tasks started after every task of the array before it had ended (--jobs 2 caps the class, and
    an array's %2 caps only its own tasks)."""
    top = os.path.join(report, ".slurm")
    chunk = MAX_ARRAY_SIZE - 1
    listings = sorted((n for n in os.listdir(top) if n.startswith("round0-")), key=lambda n: int(n[7:-4]))
    assert len(listings) == -(-lines // chunk) >= 3, f"round 0 went as {listings} for {lines} lines"
    assert "as job arrays" in output, output[-2000:]
    with open(os.path.join(top, "attempts.json")) as f:
        attempts = json.load(f)
    by_array = {}
    for listing in listings:
        with open(os.path.join(top, listing)) as f:
            indices = [int(x) for x in f.read().split()]
        assert 0 < len(indices) < MAX_ARRAY_SIZE, (listing, indices)
        firsts = [a for a in attempts if a["index"] in indices and a["start"] is not None]
        job = min(int(a["task"].split("_")[0]) for a in firsts)  # round 0's job of these lines: the first
        by_array[listing] = [a for a in firsts if a["task"].startswith(f"{job}_")]
    for earlier, later in zip(listings, listings[1:]):
        ended = max(a["start"] + a["seconds"] for a in by_array[earlier] if a["seconds"] is not None)
        began = min(a["start"] for a in by_array[later])
        # one clock (one machine); 0.01 s for the record's seconds, rounded to the millisecond
        assert began >= ended - 0.01, f"{later} began {ended - began:.1f} s before {earlier} had ended"


def test_class_on_slurm_survives_a_lost_node(ctx):
    if "asan" in ctx.build:
        return  # the kit builds its own binaries: the plain build's run is the test
    missing = [t for t in ("slurmctld", "slurmd", "sbatch", "squeue", "scontrol", "munged", "mungekey", "bwrap",
                           "parallel", "patch") if not shutil.which(t)]
    assert not missing, f"missing {missing}: make deps-cluster installs them (Debian's slurm-wlm, munge)"
    assert os.geteuid() == 0, "the test runs slurmd and grades in the sandbox: it needs root"
    slurm_report, parallel_report = ctx.path("class-slurm"), ctx.path("class-parallel")
    victims = [os.path.join(r, "solution00", "report.json") for r in (slurm_report, parallel_report)]
    kinds, listing = make_class(ctx, victims)
    rubric = write_rubric(ctx)
    cluster = Cluster(ctx.path("slurm"))
    graders, leftover = set(), set()
    try:
        cluster.start()
        code, killed, graders, seconds = grade_on_slurm_losing_a_node(cluster, listing, rubric, slurm_report, kinds,
                                                                      ctx.path("slurm-class.out"))
        with open(ctx.path("slurm-class.out")) as f:
            output = f.read()
        assert code == 0, f"grade_class.py --slurm: exit status {code}: {output[-3000:]}"
    finally:
        leftover = cluster.stop()
        for pid in graders:  # the sandboxes' cgroups of the gradings killed with n2
            sandbox.remove_groups(f"gi-sandbox-{pid}")
    assert not leftover, f"processes of the cluster left after stopping it: {sorted(leftover)}"
    print(f"     Slurm: {len(kinds)} submissions in {seconds:.0f} s; n2 lost while grading {sorted(killed)}", flush=True)

    # every submission: exactly one report, installed by exactly one attempt
    students = set(kinds)
    entries = {n for n in os.listdir(slurm_report) if os.path.isdir(os.path.join(slurm_report, n))}
    assert entries == students | {".slurm"}, f"report directories: {sorted(entries ^ (students | {'.slurm'}))}"
    records = attempt_records(slurm_report)
    for s in students:
        assert os.path.isfile(os.path.join(slurm_report, s, "report.json")), f"{s}: no report ({output[-2000:]})"
        installed = [a["task"] for a in records if a["student"] == s and a["installed"]]
        assert len(installed) == 1, f"{s}: reports installed by {installed}"
    nodes = {a["node"] for a in records}
    assert nodes == set(NODES), f"the tasks ran on {nodes}"
    expect_chained_arrays(slurm_report, len(kinds) + 1, output)

    # the retried: the gradings killed with n2, named NODE_FAIL in summary.csv's "retried" column and summary.html
    rows = read_summary(slurm_report)
    retried = {s: row["retried"] for s, row in rows.items() if row["retried"]}
    assert killed <= set(retried), f"killed with n2: {sorted(killed)}, retried: {retried}"
    for s in killed:
        assert "NODE_FAIL" in retried[s] and "on n2" in retried[s] and "graded" in retried[s], retried[s]
        assert rows[s]["status"] == "graded", rows[s]
    with open(os.path.join(slurm_report, "summary.html")) as f:
        page = f.read()
    assert f"Retried on Slurm ({len(retried)})" in page and all(s in page for s in retried), page[-2000:]
    assert "retried" in output, output[-2000:]
    assert rows["gone"]["status"].startswith("not graded: ") and "missing" in rows["gone"]["status"], rows["gone"]
    assert not rows["gone"]["retried"] and sum(1 for a in records if a["student"] == "gone") == 1, rows["gone"]

    # the same class graded by GNU parallel, same seed: the same points, criterion by criterion
    start = time.time()
    r = run(["nice", PY, GRADE_CLASS, "@" + listing, "--report", parallel_report, "--jobs", "2", "--chapters",
             "01_local", "--seed", SEED, "--rubric", rubric], timeout=CLASS_TIMEOUT, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    print(f"     GNU parallel: {len(kinds)} submissions in {time.time() - start:.0f} s", flush=True)
    prows = read_summary(parallel_report)
    assert prows["gone"]["status"] == rows["gone"]["status"], (prows["gone"], rows["gone"])
    totals = {}
    for s in sorted(students):
        a, b = read_report(slurm_report, s), read_report(parallel_report, s)
        points = [[(c["name"], c["points"]) for c in x["criteria"]] for x in (a, b)]
        assert (a["total"], a["max"], points[0]) == (b["total"], b["max"], points[1]), \
            f"{s}: Slurm {a['total']} {points[0]}, GNU parallel {b['total']} {points[1]}"
        assert a["seed"] == b["seed"] == int(SEED) and a["submission_sha256"] == b["submission_sha256"], s
        assert a["sandbox"].startswith("bubblewrap"), f"{s}: graded in {a['sandbox']}"
        totals[s] = a["total"]
    top = max(totals.values())
    assert top == read_report(slurm_report, "solution00")["max"], totals
    for s, kind in kinds.items():
        if kind == "solution":
            assert totals[s] == top, f"{s}: {totals[s]} of {top}"
        elif kind != "hostile":  # a hostile one is chapter 1's solution: its attacks fail, its points stand
            assert totals[s] < top, f"{s} ({kind}): full marks"
    # the hostile submissions reached no classmate's report (both gradings read it above as JSON)
    for victim in victims:
        with open(victim) as f:
            assert not f.read().endswith("{}"), victim


def test_slurm_bad_input_exits_2(ctx):
    """--slurm with --sshloginfile, and --slurm where Slurm's commands are missing: exit 2, one clear line."""
    os.makedirs(ctx.path("a"))
    cases = [(["--slurm", "--sshloginfile", ctx.write("logins", ":\n")], {}, "one or the other"),
             (["--slurm"], {"PATH": ctx.path("empty")}, "sbatch is missing")]
    for args, env, said in cases:
        r = run([PY, GRADE_CLASS, *args, ctx.path("a"), "--report", ctx.path("r")], env=dict(os.environ, **env),
                timeout=60)
        assert r.returncode == 2 and said in r.stderr and "Traceback" not in r.stderr, (args, r.returncode, r.stderr)
