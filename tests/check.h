/* check.h — the smallest test harness that does the job.
 *
 * A test is a function; CHECK records a failure with file:line and a
 * message and goes on.  RUN_TEST prints one line per test:
 *   "ok   name"  or  "FAIL name: file:line: message"
 * tests/run.py reads those lines and prints the final "N passed, N failed".
 */
#ifndef TESTS_CHECK_H
#define TESTS_CHECK_H

#include <math.h>
#include <stdio.h>
#include <string.h>

static int check_failures_in_test;
static int check_tests_failed;
static int check_tests_run;
static char check_first_message[512];

#define CHECK(condition, ...)                                                                                          \
    do {                                                                                                               \
        if (!(condition)) {                                                                                            \
            if (check_failures_in_test++ == 0) {                                                                       \
                int n_ = snprintf(check_first_message, sizeof check_first_message, "%s:%d: ", __FILE__, __LINE__);     \
                snprintf(check_first_message + n_, sizeof check_first_message - (size_t)n_, __VA_ARGS__);              \
            }                                                                                                          \
        }                                                                                                              \
    } while (0)

/* |actual - expected| <= tolerance, with both numbers in the message. */
#define CHECK_NEAR(actual, expected, tolerance, what)                                                                  \
    do {                                                                                                               \
        double a_ = (actual), e_ = (expected), t_ = (tolerance);                                                       \
        CHECK(fabs(a_ - e_) <= t_, "%s: got %.10g, expected %.10g +- %.3g", what, a_, e_, t_);                         \
    } while (0)

#define RUN_TEST(function)                                                                                             \
    do {                                                                                                               \
        check_failures_in_test = 0;                                                                                    \
        function();                                                                                                    \
        check_tests_run++;                                                                                             \
        if (check_failures_in_test) {                                                                                  \
            check_tests_failed++;                                                                                      \
            printf("FAIL %s: %s\n", #function, check_first_message);                                                   \
        } else {                                                                                                       \
            printf("ok   %s\n", #function);                                                                            \
        }                                                                                                              \
        fflush(stdout);                                                                                                \
    } while (0)

#define CHECK_EXIT_STATUS() (check_tests_failed ? 1 : 0)

#endif
