/* Layer probe: a core file may not include simdev.h; tests/layers.sh checks that this fails to build. */
#include "simdev.h"
int layer_probe_core_sim(void);
int layer_probe_core_sim(void) { return 0; }
