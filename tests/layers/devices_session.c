/* Layer probe: a devices file may not include navview.h; tests/layers.sh checks that this fails to build. */
#include "navview.h"
int layer_probe_devices_session(void);
int layer_probe_devices_session(void) { return 0; }
