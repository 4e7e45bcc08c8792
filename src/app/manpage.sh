#!/bin/sh
# manpage.sh PROGRAM NAME VERSION: writes NAME(1) in troff on standard output, made from the
# program's own --help texts (its overview, then each command's), so the man page says what
# --help says and never drifts from it.
set -eu
prog=$1 name=$2 version=$3

# Text as troff: backslashes escaped, and a line starting with . or ' kept from being a request.
esc() { sed -e 's/\\/\\e/g' -e "s/^\\([.']\\)/\\\\\\&\\1/"; }

# The commands an overview lists: the indented words under its "commands:" (or "benchmarks:")
# heading, for fracnav; fracnav-sim's usage lines name its subcommands.
commands() {
    "$prog" "$@" --help | awk '
        /^(commands|benchmarks):$/ { on = 1; next }
        on && /^  [a-z]/ { print $1; next }
        on && !/^  / { on = 0 }'
}

printf '.TH %s 1 "" "%s %s" "User Commands"\n' "$(echo "$name" | tr a-z A-Z)" "$name" "$version"
printf '.SH NAME\n'
case $name in
fracnav) printf '%s \\- plan bone-fracture reductions with a 6-DOF controller\n' "$name" ;;
*) printf '%s \\- the virtual 6-DOF controller of fracnav\n' "$name" ;;
esac
printf '.SH SYNOPSIS\n.nf\n'
"$prog" --help | awk 'NR == 1, /^$/' | esc
printf '.fi\n.SH DESCRIPTION\n.nf\n'
"$prog" --help | awk 'f; /^$/ && !f { f = 1 }' | esc
printf '.fi\n'

if [ "$name" = fracnav ]; then
    printf '.SH COMMANDS\n'
    for c in $(commands); do
        printf '.SS %s\n.nf\n' "$c"
        "$prog" "$c" --help | esc
        printf '.fi\n'
        if [ "$c" = bench ]; then
            for b in $(commands bench); do
                printf '.SS "bench %s"\n.nf\n' "$b"
                "$prog" bench "$b" --help | esc
                printf '.fi\n'
            done
        fi
    done
else
    printf '.SH COMMANDS\n'
    for c in $("$prog" --help | sed -n 's/^usage: fracnav-sim \([a-z]*\).*/\1/p; s/^ *fracnav-sim \([a-z]*\) .*/\1/p; s/^ *fracnav-sim \([a-z]*\)$/\1/p' | sort -u); do
        printf '.SS %s\n.nf\n' "$c"
        "$prog" "$c" --help | esc
        printf '.fi\n'
    done
fi
printf '.SH SEE ALSO\nThe documentation in /usr/share/doc/fracnav (README.md and docs/).\n'
