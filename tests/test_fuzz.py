"""Fuzzing ``iblbench run`` with corrupt user scenes (ARCHITECTURE.md §Scenes and bad input, issue 6 "input robustness").

Tiny valid inputs (lat-long EXRs, Radiance HDRs, six face EXRs, a 320-triangle ball as OBJ and
PLY, a scene TOML naming them) are mutated with a seeded RNG, so every run sees the same
mutants: truncated, bit-flipped, header fields overwritten, resized to sizes no layout accepts,
or given NaN/Inf/negative pixels or vertices.  Each mutant goes through ``iblbench run`` and
must either succeed with a complete result, or exit 2 with one stderr line that names the
mutated file and the problem: never a traceback, another exit code, a hang, or anything left
in ``--out``.

The mutants run in this process through ``cli.main`` (one OpenCL context, kernels built once,
about 0.2 s per successful run); a sample also runs as real ``python -m iblbench.cli``
processes, to see the real exit code and stderr.
"""
from __future__ import annotations

import collections
import contextlib
import dataclasses
import io
import json
import math
import random
import signal
import struct
import subprocess
import sys
import tempfile
import traceback
import warnings
from pathlib import Path
from typing import Callable

import numpy as np
import OpenEXR
import pandas as pd
import pytest
import trimesh

from iblbench import cli
from iblbench.scenes.envmap import FACE_FILE_NAMES
from iblbench.scenes.imageio import write_exr, write_hdr

SECONDS_PER_MUTANT = 5.0      # in process; a successful run takes about 0.2 s
SUBPROCESS_SECONDS = 60.0     # includes starting Python and loading the OpenCL kernels
LATLONG = (8, 16)             # (height, width): default cube faces 4²
CROSS = (16, 12)              # a vertical cross of 4² faces
FACE = 4

SCENE = """\
[mesh]
path = "{mesh}"

[environment]
path = "{env}"

[material]
kd = 0.5
ks = 0.3
shininess = 50

[camera]
eye = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
fov_y = 45.0

[render]
width = 8
height = 8
"""


# --- the valid inputs ------------------------------------------------------------------------


def radiance(height: int, width: int, seed: int = 0) -> np.ndarray:
    """Random texels; an image with a cross's aspect is black outside the cross, as a real one is
    (layout "auto" refuses a 3:4 or 4:3 image with lit unused cells: issue 11, defect 7)."""
    image = np.random.default_rng(seed).uniform(0.05, 2.0, (height, width, 3)).astype(np.float32)
    cells = {(4, 3): ((1, 0), (0, 1), (1, 1), (2, 1), (1, 2), (1, 3)),    # (column, row)
             (3, 4): ((1, 0), (0, 1), (1, 1), (2, 1), (3, 1), (1, 2))}
    rows, columns = (4, 3) if 3 * height == 4 * width else (3, 4) if 4 * height == 3 * width else (0, 0)
    if rows:
        size = height // rows
        inside = np.zeros((rows, columns), bool)
        inside[tuple(zip(*cells[rows, columns]))[::-1]] = True
        image *= np.kron(inside, np.ones((size, size)))[..., None].astype(np.float32)
    return image


def written(write: Callable[[Path], None], suffix: str) -> bytes:
    """The bytes ``write(path)`` puts in a file."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"file{suffix}"
        write(path)
        return path.read_bytes()


def exr_bytes(image: np.ndarray | None = None, channels: dict | None = None,
              compression=OpenEXR.NO_COMPRESSION) -> bytes:
    """A scanline EXR of ``image`` (float RGB) or of ``channels``; uncompressed by default, so
    that bit flips land in the pixels rather than in a compressed stream."""
    channels = channels or {"RGB": np.ascontiguousarray(image)}
    header = {"compression": compression, "type": OpenEXR.scanlineimage}
    return written(lambda path: OpenEXR.File(header, channels).write(str(path)), ".exr")


def hdr_bytes(image: np.ndarray, rle: bool = True) -> bytes:
    return written(lambda path: write_hdr(path, image, rle=rle), ".hdr")


def ball() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=2)   # 162 vertices, 320 triangles


def base_files() -> dict[str, bytes]:
    """Every valid input by file name; a mutant replaces one of them."""
    latlong = radiance(*LATLONG)
    files = {
        "env.exr": exr_bytes(latlong),
        "zip.exr": written(lambda path: write_exr(path, latlong), ".exr"),
        "cross.hdr": hdr_bytes(radiance(*CROSS, seed=1)),
        "flat.hdr": hdr_bytes(latlong, rle=False),
        "frame0.exr": exr_bytes(latlong),
        "frame1.exr": exr_bytes(radiance(*LATLONG, seed=2)),
        "ball.obj": ball().export(file_type="obj", include_normals=True).encode(),
        "ball.ply": ball().export(file_type="ply"),
        "ascii.ply": ball().export(file_type="ply", encoding="ascii"),
    }
    for index, face in enumerate(FACE_FILE_NAMES):
        files[f"face_{face}.exr"] = exr_bytes(radiance(FACE, FACE, seed=10 + index))
    files["scene.toml"] = scene_text("scene.toml").encode()
    return files


def scene_text(target: str) -> str:
    """The scene TOML of a mutant of ``target``: it names that file and valid others."""
    mesh = target if target.endswith((".obj", ".ply")) else "ball.obj"
    if target.startswith("face_"):
        env = "face_{face}.exr"
    elif target.startswith("frame"):
        env = "frame*.exr"
    elif target.endswith((".exr", ".hdr")):
        env = target
    else:
        env = "env.exr"
    return SCENE.format(mesh=mesh, env=env)


# --- mutations: each is (bytes, rng) -> bytes ---------------------------------------------------

Mutation = Callable[[bytes, random.Random], bytes]


def keep(length: int | float) -> Mutation:
    """Truncate to ``length`` bytes, or to that fraction of the file when a float."""
    return lambda data, rng: data[:length if isinstance(length, int) else int(len(data) * length)]


def keep_random(region: Callable[[bytes], tuple[int, int]]) -> Mutation:
    """Truncate at a random offset inside ``region(data)``."""
    return lambda data, rng: data[:rng.randrange(*region(data))]


def flip_bits(count: int, region: Callable[[bytes], tuple[int, int]] | None = None) -> Mutation:
    """Flip ``count`` random bits inside ``region(data)`` (default: anywhere)."""
    def mutate(data: bytes, rng: random.Random) -> bytes:
        start, stop = region(data) if region else (0, len(data))
        out = bytearray(data)
        for _ in range(count):
            out[rng.randrange(start, stop)] ^= 1 << rng.randrange(8)
        return bytes(out)
    return mutate


def random_bytes(count: int, region: Callable[[bytes], tuple[int, int]] | None = None) -> Mutation:
    """Overwrite ``count`` random bytes inside ``region(data)`` with random values."""
    def mutate(data: bytes, rng: random.Random) -> bytes:
        start, stop = region(data) if region else (0, len(data))
        out = bytearray(data)
        for _ in range(count):
            out[rng.randrange(start, stop)] = rng.randrange(256)
        return bytes(out)
    return mutate


def replace(old: bytes | str, new: bytes | str) -> Mutation:
    """Replace the first ``old`` with ``new``."""
    old = old.encode() if isinstance(old, str) else old
    new = new.encode() if isinstance(new, str) else new

    def mutate(data: bytes, rng: random.Random) -> bytes:
        assert old in data, f"{old!r} is not in the base file"
        return data.replace(old, new, 1)
    return mutate


def constant(data: bytes) -> Mutation:
    """Ignore the base file: write ``data`` instead."""
    return lambda _data, rng: data


def poke(offset: Callable[[bytes], int], fmt: str, value) -> Mutation:
    """Overwrite the struct ``fmt`` at ``offset(data)`` with ``value``."""
    def mutate(data: bytes, rng: random.Random) -> bytes:
        out = bytearray(data)
        struct.pack_into(fmt, out, offset(data), value)
        return bytes(out)
    return mutate


# --- OpenEXR layout: magic, version, attributes (name\0 type\0 int32 size, value), \0, offset
# table (uint64 per chunk), chunks (int32 y, int32 size, data) --------------------------------


def exr_attributes(data: bytes) -> tuple[dict[str, tuple[int, int]], int]:
    """Attribute name → (offset of its value, size), and the offset of the chunk table."""
    attributes, pos = {}, 8
    while data[pos] != 0:
        name_end = data.index(b"\0", pos)
        type_end = data.index(b"\0", name_end + 1)
        size = struct.unpack_from("<i", data, type_end + 1)[0]
        attributes[data[pos:name_end].decode()] = (type_end + 5, size)
        pos = type_end + 5 + size
    return attributes, pos + 1


def exr_value(name: str, delta: int = 0) -> Callable[[bytes], int]:
    return lambda data: exr_attributes(data)[0][name][0] + delta


def exr_size_field(name: str) -> Callable[[bytes], int]:
    return lambda data: exr_attributes(data)[0][name][0] - 4


def exr_channel(name: str, delta: int) -> Callable[[bytes], int]:
    """Offset of a field of one channel in ``channels``: +0 pixel type, +8 x, +12 y sampling."""
    def offset(data: bytes) -> int:
        start, size = exr_attributes(data)[0]["channels"]
        return data.index(name.encode() + b"\0", start, start + size) + len(name) + 1 + delta
    return offset


def exr_table(data: bytes) -> int:
    return exr_attributes(data)[1]


def exr_first_chunk(data: bytes) -> int:
    return struct.unpack_from("<Q", data, exr_table(data))[0]


def exr_header(data: bytes) -> tuple[int, int]:
    return 0, exr_table(data)


def exr_pixels(data: bytes) -> tuple[int, int]:
    return exr_first_chunk(data), len(data)


# --- Radiance and PLY layout -----------------------------------------------------------------


def text_header(end_marker: bytes) -> Callable[[bytes], tuple[int, int]]:
    return lambda data: (0, data.index(end_marker) + len(end_marker))


def after_header(end_marker: bytes) -> Callable[[bytes], tuple[int, int]]:
    return lambda data: (data.index(end_marker) + len(end_marker), len(data))


HDR_HEADER = text_header(b"+X ")
HDR_PIXELS = after_header(b"+X 12\n")
FLAT_PIXELS = after_header(b"+X 16\n")
PLY_HEADER = text_header(b"end_header\n")
PLY_DATA = after_header(b"end_header\n")
PLY_VERTEX_BYTES = 162 * 12


def ply_data(offset: int) -> Callable[[bytes], int]:
    return lambda data: data.index(b"end_header\n") + len(b"end_header\n") + offset


def ply_face(index: int, corner: int) -> Callable[[bytes], int]:
    """Offset of one vertex index of a face in the binary PLY (uchar count, 3 int32)."""
    return ply_data(PLY_VERTEX_BYTES + 13 * index + 1 + 4 * corner)


def obj_line(kind: str, mutate_line: Callable[[str, random.Random], str]) -> Mutation:
    """Rewrite one random line starting with ``kind`` ("v ", "vn ", "f ")."""
    def mutate(data: bytes, rng: random.Random) -> bytes:
        lines = data.decode().split("\n")
        chosen = rng.choice([i for i, line in enumerate(lines) if line.startswith(kind)])
        lines[chosen] = mutate_line(lines[chosen], rng)
        return "\n".join(lines).encode()
    return mutate


def obj_all(kind: str, mutate_line: Callable[[str, random.Random], str]) -> Mutation:
    """Rewrite every line starting with ``kind``."""
    def mutate(data: bytes, rng: random.Random) -> bytes:
        return "\n".join(mutate_line(line, rng) if line.startswith(kind) else line
                         for line in data.decode().split("\n")).encode()
    return mutate


def field(index: int, value: str) -> Callable[[str, random.Random], str]:
    """Set whitespace-separated field ``index`` of an OBJ line (0 is the keyword)."""
    def mutate(line: str, rng: random.Random) -> str:
        parts = line.split()
        parts[index] = value
        return " ".join(parts)
    return mutate


def exr_image(image: np.ndarray) -> Mutation:
    return constant(exr_bytes(image))


def with_texel(value: float, count: int = 1) -> Mutation:
    """The lat-long EXR with ``value`` in one channel of ``count`` random texels."""
    def mutate(data: bytes, rng: random.Random) -> bytes:
        image = radiance(*LATLONG)
        for _ in range(count):
            image[rng.randrange(LATLONG[0]), rng.randrange(LATLONG[1]), rng.randrange(3)] = value
        return exr_bytes(image)
    return mutate


def scale_vertices(factor: float, offset: float = 0.0) -> Mutation:
    def mutate(data: bytes, rng: random.Random) -> bytes:
        mesh = ball()
        mesh.vertices = mesh.vertices * factor + offset
        return mesh.export(file_type="ply")
    return mutate


# --- the mutants -----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Mutant:
    id: str
    target: str              # the file mutated, a name in base_files()
    kind: str                # truncate, bitflip, header, size or payload
    mutate: Mutation
    expect: str = "either"   # "ok", "error" or "either"
    sanitize: bool = False   # run with --sanitize
    blamed: str | None = None   # the file the error must name, when not ``target``

    @property
    def file_type(self) -> str:
        return {"toml": "TOML", "obj": "OBJ", "ply": "PLY", "hdr": "HDR"}.get(
            self.target.rsplit(".", 1)[1], "EXR")


def mutants() -> list[Mutant]:
    found: list[Mutant] = []
    counters: collections.Counter = collections.Counter()

    def add(target: str, kind: str, mutate: Mutation, expect: str = "either", **options):
        stem = target.replace(".", "-")
        counters[(stem, kind)] += 1
        found.append(Mutant(f"{stem}-{kind}-{counters[(stem, kind)]:02d}", target, kind, mutate,
                            expect, **options))

    add_exr(add)
    add_hdr(add)
    add_faces_and_frames(add)
    add_obj(add)
    add_ply(add)
    add_toml(add)
    return found


def add_exr(add) -> None:
    for length in (0, 1, 4, 8, 20, 60, 120, 200):       # empty, magic, version, mid-header
        add("env.exr", "truncate", keep(length), "error")
    add("env.exr", "truncate", lambda d, rng: d[:exr_table(d)], "error")   # no chunk table
    add("env.exr", "truncate", lambda d, rng: d[:exr_table(d) + 12], "error")
    add("env.exr", "truncate", keep_random(exr_pixels))
    add("env.exr", "truncate", keep_random(exr_pixels))
    add("env.exr", "truncate", keep(-1))
    for length in (0, 30, 0.5, 0.9, -1):
        add("zip.exr", "truncate", keep(length), "error")
    for count in (1, 1, 1, 2, 2, 3, 4, 8, 8, 16, 16, 32):
        add("env.exr", "bitflip", flip_bits(count, exr_header))
    for count in (1, 2, 4, 8, 16, 64):
        add("env.exr", "bitflip", flip_bits(count, exr_pixels))
    for count in (1, 2, 4, 8, 32, 64):
        add("env.exr", "bitflip", random_bytes(count))
    for count in (1, 1, 2, 4, 8, 32):
        add("zip.exr", "bitflip", flip_bits(count))
    # Header fields.
    add("env.exr", "header", poke(lambda d: 0, "<I", 0x12345678), "error")           # magic
    for version in (0x01, 0x03, 0x202, 0x402, 0x802, 0x1002, 0xFFFFFFFF):
        add("env.exr", "header", poke(lambda d: 4, "<I", version))    # tiled, long names, deep, multipart
    for delta, value in ((8, 2**31 - 1), (12, 2**31 - 1), (8, -5), (12, -1), (0, -2**31),
                         (4, 2**31 - 1), (8, 100000), (12, 100000), (0, 3)):
        add("env.exr", "header", poke(exr_value("dataWindow", delta), "<i", value))
    add("env.exr", "header", poke(exr_value("displayWindow", 8), "<i", -2**31))
    for channel, delta, value in (("R", 0, 0), ("R", 0, 1), ("G", 0, 7), ("B", 0, -1),
                                  ("R", 8, 0), ("R", 8, 2), ("G", 12, 0), ("B", 12, 3),
                                  ("R", 8, -1)):
        add("env.exr", "header", poke(exr_channel(channel, delta), "<i", value))
    add("env.exr", "header", replace(b"R\0", b"Q\0"))          # no R channel
    add("env.exr", "header", poke(exr_value("compression"), "<B", 200))
    add("env.exr", "header", poke(exr_value("compression"), "<B", 3))    # ZIP on raw data
    add("env.exr", "header", poke(exr_value("compression"), "<B", 7))
    add("env.exr", "header", poke(exr_value("lineOrder"), "<B", 9))
    for name, value in (("channels", 2**31 - 1), ("channels", -7), ("dataWindow", 0),
                        ("dataWindow", 4), ("compression", 100000)):
        add("env.exr", "header", poke(exr_size_field(name), "<i", value))
    add("env.exr", "header", replace(b"box2i\0", b"box2j\0"))
    add("env.exr", "header", replace(b"chlist\0", b"string\0"))
    add("env.exr", "header", lambda d, rng: d[:exr_table(d) - 1] + d[exr_table(d):])  # no end
    for value in (0, 2**63, 8, 2**40):
        add("env.exr", "header", poke(exr_table, "<Q", value))
    add("env.exr", "header", poke(lambda d: exr_table(d) + 8 * 7, "<Q", 2**64 - 1))
    for delta, value in ((0, 999), (0, -2**31), (4, 2**31 - 1), (4, -1), (4, 0), (4, 1)):
        add("env.exr", "header", poke(lambda d, delta=delta: exr_first_chunk(d) + delta, "<i", value))
    # Sizes: tiny, odd, and aspect ratios no layout accepts.
    for shape, expect in (((1, 1), "error"), ((1, 2), "ok"), ((7, 15), "error"), ((7, 14), "ok"),
                          ((9, 16), "error"), ((15, 12), "error"), ((4, 3), "ok"), ((3, 4), "ok"),
                          ((1, 3), "error"), ((2, 1), "error"), ((64, 128), "ok"), ((1, 4096), "error")):
        add("env.exr", "size", exr_image(radiance(*shape)), expect)
    rgb = radiance(*LATLONG)
    planes = {name: np.ascontiguousarray(rgb[..., i]) for i, name in enumerate("RGB")}
    add("env.exr", "size", constant(exr_bytes(channels={"Y": planes["R"]})), "error")
    add("env.exr", "size", constant(exr_bytes(channels={"R": planes["R"], "G": planes["G"]})), "error")
    add("env.exr", "size", constant(exr_bytes(channels={**planes, "A": planes["R"]})), "ok")
    half = {name: plane.astype(np.float16) for name, plane in planes.items()}
    add("env.exr", "size", constant(exr_bytes(channels=half)), "ok")
    integers = {name: (plane * 100).astype(np.uint32) for name, plane in planes.items()}
    add("env.exr", "size", constant(exr_bytes(channels=integers)), "error")
    add("env.exr", "size", constant(exr_bytes(channels={**planes, "B": integers["B"]})), "error")
    add("env.exr", "header", constant(hdr_bytes(radiance(*LATLONG))), "error")     # an .hdr inside
    # Payloads: refused without --sanitize, repaired with it.
    for value in (math.nan, math.inf, -math.inf, -1.0, -1e-30):
        add("env.exr", "payload", with_texel(value), "error")
        add("env.exr", "payload", with_texel(value, count=5), "ok", sanitize=True)
    add("env.exr", "payload", exr_image(np.full((*LATLONG, 3), np.nan, np.float32)), "error")
    add("env.exr", "payload", exr_image(np.full((*LATLONG, 3), np.nan, np.float32)), "ok", sanitize=True)
    add("env.exr", "payload", with_texel(-0.0, count=8), "ok")
    add("env.exr", "payload", with_texel(1e-40, count=8), "ok")                  # denormals
    add("env.exr", "payload", with_texel(3e38, count=1), "error")                # near FLT_MAX
    add("env.exr", "payload", with_texel(3e38, count=3), "ok", sanitize=True)
    add("env.exr", "payload", exr_image(np.full((*LATLONG, 3), 3e38, np.float32)), "error")
    add("env.exr", "payload", exr_image(np.zeros((*LATLONG, 3), np.float32)), "either")   # black
    add("env.exr", "payload", constant(exr_bytes(channels={k: np.full(LATLONG, 65504, np.float16)
                                                           for k in "RGB"})), "either")
    add("zip.exr", "payload", with_texel(math.nan), "error")


def add_hdr(add) -> None:
    for length in (0, 1, 2, 5, 12, 30, 45):     # empty, signature, inside FORMAT, before resolution
        add("cross.hdr", "truncate", keep(length), "error")
    add("cross.hdr", "truncate", lambda d, rng: d[:d.index(b"+X")], "error")   # mid resolution line
    add("cross.hdr", "truncate", lambda d, rng: d[:d.index(b"+X 12\n") + 6], "error")
    for _ in range(3):
        add("cross.hdr", "truncate", keep_random(HDR_PIXELS), "error")
    add("cross.hdr", "truncate", keep(-1), "error")
    for length in (0.5, 0.9, -1):
        add("flat.hdr", "truncate", keep(length), "error")
    for count in (1, 2, 3, 4, 8, 16):
        add("cross.hdr", "bitflip", flip_bits(count, HDR_HEADER))
    for count in (1, 1, 2, 2, 4, 4, 8, 8, 16, 32, 64, 128):
        add("cross.hdr", "bitflip", flip_bits(count, HDR_PIXELS))
    for count in (1, 4, 16, 64):
        add("cross.hdr", "bitflip", random_bytes(count))
    for count in (1, 2, 8, 32, 128, 512):
        add("flat.hdr", "bitflip", flip_bits(count, FLAT_PIXELS))
    # Header lines.
    for old, new, expect in (
            ("#?", "#!", "error"), ("#?RADIANCE", "#?RGBE", "ok"),
            ("32-bit_rle_rgbe", "32-bit_rle_xyze", "error"), ("FORMAT=32-bit_rle_rgbe", "FORMAT=", "error"),
            ("\n\n", "\n", "error"), ("\n\n", "\nEXPOSURE=oops\n\n", "ok"),
            ("-Y 16 +X 12", "+Y 16 +X 12", "error"), ("-Y 16 +X 12", "-Y 16 -X 12", "error"),
            ("-Y 16 +X 12", "-Y 0 +X 12", "error"), ("-Y 16 +X 12", "-Y 16 +X 0", "error"),
            ("-Y 16 +X 12", "-Y -16 +X 12", "error"), ("-Y 16 +X 12", "-Y 99999999 +X 99999999", "error"),
            ("-Y 16 +X 12", "-Y 17 +X 12", "error"), ("-Y 16 +X 12", "-Y 12 +X 9", "either"),
            ("-Y 16 +X 12", "-Y 16 +X 13", "error"), ("-Y 16 +X 12", "-Y 4 +X 3", "either"),
            ("-Y 16 +X 12", "-Y 2147483648 +X 1", "error"),
            ("-Y 16 +X 12", "-Y 18446744073709551616 +X 18446744073709551616", "error"),
            ("-Y 16 +X 12", "-Y  16  +X  12", "either"), ("-Y 16 +X 12", "-Y 016 +X 012", "either"),
            ("-Y 16 +X 12", "-Y \u0661\u0666 +X 12", "either"),     # Arabic-Indic digits
            ("\n\n", "\n" + "X" * 100000 + "\n\n", "ok"),
            ("-Y 16 +X 12", "-Y 16\x0c+X 12", "error"), ("32-bit_rle_rgbe", "32-bit\rrle_rgbe", "error"),
            ("32-bit_rle_rgbe", "32-bit\x85rle_rgbe", "error"),       # characters that end a line
            ("#?RADIANCE\n", "#?RADIANCE", "either"),
    ):
        add("cross.hdr", "header", replace(old, new), expect)
    add("cross.hdr", "header", lambda d, rng: d.replace(b"\n", b" "), "error")   # no line ends
    add("cross.hdr", "header", lambda d, rng: d.replace(b"\n", b"\r\n"), "either")
    add("cross.hdr", "header", poke(lambda d: HDR_PIXELS(d)[0] + 4, "<B", 0), "error")    # run of 0
    add("cross.hdr", "header", poke(lambda d: HDR_PIXELS(d)[0] + 4, "<B", 255), "error")  # run past the end
    add("cross.hdr", "header", poke(lambda d: HDR_PIXELS(d)[0] + 3, "<B", 200), "either")  # RLE width
    add("cross.hdr", "header", constant(exr_bytes(radiance(*CROSS))), "error")    # an .exr inside
    # Sizes.
    for shape, expect in (((1, 1), "error"), ((4, 3), "ok"), ((15, 12), "error"), ((12, 16), "ok"),
                          ((7, 15), "error"), ((7, 14), "ok"), ((1, 2), "ok"), ((3, 4), "ok"),
                          ((2, 32768), "error")):
        add("cross.hdr", "size", constant(hdr_bytes(radiance(*shape))), expect)
    # Payloads: RGBE holds no NaN, Inf or negative, but an exponent of 255 is close to FLT_MAX.
    add("cross.hdr", "payload", constant(hdr_bytes(np.zeros((*CROSS, 3)))), "either")
    add("cross.hdr", "payload", constant(hdr_bytes(np.full((*CROSS, 3), 1.7e38))), "error")
    add("flat.hdr", "payload", poke(lambda d: FLAT_PIXELS(d)[0] + 3, "<B", 255), "error")
    add("flat.hdr", "payload", poke(lambda d: FLAT_PIXELS(d)[0] + 3, "<B", 255), "ok", sanitize=True)
    add("flat.hdr", "payload", lambda d, rng: d[:FLAT_PIXELS(d)[0]] + b"\xff" * (len(d) - FLAT_PIXELS(d)[0]),
        "error")
    add("flat.hdr", "payload", constant(hdr_bytes(-radiance(*LATLONG), rle=False)), "either")


def add_faces_and_frames(add) -> None:
    add("face_pz.exr", "size", exr_image(radiance(FACE, FACE + 1)), "error")     # not square
    add("face_nx.exr", "size", exr_image(radiance(FACE * 2, FACE * 2)), "error")  # another size
    add("face_py.exr", "size", exr_image(radiance(1, 1)), "error")
    add("face_nz.exr", "truncate", keep(0.5), "error")
    add("face_ny.exr", "payload", with_face_texel(math.nan), "error")
    add("face_ny.exr", "payload", with_face_texel(-2.0), "ok", sanitize=True)
    add("face_px.exr", "bitflip", flip_bits(4))
    add("frame1.exr", "size", exr_image(radiance(16, 32)), "error")   # frames of two sizes
    add("frame1.exr", "size", exr_image(radiance(4, 8)), "error")
    add("frame1.exr", "payload", with_texel(math.inf), "error")
    add("frame1.exr", "truncate", keep(0), "error")
    add("frame1.exr", "bitflip", flip_bits(8))


def with_face_texel(value: float) -> Mutation:
    image = radiance(FACE, FACE)
    image[1, 2, 0] = value
    return exr_image(image)


def add_obj(add) -> None:
    for length in (0, 1, 40, 0.1, 0.3):          # empty, a comment, inside the vertices
        add("ball.obj", "truncate", keep(length), "error" if length in (0, 1, 40) else "either")
    for length in (0.75, 0.9, 0.99, -1):
        add("ball.obj", "truncate", keep(length))
    add("ball.obj", "truncate", lambda d, rng: d[:d.index(b"\nf ")], "error")    # no faces
    for count in (1, 1, 2, 2, 4, 4, 8, 16, 32, 64):
        add("ball.obj", "bitflip", flip_bits(count))
    for count in (1, 4, 16, 64, 256):
        add("ball.obj", "bitflip", random_bytes(count))
    for line_kind, mutate_line, expect in (
            ("f ", field(1, "999999"), "error"), ("f ", field(2, "0"), "error"),
            ("f ", field(3, "-99999"), "error"), ("f ", field(1, "163"), "error"),
            ("f ", field(1, "-1"), "either"), ("f ", field(1, "abc"), "either"),
            ("f ", field(1, "1.5"), "either"), ("f ", field(1, "9" * 30), "error"),
            ("f ", lambda line, rng: " ".join(line.split()[:3]), "either"),
            ("f ", lambda line, rng: line + " 5 6", "either"),            # a pentagon
            ("v ", field(1, "nan"), "error"), ("v ", field(2, "inf"), "error"),
            ("v ", field(3, "-inf"), "error"), ("v ", field(1, "1e300"), "either"),
            ("v ", field(1, "1e39"), "either"), ("v ", lambda line, rng: "v 0.5", "either"),
            ("v ", field(1, "0x1p3"), "either"), ("vn ", field(1, "nan"), "either"),
            ("vn ", field(1, "0"), "either"),
    ):
        add("ball.obj", "header", obj_line(line_kind, mutate_line), expect)
    add("ball.obj", "header", obj_all("vn ", lambda line, rng: "vn nan nan nan"), "either")
    add("ball.obj", "header", obj_all("vn ", lambda line, rng: "vn 0 0 0"), "either")
    add("ball.obj", "header", obj_all("v ", field(1, "nan")), "error")
    add("ball.obj", "header", obj_all("v ", lambda line, rng: "v 0 0 0"), "either")    # degenerate
    add("ball.obj", "header", obj_all("v ", lambda line, rng: line + " 1000"), "either")   # v x y z w
    add("ball.obj", "header", obj_all("f ", lambda line, rng: "f 1 2 999999"), "error")
    add("ball.obj", "header", lambda d, rng: d.replace(b"\n", b"\r\n"), "ok")
    add("ball.obj", "header", constant(ball().export(file_type="ply")), "either")   # PLY inside
    add("ball.obj", "header", lambda d, rng: b"mtllib missing.mtl\nusemtl red\n" + d, "ok")
    add("ball.obj", "header", lambda d, rng: b"\xff\xfe" + d.decode().encode("utf-16-le"), "either")
    add("ball.obj", "header", lambda d, rng: d + bytes(range(256)) * 4, "either")
    add("ball.obj", "header", lambda d, rng: d + b"f " + b"1 " * 5000 + b"\n", "either")
    add("ball.obj", "header", lambda d, rng: d.replace(b"v ", b"v\t", 10), "either")
    add("ball.obj", "payload", obj_all("v ", lambda line, rng: "v " + " ".join(
        str(float(c) + 1000.0) for c in line.split()[1:])), "error")    # out of view
    add("ball.obj", "payload", obj_all("v ", lambda line, rng: "v " + " ".join(
        str(float(c) * 1e-30) for c in line.split()[1:])), "either")    # a speck


def add_ply(add) -> None:
    for length in (0, 3, 20, 60, 150):          # empty, "ply", inside the header
        add("ball.ply", "truncate", keep(length), "error")
    add("ball.ply", "truncate", lambda d, rng: d[:PLY_DATA(d)[0]], "error")   # header only
    add("ball.ply", "truncate", lambda d, rng: d[:PLY_DATA(d)[0] + 100], "error")
    add("ball.ply", "truncate", lambda d, rng: d[:PLY_DATA(d)[0] + PLY_VERTEX_BYTES + 50], "either")
    add("ball.ply", "truncate", keep(-1), "either")
    add("ball.ply", "truncate", keep(-13), "either")
    for length in (0, 0.3, 0.7, -1):
        add("ascii.ply", "truncate", keep(length), "error" if length == 0 else "either")
    for count in (1, 2, 4, 8, 16):
        add("ball.ply", "bitflip", flip_bits(count, PLY_HEADER))
    for count in (1, 1, 2, 4, 8, 16, 32, 64):
        add("ball.ply", "bitflip", flip_bits(count, PLY_DATA))
    for count in (1, 8, 64):
        add("ball.ply", "bitflip", random_bytes(count))
    for count in (1, 4, 16, 64):
        add("ascii.ply", "bitflip", flip_bits(count))
    # Header fields.
    for old, new, expect in (
            ("ply\n", "plx\n", "error"), ("binary_little_endian", "binary_big_endian", "either"),
            ("binary_little_endian", "ascii", "error"), ("binary_little_endian 1.0", "foo 1.0", "either"),
            ("binary_little_endian 1.0", "binary_little_endian 9.9", "either"),
            ("element vertex 162", "element vertex 1000000000000", "error"),
            ("element vertex 162", "element vertex -5", "error"),
            ("element vertex 162", "element vertex 0", "error"),
            ("element vertex 162", "element vertex 163", "either"),
            ("element vertex 162", "element vertex 161", "either"),
            ("element vertex 162", "element vertex x", "error"),
            ("element face 320", "element face 1000000000", "error"),
            ("element face 320", "element face 0", "error"),
            ("element face 320", "element face -1", "error"),
            ("element face 320", "element face 321", "either"),
            ("element face 320", "element face 99999999999999999999", "error"),
            ("property float x", "property double x", "either"),
            ("property float x\n", "", "either"),
            ("property float x", "property quux x", "error"),
            ("list uchar int", "list int int", "either"),
            ("list uchar int", "list uchar float", "either"),
            ("list uchar int", "list quux int", "error"),
            ("end_header\n", "", "error"),
            ("element face", "element fish", "either"),
            ("comment", "comment a\ncomment b\nobj_info c\ncomment", "ok"),
    ):
        add("ball.ply", "header", replace(old, new), expect)
    add("ball.ply", "header", constant(ball().export(file_type="obj").encode()), "error")  # OBJ inside
    add("ball.ply", "header", poke(ply_face(0, 0), "<i", 2**31 - 1), "error")
    add("ball.ply", "header", poke(ply_face(5, 2), "<i", -1), "either")
    add("ball.ply", "header", poke(ply_face(7, 1), "<i", 162), "error")
    add("ball.ply", "header", poke(ply_data(PLY_VERTEX_BYTES + 13 * 3), "<B", 0), "either")  # a 0-gon
    add("ball.ply", "header", poke(ply_data(PLY_VERTEX_BYTES + 13 * 3), "<B", 255), "either")
    add("ascii.ply", "header", replace("\n3 0 ", "\n3 999 "), "error")
    add("ascii.ply", "header", replace("\n3 ", "\n2 "), "either")
    add("ascii.ply", "header", replace("element vertex 162", "element vertex 9999"), "error")
    # Payloads.
    add("ball.ply", "payload", poke(ply_data(4), "<f", math.nan), "error")
    add("ball.ply", "payload", poke(ply_data(12 * 40), "<f", math.inf), "error")
    add("ball.ply", "payload", poke(ply_data(8), "<f", 3e38), "either")
    add("ascii.ply", "payload", replace("-0.52573109 0.85065079", "nan 0.85065079"), "error")
    add("ball.ply", "payload", scale_vertices(1.0, 500.0), "error")       # out of view
    add("ball.ply", "payload", scale_vertices(1e-20), "either")
    add("ball.ply", "payload", scale_vertices(1e30), "either")


def add_toml(add) -> None:
    for length in (0, 10, 0.3, 0.6):
        add("scene.toml", "truncate", keep(length), "error")
    add("scene.toml", "truncate", keep(0.95))
    add("scene.toml", "truncate", keep(-1), "ok")
    for count in (1, 1, 1, 2, 2, 3, 4, 8):
        add("scene.toml", "bitflip", flip_bits(count))
    for count in (1, 4, 16):
        add("scene.toml", "bitflip", random_bytes(count))
    for old, new, blamed in (
            ('[mesh]\npath = "ball.obj"', '[mesh\npath = "ball.obj"', None),
            ('path = "ball.obj"', 'path = "ball.obj', None),
            ('path = "ball.obj"', 'path = "ball.obj"\npath = "ball.obj"', None),
            ("[camera]", "[camera]\n[camera]", None),
            ("shininess = 50", "shininess = ", None),
            ("kd = 0.5", b"kd = 0.5\xff", None),
            ("kd = 0.5", "kd = \x00", None),
            ("[render]", "[render]]", None),
            ('path = "ball.obj"', "path = 5", None),
            ('path = "env.exr"', "path = []", None),
            ('path = "env.exr"', 'path = ""', None),
            ('path = "env.exr"', 'path = "env.exr"\nres = "4"', None),
            ('path = "env.exr"', 'path = "env.exr"\nres = true', None),
            ('path = "env.exr"', 'path = "env.exr"\nres = 4.5', None),
            ('path = "env.exr"', 'path = "env.exr"\nres = -1', None),
            ('path = "env.exr"', 'path = "env.exr"\nres = 0', None),
            ('path = "env.exr"', 'path = "env.exr"\nlayout = "vcross"', "env.exr"),
            ('path = "env.exr"', 'path = "env.exr"\nlayout = "faces"', "env.exr"),
            ('path = "env.exr"', 'path = "env.exr"\nlayout = "diagonal"', None),
            ('path = "env.exr"', 'path = "env.exr"\nlayout = 3', None),
            ("width = 8", "width = 0", None), ("height = 8", "height = -8", None),
            ("width = 8", 'width = "8"', None),
            ("kd = 0.5", 'kd = "grey"', None), ("kd = 0.5", "kd = [0.5, 0.5]", None),
            ("kd = 0.5", "kd = -0.5", None), ("kd = 0.5", "kd = 0.9", None),
            ("kd = 0.5", "kd = nan", None), ("ks = 0.3", "ks = [0.3, inf, 0.3]", None),
            ("shininess = 50", "shininess = -1", None), ("shininess = 50", "shininess = inf", None),
            ("shininess = 50", "shininess = nan", None),
            ("fov_y = 45.0", "fov_y = 0", None), ("fov_y = 45.0", "fov_y = 180", None),
            ("fov_y = 45.0", "fov_y = nan", None), ("fov_y = 45.0", "fov_y = -30", None),
            ("eye = [0.0, 0.0, 3.0]", "eye = [0.0, 0.0, 0.0]", None),
            ("eye = [0.0, 0.0, 3.0]", "eye = [0.0, 3.0, 0.0]", None),    # up ∥ view
            ("eye = [0.0, 0.0, 3.0]", "eye = [nan, 0.0, 3.0]", None),
            ("eye = [0.0, 0.0, 3.0]", "eye = [0.0, 0.0]", None),
            ("eye = [0.0, 0.0, 3.0]", 'eye = ["0", 0.0, 3.0]', None),
            ("target = [0.0, 0.0, 0.0]", "target = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 0.0]", None),
            ('[mesh]\npath = "ball.obj"', "mesh = 5", None),
            ('[environment]\npath = "env.exr"', 'environment = "env.exr"', None),
            ("[render]", "[lights]", None), ("fov_y = 45.0", "fov = 45.0", None),
            ('[mesh]\npath = "ball.obj"', "", None), ('path = "ball.obj"', "", None),
            ('[environment]\npath = "env.exr"', "", None), ('path = "env.exr"', "", None),
            ("eye = [0.0, 0.0, 3.0]", "", None),
            ("[camera]\neye = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\nfov_y = 45.0", "", None),
    ):
        add("scene.toml", "header", replace(old, new), "error", blamed=blamed)
    for old, new, blamed in (
            ('"ball.obj"', '"absent.obj"', "absent.obj"), ('"env.exr"', '"absent.exr"', "absent.exr"),
            ('"ball.obj"', '"."', ""), ('"env.exr"', '"."', ""),
            ('"ball.obj"', '"env.exr"', "env.exr"), ('"env.exr"', '"ball.obj"', "ball.obj"),
            ('"ball.obj"', '"scene.toml"', "scene.toml"), ('"env.exr"', '"none*.exr"', None),
            ('"env.exr"', '"/dev/null"', "/dev/null"), ('"env.exr"', '"/dev/zero"', "/dev/zero"),
            ('"ball.obj"', '"/dev/null"', "/dev/null"), ('"ball.obj"', '"/dev/zero.obj"', "/dev/zero.obj"),
            ('"env.exr"', '"{face}.exr"', "px.exr"), ('"env.exr"', '"*"', "ascii.ply"),
    ):
        add("scene.toml", "header", replace(old, new), "error", blamed=blamed)
    # Negative and huge sizes.
    for old, new in (("width = 8", "width = 1000000000"), ("height = 8", "height = 9223372036854775807"),
                     ("width = 8", "width = 100000"),
                     ('path = "env.exr"', 'path = "env.exr"\nres = 9223372036854775807'),
                     ('path = "env.exr"', 'path = "env.exr"\nres = 1000000'),
                     ('path = "env.exr"', 'path = "env.exr"\nres = 65536'),
                     ("shininess = 50", "shininess = 1e308"), ("fov_y = 45.0", "fov_y = 1e-300"),
                     ("eye = [0.0, 0.0, 3.0]", "eye = [0.0, 0.0, 1e300]"),
                     ("eye = [0.0, 0.0, 3.0]", "eye = [0.0, 0.0, 1e-300]")):
        add("scene.toml", "size", replace(old, new), "either")
    for old, new in (("width = 8", "width = 1"), ('path = "env.exr"', 'path = "env.exr"\nres = 1'),
                     ('path = "env.exr"', 'path = "env.exr"\nres = 3'), ("shininess = 50", "shininess = 0"),
                     ("shininess = 50", "shininess = 1e6"), ("kd = 0.5\nks = 0.3", "kd = 0\nks = 0")):
        add("scene.toml", "size", replace(old, new), "ok")


MUTANTS = mutants()
BY_ID = {mutant.id: mutant for mutant in MUTANTS}
assert len(BY_ID) == len(MUTANTS)


# --- running a mutant --------------------------------------------------------------------------


@dataclasses.dataclass
class Outcome:
    status: int | None       # the exit code; None when it crashed or hung
    stdout: str
    stderr: str
    crash: str | None = None   # the traceback, or why there is no exit code


class Hung(BaseException):
    """Raised by the alarm in the run that overstayed (BaseException: no ``except Exception``
    in the code under test may swallow it)."""


def _alarm(signum, frame):
    raise Hung


def run_in_process(argv: list[str], timeout: float) -> Outcome:
    """``cli.main(argv)`` with stdout and stderr captured, and warnings printed to stderr as a
    real run would."""
    stdout, stderr = io.StringIO(), io.StringIO()

    def show(message, category, filename, lineno, file=None, line=None):
        stderr.write(warnings.formatwarning(message, category, filename, lineno, line))

    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr), \
                warnings.catch_warnings():
            # Python's own default filters (pytest changes them), so that what is shown is what
            # a user of the command would see.
            warnings.simplefilter("default")
            for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
                warnings.simplefilter("ignore", category)
            warnings.showwarning = show
            status = cli.main(argv)
        return Outcome(status, stdout.getvalue(), stderr.getvalue())
    except Hung:
        return Outcome(None, stdout.getvalue(), stderr.getvalue(), f"no exit within {timeout} s")
    except BaseException as error:   # anything but an exit code is a failure
        return Outcome(None, stdout.getvalue(), stderr.getvalue(),
                       "".join(traceback.format_exception(error)))
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def start_process(argv: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "iblbench.cli", *argv],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish_process(process: subprocess.Popen, timeout: float) -> Outcome:
    try:
        stdout, stderr = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        stdout, stderr = process.communicate()
        return Outcome(None, stdout, stderr, f"no exit within {timeout} s")
    status = process.returncode
    return Outcome(status, stdout, stderr, None if status in (0, 2) else f"exit code {status}")


def prepare(mutant: Mutant, base: Path, folder: Path) -> tuple[list[str], Path, Path]:
    """The mutant's folder (the mutated file, links to the valid others, the scene TOML);
    returns the ``iblbench run`` arguments, the path of the mutated file and ``--out``."""
    rng = random.Random(mutant.id)
    for source in base.iterdir():
        if source.name not in (mutant.target, "scene.toml"):
            (folder / source.name).symlink_to(source)
    original = (base / mutant.target).read_bytes()
    if mutant.target != "scene.toml":
        (folder / "scene.toml").write_text(scene_text(mutant.target))
    (folder / mutant.target).write_bytes(mutant.mutate(original, rng))
    out = folder / "out"
    argv = ["run", "--scene", str(folder / "scene.toml"), "--estimator", "uniform", "--spp", "1",
            "--seeds", "1", "--out", str(out), "--no-progress"]
    if mutant.sanitize:
        argv.append("--sanitize")
    blamed = folder / (mutant.blamed if mutant.blamed is not None else mutant.target)
    return argv, blamed, out


def problems(mutant: Mutant, outcome: Outcome, blamed: Path, out: Path) -> list[str]:
    """What is wrong with the outcome; empty when the run kept every promise."""
    if outcome.crash:
        return [outcome.crash]
    if outcome.status not in (0, 2):
        return [f"exit code {outcome.status}"]
    if "Traceback" in outcome.stderr:
        return ["a traceback on stderr"]
    found = []
    if mutant.expect == "ok" and outcome.status != 0:
        found.append("expected success")
    if mutant.expect == "error" and outcome.status != 2:
        found.append("expected exit 2")
    if outcome.status == 2:
        lines = outcome.stderr.splitlines()
        if len(lines) != 1 or not outcome.stderr.endswith("\n"):
            found.append(f"exit 2 with {len(lines)} stderr lines instead of one")
        elif not lines[0].startswith("iblbench: error: "):
            found.append("the stderr line does not start with 'iblbench: error: '")
        elif str(blamed) not in lines[0]:
            found.append(f"the error does not name {blamed}")
        elif not lines[0].removeprefix("iblbench: error: ").partition(": ")[2].strip():
            found.append("the error names no problem after the file")
        if out.exists():
            left = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
            found.append(f"exit 2 left --out behind, holding {left}")
    else:
        noise = [line for line in outcome.stderr.splitlines() if not line.startswith("iblbench: ")]
        if noise:
            found.append(f"exit 0 with warnings on stderr, a sign of a silent overflow: {noise[:2]}")
        found += incomplete_result(out, frames=2 if mutant.target.startswith("frame") else 1)
    return found


def incomplete_result(out: Path, frames: int) -> list[str]:
    """What a successful run failed to leave in ``out``: the table, the manifest, finite scores."""
    missing = [name for name in ("results.parquet", "results.csv", "manifest.json")
               if not (out / name).is_file()]
    if missing:
        return [f"exit 0 without {', '.join(missing)}"]
    found = []
    if json.loads((out / "manifest.json").read_text()).get("status") != "complete":
        found.append("the manifest does not say complete")
    table = pd.read_parquet(out / "results.parquet")
    if len(table) != frames:
        found.append(f"{len(table)} result rows, expected {frames}")
    if (table.nonfinite != 0).any():
        found.append(f"non-finite pixels in the estimate: {table.nonfinite.tolist()}")
    scores = table[["mean_delta_e76", "mean_delta_e2000", "rel_mse"]].to_numpy()
    if not np.isfinite(scores).all():
        found.append(f"non-finite scores {scores.tolist()}: a silent NaN")
    return found


def describe(mutant: Mutant, outcome: Outcome, found: list[str]) -> str:
    return (f"mutant {mutant.id} ({mutant.kind} of {mutant.target}): {'; '.join(found)}\n"
            f"exit code: {outcome.status}\nstderr:\n{outcome.stderr}")


# --- the tests ---------------------------------------------------------------------------------


OUTCOMES: dict[str, int] = {}   # mutant id → exit code, for the summary


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """The valid inputs, and one run of the valid scene (it builds the kernels once)."""
    folder = tmp_path_factory.mktemp("fuzz-base")
    for name, data in base_files().items():
        (folder / name).write_bytes(data)
    outcome = run_in_process(["run", "--scene", str(folder / "scene.toml"), "--estimator",
                              "uniform", "--spp", "1", "--seeds", "1", "--out",
                              str(folder.parent / "fuzz-base-out"), "--no-progress"], timeout=120)
    assert outcome.status == 0, outcome.crash or outcome.stderr
    return folder


@pytest.mark.parametrize("mutant", MUTANTS, ids=[m.id for m in MUTANTS])
def test_mutant(mutant: Mutant, base: Path, tmp_path: Path, capfd):
    argv, blamed, out = prepare(mutant, base, tmp_path)
    capfd.readouterr()
    outcome = run_in_process(argv, SECONDS_PER_MUTANT)
    outcome.stderr += capfd.readouterr().err   # what C and C++ libraries print themselves
    OUTCOMES[mutant.id] = outcome.status
    found = problems(mutant, outcome, blamed, out)
    assert not found, describe(mutant, outcome, found)


# Each file type, the runner's own check and a success, as real processes.
SUBPROCESS_SAMPLE = (
    "env-exr-header-46",         # a chunk's scanline number overwritten (OpenEXR prints)
    "env-exr-payload-02",        # NaN texels with --sanitize: exit 0
    "cross-hdr-header-12",       # resolution line -Y 99999999 +X 99999999
    "ball-obj-payload-01",       # the mesh moved out of view (the runner's check)
    "ball-ply-header-06",        # element vertex 1000000000000
    "scene-toml-header-01",      # TOML syntax error
)


def test_a_sample_as_real_processes(base: Path, tmp_path: Path):
    """The real exit code and stderr, with no traceback.  The processes run side by side: each
    spends seconds importing."""
    runs = []
    for mutant_id in SUBPROCESS_SAMPLE:
        mutant = BY_ID[mutant_id]
        folder = tmp_path / mutant_id
        folder.mkdir()
        argv, blamed, out = prepare(mutant, base, folder)
        runs.append((mutant, start_process(argv), blamed, out))
    failures = []
    for mutant, process, blamed, out in runs:
        outcome = finish_process(process, SUBPROCESS_SECONDS)
        found = problems(mutant, outcome, blamed, out)
        if found:
            failures.append(describe(mutant, outcome, found))
    assert not failures, "\n".join(failures)


def test_fuzz_covers_every_file_type_and_kind():
    """At least 300 mutants; every file type gets truncated, bit-flipped and header-corrupted,
    and, after a full run, both outcomes occur (a fuzz that only fails tests no successful path).
    With ``-s`` it prints the mutants by file type and kind, and how their runs ended."""
    assert len(MUTANTS) >= 300
    kinds = collections.Counter((m.file_type, m.kind) for m in MUTANTS)
    for file_type in ("EXR", "HDR", "OBJ", "PLY", "TOML"):
        for kind in ("truncate", "bitflip", "header"):
            assert kinds[(file_type, kind)] >= 3, (file_type, kind)
    if len(OUTCOMES) < len(MUTANTS):
        return   # a selection ran
    ended = collections.Counter((m.file_type, m.kind, OUTCOMES[m.id]) for m in MUTANTS)
    print(f"\n{len(MUTANTS)} mutants: file type, kind, count, exit 0, exit 2")
    for file_type, kind in sorted(kinds):
        print(f"  {file_type:5s} {kind:9s} {kinds[(file_type, kind)]:4d} "
              f"{ended[(file_type, kind, 0)]:4d} {ended[(file_type, kind, 2)]:4d}")
    statuses = collections.Counter(OUTCOMES.values())
    assert statuses[0] > 30 and statuses[2] > 100, statuses
