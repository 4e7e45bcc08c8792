/* Layer probe: a core io file may not include an OpenGL header (tests/layers.sh). */
#include <GL/osmesa.h>
