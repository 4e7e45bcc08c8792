/* Layer probe: a core navigation file may not include case.h (tests/layers.sh: must not build). */
#include "case.h"
int layer_probe_navigation_io(void);
int layer_probe_navigation_io(void) { return 0; }
