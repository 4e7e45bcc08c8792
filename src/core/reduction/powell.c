/* powell: Powell's direction-set method with Brent's line search (see powell.h). */
#include "powell.h"

#include "err.h"

#include <math.h>
#include <string.h>

#define GOLD 1.618033988749895
#define CGOLD 0.3819660112501051
#define GROW_LIMIT 50.0

void powell_defaults(powell_opts *o)
{
    memset(o, 0, sizeof *o);
    o->step = 1;
    o->xtol = 1e-3;
    o->ftol = 1e-7;
    o->line_tol = 1e-3;
    o->max_iter = 200;
    o->max_eval = 5000;
}

typedef struct line {
    powell_fn fn;
    void *ctx;
    const double *x0, *d;
    int n;
    int evals;
} line;

static double line_eval(line *L, double a)
{
    double x[POWELL_MAX_N];
    for (int i = 0; i < L->n; i++)
        x[i] = L->x0[i] + a * L->d[i];
    L->evals++;
    return L->fn(x, L->ctx);
}

/* Brackets a minimum: a < b < c (or reversed) with f(b) <= f(a), f(b) <= f(c). Golden growth with
 * parabolic extrapolation; gives up (returns 0) after max_eval evaluations on a function that
 * keeps falling or stays flat forever. */
static int bracket(line *L, double *a, double *b, double *c, double *fa, double *fb, double *fc,
                   int max_eval)
{
    if (*fb > *fa) {
        double t = *a; *a = *b; *b = t;
        t = *fa; *fa = *fb; *fb = t;
    }
    *c = *b + GOLD * (*b - *a);
    *fc = line_eval(L, *c);
    while (*fb > *fc) {
        if (L->evals >= max_eval)
            return 0;
        double r = (*b - *a) * (*fb - *fc), q = (*b - *c) * (*fb - *fa);
        double den = 2 * copysign(fmax(fabs(q - r), 1e-20), q - r);
        double u = *b - ((*b - *c) * q - (*b - *a) * r) / den, ulim = *b + GROW_LIMIT * (*c - *b), fu;
        if ((*b - u) * (u - *c) > 0) { /* parabola's minimum between b and c */
            fu = line_eval(L, u);
            if (fu < *fc) {
                *a = *b; *b = u; *fa = *fb; *fb = fu;
                return 1;
            }
            if (fu > *fb) {
                *c = u; *fc = fu;
                return 1;
            }
            u = *c + GOLD * (*c - *b);
            fu = line_eval(L, u);
        } else if ((*c - u) * (u - ulim) > 0) { /* beyond c, within the limit */
            fu = line_eval(L, u);
            if (fu < *fc) {
                *b = *c; *c = u; *fb = *fc; *fc = fu;
                u = *c + GOLD * (*c - *b);
                fu = line_eval(L, u);
            }
        } else if ((u - ulim) * (ulim - *c) >= 0) {
            u = ulim;
            fu = line_eval(L, u);
        } else {
            u = *c + GOLD * (*c - *b);
            fu = line_eval(L, u);
        }
        *a = *b; *b = *c; *c = u;
        *fa = *fb; *fb = *fc; *fc = fu;
    }
    return 1;
}

/* Brent's method on the bracket (a, b, c); returns the abscissa of the minimum, *fmin its value. */
static double brent(line *L, double a, double b, double c, double fb, double tol, int max_eval,
                    double *fout)
{
    double lo = fmin(a, c), hi = fmax(a, c);
    double x = b, w = b, v = b, fx = fb, fw = fb, fv = fb, d = 0, e = 0;
    while (L->evals < max_eval) {
        double m = 0.5 * (lo + hi), tol1 = tol + 1e-10 * fabs(x), tol2 = 2 * tol1;
        if (fabs(x - m) <= tol2 - 0.5 * (hi - lo))
            break;
        int golden = 1;
        if (fabs(e) > tol1) { /* try a parabola through x, w, v */
            double r = (x - w) * (fx - fv), q = (x - v) * (fx - fw), p = (x - v) * q - (x - w) * r;
            q = 2 * (q - r);
            if (q > 0)
                p = -p;
            q = fabs(q);
            double etemp = e;
            e = d;
            if (fabs(p) < fabs(0.5 * q * etemp) && p > q * (lo - x) && p < q * (hi - x)) {
                d = p / q;
                double u = x + d;
                if (u - lo < tol2 || hi - u < tol2)
                    d = copysign(tol1, m - x);
                golden = 0;
            }
        }
        if (golden) {
            e = x >= m ? lo - x : hi - x;
            d = CGOLD * e;
        }
        double u = fabs(d) >= tol1 ? x + d : x + copysign(tol1, d);
        double fu = line_eval(L, u);
        if (fu <= fx) {
            if (u >= x)
                lo = x;
            else
                hi = x;
            v = w; w = x; x = u;
            fv = fw; fw = fx; fx = fu;
        } else {
            if (u < x)
                lo = u;
            else
                hi = u;
            if (fu <= fw || w == x) {
                v = w; w = u;
                fv = fw; fw = fu;
            } else if (fu <= fv || v == x || v == w) {
                v = u;
                fv = fu;
            }
        }
    }
    *fout = fx;
    return x;
}

double powell_line(powell_fn fn, void *ctx, double *x, const double *d, int n, double f0, double step,
                   double tol, int max_eval, int *evals)
{
    line L = {fn, ctx, x, d, n, 0};
    double a = 0, b = step, c, fa = f0, fb = line_eval(&L, b), fc, fbest = f0, best = 0;
    if (fb < fbest) {
        fbest = fb;
        best = b;
    }
    if (bracket(&L, &a, &b, &c, &fa, &fb, &fc, max_eval)) {
        double fm, m = brent(&L, a, b, c, fb, tol, max_eval, &fm);
        if (fm < fbest) {
            fbest = fm;
            best = m;
        }
    } else if (fc < fbest) { /* ran out while still descending: keep the best seen */
        fbest = fc;
        best = c;
    }
    if (fb < fbest) {
        fbest = fb;
        best = b;
    }
    for (int i = 0; i < n; i++)
        x[i] += best * d[i];
    if (evals)
        *evals += L.evals;
    return fbest;
}

int powell_minimize(powell_fn fn, void *ctx, double *x, int n, const powell_opts *o, powell_stats *st)
{
    if (!fn || !x || !o || n < 1 || n > POWELL_MAX_N || !(o->step > 0) || o->max_iter < 1 ||
        o->max_eval < 1)
        return fn_err_set(FN_EINVAL, "powell: bad arguments (n %d, step %g)", n, o ? o->step : 0);
    double dir[POWELL_MAX_N][POWELL_MAX_N], x0[POWELL_MAX_N], xe[POWELL_MAX_N], dn[POWELL_MAX_N];
    memset(dir, 0, sizeof dir);
    for (int i = 0; i < n; i++)
        dir[i][i] = 1;
    int evals = 1, iter = 0, converged = 0;
    double f = fn(x, ctx);
    while (iter < o->max_iter && evals < o->max_eval) {
        iter++;
        memcpy(x0, x, (size_t)n * sizeof *x);
        double f0 = f, big = 0;
        int ibig = 0;
        for (int i = 0; i < n && evals < o->max_eval; i++) {
            double fprev = f;
            f = powell_line(fn, ctx, x, dir[i], n, f, o->step, o->line_tol, o->max_eval - evals, &evals);
            if (fprev - f > big) {
                big = fprev - f;
                ibig = i;
            }
        }
        double moved = 0;
        for (int i = 0; i < n; i++) {
            dn[i] = x[i] - x0[i];
            xe[i] = 2 * x[i] - x0[i];
            moved += dn[i] * dn[i];
        }
        int stop = o->on_iter && o->on_iter(iter, f, o->iter_ctx);
        if (sqrt(moved) < o->xtol || 2 * (f0 - f) <= o->ftol * (fabs(f0) + fabs(f) + 1e-12)) {
            converged = 1;
            break;
        }
        if (stop || evals >= o->max_eval)
            break;
        double fe = fn(xe, ctx);
        evals++;
        if (fe < f0) {
            double t = 2 * (f0 - 2 * f + fe) * (f0 - f - big) * (f0 - f - big) - big * (f0 - fe) * (f0 - fe);
            if (t < 0) { /* the net displacement becomes a direction, replacing the largest drop's */
                f = powell_line(fn, ctx, x, dn, n, f, 1, o->line_tol, o->max_eval - evals, &evals);
                memcpy(dir[ibig], dir[n - 1], sizeof dir[0]);
                memcpy(dir[n - 1], dn, sizeof dir[0]);
            }
        }
    }
    if (st) {
        st->iterations = iter;
        st->evaluations = evals;
        st->f = f;
        st->converged = converged;
    }
    return 0;
}
