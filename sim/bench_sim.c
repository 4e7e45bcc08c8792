/* fracnav-sim bench: throughput and timing jitter of the virtual device through FUSE and the real
 * hidapi (the devices' hidraw transport), printed as one JSON object (jsonw). The server runs as a child process
 * (this same program, `serve`), so the numbers include the whole kernel/FUSE round trip. */
#include "bench_sim.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "dev.h"
#include "err.h"
#include "fnclock.h"
#include "fnrec.h"
#include "jsonw.h"
#include "script.h"
#include "simdev.h"

#define THROUGHPUT_REPORTS 20000

static void msleep(int ms)
{
    fnclock_sleep_us((int64_t)ms * 1000);
}

static pid_t start_server(const char *mount, const char *play, int fast)
{
    char m[512], pl[512]; /* execv takes char *const argv[]: writable copies, no cast */
    snprintf(m, sizeof m, "%s", mount);
    snprintf(pl, sizeof pl, "%s", play);
    char *argv[] = {"/proc/self/exe", "serve", "--mount", m, "--play", pl,
                    fast ? "--fast" : "--start-on-read", NULL};
    pid_t pid = fork();
    if (pid == 0) {
        int null = open("/dev/null", O_WRONLY);
        if (null >= 0)
            dup2(null, 2);
        execv(argv[0], argv);
        _exit(127);
    }
    char node[600];
    snprintf(node, sizeof node, "%s/hidraw0", mount);
    struct stat st;
    for (int i = 0; i < 500 && stat(node, &st); i++)
        msleep(10);
    return pid;
}

static void stop_server(pid_t pid)
{
    kill(pid, SIGTERM);
    waitpid(pid, NULL, 0);
}

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* Reads up to want reports; arrival times into t (may be NULL). Returns the count. */
static int read_reports(const char *node, int want, int64_t *t, int64_t *span_us)
{
    const dev_transport *tr = dev_transport_find("hidraw");
    dev_handle *h;
    if (!tr || tr->open(node, &h))
        return fn_err_wrap(FN_ENODEV, "bench: cannot open %s", node);
    uint8_t buf[64];
    int n = 0;
    int64_t first = 0, last = 0, at;
    while (n < want) {
        int got = tr->read(h, buf, sizeof buf, 1000, &at);
        if (got <= 0)
            break;
        if (n == 0)
            first = at;
        last = at;
        if (t)
            t[n] = at;
        n++;
    }
    tr->close(h);
    *span_us = last - first;
    return n;
}

static int save_rec(fnrec *r, const char *dir, const char *name, char *path, size_t cap)
{
    snprintf(path, cap, "%s/%s", dir, name);
    int rc = fnrec_save(r, path);
    fnrec_free(r);
    return rc;
}

/* As fast as possible: a long recording served with --fast, read as fast as hidapi reads. */
static int throughput(const char *mount, const char *tmp, double *per_s, int *count)
{
    const sim_profile *p = sim_profile_find("spacemouse-wireless");
    fnrec_header h;
    script_header(p, &h);
    fnrec *r = fnrec_new(&h);
    if (!r)
        return FN_ENOMEM;
    for (int i = 0; i < THROUGHPUT_REPORTS; i++) {
        fnrec_event e = {.t_us = i, .dir = FNREC_IN, .len = 13, .data = {1, (uint8_t)i, 0, 7}};
        if (fnrec_append(r, &e)) {
            fnrec_free(r);
            return FN_ENOMEM;
        }
    }
    char path[600], node[600];
    if (save_rec(r, tmp, "throughput.fnrec", path, sizeof path))
        return FN_EIO;
    snprintf(node, sizeof node, "%s/hidraw0", mount);
    pid_t srv = start_server(mount, path, 1);
    int64_t span = 0;
    *count = read_reports(node, THROUGHPUT_REPORTS, NULL, &span);
    stop_server(srv);
    if (*count < 0)
        return *count;
    *per_s = span > 0 ? (*count - 1) / (span / 1e6) : 0;
    return 0;
}

typedef struct jitter {
    int n;
    double mean_us, p99_us, max_us, period_us, drift_us;
} jitter;

/* At the cadence: full deflection for a while on a SpaceNavigator (8 ms), arrival intervals. */
static int cadence(const char *mount, const char *tmp, double seconds, jitter *j)
{
    const sim_profile *p = sim_profile_find("spacenavigator");
    char text[128], path[600], node[600];
    snprintf(text, sizeof text, "translate +x %.3f mm over %.3f s\n", SCRIPT_MM_PER_S_FULL * seconds,
             seconds);
    script *s = NULL;
    if (script_parse(text, strlen(text), "bench", &s))
        return FN_EINVAL;
    fnrec *r = script_render(s, p);
    free(s);
    if (!r || save_rec(r, tmp, "cadence.fnrec", path, sizeof path))
        return FN_EIO;
    snprintf(node, sizeof node, "%s/hidraw0", mount);
    int want = (int)(seconds * 1e6 / p->period_us) - 2;
    int64_t *t = calloc((size_t)want, sizeof *t), *dev = calloc((size_t)want, sizeof *dev), span = 0;
    if (!t || !dev) {
        free(t);
        free(dev);
        return FN_ENOMEM;
    }
    pid_t srv = start_server(mount, path, 0);
    int n = read_reports(node, want, t, &span);
    stop_server(srv);
    double sum = 0;
    for (int i = 1; i < n; i++) {
        dev[i - 1] = llabs(t[i] - t[i - 1] - p->period_us);
        sum += (double)dev[i - 1];
    }
    if (n > 2) {
        qsort(dev, (size_t)n - 1, sizeof *dev, cmp_i64);
        j->mean_us = sum / (n - 1);
        j->p99_us = (double)dev[(size_t)((n - 1) * 0.99)];
        j->max_us = (double)dev[n - 2];
        j->drift_us = (double)span - (double)(n - 1) * p->period_us;
    }
    j->n = n;
    j->period_us = p->period_us;
    free(t);
    free(dev);
    return n > 2 ? 0 : fn_err_set(FN_EIO, "bench: only %d reports at the cadence", n);
}

int bench_sim_run(const char *mount, double seconds)
{
    char tmp[] = "/tmp/fracnav-sim-bench-XXXXXX", mnt[64];
    if (!mkdtemp(tmp)) {
        fprintf(stderr, "fracnav-sim bench: cannot make a temporary directory: %s\n", strerror(errno));
        return 1;
    }
    if (!mount) {
        snprintf(mnt, sizeof mnt, "%s/mnt", tmp);
        mkdir(mnt, 0755);
        mount = mnt;
    }
    double per_s = 0;
    int count = 0;
    jitter j = {0};
    int rc = throughput(mount, tmp, &per_s, &count);
    if (!rc)
        rc = cadence(mount, tmp, seconds, &j);
    char cmd[256];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmp);
    if (system(cmd) != 0)
        fprintf(stderr, "fracnav-sim bench: could not remove %s\n", tmp);
    if (rc) {
        fprintf(stderr, "fracnav-sim bench: %s\n", fn_err_msg());
        return 1;
    }
    json_t *o = jsonw_object("fracnav-sim bench");
    if (o) {
        jsonw_set(o, "path", json_string("FUSE hidraw node + libhidapi-hidraw"));
        jsonw_set(o, "throughput", json_pack("{s:i,s:o}", "reports", count, "report_hz", jsonw_measure(per_s)));
        jsonw_set(o, "cadence", json_pack("{s:s,s:o,s:i,s:o,s:o,s:o,s:o}", "device", "spacenavigator",
                                          "period_us", jsonw_measure(j.period_us), "reports", j.n,
                                          "deviation_mean_us", jsonw_measure(j.mean_us),
                                          "deviation_p99_us", jsonw_measure(j.p99_us),
                                          "deviation_max_us", jsonw_measure(j.max_us),
                                          "drift_us", jsonw_measure(j.drift_us)));
    }
    if (jsonw_print(o, stdout) < 0) {
        fprintf(stderr, "fracnav-sim bench: %s\n", fn_err_msg());
        return 1;
    }
    return 0;
}
