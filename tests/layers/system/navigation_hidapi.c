/* Layer probe: a core navigation file may not include a device header (tests/layers.sh). */
#include <hidapi/hidapi.h>
