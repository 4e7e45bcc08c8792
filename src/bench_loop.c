#include "bench.h"

#include <stdio.h>

/* Placeholder until the loop benchmark is built (branch loop). */
int bench_loop(int argc, char **argv)
{
    fprintf(stderr, "fracnav bench loop: not built yet\n");
    return 1;
}
