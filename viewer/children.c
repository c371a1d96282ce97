/* children.c — chapters run as child processes (live and raster modes):
 * their command line, start, warnings from their log, stop and reap. */
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include "viewer.h"

/* The chapter's command line: its scene, outputs, size, budget, the
 * viewer's camera and the mode's extra options. */
typedef struct {
    char size[64], budget[64], eye[128], look[128], up[128], fov[64];
    const char *argv[40];
} child_args;

static const char **child_argv(child_args *a, const panel *p, const child_spec *spec)
{
    snprintf(a->size, sizeof a->size, "%dx%d", spec->width, spec->height);
    snprintf(a->budget, sizeof a->budget, "%g", spec->time_budget);
    snprintf(a->eye, sizeof a->eye, "%.17g,%.17g,%.17g", spec->cam.eye.x, spec->cam.eye.y, spec->cam.eye.z);
    snprintf(a->look, sizeof a->look, "%.17g,%.17g,%.17g", spec->cam.look.x, spec->cam.look.y, spec->cam.look.z);
    snprintf(a->up, sizeof a->up, "%.17g,%.17g,%.17g", spec->cam.up.x, spec->cam.up.y, spec->cam.up.z);
    snprintf(a->fov, sizeof a->fov, "%.17g", spec->cam.fov_degrees);
    const char **argv = a->argv;
    int argc = 0;
    const char *fixed[] = {p->exe,    spec->scene_path, "--quiet", "--out", p->path,
                           "--stats", p->stats_path,    "--size",  a->size};
    for (size_t k = 0; k < sizeof fixed / sizeof *fixed; k++)
        argv[argc++] = fixed[k];
    if (spec->time_budget > 0) {
        argv[argc++] = "--time";
        argv[argc++] = a->budget;
    }
    const char *camera[] = {"--eye", a->eye, "--look", a->look, "--up", a->up, "--fov", a->fov};
    for (size_t k = 0; k < sizeof camera / sizeof *camera; k++)
        argv[argc++] = camera[k];
    for (int i = 0; i < spec->extra_count; i++)
        argv[argc++] = spec->extra[i];
    argv[argc] = NULL;
    return argv;
}

int child_start(panel *p, const child_spec *spec, char *err, size_t err_size)
{
    const char *name = strrchr(p->exe, '/') ? strrchr(p->exe, '/') + 1 : p->exe;
    snprintf(p->method, sizeof p->method, "%.63s", name);
    snprintf(p->path, sizeof p->path, "%.3000s/%.900s.pfm", spec->directory, name);
    snprintf(p->stats_path, sizeof p->stats_path, "%.3000s/%.900s.json", spec->directory, name);
    snprintf(p->log_path, sizeof p->log_path, "%.3000s/%.900s.log", spec->directory, name);
    unlink(p->stats_path);
    /* A restart: the old image stays on screen, marked stale, until the new
     * run's first pass replaces the file (the old one is removed, so it
     * cannot be mistaken for the new run's). */
    p->stale = p->img.pixels != NULL;
    unlink(p->path);
    p->warning[0] = '\0', p->warnings = 0, p->log_read = 0;

    child_args args;
    const char **argv = child_argv(&args, p, spec);
    int log_fd = open(p->log_path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    pid_t parent = getpid();
    fflush(stdout);
    fflush(stderr);
    pid_t pid = fork();
    if (pid < 0) {
        if (log_fd >= 0)
            close(log_fd);
        snprintf(err, err_size, "viewer: cannot start %s: %s", p->exe, strerror(errno));
        return 2;
    }
    if (pid == 0) {
        /* The child dies with the viewer, however the viewer ends. */
        prctl(PR_SET_PDEATHSIG, SIGKILL);
        if (getppid() != parent)
            _exit(127);
        int null_fd = open("/dev/null", O_RDONLY);
        if (null_fd >= 0)
            dup2(null_fd, STDIN_FILENO);
        if (log_fd >= 0) {
            dup2(log_fd, STDOUT_FILENO);
            dup2(log_fd, STDERR_FILENO);
        }
        execv(p->exe, (char *const *)argv);
        fprintf(stderr, "viewer: cannot run %s: %s\n", p->exe, strerror(errno));
        _exit(127);
    }
    if (log_fd >= 0)
        close(log_fd);
    p->pid = pid;
    p->exit_status = -1;
    p->started = now_seconds();
    p->generation++;
    snprintf(p->detail, sizeof p->detail, "running");
    return 0;
}

bool child_poll_warnings(panel *p)
{
    FILE *f = fopen(p->log_path, "r");
    if (!f)
        return false;
    bool found = false;
    char line[512];
    if (fseek(f, p->log_read, SEEK_SET) == 0)
        while (fgets(line, sizeof line, f)) {
            size_t n = strlen(line);
            if (n == 0 || (line[n - 1] != '\n' && n + 1 < sizeof line))
                break;              /* a line still being written: read it next time */
            p->log_read += (long)n; /* (a longer line: the rest is read as a line of its own) */
            line[strcspn(line, "\n")] = '\0';
            if (strncmp(line, "warning:", 8) == 0) {
                snprintf(p->warning, sizeof p->warning, "%.159s", line);
                p->warnings++;
                found = true;
            }
        }
    fclose(f);
    return found;
}

void child_stop(panel *p)
{
    if (p->pid <= 0)
        return;
    kill(p->pid, SIGTERM);
    int status;
    while (waitpid(p->pid, &status, 0) < 0 && errno == EINTR)
        ;
    p->pid = 0;
}

bool child_reap(panel *p)
{
    if (p->pid <= 0)
        return false;
    int status;
    pid_t r = waitpid(p->pid, &status, WNOHANG);
    if (r != p->pid)
        return false;
    p->pid = 0;
    p->exit_status = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    panel_poll(p); /* the final image */
    if (p->exit_status == 0) {
        panel_read_stats(p, p->stats_path);
    } else {
        /* Say why: the last line of the child's log. */
        char last[256] = "", line[256];
        FILE *f = fopen(p->log_path, "r");
        while (f && fgets(line, sizeof line, f))
            if (line[0] != '\n')
                snprintf(last, sizeof last, "%s", line);
        if (f)
            fclose(f);
        last[strcspn(last, "\n")] = '\0';
        fprintf(stderr, "viewer: %s exited with status %d: %s\n", p->exe, p->exit_status, last);
        snprintf(p->detail, sizeof p->detail, "exit %d: %.120s", p->exit_status, last);
    }
    return true;
}
