/* Until devices/ has sources of its own. */
typedef int fracnav_devices_placeholder;
