/* powell: Powell's direction-set method with Brent's line search, for small unconstrained problems
 * (the 6 pose parameters of a fragment). Derivative-free: only function values are used.
 *
 * Each iteration minimises along every direction of the set in turn (Brent's method inside a
 * golden-section bracket), then tries the extrapolated point and, when worthwhile, replaces the
 * direction of largest decrease by the iteration's net displacement (Powell 1964, in the form of
 * Brent 1973 / Press et al.'s "powell" rule). Directions start as the coordinate axes scaled by
 * `step`.
 *
 * Not thread-safe per call only through fn: it allocates nothing beyond a few small arrays of n
 * doubles on the stack (n <= POWELL_MAX_N). */
#ifndef FN_POWELL_H
#define FN_POWELL_H

#define POWELL_MAX_N 16

/* The objective; must be finite where it is evaluated (return a large value to refuse a point). */
typedef double (*powell_fn)(const double *x, void *ctx);
/* Called after every iteration with the iteration number (1..) and the best value; return non-zero
 * to stop early (a user's interrupt). May be NULL. */
typedef int (*powell_iter_fn)(int iter, double f, void *ctx);

typedef struct powell_opts {
    double step;     /* initial line-search step along each axis (> 0) */
    double xtol;     /* stop when an iteration moves x by less than this (Euclidean) */
    double ftol;     /* or when it lowers f by less than ftol * (|f| + 1e-12) relative */
    double line_tol; /* Brent's absolute tolerance along a line, in units of x */
    int max_iter;    /* iterations (>= 1) */
    int max_eval;    /* function evaluations (>= 1); the search stops once it is exceeded */
    powell_iter_fn on_iter;
    void *iter_ctx;
} powell_opts;

/* step 1, xtol 1e-3, ftol 1e-7, line_tol 1e-3, 200 iterations, 5000 evaluations. */
void powell_defaults(powell_opts *o);

typedef struct powell_stats {
    int iterations;
    int evaluations;
    double f;        /* the value at the returned x */
    int converged;   /* 1: a tolerance was met; 0: a limit or on_iter stopped it */
} powell_stats;

/* Minimises fn from x (n values, 1 <= n <= POWELL_MAX_N); x receives the best point found. Returns
 * 0, or FN_EINVAL for bad arguments (with a message). st may be NULL. */
int powell_minimize(powell_fn fn, void *ctx, double *x, int n, const powell_opts *o, powell_stats *st);

/* One-dimensional minimisation along direction d from x: x += a*d for the best a found by Brent's
 * method after bracketing from a = 0 and a = step. Returns the value at the new x. Exposed for
 * tests. evals counts the evaluations made. */
double powell_line(powell_fn fn, void *ctx, double *x, const double *d, int n, double f0, double step,
                   double tol, int max_eval, int *evals);

#endif
