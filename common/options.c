/* options.c — parsing, defaults and --help from one option table. */
#include "options.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The field a row sets, inside the state of its group. */
static void *field_of(const option *row, void *state) { return (char *)state + row->offset; }

/* "phong or blinn", "a, b or c" from "phong|blinn", "a|b|c". */
static void choices_in_words(const char *choices, char *out, size_t out_size)
{
    size_t n = 0, words = 1, written = 0;
    for (const char *c = choices; *c; c++)
        words += *c == '|';
    out[0] = '\0';
    for (const char *c = choices; *c && written + 8 < out_size; c++) {
        if (*c != '|') {
            out[written++] = *c;
            continue;
        }
        n++;
        const char *joint = n + 1 == words ? " or " : ", ";
        memcpy(out + written, joint, strlen(joint));
        written += strlen(joint);
    }
    out[written] = '\0';
}

/* The index of `word` among the '|'-separated choices, or -1. */
static int choice_index(const char *choices, const char *word)
{
    size_t length = strlen(word);
    int index = 0;
    for (const char *c = choices;; index++) {
        const char *end = strchr(c, '|');
        size_t n = end ? (size_t)(end - c) : strlen(c);
        if (n == length && !strncmp(c, word, n))
            return index;
        if (!end)
            return -1;
        c = end + 1;
    }
}

/* Parse `text` as the value of `row` into its field.  `where` is
 * "argv:N" for the command line, or the option's name for a default. */
static int parse_value(const option *row, void *state, const char *text, int index, char *err, size_t err_size)
{
    char where[96];
    if (index >= 0)
        snprintf(where, sizeof where, "argv:%d", index);
    else
        snprintf(where, sizeof where, "default of %s", row->name);
    char *end;
    errno = 0;
    switch (row->type) {
    case OPTION_FLAG: *(bool *)field_of(row, state) = true; return 0;
    case OPTION_INT: {
        long v = strtol(text, &end, 10);
        if (errno || end == text || *end || v < row->min || v > row->max) {
            snprintf(err, err_size, "%s: %s wants a whole number in [%ld, %ld], not '%s'", where, row->name,
                     (long)row->min, (long)row->max, text);
            return 2;
        }
        *(int *)field_of(row, state) = (int)v;
        return 0;
    }
    case OPTION_DOUBLE: {
        double v = strtod(text, &end);
        bool below = row->min_exclusive ? !(v > row->min) : !(v >= row->min);
        if (errno || end == text || *end || !isfinite(v) || below || v > row->max) {
            snprintf(err, err_size, "%s: %s wants a number in %c%g, %g], not '%s'", where, row->name,
                     row->min_exclusive ? '(' : '[', row->min, row->max, text);
            return 2;
        }
        *(double *)field_of(row, state) = v;
        return 0;
    }
    case OPTION_CHOICE: {
        int index = choice_index(row->choices, text);
        if (index < 0) {
            char words[256];
            choices_in_words(row->choices, words, sizeof words);
            snprintf(err, err_size, "%s: %s wants %s, not '%s'", where, row->name, words, text);
            return 2;
        }
        *(int *)field_of(row, state) = index;
        return 0;
    }
    case OPTION_STRING: *(const char **)field_of(row, state) = text; return 0;
    case OPTION_CUSTOM: {
        char why[512];
        if (row->parse(state, text, index, why, sizeof why) == 0)
            return 0;
        snprintf(err, err_size, "%s: %s %s", where, row->name, why);
        return 2;
    }
    }
    return 2;
}

static const option *find_row(const option_group *groups, int group_count, const char *name, void **state)
{
    for (int g = 0; g < group_count; g++)
        for (const option *row = groups[g].table; row->name; row++)
            if (!strcmp(row->name, name)) {
                *state = groups[g].state;
                return row;
            }
    return NULL;
}

int options_set_defaults(const option_group *groups, int group_count, char *err, size_t err_size)
{
    for (int g = 0; g < group_count; g++)
        for (const option *row = groups[g].table; row->name; row++) {
            if (!row->default_text || row->alias_of)
                continue;
            if (parse_value(row, groups[g].state, row->default_text, -1, err, err_size))
                return 2;
        }
    return 0;
}

/* An alias parses as what it stands for: "--smooth" for "--shading smooth"
 * (the value written in alias_of), or "--live-time" for "--budget" (no value
 * in alias_of: the command line's next word is the value, if the option takes one). */
static int parse_alias(const option_group *groups, int group_count, const option *row, int argc, char **argv, int *i,
                       char *err, size_t err_size)
{
    char name[64];
    const char *space = strchr(row->alias_of, ' ');
    size_t n = space ? (size_t)(space - row->alias_of) : strlen(row->alias_of);
    snprintf(name, sizeof name, "%.*s", (int)n, row->alias_of);
    void *state;
    const option *target = find_row(groups, group_count, name, &state);
    if (!target) {
        snprintf(err, err_size, "argv:%d: %s stands for unknown option %s", *i, row->name, name);
        return 2;
    }
    if (space || target->type == OPTION_FLAG)
        return parse_value(target, state, space ? space + 1 : "", *i, err, err_size);
    if (*i + 1 >= argc) {
        snprintf(err, err_size, "argv:%d: %s needs a value (see --help)", *i, argv[*i]);
        return 2;
    }
    ++*i;
    return parse_value(target, state, argv[*i], *i, err, err_size);
}

int options_parse_one(const option_group *groups, int group_count, int argc, char **argv, int *i, char *err,
                      size_t err_size)
{
    void *state;
    const option *row = find_row(groups, group_count, argv[*i], &state);
    if (!row)
        return 0;
    if (row->alias_of)
        return parse_alias(groups, group_count, row, argc, argv, i, err, err_size) ? 2 : 1;
    if (row->type == OPTION_FLAG)
        return parse_value(row, state, "", *i, err, err_size) ? 2 : 1;
    if (*i + 1 >= argc) {
        snprintf(err, err_size, "argv:%d: %s needs a value (see --help)", *i, argv[*i]);
        return 2;
    }
    ++*i;
    return parse_value(row, state, argv[*i], *i, err, err_size) ? 2 : 1;
}

/* "N in [0, 64]", "phong|blinn" ... : what follows the name in the help. */
static void value_text(const option *row, char *out, size_t out_size)
{
    if (row->type == OPTION_CHOICE)
        snprintf(out, out_size, " %s", row->choices);
    else if (row->value_name)
        snprintf(out, out_size, " %s", row->value_name);
    else
        out[0] = '\0';
}

/* "[0, 64], default 5": the parenthesis after an option's help line. */
static void range_and_default(const option *row, char *out, size_t out_size)
{
    size_t n = 0;
    out[0] = '\0';
    if (row->type == OPTION_INT)
        n = (size_t)snprintf(out, out_size, "[%ld, %ld]", (long)row->min, (long)row->max);
    else if (row->type == OPTION_DOUBLE)
        n = (size_t)snprintf(out, out_size, "%c%g, %g]", row->min_exclusive ? '(' : '[', row->min, row->max);
    if (row->default_text && n < out_size)
        snprintf(out + n, out_size - n, "%sdefault %s", n ? ", " : "", row->default_text);
}

/* Write `text` from column `column` on, wrapped before `width` columns,
 * continuation lines indented to `column`. */
static void print_wrapped(FILE *out, const char *text, int column, int width)
{
    int at = column;
    while (*text) {
        size_t word = strcspn(text, " ");
        if (at > column && at + 1 + (int)word > width) {
            fprintf(out, "\n%*s", column, "");
            at = column;
        } else if (at > column) {
            fputc(' ', out);
            at++;
        }
        fprintf(out, "%.*s", (int)word, text);
        at += (int)word;
        text += word;
        text += strspn(text, " ");
    }
    fputc('\n', out);
}

void options_print_help(FILE *out, const option *table)
{
    enum { NAME_COLUMNS = 24, WIDTH = 100 };
    for (const option *row = table; row->name; row++) {
        char value[128], left[192], parenthesis[128], line[1024];
        value_text(row, value, sizeof value);
        snprintf(left, sizeof left, "%s%s", row->name, value);
        range_and_default(row, parenthesis, sizeof parenthesis);
        if (row->alias_of)
            snprintf(line, sizeof line, "same as %s", row->alias_of);
        else
            snprintf(line, sizeof line, "%s%s%s%s", row->help, *parenthesis ? " (" : "", parenthesis,
                     *parenthesis ? ")" : "");
        if ((int)strlen(left) > NAME_COLUMNS)
            fprintf(out, "  %s\n%*s", left, NAME_COLUMNS + 3, ""); /* a long name: the help on the next line */
        else
            fprintf(out, "  %-*s ", NAME_COLUMNS, left);
        print_wrapped(out, line, NAME_COLUMNS + 3, WIDTH);
    }
}
