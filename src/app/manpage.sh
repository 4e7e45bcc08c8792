#!/bin/sh
# Writes the man page of a program from its --help texts, so the two never disagree: the
# top-level --help, then, for every entry of a "commands:" or "benchmarks:" list in a help text,
# `PROGRAM ... ENTRY --help`, each verbatim under its own heading. The page is written compressed
# (gzip -9n: best compression, no name or time stamp in the header), as Debian's policy asks of
# installed man pages, so the build makes the same bytes every time.
# Usage: manpage.sh PROGRAM NAME VERSION SUMMARY OUT.1.gz
set -eu
prog=$1 name=$2 version=$3 summary=$4 out=$5
exec >"$out.tmp.1"

# Help text as roff: verbatim lines, backslashes and hyphens escaped, no line read as a request.
roff() {
    printf '.nf\n'
    sed -e 's/\\/\\e/g' -e 's/-/\\-/g' -e "s/^[.']/\\\\\\&&/"
    printf '.fi\n'
}

# The entries of the "commands:" and "benchmarks:" lists of a help text, one per line.
entries() {
    awk '/^(commands|benchmarks):$/ { on = 1; next }
         on && /^  [a-z][a-z-]*  / { print $1; next }
         { on = 0 }'
}

# The help of `PROGRAM ARGS --help` under the heading ARGS, then its own entries, one level down.
section() {
    text=$("$prog" "$@" --help 2>&1)
    printf '.SS "%s %s"\n' "$name" "$*"
    printf '%s\n' "$text" | roff
    for e in $(printf '%s\n' "$text" | entries); do
        section "$@" "$e"
    done
}

top=$("$prog" --help 2>&1)
printf '.TH %s 1 "" "%s %s" "User Commands"\n' "$(echo "$name" | tr a-z A-Z)" "$name" "$version"
printf '.SH NAME\n%s \\- %s\n' "$name" "$summary"
printf '.SH DESCRIPTION\n'
printf '%s\n' "$top" | roff
printf '.SH COMMANDS\n'
subs=$(printf '%s\n' "$top" | entries)
[ -n "$subs" ] || printf '.PP\nEvery subcommand is described above.\n'
for e in $subs; do
    section "$e"
done
printf '.SH SEE ALSO\n'
if [ "$name" = fracnav ]; then
    printf 'fracnav\\-sim(1); the README and the documentation in /usr/share/doc/fracnav.\n'
else
    printf 'fracnav(1); sim/FNREC.md (the recording format) in /usr/share/doc/fracnav.\n'
fi
exec >&-
gzip -9n -c "$out.tmp.1" >"$out.tmp"
rm -f "$out.tmp.1"
mv "$out.tmp" "$out"
