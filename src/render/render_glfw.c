/* The window platform: GLFW (GLX), which loads libGL itself when a display exists. Built only when
 * GLFW is found (FRACNAV_HAVE_GLFW); without it, opening says so. */
#include "render_impl.h"

#include "err.h"

#include <stdlib.h>

#ifdef FRACNAV_HAVE_GLFW
#include <GLFW/glfw3.h>

static int glfw_open(render *r, int w, int h)
{
    if (!glfwInit())
        return fn_err_set(FN_ENODEV, "glfw: cannot start (no display? $DISPLAY is '%s')",
                          getenv("DISPLAY") ? getenv("DISPLAY") : "");
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 4);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 5);
    glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
    glfwWindowHint(GLFW_RESIZABLE, GLFW_FALSE);
    GLFWwindow *win = glfwCreateWindow(w, h, "fracnav", NULL, NULL);
    if (!win) {
        const char *why = NULL;
        glfwGetError(&why);
        glfwTerminate();
        return fn_err_set(FN_ENODEV, "glfw: no OpenGL 4.5 core window: %s (install Mesa 20 or later "
                                     "or a newer GPU driver)", why ? why : "unknown reason");
    }
    glfwMakeContextCurrent(win);
    glfwSwapInterval(0);
    r->plat_state = win;
    return 0;
}

static void *glfw_proc(render *r, const char *name)
{
    return (void *)glfwGetProcAddress(name);
}

static int glfw_present(render *r)
{
    glfwSwapBuffers(r->plat_state);
    glfwPollEvents();
    return 0;
}

static void glfw_close(render *r)
{
    glfwDestroyWindow(r->plat_state);
    glfwTerminate();
    r->plat_state = NULL;
}

const render_platform render__glfw = {
    .name = "glfw",
    .available = 1,
    .open = glfw_open,
    .proc = glfw_proc,
    .present = glfw_present,
    .close = glfw_close,
};
#else
static int none_open(render *r, int w, int h)
{
    return fn_err_set(FN_ENODEV, "glfw: this fracnav was built without GLFW (install libglfw3-dev "
                                 "and rebuild)");
}

const render_platform render__glfw = {.name = "glfw", .available = 0, .open = none_open};
#endif
