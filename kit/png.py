"""A small PNG writer (8-bit RGB, zlib) and the pictures of the grading report."""
import math
import struct
import zlib


def write_png(path, width, height, rgb_rows):
    """rgb_rows: height rows of width (r, g, b) tuples of ints 0..255, top row first."""
    raw = b"".join(b"\0" + bytes(c for px in row for c in px) for row in rgb_rows)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xffffffff)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)) +
                chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


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


def write_image(path, width, height, pixels, scale=4):
    """pixels: linear RGB triples, top row first; tone-mapped like the chapters' PNG (sRGB, clamped)."""
    rows = []
    for y in range(height):
        row = []
        for x in range(width):
            row += [tuple(srgb(c) for c in pixels[y * width + x])] * scale
        rows += [row] * scale
    write_png(path, width * scale, height * scale, rows)


def write_heat(path, width, height, values, scale=4):
    """values: one number per pixel, top row first."""
    rows = []
    for y in range(height):
        row = []
        for x in range(width):
            row += [heat(values[y * width + x])] * scale
        rows += [row] * scale
    write_png(path, width * scale, height * scale, rows)
