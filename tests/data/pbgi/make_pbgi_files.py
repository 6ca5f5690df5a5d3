#!/usr/bin/env python3
"""Writes the .pbgi files that tests/formats/pbgi/page_file_test.cpp reads, and the seed corpus
of the fuzz target (tests/fuzz/page_file_fuzz.cpp) under fuzz_corpus/.

The encoder here is written from the layout comment in formats/pbgi/page_file.h, not from the
C++ writer, so valid.pbgi also checks that the two agree. Hostile files carry correct checksums:
an attacker computes them too, and the tests must reach the checks behind them.

  valid.pbgi                3 pages of 4 KiB capacity, 2 sections, known contents
  single.pbgi               1 page, no sections (the smallest valid file)
  future_version.pbgi       valid.pbgi claiming format version 7
  version_zero.pbgi         valid.pbgi claiming format version 0
  wrong_magic.pbgi          a line of text
  huge_page_count.pbgi      a 1 KiB file whose header claims 2^32 - 1 pages
  huge_header_size.pbgi     a 1 KiB file whose header claims to be 4 GiB
  huge_sections.pbgi        a 1 KiB file whose header claims 1 TiB of sections
  huge_uncompressed_page.pbgi  valid.pbgi whose directory claims page 0 inflates to 4 GiB
  lying_frame.pbgi          page 0's zstd frame holds 2000 bytes, the directory says 1000
  truncated.pbgi            valid.pbgi cut two thirds of the way through

Needs libxxhash and libzstd (the shared libraries the build links); run it from anywhere, it
writes beside itself.
"""
import ctypes
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))

_xxhash = ctypes.CDLL("libxxhash.so.0")
_xxhash.XXH3_64bits.restype = ctypes.c_uint64
_xxhash.XXH3_64bits.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
_zstd = ctypes.CDLL("libzstd.so.1")
_zstd.ZSTD_compressBound.restype = ctypes.c_size_t
_zstd.ZSTD_compressBound.argtypes = [ctypes.c_size_t]
_zstd.ZSTD_compress.restype = ctypes.c_size_t
_zstd.ZSTD_compress.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p,
                                ctypes.c_size_t, ctypes.c_int]
_zstd.ZSTD_isError.restype = ctypes.c_uint
_zstd.ZSTD_isError.argtypes = [ctypes.c_size_t]

MAGIC = b"PBGITREE"
HEADER_SIZE = 128
ENTRY_SIZE = 24


def xxh3(data):
    return _xxhash.XXH3_64bits(bytes(data), len(data))


def zstd(data, level=3):
    """A single frame that records its content size (zstd's simple API does)."""
    cap = _zstd.ZSTD_compressBound(len(data))
    out = ctypes.create_string_buffer(cap)
    n = _zstd.ZSTD_compress(out, cap, bytes(data), len(data), level)
    assert not _zstd.ZSTD_isError(n)
    return out.raw[:n]


def lcg_bytes(n, seed):
    """Incompressible but reproducible bytes; page_file_test.cpp computes the same."""
    out = bytearray()
    x = seed
    for _ in range(n):
        x = (x * 1103515245 + 12345) & 0x7FFFFFFF
        out.append((x >> 16) & 0xFF)
    return bytes(out)


def encode_sections(sections):
    out = struct.pack("<I", len(sections))
    for name, data in sections:
        out += struct.pack("<B", len(name)) + name + struct.pack("<I", len(data)) + data
    return out


def header_checksum(header):
    return struct.pack("<Q", xxh3(header[: len(header) - 8]))


def assemble(pages, sections, page_size=4096, root=(0, 0),
             bounds=(0.0, 0.0, 0.0, 1.0, 1.0, 1.0), counts=(0, 0, 0), scene_hash=0):
    """pages: list of (compressed frame, uncompressed size). Returns the file as a bytearray."""
    body = b""
    directory = b""
    offset = HEADER_SIZE
    for frame, size in pages:
        directory += struct.pack("<QIIQ", offset, len(frame), size, xxh3(frame))
        body += frame
        offset += len(frame)
    section_bytes = encode_sections(sections)
    file_size = HEADER_SIZE + len(body) + len(directory) + len(section_bytes)
    header = MAGIC + struct.pack("<III", 1, HEADER_SIZE, page_size)
    header += struct.pack("<IQQQQII", len(pages), file_size, xxh3(directory), len(section_bytes),
                          xxh3(section_bytes), root[0], root[1])
    header += struct.pack("<6f", *bounds)
    header += struct.pack("<QQQQ", counts[0], counts[1], counts[2], scene_hash)
    header += b"\0" * 8
    assert len(header) == HEADER_SIZE
    header = bytearray(header)
    header[120:128] = header_checksum(header)
    return bytearray(header) + body + directory + section_bytes


def set_field(data, offset, fmt, value):
    """Overwrites a header field and recomputes the header checksum."""
    struct.pack_into(fmt, data, offset, value)
    data[120:128] = header_checksum(data[:HEADER_SIZE])


def header_only(size, fields):
    """A `size`-byte file of which only the header is meaningful: a valid single-page header
    with `fields` (offset -> (format, value)) overwritten and the checksum recomputed."""
    data = bytearray(single()[:HEADER_SIZE])
    struct.pack_into("<Q", data, 24, size)
    for offset, (fmt, value) in fields.items():
        struct.pack_into(fmt, data, offset, value)
    data[120:128] = header_checksum(data)
    return data + b"\0" * (size - HEADER_SIZE)


# The contents of valid.pbgi, mirrored in page_file_test.cpp (GeneratedFileReadsAsWritten).
VALID_PAGES = [bytes(range(256)) * 4, lcg_bytes(4096, 12345), b"leaf" * 100]
VALID_SECTIONS = [(b"codebook", struct.pack("<81f", *[0.25 * i for i in range(81)])),
                  (b"bake", b'{"points_per_leaf":16,"seed":7}')]


def valid():
    return assemble([(zstd(p), len(p)) for p in VALID_PAGES], VALID_SECTIONS, page_size=4096,
                    root=(0, 16), bounds=(-1.0, -2.0, -3.0, 4.0, 5.0, 6.0),
                    counts=(1000, 150, 120), scene_hash=0x0123456789ABCDEF)


def single():
    page = b"root" * 8
    return assemble([(zstd(page), len(page))], [], page_size=4096, root=(0, 0))


def with_directory_entry(data, index, fmt, offset_in_entry, value):
    """Overwrites a field of directory entry `index` and recomputes the directory checksum."""
    page_count = struct.unpack_from("<I", data, 20)[0]
    sections_size = struct.unpack_from("<Q", data, 40)[0]
    dir_offset = len(data) - sections_size - ENTRY_SIZE * page_count
    struct.pack_into(fmt, data, dir_offset + ENTRY_SIZE * index + offset_in_entry, value)
    directory = data[dir_offset: dir_offset + ENTRY_SIZE * page_count]
    set_field(data, 32, "<Q", xxh3(directory))
    return data


def lying_frame():
    page = lcg_bytes(2000, 99)
    frame = zstd(page)
    pages = [(frame, 1000)] + [(zstd(p), len(p)) for p in VALID_PAGES[1:]]
    return assemble(pages, VALID_SECTIONS, page_size=4096, root=(0, 16))


def files():
    out = {}
    out["valid.pbgi"] = valid()
    out["single.pbgi"] = single()
    future = valid()
    set_field(future, 8, "<I", 7)
    out["future_version.pbgi"] = future
    zero = valid()
    set_field(zero, 8, "<I", 0)
    out["version_zero.pbgi"] = zero
    out["wrong_magic.pbgi"] = b"This is not a .pbgi file, only a line of text.\n"
    out["huge_page_count.pbgi"] = header_only(1024, {20: ("<I", 0xFFFFFFFF)})
    out["huge_header_size.pbgi"] = header_only(1024, {12: ("<I", 0xFFFFFFF0)})
    out["huge_sections.pbgi"] = header_only(1024, {40: ("<Q", 1 << 40)})
    out["huge_uncompressed_page.pbgi"] = with_directory_entry(valid(), 0, "<I", 12, 0xFFFFFFFF)
    out["lying_frame.pbgi"] = lying_frame()
    v = valid()
    out["truncated.pbgi"] = v[: len(v) * 2 // 3]
    return out


def main():
    made = files()
    for name, data in made.items():
        with open(os.path.join(HERE, name), "wb") as f:
            f.write(bytes(data))
    # The fuzz seeds: every file above, and a raw page for the target's page-only mode (a zstd
    # frame followed by the uncompressed size it claims, little-endian u32).
    corpus = os.path.join(HERE, "fuzz_corpus")
    os.makedirs(corpus, exist_ok=True)
    for name, data in made.items():
        with open(os.path.join(corpus, name), "wb") as f:
            f.write(bytes(data))
    page = b"surfel" * 50
    with open(os.path.join(corpus, "raw_page.bin"), "wb") as f:
        f.write(zstd(page) + struct.pack("<I", len(page)))


if __name__ == "__main__":
    main()
