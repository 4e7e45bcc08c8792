/* reduce_impl: what the files of the reduction share (not part of the interface): the metric's
 * internals (reduce_metric.c), the tuning table (reduce.c), the collision context
 * (reduce_collide.c), the geometry and the pre-alignment (reduce_prealign.c); the automatic VOI is
 * in reduce_voi.c, the fit's stages in reduce_fit.c, the order of several fragments in
 * reduce_order.c. */
#ifndef FN_REDUCE_IMPL_H
#define FN_REDUCE_IMPL_H

#include "obb.h"
#include "reduce.h"

#include <stddef.h>
#include <stdint.h>

/* A run of bone voxels along i: crop voxels (i0 .. i0+len-1, j, k). */
typedef struct reduce_run {
    uint16_t i0, len, j, k;
} reduce_run;

/* An 8^3 block of the moving crop with its runs run[first .. first+n-1]; c its centre (crop
 * index), r_mm the radius of a sphere around it. */
typedef struct reduce_brick {
    float c[3];
    float r_mm;
    int first, n;
} reduce_brick;

/* The moving fragment's bone as bricks of runs: made once, shared by every VOI it is scored in. */
typedef struct reduce_bricks {
    reduce_brick *brick;
    int nbrick;
    reduce_run *run;
    size_t nrun;
    size_t voxels;
    double spacing[3];
    pose home;
} reduce_bricks;

/* A VOI cell's bits: it counts (inside the box, and within the band of the assembly's bone), and
 * the assembly has bone there (a cell with bone counts). One byte a cell keeps a VOI of a skull's
 * contact zone in the caches. */
enum { REDUCE_CELL_V = 1, REDUCE_CELL_A = 2 };

struct reduce_metric {
    reduce_count mode;
    reduce_bricks *b;
    int own_bricks;
    int c0[3];          /* the VOI's first cell in the grid fragment's crop indices */
    int d[3];           /* VOI cells per axis */
    int D[3];           /* d + 2: the raster has a ring of empty cells around the VOI */
    uint8_t *cell;      /* the padded VOI cells (REDUCE_CELL_*) */
    int8_t *score;      /* the same cells' part in the metric's numerator 2 n_I - n_2: +1 bone, -1 a
                         * counted cell without bone, 0 not counted (a trilinear evaluation
                         * interpolates this one field, not the two flags) */
    uint8_t *near;      /* a bit per cell (cell c: bit c % 8 of byte c / 8), set where the cell or
                         * one after it along each axis (the eight a trilinear weight from there
                         * reaches) has a score: most voxels an evaluation visits have none, and
                         * one load of a table an eighth the size tells */
    int nb[3];          /* blocks of REDUCE_BLOCK^3 padded cells per axis */
    uint32_t *bsum;     /* (nb+1)^3 summed-volume table of blocks holding a counted cell */
    double sg[3];       /* the grid's spacing */
    double n1, nvoi, w; /* w: a moving voxel's volume in grid voxels */
    pose grid_inv;      /* world -> grid crop mm */
    pose grid_world;    /* grid crop mm -> world */
    double fixed_centre[3]; /* world centroid of the assembly's bone in the VOI */
    /* The band (reduce__metric_rebase): per brick, the runs of its voxels that lay within band_k
     * cells of a counted cell at a reference pose. A brick that moved less than band_slack cells
     * from there can weigh no counted cell with its other voxels, so an evaluation near that pose
     * counts its band runs alone; one farther away counts all its runs. */
    uint8_t *reach;     /* d cells: 1 within band_k cells (per axis) of a counted cell */
    int band_k[3];
    double band_slack[3]; /* band_k - 1.5: the voxels a trilinear weight reaches, half a cell more */
    int band_ref;       /* 1 once the band is made (else every brick counts all its runs) */
    double band_M[3][3]; /* the reference pose's carry */
    double (*band_x)[3]; /* per brick: its centre's VOI cell coordinates there */
    size_t *band_first; /* per brick: its band runs band[band_first[bi] .. band_first[bi + 1] - 1] */
    reduce_run *band;
    size_t nband, capband;
    int shared;         /* 1: a copy of another's band (reduce__metric_share): its cells are that one's */
};

#define REDUCE_BLOCK 4

/* out = in dilated by k[a] cells along each axis a (a box), by ORs of whole shifted lines;
 * in, out and tmp (scratch) span d[0]*d[1]*d[2] cells. */
void reduce__dilate_box(const uint8_t *in, uint8_t *out, uint8_t *tmp, const int d[3], const int k[3]);
/* A summed-volume table t of (nb[0] + 1) x (nb[1] + 1) x (nb[2] + 1) counts, the first plane of each
 * axis 0 and block (i, j, k) at t[i + 1, j + 1, k + 1]: sums in place, and the sum over blocks
 * [lo, hi] (inclusive) of the summed table. */
void reduce__sat_sum(uint32_t *t, const int nb[3]);
uint32_t reduce__sat_count(const uint32_t *t, const int nb[3], const int lo[3], const int hi[3]);
reduce_bricks *reduce__bricks_new(const frag *m);
void reduce__bricks_free(reduce_bricks *b);
/* The metric's band made again at pose ref (the moving fragment's world pose), where the next
 * evaluations will be: they cost the band's voxels near it, and stay exact anywhere. 0 or FN_ENOMEM
 * (the metric then counts every run, exact and slower). Not thread-safe with evaluations of m. */
int reduce__metric_rebase(reduce_metric *m, const pose *ref);
/* A metric that shares m's cells (read-only) and has a band of its own, not made yet (every run
 * counts until reduce__metric_rebase): threads may each rebase their own copy and evaluate it
 * while m lives. Freed by reduce_metric_free (the cells stay m's). NULL with fn_err. */
reduce_metric *reduce__metric_share(const reduce_metric *m);
/* The metric counted by mode from now on (its VOI and band stay: the trilinear band holds every
 * voxel a nearest count reaches); the mode it counted by before. Not thread-safe with evaluations
 * of m. */
reduce_count reduce__metric_count(reduce_metric *m, reduce_count mode);
/* 1 when some brick of the band moved halfway to where it would count all its runs, from the band's
 * reference pose to p: time to rebase there. */
int reduce__metric_drifted(const reduce_metric *m, const pose *p);
/* A metric over shared bricks (not freed with it). cut_mm > 0: of the band's box, only the cells
 * within cut_mm (Euclidean) count (reduce__band_cut; 0: the whole box, as on the coarse level).
 * gap_mm > 0: the VOI cells within gap_mm (Euclidean) of the assembly's bone count as its bone
 * (reduce_opts.gap_mm); 0: none. */
reduce_metric *reduce__metric_with(const frag *const *asm_, int nasm, const frag *moving, reduce_bricks *b,
                                   const reduce_voi *voi, reduce_count mode, double band_mm, double cut_mm,
                                   double gap_mm);
/* The band's Euclidean cut on the fine grid: band_corner * band_mm. */
double reduce__band_cut(double band_mm);
/* A coarse copy of f (the first stage's level): 2 voxels a cell along each axis whose spacing is
 * within 1.5 times the finest, bone where at least half of a cell's voxels are; same id, pose,
 * centroid and axes, home moved to the cell centres. 0 or FN_ENOMEM (*c then holds nothing to free). */
int reduce__coarse_frag(const frag *f, frag *c);

/* ---- the tuning table ------------------------------------------------------------------------ */

/* The first stage's ends looked at for rival basins (the size of an array; part of the table). */
#define REDUCE_STARTS_SEEN REDUCE_CANDIDATES_MAX
/* The global stage's candidates refined, at most (the size of an array; part of the table). */
#define REDUCE_GLOBAL_KEEP_MAX 3
/* The polish's steps (the size of an array; part of the table). */
#define REDUCE_POLISH_STEPS 4

/* Every number the reduction's stages are tuned by, in one place (reduce.c holds the values, with
 * the measurement that chose each where one did). What a user may set is in reduce_opts instead. */
typedef struct reduce_tuning {
    /* the contact zone (reduce_auto_voi) */
    double zone_cell_mm;     /* its coarse occupancy grid's cell */
    double zone_reach_mm;    /* delta doubles up to this; nothing nearer: the piece is apart */
    double zone_delta_mm[2]; /* the fit's contact distance: first stage, later stages */
    double zone_margin_mm;   /* the fit's zone grown by this */
    double zone_grow;        /* a zone at the end this much larger (volume) than the VOI fitted: again */
    double band_reach_mm;    /* the metric's band holds the moving voxels this near its counted cells */
    double band_corner;      /* the counted cells: those within band_mm on each axis (whole cells) and
                              * within band_corner * band_mm (Euclidean): on 1 mm slices, not the
                              * box's corners (the coarse level keeps the box) */
    int zone_grow_stages;    /* at most this many stages more for it */
    /* collision */
    double tolerance_voxels; /* the query's tolerance: at most this times the smallest spacing
                              * (the query takes tolerances below half a voxel) */
    double collide_cost;     /* a colliding pose's cost: more than any metric difference */
    double push_step_mm, push_max_mm; /* a colliding result pushed out by this step, this far */
    /* pre-alignment and the approach */
    double placed_mm;        /* nearer than this to the assembly, a piece counts as placed by hand */
    double prealign_turn_deg; /* the candidates' turn about the fixed long axis (a divisor of 180) */
    double prealign_span_mm; /* the slide starts this much beyond the two pieces' lengths */
    double prealign_box_mm;  /* a candidate's box: the two boxes' overlap grown by this */
    double approach_mm;      /* the farthest a piece slides into contact before the fit */
    double slide_step_mm;    /* the slide's smallest step (it advances by the separation bound) */
    int slide_halvings;      /* bisections of the last step to contact */
    /* the optimizer */
    double scale_min_mm, scale_max_mm; /* the rotation parameters' scale (mm per radian) clamped */
    double bound;            /* the parameters' bounds (not PRAXIS, which takes none) */
    double nlopt_step;       /* NLopt's initial step */
    double powell_step[3];   /* our Powell's restarts: one step each */
    double gain;             /* a restart or a hop that gains less ends its sequence */
    double first_xtol;       /* the first of two stages stops at this times reduce_opts.xtol_mm */
    /* the global stage */
    double global_deg;       /* its candidates: the placed pose turned this much about each axis */
    double global_mm;        /* and moved this much along each */
    int global_coarse;       /* 1: their fits on the coarse level (reduce__coarse_frag) */
    int global_evals;        /* evaluations per candidate's fit */
    double global_xtol_mm;   /* and its convergence step */
    int global_keep;         /* at most this many candidates refined (<= REDUCE_GLOBAL_KEEP_MAX)... */
    double global_margin;    /* ...the best, and others distinct from it that score this close */
    /* starts and attempts */
    double start_deg;        /* the first stage's extra starts: turned this much about each axis */
    double wide_starts;      /* the third attempt turns its starts this many times wider */
    double wall_mm, wall_deg; /* a fit ending this near the trust wall is at it */
    /* rival basins and hops */
    double rival_metric;     /* a first-stage end this close in metric to the best is a rival... */
    double rival_mm, rival_deg; /* ...when it lies farther than this from the best */
    double hop_elongation;   /* a long piece: largest principal variance this many times the next */
    double hop_deg;          /* a hop's turn */
    double hop_mm;           /* and a hop's move */
    int hop_evals;           /* a strict hop's fit stops after this many evaluations */
    double hop_margin;       /* a hop of a piece that is not long must gain this much metric */
    double long_margin;      /* and one of a long piece this much */
    /* the polish (stage_polish) */
    double polish_step[REDUCE_POLISH_STEPS]; /* its compass steps, largest first */
    int polish_sweeps;       /* sweeps at most per step */
    double polish_round;     /* a long piece whose second principal variance is under this times
                              * the third is a tube, not polished */
    /* the order of several fragments */
    double touch_mm;         /* a piece with no bone this near another's in the CT, nor moved by the
                              * hand to this near another, touches nothing;
                              * in the second sweep, pieces this far apart fit at once */
} reduce_tuning;

extern const reduce_tuning reduce__tune;

/* ---- the contact zone (reduce_voi.c) ----------------------------------------------------------- */

/* Bone voxels as world points (float xyz), at their fragments' poses. */
typedef struct reduce_cloud_grid reduce_cloud_grid;
typedef struct reduce_cloud {
    float *p;
    size_t n;
    double lo[3], hi[3];     /* the points' box (reduce__cloud_new) */
    reduce_cloud_grid *grid; /* the contact grid of these points (reduce__cloud_grid; freed with
                              * the cloud) */
} reduce_cloud;

/* The assembly's bone voxels at its poses: made once per fit, for every contact zone of it. 0 or
 * FN_ENOMEM (free it either way). */
int reduce__cloud_new(reduce_cloud *c, const frag *const *asm_, int nasm);
void reduce__cloud_free(reduce_cloud *c);
/* The cloud's contact grid, made once (reduce_voi.c); after it, zones only read the cloud, and
 * threads may share it. 0 or FN_E*. */
int reduce__cloud_grid(reduce_cloud *c);
/* reduce_auto_voi over an assembly's points A (made by reduce__cloud_new at the same poses); b:
 * the moving fragment's bricks (reduce__bricks_new), or NULL (made for the call). */
int reduce__zone_voi(reduce_cloud *A, const frag *moving, const reduce_bricks *b, double delta_mm, double margin_mm,
                     double max_mm, reduce_voi *voi, double *contact_ml);
/* 1 when some bone voxel of moving lies within about mm of the others' bone at their poses (on the
 * contact zone's grid: boxes of whole zone_cell_mm cells, so a cell or two farther may count as
 * near), 0 when none does, or FN_E*. */
int reduce__touches(const frag *const *others, int n, const frag *moving, double mm);

/* ---- collision (reduce_collide.c) -------------------------------------------------------------- */

/* The moving fragment against the assembly: their hierarchies and the query. */
typedef struct reduce_collider {
    const frag *const *asm_;
    int nasm;
    frag *moving;
    obb_tree **trees; /* nasm + 1: the last is the moving fragment's */
    obb_query q;
    obb_cache *cache; /* nasm, for the queries of the optimizer (temporal coherence) */
} reduce_collider;

/* Builds the hierarchies (o's thresholds) and the query (o's tolerance, capped by the table). 0 or
 * FN_ENOMEM; close it either way. */
int reduce__collider_open(reduce_collider *c, const frag *const *asm_, int nasm, frag *moving,
                          const reduce_opts *o);
void reduce__collider_close(reduce_collider *c);
/* 1 collides, 0 free, <0 error; *sep (may be NULL): the smallest separation estimate. */
int reduce__collides(const reduce_collider *c, const pose *mp, double *sep);
/* r->end colliding is pushed out along the contact normal (from m's assembly bone to the moving
 * centroid) or a world axis; failing that, r->start stays (r->collides: whether it collides). A
 * free end is then settled: pushed out up to settle_mm more until free at tolerance 0, and left
 * where it is when that is not enough. r->push_mm grows by the pushes. 0 or <0. */
int reduce__resolve_collision(const reduce_collider *c, const reduce_metric *m, double settle_mm,
                              reduce_result *r);

/* ---- geometry and pre-alignment (reduce_prealign.c) -------------------------------------------- */

/* Principal axis col of f at its pose (world), and its centroid (world). */
void reduce__axis_world(const frag *f, int col, double v[3]);
void reduce__centroid_world(const frag *f, double c[3]);
/* x -> rot (P(x) - c) + to: the pose P turned about point c and moved to `to`. */
pose reduce__turned(const pose *P, const pose *rot, const double c[3], const double to[3]);
/* Slides *p from where it is along unit dir until the moving fragment touches (at most 2 span
 * mm), by conservative advancement and bisection. 1 when it touches (*p moved there), 0 when it
 * never does or collides from the start (*p unchanged), <0 on error. */
int reduce__slide_to_contact(const reduce_collider *c, pose *p, const double dir[3], double span);
/* The paper's pre-alignment (see reduce.h): sets c->moving->pose to the best candidate (the placed
 * pose included); *changed: 1 when that is not the placed pose. 0 or <0. */
int reduce__prealign(const reduce_collider *c, reduce_bricks *b, const reduce_opts *o, int *changed);

#endif
