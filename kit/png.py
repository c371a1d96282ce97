"""A small PNG writer (8-bit RGB, zlib) and the pictures of the grading report.

The report's pictures are the renders enlarged by whole pixels (nearest neighbour, so every pixel of
the render stays a visible square) to at least MIN_SIDE pixels, with the compare test's tile grid
drawn over them and the tiles that failed outlined: BRIGHTER where the submission is brighter than
the solution, DARKER where it is darker (two colours that colour-blind readers tell apart too).
"""
import math
import struct
import zlib

MIN_SIDE = 192                # the report shows every picture at least this many pixels wide
BRIGHTER = (230, 159, 0)      # orange: the submission is brighter than the solution in this tile
DARKER = (0, 114, 178)        # blue: darker
GRID = (128, 128, 128)        # the tile grid, blended half into the picture


def write_png(path, width, height, rgb_rows):
    """rgb_rows: height rows of width (r, g, b) tuples of ints 0..255, top row first."""
    raw = b"".join(b"\0" + bytes(c for px in row for c in px) for row in rgb_rows)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xffffffff)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)) +
                chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def png_size(path):
    """(width, height) of a PNG file, from its IHDR chunk."""
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG file")
    return struct.unpack(">II", head[16:24])


def srgb(x):
    if not math.isfinite(x):
        return 255  # NaN and inf show white
    x = min(max(x, 0.0), 1.0)
    return round(255 * (12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055))


def heat(v):
    """0 -> black, 1 -> red, 2 -> yellow, >= 3 -> white (v: |error| in standard errors / 2)."""
    if not math.isfinite(v):
        return (255, 0, 255)
    v = max(0.0, min(v, 3.0))
    return (round(255 * min(v, 1.0)), round(255 * min(max(v - 1.0, 0.0), 1.0)), round(255 * max(v - 2.0, 0.0)))


def scale_for(width, height):
    """The whole-pixel enlargement that makes the picture at least MIN_SIDE wide and high."""
    return max(1, math.ceil(MIN_SIDE / max(1, min(width, height))))


def enlarged(width, height, colours, scale):
    """Rows of the picture `colours` (one (r, g, b) per pixel, top row first) enlarged by `scale`."""
    rows = []
    for y in range(height):
        row = []
        for x in range(width):
            row += [colours[y * width + x]] * scale
        rows += [list(row) for _ in range(scale)]
    return rows


def blend(a, b, t):
    return tuple(round(a[k] * (1 - t) + b[k] * t) for k in range(3))


def draw_grid(rows, step):
    """Half-transparent grey lines every `step` pixels (the tile borders)."""
    h, w = len(rows), len(rows[0])
    for y in range(h):
        for x in range(w):
            if x % step == 0 or y % step == 0 or x == w - 1 or y == h - 1:
                rows[y][x] = blend(rows[y][x], GRID, 0.5)


def outline(rows, x0, y0, size, colour, thickness):
    """A square frame of `thickness` pixels inside the square at (x0, y0) of side `size`."""
    for y in range(y0, y0 + size):
        for x in range(x0, x0 + size):
            if min(x - x0, y - y0, x0 + size - 1 - x, y0 + size - 1 - y) < thickness:
                rows[y][x] = colour


def write_image(path, width, height, pixels, scale=None, tile=None, marks=None):
    """pixels: linear RGB triples, top row first; tone-mapped like the chapters' PNG (sRGB, clamped),
    enlarged (default: to MIN_SIDE), with the grid of `tile` x `tile` pixel tiles when tile is given,
    and marks {tile index (row-major): +1 brighter / -1 darker} outlined in BRIGHTER / DARKER."""
    scale = scale or scale_for(width, height)
    rows = enlarged(width, height, [tuple(srgb(c) for c in p) for p in pixels], scale)
    if tile:
        draw_grid(rows, tile * scale)
        tiles_x = width // tile
        for index, sign in (marks or {}).items():
            x0, y0 = (index % tiles_x) * tile * scale, (index // tiles_x) * tile * scale
            outline(rows, x0, y0, tile * scale, BRIGHTER if sign > 0 else DARKER, max(2, tile * scale // 16))
    write_png(path, width * scale, height * scale, rows)


def write_tile_map(path, width, height, tile, pixels, marks, strength):
    """The signed difference per tile: failing tiles filled with BRIGHTER or DARKER, stronger for a
    larger relative difference (strength {tile: 0..1}); the other tiles show the picture `pixels`
    in grey, dimmed, so a student sees where the marked tiles are."""
    scale = scale_for(width, height)
    tiles_x = width // tile
    colours = []
    for y in range(height):
        for x in range(width):
            k = (y // tile) * tiles_x + x // tile
            if k in marks:
                colours.append(blend((255, 255, 255), BRIGHTER if marks[k] > 0 else DARKER,
                                     0.45 + 0.55 * min(1.0, strength.get(k, 1.0))))
            else:
                p = pixels[y * width + x]
                g = round(0.35 * srgb(0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]))
                colours.append((g, g, g))
    rows = enlarged(width, height, colours, scale)
    draw_grid(rows, tile * scale)
    write_png(path, width * scale, height * scale, rows)


def write_heat(path, width, height, values, scale=None):
    """values: one number per pixel, top row first."""
    scale = scale or scale_for(width, height)
    write_png(path, width * scale, height * scale, enlarged(width, height, [heat(v) for v in values], scale))
