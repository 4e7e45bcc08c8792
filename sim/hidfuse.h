/* hidfuse: `fracnav-sim serve`'s server, the virtual 6-DOF controller as a hidraw node through
 * FUSE (MOUNT/hidraw0): the ioctls hidapi asks (descriptor, info, name, serial, feature reports),
 * reads and poll with the kernel's per-reader queue (reportq.h), writes (the LED), unplug/replug
 * (SIGUSR1, a control line, or the recording), and the --control FIFO of script lines.
 *
 * Part of the fracnav-sim executable: only it links libfuse. One thread; the server's state is
 * FUSE's userdata, nothing is file-global but the operation table. */
#ifndef FN_HIDFUSE_H
#define FN_HIDFUSE_H

#include "fnrec.h"
#include "script.h"
#include "simdev.h"

#define HIDFUSE_NODE "hidraw0"

/* What the server serves and plays. */
typedef struct hidfuse_source {
    const sim_profile *p; /* the device impersonated */
    fnrec_header id;      /* identity served: descriptor, name, vid:pid */
    const char *serial;   /* HIDIOCGRAWUNIQ */
    fnrec *rec;           /* what the device plays */
    script *script;       /* its script, rendered again when playback starts (NULL: a recording) */
    fnrec_writer *log;    /* every event served (--log), or NULL */
    int start_on_read;    /* start playing when the node is first read or polled */
    int fast;             /* play as fast as the readers read */
    int exit_at_end;      /* stop once the playback is over and read */
} hidfuse_source;

/* Serves src at mount/hidraw0 until SIGINT, SIGTERM or SIGHUP, an unmount from outside, or the end
 * (exit_at_end), then unmounts. control: a FIFO (made when absent) whose lines are script lines
 * played in turn, or NULL. Takes src's rec, script and log and frees them (the log closed) whatever
 * it returns. Returns 0, or 1 with the cause said on stderr (mount point, FUSE access, signals). */
int hidfuse_serve(const char *mount, const char *control, const hidfuse_source *src);

#endif
