/* Layer probe: a render file may not include navview.h; tests/layers.sh checks that this fails to build. */
#include "navview.h"
int layer_probe_render_session(void);
int layer_probe_render_session(void) { return 0; }
