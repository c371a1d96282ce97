/* dense_solve.h — a dense linear system A x = b by Gaussian elimination with
 * partial pivoting (O(n^3)), for radiosity's direct solve of (I - K) L = E.
 * Numerical linear algebra, not the lecture. */
#ifndef COMMON_DENSE_SOLVE_H
#define COMMON_DENSE_SOLVE_H

#include <stddef.h>

/* Solve A x = b for the n x n row-major matrix a; on return b holds x and a
 * is overwritten.  A must be non-singular (radiosity's I - K is diagonally
 * dominant by columns). */
void dense_solve(double *a, double *b, size_t n);

#endif
