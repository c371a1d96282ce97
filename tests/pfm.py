"""pfm.py — the colour PFM images the chapters write, read by every Python
tool (tests, kit, slides, the trade-off sweep, benchmarks): one reader, one
set of checks."""
import array
import os
import stat
import sys

# The largest output file a tool reads: a program's output is data of bounded size, and is read
# as a regular file itself, never through a symbolic link (a graded program may have left one).
OUTPUT_LIMIT = 1 << 28


def read_output(path, limit=OUTPUT_LIMIT):
    """The bytes of the output file `path`; OSError if it is a link or not a regular file,
    ValueError if it is larger than `limit`."""
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    with os.fdopen(fd, "rb") as f:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise OSError(f"{path}: not a regular file")
        if info.st_size > limit:
            raise ValueError(f"{path}: {info.st_size} bytes, more than the {limit} an output may have")
        return f.read(limit + 1)[:limit]


def read_pfm(path):
    """(width, height, floats): the RGB floats in file order (bottom row
    first) as an array('f') in this machine's byte order.  ValueError when
    the file is not a colour PFM or is cut short."""
    data = read_output(path)
    parts = data.split(b"\n", 3)
    if len(parts) < 4 or parts[0] != b"PF":
        raise ValueError(f"{path}: not a colour PFM")
    width, height = map(int, parts[1].split())
    if not (0 < width <= 1 << 15 and 0 < height <= 1 << 15):
        raise ValueError(f"{path}: image size {width}x{height} out of range")
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
