/* picture: the PNG writer of every picture fracnav saves (renders, reports). Pictures themselves come
 * from the renderer (src/render); this module only writes them. */
#ifndef FN_PICTURE_H
#define FN_PICTURE_H

#include <stdint.h>

/* Writes an 8-bit RGB image (w*h*3 bytes, rows top to bottom) to path, atomically (a temporary
 * file, then a rename: durable_replace). Returns 0 or a negative FN_E* code with fn_err set (file name included). */
int picture_write_png(const char *path, const uint8_t *rgb, int w, int h);

#endif
