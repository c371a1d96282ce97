"""pfm.py — the colour PFM images the chapters write, read by every Python
tool (tests, kit, slides, the trade-off sweep, benchmarks): one reader, one
set of checks."""
import array
import sys


def read_pfm(path):
    """(width, height, floats): the RGB floats in file order (bottom row
    first) as an array('f') in this machine's byte order.  ValueError when
    the file is not a colour PFM or is cut short."""
    with open(path, "rb") as f:
        data = f.read()
    parts = data.split(b"\n", 3)
    if len(parts) < 4 or parts[0] != b"PF":
        raise ValueError(f"{path}: not a colour PFM")
    width, height = map(int, parts[1].split())
    count = 3 * width * height
    if len(parts[3]) < 4 * count:
        raise ValueError(f"{path}: truncated PFM")
    floats = array.array("f")
    floats.frombytes(parts[3][:4 * count])
    if (float(parts[2]) < 0) != (sys.byteorder == "little"):  # a negative scale means little-endian
        floats.byteswap()
    return width, height, floats


def pixels_top_first(width, height, floats):
    """The pixels as (r, g, b) tuples, top row first (as the image is seen)."""
    pixels = []
    for y in range(height - 1, -1, -1):
        base = 3 * width * y
        pixels.extend(tuple(floats[base + 3 * x:base + 3 * x + 3]) for x in range(width))
    return pixels
