/* Until sim/ has sources of its own. */
typedef int fracnav_sim_placeholder;
