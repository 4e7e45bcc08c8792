#!/usr/bin/env python3
"""Kill -9 table: kills segment, fracture, edit and replay --realtime --save at random moments and
says what survived. Not a CI test (it takes minutes and its moments are random); a tool for the
crash-safety claims of the README.

usage: tests/killtable.py [--bin build/fracnav] [--ct CT] [--runs 20] [--seed 1] [--json OUT]

For each command a reference run gives its duration D and its result (the "new" case); each of
the runs starts the command on a copy of the "old" case, kills it with SIGKILL after a uniform
random delay in [0, 1.1 D], and then classifies the case folder:
  old     case.json, labels and source are byte for byte the old case's
  new     they are the reference run's
  absent  no case folder (a first save killed before its rename: nothing half-made)
  broken  anything else, or a case that no longer loads
The step at the kill is read from what the command had written at that moment (its staging
folder, its temporary files). For replay the journal is read too: how many poses it kept, how
much motion the kill lost at most (the wall time from the "stepping" line to the kill, capped at
where the longest journal ends, less the recording time the journal reached: an upper bound, since
a loaded machine also delays the replay's start and pacing), and whether `replay --recover
--save` then restores a loadable case.
"""
import argparse
import hashlib
import json
import os
import random
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time

CASE_FILES = ("case.json", "labels.nii.gz", "source.nii.gz")


def digest(folder):
    if not os.path.isdir(folder):
        return None
    h = hashlib.sha256()
    for name in CASE_FILES:
        p = os.path.join(folder, name)
        if os.path.exists(p):
            with open(p, "rb") as f:
                h.update(name.encode() + f.read())
    return h.hexdigest()


def loads(binary, folder, idle):
    """1 when the case loads (a replay of an idle recording that writes nothing)."""
    r = subprocess.run([binary, "replay", folder, idle, "--no-journal"], capture_output=True)
    return r.returncode == 0 or b"poses not saved" in r.stderr


def staged_state(parent, base):
    """What the command had written when it was killed: the files of its staging folder."""
    for name in os.listdir(parent):
        if name.startswith("." + base + ".new-"):
            files = sorted(os.listdir(os.path.join(parent, name)))
            return "staging: " + (",".join(files) if files else "empty")
    p = os.path.join(parent, base)
    if os.path.isdir(p):
        tmp = [n for n in os.listdir(p)
               if (n.startswith(".") and n != ".fracnav-lock") or n.endswith(".prev.nii.gz")]
        if tmp:
            return "in place: " + ",".join(sorted(tmp))
    return "before writing"


def journal_poses(folder):
    """(records, last report time us, first report time us) of CASE/journal, None when absent."""
    p = os.path.join(folder, "journal")
    if not os.path.exists(p):
        return None
    with open(p, "rb") as f:
        data = f.read()
    if len(data) < 256:
        return (0, None, None)
    n = (len(data) - 256) // 88
    if n == 0:
        return (0, None, None)
    first = struct.unpack_from("<q", data, 256 + 16)[0]
    last = struct.unpack_from("<q", data, 256 + (n - 1) * 88 + 16)[0]
    return (n, last, first)


def run_and_kill(cmd, delay, watch_line=None):
    """Starts cmd, waits delay seconds (from the watch line on stderr, when given), SIGKILLs it.
    Returns (killed, seconds from start or from the watch line to the kill)."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t0 = time.monotonic()
    if watch_line:
        line = proc.stderr.readline()
        t0 = time.monotonic()
        if watch_line.encode() not in line:
            proc.wait()
            return False, 0.0, "no watch line: " + line.decode(errors="replace")
    while time.monotonic() - t0 < delay:
        if proc.poll() is not None:
            break
        time.sleep(0.001)
    killed = proc.poll() is None
    if killed:
        proc.send_signal(signal.SIGKILL)
    proc.wait()
    return killed, time.monotonic() - t0, ""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="build/fracnav")
    ap.add_argument("--ct", default=os.environ.get("FRACNAV_DATA", "/var/cache/fracnav") + "/Cranium.inv3")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json")
    ap.add_argument("--only", help="one command: segment, fracture, edit or replay")
    a = ap.parse_args()
    binary = os.path.abspath(a.bin)
    rnd = random.Random(a.seed)
    work = tempfile.mkdtemp(prefix="fracnav-killtable-")
    table = []
    try:
        table = run_all(binary, os.path.abspath(a.ct), work, a.runs, rnd, a.only)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print_table(table)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(table, f, indent=1)


def sh(*cmd):
    r = subprocess.run(list(cmd), capture_output=True)
    if r.returncode != 0:
        sys.exit("killtable: %s failed: %s" % (" ".join(cmd), r.stderr.decode(errors="replace")))


def make_recording(binary, work):
    """A recording that moves fragment 2 for 1.5 s (made with fracnav-sim's script renderer)."""
    script = os.path.join(work, "move.script")
    with open(script, "w") as f:
        f.write("translate +z 4 mm over 1.5 s\n")
    sim = os.path.join(os.path.dirname(binary), "sim", "fracnav-sim")
    rec = os.path.join(work, "move.fnrec")
    sh(sim, "render", "--script", script, "-o", rec, "--as", "spaceexplorer")
    idle_script = os.path.join(work, "idle.script")
    with open(idle_script, "w") as f:
        f.write("wait 0.05 s\n")
    idle = os.path.join(work, "idle.fnrec")
    sh(sim, "render", "--script", idle_script, "-o", idle, "--as", "spaceexplorer")
    return rec, idle


def one_command(name, binary, work, runs, rnd, old, make_cmd, reference, idle, watch=None):
    """Runs of one command: returns the rows."""
    rows = []
    ref_dir = os.path.join(work, name + "-ref")
    shutil.copytree(old, ref_dir)
    proc = subprocess.Popen(make_cmd(ref_dir), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    if watch:
        proc.stderr.readline()
    t0 = time.monotonic()  # the kills' delays count from the same moment: the watch line or start
    err = proc.stderr.read()
    duration = time.monotonic() - t0
    if proc.wait() != 0:
        sys.exit("killtable: %s reference run failed: %s" % (name, err.decode(errors="replace")))
    new = reference(ref_dir)
    old_digest = digest(old)
    for i in range(runs):
        target = os.path.join(work, "%s-%d" % (name, i))
        shutil.copytree(old, target)
        delay = rnd.uniform(0, 1.1 * duration)
        killed, at, err = run_and_kill(make_cmd(target), delay, watch)
        step = staged_state(work, os.path.basename(target)) if killed else "finished"
        d = digest(target)
        if d is None:
            outcome = "absent"
        elif d == old_digest:
            outcome = "old"
        elif d == new:
            outcome = "new"
            if killed and step == "before writing":
                step = "after the new case was in place"
        else:
            outcome = "broken"
        if outcome in ("old", "new") and not loads(binary, target, idle):
            outcome = "broken (does not load)"
        row = {"command": name, "run": i, "delay_s": round(delay, 3), "killed": killed,
               "step": step, "outcome": outcome}
        if name == "replay":
            row.update(replay_journal(binary, target, at, idle))
        rows.append(row)
        shutil.rmtree(target, ignore_errors=True)
        for n in os.listdir(work):  # a killed run's staging folder: counted above, removed here
            if n.startswith("." + os.path.basename(target) + ".new-"):
                shutil.rmtree(os.path.join(work, n), ignore_errors=True)
    return rows


def replay_journal(binary, target, at, idle):
    """The journal a killed replay left: poses kept, motion lost, and whether --recover works."""
    j = journal_poses(target)
    out = {"journal_records": j[0] if j else None}
    if j and j[0]:
        out["reached_ms"] = round((j[1] - j[2]) / 1000.0, 1)
        out["killed_at_ms"] = round(at * 1000.0, 1)
        r = subprocess.run([binary, "replay", target, idle, "--recover", "--save"], capture_output=True)
        out["recover_rc"] = r.returncode
    return out


def run_all(binary, ct, work, runs, rnd, only):
    rec, idle = make_recording(binary, work)
    base = os.path.join(work, "base")
    sh(binary, "segment", ct, "-o", base, "--min-volume", "5")
    table = []
    seg = lambda d: [binary, "segment", ct, "-o", d, "--min-volume", "5", "--threshold", "400",
                     "--force"]
    if only in (None, "segment"):
        table += one_command("segment", binary, work, runs, rnd, base, seg, digest, idle)
    frac = lambda d: [binary, "fracture", ct, "-o", d, "--seed", "3", "--force"]
    fbase = os.path.join(work, "fbase")
    sh(binary, "fracture", ct, "-o", fbase, "--seed", "2")
    if only in (None, "fracture"):
        table += one_command("fracture", binary, work, runs, rnd, fbase, frac, digest, idle)
    with open(os.path.join(fbase, "case.json")) as f:
        centre = json.load(f)["fragments"][0]["centroid"]
    edit = lambda d: [binary, "edit", d, "erase-sphere"] + ["%g" % x for x in centre] + ["15"]
    if only in (None, "edit"):
        table += one_command("edit", binary, work, runs, rnd, fbase, edit, digest, idle)
    rep = lambda d: [binary, "replay", d, rec, "--realtime", "--save"]
    if only in (None, "replay"):
        table += one_command("replay", binary, work, runs, rnd, fbase, rep, digest, idle,
                             watch="stepping")
    return table


def print_table(table):
    by = {}
    for r in table:
        key = (r["command"], r["step"], r["outcome"])
        by[key] = by.get(key, 0) + 1
    print("| command | step at the kill | what survived | runs |")
    print("|---|---|---|---|")
    for (c, s, o), n in sorted(by.items()):
        print("| %s | %s | %s | %d |" % (c, s, o, n))
    # The motion's accepted poses end where the longest journal ends; a kill after that lost none.
    reach = [r["reached_ms"] for r in table if "reached_ms" in r]
    lost = [max(0.0, min(r["killed_at_ms"], max(reach)) - r["reached_ms"]) for r in table
            if "reached_ms" in r]
    if lost:
        print("\nreplay --realtime --save: motion lost per kill (ms of recording): min %.0f, "
              "median %.0f, max %.0f over %d kills with a journal; --recover --save exit codes: %s"
              % (min(lost), sorted(lost)[len(lost) // 2], max(lost), len(lost),
                 sorted(set(r.get("recover_rc") for r in table if "recover_rc" in r))))


if __name__ == "__main__":
    main()
