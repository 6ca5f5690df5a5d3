#!/usr/bin/env python3
"""Writes the hostile image files that tests/formats/image/image_io_test.cpp feeds to readImage.

Each is a few hundred bytes, crafted byte by byte so that no image library decides what goes
in them:
  huge_header.exr      a valid scanline EXR header claiming 100000 x 100000 RGB float pixels
                       (120 GB), DWAB-compressed so that its line offset table (one entry
                       per 256 scanlines) stays small, and no pixel data at all
  too_many_floats.exr  the same for 65536 x 65536 x 1 float: each side within the
                       per-dimension limit, the total (2^32 floats) over the 2^31 limit
  huge_header.png      a PNG whose IHDR claims 100000 x 100000 RGB pixels, with valid CRCs
                       and a one-byte IDAT
  truncated.exr        a correct 16 x 16 uncompressed RGB float EXR cut off half way
                       through its pixel data
  not_an_image.exr     plain text with an .exr name
Run it from anywhere; it writes beside itself.
"""
import os
import struct
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))

FLOAT = 2  # OpenEXR PixelType
NO_COMPRESSION = 0
DWAB_COMPRESSION = 9
LINES_PER_CHUNK = {NO_COMPRESSION: 1, DWAB_COMPRESSION: 256}


def attr(name, type_name, payload):
    return name.encode() + b"\0" + type_name.encode() + b"\0" + struct.pack("<i", len(payload)) + payload


def exr_header(width, height, channels, compression=NO_COMPRESSION):
    chlist = b""
    for c in sorted(channels):  # OpenEXR requires channels in alphabetical order
        chlist += c.encode() + b"\0" + struct.pack("<iB3xii", FLOAT, 0, 1, 1)
    chlist += b"\0"
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = struct.pack("<ii", 20000630, 2)  # magic, version 2 with no flags: scanline, one part
    header += attr("channels", "chlist", chlist)
    header += attr("compression", "compression", bytes([compression]))
    header += attr("dataWindow", "box2i", box)
    header += attr("displayWindow", "box2i", box)
    header += attr("lineOrder", "lineOrder", b"\0")
    header += attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
    header += attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0))
    header += attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
    return header + b"\0"


def header_only_exr(width, height, channels):
    """A header and a plausible offset table (every entry just past it) but no chunks: enough
    for a reader to open the file and report its size."""
    header = exr_header(width, height, channels, DWAB_COMPRESSION)
    chunks = -(-height // LINES_PER_CHUNK[DWAB_COMPRESSION])
    table_end = len(header) + 8 * chunks
    return header + struct.pack("<%dQ" % chunks, *([table_end] * chunks))


def small_exr(width, height):
    channels = ["R", "G", "B"]
    header = exr_header(width, height, channels)
    line_bytes = 4 * width * len(channels)
    chunk = 8 + line_bytes
    table_end = len(header) + 8 * height
    offsets = b"".join(struct.pack("<Q", table_end + y * chunk) for y in range(height))
    lines = b""
    for y in range(height):
        lines += struct.pack("<ii", y, line_bytes)
        for c in range(len(channels)):  # B, G, R planes of the scanline
            lines += struct.pack("<%df" % width, *[(x + y + c) / 32.0 for x in range(width)])
    return header + offsets + lines


def png_chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def write(name, data):
    with open(os.path.join(HERE, name), "wb") as f:
        f.write(data)


def main():
    write("huge_header.exr", header_only_exr(100000, 100000, ["R", "G", "B"]))
    write("too_many_floats.exr", header_only_exr(65536, 65536, ["Y"]))
    ihdr = struct.pack(">IIBBBBB", 100000, 100000, 8, 2, 0, 0, 0)
    write("huge_header.png",
          b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) +
          png_chunk(b"IDAT", zlib.compress(b"\0")) + png_chunk(b"IEND", b""))
    full = small_exr(16, 16)
    header_and_table = len(exr_header(16, 16, ["R", "G", "B"])) + 8 * 16
    write("truncated.exr", full[: header_and_table + (len(full) - header_and_table) // 2])
    write("not_an_image.exr", b"This is a text file, not an OpenEXR image.\n")


if __name__ == "__main__":
    main()
