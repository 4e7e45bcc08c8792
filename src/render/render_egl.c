/* The headless GPU platform: EGL on a GPU's EGL device (EGL_EXT_device_enumeration and
 * EGL_EXT_platform_device), with a w x h pbuffer as the default framebuffer, so a machine with a
 * GPU and no display renders offscreen on the GPU. libEGL is loaded with dlopen only here, as
 * libOSMesa is: a machine without it keeps OSMesa. A software device (Mesa's
 * EGL_MESA_device_software, llvmpipe again) is not a GPU and is not used. */
#include "render_impl.h"

#include "err.h"

#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <dlfcn.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define EGL_FUNCS(X)                                                                               \
    X(PFNEGLGETPROCADDRESSPROC, eglGetProcAddress) X(PFNEGLINITIALIZEPROC, eglInitialize)          \
    X(PFNEGLTERMINATEPROC, eglTerminate) X(PFNEGLBINDAPIPROC, eglBindAPI)                          \
    X(PFNEGLCHOOSECONFIGPROC, eglChooseConfig) X(PFNEGLCREATEPBUFFERSURFACEPROC, eglCreatePbufferSurface) \
    X(PFNEGLCREATECONTEXTPROC, eglCreateContext) X(PFNEGLMAKECURRENTPROC, eglMakeCurrent)          \
    X(PFNEGLDESTROYCONTEXTPROC, eglDestroyContext) X(PFNEGLDESTROYSURFACEPROC, eglDestroySurface)

static struct {
#define EGL_MEMBER(type, name) type name;
    EGL_FUNCS(EGL_MEMBER)
#undef EGL_MEMBER
    PFNEGLQUERYDEVICESEXTPROC query_devices;
    PFNEGLQUERYDEVICESTRINGEXTPROC device_string;
    PFNEGLGETPLATFORMDISPLAYEXTPROC platform_display;
} egl;

/* Loaded once and never unloaded, as libOSMesa (render_osmesa.c). */
static pthread_once_t lib_once = PTHREAD_ONCE_INIT;
static char lib_error[256];
static int lib_ok;

static void lib_load(void)
{
    void *lib = dlopen("libEGL.so.1", RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        snprintf(lib_error, sizeof lib_error, "cannot load libEGL.so.1 (install libegl1): %s", dlerror());
        return;
    }
    int missing = 0;
#define EGL_LOAD(type, name) missing |= !(egl.name = (type)dlsym(lib, #name));
    EGL_FUNCS(EGL_LOAD)
#undef EGL_LOAD
    if (!missing) {
        egl.query_devices = (PFNEGLQUERYDEVICESEXTPROC)egl.eglGetProcAddress("eglQueryDevicesEXT");
        egl.device_string = (PFNEGLQUERYDEVICESTRINGEXTPROC)egl.eglGetProcAddress("eglQueryDeviceStringEXT");
        egl.platform_display = (PFNEGLGETPLATFORMDISPLAYEXTPROC)egl.eglGetProcAddress("eglGetPlatformDisplayEXT");
    }
    if (missing || !egl.query_devices || !egl.device_string || !egl.platform_display)
        snprintf(lib_error, sizeof lib_error, "libEGL lacks EGL 1.4 or EGL_EXT_device_enumeration and "
                                              "EGL_EXT_platform_device");
    else
        lib_ok = 1;
}

/* The first GPU's EGL device into *dev; 0, or FN_ENODEV with the reason. */
static int find_gpu(EGLDeviceEXT *dev)
{
    pthread_once(&lib_once, lib_load);
    if (!lib_ok)
        return fn_err_set(FN_ENODEV, "egl: %s", lib_error);
    EGLDeviceEXT devs[16];
    EGLint n = 0;
    if (!egl.query_devices(16, devs, &n))
        n = 0;
    for (EGLint i = 0; i < n; i++) {
        const char *ext = egl.device_string(devs[i], EGL_EXTENSIONS);
        if (!ext || !strstr(ext, "EGL_MESA_device_software")) {
            *dev = devs[i];
            return 0;
        }
    }
    return fn_err_set(FN_ENODEV, "egl: no GPU's EGL device (%d software device(s) only)", (int)n);
}

int render__egl_gpu(void)
{
    EGLDeviceEXT dev;
    return find_gpu(&dev) == 0;
}

typedef struct egl_state {
    EGLDisplay dpy;
    EGLSurface surf;
    EGLContext ctx;
} egl_state;

static void egl_close(render *r)
{
    egl_state *e = r->plat_state;
    if (!e)
        return;
    if (e->dpy != EGL_NO_DISPLAY) {
        egl.eglMakeCurrent(e->dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        if (e->ctx != EGL_NO_CONTEXT)
            egl.eglDestroyContext(e->dpy, e->ctx);
        if (e->surf != EGL_NO_SURFACE)
            egl.eglDestroySurface(e->dpy, e->surf);
        egl.eglTerminate(e->dpy);
    }
    free(e);
    r->plat_state = NULL;
}

static int egl_open(render *r, int w, int h)
{
    EGLDeviceEXT dev;
    int rc = find_gpu(&dev);
    if (rc)
        return rc;
    egl_state *e = calloc(1, sizeof *e);
    if (!e)
        return fn_err_set(FN_ENOMEM, "egl: out of memory");
    e->dpy = EGL_NO_DISPLAY;
    e->surf = EGL_NO_SURFACE;
    e->ctx = EGL_NO_CONTEXT;
    r->plat_state = e;
    e->dpy = egl.platform_display(EGL_PLATFORM_DEVICE_EXT, dev, NULL);
    if (e->dpy == EGL_NO_DISPLAY || !egl.eglInitialize(e->dpy, NULL, NULL)) {
        e->dpy = EGL_NO_DISPLAY;
        return fn_err_set(FN_ENODEV, "egl: cannot initialize the GPU's EGL display");
    }
    const EGLint cattr[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT,
                            EGL_RED_SIZE, 8, EGL_GREEN_SIZE, 8, EGL_BLUE_SIZE, 8, EGL_DEPTH_SIZE, 24,
                            EGL_NONE};
    EGLConfig cfg;
    EGLint ncfg = 0;
    if (!egl.eglChooseConfig(e->dpy, cattr, &cfg, 1, &ncfg) || ncfg < 1)
        return fn_err_set(FN_ENODEV, "egl: the GPU offers no RGB8 pbuffer with a 24-bit depth buffer");
    const EGLint sattr[] = {EGL_WIDTH, w, EGL_HEIGHT, h, EGL_NONE};
    e->surf = egl.eglCreatePbufferSurface(e->dpy, cfg, sattr);
    if (e->surf == EGL_NO_SURFACE)
        return fn_err_set(FN_ENODEV, "egl: cannot make a %dx%d pbuffer", w, h);
    const EGLint xattr[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 5,
                            EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    if (!egl.eglBindAPI(EGL_OPENGL_API) ||
        (e->ctx = egl.eglCreateContext(e->dpy, cfg, EGL_NO_CONTEXT, xattr)) == EGL_NO_CONTEXT)
        return fn_err_set(FN_ENODEV, "egl: the GPU gives no OpenGL 4.5 core context");
    if (!egl.eglMakeCurrent(e->dpy, e->surf, e->surf, e->ctx))
        return fn_err_set(FN_ENODEV, "egl: cannot make the %dx%d context current", w, h);
    return 0;
}

static void *egl_proc(render *r, const char *name)
{
    (void)r;
    return (void *)egl.eglGetProcAddress(name);
}

static int egl_present(render *r)
{
    (void)r;
    return 0;
}

const render_platform render__egl = {
    .name = "egl",
    .available = 1,
    .open = egl_open,
    .proc = egl_proc,
    .present = egl_present,
    .close = egl_close,
};
