#!/bin/sh
# The build enforces the layers:
# - a file of a lower layer that includes a header of a higher one fails to compile. Builds every
#   probe of tests/layers/*.c (EXCLUDE_FROM_ALL) in BUILD_DIR; each must fail with its header not
#   found;
# - each folder of the core (src/core/*/) includes only the system headers of its allow-list below,
#   so no device, window or GL header (hidapi, GLFW, OSMesa) reaches the core. The probes
#   tests/layers/system/FOLDER_*.c stand for a core file of FOLDER that includes one: each must be
#   refused;
# - navigate and replay (src/app/cmd_navigate.c, cmd_replay.c) include, of the layers below them,
#   the session's headers only.
# Exit 0 when all is so, 1 otherwise.
# Usage: tests/layers.sh BUILD_DIR   (probes and headers)
#        tests/layers.sh --headers   (the core's headers only: the build runs this)
set -u
here=$(dirname "$0")
core=$here/../src/core

# The C library's headers, which every core folder may include.
C_HEADERS="assert.h errno.h float.h limits.h math.h stdarg.h stdatomic.h stdbool.h stddef.h stdint.h
           stdio.h stdlib.h string.h strings.h time.h"
# What each folder adds: the OS and the processor (cpuid.h, immintrin.h: the SHA extensions) only in
# platform (and POSIX files and threads where the folder writes files or runs threads), third-party
# libraries only where their target links them.
allowed() {
    case $1 in
    base | segment | geometry) ;;
    platform) echo "cpuid.h dirent.h fcntl.h immintrin.h link.h pthread.h sched.h signal.h spawn.h sys/mman.h sys/prctl.h sys/resource.h sys/stat.h sys/syscall.h sys/types.h sys/wait.h unistd.h" ;;
    navigation) echo "fcntl.h pthread.h semaphore.h sys/stat.h unistd.h zlib.h" ;;
    json) echo "jansson.h" ;;
    io) echo "dirent.h fcntl.h signal.h sys/file.h sys/stat.h unistd.h jansson.h png.h nifti1_io.h teem/nrrd.h zlib.h" ;;
    reduction) echo "pthread.h sys/stat.h jansson.h nlopt.h" ;;
    *) echo "?" ;; # a folder without a list: every system header is refused until it has one
    esac
}

# The system headers that FILE includes and core FOLDER may not, one per line.
refused() {
    ok=" $(echo $C_HEADERS $(allowed "$1")) "
    for h in $(sed -n 's/^[[:space:]]*#[[:space:]]*include[[:space:]]*<\([^>]*\)>.*/\1/p' "$2"); do
        case $ok in *" $h "*) ;; *) echo "$h" ;; esac
    done
}

bad=0
for dir in "$core"/*/; do
    folder=$(basename "$dir")
    for f in "$dir"*.c "$dir"*.h; do
        [ -e "$f" ] || continue
        for h in $(refused "$folder" "$f"); do
            echo "layers: src/core/$folder/$(basename "$f") includes <$h>, which the core's $folder may" \
                 "not (its allow-list is in tests/layers.sh)" >&2
            bad=1
        done
    done
done
n=0
for f in "$here"/layers/system/*.c; do
    name=$(basename "$f" .c)
    n=$((n + 1))
    if [ -n "$(refused "${name%%_*}" "$f")" ]; then
        echo "layers: $name: $(refused "${name%%_*}" "$f" | tr '\n' ' ')refused in the core's ${name%%_*}, as it should be"
    else
        echo "layers: $name: its system header was not refused" >&2
        bad=1
    fi
done
# The command line's session clients (navigate, replay) and the window reach the layers below
# through the session's headers alone (session.h, its terminal view navview.h), besides the
# application's own headers, which include no other header of the layers below either: but the
# window's (navwin.c, navwin.h), which draws (render.h), and navseed.h, whose seeds are the case's
# (case.h).
CLIENT_HEADERS="session.h navview.h cmd.h framedump.h navwin.h navseed.h"
app=$here/../src/app
for f in "$app"/cmd_navigate.c "$app"/cmd_replay.c "$app"/navwin.c "$app"/cmd.h "$app"/framedump.h \
         "$app"/navwin.h "$app"/navseed.h; do
    allowed=$CLIENT_HEADERS
    case $(basename "$f") in
    navwin.[ch]) allowed="$CLIENT_HEADERS render.h" ;;
    navseed.h) allowed="$CLIENT_HEADERS case.h" ;;
    esac
    for h in $(sed -n 's/^[[:space:]]*#[[:space:]]*include[[:space:]]*"\([^"]*\)".*/\1/p' "$f"); do
        case " $allowed " in
        *" $h "*) ;;
        *) echo "layers: src/app/$(basename "$f") includes \"$h\": a client of the session reaches" \
                "the layers below through session.h" >&2
           bad=1 ;;
        esac
    done
done
[ "${1:-}" = --headers ] && exit $bad

build=${1:?usage: layers.sh BUILD_DIR | --headers}
for src in "$here"/layers/*.c; do
    name=$(basename "$src" .c)
    header=$(sed -n 's/^#include "\(.*\)"/\1/p' "$src")
    out=$(cmake --build "$build" --target "layer_probe_$name" 2>&1)
    n=$((n + 1))
    if printf '%s\n' "$out" | grep -q "$header: No such file"; then
        echo "layers: $name: $header is out of reach, as it should be"
    else
        echo "layers: $name: expected '$header: No such file or directory', got:" >&2
        printf '%s\n' "$out" | tail -5 >&2
        bad=1
    fi
done
[ $bad -eq 0 ] && echo "layers: all $n probes refused"
exit $bad
