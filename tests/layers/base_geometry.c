/* Layer probe: a core base file may not include frag.h (tests/layers.sh: must not build). */
#include "frag.h"
int layer_probe_base_geometry(void);
int layer_probe_base_geometry(void) { return 0; }
