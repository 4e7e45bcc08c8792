/* Layer probe: the session uses nothing of the sim, so it does not see its headers (tests/layers.sh:
 * must not build). */
#include "simdev.h"
int layer_probe_session_sim(void);
int layer_probe_session_sim(void) { return 0; }
