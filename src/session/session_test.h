/* session: what the tests reach beneath the session's API, and nothing else does. Not for the
 * application: its clients go through session.h alone (tests/layers.sh). Functions: session__. */
#ifndef FN_SESSION_TEST_H
#define FN_SESSION_TEST_H

#include "session.h"

/* The session's loop (e.g. loop_measure while it does not run). Valid until session_close. */
loop *session__loop(session *s);

#endif
