/* frame.c — the viewer's layout and one frame: panels in a grid, their labels, the status line. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "app.h"

/* ---- layout ------------------------------------------------------------------------------------ */

/* The grid: the columns (rows follow) and the label's place (above the
 * image, or a column beside it) that make the images largest for their
 * aspect ratio, judged on the nominal cell (width / cols, height / rows,
 * rounded down); ties keep fewer columns, and the label above. */
typedef struct {
    int cols, rows;
    bool beside;
} grid;

static double fitted_height(int area_w, int area_h)
{
    if (area_w < 1 || area_h < 1)
        return 0.0;
    return fmin((double)area_w * V.aspect_h / V.aspect_w, (double)area_h);
}

static grid choose_grid(int n, int width, int height)
{
    grid best = {1, n > 0 ? n : 1, false};
    double best_h = -1.0;
    for (int cols = 1; cols <= (n > 0 ? n : 1); cols++) {
        int rows = (n + cols - 1) / cols, cw = width / cols, ch = (height - STATUS_BAND) / (rows > 0 ? rows : 1);
        double above = fitted_height(cw, ch - LABEL_BAND), beside = fitted_height(cw - LABEL_COLUMN, ch);
        if (above > best_h)
            best = (grid){cols, rows, false}, best_h = above;
        if (beside > best_h)
            best = (grid){cols, rows, true}, best_h = beside;
    }
    return best;
}

void panel_rects(int i, int n, int width, int height, rect *whole, rect *label, rect *area)
{
    grid g = choose_grid(n, width, height);
    int c = i % g.cols, r = i / g.cols;
    height -= STATUS_BAND;
    whole->x = c * width / g.cols, whole->w = (c + 1) * width / g.cols - whole->x;
    whole->y = r * height / g.rows, whole->h = (r + 1) * height / g.rows - whole->y;
    if (g.beside) {
        *label = (rect){whole->x, whole->y, LABEL_COLUMN, whole->h};
        *area = (rect){whole->x + LABEL_COLUMN, whole->y, whole->w - LABEL_COLUMN, whole->h};
    } else {
        *label = (rect){whole->x, whole->y, whole->w, LABEL_BAND};
        *area = (rect){whole->x, whole->y + LABEL_BAND, whole->w, whole->h - LABEL_BAND};
    }
    area->w = area->w < 1 ? 1 : area->w, area->h = area->h < 1 ? 1 : area->h;
}

int shown_panels(void) { return V.split ? 1 : V.panel_count; }

void placement(const panel *p, rect area, double *ox, double *oy, double *scale)
{
    int iw = p->img.width > 0 ? p->img.width : area.w, ih = p->img.height > 0 ? p->img.height : area.h;
    *scale = fmin((double)area.w / iw, (double)area.h / ih) * V.zoom;
    *ox = floor(area.x + area.w / 2.0 - V.cx * iw * *scale + 0.5);
    *oy = floor(area.y + area.h / 2.0 - V.cy * ih * *scale + 0.5);
}

int panel_at(double x, double y, double *u, double *v)
{
    int W = V.width, H = V.height, n = shown_panels();
    for (int i = 0; i < n; i++) {
        rect whole, label, area;
        panel_rects(i, n, W, H, &whole, &label, &area);
        if (x < area.x || y < area.y || x >= area.x + area.w || y >= area.y + area.h)
            continue;
        int index = V.split ? (x < W * V.split_position ? V.reference : V.split_b) : i;
        const panel *p = &V.panels[index];
        if (!p->img.pixels)
            return -1;
        double ox, oy, s;
        placement(p, area, &ox, &oy, &s);
        *u = (x - ox) / s / p->img.width, *v = (y - oy) / s / p->img.height;
        return index;
    }
    return -1;
}

/* ---- drawing a frame ------------------------------------------------------------------------- */

const float WHITE[4] = {0.95f, 0.95f, 0.95f, 1.0f}, GREY[4] = {0.7f, 0.7f, 0.7f, 1.0f},
            YELLOW[4] = {1.0f, 0.85f, 0.3f, 1.0f}, BAND[4] = {0.08f, 0.08f, 0.1f, 1.0f},
            ORANGE[4] = {1.0f, 0.45f, 0.2f, 1.0f}, DIM[4] = {0.0f, 0.0f, 0.0f, 0.65f};

/* The relative MSE of a against b, as the chapters' --ref computes it (common/image.c). */
static double relmse_against(const panel *a, const panel *b)
{
    if (!a->img.pixels || !b->img.pixels || a->img.width != b->img.width || a->img.height != b->img.height)
        return NAN;
    size_t n = (size_t)a->img.width * (size_t)a->img.height * 3;
    double sum = 0.0;
    for (size_t k = 0; k < n; k++) {
        double d = (double)a->img.pixels[k] - b->img.pixels[k], r = b->img.pixels[k];
        sum += d * d / (r * r + 0.01);
    }
    return sum / (double)n;
}

/* What a panel is, in its label: line 1 "[N] chapter  variant" (the
 * estimator, solver, model and bounces from the stats JSON), line 2 the
 * numbers (samples or patches, seconds, error) and the file name. */
void label_lines(int index, char *title, size_t title_size, char *numbers, size_t numbers_size)
{
    const panel *p = &V.panels[index];
    snprintf(title, title_size, "[%d] %s%s%s", index + 1, p->method, p->variant[0] ? "  " : "", p->variant);
    if (p->kind == SOURCE_CHILD)
        snprintf(numbers, numbers_size, "%s  updates %d", p->detail, p->updates);
    else
        snprintf(numbers, numbers_size, "%s%s%s", p->detail, p->file[0] ? "  " : "", p->file);
}

/* Label line 3: the radiance under the pointer (at the same image point
 * in every panel), or with the heat map the error against the reference. */
static void readout_line(int index, char *line, size_t line_size)
{
    const panel *p = &V.panels[index];
    double u, v;
    line[0] = '\0';
    if (p->warning[0]) { /* a child's warning: more than anything else */
        snprintf(line, line_size, "%s%s", p->warnings > 1 ? "(+more) " : "", p->warning);
        return;
    }
    int under = V.mouse_inside ? panel_at(V.mouse_x, V.mouse_y, &u, &v) : -1;
    if (under >= 0 && p->img.pixels && u >= 0 && v >= 0 && u < 1 && v < 1) {
        int x = (int)floor(u * p->img.width), y = (int)floor(v * p->img.height);
        vec3 c = image_get(&p->img, x, y);
        snprintf(line, line_size, "(%d,%d) %.4g %.4g %.4g", x, y, c.x, c.y, c.z);
    } else if (V.diff && !V.split && index != V.reference && V.reference < V.panel_count) {
        snprintf(line, line_size, "heat vs [%d]  rel.MSE %.3g", V.reference + 1,
                 relmse_against(p, &V.panels[V.reference]));
    }
}

/* Above the image: 3 lines.  Beside it: every field (the parts of a line
 * between double spaces) on a line of its own, so nothing is clipped. */
static void draw_label(int index, rect label, bool beside, const char *title_suffix)
{
    gfx_fill(label, BAND);
    char title[256], numbers[256], lines[3][512];
    label_lines(index, title, sizeof title, numbers, sizeof numbers);
    snprintf(lines[0], sizeof lines[0], "%s%s", title, title_suffix);
    snprintf(lines[1], sizeof lines[1], "%s", numbers);
    readout_line(index, lines[2], sizeof lines[2]);
    const float *colours[3] = {WHITE, GREY, V.panels[index].warning[0] ? ORANGE : YELLOW};
    int y = label.y + 2;
    for (int k = 0; k < 3; k++) {
        char *field = lines[k], *next;
        do {
            next = beside ? strstr(field, "  ") : NULL;
            if (next)
                *next = '\0', next += 2;
            if (*field || !beside)
                gfx_text(label.x + 4, y, field, colours[k], label), y += LINE;
            field = next;
        } while (field);
    }
}

/* The status line, the bottom STATUS_BAND pixels whatever the mouse does:
 * with the heat map its reference and its colour legend (1e-3 black at the
 * left end .. 1 at the right, a tick at every decade); then the exposure,
 * the zoom and the help hint. */
static void draw_status(int width, int height)
{
    rect band = {0, height - STATUS_BAND, width, STATUS_BAND};
    gfx_fill(band, BAND);
    int x = 4, y = band.y + (STATUS_BAND - LINE) / 2 + 2;
    char line[256];
    if (V.diff && !V.split && V.reference < V.panel_count) {
        snprintf(line, sizeof line, "heat vs [%d]  1e-3", V.reference + 1);
        gfx_text(x, y, line, YELLOW, band);
        rect bar = {x + gfx_text_width(line) + 6, band.y + 4, 10 * V.font_px, STATUS_BAND - 8};
        gfx_heat_legend(bar);
        for (int k = 1; k < 3; k++)
            gfx_fill((rect){bar.x + k * bar.w / 3, bar.y + bar.h - 3, 1, 3}, WHITE);
        gfx_text(bar.x + bar.w + 6, y, "1", YELLOW, band);
        x = bar.x + bar.w + 6 + 3 * V.font_px;
    }
    snprintf(line, sizeof line, "exposure %+.1f  zoom %.2fx  H: help", V.exposure, V.zoom);
    gfx_text(x, y, line, YELLOW, band);
}

void draw_frame(GLuint fbo, int width, int height)
{
    V.width = width, V.height = height;
    gfx_begin(fbo, width, height);
    int n = shown_panels();
    bool beside = choose_grid(n, width, height).beside;
    for (int i = 0; i < n; i++) {
        rect whole, label, area;
        panel_rects(i, n, width, height, &whole, &label, &area);
        if (V.split) {
            panel *a = &V.panels[V.reference], *b = &V.panels[V.split_b];
            int split_x = (int)lround(width * V.split_position);
            rect left = {area.x, area.y, split_x - area.x, area.h},
                 right = {split_x, area.y, area.x + area.w - split_x, area.h};
            double ox, oy, s;
            placement(a, area, &ox, &oy, &s);
            gfx_image(left, a->texture, ox, oy, s, V.exposure, PANEL_RADIANCE, 0);
            placement(b, area, &ox, &oy, &s);
            gfx_image(right, b->texture, ox, oy, s, V.exposure, PANEL_RADIANCE, 0);
            gfx_fill((rect){split_x, area.y, 1, area.h}, WHITE);
            char suffix[160];
            snprintf(suffix, sizeof suffix, "  |  [%d] %s", V.split_b + 1, b->method);
            draw_label(V.reference, label, beside, suffix);
            continue;
        }
        panel *p = &V.panels[i];
        double ox, oy, s;
        placement(p, area, &ox, &oy, &s);
        bool heat = V.diff && i != V.reference && V.reference < V.panel_count;
        if (p->img.pixels || p->kind == SOURCE_RASTER || p->kind == SOURCE_PLY)
            gfx_image(area, p->texture, ox, oy, s, V.exposure, heat ? PANEL_HEAT : PANEL_RADIANCE,
                      heat ? V.panels[V.reference].texture : 0);
        else
            gfx_text(area.x + 8, area.y + 8, p->pid > 0 ? "waiting for the first image ..." : "no image", GREY, area);
        if (p->stale) { /* restarted: the old camera's image, dimmed, until the first new pass */
            gfx_fill(area, DIM);
            gfx_text(area.x + 8, area.y + 8, "restarting ...", WHITE, area);
        }
        draw_label(i, label, beside, p->stale ? "  (restarting)" : V.diff && i == V.reference ? "  (reference)" : "");
    }
    draw_status(width, height);
    if (V.help)
        draw_help(width, height);
}
