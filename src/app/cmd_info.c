/* fracnav info: what a volume file holds, as text or JSON. */
#include "cmd.h"

#include "err.h"
#include "jsonw.h"
#include "volio.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void usage(FILE *out)
{
    fprintf(out, "usage: fracnav info FILE [--json]\n\n"
                 "Print a volume's dimensions (i j k), voxel type, spacing, index-to-world affine\n"
                 "(LPS mm, 3x4: world = A * [i j k 1]) and intensity range.\n"
                 "FILE: .nii .nii.gz .nrrd .nhdr .inv3, or a folder of DICOM files (via dcm2niix).\n\n"
                 "  --json   one JSON object instead of text: command, file, dim, type, spacing_mm,\n"
                 "           space, affine (3x4), range (null when every voxel is NaN)\n"
                 "  --help   this text\n");
}

static void print_text(const char *path, const vol *v, float lo, float hi)
{
    printf("file:        %s\n", path);
    printf("dimensions:  %d x %d x %d (i j k)\n", v->dim[0], v->dim[1], v->dim[2]);
    printf("voxel type:  %s\n", vol_type_name(v->src_type));
    printf("spacing:     %.6g %.6g %.6g mm\n", v->spacing[0], v->spacing[1], v->spacing[2]);
    printf("index to world (LPS mm):\n");
    for (int r = 0; r < 3; r++) /* + 0.0 prints -0 as 0 */
        printf("  [ %12.6f %12.6f %12.6f %12.6f ]\n", v->affine[r][0] + 0.0, v->affine[r][1] + 0.0,
               v->affine[r][2] + 0.0, v->affine[r][3] + 0.0);
    if (lo <= hi)
        printf("range:       %.6g .. %.6g\n", lo, hi);
    else
        printf("range:       none (every voxel is NaN)\n");
}

static int print_json(const char *path, const vol *v, float lo, float hi)
{
    json_t *o = jsonw_object("info"), *aff = json_array();
    for (int r = 0; r < 3; r++)
        json_array_append_new(aff, jsonw_exact_array(v->affine[r], 4));
    const double range[2] = {lo, hi};
    if (o) {
        jsonw_set(o, "file", jsonw_string(path));
        jsonw_set(o, "dim", json_pack("[iii]", v->dim[0], v->dim[1], v->dim[2]));
        jsonw_set(o, "type", json_string(vol_type_name(v->src_type)));
        jsonw_set(o, "spacing_mm", jsonw_exact_array(v->spacing, 3));
        jsonw_set(o, "space", json_string("LPS"));
        jsonw_set(o, "affine", aff);
        jsonw_set(o, "range", lo <= hi ? jsonw_exact_array(range, 2) : json_null());
    } else
        json_decref(aff);
    return jsonw_print(o, stdout);
}

int cmd_info(int argc, char **argv)
{
    const char *path = NULL;
    int json = 0;
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--json"))
            json = 1;
        else if (argv[i][0] == '-' && argv[i][1]) {
            fprintf(stderr, "fracnav info: unknown option '%s'\n", argv[i]);
            usage(stderr);
            return 2;
        } else if (path) {
            fprintf(stderr, "fracnav info: one FILE only ('%s' and '%s' given)\n", path, argv[i]);
            return 2;
        } else
            path = argv[i];
    }
    if (!path) {
        usage(stderr);
        return 2;
    }
    vol *v = volio_read(path);
    if (!v) {
        const char *m = fn_err_msg();
        size_t n = strlen(path);
        /* the readers' messages start with the path already */
        if (!strncmp(m, path, n) && m[n] == ':')
            fprintf(stderr, "fracnav info: %s\n", m);
        else
            fprintf(stderr, "fracnav info: %s: %s\n", path, m);
        return 1;
    }
    float lo, hi;
    vol_range(v, &lo, &hi);
    int rc = 0;
    if (json)
        rc = print_json(path, v, lo, hi);
    else
        print_text(path, v, lo, hi);
    vol_free(v);
    if (rc < 0) {
        fprintf(stderr, "fracnav info: %s: %s\n", path, fn_err_msg());
        return 1;
    }
    return 0;
}
