/*
 * tinytest.h — the smallest test framework that does the job: a test is a void function; a failed
 * CHECK prints where and why and marks the running test failed; the runner counts tests.
 */
#ifndef TINYTEST_H
#define TINYTEST_H

#include <stdio.h>
#include <string.h>

extern int tt_current_failed;

#define TT_FAIL(...)                                                                              \
    do {                                                                                          \
        printf("  FAIL %s:%d: ", __FILE__, __LINE__);                                             \
        printf(__VA_ARGS__);                                                                      \
        printf("\n");                                                                             \
        tt_current_failed = 1;                                                                    \
    } while (0)

#define CHECK(cond)                                                                               \
    do {                                                                                          \
        if (!(cond)) {                                                                            \
            TT_FAIL("%s", #cond);                                                                 \
        }                                                                                         \
    } while (0)

#define CHECK_INT(actual, expected)                                                               \
    do {                                                                                          \
        long long tt_a = (long long)(actual), tt_e = (long long)(expected);                        \
        if (tt_a != tt_e) {                                                                       \
            TT_FAIL("%s == %lld, expected %lld", #actual, tt_a, tt_e);                            \
        }                                                                                         \
    } while (0)

#define CHECK_STR(actual, expected)                                                               \
    do {                                                                                          \
        const char *tt_a = (actual), *tt_e = (expected);                                          \
        if (strcmp(tt_a, tt_e) != 0) {                                                            \
            TT_FAIL("%s\n       got      \"%s\"\n       expected \"%s\"", #actual, tt_a, tt_e);  \
        }                                                                                         \
    } while (0)

typedef void (*tt_fn)(void);
void tt_run(const char *name, tt_fn fn);

/* Each test file exposes one function that runs its tests. */
void protocol_tests(void);
void motion_tests(void);
void head_tests(void);
void head_id_tests(void);
void servo_tests(void); /* the servo head (make HEAD=servo), its own runner */

#define RUN(fn) tt_run(#fn, fn)

#endif
