/* check.h — the smallest test harness that does the job.
 *
 * A test is a function; CHECK records a failure with file:line and a
 * message and goes on.  RUN_TEST prints one line per test:
 *   "ok   name"  or  "FAIL name: file:line: message"
 * tests/run.py reads those lines and prints the final "N passed, N failed".
 *
 * CHECK_EXIT_STATUS also prints one "site" line per CHECK in the source:
 *   "site file:line checks held sum_of_values sum_of_tolerances"
 * (values and tolerances from CHECK_NEAR).  The grader (kit/grade.py) runs
 * the same test built from the solution and compares these lines: "ok"
 * lines could be printed by anything in the process (a constructor in a
 * submitted header), the values behind them only by code that computes them.
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

enum { CHECK_MAX_SITES = 512 };
static struct check_site {
    const char *file;
    int line;
    long checks, held;
    double values, tolerances;
} check_sites[CHECK_MAX_SITES];
static int check_site_count;

static struct check_site *check_site_at(const char *file, int line)
{
    for (int i = 0; i < check_site_count; i++)
        if (check_sites[i].line == line && strcmp(check_sites[i].file, file) == 0)
            return &check_sites[i];
    if (check_site_count == CHECK_MAX_SITES)
        return NULL;
    check_sites[check_site_count] = (struct check_site){.file = file, .line = line};
    return &check_sites[check_site_count++];
}

static int check_record(const char *file, int line, int held, double value, double tolerance)
{
    struct check_site *site = check_site_at(file, line);
    if (site) {
        site->checks++;
        site->held += held != 0;
        site->values += value;
        site->tolerances += tolerance;
    }
    return held;
}

#define CHECK_AT(condition, value, tolerance, ...)                                                                     \
    do {                                                                                                               \
        if (!check_record(__FILE__, __LINE__, (condition), (value), (tolerance))) {                                    \
            if (check_failures_in_test++ == 0) {                                                                       \
                int n_ = snprintf(check_first_message, sizeof check_first_message, "%s:%d: ", __FILE__, __LINE__);     \
                snprintf(check_first_message + n_, sizeof check_first_message - (size_t)n_, __VA_ARGS__);              \
            }                                                                                                          \
        }                                                                                                              \
    } while (0)

#define CHECK(condition, ...) CHECK_AT((condition), 0.0, 0.0, __VA_ARGS__)

/* |actual - expected| <= tolerance, with both numbers in the message. */
#define CHECK_NEAR(actual, expected, tolerance, what)                                                                  \
    do {                                                                                                               \
        double a_ = (actual), e_ = (expected), t_ = (tolerance);                                                       \
        CHECK_AT(fabs(a_ - e_) <= t_, isfinite(a_) ? a_ : 1e300, t_, "%s: got %.10g, expected %.10g +- %.3g", what,    \
                 a_, e_, t_);                                                                                          \
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

static int check_exit_status(void)
{
    for (int i = 0; i < check_site_count; i++)
        printf("site %s:%d %ld %ld %.17g %.17g\n", check_sites[i].file, check_sites[i].line, check_sites[i].checks,
               check_sites[i].held, check_sites[i].values, check_sites[i].tolerances);
    return check_tests_failed ? 1 : 0;
}

#define CHECK_EXIT_STATUS() check_exit_status()

#endif
