/* Layer probe: a core file may not include navview.h; tests/layers.sh checks that this fails to build. */
#include "navview.h"
int layer_probe_core_session(void);
int layer_probe_core_session(void) { return 0; }
