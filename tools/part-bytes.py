#!/usr/bin/env python3
"""Where the bytes of `.vdtpart` files go: prints, per file and in all, the bytes of the roots'
heads and tops, leaf positions, sealed pages, open pages' records, region tails and cross
corners, following the body layout in `crates/vds-build/src/shard/part_file.rs`.

    tools/part-bytes.py shard-*.vdtpart
"""
import struct
import sys

HEADER, TRAILER = 32, 24
SUMS = 10 * 8 + 3 * 8 + 12 * 4 + 4 * 8 + 1 + 4 * 8 + 4 * 4
NODE, TRIANGLE, CROSS = 80, 16, 25
KINDS = ("heads", "top", "leaves", "sealed", "open", "tails", "cross")


def tally(path):
    data = open(path, "rb").read()
    body = data[HEADER:len(data) - TRAILER]
    at = 0
    bytes_of = dict.fromkeys(KINDS, 0)

    def u32():
        nonlocal at
        value = struct.unpack_from("<I", body, at)[0]
        at += 4
        return value

    def count(kind, n):
        nonlocal at
        at += n
        bytes_of[kind] += n

    roots = u32()
    bytes_of["heads"] += 4
    for _ in range(roots):
        _, tops, top_triangles, regions, leaves = [u32() for _ in range(5)]
        bytes_of["heads"] += 20
        count("heads", SUMS)
        count("top", tops * (4 + NODE) + top_triangles * TRIANGLE)
        count("leaves", 12 * leaves)
        for _ in range(regions):
            _, pages = u32(), u32()
            bytes_of["heads"] += 8
            for _ in range(pages):
                kind = body[at]
                at += 1
                a, b, c, _ = [u32() for _ in range(4)]
                if kind == 0:
                    bytes_of["sealed"] += 17
                    count("sealed", a)
                else:
                    bytes_of["open"] += 17
                    count("open", (b - 1) * 4 + b * NODE + c * TRIANGLE)
            count("tails", 9 * 8 + 4)
            parts = u32()
            bytes_of["tails"] += 4
            count("tails", 12 * parts)
    crosses = struct.unpack_from("<Q", body, at)[0]
    count("cross", 8 + CROSS * crosses)
    assert at == len(body), f"{path}: parsed {at} of {len(body)} body bytes"
    return bytes_of


def show(name, bytes_of):
    total = sum(bytes_of.values())
    shares = ", ".join(
        f"{k} {v / 1e6:.1f} MB ({100 * v / total:.0f} %)" for k, v in bytes_of.items()
    )
    print(f"{name}: {total / 1e6:.1f} MB: {shares}")


all_files = dict.fromkeys(KINDS, 0)
for path in sys.argv[1:]:
    bytes_of = tally(path)
    show(path, bytes_of)
    for k, v in bytes_of.items():
        all_files[k] += v
if len(sys.argv) > 2:
    show("all", all_files)
