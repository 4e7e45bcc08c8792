/* session: machine output -- the summary of `replay --json` and `navigate --json`, and the
 * loop statistics' members every command shares (bench loop too). */
#include "session_impl.h"

#include "err.h"
#include "jsonw.h"

#include <inttypes.h>
#include <jansson.h>

static json_t *count(uint64_t n)
{
    return json_integer((json_int_t)n);
}

/* The loop's statistics under the keys every command uses for them (bench loop too). */
static void put_stats(json_t *j, const loop_stats *s)
{
    static const char *const counts[] = {"events", "steps", "accepted", "limited", "slid", "refused",
                                         "collisions_in_accepted", "unchecked", "escaping", "queries",
                                         "queries_from_scratch", "dropped", "journal_errors"};
    const uint64_t values[] = {s->events, s->steps, s->accepted, s->limited, s->slid, s->refused,
                               s->collisions_in_accepted, s->unchecked, s->escaping, s->queries,
                               s->searches, s->dropped, s->journal_errors};
    for (size_t i = 0; i < sizeof counts / sizeof counts[0]; i++)
        json_object_set_new(j, counts[i], count(values[i]));
    int timed = s->latency_samples > 0, queried = s->queries > 0;
    json_object_set_new(j, "loop_hz", jsonw_measure(s->step_hz));
    json_object_set_new(j, "tick_hz", jsonw_measure(s->tick_hz > 0 ? s->tick_hz : JSONW_NA));
    json_object_set_new(j, "latency_p50_us", jsonw_measure(timed ? s->latency_p50_us : JSONW_NA));
    json_object_set_new(j, "latency_p99_us", jsonw_measure(timed ? s->latency_p99_us : JSONW_NA));
    json_object_set_new(j, "latency_max_us", jsonw_measure(timed ? s->latency_max_us : JSONW_NA));
    json_object_set_new(j, "query_mean_us", jsonw_measure(queried ? s->query_us_mean : JSONW_NA));
    json_object_set_new(j, "query_max_us", jsonw_measure(queried ? s->query_us_max : JSONW_NA));
}

json_t *session_stats_json(const char *command, const loop_stats *st)
{
    json_t *j = jsonw_object(command);
    if (j)
        put_stats(j, st);
    return j;
}

int session_print_json(session *s, FILE *out, const char *command, long unplugs, uint64_t skipped)
{
    if (!s->c)
        return fn_err_set(FN_EINVAL, "this session has no case to summarize (fragments only)");
    loop_stats st;
    loop_get_stats(s->L, &st);
    char digest[17];
    snprintf(digest, sizeof digest, "%016" PRIx64, st.pose_digest);
    json_t *poses = json_array();
    for (int i = 0; i < s->nfrag; i++) {
        pose p = loop_pose(s->L, i);
        json_t *o = json_object();
        json_object_set_new(o, "id", json_integer(s->frags[i].id));
        json_object_set_new(o, "name", jsonw_string(s->frags[i].name));
        json_object_set_new(o, "fixed", json_boolean(loop_fixed(s->L, i)));
        json_object_set_new(o, "q", jsonw_exact_array(p.q, 4));
        json_object_set_new(o, "t", jsonw_exact_array(p.t, 3));
        json_array_append_new(poses, o);
    }
    json_t *j = session_stats_json(command, &st);
    if (j) {
        json_object_set_new(j, "skipped_reports", count(skipped));
        json_object_set_new(j, "unplugs", unplugs >= 0 ? json_integer(unplugs) : json_null());
        json_object_set_new(j, "resumed_from_journal", count(s->resumed));
        json_object_set_new(j, "journal_records", count(s->jr ? journal_count(s->jr) : 0));
        json_object_set_new(j, "final_poses", poses);
        json_object_set_new(j, "pose_digest", json_string(digest));
        json_object_set(j, "penetrating", s->penetrating ? s->penetrating : json_null());
    } else
        json_decref(poses);
    return jsonw_print(j, out);
}
