/* dense_solve.c — Gaussian elimination with partial pivoting (see dense_solve.h). */
#include "dense_solve.h"

#include <math.h>

void dense_solve(double *a, double *b, size_t n)
{
    for (size_t col = 0; col < n; col++) {
        size_t pivot = col;
        for (size_t r = col + 1; r < n; r++)
            if (fabs(a[r * n + col]) > fabs(a[pivot * n + col]))
                pivot = r;
        if (pivot != col) {
            for (size_t k = 0; k < n; k++) {
                double t = a[col * n + k];
                a[col * n + k] = a[pivot * n + k], a[pivot * n + k] = t;
            }
            double t = b[col];
            b[col] = b[pivot], b[pivot] = t;
        }
        /* Radiosity's I - K is strictly diagonally dominant by columns (column
         * sums of rho F are below 1 in the power norm), so the pivot is never 0. */
#pragma omp parallel for schedule(static)
        for (size_t r = col + 1; r < n; r++) {
            double factor = a[r * n + col] / a[col * n + col];
            if (factor == 0.0)
                continue; /* a zero row below the pivot: nothing to eliminate (saves the work) */
            for (size_t k = col; k < n; k++)
                a[r * n + k] -= factor * a[col * n + k];
            b[r] -= factor * b[col];
        }
    }
    for (size_t i = n; i-- > 0;) {
        double sum = b[i];
        for (size_t k = i + 1; k < n; k++)
            sum -= a[i * n + k] * b[k];
        b[i] = sum / a[i * n + i];
    }
}
