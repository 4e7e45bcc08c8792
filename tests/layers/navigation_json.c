/* Layer probe: a core navigation file may not include jsonw.h (tests/layers.sh: must not build). */
#include "jsonw.h"
int layer_probe_navigation_json(void);
int layer_probe_navigation_json(void) { return 0; }
