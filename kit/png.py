"""A small PNG reader and writer (8-bit RGB, zlib) and the pictures of the grading report.

The report's pictures are renders of at least MIN_SIDE pixels (kit/compare.py renders the student's
at 128 x 128; smaller pictures are enlarged by whole pixels, nearest neighbour, so every pixel stays
a visible square), with the compare test's tile grid drawn over them and the tiles that failed
outlined: BRIGHTER where the submission is brighter than the solution, DARKER where it is darker
(two colours that colour-blind readers tell apart too).  Tiles that pass carry no mark.
"""
import math
import struct
import zlib

MIN_SIDE = 128                # the report shows every picture at least this many pixels wide
BRIGHTER = (230, 159, 0)      # orange: the submission is brighter than the solution in this tile
DARKER = (0, 114, 178)        # blue: darker
GRID = (128, 128, 128)        # the tile grid, blended half into the picture


def write_png(path, width, height, rgb_rows, comment=None):
    """rgb_rows: height rows of width (r, g, b) tuples of ints 0..255, top row first; comment: a
    text kept in the file (a tEXt "Comment" chunk; read_png_comment reads it back)."""
    raw = b"".join(b"\0" + bytes(c for px in row for c in px) for row in rgb_rows)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xffffffff)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)) +
                (chunk(b"tEXt", b"Comment\0" + comment.encode("latin-1", "replace")) if comment else b"") +
                chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def png_size(path):
    """(width, height) of a PNG file, from its IHDR chunk."""
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG file")
    return struct.unpack(">II", head[16:24])


def read_png(path):
    """(width, height, pixels) of an 8-bit RGB or RGBA PNG without interlacing (what write_png and
    the chapters write): pixels is a list of (r, g, b) tuples, top row first.  ValueError otherwise."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG file")
    pos, compressed, header = 8, b"", None
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            compressed += body
    if header is None or header[2] != 8 or header[3] not in (2, 6) or header[6] != 0:
        raise ValueError(f"{path}: not an 8-bit RGB(A) PNG without interlacing")
    width, height, channels = header[0], header[1], 3 if header[3] == 2 else 4
    raw, stride = zlib.decompress(compressed), width * channels
    pixels, previous = [], bytearray(stride)
    for y in range(height):
        start = y * (stride + 1)
        kind, line = raw[start], bytearray(raw[start + 1:start + 1 + stride])
        unfilter(kind, line, previous, channels)
        pixels += [tuple(line[x * channels:x * channels + 3]) for x in range(width)]
        previous = line
    return width, height, pixels


def read_png_comment(path):
    """The text of a PNG's tEXt "Comment" chunk (write_png's comment), or None."""
    with open(path, "rb") as f:
        data = f.read()
    pos = 8
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"tEXt" and body.startswith(b"Comment\0"):
            return body[len(b"Comment\0"):].decode("latin-1")
        pos += 12 + length
    return None


def unfilter(kind, line, previous, bpp):
    """Undo a PNG row filter in place (0 none, 1 sub, 2 up, 3 average, 4 Paeth)."""
    for x in range(len(line)):
        a = line[x - bpp] if x >= bpp else 0
        b = previous[x]
        c = previous[x - bpp] if x >= bpp else 0
        if kind == 1:
            line[x] = (line[x] + a) & 255
        elif kind == 2:
            line[x] = (line[x] + b) & 255
        elif kind == 3:
            line[x] = (line[x] + (a + b) // 2) & 255
        elif kind == 4:
            p = a + b - c
            pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
            line[x] = (line[x] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255


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


def draw_grid(rows, step_x, step_y):
    """Half-transparent grey lines every step_x and step_y pixels (the tile borders)."""
    h, w = len(rows), len(rows[0])
    for y in range(h):
        for x in range(w):
            if x % step_x == 0 or y % step_y == 0 or x == w - 1 or y == h - 1:
                rows[y][x] = blend(rows[y][x], GRID, 0.5)


def outline(rows, x0, y0, size_x, size_y, colour, thickness, sides=(True, True, True, True)):
    """A frame of `thickness` pixels inside the size_x x size_y rectangle at (x0, y0), on the
    sides (left, top, right, bottom) that are True."""
    for y in range(y0, y0 + size_y):
        for x in range(x0, x0 + size_x):
            near = (x - x0, y - y0, x0 + size_x - 1 - x, y0 + size_y - 1 - y)
            if any(side and d < thickness for side, d in zip(sides, near)):
                rows[y][x] = colour


def region_sides(index, sign, marks, tiles_x, tiles_y):
    """Which sides (left, top, right, bottom) of a marked tile border a tile not marked the same
    way: a block of tiles that differ the same way gets one frame around it, not a grid of frames."""
    tx, ty = index % tiles_x, index // tiles_x
    neighbours = ((tx - 1, ty), (tx, ty - 1), (tx + 1, ty), (tx, ty + 1))
    return tuple(not (0 <= x < tiles_x and 0 <= y < tiles_y and marks.get(y * tiles_x + x) == sign)
                 for x, y in neighbours)


def tone_mapped(pixels):
    """Linear RGB triples to 8-bit sRGB, clamped, as the chapters write their PNG."""
    return [tuple(srgb(c) for c in p) for p in pixels]


def write_marked(path, width, height, colours, tiles_x, tiles_y, marks=None, comment=None):
    """The picture `colours` (8-bit RGB, top row first), enlarged to MIN_SIDE if smaller, with the
    grid of tiles_x x tiles_y tiles drawn over it and marks {tile index (row-major): +1 brighter /
    -1 darker} outlined in BRIGHTER / DARKER (neighbouring tiles marked the same way share one
    frame); tiles without a mark are left as they are."""
    scale = scale_for(width, height)
    rows = enlarged(width, height, colours, scale)
    step_x, step_y = width * scale // tiles_x, height * scale // tiles_y
    draw_grid(rows, step_x, step_y)
    marks = marks or {}
    for index, sign in marks.items():
        x0, y0 = (index % tiles_x) * step_x, (index // tiles_x) * step_y
        outline(rows, x0, y0, step_x, step_y, BRIGHTER if sign > 0 else DARKER, max(2, step_x // 16),
                region_sides(index, sign, marks, tiles_x, tiles_y))
    write_png(path, width * scale, height * scale, rows, comment)


def write_tile_map(path, width, height, colours, tiles_x, tiles_y, marks, strength):
    """The signed difference per tile over the picture `colours` shown grey and dimmed: failing
    tiles filled with BRIGHTER or DARKER, stronger for a larger relative difference (strength
    {tile: 0..1}), so a student sees at a glance where the marked tiles are and which way."""
    scale = scale_for(width, height)
    out = []
    for y in range(height):
        for x in range(width):
            k = (y * tiles_y // height) * tiles_x + x * tiles_x // width
            if k in marks:
                out.append(blend((255, 255, 255), BRIGHTER if marks[k] > 0 else DARKER,
                                 0.45 + 0.55 * min(1.0, strength.get(k, 1.0))))
            else:
                p = colours[y * width + x]
                g = round(0.35 * (0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]))
                out.append((g, g, g))
    rows = enlarged(width, height, out, scale)
    draw_grid(rows, width * scale // tiles_x, height * scale // tiles_y)
    write_png(path, width * scale, height * scale, rows)


def write_heat(path, width, height, values, scale=None):
    """values: one number per pixel, top row first."""
    scale = scale or scale_for(width, height)
    write_png(path, width * scale, height * scale, enlarged(width, height, [heat(v) for v in values], scale))
