/* reduce_impl: what reduce_metric.c and reduce.c share (not part of the interface). */
#ifndef FN_REDUCE_IMPL_H
#define FN_REDUCE_IMPL_H

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

/* A VOI cell: v 1 where it counts (inside the box, and within the band of the assembly's bone),
 * a 1 where the assembly has bone. */
typedef struct reduce_cell {
    float v, a;
} reduce_cell;

struct reduce_metric {
    reduce_count mode;
    reduce_bricks *b;
    int own_bricks;
    int c0[3];          /* the VOI's first cell in the grid fragment's crop indices */
    int d[3];           /* VOI cells per axis */
    int D[3];           /* d + 2: the raster has a ring of empty cells around the VOI */
    reduce_cell *cell;  /* the padded VOI cells */
    int nb[3];          /* blocks of REDUCE_BLOCK^3 padded cells per axis */
    uint32_t *bsum;     /* (nb+1)^3 summed-volume table of blocks holding a counted cell */
    double sg[3];       /* the grid's spacing */
    double n1, nvoi, w; /* w: a moving voxel's volume in grid voxels */
    pose grid_inv;      /* world -> grid crop mm */
    pose grid_world;    /* grid crop mm -> world */
    double fixed_centre[3]; /* world centroid of the assembly's bone in the VOI */
};

#define REDUCE_BLOCK 4

reduce_bricks *reduce__bricks_new(const frag *m);
void reduce__bricks_free(reduce_bricks *b);
/* A metric over shared bricks (not freed with it). gap_mm > 0: the VOI cells within gap_mm
 * (Euclidean) of the assembly's bone count as its bone (reduce_opts.gap_mm); 0: none. */
reduce_metric *reduce__metric_with(const frag *const *asm_, int nasm, const frag *moving, reduce_bricks *b,
                                   const reduce_voi *voi, reduce_count mode, double band_mm, double gap_mm);
/* A coarse copy of f (the first stage's level): 2 voxels a cell along each axis whose spacing is
 * within 1.5 times the finest, bone where at least half of a cell's voxels are; same id, pose,
 * centroid and axes, home moved to the cell centres. 0 or FN_ENOMEM (*c then holds nothing to free). */
int reduce__coarse_frag(const frag *f, frag *c);

#endif
