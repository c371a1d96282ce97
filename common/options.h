/* options.h — command-line options written once, as a table.
 *
 * Each option is one row: its name, the kind of value, the field it sets,
 * the range the value must lie in, its default and its help line.  The same
 * rows set the defaults, parse argv (with the range checks and the
 * "argv:N: message" errors) and print --help, so an option cannot be
 * documented one way and parsed another.  The driver (render.c) has a table
 * for the options every chapter shares; each chapter has one for its own.
 *
 *     static const option WHITTED_OPTIONS[] = {
 *         {"--max-depth", "N", OPTION_INT, offsetof(whitted_state, max_depth),
 *          .min = 0, .max = 64, .default_text = "5", .help = "deepest reflection/refraction"},
 *         {0},
 *     };
 */
#ifndef COMMON_OPTIONS_H
#define COMMON_OPTIONS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>

typedef enum {
    OPTION_FLAG,   /* no value: sets a bool field to true */
    OPTION_INT,    /* a whole number in [min, max] into an int field */
    OPTION_DOUBLE, /* a finite number in [min, max] into a double field */
    OPTION_CHOICE, /* one of the words of `choices` ("phong|blinn"): its index into an int field */
    OPTION_STRING, /* any text into a const char * field */
    OPTION_CUSTOM, /* the value is handed to `parse` */
} option_type;

typedef struct option {
    const char *name;       /* "--max-depth"; NULL ends a table */
    const char *value_name; /* what --help shows for the value ("N"); NULL for flags and choices */
    option_type type;
    size_t offset;            /* offsetof(the state struct, the field) */
    double min, max;          /* OPTION_INT and OPTION_DOUBLE: the value must lie in [min, max] */
    bool min_exclusive;       /* OPTION_DOUBLE: the value must be > min rather than >= min */
    const char *choices;      /* OPTION_CHOICE: the words, separated by '|' */
    const char *default_text; /* parsed like a value given on the command line; NULL: zero */
    const char *help;         /* one line for --help */
    const char *alias_of;     /* "--shading smooth": this name is a short way of writing that; "--budget"
                                 (no value): another name for that option, taking its value */
    /* OPTION_CUSTOM: parse `value` (argv[argv_index]) into the state; 0, or
     * 2 with the reason (without "argv:N: --name") in why. */
    int (*parse)(void *state, const char *value, int argv_index, char *why, size_t why_size);
} option;

/* A table and the state its offsets are relative to: a chapter that embeds
 * another's struct (Whitted embeds the local model) lists both tables. */
typedef struct {
    const option *table;
    void *state;
} option_group;

enum { OPTION_MAX_GROUPS = 4 };

/* Set every field of the groups to its default.  0, or 2 with a message
 * (a default that does not parse is a programming error, said plainly). */
int options_set_defaults(const option_group *groups, int group_count, char *err, size_t err_size);

/* Is argv[*i] one of the groups' options?  1: parsed, *i advanced past its
 * value; 0: not one of them; 2: a bad or missing value, "argv:N: message" in err. */
int options_parse_one(const option_group *groups, int group_count, int argc, char **argv, int *i, char *err,
                      size_t err_size);

/* The --help lines of a table: "  --name VALUE   help (range, default)". */
void options_print_help(FILE *out, const option *table);

#endif
