#include "cmd.h"

#include <stdio.h>

/* Placeholder until this command is built. */
int cmd_segment(int argc, char **argv)
{
    fprintf(stderr, "fracnav %s: not built yet\n", argv[0]);
    return 1;
}
