#include "simdev.h"

#include <ctype.h>
#include <pthread.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>

#include "err.h"

/* Sim-only data: the cadence of each report format. Everything else (identity, short name, USB
 * strings, format, buttons, battery, key codes) comes from the device table, so every hardware row
 * of devices/devtab.c can be impersonated, including rows added later. */
static int cadence_us(devtab_format f)
{
    return f == DEVTAB_COMBINED ? 16000 : 8000; /* split and legacy: 8 ms */
}

#define OPEN_CADENCE_US 8000 /* firmware-spec/open-controller.md, 6 */

#define MAX_PROFILES 64
#define ID_MAX 48
#define NAME_MAX_ 128

static sim_profile profiles[MAX_PROFILES];
static char profile_ids[MAX_PROFILES][ID_MAX];
static char profile_names[MAX_PROFILES][NAME_MAX_];
static char profile_serials[MAX_PROFILES][SIMDEV_SERIAL_MAX];
static size_t nprofiles;
static pthread_once_t profiles_once = PTHREAD_ONCE_INIT;

/* A row without a short name is named after its product: "3Dconnexion SpaceMouse Plus XT (USB)" ->
 * "spacemouse-plus-xt-usb". */
static void slug(const char *name, char *out, size_t cap)
{
    static const char vendor[] = "3Dconnexion ";
    if (!strncmp(name, vendor, sizeof vendor - 1))
        name += sizeof vendor - 1;
    size_t n = 0;
    for (; *name && n + 1 < cap; name++) {
        if (isalnum((unsigned char)*name))
            out[n++] = (char)tolower((unsigned char)*name);
        else if (n && out[n - 1] != '-')
            out[n++] = '-';
    }
    while (n && out[n - 1] == '-')
        n--;
    out[n] = '\0';
}

static int top_bit(uint32_t mask)
{
    int n = 0;
    while (n < 32 && mask >> n)
        n++;
    return n;
}

static void profile_from_row(const devtab_row *row, sim_profile *p, size_t k)
{
    char *id = profile_ids[k], *name = profile_names[k], *serial = profile_serials[k];
    if (row->alias)
        snprintf(id, ID_MAX, "%s", row->alias);
    else
        slug(row->name, id, ID_MAX);
    /* Linux usbhid names a device manufacturer + " " + product (HIDIOCGRAWNAME). */
    snprintf(name, NAME_MAX_, "%s%s%s", row->usb_vendor ? row->usb_vendor : "", row->usb_vendor ? " " : "",
             row->name);
    snprintf(serial, SIMDEV_SERIAL_MAX, "FNSIM%04X%04X", row->vid, row->pid); /* stable, 13 chars */
    int open = (row->flags & DEVTAB_F_OPEN) != 0;
    *p = (sim_profile){
        .id = id, .vid = row->vid, .pid = row->pid, .name = name, .serial = serial,
        .format = row->format == DEVTAB_COMBINED ? SIMDEV_COMBINED : SIMDEV_SPLIT,
        .period_us = open ? OPEN_CADENCE_US : cadence_us(row->format),
        .nbuttons = top_bit(row->button_mask),
        .keycodes = (row->flags & DEVTAB_F_KEYCODES) != 0,
        .battery = (row->flags & DEVTAB_F_BATTERY) != 0,
        .open = open, .row = row,
    };
}

static void build_profiles(void)
{
    size_t n;
    const devtab_row *rows = devtab_rows(&n);
    for (size_t i = 0; i < n && nprofiles < MAX_PROFILES; i++)
        if (!(rows[i].flags & DEVTAB_F_SYNTH)) {
            profile_from_row(&rows[i], &profiles[nprofiles], nprofiles);
            nprofiles++;
        }
}

const sim_profile *sim_profile_at(size_t i)
{
    pthread_once(&profiles_once, build_profiles);
    return i < nprofiles ? &profiles[i] : NULL;
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
    const sim_profile *p;
    for (size_t i = 0; (p = sim_profile_at(i)); i++)
        if (byid ? p->vid == vid && p->pid == pid : !strcasecmp(p->id, id))
            return p;
    if (byid)
        fn_err_set(FN_EINVAL, "no device %s in the device table (fracnav-sim list shows them)", id);
    else
        fn_err_set(FN_EINVAL, "unknown device '%s' (fracnav-sim list shows the names; VID:PID in hex "
                              "such as 046d:c626 also works)", id);
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
    d->period_us = p->period_us;
    d->idle_zeros = SIMDEV_ZERO_REPEATS;
}

void simdev_replug(simdev *d)
{
    int16_t offset[6];
    uint8_t zero[SIMDEV_FEATURE_LEN];
    memcpy(offset, d->offset, sizeof offset);
    memcpy(zero, d->feature[0x21], sizeof zero);
    simdev_init(d, d->p);
    if (d->p->open) {
        memcpy(d->offset, offset, sizeof offset);
        memcpy(d->feature[0x21], zero, sizeof zero);
    }
}

int simdev_period_us(const simdev *d)
{
    return d->period_us;
}

void simdev_copy_settings(simdev *d, const simdev *src)
{
    memcpy(d->feature, src->feature, sizeof d->feature);
    memcpy(d->feature_len, src->feature_len, sizeof d->feature_len);
    memcpy(d->offset, src->offset, sizeof d->offset);
    d->period_us = src->period_us;
    d->idle_zeros = src->idle_zeros;
    d->led_mode = src->led_mode;
    d->led = src->led;
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
    d->buttons = buttons & d->p->row->button_mask;
    if (moving(d))
        d->zeros_left = d->idle_zeros * (d->p->format == SIMDEV_SPLIT ? 2 : 1);
    if (d->led_mode)
        d->led = moving(d);
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

#define NOISE_FLOOR 2 /* open controller: |value| <= 2 after the offsets is sent as 0 */

/* What the device reports for axis i: the reading less its zero offset, clamped, noise floored.
 * A released cap reads exactly 0 (the virtual sensor has no drift): its zeros stay zeros. */
static int16_t reported(const simdev *d, int i)
{
    if (!d->offset[i] || !moving(d))
        return d->axes[i];
    int v = d->axes[i] - d->offset[i];
    v = v > 350 ? 350 : v < -350 ? -350 : v;
    return (int16_t)(v >= -NOISE_FLOOR && v <= NOISE_FLOOR ? 0 : v);
}

static int keycode_report(const simdev *d, uint8_t *buf)
{
    memset(buf, 0, 13);
    buf[0] = 0x1C;
    int k = 0;
    size_t nkeys;
    const devtab_key *keys = devtab_keys(&nkeys); /* the key a button number stands for */
    for (size_t i = 0; i < nkeys && k < 6; i++)
        if (d->buttons >> keys[i].button & 1)
            le16(buf + 1 + 2 * k++, (int16_t)keys[i].code);
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
            le16(buf + 1 + 2 * i, reported(d, i));
        return 13;
    }
    buf[0] = (uint8_t)(1 + d->phase);
    for (int i = 0; i < 3; i++)
        le16(buf + 1 + 2 * i, reported(d, 3 * d->phase + i));
    d->phase ^= 1;
    return 7;
}

int simdev_output(simdev *d, const uint8_t *buf, size_t len)
{
    if (len == 2 && buf[0] == 4 && buf[1] <= 1) {
        if (!d->led_mode)
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

/* The open controller acts on its settings at once (the next period uses them). */
static void apply_open_feature(simdev *d, const uint8_t *b)
{
    if (b[0] == 0x21) {
        for (int i = 0; i < 6; i++)
            d->offset[i] = (int16_t)(b[1 + 2 * i] | b[2 + 2 * i] << 8);
    } else {
        d->period_us = b[1] * 1000;
        d->idle_zeros = b[2];
        d->led_mode = b[3];
        if (d->zeros_left > d->idle_zeros)
            d->zeros_left = d->idle_zeros;
    }
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
    if (d->p->open)
        apply_open_feature(d, buf);
    return (int)len;
}
