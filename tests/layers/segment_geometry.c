/* Layer probe: a core segment file may not include frag.h (tests/layers.sh: must not build). */
#include "frag.h"
int layer_probe_segment_geometry(void);
int layer_probe_segment_geometry(void) { return 0; }
