/* Layer probe: a core file may not include dev.h; tests/layers.sh checks that this fails to build. */
#include "dev.h"
int layer_probe_core_dev(void);
int layer_probe_core_dev(void) { return 0; }
