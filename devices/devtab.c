#include "devtab.h"

#include <stdio.h>
#include <string.h>

#define ALL(n) ((uint32_t)(((uint64_t)1 << (n)) - 1))
/* A hardware row; HWA gives it a short name of its own (fracnav-sim --as has always taken these). */
#define HW(vid, pid, name, fmt, nb, mask, fl) {vid, pid, name, fmt, nb, mask, 0, 350, fl, NULL, NULL}
#define HWA(vid, pid, name, fmt, nb, mask, fl, alias) {vid, pid, name, fmt, nb, mask, 0, 350, fl, alias, NULL}

enum { LED = DEVTAB_F_LED, BAT = DEVTAB_F_BATTERY, RCV = DEVTAB_F_RECEIVER };

/* Facts as written in firmware-spec/3dconnexion.md; one row per product id. */
static const devtab_row rows[] = {
    HWA(0x046d, 0xc626, "3Dconnexion SpaceNavigator", DEVTAB_SPLIT, 2, ALL(2), LED, "spacenavigator"),
    HWA(0x046d, 0xc628, "3Dconnexion SpaceNavigator for Notebooks", DEVTAB_SPLIT, 2, ALL(2), LED,
        "spacenavigator-notebook"),
    HWA(0x046d, 0xc627, "3Dconnexion SpaceExplorer", DEVTAB_SPLIT, 15, ALL(15), LED, "spaceexplorer"),
    HW(0x046d, 0xc625, "3Dconnexion SpacePilot", DEVTAB_SPLIT, 21, ALL(21), LED),
    HWA(0x046d, 0xc629, "3Dconnexion SpacePilot Pro", DEVTAB_SPLIT, 31, ALL(31), LED, "spacepilot-pro"),
    HWA(0x046d, 0xc62b, "3Dconnexion SpaceMouse Pro", DEVTAB_SPLIT, 15, 0x07C0F137u, LED, "spacemouse-pro"),
    HW(0x046d, 0xc603, "3Dconnexion SpaceMouse Plus XT (USB)", DEVTAB_LEGACY, 10, ALL(10), 0),
    HW(0x046d, 0xc605, "3Dconnexion CadMan (USB)", DEVTAB_LEGACY, 4, ALL(4), 0),
    HW(0x046d, 0xc606, "3Dconnexion SpaceMouse Classic (USB)", DEVTAB_LEGACY, 8, ALL(8), 0),
    HW(0x046d, 0xc621, "3Dconnexion Spaceball 5000 (USB)", DEVTAB_LEGACY, 12, ALL(12), 0),
    HW(0x046d, 0xc623, "3Dconnexion SpaceTraveller", DEVTAB_LEGACY, 8, ALL(8), 0),
    HW(0x046d, 0xc640, "3Dconnexion NuLOOQ", DEVTAB_LEGACY, 4, ALL(4), 0),
    HWA(0x256f, 0xc62e, "3Dconnexion SpaceMouse Wireless (cable)", DEVTAB_COMBINED, 2, ALL(2), LED | BAT,
        "spacemouse-wireless"),
    HW(0x256f, 0xc62f, "3Dconnexion SpaceMouse Wireless (receiver)", DEVTAB_COMBINED, 2, ALL(2),
       LED | BAT | RCV),
    HWA(0x256f, 0xc631, "3Dconnexion SpaceMouse Pro Wireless (cable)", DEVTAB_COMBINED, 15, ALL(15),
        LED | BAT, "spacemouse-pro-wireless"),
    HW(0x256f, 0xc632, "3Dconnexion SpaceMouse Pro Wireless (receiver)", DEVTAB_COMBINED, 15, ALL(15),
       LED | BAT | RCV),
    HWA(0x256f, 0xc633, "3Dconnexion SpaceMouse Enterprise", DEVTAB_COMBINED, 31, ALL(31),
        LED | DEVTAB_F_KEYCODES, "spacemouse-enterprise"),
    HWA(0x256f, 0xc635, "3Dconnexion SpaceMouse Compact", DEVTAB_SPLIT, 2, ALL(2), LED, "spacemouse-compact"),
    HW(0x256f, 0xc638, "3Dconnexion SpaceMouse Pro Wireless (Bluetooth)", DEVTAB_COMBINED, 15, ALL(15),
       LED | BAT),
    HW(0x256f, 0xc63a, "3Dconnexion SpaceMouse Wireless (Bluetooth)", DEVTAB_COMBINED, 2, ALL(2),
       LED | BAT),
    HW(0x256f, 0xc652, "3Dconnexion Universal Receiver", DEVTAB_COMBINED, 15, ALL(15), LED | BAT | RCV),
    /* Its USB strings: manufacturer "fracnav", product its name (firmware-spec/open-controller.md). */
    {DEVTAB_OPEN_VID, DEVTAB_OPEN_PID, "fracnav open 6-DOF controller", DEVTAB_COMBINED, 8, ALL(8), 0, 350,
     LED | BAT | DEVTAB_F_OPEN, "open-controller", "fracnav"},
    /* Synthetic rows: transports that make reports of their own. */
    {0, 0, "spnav", DEVTAB_COMBINED, 32, 0xffffffffu, 0, 350, DEVTAB_F_SYNTH | LED, NULL, NULL},
    {0, 0, "keyboard", DEVTAB_COMBINED, 14, ALL(14), 0, 350, DEVTAB_F_SYNTH, NULL, NULL},
    /* An unlisted product whose descriptor declares 6-DOF motion reports (new ids keep working). */
    {0, 0, "generic", DEVTAB_COMBINED, 32, 0xffffffffu, 0, 350, DEVTAB_F_SYNTH | LED, NULL, NULL},
};

/* The SpaceMouse Enterprise's 31 keys as it reports them in 0x1C. Codes 1-31 keep 3Dconnexion's
 * numbering (button = code - 1, as in its report 3); the keys that exist only in 0x1C take the
 * numbers of the codes the Enterprise has no key for (4, 7, 8 other views, 10 roll back, 12 ISO2,
 * 28-31 pan/zoom, dominant, +, -; those codes, when some device sends them, stay key codes with the
 * calibration's built-in actions). */
static const devtab_key keys[] = {
    {1, 0, "MENU"},     {2, 1, "FIT"},     {3, 2, "T"},        {5, 4, "R"},        {6, 5, "F"},
    {9, 8, "ROLL"},     {11, 10, "ISO1"},  {13, 12, "1"},      {14, 13, "2"},      {15, 14, "3"},
    {16, 15, "4"},      {17, 16, "5"},     {18, 17, "6"},      {19, 18, "7"},      {20, 19, "8"},
    {21, 20, "9"},      {22, 21, "10"},    {23, 22, "ESC"},    {24, 23, "ALT"},    {25, 24, "SHIFT"},
    {26, 25, "CTRL"},   {27, 26, "ROTATE"}, {36, 3, "ENTER"},  {37, 6, "DELETE"},  {77, 7, "11"},
    {78, 9, "12"},      {103, 11, "V1"},   {104, 27, "V2"},    {105, 28, "V3"},    {175, 29, "TAB"},
    {176, 30, "SPACE"},
};

const devtab_key *devtab_keys(size_t *n)
{
    *n = sizeof keys / sizeof keys[0];
    return keys;
}

int devtab_key_button(uint16_t code)
{
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++)
        if (keys[i].code == code)
            return keys[i].button;
    return -1;
}

const char *devtab_key_name(uint16_t code)
{
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++)
        if (keys[i].code == code)
            return keys[i].name;
    return NULL;
}

const char *devtab_button_name(const devtab_row *row, int button, char *buf, size_t cap)
{
    for (size_t i = 0; row && (row->flags & DEVTAB_F_KEYCODES) && i < sizeof keys / sizeof keys[0]; i++)
        if (keys[i].button == button)
            return keys[i].name;
    snprintf(buf, cap, "B%d", button + 1);
    return buf;
}

int devtab_key1_button(const devtab_row *row)
{
    int b = row && (row->flags & DEVTAB_F_KEYCODES) ? devtab_key_button(13) : -1; /* code 13: "1" */
    return b > 0 ? b : 0;
}

const devtab_row *devtab_rows(size_t *n)
{
    *n = sizeof rows / sizeof rows[0];
    return rows;
}

const devtab_row *devtab_find(uint16_t vid, uint16_t pid)
{
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++)
        if (!(rows[i].flags & DEVTAB_F_SYNTH) && rows[i].vid == vid && rows[i].pid == pid)
            return &rows[i];
    return NULL;
}

const devtab_row *devtab_synthetic(const char *name)
{
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++)
        if ((rows[i].flags & DEVTAB_F_SYNTH) && !strcmp(rows[i].name, name))
            return &rows[i];
    return NULL;
}

const char *devtab_format_name(devtab_format f)
{
    switch (f) {
    case DEVTAB_SPLIT: return "split";
    case DEVTAB_COMBINED: return "combined";
    case DEVTAB_LEGACY: return "legacy";
    }
    return "unknown";
}
