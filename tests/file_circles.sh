#!/bin/sh
# No circles between files: file A uses a function or variable that file B defines while B, directly
# or through others, uses one that A defines. Reads the symbols of the project's object files (the
# libraries and the programs, not the tests) in a build folder with nm; prints each circle's files,
# or how many files it checked. Exit 0: none; 1: circles; 2: no object files. Objects of deleted
# sources stay in a build folder: check a fresh one.
# Usage: tests/file_circles.sh BUILD_DIR
set -eu
build=${1:?usage: file_circles.sh BUILD_DIR}
objs=$(find "$build" -path "$build/tests" -prune -o -path '*/CMakeFiles/fracnav*.dir/*' -name '*.o' -print |
       sort)
[ -n "$objs" ] || { echo "file_circles: no object files under $build (build first)" >&2; exit 2; }
for o in $objs; do
    f=${o#*.dir/}                          # the object path below its folder
    case $f in */*) ;; *) sub=${o#"$build"/}; f=${sub%%/CMakeFiles/*}/$f ;; esac
    f=${f%.o}
    nm -g --defined-only "$o" | awk -v f="$f" 'NF >= 3 { print "D", f, $3 }'
    nm -u "$o" | awk -v f="$f" '{ print "U", f, $NF }'
done | awk '
$1 == "D" { def[$3] = $2; file[$2] = 1; next }
{ use[NR] = $2 " " $3 }
END {
    n = 0
    for (f in file) { id[f] = ++n; name[n] = f }
    for (k in use) {
        split(use[k], p, " ")
        if ((p[2] in def) && def[p[2]] != p[1])
            r[id[p[1]], id[def[p[2]]]] = 1
    }
    for (k = 1; k <= n; k++)             # transitive closure (Warshall)
        for (i = 1; i <= n; i++)
            if ((i, k) in r)
                for (j = 1; j <= n; j++)
                    if ((k, j) in r)
                        r[i, j] = 1
    bad = 0
    for (i = 1; i <= n; i++) {
        if (i in done || !((i, i) in r))
            continue
        line = name[i]
        for (j = 1; j <= n; j++)
            if (j != i && ((i, j) in r) && ((j, i) in r)) {
                line = line " <-> " name[j]
                done[j] = 1
            }
        print "circle: " line
        bad = 1
    }
    if (!bad)
        printf "no circles between %d files\n", n
    exit bad
}'
