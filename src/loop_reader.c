/* loop: the input thread that drains a device into the loop's ring. */
#include "loop.h"

#include "../devices/dev.h"
#include "err.h"

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

struct loop_reader {
    const dev_transport *tr;
    dev_handle *h;
    char path[256];
    int has_path;
    loop_decoder dec;
    ring *r;
    atomic_int stop;
    int errors;
    pthread_t thread;
};

static void push_kind(loop_reader *rd, int kind)
{
    loop_event ev = {0};
    ev.kind = kind;
    ev.t_us = ev.arrival_us = loop_now_us();
    ring_push(rd->r, &ev);
}

static void nap_ms(int ms)
{
    struct timespec ts = {0, ms * 1000000L};
    nanosleep(&ts, NULL);
}

/* Blocks up to 10 ms for the first report, then takes every report already queued. */
static void *reader_main(void *arg)
{
    loop_reader *rd = arg;
    uint8_t buf[DEV_REPORT_MAX];
    while (!atomic_load(&rd->stop)) {
        if (!rd->h) {
            nap_ms(200);
            if (rd->tr->open(rd->has_path ? rd->path : NULL, &rd->h) == 0 && rd->h)
                push_kind(rd, LOOP_EV_REPLUG);
            else
                rd->h = NULL;
            continue;
        }
        int timeout = 10;
        for (;;) {
            int64_t t_us = 0;
            int n = rd->tr->read(rd->h, buf, sizeof buf, timeout, &t_us);
            if (n == FN_ENODEV) {
                rd->tr->close(rd->h);
                rd->h = NULL;
                push_kind(rd, LOOP_EV_UNPLUG);
                break;
            }
            if (n < 0) {
                rd->errors++;
                nap_ms(10);
                break;
            }
            if (n == 0)
                break;
            loop_event ev = {0};
            if (rd->dec.decode(rd->dec.ctx, buf, (size_t)n, t_us, &ev) == 1) {
                ev.arrival_us = loop_now_us();
                ring_push(rd->r, &ev);
            }
            timeout = 0;
        }
    }
    return NULL;
}

loop_reader *loop_reader_start(const struct dev_transport *tr, struct dev_handle *h, const char *path,
                               loop_decoder dec, ring *r)
{
    loop_reader *rd = calloc(1, sizeof *rd);
    if (!rd) {
        fn_err_set(FN_ENOMEM, "loop reader: out of memory");
        return NULL;
    }
    rd->tr = tr;
    rd->h = h;
    rd->has_path = path != NULL;
    if (path)
        snprintf(rd->path, sizeof rd->path, "%s", path);
    rd->dec = dec;
    rd->r = r;
    atomic_init(&rd->stop, 0);
    if (pthread_create(&rd->thread, NULL, reader_main, rd) != 0) {
        free(rd);
        fn_err_set(FN_EIO, "loop reader: cannot start the input thread");
        return NULL;
    }
    return rd;
}

int loop_reader_stop(loop_reader *rd)
{
    if (!rd)
        return 0;
    atomic_store(&rd->stop, 1);
    pthread_join(rd->thread, NULL);
    if (rd->h)
        rd->tr->close(rd->h);
    int errors = rd->errors;
    free(rd);
    return errors;
}
