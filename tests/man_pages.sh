#!/bin/sh
# The man pages say what --help says: every command that fracnav --help lists (and every
# benchmark of fracnav bench --help) has its section in fracnav.1, every subcommand of
# fracnav-sim's usage is in fracnav-sim.1, and every option that any of those --help texts
# lists appears in the page. groff, when there, reads the pages without a warning. The pages are
# built as they are installed, compressed with gzip -9n (Debian's policy).
# Usage: tests/man_pages.sh BUILD_DIR
set -u
build=${1:?usage: man_pages.sh BUILD_DIR}
bad=0
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# unpack NAME: BUILD_DIR/NAME.1.gz, checked to be gzip -9n (its header names no file and holds no
# time stamp, and says best compression), as text in $tmp/NAME.1.
unpack() {
    gz=$build/$1.1.gz
    [ -s "$gz" ] || { echo "man_pages: $gz is missing (build first)" >&2; exit 1; }
    # the header: 31 139 8, flags, 4 bytes of time, extra flags (2: best compression), OS
    head=$(od -An -tu1 -N9 "$gz" | tr -s ' \n' ' ')
    case $head in
    " 31 139 8 0 0 0 0 0 2 ") ;;
    *) echo "man_pages: $gz is not compressed with gzip -9n (its header:$head)" >&2
       bad=1 ;;
    esac
    gzip -dc "$gz" >"$tmp/$1.1" || { echo "man_pages: $gz does not decompress" >&2; exit 1; }
}

# The options a help text lists: --long ones and single-letter ones (-o) standing alone.
options() {
    tr '[],|=' '     ' | tr ' ' '\n' | grep -E '^(--[a-z][a-z0-9-]*|-[a-zA-Z])$' | sort -u
}

# Whether the text on stdin names the option $1 as a word of its own (--json, not --json-out).
mentions() {
    grep -qE -- "(^|[^a-zA-Z0-9-])$1([^a-zA-Z0-9-]|\$)"
}

# check PROGRAM PAGE ARGS...: `PROGRAM ARGS --help` has its heading and its options in PAGE.
check() {
    prog=$1 page=$2
    shift 2
    help=$("$prog" "$@" --help 2>&1) || { echo "man_pages: $prog $* --help failed" >&2; bad=1; return; }
    text=$(sed -e 's/\\-/-/g' -e 's/\\e/\\/g' "$page")
    if [ $# -gt 0 ] && ! printf '%s\n' "$text" | grep -qF ".SS \"$(basename "$prog") $*\""; then
        echo "man_pages: $page has no section for '$(basename "$prog") $*'" >&2
        bad=1
    fi
    for o in $(printf '%s\n' "$help" | options); do
        if ! printf '%s\n' "$text" | mentions "$o"; then
            echo "man_pages: $(basename "$prog") $* --help lists $o, which $page does not" >&2
            bad=1
        fi
    done
}

# The entries of the "commands:" or "benchmarks:" list of `PROGRAM ARGS --help`.
listed() {
    prog=$1
    shift
    "$prog" "$@" --help 2>&1 | awk '/^(commands|benchmarks):$/ { on = 1; next }
                                    on && /^  [a-z][a-z-]*  / { print $1; next } { on = 0 }'
}

n=0
unpack fracnav
page=$tmp/fracnav.1
check "$build/fracnav" "$page"
for c in $(listed "$build/fracnav"); do
    check "$build/fracnav" "$page" "$c"
    n=$((n + 1))
    for b in $(listed "$build/fracnav" "$c"); do
        check "$build/fracnav" "$page" "$c" "$b"
        n=$((n + 1))
    done
done
pages=$page
if [ -x "$build/sim/fracnav-sim" ]; then
    unpack fracnav-sim
    page=$tmp/fracnav-sim.1
    pages="$pages $page"
    check "$build/sim/fracnav-sim" "$page"
    for c in $("$build/sim/fracnav-sim" --help | sed -n 's/^ *\(usage: \)\{0,1\}fracnav-sim \([a-z][a-z-]*\).*/\2/p'); do
        help=$("$build/sim/fracnav-sim" "$c" --help 2>&1)
        for o in $(printf '%s\n' "$help" | options); do
            sed -e 's/\\-/-/g' "$page" | mentions "$o" ||
                { echo "man_pages: fracnav-sim $c --help lists $o, which $page does not" >&2; bad=1; }
        done
        n=$((n + 1))
    done
fi
if command -v groff >/dev/null; then
    for p in $pages; do
        w=$(groff -man -Tutf8 -ww -z "$p" 2>&1)
        [ -z "$w" ] || { echo "man_pages: groff on $p: $w" >&2; bad=1; }
    done
fi
[ $bad -eq 0 ] && echo "man_pages: $n commands and every option of their --help are in $(echo "$pages" | sed "s|$tmp/||g") (gzip -9n)"
exit $bad
