/* bench: the starts of the fit benchmarks (bench reduce and its --labels workload), drawn as a
 * hand leaves a piece. */
#include "bench.h"

#include <math.h>

static double urand(uint64_t *rng)
{
    *rng = *rng * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*rng >> 11) / 9007199254740992.0;
}

static void unit_vector(uint64_t *rng, double v[3])
{
    double n;
    do {
        for (int a = 0; a < 3; a++)
            v[a] = 2 * urand(rng) - 1;
        n = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    } while (n > 1 || n < 1e-6);
    n = sqrt(n);
    for (int a = 0; a < 3; a++)
        v[a] /= n;
}

pose bench_reduce_start(const frag *f, const obb_tree *tf, const frag *m, const obb_tree *tm, const pose *truth,
                        const double mm[2], const double deg[2], uint64_t *rng)
{
    pose fw = pose_compose(f->pose, f->home), best = *truth;
    for (int tries = 0; tries < 100; tries++) {
        double axis[3], dir[3], c[3], rc[3];
        unit_vector(rng, axis);
        unit_vector(rng, dir);
        double turn = deg[0] + (deg[1] - deg[0]) * urand(rng), move = mm[0] + (mm[1] - mm[0]) * urand(rng);
        pose rot = pose_from_axis_angle(axis, turn * M_PI / 180), p = pose_compose(rot, *truth);
        pose_apply(truth, m->centroid, c);
        pose_rotate(&rot, c, rc);
        for (int a = 0; a < 3; a++)
            p.t[a] += c[a] - rc[a] + move * dir[a];
        pose mw = pose_compose(p, m->home);
        obb_query q = {.threshold = 0, .tolerance_mm = 0};
        obb_result r;
        best = p;
        if (obb_collide(tf, &fw, tm, &mw, &q, NULL, &r) == 0 && !r.collides)
            break;
    }
    return best;
}
