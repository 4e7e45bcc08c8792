/* The offscreen platform: OSMesa (llvmpipe), loaded with dlopen only here, because libOSMesa
 * exports its own gl* symbols and would shadow a window system's libGL if it were linked. */
#include "render_impl.h"

#include "err.h"

#include <GL/osmesa.h>
#include <dlfcn.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>

typedef struct osm {
    OSMesaContext ctx;
    unsigned char *buf;
    void *(*get_proc)(const char *);
    void (*destroy)(OSMesaContext);
} osm;

/* Loaded once and never unloaded: Mesa keeps process-wide state (LLVM, its screen) that an unload
 * would strand. */
static pthread_once_t lib_once = PTHREAD_ONCE_INIT;
static void *lib;
static char lib_error[256];

static void lib_load(void)
{
    lib = dlopen("libOSMesa.so.8", RTLD_NOW | RTLD_LOCAL);
    if (!lib)
        lib = dlopen("libOSMesa.so", RTLD_NOW | RTLD_LOCAL);
    if (!lib)
        snprintf(lib_error, sizeof lib_error, "%s", dlerror());
}

typedef OSMesaContext (*create_fn)(const int *, OSMesaContext);
typedef GLboolean (*make_current_fn)(OSMesaContext, void *, GLenum, GLsizei, GLsizei);

static void osm_close(render *r)
{
    osm *o = r->plat_state;
    if (!o)
        return;
    if (o->ctx)
        o->destroy(o->ctx);
    free(o->buf);
    free(o);
    r->plat_state = NULL;
}

static int osm_open(render *r, int w, int h)
{
    osm *o = calloc(1, sizeof *o);
    if (!o)
        return fn_err_set(FN_ENOMEM, "osmesa: out of memory");
    r->plat_state = o;
    pthread_once(&lib_once, lib_load);
    if (!lib)
        return fn_err_set(FN_ENODEV, "osmesa: cannot load libOSMesa.so.8 (install libosmesa6): %s",
                          lib_error);
    create_fn create = (create_fn)dlsym(lib, "OSMesaCreateContextAttribs");
    make_current_fn make_current = (make_current_fn)dlsym(lib, "OSMesaMakeCurrent");
    o->get_proc = (void *(*)(const char *))dlsym(lib, "OSMesaGetProcAddress");
    o->destroy = (void (*)(OSMesaContext))dlsym(lib, "OSMesaDestroyContext");
    if (!create || !make_current || !o->get_proc || !o->destroy)
        return fn_err_set(FN_ENODEV, "osmesa: libOSMesa lacks OSMesaCreateContextAttribs (Mesa 11.2 "
                                     "or later needed)");
    const int attrs[] = {OSMESA_FORMAT, OSMESA_RGBA, OSMESA_DEPTH_BITS, 24, OSMESA_PROFILE,
                         OSMESA_CORE_PROFILE, OSMESA_CONTEXT_MAJOR_VERSION, 4,
                         OSMESA_CONTEXT_MINOR_VERSION, 5, 0};
    o->ctx = create(attrs, NULL);
    if (!o->ctx) {
        /* Ask for any context to name the version this Mesa gives. */
        const int any[] = {OSMESA_FORMAT, OSMESA_RGBA, 0};
        o->ctx = create(any, NULL);
        if (!o->ctx)
            return fn_err_set(FN_ENODEV, "osmesa: no GL context at all (is llvmpipe installed?)");
    }
    o->buf = malloc((size_t)w * (size_t)h * 4);
    if (!o->buf)
        return fn_err_set(FN_ENOMEM, "osmesa: out of memory for a %dx%d buffer", w, h);
    if (!make_current(o->ctx, o->buf, GL_UNSIGNED_BYTE, w, h))
        return fn_err_set(FN_ENODEV, "osmesa: cannot make the %dx%d context current", w, h);
    return 0;
}

static void *osm_proc(render *r, const char *name)
{
    osm *o = r->plat_state;
    return o->get_proc(name);
}

static int osm_present(render *r)
{
    return 0;
}

const render_platform render__osmesa = {
    .name = "osmesa",
    .available = 1,
    .open = osm_open,
    .proc = osm_proc,
    .present = osm_present,
    .close = osm_close,
};
