/* Layer probe: a core io file may not include reduce.h (tests/layers.sh: must not build). */
#include "reduce.h"
int layer_probe_io_reduction(void);
int layer_probe_io_reduction(void) { return 0; }
