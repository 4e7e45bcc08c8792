/* Layer probe: a session file may not include cmd.h; tests/layers.sh checks that this fails to build. */
#include "cmd.h"
int layer_probe_session_app(void);
int layer_probe_session_app(void) { return 0; }
