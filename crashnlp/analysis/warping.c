/* The dynamic time warping of crashnlp.analysis.rating in C (crashnlp.analysis.warping): the same
   additions and comparisons in the same order as the numpy recurrence it stands in for, so the
   same path to the bit. Compiled without contraction into FMA (-ffp-contract=off). */
#include <math.h>
#include <stdlib.h>

/* np.minimum's: the smaller, or a nan if either is one */
static double least(double a, double b) { return (a < b || isnan(a)) ? a : b; }

/* Row i of the band in `cost` (n (2 band + 2) + 1 long): cells j = i - band - 1 .. i + band + 1,
   the first and last shared with the rows before and after and kept infinite (the cells left of
   and above the band), and so are those of j < 0: the recurrence reads them without a test. */
#define ROW(i) (cost + 1 + (i) * (2 * band + 1) + band)

/* Least cost from (0, 0) to each cell (i, j), |i - j| <= band, of x (rows) against y (columns),
   n samples each: squared differences, steps (1, 0), (0, 1), (1, 1) of weight 1. */
static void cumulative(const double *x, const double *y, long n, long band, double *cost)
{
    for (long i = 0; i < n; i++) {
        double *row = ROW(i);
        row[i + band + 1] = INFINITY;
        for (long j = i - band - 1; j < 0; j++)
            row[j] = INFINITY;
    }
    double *row = ROW(0);
    row[0] = (x[0] - y[0]) * (x[0] - y[0]);
    for (long j = 1; j <= band && j < n; j++)
        row[j] = row[j - 1] + (x[0] - y[j]) * (x[0] - y[j]);
    for (long i = 1; i < n; i++) {
        double *above = ROW(i - 1);
        row = ROW(i);
        long lo = i > band ? i - band : 0, hi = i + band < n - 1 ? i + band : n - 1;
        for (long j = lo; j <= hi; j++) {
            double d = x[i] - y[j];
            row[j] = least(least(above[j], row[j - 1]), above[j - 1]) + d * d;
        }
    }
}

/* Cell (i, j)'s least cost; infinite off the band, where a path whose costs are all infinite
   goes on ties (as on dtwalign's whole matrix) */
static double at(const double *cost, long band, long i, long j)
{
    return labs(i - j) <= band ? ROW(i)[j] : INFINITY;
}

/* The path back from (n - 1, n - 1) to (0, 0) through the cheapest of the cells above, left and
   diagonal, the first of them on ties (dtwalign's order), along the first row or column once on
   it. Writes the pairs from the end into path_i, path_j (2 n - 1 long at most); returns their count. */
long warping_path(const double *x, const double *y, long n, long band, double *cost, long *path_i, long *path_j)
{
    long i = n - 1, j = n - 1, count = 0;
    cumulative(x, y, n, band, cost);
    path_i[count] = i, path_j[count++] = j;
    while (i > 0 || j > 0) {
        if (i == 0 || j == 0) {
            i -= i > 0, j -= j > 0;
        } else {
            double up = at(cost, band, i - 1, j), left = at(cost, band, i, j - 1), diag = at(cost, band, i - 1, j - 1);
            if (up <= left && up <= diag)
                i -= 1;
            else if (left <= diag)
                j -= 1;
            else
                i -= 1, j -= 1;
        }
        path_i[count] = i, path_j[count++] = j;
    }
    return count;
}
