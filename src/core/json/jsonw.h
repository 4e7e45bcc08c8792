/* jsonw: the machine output of every command's --json (README "Machine output").
 *
 * A command builds one jansson object with jsonw_object (which labels it with the command) and
 * writes it with jsonw_print, the only writer of --json output, so that every command prints the
 * same way:
 *  - one object on the stream and nothing else, objects indented by 2, arrays of plain values on
 *    one line;
 *  - a measured figure (a time, a rate, a size, a volume) carries JSONW_DIGITS significant digits
 *    (jsonw_measure); an exact figure (a pose, a coordinate, a threshold) reads back as the same
 *    double (jsonw_exact); both are JSON reals, written with a '.' or an exponent; counts are
 *    integers;
 *  - null where a figure does not apply (JSONW_NA, or any NaN or infinity).
 * Keys follow <measure>_<statistic>_<unit> (query_mean_us, latency_p99_us, build_ms), rates
 * <x>_hz (loop_hz): the same key for the same measure in every command. */
#ifndef FN_JSONW_H
#define FN_JSONW_H

#include <jansson.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>

#define JSONW_DIGITS 6
#define JSONW_NA NAN

/* {"command": command}; NULL when out of memory. */
json_t *jsonw_object(const char *command);
/* A measured figure rounded to JSONW_DIGITS significant digits; null when not finite. */
json_t *jsonw_measure(double v);
/* An exact figure; null when not finite. */
json_t *jsonw_exact(double v);
/* n exact figures as an array. */
json_t *jsonw_exact_array(const double *v, size_t n);
/* A string. One that is not valid UTF-8 (a path may hold any bytes) keeps its ASCII bytes and
 * has '?' for each of the others. */
json_t *jsonw_string(const char *s);
/* Sets o[key] = v (v's reference is taken, as json_object_set_new). 0 or FN_ENOMEM. */
int jsonw_set(json_t *o, const char *key, json_t *v);

/* The text of root as jsonw_print writes it, with a final newline; malloc'd, NULL when out of
 * memory. */
char *jsonw_dumps(json_t *root);
/* Writes root to out and flushes it; takes root's reference (NULL: an allocation failed on the
 * way). 0, FN_ENOMEM or FN_EIO (with a message). */
int jsonw_print(json_t *root, FILE *out);

#endif
