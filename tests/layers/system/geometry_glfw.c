/* Layer probe: a core geometry file may not include a window header (tests/layers.sh). */
#include <GLFW/glfw3.h>
