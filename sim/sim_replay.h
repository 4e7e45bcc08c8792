/* sim_replay: the "replay" and "virtual" transports of the devices seam (dev.h).
 *
 * replay: path = a .fnrec file. Reads return the recorded input reports in order with *t_us = the
 * recorded timestamp, so a replay is deterministic. By default as fast as possible (timeouts never
 * wait); sim_replay_realtime_transport (or opts.realtime) paces them at recorded speed from the first
 * read. A recorded disconnect makes one read return FN_ENODEV ("device disconnected"), reading on
 * continues after it; the end of the recording returns FN_ENODEV on every read and
 * sim_replay_finished() becomes true. write() accepts output reports; get_feature returns the last
 * recorded feature report with that ID (FN_EINVAL if none).
 *
 * virtual: the simulated device in process, for machines without FUSE. path = "DEVICE" or
 * "DEVICE:script=FILE" or "DEVICE:play=FILE.fnrec" (DEVICE as in simdev.h, e.g. spacenavigator).
 * A recording (play=) plays as the device it was recorded from: a DEVICE that differs is ignored
 * with a warning on stderr. Reports come at the device's cadence in real time; unplug reads return FN_ENODEV until replug;
 * LED output and feature reports go to the same generator the FUSE server uses.
 *
 * The replay and the virtual device are two function sets over one handle type; what they are
 * (DEV_CAP_RECORDING for the replays, `finished` for all three) is in their transport entries.
 * Handles are not thread-safe; use one from one thread. */
#ifndef FN_SIM_REPLAY_H
#define FN_SIM_REPLAY_H

#include "dev.h"
#include "fnrec.h"

extern const dev_transport sim_replay_transport;          /* name "replay" */
extern const dev_transport sim_replay_realtime_transport; /* name "replay-realtime" */
extern const dev_transport sim_virtual_transport;         /* name "virtual" */

/* Registers the three with the devices registry (dev_transport_register) so that dev_open() takes
 * "virtual:DEVICE...", "replay:FILE" and "replay-realtime:FILE". Idempotent; call before starting
 * threads. Returns 0 or FN_ENOMEM when the registry is full. */
int sim_register_transports(void);

typedef struct sim_replay_opts {
    int realtime; /* pace by timestamps */
    double speed; /* realtime speed factor (1 = recorded speed; <= 0 means 1) */
} sim_replay_opts;

/* Opens a replay of rec, which the handle borrows (it must outlive the handle). */
int sim_replay_open_rec(const fnrec *rec, const sim_replay_opts *o, dev_handle **out);
/* Opens a replay of a file; the handle owns the loaded recording. */
int sim_replay_open_file(const char *path, const sim_replay_opts *o, dev_handle **out);
/* True once every event of the recording has been read. */
int sim_replay_finished(const dev_handle *h);
/* The recording's header (identity and descriptor). */
const fnrec_header *sim_replay_header(const dev_handle *h);

#endif
