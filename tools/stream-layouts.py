#!/usr/bin/env python3
"""What other layouts of a .vdt page's varint streams would cost in bytes.

An evaluation driver for a faster-decoding page format (docs/benchmarks.md, the .vdt
section): it reads pages dumped by the `page_seeds` example (each seed is a 28-byte shape
prefix and the page's decompressed streams), re-encodes chosen varint streams as byte
planes or as a low-byte plane plus an exception list, compresses every page again with
zstd level 6 as the writer does, and prints bytes per input triangle, pages only.

    pip install zstandard
    cargo run --release -p vds-format --features fuzzing --example page_seeds -- FILE.vdt DIR
    tools/stream-layouts.py DIR INPUT_TRIANGLES
"""
import os
import struct
import sys

import zstandard

STREAMS = 15
# Streams 0, 7, 11 and 12 hold raw bytes; the others LEB128 varints (docs/format.md).
VARINT_STREAMS = {1, 2, 3, 4, 5, 6, 8, 9, 10, 13, 14}
CORNERS, PART, LEAF_HIGH = 13, 14, 8


def varints(stream):
    values, value, shift = [], 0, 0
    for byte in stream:
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            values.append(value)
            value, shift = 0, 0
    return values


def put_varint(out, value):
    while value >= 0x80:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)


def byte_planes(values):
    """As many planes as the page's largest value needs, lowest byte first."""
    if not values:
        return [b""]
    width = max(1, (max(values).bit_length() + 7) // 8)
    return [bytes([width])] + [bytes((v >> (8 * b)) & 0xFF for v in values) for b in range(width)]


def low_bytes_and_exceptions(values):
    """Every value's low byte, and (gap, high part) varints for the values of 256 and more."""
    exceptions, last = bytearray(), 0
    for i, v in enumerate(values):
        if v >= 256:
            put_varint(exceptions, i - last)
            put_varint(exceptions, v >> 8)
            last = i
    return [bytes(v & 0xFF for v in values), bytes(exceptions)]


def pages(directory):
    for name in sorted(os.listdir(directory)):
        data = open(os.path.join(directory, name), "rb").read()[28:]
        lengths = struct.unpack_from(f"<{STREAMS}I", data, 0)
        if 4 * STREAMS + sum(lengths) != len(data):
            sys.exit(f"{name}: not a page seed")
        at, streams = 4 * STREAMS, []
        for length in lengths:
            streams.append(data[at:at + length])
            at += length
        yield streams


def compressed_bytes(directory, streams_to_convert, layout):
    compressor = zstandard.ZstdCompressor(level=6)
    total = 0
    for streams in pages(directory):
        out = []
        for k, stream in enumerate(streams):
            out += layout(varints(stream)) if k in streams_to_convert else [stream]
        page = struct.pack(f"<{len(out)}I", *map(len, out)) + b"".join(out)
        total += len(compressor.compress(page))
    return total


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    directory, triangles = sys.argv[1], int(sys.argv[2])
    now = compressed_bytes(directory, set(), None)
    print(f"{directory}: as now {now / triangles:.3f} B/triangle (pages only)")
    for layout_name, layout in [("byte planes", byte_planes),
                                ("low bytes + exceptions", low_bytes_and_exceptions)]:
        for streams_name, streams in [("corners", {CORNERS}),
                                      ("corners, part, leaf_high", {CORNERS, PART, LEAF_HIGH}),
                                      ("all eleven varint streams", VARINT_STREAMS)]:
            size = compressed_bytes(directory, streams, layout)
            print(f"  {layout_name:23s} {streams_name:26s} {size / triangles:.3f} B/triangle "
                  f"({100 * (size - now) / now:+.1f} %)")


if __name__ == "__main__":
    main()
