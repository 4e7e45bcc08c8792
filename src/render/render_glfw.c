/* The window platform: GLFW (GLX), which loads libGL itself when a display exists. Built only when
 * GLFW is found (FRACNAV_HAVE_GLFW); without it, opening says so. */
#include "render_impl.h"

#include "err.h"

#include <stdlib.h>

#ifdef FRACNAV_HAVE_GLFW
#include <GLFW/glfw3.h>

#include <math.h>
#include <string.h>

/* The window and the input that arrived since the last render_poll. */
typedef struct glfw_state {
    GLFWwindow *win;
    render_input in;
    double x, y;
    int have_pos;
    double press[2]; /* where the left button went down */
    int pressed;
} glfw_state;

static void on_char(GLFWwindow *w, unsigned int c)
{
    glfw_state *st = glfwGetWindowUserPointer(w);
    if (c < 128 && st->in.nkeys < RENDER_INPUT_KEYS)
        st->in.keys[st->in.nkeys++] = (int)c;
}

/* The keys that type no character (render.h's RENDER_KEY_*); 0 for the others. */
static int special_key(int key, int action, int mods)
{
    if (key >= GLFW_KEY_F1 && key <= GLFW_KEY_F12)
        return RENDER_KEY_F1 + key - GLFW_KEY_F1;
    if (key >= GLFW_KEY_RIGHT && key <= GLFW_KEY_UP) {
        static const int arrow[] = {RENDER_KEY_RIGHT, RENDER_KEY_LEFT, RENDER_KEY_DOWN, RENDER_KEY_UP};
        return arrow[key - GLFW_KEY_RIGHT];
    }
    if (action != GLFW_PRESS)
        return 0;
    if (key == GLFW_KEY_ESCAPE)
        return RENDER_KEY_ESCAPE;
    if (key == GLFW_KEY_ENTER || key == GLFW_KEY_KP_ENTER)
        return '\r';
    if (key == GLFW_KEY_BACKSPACE)
        return '\b';
    if ((mods & GLFW_MOD_CONTROL) && key >= GLFW_KEY_0 && key <= GLFW_KEY_9)
        return RENDER_KEY_CTRL | ('0' + key - GLFW_KEY_0);
    if ((mods & GLFW_MOD_CONTROL) && key >= GLFW_KEY_A && key <= GLFW_KEY_Z)
        return RENDER_KEY_CTRL | ('a' + key - GLFW_KEY_A);
    return 0;
}

static void on_key(GLFWwindow *w, int key, int scancode, int action, int mods)
{
    glfw_state *st = glfwGetWindowUserPointer(w);
    (void)scancode;
    int k = action == GLFW_RELEASE ? 0 : special_key(key, action, mods);
    if (k && st->in.nkeys < RENDER_INPUT_KEYS)
        st->in.keys[st->in.nkeys++] = k;
}

static void on_cursor(GLFWwindow *w, double x, double y)
{
    glfw_state *st = glfwGetWindowUserPointer(w);
    static const int buttons[3] = {GLFW_MOUSE_BUTTON_LEFT, GLFW_MOUSE_BUTTON_RIGHT, GLFW_MOUSE_BUTTON_MIDDLE};
    if (st->have_pos)
        for (int b = 0; b < 3; b++)
            if (glfwGetMouseButton(w, buttons[b]) == GLFW_PRESS) {
                st->in.drag[b][0] += x - st->x;
                st->in.drag[b][1] += y - st->y;
                if (b == 0)
                    memcpy(st->in.press, st->press, sizeof st->press);
            }
    st->x = x;
    st->y = y;
    st->have_pos = 1;
}

/* A left press and release within 3 pixels is a click (a longer way is a drag: an orbit). */
static void on_button(GLFWwindow *w, int button, int action, int mods)
{
    glfw_state *st = glfwGetWindowUserPointer(w);
    (void)mods;
    if (button != GLFW_MOUSE_BUTTON_LEFT)
        return;
    if (action == GLFW_PRESS) {
        st->press[0] = st->x, st->press[1] = st->y;
        st->pressed = 1;
    } else if (st->pressed && fabs(st->x - st->press[0]) < 3 && fabs(st->y - st->press[1]) < 3) {
        st->pressed = 0;
        if (st->in.nclicks < RENDER_INPUT_CLICKS && st->in.nkeys < RENDER_INPUT_KEYS) {
            st->in.click[st->in.nclicks][0] = st->x, st->in.click[st->in.nclicks][1] = st->y;
            st->in.keys[st->in.nkeys++] = RENDER_KEY_CLICK + st->in.nclicks++;
        }
    }
}

static void on_scroll(GLFWwindow *w, double dx, double dy)
{
    glfw_state *st = glfwGetWindowUserPointer(w);
    (void)dx;
    st->in.scroll += dy;
}

static int glfw_open(render *r, int w, int h)
{
    if (!glfwInit())
        return fn_err_set(FN_ENODEV, "glfw: cannot start (no display? $DISPLAY is '%s')",
                          getenv("DISPLAY") ? getenv("DISPLAY") : "");
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 4);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 5);
    glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
    glfwWindowHint(GLFW_RESIZABLE, GLFW_TRUE);
    GLFWwindow *win = glfwCreateWindow(w, h, "fracnav", NULL, NULL);
    if (!win) {
        const char *why = NULL;
        glfwGetError(&why);
        glfwTerminate();
        return fn_err_set(FN_ENODEV, "glfw: no OpenGL 4.5 core window: %s (install Mesa 20 or later "
                                     "or a newer GPU driver)", why ? why : "unknown reason");
    }
    glfw_state *st = calloc(1, sizeof *st);
    if (!st) {
        glfwDestroyWindow(win);
        glfwTerminate();
        return fn_err_set(FN_ENOMEM, "glfw: out of memory");
    }
    st->win = win;
    glfwSetWindowUserPointer(win, st);
    glfwSetCharCallback(win, on_char);
    glfwSetKeyCallback(win, on_key);
    glfwSetCursorPosCallback(win, on_cursor);
    glfwSetScrollCallback(win, on_scroll);
    glfwSetMouseButtonCallback(win, on_button);
    glfwMakeContextCurrent(win);
    glfwSwapInterval(0);
    r->plat_state = st;
    return 0;
}

static void *glfw_proc(render *r, const char *name)
{
    (void)r;
    return (void *)glfwGetProcAddress(name);
}

static int glfw_present(render *r)
{
    glfw_state *st = r->plat_state;
    glfwSwapBuffers(st->win);
    glfwPollEvents();
    return 0;
}

static int glfw_poll(render *r, render_input *in)
{
    glfw_state *st = r->plat_state;
    glfwPollEvents();
    *in = st->in;
    in->close = glfwWindowShouldClose(st->win);
    in->x = st->x, in->y = st->y;
    in->left_down = glfwGetMouseButton(st->win, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS;
    memset(&st->in, 0, sizeof st->in);
    /* A resized window: the frame follows its framebuffer. */
    int w, h;
    glfwGetFramebufferSize(st->win, &w, &h);
    if (w > 0 && h > 0)
        r->w = w, r->h = h;
    return 0;
}

static float glfw_content_scale(const render *r)
{
    glfw_state *st = r->plat_state;
    float x = 1, y = 1;
    glfwGetWindowContentScale(st->win, &x, &y);
    return y > 0 ? y : 1;
}

static void glfw_close(render *r)
{
    glfw_state *st = r->plat_state;
    glfwDestroyWindow(st->win);
    glfwTerminate();
    free(st);
    r->plat_state = NULL;
}

const render_platform render__glfw = {
    .name = "glfw",
    .available = 1,
    .open = glfw_open,
    .proc = glfw_proc,
    .present = glfw_present,
    .poll = glfw_poll,
    .content_scale = glfw_content_scale,
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
