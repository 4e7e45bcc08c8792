#include "simdev.h"

#include <string.h>
#include <strings.h>

#include "err.h"

#define SPLIT_MS 8000
#define COMBINED_MS 16000

#define P(id, vid, pid, name, fmt, period, nb, keys, bat, open) \
    {id, vid, pid, name, fmt, period, nb, keys, bat, open}
#define S3DX(id, pid, name, nb) P(id, 0x046d, pid, name, SIMDEV_SPLIT, SPLIT_MS, nb, 0, 0, 0)

/* Identities as in ../shared/DEVICES.md and the device table (devices/devtab.c). */
static const sim_profile profiles[] = {
    S3DX("spacenavigator", 0xc626, "3Dconnexion SpaceNavigator", 2),
    S3DX("spacenavigator-notebook", 0xc628, "3Dconnexion SpaceNavigator for Notebooks", 2),
    S3DX("spaceexplorer", 0xc627, "3Dconnexion SpaceExplorer", 15),
    S3DX("spacepilot-pro", 0xc629, "3Dconnexion SpacePilot Pro", 31),
    S3DX("spacemouse-pro", 0xc62b, "3Dconnexion SpaceMouse Pro", 27), /* sparse bits up to 26 */
    P("spacemouse-compact", 0x256f, 0xc635, "3Dconnexion SpaceMouse Compact", SIMDEV_SPLIT, SPLIT_MS,
      2, 0, 0, 0),
    P("spacemouse-wireless", 0x256f, 0xc62e, "3Dconnexion SpaceMouse Wireless (cable)",
      SIMDEV_COMBINED, COMBINED_MS, 2, 0, 1, 0),
    P("spacemouse-pro-wireless", 0x256f, 0xc631, "3Dconnexion SpaceMouse Pro Wireless (cable)",
      SIMDEV_COMBINED, COMBINED_MS, 15, 0, 1, 0),
    P("spacemouse-enterprise", 0x256f, 0xc633, "3Dconnexion SpaceMouse Enterprise", SIMDEV_COMBINED,
      COMBINED_MS, 31, 1, 0, 0),
    P("open-controller", 0x1209, 0x0001, "fracnav open 6-DOF controller", SIMDEV_COMBINED, SPLIT_MS,
      8, 0, 1, 1),
};

#define NPROFILES (sizeof profiles / sizeof profiles[0])

const sim_profile *sim_profile_at(size_t i)
{
    return i < NPROFILES ? &profiles[i] : NULL;
}

static int hex4(const char *s, uint16_t *v)
{
    unsigned x = 0;
    for (int i = 0; i < 4; i++) {
        char c = s[i];
        int d = c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10
              : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
        if (d < 0)
            return -1;
        x = x << 4 | (unsigned)d;
    }
    *v = (uint16_t)x;
    return 0;
}

const sim_profile *sim_profile_find(const char *id)
{
    uint16_t vid, pid;
    int byid = strlen(id) == 9 && id[4] == ':' && !hex4(id, &vid) && !hex4(id + 5, &pid);
    for (size_t i = 0; i < NPROFILES; i++)
        if (byid ? profiles[i].vid == vid && profiles[i].pid == pid : !strcasecmp(profiles[i].id, id))
            return &profiles[i];
    fn_err_set(FN_EINVAL, "unknown device '%s' (try one of: spacenavigator, spacemouse-wireless, "
                          "spacemouse-enterprise, open-controller, ... or VID:PID)", id);
    return NULL;
}

static int button_bytes(const sim_profile *p)
{
    return p->open ? 1 : p->nbuttons <= 16 ? 2 : p->nbuttons <= 24 ? 3 : 4;
}

int sim_profile_report_len(const sim_profile *p, uint8_t id)
{
    switch (id) {
    case 1: return p->format == SIMDEV_SPLIT ? 7 : 13;
    case 2: return p->format == SIMDEV_SPLIT ? 7 : 0;
    case 3: return 1 + button_bytes(p);
    case 0x17: return p->battery ? 2 : 0;
    case 0x1C: return p->keycodes ? 13 : 0;
    }
    return 0;
}

/* Vendor feature report IDs on usage page 0xFF00 and their payload bytes. */
static const uint8_t feature_ids[] = {5, 6, 7, 8, 9, 10, 11, 19};
static const uint8_t wireless_feature_ids[] = {25, 26};
#define FEATURE_PAYLOAD 4

typedef struct emitter {
    uint8_t *b;
    size_t n, cap;
} emitter;

static void put(emitter *e, const uint8_t *bytes, size_t n)
{
    for (size_t i = 0; i < n && e->n < e->cap; i++)
        e->b[e->n++] = bytes[i];
}

#define PUT(e, ...) put((e), (const uint8_t[]){__VA_ARGS__}, sizeof((const uint8_t[]){__VA_ARGS__}))

/* Logical +-350, physical +-1400, unit exponent -4, 16-bit fields, relative data. */
static void axes(emitter *e, uint8_t id, uint8_t first_usage, uint8_t count)
{
    PUT(e, 0xA1, 0x00, 0x85, id, 0x16, 0xA2, 0xFE, 0x26, 0x5E, 0x01, 0x36, 0x88, 0xFA, 0x46, 0x78,
        0x05, 0x55, 0x0C);
    for (uint8_t i = 0; i < count; i++)
        PUT(e, 0x09, (uint8_t)(first_usage + i));
    PUT(e, 0x75, 0x10, 0x95, count, 0x81, 0x06, 0xC0);
}

static void features(emitter *e, const uint8_t *ids, size_t n)
{
    for (size_t i = 0; i < n; i++)
        PUT(e, 0x85, ids[i], 0x09, ids[i], 0x75, 0x08, 0x95, FEATURE_PAYLOAD, 0xB1, 0x02);
}

/* firmware-spec/open-controller.desc.hex, byte for byte (a test compares them). */
static const uint8_t open_desc[] = {
    0x05, 0x01, 0x09, 0x08, 0xA1, 0x01, 0xA1, 0x00, 0x85, 0x01, 0x16, 0xA2, 0xFE, 0x26, 0x5E, 0x01,
    0x36, 0x88, 0xFA, 0x46, 0x78, 0x05, 0x55, 0x0C, 0x09, 0x30, 0x09, 0x31, 0x09, 0x32, 0x09, 0x33,
    0x09, 0x34, 0x09, 0x35, 0x75, 0x10, 0x95, 0x06, 0x81, 0x02, 0xC0, 0x85, 0x03, 0x05, 0x09, 0x19,
    0x01, 0x29, 0x08, 0x15, 0x00, 0x25, 0x01, 0x35, 0x00, 0x45, 0x01, 0x55, 0x00, 0x75, 0x01, 0x95,
    0x08, 0x81, 0x02, 0x85, 0x17, 0x05, 0x06, 0x09, 0x20, 0x15, 0x00, 0x25, 0x64, 0x45, 0x64, 0x75,
    0x08, 0x95, 0x01, 0x81, 0x02, 0x85, 0x04, 0x05, 0x08, 0x09, 0x4B, 0x15, 0x00, 0x25, 0x01, 0x45,
    0x01, 0x75, 0x01, 0x95, 0x01, 0x91, 0x02, 0x75, 0x07, 0x91, 0x03, 0x06, 0x00, 0xFF, 0x85, 0x20,
    0x09, 0x20, 0x15, 0x00, 0x26, 0xFF, 0x00, 0x46, 0xFF, 0x00, 0x75, 0x08, 0x95, 0x06, 0xB1, 0x03,
    0x85, 0x21, 0x09, 0x21, 0x16, 0xA2, 0xFE, 0x26, 0x5E, 0x01, 0x36, 0xA2, 0xFE, 0x46, 0x5E, 0x01,
    0x75, 0x10, 0x95, 0x06, 0xB1, 0x02, 0x85, 0x22, 0x09, 0x22, 0x15, 0x00, 0x26, 0xFF, 0x00, 0x35,
    0x00, 0x46, 0xFF, 0x00, 0x75, 0x08, 0x95, 0x03, 0xB1, 0x02, 0xC0};

size_t sim_profile_descriptor(const sim_profile *p, uint8_t *out, size_t cap)
{
    emitter e = {out, 0, cap};
    if (p->open) {
        put(&e, open_desc, sizeof open_desc);
        return e.n;
    }
    PUT(&e, 0x05, 0x01, 0x09, 0x08, 0xA1, 0x01); /* Generic Desktop, Multi-axis Controller */
    if (p->format == SIMDEV_SPLIT) {
        axes(&e, 1, 0x30, 3);
        axes(&e, 2, 0x33, 3);
    } else {
        axes(&e, 1, 0x30, 6);
    }
    uint8_t bits = (uint8_t)(8 * button_bytes(p));
    PUT(&e, 0xA1, 0x02, 0x85, 0x03, 0x05, 0x09, 0x19, 0x01, 0x29, bits, 0x15, 0x00, 0x25, 0x01, 0x35,
        0x00, 0x45, 0x01, 0x75, 0x01, 0x95, bits, 0x81, 0x02, 0xC0);
    PUT(&e, 0xA1, 0x02, 0x05, 0x08, 0x85, 0x04, 0x09, 0x4B, 0x15, 0x00, 0x25, 0x01, 0x95, 0x01, 0x75,
        0x01, 0x91, 0x02, 0x95, 0x01, 0x75, 0x07, 0x91, 0x03, 0xC0);
    if (p->battery)
        PUT(&e, 0x05, 0x06, 0x85, 0x17, 0x09, 0x20, 0x15, 0x00, 0x26, 0x64, 0x00, 0x75, 0x08, 0x95,
            0x01, 0x81, 0x02);
    PUT(&e, 0x06, 0x00, 0xFF, 0x15, 0x00, 0x26, 0xFF, 0x00);
    if (p->keycodes)
        PUT(&e, 0x85, 0x1C, 0x09, 0x1C, 0x75, 0x10, 0x95, 0x06, 0x27, 0xFF, 0xFF, 0x00, 0x00, 0x81,
            0x00, 0x26, 0xFF, 0x00);
    features(&e, feature_ids, sizeof feature_ids);
    if (p->battery)
        features(&e, wireless_feature_ids, sizeof wireless_feature_ids);
    PUT(&e, 0xC0);
    return e.n;
}

/* The open controller's feature reports at power-on (firmware-spec/open-controller.md, 5). */
static const uint8_t open_info[] = {0x20, 1, 1, 0, 8, 0x5E, 0x01};
static const uint8_t open_offsets[13] = {0x21};
static const uint8_t open_settings[] = {0x22, 8, SIMDEV_ZERO_REPEATS, 0};

static void set_default(simdev *d, const uint8_t *b, size_t n)
{
    memcpy(d->feature[b[0]], b, n);
    d->feature_len[b[0]] = (uint8_t)n;
}

static int feature_known(const sim_profile *p, uint8_t id)
{
    if (p->open)
        return 0;
    if (memchr(feature_ids, id, sizeof feature_ids))
        return 1;
    return p->battery && memchr(wireless_feature_ids, id, sizeof wireless_feature_ids) != NULL;
}

void simdev_init(simdev *d, const sim_profile *p)
{
    memset(d, 0, sizeof *d);
    d->p = p;
    for (size_t i = 0; i < SIMDEV_FEATURE_IDS; i++)
        if (feature_known(p, (uint8_t)i)) {
            d->feature[i][0] = (uint8_t)i;
            d->feature_len[i] = 1 + FEATURE_PAYLOAD;
        }
    if (p->open) {
        set_default(d, open_info, sizeof open_info);
        set_default(d, open_offsets, sizeof open_offsets);
        set_default(d, open_settings, sizeof open_settings);
    }
    d->battery_pending = p->battery;
}

static int moving(const simdev *d)
{
    for (int i = 0; i < 6; i++)
        if (d->axes[i])
            return 1;
    return 0;
}

void simdev_set(simdev *d, const int16_t a[6], uint32_t buttons)
{
    for (int i = 0; i < 6; i++)
        d->axes[i] = a[i] > 350 ? 350 : a[i] < -350 ? -350 : a[i];
    uint32_t valid = d->p->nbuttons >= 32 ? 0xffffffffu : (1u << d->p->nbuttons) - 1;
    d->buttons = buttons & valid;
    if (moving(d))
        d->zeros_left = SIMDEV_ZERO_REPEATS * (d->p->format == SIMDEV_SPLIT ? 2 : 1);
}

int simdev_idle(const simdev *d)
{
    return !moving(d) && !d->zeros_left && d->buttons == d->sent_buttons && !d->keycode_pending &&
           !d->battery_pending;
}

static void le16(uint8_t *b, int16_t v)
{
    b[0] = (uint8_t)((uint16_t)v & 0xff);
    b[1] = (uint8_t)((uint16_t)v >> 8);
}

/* Enterprise key codes for bitmask bits 0..: buttons 1-10, 11, 12, then MENU, FIT, ESC ALT SHIFT
 * CTRL, rotate, pan/zoom, dominant, +, -, ENTER, DELETE, V1-V3, TAB, SPACE, views. */
static const uint16_t keycode_of_bit[32] = {13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 77, 78, 1, 2, 23,
                                            24, 25, 26, 27, 28, 29, 30, 31, 36, 37, 103, 104, 105,
                                            175, 176, 3, 4};

static int keycode_report(const simdev *d, uint8_t *buf)
{
    memset(buf, 0, 13);
    buf[0] = 0x1C;
    int k = 0;
    for (int bit = 0; bit < 32 && k < 6; bit++)
        if (d->buttons >> bit & 1)
            le16(buf + 1 + 2 * k++, (int16_t)keycode_of_bit[bit]);
    return 13;
}

int simdev_next(simdev *d, uint8_t *buf, size_t cap)
{
    if (cap < 16)
        return 0;
    if (d->battery_pending) {
        d->battery_pending = 0;
        buf[0] = 0x17;
        buf[1] = 100;
        return 2;
    }
    if (d->buttons != d->sent_buttons) {
        int n = sim_profile_report_len(d->p, 3);
        buf[0] = 3;
        for (int i = 1; i < n; i++)
            buf[i] = (uint8_t)(d->buttons >> (8 * (i - 1)));
        d->sent_buttons = d->buttons;
        d->keycode_pending = d->p->keycodes;
        return n;
    }
    if (d->keycode_pending) {
        d->keycode_pending = 0;
        return keycode_report(d, buf);
    }
    if (!moving(d) && !d->zeros_left)
        return 0;
    if (!moving(d))
        d->zeros_left--;
    if (d->p->format == SIMDEV_COMBINED) {
        buf[0] = 1;
        for (int i = 0; i < 6; i++)
            le16(buf + 1 + 2 * i, d->axes[i]);
        return 13;
    }
    buf[0] = (uint8_t)(1 + d->phase);
    for (int i = 0; i < 3; i++)
        le16(buf + 1 + 2 * i, d->axes[3 * d->phase + i]);
    d->phase ^= 1;
    return 7;
}

int simdev_output(simdev *d, const uint8_t *buf, size_t len)
{
    if (len == 2 && buf[0] == 4 && buf[1] <= 1) {
        d->led = buf[1];
        return (int)len;
    }
    return fn_err_set(FN_EINVAL, "virtual device: unknown output report (id %u, %zu bytes)",
                      len ? buf[0] : 0u, len);
}

int simdev_get_feature(simdev *d, uint8_t *buf, size_t cap)
{
    uint8_t id = buf[0];
    if (id >= SIMDEV_FEATURE_IDS || !d->feature_len[id])
        return fn_err_set(FN_EINVAL, "virtual device: no feature report %u", id);
    size_t n = d->feature_len[id] < cap ? d->feature_len[id] : cap;
    memcpy(buf, d->feature[id], n);
    return (int)n;
}

/* The open controller refuses (stalls) read-only reports and values out of range. */
static int open_feature_ok(const uint8_t *b, size_t len)
{
    if (b[0] == 0x21 && len == 13) {
        for (int i = 0; i < 6; i++) {
            int16_t v = (int16_t)(b[1 + 2 * i] | b[2 + 2 * i] << 8);
            if (v < -350 || v > 350)
                return 0;
        }
        return 1;
    }
    return b[0] == 0x22 && len == 4 && b[1] >= 1 && b[3] <= 1;
}

int simdev_set_feature(simdev *d, const uint8_t *buf, size_t len)
{
    uint8_t id = len ? buf[0] : 0;
    if (!len || id >= SIMDEV_FEATURE_IDS || !d->feature_len[id] || len > SIMDEV_FEATURE_LEN ||
        (d->p->open && !open_feature_ok(buf, len)))
        return fn_err_set(FN_EINVAL, "virtual device: cannot set feature report %u (%zu bytes)", id,
                          len);
    memcpy(d->feature[id], buf, len);
    d->feature_len[id] = (uint8_t)len;
    return (int)len;
}
