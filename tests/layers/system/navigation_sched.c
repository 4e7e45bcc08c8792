/* Layer probe: only the core's platform folder may reach the scheduler (tests/layers.sh). */
#include <sched.h>
