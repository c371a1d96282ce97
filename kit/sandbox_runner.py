"""The runner inside a grading's sandbox: starts the programs the judge asks for (kit/sandbox.py Session).

usage (by kit/sandbox.py, as the sandbox's first process, uid 65534):
  python3 -I sandbox_runner.py REQUESTS RESPONSES

Starting a bubblewrap sandbox costs 30-80 ms (namespaces, a cgroup), and a
grading runs hundreds of short programs; so one sandbox serves a whole
grading and this runner starts its programs.  It is the grader's code but
runs with the submission's uid, so nothing it reports is trusted more than
the programs' own output: the judge reads what it writes as data.

Protocol (files only: no descriptor of the grader is open in the sandbox):
- REQUESTS (read-only here, written by the judge, renamed into place):
  ID.json = {"argv": [...], "cwd": DIR, "timeout": S} runs a program;
  {"reset": true} kills every process but this runner's and drops the other
  requests read so far (between criteria, or a criterion stopped by a cap).
- RESPONSES (this runner's): ID.out and ID.err (the program's stdout and
  stderr), then ID.done = {"returncode": N or null, "stopped": "..."}.

The runner is the sandbox's PID 1 (a run cannot kill it: the kernel drops
its signals).  Nothing outlives a run: whenever no run is active, every
other process of the sandbox's PID namespace is killed (a child that detached into a session
of its own is one), and the run that just ended says how many there were.  Two runs
share the sandbox only if they run the same program (two renders of one
criterion): a program of another chapter (an instructor's one a test
compares with) waits until nothing else is running.
"""
import ctypes
import json
import os
import select
import signal
import subprocess
import sys
import time

IN_MOVED_TO = 0x80  # inotify: a file renamed into the directory (requests and answers are renamed into place)


def watch(directory):
    """A descriptor that becomes readable when a file is renamed into directory (Linux inotify), so
    that neither side polls: each wakes when the other has written (kit/sandbox.py Client too)."""
    libc = ctypes.CDLL(None, use_errno=True)
    fd = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
    if fd < 0 or libc.inotify_add_watch(fd, os.fsencode(directory), IN_MOVED_TO) < 0:
        raise OSError(ctypes.get_errno(), f"inotify on {directory}: {os.strerror(ctypes.get_errno())}")
    return fd


def drain(fd):
    """Read what a watch() descriptor holds: it is readable again only after the next event."""
    try:
        while os.read(fd, 65536):
            pass
    except BlockingIOError:
        pass


def others():
    """The PIDs of this PID namespace but the runner's (PID 1: bwrap --as-pid-1)."""
    me = os.getpid()
    return {int(p) for p in os.listdir("/proc") if p.isdigit() and int(p) not in (1, me)}


def reap_orphans():
    """Collect the exit status of every process that ended: the runner is the sandbox's PID 1, so
    the children of ended runs (a daemon's) become its own.  Only while no run is active: a run's
    status is its Popen's."""
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return


def kill_leftovers(active_pids):
    """Kill every process that is not an active run; how many there were."""
    left = {p for p in others() - active_pids if not zombie(p)}
    found = len(left)
    for _ in range(100 if left else 0):
        for pid in left:
            try:
                os.kill(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        time.sleep(0.002)
        if not active_pids:
            reap_orphans()
        left = {p for p in others() - active_pids if not zombie(p)}
        if not left:
            break
    return found


def first_to_kill():
    """In a run, before it starts: the out-of-memory killer takes it (oom_score_adj 1000, the most) before
    the runner (kit/sandbox.py SANDBOX_OOM_SCORE), so a grading over its memory cap loses a run, which
    says so, not its sandbox."""
    try:
        with open("/proc/self/oom_score_adj", "w") as f:
            f.write("1000")
    except OSError:
        pass


def kill_group(pid):
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def zombie(pid):
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except (OSError, IndexError):
        return True


def write_atomically(path, data):
    with open(path + ".tmp", "w") as f:
        json.dump(data, f)
    os.rename(path + ".tmp", path)


class Runner:
    def __init__(self, requests, responses):
        self.requests, self.responses = requests, responses
        self.seen, self.waiting = set(), []
        self.active = {}  # id -> (Popen, deadline, program, pidfd: readable when it ends)

    def read_new_requests(self):
        for name in sorted(os.listdir(self.requests)):
            if name.endswith(".json") and name not in self.seen:
                self.seen.add(name)
                try:
                    with open(os.path.join(self.requests, name)) as f:
                        self.waiting.append((name[:-5], json.load(f)))
                except (OSError, ValueError):
                    self.finish(name[:-5], None, "the grader's request could not be read")

    def start_waiting(self):
        while self.waiting:
            rid, request = self.waiting[0]
            if any(r.get("reset") for _, r in self.waiting):  # a criterion is over, or stopped (a cap):
                self.stop_active("stopped by the grader")      # its runs and requests with it
                for other, r in self.waiting:
                    self.finish(other, 0 if r.get("reset") else None, "" if r.get("reset") else "stopped by the grader")
                self.waiting.clear()
                kill_leftovers(set())
                return
            program = request["argv"][0]
            if any(run[2] != program for run in self.active.values()):
                return  # another program is running: this one waits (see the module)
            self.waiting.pop(0)
            self.start(rid, request, program)

    def start(self, rid, request, program):
        base = os.path.join(self.responses, rid)
        try:
            with open(base + ".out", "wb") as out, open(base + ".err", "wb") as err:
                p = subprocess.Popen(request["argv"], cwd=request["cwd"], stdin=subprocess.DEVNULL, stdout=out,
                                     stderr=err, start_new_session=True, preexec_fn=first_to_kill)
        except OSError as e:
            self.finish(rid, 127, "", f"cannot start {program}: {e.strerror}\n")
            return
        self.active[rid] = (p, time.monotonic() + float(request["timeout"]), program, os.pidfd_open(p.pid))

    def stop_active(self, why):
        for rid, (p, _, _, ended) in list(self.active.items()):
            kill_group(p.pid)
            p.wait()
            os.close(ended)
            self.finish(rid, None, why)
        self.active.clear()

    def reap(self):
        for rid, (p, deadline, _, ended) in list(self.active.items()):
            code, stopped = p.poll(), ""
            if code is None and time.monotonic() > deadline:
                kill_group(p.pid)
                code, stopped = p.wait(), "time-out"
            if code is None:
                continue
            os.close(ended)
            del self.active[rid]
            if not self.active:
                left = kill_leftovers(set())
                if left and not stopped:
                    stopped = f"{left} processes outlived the run (killed)"
            self.finish(rid, None if stopped == "time-out" else code, stopped)

    def finish(self, rid, code, stopped, error=""):
        if error:
            with open(os.path.join(self.responses, rid + ".err"), "w") as f:
                f.write(error)
        write_atomically(os.path.join(self.responses, rid + ".done"), {"returncode": code, "stopped": stopped})

    def serve(self):
        requests_came = watch(self.requests)
        while True:
            drain(requests_came)
            self.read_new_requests()
            self.start_waiting()
            self.reap()
            now = time.monotonic()  # wake for a request, a run's end, or a run's time-out
            deadline = min([run[1] for run in self.active.values()] + [now + 1.0])
            select.select([requests_came] + [run[3] for run in self.active.values()], [], [],
                          max(0.0, deadline - now))


if __name__ == "__main__":
    # The sandbox's PID 1: the kernel drops every signal its processes send it that it has no
    # handler for (SIGKILL always), so a run cannot kill the runner; Python's SIGINT handler goes.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    log = os.open(os.path.join(sys.argv[2], "runner.log"), os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.dup2(log, 2)  # its own errors, for the grader to read; stdin and stdout are /dev/null
    write_atomically(os.path.join(sys.argv[2], "ready"), {"pid": os.getpid()})
    Runner(sys.argv[1], sys.argv[2]).serve()
