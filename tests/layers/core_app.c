/* Layer probe: a core file may not include cmd.h; tests/layers.sh checks that this fails to build. */
#include "cmd.h"
int layer_probe_core_app(void);
int layer_probe_core_app(void) { return 0; }
