/* Layer probe: a devices file may not include simdev.h; tests/layers.sh checks that this fails to build. */
#include "simdev.h"
int layer_probe_devices_sim(void);
int layer_probe_devices_sim(void) { return 0; }
