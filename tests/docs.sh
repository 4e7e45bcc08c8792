#!/bin/sh
# docs.sh FRACNAV FRACNAV_SIM SRC: the documentation tells what the programs do.
#  - every command the README's command table names exists (its --help exits 0);
#  - every option a --help lists is documented in README.md or docs/ (the man pages hold the
#    --help texts themselves: tests/man_pages.sh).
set -u
bin=$1 sim=$2 src=$3
fail=0
flag=$(mktemp)
trap 'rm -f "$flag"' EXIT
say() { echo "docs: $*"; fail=1; }

# The README's table: rows starting with | `fracnav CMD or | `fracnav-sim CMD|CMD.
for row in $(sed -n 's/^| `\(fracnav[a-z-]*\) \([a-z|\\-]*\).*/\1:\2/p' "$src/README.md"); do
    prog=${row%%:*} cmds=$(echo "${row#*:}" | tr -d '\\' | tr '|' ' ')
    [ "$prog" = fracnav ] && p=$bin || p=$sim
    first=$(echo "$cmds" | cut -d' ' -f1)
    for c in $cmds; do
        if [ "$prog" = fracnav ] && [ "$first" = bench ] && [ "$c" != bench ]; then set -- bench "$c"; else set -- "$c"; fi
        [ "$c" = bench ] && [ "$cmds" != bench ] && continue
        "$p" "$@" --help >/dev/null 2>&1 || say "README's command table names '$prog $*', which has no --help"
    done
done

# Every option of every --help.
docs=$(cat "$src/README.md" "$src"/docs/*.md)
helps() {
    for c in $("$bin" --help | awk '/^commands:$/{on=1;next} on&&/^  [a-z]/{print $1}'); do
        echo "fracnav $c"
        [ "$c" = bench ] && for b in $("$bin" bench --help | awk '/^benchmarks:$/{on=1;next} on&&/^  [a-z]/{print $1}'); do echo "fracnav bench $b"; done
    done
    for c in serve render list bench; do echo "fracnav-sim $c"; done
}
helps | while read -r prog args; do
    [ "$prog" = fracnav ] && p=$bin || p=$sim
    for opt in $("$p" $args --help 2>/dev/null | grep -o -- '--[a-z][a-z0-9-]*' | sort -u); do
        case $docs in
        *"$opt"*) ;;
        *) echo "docs: '$prog $args' lists $opt, which README.md and docs/ never mention"; echo x >>"$flag" ;;
        esac
    done
done

[ -s "$flag" ] && fail=1
[ $fail = 0 ] && echo "docs: every command and option is documented"
exit $fail
