#!/bin/sh
# The build enforces the layers: a file of a lower layer that includes a header of a higher one fails
# to compile. Builds every probe of tests/layers/ (EXCLUDE_FROM_ALL) in BUILD_DIR; each must fail
# with its header not found. Exit 0 when all fail so, 1 when one builds or fails for another reason.
# Usage: tests/layers.sh BUILD_DIR
set -u
build=${1:?usage: layers.sh BUILD_DIR}
here=$(dirname "$0")/layers
bad=0
n=0
for src in "$here"/*.c; do
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
