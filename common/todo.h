/* todo.h — what a student's handout puts in place of a function to write.
 *
 * The instructor's handout script replaces the body of every function
 * marked [exercise N.M] with a stub that calls TODO_ONCE("name") and returns
 * a neutral value (zero, false, nothing), so the chapter compiles and runs
 * and its image is black or partial.  The first call prints "file:line: TODO name is not implemented"
 * on stderr; later calls (from any thread) print nothing.
 */
#ifndef COMMON_TODO_H
#define COMMON_TODO_H

#include <stdatomic.h>
#include <stdio.h>

static inline void todo_once(atomic_flag *printed, const char *file, int line, const char *name)
{
    if (!atomic_flag_test_and_set(printed))
        fprintf(stderr, "%s:%d: TODO %s is not implemented\n", file, line, name);
}

/* One flag per call site: each stub speaks once. */
#define TODO_ONCE(name)                                                                                                \
    do {                                                                                                               \
        static atomic_flag todo_printed_ = ATOMIC_FLAG_INIT;                                                           \
        todo_once(&todo_printed_, __FILE__, __LINE__, name);                                                           \
    } while (0)

#endif
