/* Layer probe: a core file may not include render.h; tests/layers.sh checks that this fails to build. */
#include "render.h"
int layer_probe_core_render(void);
int layer_probe_core_render(void) { return 0; }
