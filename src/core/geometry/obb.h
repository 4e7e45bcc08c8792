/* obb: the OBB octree of a fragment and the exact collision query between two fragments.
 *
 * Geometry. Voxel (i,j,k) of a fragment is the box centred at (i*sx, j*sy, k*sz) in the fragment's
 * local mm frame with half-extents spacing/2. Every box of a fragment shares its rotation, so a node
 * is an axis-aligned box of voxel indices in local units; the world placement comes per query.
 *
 * Probabilities. A voxel's byte p (probability*255, 0 = not bone) becomes an effective byte
 * (obb_effective_prob): 0 when p = 0 or p/255 < tau_min (dropped), 255 when p/255 > tau_max or
 * p = 255 (certain bone, "solid"), else p unchanged. Tree and brute force use the same map.
 *
 * Collision (the definition both obb_collide and obb_collide_brute implement): A and B collide when
 * some voxel box of A and some voxel box of B, each shrunk by tolerance_mm on every side, still
 * overlap with a non-empty interior (touching faces do not count) and pa*pb/255^2 >= threshold with
 * pa, pb the effective bytes. Inner boxes only reject (conservatively, with a 1e-6 mm slack);
 * voxel pairs get the exact 15-axis test, the same code brute force runs, so the two agree bit for
 * bit (obb_box_overlap exposes that test).
 *
 * Threads: a built tree is read-only; any number of threads may query shared trees at once, each with
 * its own obb_cache (or none). Queries allocate nothing; they use about 100 KB of stack.
 * Errors: see err.h. */
#ifndef FN_OBB_H
#define FN_OBB_H

#include "frag.h"
#include "pose.h"

#include <stddef.h>
#include <stdint.h>

typedef struct obb_tree obb_tree;

/* Probability thresholds in [0,1], tau_min <= tau_max. {0, 1} keeps every voxel, as-is. */
typedef struct obb_params {
    double tau_min; /* voxels and nodes with rho_max < tau_min are dropped */
    double tau_max; /* nodes with rho_min > tau_max become solid leaves (probability 1) */
} obb_params;

/* One node: 16 bytes. Box = voxel index range [lo, hi] (inclusive), tight around its voxels.
 * info bit 31 set: leaf, bits 0-7 its effective probability; a leaf with 255 and lo != hi is a solid
 * block whose every voxel is bone (queries subdivide it on the fly). bit 31 clear: inner node,
 * bits 0-23 first child (children are contiguous), bits 24-27 ceil(rho_max*15) (an upper bound),
 * bits 28-30 child count - 1. Node 0 is the root. */
typedef struct obb_node {
    uint16_t lo[3], hi[3];
    uint32_t info;
} obb_node;

/* Builds the hierarchy of f (dims up to 65535 per axis, at most 2^24 nodes) in time linear in the
 * voxel count, using about 2.3 bytes per voxel of temporary memory. NULL + fn_err on bad params
 * (FN_EINVAL), a bad fragment (FN_EFORMAT) or memory (FN_ENOMEM). f may be freed afterwards.
 * p NULL = {0, 1}. A fragment with no voxel left gives a valid empty tree (0 nodes). */
obb_tree *obb_tree_build(const frag *f, const obb_params *p);
void obb_tree_free(obb_tree *t);
size_t obb_tree_nodes(const obb_tree *t);
/* Read-only view of the nodes (for display: boxes at a depth) and the spacing in mm. */
const obb_node *obb_tree_node_array(const obb_tree *t);
const double *obb_tree_spacing(const obb_tree *t);
/* Depth of the tree (root = 1, empty = 0) and bytes held in total. */
int obb_tree_depth(const obb_tree *t);
size_t obb_tree_bytes(const obb_tree *t);

/* The effective probability byte of raw byte p under params (see above). */
uint8_t obb_effective_prob(uint8_t p, const obb_params *params);

enum { OBB_DEPTH_FIRST = 0, OBB_BREADTH_FIRST = 1 };

typedef struct obb_pair {
    uint16_t a[3], b[3]; /* voxel indices of a colliding voxel pair */
} obb_pair;

typedef struct obb_query {
    double threshold;    /* probability product needed to collide, [0,1]; 0 counts every voxel */
    double tolerance_mm; /* boxes overlap by more than this to collide; >= 0 */
    int want_pairs;      /* 1: collect colliding voxel pairs into pairs[] (up to max_pairs) */
    obb_pair *pairs;     /* caller-owned buffer for want_pairs */
    size_t max_pairs;
    int order;           /* OBB_DEPTH_FIRST (default) or OBB_BREADTH_FIRST */
    int inner_axes;      /* axes tried on inner boxes: 0 or 6 = face axes only (default, fastest:
                          * edge axes rarely reject there), 15 = Gottschalk's full test. Voxel
                          * pairs always get all 15; the answer is the same either way. */
} obb_query;

typedef struct obb_result {
    int collides;
    /* > 0: a lower bound on the distance between the (tolerance-shrunk) fragments: a rigid motion
     * that moves no point of A by as much as this, relative to B, cannot make them collide.
     * < 0: minus the penetration depth of the deepest colliding voxel pair found (an estimate).
     * 0 only when the fragments touch exactly. INFINITY when nothing can ever collide. */
    double separation_mm;
    size_t npairs;       /* colliding voxel pairs written to q->pairs (want_pairs) */
    size_t pairs_total;  /* colliding voxel pairs found (may exceed max_pairs) */
    size_t tests;        /* box tests done (for benchmarks) */
} obb_result;

/* Temporal coherence for one ordered pair of trees. Caller-owned plain data (about 160 KB): zero it
 * (or obb_cache_reset) before first use; it notices a different tree or query setting by itself,
 * but not a tree rebuilt at the same address: reset it then. Never share one between threads.
 * - witnesses: the last OBB_WITNESSES colliding voxel pairs, tried first (a colliding pose stays
 *   colliding while the user pushes into contact, and a fragment pushed into a contact of many
 *   points, as a fit's, meets one of a few pairs: answered in a few tests).
 * - front: every node pair the last full search rejected, with its gap, for the relative pose it
 *   was made at. A later query moves B by at most delta relative to A (from the two poses and B's
 *   root box); a pair whose gap exceeds delta is still apart and is skipped, the rest are searched
 *   again, so the answer stays exact. A free answer moves the front to the pose queried: the pairs
 *   searched again are replaced by what their search rejected, the others keep their gaps less
 *   delta (one number for all, `lowered`), so the next query's delta counts from there. When too
 *   many pairs need a look, or the front has grown by half since its search (moved fronts keep
 *   the fine pairs of contacts left behind), the search runs from the root and makes a new front
 *   (also when the front would exceed OBB_FRONT_MAX pairs: no front).
 * The yes or no is the same with a cache as without; the separation is a valid bound either way,
 * but with a cache it depends on the queries before (which pairs the front kept): a caller that
 * steps by it and must not depend on its history queries without a cache (reduce does), or lets
 * it decide only how an answer is found, never which (the loop: a move the bound proves free costs
 * a try of the step's budget as a query would). */
#define OBB_FRONT_MAX 16384 /* a fitted piece of the skull, interlocked at the fit's tolerance: 9,232 */
#define OBB_WITNESSES 8

typedef struct obb_front_pair {
    obb_node a, b;
    double gap; /* mm, a lower bound on the distance between the two boxes at the reference pose */
} obb_front_pair;

typedef struct obb_cache {
    int nwit, wnext;           /* witnesses held, the next one replaced */
    obb_node wa[OBB_WITNESSES], wb[OBB_WITNESSES]; /* recent colliding voxel pairs */
    int front_valid;
    size_t front_n;
    const obb_tree *ta, *tb;   /* what the front was made for */
    double threshold, tolerance_mm;
    int inner_axes;
    double ref_R[3][3], ref_t[3]; /* B's frame in A's frame when the front was made or moved */
    double lowered;            /* mm: a front pair's gap there is its gap field less this */
    size_t front_made;         /* front_n when the search made it */
    size_t reuses, rebuilds;   /* queries answered from the front / that made a new one */
    obb_front_pair front[OBB_FRONT_MAX];
} obb_cache;

void obb_cache_reset(obb_cache *c);

/* a_world, b_world: local mm -> current world of each tree's fragment (pose ∘ home).
 * q NULL = threshold 0, tolerance 0, no pairs. cache may be NULL. Returns 0, or FN_EINVAL for
 * bad arguments (NULL tree/pose/result, NaN values, want_pairs without a buffer).
 * Thread-safe on shared read-only trees; allocates nothing. */
int obb_collide(const obb_tree *a, const pose *a_world, const obb_tree *b, const pose *b_world,
                const obb_query *q, obb_cache *cache, obb_result *r);

/* Reference: every voxel pair that can matter, exactly by the definition above. A voxel of B is
 * skipped only when its A-frame bounding box misses A's crop, and it is tested against every A voxel
 * inside that bounding box (plus a margin): obviously safe. params must match those of the trees
 * compared (NULL = {0, 1}). separation_mm: minus the smallest overlap depth of the first colliding
 * pair found (the deepest of all with want_pairs); NAN when apart (not computed). Slow: for tests
 * and benchmarks. */
int obb_collide_brute(const frag *a, const pose *a_world, const frag *b, const pose *b_world,
                      const obb_params *params, const obb_query *q, obb_result *r);

/* The voxel-level SAT test shared by tree and brute force: boxes A (centre ca, half-extents ha, in
 * A's frame) and B (centre cb, half-extents hb, in B's frame); B's frame maps into A's by
 * x_A = R x_B + t. Returns 1 when the open boxes overlap. When they do not and gap is non-NULL,
 * *gap = a lower bound on the distance between them (>= 0); when they do, *gap = minus the
 * smallest overlap depth over the 15 axes. */
int obb_box_overlap(const double R[3][3], const double t[3], const double ca[3], const double ha[3],
                    const double cb[3], const double hb[3], double *gap);

#endif
