/* Layer probe: a core geometry file may not include loop.h (tests/layers.sh: must not build). */
#include "loop.h"
int layer_probe_geometry_navigation(void);
int layer_probe_geometry_navigation(void) { return 0; }
