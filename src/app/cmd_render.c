/* fracnav render: a case's fragments at their poses, drawn by the renderer into a PNG. */
#include "cmd.h"

#include "case.h"
#include "caselock.h"
#include "err.h"
#include "jsonw.h"
#include "render.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav render CASE -o FILE.png [--mode iso|dvr|mip|surface] [--size WxH]\n"
            "                      [--view VIEW] [--layout 3d|four-up] [--overlay LIST]\n"
            "                      [--point X,Y,Z] [--fragment ID] [--cutaway on|off]\n"
            "                      [--split F] [--platform P]\n"
            "                      [--json] [--recover] [--wait]\n\n"
            "Draw a case's fragments at their current poses with OpenGL 4.5 core: offscreen (on a\n"
            "GPU through EGL, else OSMesa's llvmpipe) unless --platform glfw asks for a window.\n"
            "Each fragment is its CT\n"
            "crop masked by its label, in its colour.\n\n"
            "  -o FILE.png       where the picture goes (written atomically)\n"
            "  --mode M          iso: the bone surface (first hit at the case's threshold, shaded);\n"
            "                    dvr: volume rendering through a transfer function over HU;\n"
            "                    mip: maximum intensity; surface: triangle meshes (default iso)\n"
            "  --size WxH        pixels (default 512x512)\n"
            "  --view VIEW       auto (default): framed on the selected fragment (--fragment) from\n"
            "                    the side where most of it is seen (its principal axes, the\n"
            "                    named views, the view onto the nearest fragment); or anterior,\n"
            "                    posterior, left, right, superior, inferior: the camera fits\n"
            "                    the fragments at home\n"
            "  --fragment ID     the selected fragment (default: the first that is not fixed)\n"
            "  --cutaway on|off  cut away the other fragments in front of the selected one, so\n"
            "                    it is seen (surface and iso; default on with --view auto)\n"
            "  --layout L        3d, or four-up: the 3D view over the top two thirds, and below it\n"
            "                    the axial, coronal and sagittal slices; slices show the CT in grey\n"
            "                    and each fragment's outline in its colour\n"
            "  --overlay LIST    comma-separated: hierarchy[:DEPTH] (the OBB octree's boxes at\n"
            "                    DEPTH, root = 1, default 3), contacts (in surface and iso mode\n"
            "                    each surface coloured by its gap to the nearest other fragment,\n"
            "                    red at 0 through yellow to its own colour at 3 mm, with a\n"
            "                    legend; in dvr and mip both voxels of every colliding voxel pair\n"
            "                    outlined and tinted yellow), axes (principal axes: red,\n"
            "                    green, blue from the largest), voi (the VOI boxes of the\n"
            "                    case's reduction, cyan; an error when fracnav reduce has not\n"
            "                    run)\n"
            "  --split F         four-up: the 3D view's share of the height, %.2f to %.2f\n"
            "                    (default 2/3)\n"
            "  --point X,Y,Z     where the slices cut, LPS mm (default: the first fragment's\n"
            "                    centroid at its pose)\n"
            "  --platform P      offscreen (default: egl on a GPU's EGL device where there is\n"
            "                    one, else osmesa), osmesa (llvmpipe), egl, or glfw (needs a\n"
            "                    display)\n"
            "  --json            print {\"command\": \"render\", \"view\", \"fragments\": [{\"id\",\n"
            "                    \"projected_pixels\", \"visible_pixels\"}]}: the pixels each fragment\n"
            "                    covers drawn alone, and those where it is in front (as meshes)\n"
            CMD_RECOVER_HELP
            CMD_WAIT_HELP
            "  --help            this text\n\n"
            "A GL older than 4.5 is an error that names the version found.\n",
            RENDER_SPLIT_MIN, RENDER_SPLIT_MAX);
}

static int parse_size(const char *s, int *w, int *h)
{
    char tail;
    return s && sscanf(s, "%dx%d%c", w, h, &tail) == 2 && *w >= 16 && *h >= 16 && *w <= 8192 && *h <= 8192;
}

static int parse_point(const char *s, double p[3])
{
    char buf[256];
    if (!s || strlen(s) >= sizeof buf)
        return 0;
    strcpy(buf, s);
    char *save = NULL, *tok = strtok_r(buf, ",", &save);
    for (int a = 0; a < 3; a++, tok = strtok_r(NULL, ",", &save))
        if (!tok || !cmd_number(tok, &p[a]))
            return 0;
    return tok == NULL;
}

typedef struct render_args {
    const char *dir, *out, *platform;
    int w, h, have_point, json, fragment; /* fragment: an id, 0 for the first that is not fixed */
    double point[3];
    int view; /* render_view, or -1: auto */
    int cutaway; /* 1 on, 0 off, -1: on with the auto view */
    render_options o;
} render_args;

static int parse_args(int argc, char **argv, render_args *a)
{
    for (int i = 1; i < argc; i++) {
        const char *opt = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        int takes = 1;
        if (!strcmp(opt, "-o") && val)
            a->out = val;
        else if (!strcmp(opt, "--mode")) {
            if (render_mode_parse(val, &a->o.mode))
                return cmd_bad_value("render", opt, val, "iso, dvr, mip or surface");
        } else if (!strcmp(opt, "--size")) {
            if (!parse_size(val, &a->w, &a->h))
                return cmd_bad_value("render", opt, val, "WxH, 16 to 8192 pixels each");
        } else if (!strcmp(opt, "--view")) {
            render_view v;
            if (val && !strcmp(val, "auto"))
                a->view = -1;
            else if (render_view_parse(val, &v))
                return cmd_bad_value("render", opt, val,
                                     "auto, anterior, posterior, left, right, superior or inferior");
            else
                a->view = (int)v;
        } else if (!strcmp(opt, "--fragment")) {
            double id;
            if (!val || !cmd_number(val, &id) || id < 1 || id != (int)id)
                return cmd_bad_value("render", opt, val, "a fragment's id (1, 2, ...)");
            a->fragment = (int)id;
        } else if (!strcmp(opt, "--split")) {
            if (!val || !cmd_number(val, &a->o.four_up_split) || a->o.four_up_split < RENDER_SPLIT_MIN ||
                a->o.four_up_split > RENDER_SPLIT_MAX)
                return cmd_bad_value("render", opt, val, "a share of the height, 0.25 to 0.9");
        } else if (!strcmp(opt, "--cutaway")) {
            if (!val || (strcmp(val, "on") && strcmp(val, "off")))
                return cmd_bad_value("render", opt, val, "on or off");
            a->cutaway = !strcmp(val, "on");
        } else if (!strcmp(opt, "--json")) {
            a->json = 1;
            takes = 0;
        } else if (!strcmp(opt, "--layout")) {
            if (render_layout_parse(val, &a->o.layout))
                return cmd_bad_value("render", opt, val, "3d or four-up");
        } else if (!strcmp(opt, "--overlay")) {
            if (render_overlays_parse(val, &a->o.overlays, &a->o.hierarchy_depth))
                return val ? cmd_usage_error("render", "--overlay: %s", fn_err_msg())
                           : cmd_bad_value("render", opt, val, "hierarchy[:DEPTH], contacts, axes, voi");
        } else if (!strcmp(opt, "--point")) {
            if (!parse_point(val, a->point))
                return cmd_bad_value("render", opt, val, "X,Y,Z in mm");
            a->have_point = 1;
        } else if (!strcmp(opt, "--platform")) {
            if (!val || (strcmp(val, "offscreen") && strcmp(val, "osmesa") && strcmp(val, "egl") &&
                         strcmp(val, "glfw")))
                return cmd_bad_value("render", opt, val, "offscreen, osmesa, egl or glfw");
            a->platform = val;
        } else if (!strcmp(opt, "-o")) {
            return cmd_bad_value("render", opt, NULL, "a PNG file");
        } else if (opt[0] == '-') {
            return cmd_usage_error("render", "unknown option '%s'", opt);
        } else {
            takes = 0;
            if (a->dir)
                return cmd_usage_error("render", "one CASE only ('%s' and '%s' given)", a->dir, opt);
            a->dir = opt;
        }
        i += takes;
    }
    if (!a->dir)
        return cmd_usage_error("render", "CASE is missing");
    if (!a->out)
        return cmd_usage_error("render", "-o FILE.png is missing");
    return 0;
}

/* 1 when world point p lies in one of v's voxels. */
static int inside_ct(const vol *v, const double p[3])
{
    double ijk[3];
    vol_world_to_index(v, p, ijk);
    for (int a = 0; a < 3; a++)
        if (!(ijk[a] >= -0.5 && ijk[a] <= v->dim[a] - 0.5))
            return 0;
    return 1;
}

/* The index of the selected fragment: --fragment's, or the first that is not fixed. -1 with
 * fn_err when --fragment names none. */
static int selected(const planning_case *c, int id)
{
    for (int i = 0; i < c->nfrag; i++)
        if (id ? c->frag[i].id == id : i != c->fixed)
            return i;
    if (id)
        return fn_err_set(FN_EINVAL, "--fragment %d: the case has no such fragment", id), -1;
    return 0;
}

/* --json: the view and each fragment's pixels through o's camera. */
static int print_json(render *r, const planning_case *c, const render_args *a, const render_options *o, int sel)
{
    long proj[RENDER_MAX_FRAGS], vis[RENDER_MAX_FRAGS];
    int rc = render_fragment_pixels(r, NULL, o, proj, vis);
    if (rc)
        return rc;
    static const char *names[] = {"anterior", "posterior", "left", "right", "superior", "inferior"};
    json_t *j = jsonw_object("render"), *frags = json_array();
    jsonw_set(j, "file", jsonw_string(a->out));
    jsonw_set(j, "view", jsonw_string(a->view < 0 ? "auto" : names[a->view]));
    jsonw_set(j, "mode", jsonw_string(render_mode_name(o->mode)));
    jsonw_set(j, "selected", json_integer(c->frag[sel].id));
    jsonw_set(j, "camera_forward", jsonw_exact_array(o->camera.forward, 3));
    for (int i = 0; i < c->nfrag; i++)
        json_array_append_new(frags, json_pack("{s:i,s:I,s:I}", "id", c->frag[i].id, "projected_pixels",
                                               (json_int_t)proj[i], "visible_pixels", (json_int_t)vis[i]));
    jsonw_set(j, "fragments", frags);
    return jsonw_print(j, stdout);
}

static int draw(planning_case *c, render_args *a)
{
    render_options o = a->o, d;
    int sel = selected(c, a->fragment);
    if (sel < 0)
        return FN_EINVAL;
    render_options_default(&d, c->frag, c->nfrag);
    render_camera_standard(&o.camera, a->view < 0 ? RENDER_ANTERIOR : (render_view)a->view, c->frag, c->nfrag);
    memcpy(o.slice_point, a->have_point ? a->point : d.slice_point, sizeof o.slice_point);
    o.cutaway = (a->cutaway < 0 ? a->view < 0 : a->cutaway) ? sel + 1 : 0;
    if ((o.overlays & RENDER_OVERLAY_VOI) && !(o.nvoi = cmd_case_voi(c, o.voi, RENDER_MAX_FRAGS)))
        return fn_err_set(FN_EINVAL, "--overlay voi: the case holds no reduction VOI (fracnav reduce "
                                     "defines one)");
    render *r = render_open(a->platform ? a->platform : "offscreen", a->w, a->h);
    if (!r)
        return FN_ENODEV;
    obb_params hp = {c->tau_min, c->tau_max};
    int rc = render_set_scene(r, c->ct, c->frag, c->nfrag, c->seg.threshold,
                              (o.overlays & (RENDER_OVERLAY_HIERARCHY | RENDER_OVERLAY_CONTACTS)) ? &hp : NULL);
    if (!rc && a->view < 0)
        rc = render_camera_auto(r, &o.camera, c->frag, c->nfrag, NULL, sel);
    if (!rc)
        rc = render_frame(r, NULL, &o);
    if (!rc)
        rc = cmd_write_png(r, a->out, a->w, a->h);
    if (!rc)
        fprintf(stderr, "fracnav render: %s (%s, %d fragments, %s)\n", a->out, render_mode_name(o.mode),
                c->nfrag, render_gl_renderer(r));
    if (!rc && a->json)
        rc = print_json(r, c, a, &o, sel);
    render_close(r);
    return rc;
}

int cmd_render(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    render_args a = {.w = 512, .h = 512, .view = -1, .cutaway = -1};
    a.o.mode = RENDER_ISO;
    a.o.hierarchy_depth = 3;
    int wait = cmd_take_flag(&argc, argv, "--wait"), recover = cmd_take_flag(&argc, argv, "--recover");
    int rc = parse_args(argc, argv, &a);
    if (rc)
        return rc;
    caselock *lock = cmd_lock_case("render", a.dir, recover, wait);
    if (!lock)
        return 1;
    planning_case *c = case_load(a.dir);
    if (c && cmd_journal_poses("render", c, recover) < 0) {
        case_free(c);
        c = NULL;
    }
    caselock_release(lock); /* what is drawn is the case as loaded */
    if (!c) {
        fprintf(stderr, "fracnav render: %s\n", fn_err_msg());
        return 1;
    }
    if (cmd_out_file(a.out, c) < 0) {
        fprintf(stderr, "fracnav render: -o %s\n", fn_err_msg());
        case_free(c);
        return 1;
    }
    if (a.have_point && !inside_ct(c->ct, a.point)) {
        fprintf(stderr, "fracnav render: --point %g,%g,%g lies outside the CT (%dx%dx%d voxels): the slices "
                        "through it would be empty\n", a.point[0], a.point[1], a.point[2], c->ct->dim[0],
                c->ct->dim[1], c->ct->dim[2]);
        case_free(c);
        return 1;
    }
    if (c->nfrag > RENDER_MAX_FRAGS) {
        fprintf(stderr, "fracnav render: %s has %d fragments; at most %d can be drawn\n", a.dir,
                c->nfrag, RENDER_MAX_FRAGS);
        case_free(c);
        return 1;
    }
    rc = draw(c, &a);
    if (rc)
        fprintf(stderr, "fracnav render: %s\n", fn_err_msg());
    case_free(c);
    return rc ? 1 : 0;
}
